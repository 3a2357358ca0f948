//! The directional albedo of a rough dielectric boundary, which `dielectric.rs` divides by to
//! keep energy (the compensation Cycles applies to its multiscatter glass):
//!
//! E(mu, alpha, eta) = integral over the sphere of (f_r + eta² f_t) |n.wi| dwi: what a clear
//! rough boundary between media of relative index `eta` (far side over `wo`'s side) reflects and
//! transmits in one scattering off its microfacets, for `wo` at cosine `mu`, counted as energy
//! (the 1 / eta² by which radiance is compressed entering a denser medium is no loss; it comes
//! back leaving it). A smooth boundary has E = 1; a rough one loses the light that would meet
//! another microfacet on its way out: at index 1.5 and roughness 0.3, up to 7% entering and 13%
//! leaving near grazing angles; at roughness 1, 11-30% entering and 42-58% leaving.
//! Scaling both lobes by 1 / E(mu_o) returns what single scattering drops, spread as single
//! scattering spreads its light (Kulla and Conty 2017's albedo scaling; not reciprocal, as
//! Cycles' is not).
//!
//! Two tables, for light entering a denser medium (eta >= 1) and leaving it (eta < 1, read at
//! 1 / eta), over sqrt(mu), sqrt(alpha) (the glTF roughness) and z = sqrt(|eta - 1| / (eta + 1))
//! for eta up to `MAX_ETA`, integrated by visible normals (where either lobe's f |cos| / pdf is
//! F or 1 - F times G2 / G1(wo)) on a stratified grid, stored in `ggx_glass_albedo_tables.in`
//! and checked by a test, and read trilinearly.

#[cfg(test)]
use glam::{Vec2, Vec3};

#[cfg(test)]
use super::dielectric::{fresnel_dielectric, refract_about};
#[cfg(test)]
use crate::render::{
    geometry::reflect,
    sampling::{Ggx, MIN_ALPHA},
};

/// Points in sqrt(mu).
const N_MU: usize = 16;
/// Points in sqrt(alpha) = the glTF roughness.
const N_R: usize = 16;
/// Points in z = sqrt(|eta - 1| / (eta + 1)), from 0 to that of `MAX_ETA`.
const N_Z: usize = 16;
/// The largest relative index in the tables (diamond is 2.42); beyond it the last is read.
const MAX_ETA: f32 = 3.0;
/// Visible normals per axis of the integration grid.
#[cfg(test)]
const N_GRID: usize = 40;

/// One side's table: `e[k][j][i]` at z `k`, roughness `j` and mu `i` (as `Tables` spaces them).
type Table = [[[f32; N_MU]; N_R]; N_Z];

/// The tables: `enter` for eta >= 1, `leave` for eta < 1 (at 1 / eta).
#[derive(Debug, PartialEq)]
struct Tables {
    enter: Table,
    leave: Table,
}

/// The tables as [`integrate_tables`] makes them, stored so that no process pays for the
/// integration (about a second on one core); a test checks them bit for bit and rewrites them
/// with `GGX_GLASS_ALBEDO_WRITE=1`.
static TABLES: Tables = include!("ggx_glass_albedo_tables.in");

/// z of the largest index.
#[inline]
fn z_max() -> f32 {
    ((MAX_ETA - 1.0) / (MAX_ETA + 1.0)).sqrt()
}

/// The relative index (>= 1) of z-point `k`.
#[cfg(test)]
fn table_eta(k: usize) -> f32 {
    let z = k as f32 / (N_Z - 1) as f32 * z_max();
    let z2 = z * z;
    (1.0 + z2) / (1.0 - z2)
}

/// The roughness alpha of row `j`.
#[cfg(test)]
fn table_alpha(j: usize) -> f32 {
    let r = j as f32 / (N_R - 1) as f32;
    (r * r).max(MIN_ALPHA)
}

/// Integrates the tables.
#[cfg(test)]
fn integrate_tables() -> Box<Tables> {
    let mut t =
        Box::new(Tables { enter: [[[0.0; N_MU]; N_R]; N_Z], leave: [[[0.0; N_MU]; N_R]; N_Z] });
    for k in 0..N_Z {
        let eta = table_eta(k);
        for j in 0..N_R {
            let alpha = table_alpha(j);
            for i in 0..N_MU {
                // At a grazing cosine of 0 the albedo is the limit from above: 1e-4 stands for it.
                let x = i as f64 / (N_MU - 1) as f64;
                let mu = (x * x).max(1e-4) as f32;
                // Single scattering makes no light; the grid's error may not lift it above 1.
                t.enter[k][j][i] = integrate(alpha, mu, eta).min(1.0) as f32;
                t.leave[k][j][i] = integrate(alpha, mu, 1.0 / eta).min(1.0) as f32;
            }
        }
    }
    t
}

