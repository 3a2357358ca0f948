//! Warps from uniform numbers to distributions, each next to its pdf.
//!
//! Stateless: every routine takes its uniform numbers as arguments and never a sampler, so that
//! the chi-square tests can drive them with any point set.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::{Vec2, Vec3};

use super::lanes::{Real, V3};

/// Uniform point on the unit disk (Shirley-Chiu concentric mapping: keeps stratification).
#[inline]
pub fn sample_uniform_disk_concentric(u: Vec2) -> Vec2 {
    let (x, y) = generic::sample_uniform_disk_concentric(u.x, u.y);
    Vec2::new(x, y)
}

/// sin x and cos x for |x| <= pi/4: Taylor polynomials through x^9 and x^10, whose truncation
/// error (below 2e-9 and 1.2e-10 there) is far under f32 rounding. Plain multiplications and
/// additions: the same bits on every machine, unlike a math library.
#[inline]
pub fn sin_cos_quarter(x: f32) -> (f32, f32) {
    generic::sin_cos_quarter(x)
}

/// sin 2 pi u and cos 2 pi u for u in [0, 1]: the nearest quarter turn taken off exactly, the
/// rest by [`sin_cos_quarter`]. Within 2 ulp of the true values, and the same bits on every
/// machine and in every lane of a vector.
#[inline]
pub fn sin_cos_2pi(u: f32) -> (f32, f32) {
    generic::sin_cos_2pi(u)
}

/// The warps above written once over `Real`: for one sample (`f32`, through the functions
/// above) and for a vector of them (the wavefront).
pub(crate) mod generic {
    use std::f32::consts::{FRAC_PI_4, PI};

    use super::{Real, V3};

    /// `super::sample_uniform_disk_concentric` of `(ux, uy)`.
    #[inline(always)]
    pub(crate) fn sample_uniform_disk_concentric<R: Real>(ux: R, uy: R) -> (R, R) {
        let (zero, one, two) = (ux.konst(0.0), ux.konst(1.0), ux.konst(2.0));
        let (ox, oy) = (two * ux - one, two * uy - one);
        let at_centre = ox.eq(zero) & oy.eq(zero);
        // The angle is pi/4 times a ratio in [-1, 1] (plus pi/2 on the other two quadrants,
        // which swaps sine and cosine), so a polynomial on [-pi/4, pi/4] serves and no library
        // call is made. The quadrant pair is chosen by selects, not a branch (it is a coin flip
        // per sample).
        let x_major = ox.abs().gt(oy.abs());
        let (num, den) = (R::select(x_major, oy, ox), R::select(x_major, ox, oy));
        let (sin, cos) = sin_cos_quarter(ux.konst(FRAC_PI_4) * (num / den));
        let dx = R::select(at_centre, zero, den * R::select(x_major, cos, sin));
        let dy = R::select(at_centre, zero, den * R::select(x_major, sin, cos));
        (dx, dy)
    }

    /// `super::sample_uniform_triangle` of `(ux, uy)`.
    #[inline(always)]
    pub(crate) fn sample_uniform_triangle<R: Real>(ux: R, uy: R) -> (R, R) {
        let m = ux.min(uy) / ux.konst(2.0);
        (ux - m, uy - m)
    }

    /// `super::sin_cos_quarter`.
    #[inline(always)]
    pub(crate) fn sin_cos_quarter<R: Real>(x: R) -> (R, R) {
        let c = |v: f32| x.konst(v);
        let x2 = x * x;
        let sin = x
            * (c(1.0)
                + x2 * (c(-1.0 / 6.0)
                    + x2 * (c(1.0 / 120.0) + x2 * (c(-1.0 / 5040.0) + x2 * c(1.0 / 362_880.0)))));
        let cos = c(1.0)
            + x2 * (c(-0.5)
                + x2 * (c(1.0 / 24.0)
                    + x2 * (c(-1.0 / 720.0)
                        + x2 * (c(1.0 / 40_320.0) + x2 * c(-1.0 / 3_628_800.0)))));
        (sin, cos)
    }

