//! The glTF 2.0 metallic-roughness BRDF (spec appendix B) with `KHR_materials_specular` and
//! `KHR_materials_ior`:
//!
//! f = (1 - metallic) * [ (1 - s * max(F_d)) * base / pi + s * F_d * spec ] + metallic * F_m * spec
//!
//! where spec = D G2 / (4 |n.wo| |n.wi|) is GGX with height-correlated Smith masking
//! (alpha = roughness²), F_d the dielectric Schlick Fresnel with f0 = min(((ior-1)/(ior+1))² *
//! specular_color, 1), F_m the conductor Schlick Fresnel with f0 = base, and s = specularFactor.
//! Sampling picks the GGX lobe (visible normals, Heitz 2018) or the cosine lobe with
//! probabilities from their estimated albedos.

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};
use crate::render::{
    geometry::reflect,
    sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere, Ggx},
};

/// The glTF metallic-roughness BRDF at a point.
#[derive(Clone, Copy, Debug)]
pub struct MetalRough {
    /// Base colour (linear).
    pub base: Vec3,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// Microfacet distribution (alpha = roughness²).
    pub ggx: Ggx,
    /// Dielectric reflectance at normal incidence, per channel.
    pub f0_dielectric: Vec3,
    /// `specularFactor`.
    pub specular: f32,
}

#[inline]
fn schlick_weight(cos: f32) -> f32 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

#[inline]
fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

impl MetalRough {
    /// A BRDF from glTF parameters.
    pub fn new(
        base: Vec3,
        metallic: f32,
        roughness: f32,
        ior: f32,
        specular: f32,
        specular_color: Vec3,
    ) -> Self {
        let r = ((ior - 1.0) / (ior + 1.0)).powi(2);
        MetalRough {
            base: base.clamp(Vec3::ZERO, Vec3::ONE),
            metallic: metallic.clamp(0.0, 1.0),
            ggx: Ggx::new(roughness.clamp(0.0, 1.0).powi(2)),
            f0_dielectric: (specular_color * r).min(Vec3::ONE).max(Vec3::ZERO),
            specular: specular.clamp(0.0, 1.0),
        }
    }

    /// Probability of sampling the GGX lobe for `wo`, from the lobes' albedos at normal-ish
    /// incidence. Must be the same in `sample` and `pdf`.
    #[inline]
    fn specular_probability(&self, wo: Vec3) -> f32 {
        let w = schlick_weight(wo.z);
        let f_m = self.base + (Vec3::ONE - self.base) * w;
        let f_d = self.f0_dielectric + (Vec3::ONE - self.f0_dielectric) * w;
        let f_d_max = f_d.max_element();
        let spec = self.metallic * luminance(f_m) + (1.0 - self.metallic) * self.specular * f_d_max;
        let diff = (1.0 - self.metallic) * (1.0 - self.specular * f_d_max) * luminance(self.base);
        if spec + diff <= 0.0 {
            return 0.0;
        }
        spec / (spec + diff)
    }

    /// f(wo, wi).
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return Vec3::ZERO;
        }
        let h = (wo + wi).normalize();
        let w = schlick_weight(wo.dot(h));
        let spec = self.ggx.d(h) * self.ggx.g2(wo, wi) / (4.0 * wo.z * wi.z);
        let f_d = self.f0_dielectric + (Vec3::ONE - self.f0_dielectric) * w;
        let f_m = self.base + (Vec3::ONE - self.base) * w;
        let dielectric = (1.0 - self.specular * f_d.max_element()) * self.base * FRAC_1_PI
            + self.specular * f_d * spec;
        (1.0 - self.metallic) * dielectric + self.metallic * f_m * spec
    }

    /// Density of `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z <= 0.0 {
            return 0.0;
        }
        let p_spec = self.specular_probability(wo);
        let h = (wo + wi).normalize();
        p_spec * self.ggx.reflection_pdf(wo, h) + (1.0 - p_spec) * cosine_hemisphere_pdf(wi.z)
    }

    /// Samples a lobe by `u_lobe`, then a direction from it.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let p_spec = self.specular_probability(wo);
        let (wi, lobe) = if u_lobe < p_spec {
            let h = self.ggx.sample_visible_normal(wo, u);
            (reflect(wo, h), Lobe::Glossy)
        } else {
            (sample_cosine_hemisphere(u), Lobe::Diffuse)
        };
        if wi.z <= 0.0 {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        if !(pdf > 0.0) {
            return None;
        }
        Some(BsdfSample { f: self.eval(wo, wi), wi, pdf, lobe })
    }
}
