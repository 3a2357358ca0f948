//! Materials at a hit: the glTF material's factors, textures and vertex colours resolved into a
//! `Bsdf`, an emitted radiance, an alpha coverage and a normal-map perturbation.

use common::scene::{AlphaMode, Material, Texture};
use glam::{Vec2, Vec3, Vec4};

use super::{
    bsdf::{Bsdf, Dielectric, Diffuse, MetalRough},
    sampling::{Ggx, MIN_ALPHA},
    texture,
};

/// What the material needs to know about the point: texture coordinates and vertex colour.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// TEXCOORD_0 and TEXCOORD_1 (zero when absent).
    pub uvs: [Vec2; 2],
    /// COLOR_0 (white when absent).
    pub color: Vec4,
}

impl SurfacePoint {
    /// A point with no texture coordinates and a white vertex colour.
    pub const PLAIN: SurfacePoint = SurfacePoint { uvs: [Vec2::ZERO; 2], color: Vec4::ONE };
}

/// Base colour and alpha: factor x texture (sRGB) x vertex colour.
#[inline]
pub fn base_color(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Vec4 {
    let mut c = m.base_color * sp.color;
    if let Some(r) = &m.base_color_texture {
        c *= texture::sample(textures, r, sp.uvs, true);
    }
    c
}

/// The probability that the surface is there at the point: 1 for OPAQUE, 0 or 1 for MASK (alpha
/// against the cutoff), alpha for BLEND (alpha as coverage: the surface is composited over what
/// lies behind it, as glTF's "over" operator says, in expectation).
#[inline]
pub fn coverage(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> f32 {
    match m.alpha_mode {
        AlphaMode::Opaque => 1.0,
        AlphaMode::Mask { cutoff } => {
            if base_color(textures, m, sp).w < cutoff {
                0.0
            } else {
                1.0
            }
        }
        AlphaMode::Blend => base_color(textures, m, sp).w.clamp(0.0, 1.0),
    }
}

/// The BSDF at the point, seen from the front face (`front`, the side the winding makes
/// counter-clockwise) or from the back. A material with no metal, no specular layer and no
/// transmission is pure Lambert, the cheap path (the Cornell box and furnace scenes are all
/// such). A refractive volume's boundary is a dielectric whose inside is the back face's side.
#[inline]
pub fn bsdf(textures: &[Texture], m: &Material, sp: &SurfacePoint, front: bool) -> Bsdf {
    let base = base_color(textures, m, sp).truncate().clamp(Vec3::ZERO, Vec3::ONE);
    let (mut metallic, mut roughness) = (m.metallic, m.roughness);
    if let Some(r) = &m.metallic_roughness_texture {
        let t = texture::sample(textures, r, sp.uvs, false);
        roughness *= t.y;
        metallic *= t.z;
    }
    if m.refracts() {
        // ior 0 (the extension's "no refraction") is 1: an index-matched boundary.
        let ior = if m.ior > 0.0 { m.ior } else { 1.0 };
        let eta = if front { ior } else { 1.0 / ior };
        // Below GGX's smallest alpha the boundary is a mirror: the delta lobes, exactly.
        let alpha = roughness.clamp(0.0, 1.0).powi(2);
        let ggx = (alpha >= MIN_ALPHA).then(|| Ggx::new(alpha));
        return Bsdf::Dielectric(Dielectric { eta, tint: base, ggx });
    }
    let metallic = metallic.clamp(0.0, 1.0);
    let mut transmission = m.transmission;
    if let Some(r) = &m.transmission_texture {
        transmission *= texture::sample(textures, r, sp.uvs, false).x;
    }
    let mut diffuse_transmission = m.diffuse_transmission;
    if let Some(r) = &m.diffuse_transmission_texture {
        diffuse_transmission *= texture::sample(textures, r, sp.uvs, false).w;
    }
    if metallic == 0.0 && m.specular <= 0.0 && transmission <= 0.0 && diffuse_transmission <= 0.0 {
        return Bsdf::Diffuse(Diffuse { albedo: base });
    }
    let bsdf = MetalRough::new(base, metallic, roughness, m.ior, m.specular, m.specular_color);
    let bsdf = bsdf.with_transmission(transmission);
    if diffuse_transmission <= 0.0 {
        return Bsdf::MetalRough(bsdf);
    }
    let mut color = m.diffuse_transmission_color;
    if let Some(r) = &m.diffuse_transmission_color_texture {
        color *= texture::sample(textures, r, sp.uvs, true).truncate();
    }
    Bsdf::MetalRough(bsdf.with_diffuse_transmission(diffuse_transmission, color))
}

/// Emitted radiance (before the front/back face rule): factor x strength x texture (sRGB).
#[inline]
pub fn emission(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Vec3 {
    match &m.emissive_texture {
        Some(r) => m.emissive * texture::sample(textures, r, sp.uvs, true).truncate(),
        None => m.emissive,
    }
}

/// The tangent-space normal from the normal map (z up), if the material has one.
#[inline]
pub fn normal_map(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Option<Vec3> {
    let (r, scale) = m.normal_texture.as_ref()?;
    let t = texture::sample(textures, r, sp.uvs, false);
    let n = Vec3::new((2.0 * t.x - 1.0) * scale, (2.0 * t.y - 1.0) * scale, 2.0 * t.z - 1.0);
    n.try_normalize()
}