    /// `super::sample_uniform_hemisphere` of `(ux, uy)` (the math library's sine and cosine,
    /// lane by lane).
    #[inline(always)]
    pub(crate) fn sample_uniform_hemisphere<R: Real>(ux: R, uy: R) -> V3<R> {
        let z = ux;
        let r = (ux.konst(1.0) - z * z).max0().sqrt();
        let phi = ux.konst(2.0 * PI) * uy;
        let (cos, sin) = (phi.each2(phi, |a, _| a.cos()), phi.each2(phi, |a, _| a.sin()));
        V3::new(r * cos, r * sin, z)
    }

    /// `super::sample_cosine_hemisphere` of `(ux, uy)`.
    #[inline(always)]
    pub(crate) fn sample_cosine_hemisphere<R: Real>(ux: R, uy: R) -> V3<R> {
        let (dx, dy) = sample_uniform_disk_concentric(ux, uy);
        let z = (ux.konst(1.0) - (dx * dx + dy * dy)).max0().sqrt();
        V3::new(dx, dy, z)
    }

    /// `super::sin_cos_2pi`.
    #[inline(always)]
    pub(crate) fn sin_cos_2pi<R: Real>(u: R) -> (R, R) {
        let c = |v: f32| u.konst(v);
        // The nearest quarter turn k / 4 (k = 0 to 4) and the rest u - k / 4, which is exact
        // (Sterbenz: u lies within a factor of two of k / 4), in [-1/8, 1/8].
        let (q1, q2, q3, q4) = (u.ge(c(0.125)), u.ge(c(0.375)), u.ge(c(0.625)), u.ge(c(0.875)));
        let k = R::select(
            q4,
            c(1.0),
            R::select(q3, c(0.75), R::select(q2, c(0.5), R::select(q1, c(0.25), c(0.0)))),
        );
        let (sin, cos) = sin_cos_quarter(c(2.0 * PI) * (u - k));
        // Turned by k quarter turns: (sin, cos), (cos, -sin), (-sin, -cos), (-cos, sin).
        let (first, second, third) = (q1 & !q2, q2 & !q3, q3 & !q4);
        let s = R::select(first, cos, R::select(second, -sin, R::select(third, -cos, sin)));
        let co = R::select(first, -sin, R::select(second, -cos, R::select(third, sin, cos)));
        (s, co)
    }

    /// GGX's D(h) for roughness `alpha` (`super::Ggx::d`).
    #[inline(always)]
    pub(crate) fn ggx_d<R: Real>(alpha: R, h: V3<R>) -> R {
        let a2 = alpha * alpha;
        // t = sin² + alpha² cos², with sin² taken from x and y: the textbook form
        // cos² (alpha² - 1) + 1 cancels in f32 near the peak, which made D (and so `eval` and
        // `pdf`) wrong by percents at small alpha (chi-square test, roughness 0.05).
        let t = (h.x * h.x + h.y * h.y) + a2 * h.z * h.z;
        R::select(h.z.le(alpha.konst(0.0)), alpha.konst(0.0), a2 / (alpha.konst(PI) * t * t))
    }

    /// GGX's Smith Lambda(w) for roughness `alpha` (`super::Ggx::lambda`).
    #[inline(always)]
    pub(crate) fn ggx_lambda<R: Real>(alpha: R, w: V3<R>) -> R {
        let c = |v: f32| alpha.konst(v);
        let cos2 = w.z * w.z;
        let sin2 = (c(1.0) - cos2).max0();
        let tan2 = sin2 / cos2;
        let lambda = c(0.5) * (c(-1.0) + (c(1.0) + alpha * alpha * tan2).sqrt());
        R::select(sin2.eq(c(0.0)), c(0.0), lambda)
    }

    /// GGX's height-correlated masking-shadowing G2(wo, wi) (`super::Ggx::g2`).
    #[inline(always)]
    pub(crate) fn ggx_g2<R: Real>(alpha: R, wo: V3<R>, wi: V3<R>) -> R {
        let one = alpha.konst(1.0);
        one / (one + ggx_lambda(alpha, wo) + ggx_lambda(alpha, wi))
    }