/// E at `mu` for a boundary of roughness `alpha` and relative index `eta`: the mean over
/// visible normals on an `N_GRID`² midpoint grid of F G2 / G1(wo) for the reflected direction
/// (above the surface) plus (1 - F) G2 / G1(wo) for the refracted one (below it).
#[cfg(test)]
pub(crate) fn integrate(alpha: f32, mu: f32, eta: f32) -> f64 {
    let ggx = Ggx::new(alpha);
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1 = ggx.g1(wo) as f64;
    let mut e = 0.0f64;
    for a in 0..N_GRID {
        for b in 0..N_GRID {
            let u = Vec2::new((a as f32 + 0.5) / N_GRID as f32, (b as f32 + 0.5) / N_GRID as f32);
            let m = ggx.sample_visible_normal(wo, u);
            let f = fresnel_dielectric(wo.dot(m), eta) as f64;
            let wi = reflect(wo, m);
            if wi.z > 0.0 {
                e += f * ggx.g2(wo, wi) as f64 / g1;
            }
            if let Some(wi) = refract_about(wo, m, eta).filter(|wi| wi.z < 0.0) {
                e += (1.0 - f) * ggx.g2(wo, wi) as f64 / g1;
            }
        }
    }
    e / (N_GRID * N_GRID) as f64
}

/// E(mu, alpha, eta): trilinear in (sqrt(mu), sqrt(alpha), z), eta clamped to [1 / MAX_ETA,
/// MAX_ETA].
#[inline]
pub(crate) fn albedo(mu: f32, alpha: f32, eta: f32) -> f32 {
    let (table, eta) = if eta >= 1.0 { (&TABLES.enter, eta) } else { (&TABLES.leave, 1.0 / eta) };
    let z = ((eta - 1.0) / (eta + 1.0)).max(0.0).sqrt() / z_max();
    let point = |v: f32, n: usize| {
        let x = v.clamp(0.0, 1.0) * (n - 1) as f32;
        let i = (x as usize).min(n - 2);
        (i, x - i as f32)
    };
    let (i, fx) = point(mu.clamp(0.0, 1.0).sqrt(), N_MU);
    let (j, fy) = point(alpha.clamp(0.0, 1.0).sqrt(), N_R);
    let (k, fz) = point(z, N_Z);
    let row = |k: usize, j: usize| table[k][j][i] + (table[k][j][i + 1] - table[k][j][i]) * fx;
    let plane = |k: usize| row(k, j) + (row(k, j + 1) - row(k, j)) * fy;
    plane(k) + (plane(k + 1) - plane(k)) * fz
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stored tables are the integrals, bit for bit; `GGX_GLASS_ALBEDO_WRITE=1` rewrites
    /// them.
    #[test]
    fn the_stored_glass_tables_are_the_integrals() {
        let t = integrate_tables();
        if std::env::var_os("GGX_GLASS_ALBEDO_WRITE").is_some() {
            let table = |t: &Table| {
                t.iter()
                    .map(|plane| {
                        let rows: String =
                            plane.iter().map(|r| format!("            {r:?},\n")).collect();
                        format!("        [\n{rows}        ],\n")
                    })
                    .collect::<String>()
            };
            let text = format!(
                "// Written by `GGX_GLASS_ALBEDO_WRITE=1 cargo test -p worker --lib ggx_glass`.\nTables {{\n    enter: [\n{}    ],\n    leave: [\n{}    ],\n}}\n",
                table(&t.enter),
                table(&t.leave)
            );
            let path =
                concat!(env!("CARGO_MANIFEST_DIR"), "/src/render/bsdf/ggx_glass_albedo_tables.in");
            std::fs::write(path, text).unwrap();
        }
        assert!(
            *t == TABLES,
            "the stored tables differ: rewrite them with GGX_GLASS_ALBEDO_WRITE=1"
        );
    }

    /// The albedos lie in (0, 1], a smooth boundary keeps everything (but at the most grazing
    /// cosines, where even a roughness of 1e-3 masks), and between points the lookup stays
    /// within 1% of the integral, 3.5% at grazing cosines (measured: up to 1.9% at 0.02 on the
    /// smoothest, 3.4% at 0.02 leaving a medium of index 1.05 at alpha 0.77).
    #[test]
    fn the_glass_albedos_are_bounded_and_interpolate_within_a_percent() {
        for t in [&TABLES.enter, &TABLES.leave] {
            for plane in t {
                for row in plane {
                    assert!(row.iter().all(|&e| e > 0.0 && e <= 1.0), "{row:?}");
                }
                for i in 0..N_MU {
                    assert!(i < 2 || plane[0][i] > 0.995, "smooth E {}", plane[0][i]);
                }
            }
        }
        for eta in [1.05f32, 1.33, 1.5, 2.4] {
            for eta in [eta, 1.0 / eta] {
                for alpha in [0.013f32, 0.09, 0.3, 0.77] {
                    for mu in [0.02f32, 0.11, 0.5, 0.93] {
                        let e = integrate(alpha, mu, eta);
                        let read = albedo(mu, alpha, eta) as f64;
                        // E turns fastest at grazing cosines (below 0.2 here).
                        let tolerance = if mu < 0.2 { 0.035 } else { 0.01 };
                        assert!(
                            (read - e).abs() <= tolerance * e + 2e-3,
                            "E({mu}, {alpha}, {eta}): {read} vs {e}"
                        );
                    }
                }
            }
        }
    }
}
