//! Directional albedos of the single-scattering GGX lobe, which the metal-rough BSDF uses to keep
//! energy (`metal_rough.rs`):
//!
//! E(mu, alpha) = integral over the hemisphere of D G2 / (4 mu |n.wi|) |n.wi| dwi, with F = 1:
//! what a white GGX surface reflects in one scattering for `wo` at cosine `mu`; and
//! W(mu, alpha), the same integral weighted by Schlick's (1 - |wo.h|)^5. With Schlick's Fresnel
//! F = f0 + (1 - f0) (1 - |wo.h|)^5 the lobe's albedo is linear in f0: f0 E + (1 - f0) W.
//! Their cosine-weighted means over the hemisphere, E_avg(alpha) = 2 integral E(mu) mu dmu (and
//! W_avg), give the multiple-scattering lobe of Kulla and Conty (2017) and the albedo scaling of
//! the layer below.
//!
//! The tables are integrated (stored in `ggx_albedo_tables.in`, checked by a test) by visible normals (Heitz
//! 2018, where f cos / pdf = G2 / G1(wo)) on a stratified grid, and read bilinearly in
//! (sqrt(mu), sqrt(alpha)), which crowds the points toward grazing angles and smooth surfaces,
//! where the albedos change fastest.

#[cfg(test)]
use glam::{Vec2, Vec3};

#[cfg(test)]
use crate::render::sampling::{Ggx, MIN_ALPHA};

/// Points in sqrt(mu).
const N_MU: usize = 32;
/// Points in sqrt(alpha) = the glTF roughness.
const N_R: usize = 32;
/// Visible normals per axis of the integration grid.
#[cfg(test)]
const N_GRID: usize = 48;

/// The tables: `e[j][i]` and `w[j][i]` at roughness `j / (N_R - 1)` and mu `(i / (N_MU - 1))²`,
/// and their means per roughness.
#[derive(Debug, PartialEq)]
struct Tables {
    e: [[f32; N_MU]; N_R],
    w: [[f32; N_MU]; N_R],
    e_avg: [f32; N_R],
    w_avg: [f32; N_R],
}

/// The tables as [`integrate_tables`] makes them, stored so that no process pays for the
/// integration (about 0.1 s on one core); a test checks them bit for bit and rewrites them
/// with `GGX_ALBEDO_WRITE=1`.
static TABLES: Tables = include!("ggx_albedo_tables.in");

fn tables() -> &'static Tables {
    &TABLES
}

/// Integrates the tables.
#[cfg(test)]
fn integrate_tables() -> Box<Tables> {
    let mut t = Box::new(Tables {
        e: [[0.0; N_MU]; N_R],
        w: [[0.0; N_MU]; N_R],
        e_avg: [0.0; N_R],
        w_avg: [0.0; N_R],
    });
    let weights = mean_weights();
    for j in 0..N_R {
        let alpha = table_alpha(j);
        for i in 0..N_MU {
            // At a grazing cosine of 0 the albedo is the limit from above: 1e-4 stands for it.
            let x = i as f64 / (N_MU - 1) as f64;
            let (e, w) = integrate(alpha, (x * x).max(1e-4) as f32);
            // The single-scattering albedo is at most 1; the grid's error may not lift it.
            t.e[j][i] = e.min(1.0) as f32;
            t.w[j][i] = w.min(e).min(1.0) as f32;
        }
        let mean = |row: &[f32; N_MU]| -> f64 {
            row.iter().zip(&weights).map(|(&e, &k)| e as f64 * k).sum::<f64>()
        };
        t.e_avg[j] = mean(&t.e[j]).min(1.0) as f32;
        t.w_avg[j] = mean(&t.w[j]).min(t.e_avg[j] as f64) as f32;
    }
    t
}

/// Weights that turn a row of the table into its cosine-weighted mean 2 integral E(mu) mu dmu
/// = 4 integral E x³ dx (mu = x²) of the row as `lookup` reads it, linear in x between points:
/// each point's hat function times 4 x³, integrated by the midpoint rule on 256 steps per
/// interval. They sum to 1, so that a row of ones has the mean 1.
#[cfg(test)]
fn mean_weights() -> [f64; N_MU] {
    const STEPS: usize = 256;
    let dx = 1.0 / (N_MU - 1) as f64;
    let mut k = [0.0f64; N_MU];
    for i in 0..N_MU - 1 {
        for s in 0..STEPS {
            let f = (s as f64 + 0.5) / STEPS as f64;
            let x = (i as f64 + f) * dx;
            let w = 4.0 * x * x * x * dx / STEPS as f64;
            k[i] += w * (1.0 - f);
            k[i + 1] += w * f;
        }
    }
    k
}