    /// The density of the direction reflected about a visible normal `h` of GGX
    /// (`super::Ggx::reflection_pdf`): G1(wo) D(h) / (4 wo.z), 0 for `wo.z <= 0`.
    #[inline(always)]
    pub(crate) fn ggx_reflection_pdf<R: Real>(alpha: R, wo: V3<R>, h: V3<R>) -> R {
        let (zero, one) = (alpha.konst(0.0), alpha.konst(1.0));
        let g1 = one / (one + ggx_lambda(alpha, wo));
        R::select(wo.z.le(zero), zero, g1 * ggx_d(alpha, h) / (alpha.konst(4.0) * wo.z))
    }

    /// Anisotropic GGX's D(h) for roughnesses `ax` along x and `ay` along y (`super::AnisoGgx`).
    #[inline(always)]
    pub(crate) fn aniso_d<R: Real>(ax: R, ay: R, h: V3<R>) -> R {
        let (x, y) = (h.x / ax, h.y / ay);
        let t = x * x + y * y + h.z * h.z;
        let d = ax.konst(1.0) / (ax.konst(PI) * ax * ay * t * t);
        R::select(h.z.le(ax.konst(0.0)), ax.konst(0.0), d)
    }

    /// Anisotropic GGX's Smith Lambda(w) (`super::AnisoGgx::lambda`).
    #[inline(always)]
    pub(crate) fn aniso_lambda<R: Real>(ax: R, ay: R, w: V3<R>) -> R {
        let c = |v: f32| ax.konst(v);
        let (a, b) = (ax * w.x, ay * w.y);
        let num = a * a + b * b;
        let lambda = c(0.5) * (c(-1.0) + (c(1.0) + num / (w.z * w.z)).sqrt());
        R::select(num.eq(c(0.0)), c(0.0), lambda)
    }

    /// Anisotropic GGX's height-correlated masking-shadowing G2(wo, wi).
    #[inline(always)]
    pub(crate) fn aniso_g2<R: Real>(ax: R, ay: R, wo: V3<R>, wi: V3<R>) -> R {
        let one = ax.konst(1.0);
        one / (one + aniso_lambda(ax, ay, wo) + aniso_lambda(ax, ay, wi))
    }

    /// Anisotropic GGX's density of the direction reflected about a visible normal `h`:
    /// G1(wo) D(h) / (4 wo.z), 0 for `wo.z <= 0`.
    #[inline(always)]
    pub(crate) fn aniso_reflection_pdf<R: Real>(ax: R, ay: R, wo: V3<R>, h: V3<R>) -> R {
        let (zero, one) = (ax.konst(0.0), ax.konst(1.0));
        let g1 = one / (one + aniso_lambda(ax, ay, wo));
        R::select(wo.z.le(zero), zero, g1 * aniso_d(ax, ay, h) / (ax.konst(4.0) * wo.z))
    }

    /// A microfacet distribution for every lane, as the generic BSDFs read it: isotropic GGX
    /// ([`Iso`], whose arithmetic is `super::Ggx`'s) or anisotropic ([`Aniso`], `super::AnisoGgx`'s).
    pub(crate) trait Facets<R: Real>: Copy {
        /// D(h).
        fn d(&self, h: V3<R>) -> R;
        /// G2(wo, wi).
        fn g2(&self, wo: V3<R>, wi: V3<R>) -> R;
        /// A visible normal for `wo`.
        fn visible_normal(&self, wo: V3<R>, ux: R, uy: R) -> V3<R>;
        /// The density of `wo` reflected about the visible normal `h`.
        fn reflection_pdf(&self, wo: V3<R>, h: V3<R>) -> R;
        /// The isotropic roughness whose albedo tables stand for this distribution's
        /// (`Microfacet::albedo_alpha`).
        fn albedo_alpha(&self) -> R;
    }

    /// Isotropic GGX of roughness alpha.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Iso<R>(pub(crate) R);

    /// Anisotropic GGX of roughnesses alpha_x and alpha_y.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Aniso<R>(pub(crate) R, pub(crate) R);

    impl<R: Real> Facets<R> for Iso<R> {
        #[inline(always)]
        fn d(&self, h: V3<R>) -> R {
            ggx_d(self.0, h)
        }
        #[inline(always)]
        fn g2(&self, wo: V3<R>, wi: V3<R>) -> R {
            ggx_g2(self.0, wo, wi)
        }
        #[inline(always)]
        fn visible_normal(&self, wo: V3<R>, ux: R, uy: R) -> V3<R> {
            ggx_visible_normal(self.0, self.0, wo, ux, uy)
        }
        #[inline(always)]
        fn reflection_pdf(&self, wo: V3<R>, h: V3<R>) -> R {
            ggx_reflection_pdf(self.0, wo, h)
        }
        #[inline(always)]
        fn albedo_alpha(&self) -> R {
            self.0
        }
    }

