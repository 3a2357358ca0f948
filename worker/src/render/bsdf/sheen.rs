//! The `KHR_materials_sheen` lobe: the "Charlie" microfacet sheen of Estevez and Kulla (2017),
//! a forest of fibres around the normal that scatters light back near grazing angles.
//!
//! f_sheen = sheenColor * D(h) * G / (4 |n.wo| |n.wi|), with, for alpha = sheenRoughness (the
//! extension uses the roughness itself, not its square),
//!
//! D(h) = (2 + 1 / alpha) * sin(theta_h)^(1 / alpha) / (2 pi)
//! G = 1 / (1 + Lambda(wo) + Lambda(wi)), Lambda(mu) = exp(L(mu)) for mu < 1/2 and
//!     exp(2 L(1/2) - L(1 - mu)) otherwise, L(x) = a / (1 + b x^c) + d x + e
//!
//! with (a, b, c, d, e) interpolated by (1 - alpha)² between the paper's two fits.
//! The layer scales what lies under it by 1 - max(sheenColor) * E(|n.wo|), where E(mu) is the
//! lobe's directional albedo for a white sheen: [`albedo`] reads it from a table integrated from
//! `brdf` once per process (`std::sync::OnceLock`), interpolated bilinearly in (mu, alpha).
//! The lobe is sampled uniformly over the hemisphere: f cos is D G / (4 |n.wo|), nearly flat in
//! the cosine of `wi`, and strongest toward the horizon, where a cosine lobe would starve it.

use std::{f32::consts::PI, sync::OnceLock};

use glam::Vec3;

/// Smallest sheen roughness used. A roughness of 0 (the extension's default) would make the
/// distribution a delta at the horizon; and below about 0.05 the Charlie Lambda fit lets the lobe
/// reflect more than it receives at grazing angles (E(0.001) = 1.9 at alpha 0.01, integrated
/// with `integrate_albedo`), which no albedo scaling can undo.
pub(crate) const MIN_SHEEN_ALPHA: f32 = 0.07;

/// The sheen layer at a point.
#[derive(Clone, Copy, Debug)]
pub struct Sheen {
    /// `sheenColor` (linear), each in [0, 1].
    pub color: Vec3,
    /// Roughness in [[`MIN_SHEEN_ALPHA`], 1].
    pub alpha: f32,
}

impl Sheen {
    /// A sheen of `color` and `roughness`, both clamped to their ranges.
    pub fn new(color: Vec3, roughness: f32) -> Self {
        let alpha = if roughness > MIN_SHEEN_ALPHA { roughness.min(1.0) } else { MIN_SHEEN_ALPHA };
        Sheen { color: color.clamp(Vec3::ZERO, Vec3::ONE), alpha }
    }

    /// What the layer lets through to the layers below for `wo`: 1 - max(color) * E(wo.z).
    #[inline]
    pub fn scaling(&self, cos_wo: f32) -> f32 {
        generic::scaling(self.color.max_element(), self.alpha, cos_wo)
    }

    /// f_sheen(wo, wi) for both directions above the surface (0 otherwise).
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        self.color * brdf(self.alpha, wo, wi)
    }
}

/// The Charlie distribution D at a half vector whose cosine to the normal is `cos_h`.
#[inline]
fn distribution(alpha: f32, cos_h: f32) -> f32 {
    let inv = 1.0 / alpha;
    let sin2 = (1.0 - cos_h * cos_h).max(0.0);
    (2.0 + inv) * sin2.powf(0.5 * inv) / (2.0 * PI)
}

/// The fit L(x) of the Charlie Lambda.
#[inline]
fn l(x: f32, alpha: f32) -> f32 {
    let t = (1.0 - alpha) * (1.0 - alpha);
    let mix = |p: f32, q: f32| p + (q - p) * t;
    let a = mix(21.5473, 25.3245);
    let b = mix(3.82987, 3.32435);
    let c = mix(0.19823, 0.16801);
    let d = mix(-1.97760, -1.27393);
    let e = mix(-4.32054, -4.85967);
    a / (1.0 + b * x.powf(c)) + d * x + e
}

/// The Charlie Lambda for a direction whose cosine to the normal is `cos`.
#[inline]
fn lambda(cos: f32, alpha: f32) -> f32 {
    let cos = cos.abs();
    if cos < 0.5 {
        l(cos, alpha).exp()
    } else {
        (2.0 * l(0.5, alpha) - l(1.0 - cos, alpha)).exp()
    }
}

/// The white sheen BRDF D G / (4 |n.wo| |n.wi|) (0 unless both directions are above).
#[inline]
pub(crate) fn brdf(alpha: f32, wo: Vec3, wi: Vec3) -> f32 {
    generic::brdf(alpha, wo.into(), wi.into())
}

/// The sheen written once over `Real`, for one path (`f32`, through [`Sheen`] and [`brdf`])
/// and for a vector of them (the wavefront): the arithmetic in the lanes, the distribution's
/// power, the visibility's exponentials and the albedo table's lookup lane by lane
/// (`Real::each2`), which keeps every lane's bits those of the scalar instance.
pub(crate) mod generic {
    use crate::render::lanes::{Real, V3};

