//! Lambertian reflection: f = albedo / pi, sampled with the cosine-weighted hemisphere.

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};

/// Lambertian BRDF.
#[derive(Clone, Copy, Debug)]
pub struct Diffuse {
    /// Reflectance in [0, 1].
    pub albedo: Vec3,
}

impl Diffuse {
    /// f(wo, wi).
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        generic::eval(self.albedo.into(), wo.z, wi.z).into()
    }

    /// Density of `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        generic::pdf(wo.z, wi.z)
    }

    /// Cosine-weighted sample.
    #[inline]
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        let (wi, f, pdf, ok) = generic::sample(self.albedo.into(), wo.z, (u.x, u.y));
        ok.then(|| BsdfSample { f: f.into(), wi: wi.into(), pdf, lobe: Lobe::Diffuse, eta: 1.0 })
    }
}

/// The Lambertian BRDF written once over `Real`: for one path (`f32`, through `Diffuse`) and for
/// a vector of paths (the wavefront). Directions are in the shading frame; only their z
/// (cosines) matter to it.
pub(crate) mod generic {
    use std::f32::consts::FRAC_1_PI;

    use crate::render::{
        lanes::{Real, V3},
        sampling::generic::sample_cosine_hemisphere,
    };

    /// f(wo, wi) of reflectance `albedo`: albedo / pi above the surface on both sides.
    #[inline(always)]
    pub(crate) fn eval<R: Real>(albedo: V3<R>, wo_z: R, wi_z: R) -> V3<R> {
        let zero = wo_z.konst(0.0);
        let above = !(wo_z.le(zero) | wi_z.le(zero));
        V3::select(above, albedo.scale(wo_z.konst(FRAC_1_PI)), V3::new(zero, zero, zero))
    }

    /// The density of `sample`'s direction of cosine `wi_z` (zero when `wo` lies below).
    #[inline(always)]
    pub(crate) fn pdf<R: Real>(wo_z: R, wi_z: R) -> R {
        let zero = wo_z.konst(0.0);
        R::select(wo_z.le(zero), zero, wi_z.max0() * wo_z.konst(FRAC_1_PI))
    }

    /// A cosine-weighted direction from numbers `u`: the direction, f, its density, and whether
    /// it is a sample (`wo` above the surface, a positive density).
    #[inline(always)]
    pub(crate) fn sample<R: Real>(albedo: V3<R>, wo_z: R, u: (R, R)) -> (V3<R>, V3<R>, R, R::Mask) {
        let zero = wo_z.konst(0.0);
        let wi = sample_cosine_hemisphere(u.0, u.1);
        let pdf = wi.z.max0() * wo_z.konst(FRAC_1_PI);
        let ok = !(wo_z.le(zero) | pdf.le(zero));
        (wi, albedo.scale(wo_z.konst(FRAC_1_PI)), pdf, ok)
    }
}