    impl<R: Real> Facets<R> for Aniso<R> {
        #[inline(always)]
        fn d(&self, h: V3<R>) -> R {
            aniso_d(self.0, self.1, h)
        }
        #[inline(always)]
        fn g2(&self, wo: V3<R>, wi: V3<R>) -> R {
            aniso_g2(self.0, self.1, wo, wi)
        }
        #[inline(always)]
        fn visible_normal(&self, wo: V3<R>, ux: R, uy: R) -> V3<R> {
            ggx_visible_normal(self.0, self.1, wo, ux, uy)
        }
        #[inline(always)]
        fn reflection_pdf(&self, wo: V3<R>, h: V3<R>) -> R {
            aniso_reflection_pdf(self.0, self.1, wo, h)
        }
        #[inline(always)]
        fn albedo_alpha(&self) -> R {
            self.0.min(self.1)
        }
    }

    /// A visible normal of GGX with roughness `ax` along x and `ay` along y (equal for the
    /// isotropic one) for `wo` (wo.z > 0), Heitz 2018: `wo` stretched to the hemisphere
    /// configuration, a point on the projected half disk, stretched back.
    #[inline(always)]
    pub(crate) fn ggx_visible_normal<R: Real>(ax: R, ay: R, wo: V3<R>, ux: R, uy: R) -> V3<R> {
        let c = |v: f32| ax.konst(v);
        let vh = V3::new(ax * wo.x, ay * wo.y, wo.z).normalize();
        let len2 = vh.x * vh.x + vh.y * vh.y;
        let tilted = len2.gt(c(0.0));
        let t1 = V3::new(-vh.y, vh.x, c(0.0)).div(len2.sqrt());
        let t1 = V3::select(tilted, t1, V3::new(c(1.0), c(0.0), c(0.0)));
        let t2 = vh.cross(t1);
        let r = ux.sqrt();
        let (sin, cos) = sin_cos_2pi(uy);
        let p1 = r * cos;
        let p2 = r * sin;
        let s = c(0.5) * (c(1.0) + vh.z);
        let p2 = (c(1.0) - s) * (c(1.0) - p1 * p1).max0().sqrt() + s * p2;
        let nh = t1.scale(p1) + t2.scale(p2) + vh.scale((c(1.0) - p1 * p1 - p2 * p2).max0().sqrt());
        V3::new(ax * nh.x, ay * nh.y, nh.z.glam_max(c(1e-7))).normalize()
    }
}

/// Density of `sample_uniform_disk_concentric` per unit area.
#[inline]
pub fn uniform_disk_pdf() -> f32 {
    FRAC_1_PI
}

/// Cosine-weighted direction on the hemisphere around +z.
#[inline]
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    generic::sample_cosine_hemisphere(u.x, u.y).into()
}

/// Density of `sample_cosine_hemisphere` per solid angle.
#[inline]
pub fn cosine_hemisphere_pdf(cos_theta: f32) -> f32 {
    cos_theta.max(0.0) * FRAC_1_PI
}