/// The roughness alpha of row `j`.
#[cfg(test)]
fn table_alpha(j: usize) -> f32 {
    let r = j as f32 / (N_R - 1) as f32;
    (r * r).max(MIN_ALPHA)
}

/// (E, W) at `mu` for GGX of roughness `alpha`: the mean of G2 / G1(wo) (and of it times
/// Schlick's weight) over visible normals on an `N_GRID`² midpoint grid, directions below the
/// horizon counting 0.
#[cfg(test)]
pub(crate) fn integrate(alpha: f32, mu: f32) -> (f64, f64) {
    let ggx = Ggx::new(alpha);
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1 = ggx.g1(wo) as f64;
    let (mut e, mut w) = (0.0f64, 0.0f64);
    for a in 0..N_GRID {
        for b in 0..N_GRID {
            let u = Vec2::new((a as f32 + 0.5) / N_GRID as f32, (b as f32 + 0.5) / N_GRID as f32);
            let h = ggx.sample_visible_normal(wo, u);
            let cos_oh = wo.dot(h);
            let wi = 2.0 * cos_oh * h - wo;
            if wi.z <= 0.0 {
                continue;
            }
            let weight = ggx.g2(wo, wi) as f64 / g1;
            let m = (1.0 - cos_oh.clamp(0.0, 1.0)) as f64;
            e += weight;
            w += weight * m * m * m * m * m;
        }
    }
    let n = (N_GRID * N_GRID) as f64;
    (e / n, w / n)
}

/// Bilinear lookups of the tables `a` and `b` at (mu, alpha).
#[inline]
fn lookup(a: &[[f32; N_MU]; N_R], b: &[[f32; N_MU]; N_R], mu: f32, alpha: f32) -> (f32, f32) {
    let x = mu.clamp(0.0, 1.0).sqrt() * (N_MU - 1) as f32;
    let y = alpha.clamp(0.0, 1.0).sqrt() * (N_R - 1) as f32;
    let (i, j) = ((x as usize).min(N_MU - 2), (y as usize).min(N_R - 2));
    let (fx, fy) = (x - i as f32, y - j as f32);
    let read = |t: &[[f32; N_MU]; N_R]| {
        let row = |j: usize| t[j][i] + (t[j][i + 1] - t[j][i]) * fx;
        row(j) + (row(j + 1) - row(j)) * fy
    };
    (read(a), read(b))
}

/// Linear lookup of a per-roughness `row` at alpha.
#[inline]
fn lookup_row(row: &[f32; N_R], alpha: f32) -> f32 {
    let y = alpha.clamp(0.0, 1.0).sqrt() * (N_R - 1) as f32;
    let j = (y as usize).min(N_R - 2);
    row[j] + (row[j + 1] - row[j]) * (y - j as f32)
}

/// (E(mu, alpha), W(mu, alpha)): the white single-scattering albedo for `wo` at cosine `mu`,
/// and the albedo weighted by Schlick's (1 - |wo.h|)^5.
#[inline]
pub(crate) fn albedos(mu: f32, alpha: f32) -> (f32, f32) {
    let t = tables();
    lookup(&t.e, &t.w, mu, alpha)
}