    /// `super::Sheen::scaling` for a sheen whose colour's largest channel is `color_max`.
    #[inline(always)]
    pub(crate) fn scaling<R: Real>(color_max: R, alpha: R, cos_wo: R) -> R {
        let e = cos_wo.each2(alpha, super::albedo);
        (color_max.konst(1.0) - color_max * e).max0()
    }

    /// `super::brdf`.
    #[inline(always)]
    pub(crate) fn brdf<R: Real>(alpha: R, wo: V3<R>, wi: V3<R>) -> R {
        let (zero, one) = (alpha.konst(0.0), alpha.konst(1.0));
        let h = (wo + wi).normalize();
        let g = one / (one + wo.z.each2(alpha, super::lambda) + wi.z.each2(alpha, super::lambda));
        let f = alpha.each2(h.z, super::distribution) * g / (alpha.konst(4.0) * wo.z * wi.z);
        R::select(wo.z.le(zero) | wi.z.le(zero), zero, f)
    }
}

/// Cosines of `wo` in the albedo table: (i / (N_MU - 1))², crowded toward grazing, where E
/// changes fastest.
const N_MU: usize = 32;
/// Roughnesses in the albedo table: [`MIN_SHEEN_ALPHA`] to 1 in equal steps.
const N_ALPHA: usize = 24;

/// The table of E, row by alpha.
fn table() -> &'static [[f32; N_MU]; N_ALPHA] {
    static TABLE: OnceLock<Box<[[f32; N_MU]; N_ALPHA]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut t = Box::new([[0.0; N_MU]; N_ALPHA]);
        for (j, row) in t.iter_mut().enumerate() {
            let alpha = table_alpha(j);
            for (i, e) in row.iter_mut().enumerate() {
                // E at a grazing cosine of 0 is the limit from above: 1e-4 stands for it.
                let x = i as f32 / (N_MU - 1) as f32;
                let mu = (x * x).max(1e-4);
                *e = integrate_albedo(alpha, mu) as f32;
            }
        }
        t
    })
}

/// The roughness of row `j` of the table.
fn table_alpha(j: usize) -> f32 {
    MIN_SHEEN_ALPHA + (1.0 - MIN_SHEEN_ALPHA) * j as f32 / (N_ALPHA - 1) as f32
}

/// E(mu) = integral over the hemisphere of brdf(wo, wi) cos(wi) dwi, for wo at cosine `mu`: a
/// midpoint rule in (cos theta_i = s², phi), which crowds the steps toward the horizon where the
/// sheen is strongest, over half the azimuths (the lobe is symmetric about wo's plane).
pub(crate) fn integrate_albedo(alpha: f32, mu: f32) -> f64 {
    const N_S: usize = 96;
    const N_PHI: usize = 48;
    let wo = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let mut sum = 0.0f64;
    for i in 0..N_S {
        let s = (i as f64 + 0.5) / N_S as f64;
        let cos_i = s * s;
        let sin_i = (1.0 - cos_i * cos_i).max(0.0).sqrt();
        let mut ring = 0.0f64;
        for k in 0..N_PHI {
            let phi = std::f64::consts::PI * (k as f64 + 0.5) / N_PHI as f64;
            let wi =
                Vec3::new((sin_i * phi.cos()) as f32, (sin_i * phi.sin()) as f32, cos_i as f32);
            ring += brdf(alpha, wo, wi) as f64 * cos_i;
        }
        // d(cos) = 2 s ds; the ring's azimuths span pi, counted twice.
        sum += ring * (2.0 * std::f64::consts::PI / N_PHI as f64) * (2.0 * s / N_S as f64);
    }
    sum
}

/// The directional albedo E of a white sheen of roughness `alpha` for `wo` at cosine `cos_wo`,
/// interpolated from the table.
#[inline]
pub(crate) fn albedo(cos_wo: f32, alpha: f32) -> f32 {
    let t = table();
    let x = cos_wo.clamp(0.0, 1.0).sqrt() * (N_MU - 1) as f32;
    let y = ((alpha - MIN_SHEEN_ALPHA) / (1.0 - MIN_SHEEN_ALPHA)).clamp(0.0, 1.0)
        * (N_ALPHA - 1) as f32;
    let (i, j) = ((x as usize).min(N_MU - 2), (y as usize).min(N_ALPHA - 2));
    let (fx, fy) = (x - i as f32, y - j as f32);
    let row = |j: usize| t[j][i] + (t[j][i + 1] - t[j][i]) * fx;
    row(j) + (row(j + 1) - row(j)) * fy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_holds_albedos_below_one() {
        let t = table();
        for (j, row) in t.iter().enumerate() {
            for (i, &e) in row.iter().enumerate() {
                assert!((0.0..=1.0).contains(&e), "E[{j}][{i}] = {e} (alpha {})", table_alpha(j));
            }
        }
        // Table points read back as themselves.
        assert_eq!(albedo(1.0, 1.0), t[N_ALPHA - 1][N_MU - 1]);
        // Between points, interpolation stays within 2% (absolute 2e-3) of the integral.
        for alpha in [0.08f32, 0.3, 0.77] {
            for mu in [0.02f32, 0.11, 0.5, 0.93] {
                let exact = integrate_albedo(alpha, mu) as f32;
                let read = albedo(mu, alpha);
                assert!(
                    (read - exact).abs() <= 0.02 * exact + 2e-3,
                    "alpha {alpha} mu {mu}: table {read} vs {exact}"
                );
            }
        }
    }
}