/// Uniform direction on the unit sphere.
#[inline]
pub fn sample_uniform_sphere(u: Vec2) -> Vec3 {
    let z = 1.0 - 2.0 * u.x;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// Density of `sample_uniform_sphere` per solid angle.
#[inline]
pub fn uniform_sphere_pdf() -> f32 {
    1.0 / (4.0 * PI)
}

/// Uniform direction on the hemisphere around +z.
#[inline]
pub fn sample_uniform_hemisphere(u: Vec2) -> Vec3 {
    generic::sample_uniform_hemisphere(u.x, u.y).into()
}

/// Density of `sample_uniform_hemisphere` per solid angle (on the upper hemisphere).
#[inline]
pub fn uniform_hemisphere_pdf() -> f32 {
    1.0 / (2.0 * PI)
}

/// Uniform direction in the cone around +z with half-angle acos(`cos_max`).
#[inline]
pub fn sample_uniform_cone(u: Vec2, cos_max: f32) -> Vec3 {
    let cos_theta = (1.0 - u.x) + u.x * cos_max;
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

/// Density of `sample_uniform_cone` per solid angle (inside the cone).
#[inline]
pub fn uniform_cone_pdf(cos_max: f32) -> f32 {
    1.0 / (2.0 * PI * (1.0 - cos_max))
}

/// Uniform barycentrics (b0, b1) over a triangle (Heitz 2019, low distortion, keeps strata).
#[inline]
pub fn sample_uniform_triangle(u: Vec2) -> (f32, f32) {
    // Of (u.x / 2, u.y - u.x / 2) when u.x < u.y and (u.x - u.y / 2, u.y / 2) otherwise, with
    // no branch (the half is a coin flip): x - x / 2 is exactly x / 2 for zero and every normal
    // x (the inputs are the sampler's multiples of 2^-24 or those stretched by
    // `choose_remapped`, never subnormal), so subtracting half the smaller number from both
    // gives the same bits.
    generic::sample_uniform_triangle(u.x, u.y)
}

/// The Henyey-Greenstein phase function: the density, per solid angle, of scattering by an angle
/// whose cosine is `cos_theta` (between the directions of travel before and after) with mean
/// cosine `g` in (-1, 1): (1 - g²) / (4 pi (1 + g² - 2 g cos_theta)^(3/2)). g > 0 scatters
/// forward, g < 0 back, g = 0 uniformly.
#[inline]
pub fn henyey_greenstein(cos_theta: f32, g: f32) -> f32 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    (1.0 - g * g) / (4.0 * PI * denom * denom.max(0.0).sqrt())
}

/// A direction of travel after scattering, in the frame whose +z is the direction of travel
/// before, distributed by [`henyey_greenstein`] with mean cosine `g`: the cosine inverts the
/// function's CDF, the azimuth is uniform.
#[inline]
pub fn sample_henyey_greenstein(g: f32, u: Vec2) -> Vec3 {
    let cos_theta = if g.abs() < 1e-3 {
        1.0 - 2.0 * u.x
    } else {
        let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x);
        ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
    };
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let phi = 2.0 * PI * u.y;
    Vec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
}

/// GGX (Trowbridge-Reitz) isotropic microfacet distribution in the local frame (+z = normal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ggx {
    /// Roughness alpha (= perceptual roughness²).
    pub alpha: f32,
}

/// Smallest alpha used: below this GGX is numerically a mirror and f32 overflows.
pub const MIN_ALPHA: f32 = 1.0e-3;

impl Ggx {
    /// A distribution with `alpha`, clamped away from a perfect mirror.
    pub fn new(alpha: f32) -> Self {
        Ggx { alpha: alpha.clamp(MIN_ALPHA, 1.0) }
    }

    /// Normal distribution D(h).
    #[inline]
    pub fn d(&self, h: Vec3) -> f32 {
        generic::ggx_d(self.alpha, h.into())
    }

    /// Smith Lambda(w).
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        generic::ggx_lambda(self.alpha, w.into())
    }

    /// Smith masking G1(w).
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking-shadowing G2(wo, wi).
    #[inline]
    pub fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        generic::ggx_g2(self.alpha, wo.into(), wi.into())
    }

    /// Samples a visible normal for direction `wo` (wo.z > 0), Heitz 2018.
    #[inline]
    pub fn sample_visible_normal(&self, wo: Vec3, u: Vec2) -> Vec3 {
        generic::ggx_visible_normal(self.alpha, self.alpha, wo.into(), u.x, u.y).into()
    }

    /// Density of the reflected direction `wi` when `wo` is reflected about a visible normal:
    /// D_wo(h) / (4 wo.h) = G1(wo) D(h) / (4 wo.z).
    #[inline]
    pub fn reflection_pdf(&self, wo: Vec3, h: Vec3) -> f32 {
        generic::ggx_reflection_pdf(self.alpha, wo.into(), h.into())
    }
}