/// (E_avg(alpha), W_avg(alpha)): the cosine-weighted means of E and W over the hemisphere.
#[inline]
pub(crate) fn mean_albedos(alpha: f32) -> (f32, f32) {
    let t = tables();
    (lookup_row(&t.e_avg, alpha), lookup_row(&t.w_avg, alpha))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stored tables are the integrals, bit for bit; `GGX_ALBEDO_WRITE=1` rewrites them.
    #[test]
    fn the_stored_tables_are_the_integrals() {
        let t = integrate_tables();
        if std::env::var_os("GGX_ALBEDO_WRITE").is_some() {
            let rows = |rows: &[[f32; N_MU]]| {
                rows.iter().map(|r| format!("        {r:?},\n")).collect::<String>()
            };
            let text = format!(
                "// Written by `GGX_ALBEDO_WRITE=1 cargo test -p worker --lib ggx_albedo`.\nTables {{\n    e: [\n{}    ],\n    w: [\n{}    ],\n    e_avg: {:?},\n    w_avg: {:?},\n}}\n",
                rows(&t.e),
                rows(&t.w),
                t.e_avg,
                t.w_avg
            );
            let path = concat!(env!("CARGO_MANIFEST_DIR"), "/src/render/bsdf/ggx_albedo_tables.in");
            std::fs::write(path, text).unwrap();
        }
        assert!(*t == TABLES, "the stored tables differ: rewrite them with GGX_ALBEDO_WRITE=1");
    }

    #[test]
    fn the_tables_hold_albedos_that_fall_with_roughness_and_agree_with_their_integrals() {
        let t = tables();
        for j in 0..N_R {
            for i in 0..N_MU {
                let (e, w) = (t.e[j][i], t.w[j][i]);
                assert!((0.0..=1.0).contains(&e) && (0.0..=e).contains(&w), "[{j}][{i}]: {e} {w}");
            }
            let (lo, hi) = t.e[j].iter().fold((1.0f32, 0.0f32), |(a, b), &e| (a.min(e), b.max(e)));
            assert!(
                (lo..=hi).contains(&t.e_avg[j]),
                "row {j}: mean {} outside [{lo}, {hi}]",
                t.e_avg[j]
            );
        }
        // A smooth surface reflects everything. At alpha = 1, D is 1 / pi, and at normal
        // incidence only the half vectors within 45 degrees of the normal reflect above the
        // horizon: E(1) is below sin²(45°) = 1/2 (G2 takes a little more).
        assert!(t.e_avg[0] > 0.999, "smooth E_avg {}", t.e_avg[0]);
        let normal = t.e[N_R - 1][N_MU - 1];
        assert!((0.25..0.5).contains(&normal), "rough E(1) {normal}");
        assert!((0.3..0.6).contains(&t.e_avg[N_R - 1]), "rough E_avg {}", t.e_avg[N_R - 1]);
        for i in 0..N_MU {
            assert!(t.e[N_R - 1][i] < t.e[N_R / 2][i] + 1e-4, "E falls with roughness at mu {i}");
        }
        // A smooth surface's W is Schlick's weight at the mirror direction, (1 - mu)^5.
        for mu in [0.05f32, 0.3, 0.9] {
            let w = albedos(mu, MIN_ALPHA).1;
            assert!((w - (1.0 - mu).powi(5)).abs() < 0.01, "W({mu}) = {w}");
        }
        // Between points, interpolation stays within 1% (absolute 2e-3) of the integral.
        for alpha in [0.013f32, 0.09, 0.3, 0.77] {
            for mu in [0.02f32, 0.11, 0.5, 0.93] {
                let (e, w) = integrate(alpha, mu);
                let (read_e, read_w) = albedos(mu, alpha);
                assert!(
                    (read_e as f64 - e).abs() <= 0.01 * e + 2e-3,
                    "E({mu}, {alpha}): {read_e} vs {e}"
                );
                assert!(
                    (read_w as f64 - w).abs() <= 0.01 * w + 2e-3,
                    "W({mu}, {alpha}): {read_w} vs {w}"
                );
            }
        }
    }

    /// The grid agrees with a brute-force integral of the BRDF over the hemisphere.
    #[test]
    fn visible_normal_integration_agrees_with_a_hemisphere_quadrature() {
        for (alpha, mu) in [(0.25f32, 0.6f32), (0.64, 0.2), (1.0, 0.9)] {
            let ggx = Ggx::new(alpha);
            let wo = Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
            let (n_t, n_p) = (400, 400);
            let mut sum = 0.0f64;
            for a in 0..n_t {
                // cos theta_i = s², crowding the rings toward the horizon.
                let s = (a as f64 + 0.5) / n_t as f64;
                let c = s * s;
                let sin = (1.0 - c * c).sqrt();
                for b in 0..n_p {
                    let phi = std::f64::consts::TAU * (b as f64 + 0.5) / n_p as f64;
                    let wi =
                        Vec3::new((sin * phi.cos()) as f32, (sin * phi.sin()) as f32, c as f32);
                    let h = (wo + wi).normalize();
                    let f = ggx.d(h) * ggx.g2(wo, wi) / (4.0 * wo.z * wi.z);
                    sum += f as f64 * c * 2.0 * s / n_t as f64 * std::f64::consts::TAU / n_p as f64;
                }
            }
            let (e, _) = integrate(alpha, mu);
            assert!((e - sum).abs() < 2e-3, "alpha {alpha} mu {mu}: {e} vs {sum}");
        }
    }
}
