//! BSDFs: the interface (one `match` per method) and one file per model.
//!
//! Directions follow pbrt: `wo` points toward the viewer (where light leaves), `wi` toward where
//! light comes from; both are in the local shading frame (+z = shading normal, flipped by the
//! integrator to `wo`'s side). `wi.z < 0` is light from the far side, which only a transmitting
//! BSDF passes. `eval` returns f(wo, wi) without the cosine; `pdf` is per solid
//! angle; `sample` takes its uniform numbers as arguments.

mod dielectric;
pub(crate) mod diffuse;
pub(crate) mod ggx_albedo;
pub(crate) mod ggx_glass_albedo;
pub(crate) mod layered;
pub(crate) mod metal_rough;
pub(crate) mod sheen;
mod thin_film;

pub use dielectric::{fresnel_dielectric, refract, Dielectric};
pub use diffuse::Diffuse;
pub use layered::{anisotropic, Coat, Layered};
pub use metal_rough::MetalRough;
#[cfg(test)]
pub(crate) use sheen::albedo as sheen_albedo;
pub use sheen::Sheen;
pub use thin_film::ThinFilm;

use glam::{Vec2, Vec3};

/// The GGX alpha (roughness²) from which photon mapping gathers photons at a glossy surface
/// rather than following its reflection (roughness 0.5): on the glossy plates of `veach-mis` a
/// plate of alpha 0.1 that gathered stayed 12% dark at 1,024 passes (the few photons that arrive
/// within its narrow lobe carry its reflection), and followed it agrees with the path tracer.
pub const GATHER_ALPHA: f32 = 0.25;

/// Which lobe a sample came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lobe {
    /// Diffuse reflection.
    Diffuse,
    /// Glossy (microfacet) reflection.
    Glossy,
    /// Transmission to the far side (thin-walled: the direction does not bend).
    Transmission,
    /// Mirror reflection (a delta distribution).
    SpecularReflection,
    /// Refraction into the far side's medium (a delta distribution).
    SpecularTransmission,
    /// Refraction into the far side's medium through rough microfacets.
    GlossyTransmission,
}

impl Lobe {
    /// Whether the lobe is a delta distribution: no light sample can reach it, and multiple
    /// importance sampling gives its sampled direction the whole weight.
    #[inline]
    pub fn is_delta(self) -> bool {
        matches!(self, Lobe::SpecularReflection | Lobe::SpecularTransmission)
    }

    /// Whether the sampled direction crossed into the medium on the far side.
    #[inline]
    pub fn enters_far_side(self) -> bool {
        matches!(self, Lobe::SpecularTransmission | Lobe::GlossyTransmission)
    }
}

/// A sampled direction.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// f(wo, wi), without the cosine.
    pub f: Vec3,
    /// The sampled incident direction (local frame).
    pub wi: Vec3,
    /// Density of `wi` per solid angle (of the whole BSDF, all lobes).
    pub pdf: f32,
    /// The lobe that produced it.
    pub lobe: Lobe,
    /// Index of refraction of the side `wi` leads into over that of `wo`'s side (1 unless the
    /// sample refracted).
    pub eta: f32,
}

/// A BSDF at a shading point.
#[derive(Clone, Copy, Debug)]
pub enum Bsdf {
    /// Lambertian reflection.
    Diffuse(Diffuse),
    /// The glTF metallic-roughness BRDF (Lambert + GGX, Fresnel-mixed).
    MetalRough(MetalRough),
    /// A refractive boundary, smooth or rough.
    Dielectric(Dielectric),
    /// The glTF BRDF with a clear coat, a sheen, anisotropy or a thin film (`layered.rs`).
    Layered(Layered),
}

impl Bsdf {
    /// f(wo, wi).
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match self {
            Bsdf::Diffuse(b) => b.eval(wo, wi),
            Bsdf::MetalRough(b) => b.eval(wo, wi),
            Bsdf::Dielectric(b) => b.eval(wo, wi),
            Bsdf::Layered(b) => b.eval(wo, wi),
        }
    }

    /// Density of `sample` producing `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match self {
            Bsdf::Diffuse(b) => b.pdf(wo, wi),
            Bsdf::MetalRough(b) => b.pdf(wo, wi),
            Bsdf::Dielectric(b) => b.pdf(wo, wi),
            Bsdf::Layered(b) => b.pdf(wo, wi),
        }
    }

    /// Whether `wi` on the far side of the surface (local z < 0) can carry light.
    #[inline]
    pub fn transmits(&self) -> bool {
        match self {
            Bsdf::Diffuse(_) => false,
            Bsdf::MetalRough(b) => b.transmits(),
            Bsdf::Dielectric(_) => true,
            Bsdf::Layered(b) => b.transmits(),
        }
    }

    /// Whether photon mapping takes the light arriving here from photons (a diffuse component,
    /// or a glossy lobe at least as rough as `GATHER_ALPHA`), ending its camera paths here; a
    /// near-mirror or a smooth refraction is followed instead.
    pub fn gathers_photons(&self) -> bool {
        match self {
            Bsdf::Diffuse(_) => true,
            Bsdf::MetalRough(b) => b.has_diffuse() || b.ggx.alpha >= GATHER_ALPHA,
            Bsdf::Dielectric(b) => b.ggx.is_some_and(|g| g.alpha >= GATHER_ALPHA),
            Bsdf::Layered(b) => {
                b.base.has_diffuse()
                    || b.base.ggx.alpha_x.min(b.base.ggx.alpha_y) >= GATHER_ALPHA
                    || b.sheen.is_some()
            }
        }
    }

    /// Whether `sample` uses its lobe-choice number (a single-lobe BSDF does not).
    #[inline]
    pub fn chooses_lobe(&self) -> bool {
        !matches!(self, Bsdf::Diffuse(_))
    }

    /// Samples `wi` for `wo` with lobe choice `u_lobe` and direction numbers `u`.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        match self {
            Bsdf::Diffuse(b) => b.sample(wo, u),
            Bsdf::MetalRough(b) => b.sample(wo, u_lobe, u),
            Bsdf::Dielectric(b) => b.sample(wo, u_lobe, u),
            Bsdf::Layered(b) => b.sample(wo, u_lobe, u),
        }
    }
}
