//! Lambertian reflection: f = albedo / pi, sampled with the cosine-weighted hemisphere.

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};
use crate::render::sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere};

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
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        self.albedo * FRAC_1_PI
    }

    /// Density of `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 {
            return 0.0;
        }
        cosine_hemisphere_pdf(wi.z)
    }

    /// Cosine-weighted sample.
    #[inline]
    pub fn sample(&self, wo: Vec3, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = sample_cosine_hemisphere(u);
        let pdf = cosine_hemisphere_pdf(wi.z);
        if pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample { f: self.albedo * FRAC_1_PI, wi, pdf, lobe: Lobe::Diffuse, eta: 1.0 })
    }
}
