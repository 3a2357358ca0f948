//! What the wavefront renderer reads of a scene it can render, built once when the scene is
//! prepared: the Lambert albedo and emission of each material and the emissive triangles (with
//! the mixture's probabilities where the scene chooses by it).
//! Below `scene` (which keeps the tables) and `wavefront` (which reads them), so that data flows
//! one way: `scene` does not depend on the renderers.

use common::scene::{Material, Texture};
use glam::Vec3;

use super::{
    bsdf::Bsdf,
    light::{Light, LightSampler},
    material::{self, SurfacePoint},
};

/// An emissive triangle as the wavefront reads it.
#[derive(Clone, Copy, Debug)]
pub(super) struct LightRec {
    pub(super) p: [Vec3; 3],
    pub(super) normal: Vec3,
    pub(super) area: f32,
    pub(super) emission: Vec3,
    pub(super) two_sided: bool,
    /// The mixture's probability of choosing it (0 under the tree, whose probability depends on
    /// the point: asked where a path hits the light).
    pub(super) probability: f32,
}

/// What the wavefront renderer needs of a scene it can render, built once per scene.
#[derive(Clone, Debug)]
pub struct Tables {
    /// Lambert albedo per material.
    pub(super) albedo: Vec<Vec3>,
    /// Emitted radiance per material.
    pub(super) emission: Vec<Vec3>,
    /// Every light, indexed like `LightSampler::lights`: the emissive triangles (the others
    /// are sampled by `Light::sample_li`, one lane at a time).
    pub(super) lights: Vec<Option<LightRec>>,
}

impl Tables {
    /// The tables of a scene being prepared, or `None` when it needs something only the
    /// scalar renderer does (`scalar_only`: something moves within the shutter, is
    /// alpha-tested or has vertex colours; or a material is textured, glossy, unlit, or has a
    /// clear coat, a sheen, anisotropy or iridescence).
    pub fn new(
        materials: &[Material],
        textures: &[Texture],
        light_sampler: &LightSampler,
        scalar_only: bool,
    ) -> Option<Tables> {
        let mixture = light_sampler.mixture();
        if scalar_only {
            return None;
        }
        let mut albedo = Vec::with_capacity(materials.len());
        let mut emission = Vec::with_capacity(materials.len());
        for m in materials {
            if m.base_color_texture.is_some()
                || m.metallic_roughness_texture.is_some()
                || m.normal_texture.is_some()
                || m.emissive_texture.is_some()
                || m.transmission_texture.is_some()
                || m.diffuse_transmission_texture.is_some()
                || m.diffuse_transmission_color_texture.is_some()
                || m.unlit
                || m.clearcoat.is_some()
                || m.sheen.is_some()
                || m.anisotropy.is_some()
                || m.iridescence.is_some()
            {
                return None;
            }
            // Without textures or vertex colours every point of the material is this one.
            match material::bsdf(textures, m, &SurfacePoint::PLAIN, true, [1.0; 2], m.extended()) {
                Bsdf::Diffuse(d) => albedo.push(d.albedo),
                Bsdf::MetalRough(_) | Bsdf::Dielectric(_) | Bsdf::Layered(_) => return None,
            }
            emission.push(material::emission(textures, m, &SurfacePoint::PLAIN));
        }
        let mut lights = Vec::with_capacity(light_sampler.lights.len());
        for (i, light) in light_sampler.lights.iter().enumerate() {
            let Light::Triangle(l) = light else {
                lights.push(None);
                continue;
            };
            if l.textured {
                return None;
            }
            lights.push(Some(LightRec {
                p: l.p,
                normal: l.normal,
                area: l.area,
                emission: l.emission,
                two_sided: l.two_sided,
                probability: mixture.map_or(0.0, |m| m.probability(i as u32)),
            }));
        }
        Some(Tables { albedo, emission, lights })
    }
}