/// A microfacet distribution as the BSDFs use it, so that one BSDF serves the isotropic [`Ggx`]
/// (whose arithmetic the scenes without anisotropy keep bit for bit) and the anisotropic
/// [`AnisoGgx`].
pub trait Microfacet: Copy + std::fmt::Debug {
    /// Normal distribution D(h).
    fn d(&self, h: Vec3) -> f32;
    /// Height-correlated masking-shadowing G2(wo, wi).
    fn g2(&self, wo: Vec3, wi: Vec3) -> f32;
    /// A visible normal for `wo` (wo.z > 0).
    fn sample_visible_normal(&self, wo: Vec3, u: Vec2) -> Vec3;
    /// Density of `wo` reflected about a visible normal, per solid angle of the reflection.
    fn reflection_pdf(&self, wo: Vec3, h: Vec3) -> f32;
    /// The isotropic roughness whose albedo tables (`bsdf::ggx_albedo`) stand for this
    /// distribution's: alpha, or the smoother axis's for an anisotropic one, whose energy
    /// compensation then never adds more than the lobe loses (the geometric mean of the two,
    /// as Cycles takes, adds 0.5% at grazing angles in `anisotropic_conductor_gains_no_energy`).
    fn albedo_alpha(&self) -> f32;
}

impl Microfacet for Ggx {
    #[inline]
    fn d(&self, h: Vec3) -> f32 {
        Ggx::d(self, h)
    }
    #[inline]
    fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        Ggx::g2(self, wo, wi)
    }
    #[inline]
    fn sample_visible_normal(&self, wo: Vec3, u: Vec2) -> Vec3 {
        Ggx::sample_visible_normal(self, wo, u)
    }
    #[inline]
    fn reflection_pdf(&self, wo: Vec3, h: Vec3) -> f32 {
        Ggx::reflection_pdf(self, wo, h)
    }
    #[inline]
    fn albedo_alpha(&self) -> f32 {
        self.alpha
    }
}

/// Anisotropic GGX in the local frame (+z = normal): roughness `alpha_x` along +x and `alpha_y`
/// along +y,
/// D(h) = 1 / (pi ax ay ((hx / ax)² + (hy / ay)² + hz²)²), with the anisotropic Smith
/// Lambda(w) = (sqrt(1 + (ax² wx² + ay² wy²) / wz²) - 1) / 2 and visible normals sampled by
/// stretching `wo` by (ax, ay, 1) to the hemisphere configuration (Heitz 2018).
#[derive(Clone, Copy, Debug)]
pub struct AnisoGgx {
    /// Roughness along +x.
    pub alpha_x: f32,
    /// Roughness along +y.
    pub alpha_y: f32,
}

impl AnisoGgx {
    /// A distribution with the two alphas, each clamped away from a perfect mirror.
    pub fn new(alpha_x: f32, alpha_y: f32) -> Self {
        AnisoGgx { alpha_x: alpha_x.clamp(MIN_ALPHA, 1.0), alpha_y: alpha_y.clamp(MIN_ALPHA, 1.0) }
    }

    /// Smith Lambda(w).
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        generic::aniso_lambda(self.alpha_x, self.alpha_y, w.into())
    }

    /// Smith masking G1(w).
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }
}

impl Microfacet for AnisoGgx {
    #[inline]
    fn d(&self, h: Vec3) -> f32 {
        generic::aniso_d(self.alpha_x, self.alpha_y, h.into())
    }

    #[inline]
    fn g2(&self, wo: Vec3, wi: Vec3) -> f32 {
        generic::aniso_g2(self.alpha_x, self.alpha_y, wo.into(), wi.into())
    }

    #[inline]
    fn sample_visible_normal(&self, wo: Vec3, u: Vec2) -> Vec3 {
        generic::ggx_visible_normal(self.alpha_x, self.alpha_y, wo.into(), u.x, u.y).into()
    }

