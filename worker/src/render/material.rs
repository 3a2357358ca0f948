//! Materials at a hit: the glTF material's factors (and, later, textures) resolved into a `Bsdf`.

use common::scene::Material;
use glam::Vec3;

use super::bsdf::{Bsdf, Diffuse, MetalRough};

/// The BSDF of `material`. A material with no metal and no specular layer is pure Lambert, the
/// cheap path (the Cornell box and furnace scenes are all such).
#[inline]
pub fn bsdf(material: &Material) -> Bsdf {
    let base = material.base_color.truncate().clamp(Vec3::ZERO, Vec3::ONE);
    let metallic = material.metallic.clamp(0.0, 1.0);
    if metallic == 0.0 && material.specular <= 0.0 {
        return Bsdf::Diffuse(Diffuse { albedo: base });
    }
    Bsdf::MetalRough(MetalRough::new(
        base,
        metallic,
        material.roughness,
        material.ior,
        material.specular,
        material.specular_color,
    ))
}