    #[inline]
    fn reflection_pdf(&self, wo: Vec3, h: Vec3) -> f32 {
        generic::aniso_reflection_pdf(self.alpha_x, self.alpha_y, wo.into(), h.into())
    }
    #[inline]
    fn albedo_alpha(&self) -> f32 {
        self.alpha_x.min(self.alpha_y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_2pi_is_within_two_ulp_over_the_whole_turn() {
        // Every quarter-turn boundary and the points around it, and a fine sweep: the error
        // against f64 stays within 2.4e-7 (two ulp of 1) and each quadrant's signs are right.
        let mut us: Vec<f32> = (0..=100_000).map(|i| i as f32 / 100_000.0).collect();
        for k in [0.125f32, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0] {
            us.extend([k, f32::from_bits(k.to_bits() - 1), f32::from_bits(k.to_bits() + 1)]);
        }
        us.push(1.0 - f32::EPSILON / 2.0);
        for u in us.into_iter().filter(|u| (0.0..=1.0).contains(u)) {
            let (sin, cos) = sin_cos_2pi(u);
            let phi = 2.0 * std::f64::consts::PI * u as f64;
            let (es, ec) = (sin as f64 - phi.sin(), cos as f64 - phi.cos());
            assert!(es.abs() < 2.4e-7 && ec.abs() < 2.4e-7, "u {u}: {sin} {cos} ({es:e}, {ec:e})");
        }
        assert_eq!(sin_cos_2pi(0.0), (0.0, 1.0));
        assert_eq!(sin_cos_2pi(0.25).0, 1.0);
        assert_eq!(sin_cos_2pi(0.5).1, -1.0);
        assert_eq!(sin_cos_2pi(0.75).0, -1.0);
    }

    #[test]
    fn ggx_d_is_normalised_over_projected_area() {
        // The integral of D(h) cos(theta_h) over the hemisphere is 1.
        for alpha in [0.05f32, 0.3, 1.0] {
            let g = Ggx::new(alpha);
            let n = 2000;
            let mut sum = 0.0f64;
            for i in 0..n {
                let cos_t = (i as f64 + 0.5) / n as f64;
                let h = Vec3::new((1.0 - cos_t * cos_t).sqrt() as f32, 0.0, cos_t as f32);
                sum += g.d(h) as f64 * cos_t * 2.0 * std::f64::consts::PI / n as f64;
            }
            assert!((sum - 1.0).abs() < 2e-2, "alpha {alpha}: {sum}");
        }
    }

    #[test]
    fn aniso_ggx_d_is_normalised_and_isotropic_matches_ggx() {
        // The integral of D(h) cos(theta_h) over the hemisphere is 1 (midpoint rule in
        // (cos theta, phi)); with equal alphas D and G2 are GGX's.
        for (ax, ay) in [(0.3f32, 0.3f32), (0.1, 0.6), (1.0, 0.05)] {
            let g = AnisoGgx::new(ax, ay);
            let (n_t, n_p) = (4000, 256);
            let mut sum = 0.0f64;
            for i in 0..n_t {
                // cos theta = 1 - s², which crowds the steps toward the peak at the pole.
                let s = (i as f64 + 0.5) / n_t as f64;
                let cos_t = 1.0 - s * s;
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                for j in 0..n_p {
                    let phi = 2.0 * std::f64::consts::PI * (j as f64 + 0.5) / n_p as f64;
                    let h = Vec3::new(
                        (sin_t * phi.cos()) as f32,
                        (sin_t * phi.sin()) as f32,
                        cos_t as f32,
                    );
                    sum +=
                        g.d(h) as f64 * cos_t * 2.0 * s / n_t as f64 * 2.0 * std::f64::consts::PI
                            / n_p as f64;
                }
            }
            assert!((sum - 1.0).abs() < 2e-2, "alphas {ax} {ay}: {sum}");
        }
        let (iso, aniso) = (Ggx::new(0.4), AnisoGgx::new(0.4, 0.4));
        let (wo, wi) =
            (Vec3::new(0.3, -0.2, 0.93).normalize(), Vec3::new(-0.5, 0.1, 0.86).normalize());
        let h = (wo + wi).normalize();
        assert!((iso.d(h) - Microfacet::d(&aniso, h)).abs() < 1e-5 * iso.d(h));
        assert!((iso.g2(wo, wi) - Microfacet::g2(&aniso, wo, wi)).abs() < 1e-6);
    }

    #[test]
    fn triangle_barycentrics_stay_inside() {
        for i in 0..100 {
            for j in 0..100 {
                let (b0, b1) =
                    sample_uniform_triangle(Vec2::new(i as f32 / 100.0, j as f32 / 100.0));
                assert!(b0 >= 0.0 && b1 >= 0.0 && b0 + b1 <= 1.0 + 1e-6);
            }
        }
    }
}
