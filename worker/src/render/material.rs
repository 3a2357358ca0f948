//! Materials at a hit: the glTF material's factors, textures and vertex colours resolved into a
//! `Bsdf`, an emitted radiance, an alpha coverage, a normal-map perturbation (the base's and the
//! clear coat's) and an anisotropy direction.

use common::scene::{AlphaMode, Material, Texture, TextureRef};
use glam::{Vec2, Vec3, Vec4};

use super::{
    bsdf::{anisotropic, Bsdf, Coat, Dielectric, Diffuse, Layered, MetalRough, Sheen, ThinFilm},
    sampling::{Ggx, MIN_ALPHA},
    texture,
};

/// What the material needs to know about the point: texture coordinates, their footprint and
/// the vertex colour.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// TEXCOORD_0 and TEXCOORD_1 (zero when absent).
    pub uvs: [Vec2; 2],
    /// How wide, in each set's coordinates, the texture filter is at the point
    /// (`PreparedScene::footprint`); 0 reads the full-size texture, as emission, coverage and
    /// points found other than by a path always do.
    pub footprint: [f32; 2],
    /// COLOR_0 (white when absent).
    pub color: Vec4,
}

impl SurfacePoint {
    /// A point with no texture coordinates and a white vertex colour.
    pub const PLAIN: SurfacePoint =
        SurfacePoint { uvs: [Vec2::ZERO; 2], footprint: [0.0; 2], color: Vec4::ONE };

    /// The point without a footprint: lookups at the full-size texture.
    pub fn finest(&self) -> SurfacePoint {
        SurfacePoint { footprint: [0.0; 2], ..*self }
    }
}

/// `texture::sample` at the point's texture coordinates and footprint.
#[inline]
fn sample(textures: &[Texture], r: &TextureRef, sp: &SurfacePoint, srgb: bool) -> Vec4 {
    texture::sample(textures, r, sp.uvs, sp.footprint, srgb)
}

/// Every texture the material reads through a footprint (`texture::sample` with the point's
/// footprint; emission reads the full-size texture), and how: `f(texture, decode)`. A lookup
/// added to this file adds its reference here.
pub fn filtered_textures(m: &Material, mut f: impl FnMut(usize, texture::Decode)) {
    use texture::Decode::{self, Alpha, Colour, Linear};
    let mut each = |r: Option<&TextureRef>, d: Decode| {
        if let Some(r) = r {
            f(r.texture, d);
        }
    };
    each(m.base_color_texture.as_ref(), Colour);
    each(m.metallic_roughness_texture.as_ref(), Linear);
    each(m.normal_texture.as_ref().map(|(r, _)| r), Linear);
    each(m.specular_texture.as_ref(), Alpha);
    each(m.specular_color_texture.as_ref(), Colour);
    each(m.glossiness_texture.as_ref(), Alpha);
    each(m.transmission_texture.as_ref(), Linear);
    each(m.diffuse_transmission_texture.as_ref(), Alpha);
    each(m.diffuse_transmission_color_texture.as_ref(), Colour);
    if let Some(c) = &m.clearcoat {
        each(c.texture.as_ref(), Linear);
        each(c.roughness_texture.as_ref(), Linear);
        each(c.normal_texture.as_ref().map(|(r, _)| r), Linear);
    }
    if let Some(s) = &m.sheen {
        each(s.color_texture.as_ref(), Colour);
        each(s.roughness_texture.as_ref(), Alpha);
    }
    if let Some(a) = &m.anisotropy {
        each(a.texture.as_ref(), Linear);
    }
    if let Some(i) = &m.iridescence {
        each(i.texture.as_ref(), Linear);
        each(i.thickness_texture.as_ref(), Linear);
    }
}

/// Base colour and alpha: factor x texture (sRGB) x vertex colour.
#[inline]
pub fn base_color(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Vec4 {
    let mut c = m.base_color * sp.color;
    if let Some(r) = &m.base_color_texture {
        c *= sample(textures, r, sp, true);
    }
    c
}

/// The base colour with each channel within [0, 1]: what the BSDF takes, and what an unlit
/// material (`KHR_materials_unlit`) shows, seen as it is.
#[inline]
pub fn clamped_base_color(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Vec3 {
    base_color(textures, m, sp).truncate().clamp(Vec3::ZERO, Vec3::ONE)
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
/// A material with a clear coat, a sheen, anisotropy or iridescence is `Layered` (its coat normal
/// is +z here: the integrator sets it from [`clearcoat_normal_map`]). `extended` is
/// `m.extended()`, which the caller keeps at hand: without it none of those are looked for.
#[inline]
pub fn bsdf(
    textures: &[Texture],
    m: &Material,
    sp: &SurfacePoint,
    front: bool,
    iors: [f32; 2],
    extended: bool,
) -> Bsdf {
    let base = clamped_base_color(textures, m, sp);
    let (mut metallic, mut roughness) = (m.metallic, m.roughness);
    if let Some(r) = &m.metallic_roughness_texture {
        let t = sample(textures, r, sp, false);
        roughness *= t.y;
        metallic *= t.z;
    }
    if let Some(r) = &m.glossiness_texture {
        // A specular-glossiness material's: roughness 1 - glossiness x the texture's alpha.
        roughness = 1.0 - (1.0 - roughness) * sample(textures, r, sp, false).w;
    }
    if extended && m.refracts() {
        // The relative index is the far side's over the near side's: `iors` are this volume's
        // and that of the medium on its other side (1 for air), as `media::ior` gives them.
        let [ior, other_ior] = iors;
        let eta = if front { ior / other_ior } else { other_ior / ior };
        // Below GGX's smallest alpha the boundary is a mirror: the delta lobes, exactly.
        let alpha = roughness.clamp(0.0, 1.0).powi(2);
        let ggx = (alpha >= MIN_ALPHA).then(|| Ggx::new(alpha));
        return Bsdf::Dielectric(Dielectric { eta, tint: base, ggx });
    }
    let metallic = metallic.clamp(0.0, 1.0);
    let mut transmission = m.transmission;
    if let Some(r) = &m.transmission_texture {
        transmission *= sample(textures, r, sp, false).x;
    }
    let mut diffuse_transmission = m.diffuse_transmission;
    if let Some(r) = &m.diffuse_transmission_texture {
        diffuse_transmission *= sample(textures, r, sp, false).w;
    }
    let layered = extended
        && (m.clearcoat.is_some()
            || m.sheen.is_some()
            || m.anisotropy.is_some()
            || m.iridescence.is_some());
    if !layered
        && metallic == 0.0
        && m.specular <= 0.0
        && transmission <= 0.0
        && diffuse_transmission <= 0.0
    {
        return Bsdf::Diffuse(Diffuse { albedo: base });
    }
    let (mut specular, mut specular_color) = (m.specular, m.specular_color);
    if let Some(r) = &m.specular_texture {
        specular *= sample(textures, r, sp, false).w;
    }
    if let Some(r) = &m.specular_color_texture {
        specular_color *= sample(textures, r, sp, true).truncate();
    }
    let bsdf = MetalRough::new(base, metallic, roughness, m.ior, specular, specular_color);
    let mut bsdf = bsdf.with_transmission(transmission);
    if diffuse_transmission > 0.0 {
        let mut color = m.diffuse_transmission_color;
        if let Some(r) = &m.diffuse_transmission_color_texture {
            color *= sample(textures, r, sp, true).truncate();
        }
        bsdf = bsdf.with_diffuse_transmission(diffuse_transmission, color);
    }
    if layered {
        return Bsdf::Layered(layers(textures, m, sp, bsdf));
    }
    Bsdf::MetalRough(bsdf)
}

/// The base `bsdf` with the material's anisotropy and thin film, under its sheen and clear coat.
fn layers(textures: &[Texture], m: &Material, sp: &SurfacePoint, bsdf: MetalRough) -> Layered {
    let strength = anisotropy(textures, m, sp).map_or(0.0, |(strength, _)| strength);
    let sheen = m.sheen.as_ref().map(|s| {
        let (mut color, mut roughness) = (s.color, s.roughness);
        if let Some(r) = &s.color_texture {
            color *= sample(textures, r, sp, true).truncate();
        }
        if let Some(r) = &s.roughness_texture {
            roughness *= sample(textures, r, sp, false).w;
        }
        Sheen::new(color, roughness)
    });
    let coat = m.clearcoat.as_ref().and_then(|c| {
        let (mut weight, mut roughness) = (c.factor, c.roughness);
        if let Some(r) = &c.texture {
            weight *= sample(textures, r, sp, false).x;
        }
        if let Some(r) = &c.roughness_texture {
            roughness *= sample(textures, r, sp, false).y;
        }
        (weight > 0.0).then(|| Coat {
            weight: weight.min(1.0),
            ggx: Ggx::new(roughness.clamp(0.0, 1.0).powi(2)),
            normal: Vec3::Z,
        })
    });
    let iridescence = m.iridescence.as_ref().and_then(|i| {
        let mut weight = i.factor;
        if let Some(r) = &i.texture {
            weight *= sample(textures, r, sp, false).x;
        }
        let thickness = match &i.thickness_texture {
            Some(r) => {
                let t = sample(textures, r, sp, false).y;
                i.thickness_min + (i.thickness_max - i.thickness_min) * t
            }
            None => i.thickness_max,
        };
        // A film of thickness 0 is no film: the base's own Fresnel.
        (weight > 0.0 && thickness > 0.0).then(|| ThinFilm {
            weight: weight.min(1.0),
            ior: i.ior,
            thickness,
        })
    });
    Layered { base: anisotropic(bsdf, strength), sheen, coat, iridescence }
}

/// `KHR_materials_anisotropy` at the point, if the material has it: the strength in [0, 1] and
/// the direction of the stretched roughness in tangent space (x along the tangent, y along the
/// bitangent), a unit vector: the texture's RG (or +x) rotated counter-clockwise by
/// `anisotropyRotation`.
#[inline]
pub fn anisotropy(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Option<(f32, Vec2)> {
    let a = m.anisotropy.as_ref()?;
    let (mut strength, mut direction) = (a.strength, Vec2::X);
    if let Some(r) = &a.texture {
        let t = sample(textures, r, sp, false);
        // A texel with no direction (RG at the middle) keeps the tangent.
        direction = Vec2::new(2.0 * t.x - 1.0, 2.0 * t.y - 1.0).try_normalize().unwrap_or(Vec2::X);
        strength *= t.z;
    }
    let (sin, cos) = a.rotation.sin_cos();
    let direction =
        Vec2::new(cos * direction.x - sin * direction.y, sin * direction.x + cos * direction.y);
    Some((strength.clamp(0.0, 1.0), direction))
}

/// The clear coat's tangent-space normal from its own normal map (z up), if it has one, and
/// the texture-coordinate set the map reads.
#[inline]
pub fn clearcoat_normal_map(
    textures: &[Texture],
    m: &Material,
    sp: &SurfacePoint,
) -> Option<(Vec3, u32)> {
    let (r, scale) = m.clearcoat.as_ref()?.normal_texture.as_ref()?;
    Some((tangent_normal(sample(textures, r, sp, false), *scale)?, r.tex_coord))
}

/// Emitted radiance (before the front/back face rule): factor x strength x texture (sRGB), read
/// at the full-size texture whatever the point's footprint, so that a light seen by a path and
/// the same light sampled from a point (next-event estimation) emit alike.
#[inline]
pub fn emission(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Vec3 {
    match &m.emissive_texture {
        Some(r) => m.emissive * sample(textures, r, &sp.finest(), true).truncate(),
        None => m.emissive,
    }
}

/// Emitted radiance toward direction `w` from a surface of normal `n` (neither need be unit):
/// under a clear coat (`KHR_materials_clearcoat`, which lies over emission in the layering)
/// darkened by the coat's reflection, emission x (1 - clearcoat x (0.04 + 0.96 (1 - |cos|)^5)),
/// as the extension says; [`emission`] itself otherwise (and no cosine is worked out).
#[inline]
pub fn emission_toward(
    textures: &[Texture],
    m: &Material,
    sp: &SurfacePoint,
    n: Vec3,
    w: Vec3,
) -> Vec3 {
    let e = emission(textures, m, sp);
    let Some(coat) = &m.clearcoat else { return e };
    let cos = n.dot(w) / (n.length() * w.length());
    let mut factor = coat.factor;
    if let Some(r) = &coat.texture {
        factor *= sample(textures, r, &sp.finest(), false).x;
    }
    let fresnel = 0.04 + 0.96 * (1.0 - cos.abs().min(1.0)).powi(5);
    e * (1.0 - factor.clamp(0.0, 1.0) * fresnel)
}

/// The tangent-space normal from the normal map (z up), if the material has one, and the
/// texture-coordinate set the map reads.
#[inline]
pub fn normal_map(textures: &[Texture], m: &Material, sp: &SurfacePoint) -> Option<(Vec3, u32)> {
    let (r, scale) = m.normal_texture.as_ref()?;
    Some((tangent_normal(sample(textures, r, sp, false), *scale)?, r.tex_coord))
}

/// A normal-map texel to a tangent-space normal, x and y scaled by `scale`.
#[inline]
fn tangent_normal(t: Vec4, scale: f32) -> Option<Vec3> {
    let n = Vec3::new((2.0 * t.x - 1.0) * scale, (2.0 * t.y - 1.0) * scale, 2.0 * t.z - 1.0);
    n.try_normalize()
}

#[cfg(test)]
mod tests {
    use common::scene::{Texture, TextureRef, Wrap};

    use super::*;

    /// A one-texel texture of `rgba`, looked up without filtering.
    fn texel(rgba: [u8; 4]) -> Texture {
        Texture {
            width: 1,
            height: 1,
            texels: vec![rgba].into(),
            wrap_s: Wrap::Repeat,
            wrap_t: Wrap::Repeat,
            nearest: true,
            mipmaps: false,
            levels: Vec::new(),
        }
    }

    /// `KHR_materials_specular`'s textures scale its factors: the specular texture's alpha the
    /// factor (linear), the colour texture's RGB the colour (sRGB): a texel of alpha 0 gives the
    /// BSDF of factor 0, one of alpha 255 the factor itself, and a colour texel (255, 0, 255) the
    /// colour with no green, value for value.
    #[test]
    fn specular_textures_scale_the_specular_factors() {
        let textures = [texel([9, 9, 9, 0]), texel([9, 9, 9, 255]), texel([255, 0, 255, 7])];
        let tex = |i| Some(TextureRef { texture: i, tex_coord: 0, transform: None });
        let base = Material {
            metallic: 0.3,
            roughness: 0.4,
            specular: 0.7,
            specular_color: Vec3::new(0.9, 0.8, 0.6),
            ..Material::default()
        };
        let cases = [
            (
                Material { specular_texture: tex(0), ..base.clone() },
                Material { specular: 0.0, ..base.clone() },
            ),
            (Material { specular_texture: tex(1), ..base.clone() }, base.clone()),
            (
                Material { specular_color_texture: tex(2), ..base.clone() },
                Material { specular_color: Vec3::new(0.9, 0.0, 0.6), ..base.clone() },
            ),
        ];
        let dirs = [
            (Vec3::new(0.3, 0.1, 0.95).normalize(), Vec3::new(-0.2, -0.1, 0.97).normalize()),
            (Vec3::new(0.0, 0.6, 0.8), Vec3::new(0.5, -0.5, 0.707).normalize()),
            (Vec3::new(0.9, 0.0, 0.436).normalize(), Vec3::new(-0.8, 0.1, 0.59).normalize()),
        ];
        for (k, (textured, plain)) in cases.iter().enumerate() {
            let a = bsdf(&textures, textured, &SurfacePoint::PLAIN, true, [1.0; 2], false);
            let b = bsdf(&textures, plain, &SurfacePoint::PLAIN, true, [1.0; 2], false);
            for (wo, wi) in dirs {
                assert_eq!(a.eval(wo, wi), b.eval(wo, wi), "case {k}: {wo} {wi}");
                assert_eq!(a.pdf(wo, wi), b.pdf(wo, wi), "case {k}: {wo} {wi}");
            }
            // And the texture matters: the factor without it differs.
            let bare = Material {
                specular_texture: None,
                specular_color_texture: None,
                ..textured.clone()
            };
            let c = bsdf(&textures, &bare, &SurfacePoint::PLAIN, true, [1.0; 2], false);
            if k != 1 {
                assert_ne!(a.eval(dirs[0].0, dirs[0].1), c.eval(dirs[0].0, dirs[0].1), "case {k}");
            }
        }
    }

    /// A specular-glossiness material as the loader converts it (metallic 0, specular 1, ior 0,
    /// the specular colour its `specularFactor`): the reflectance at normal incidence is the
    /// specular colour exactly, and the glossiness texture's alpha a sets the roughness to
    /// 1 - glossiness x a (a = 0: fully rough; a = 1: the factor's).
    #[test]
    fn specular_glossiness_reflects_its_specular_colour_at_normal_incidence() {
        let textures = [texel([255, 255, 255, 0]), texel([255, 255, 255, 255])];
        let tex = |i| Some(TextureRef { texture: i, tex_coord: 0, transform: None });
        let colour = Vec3::new(0.04, 0.5, 0.9);
        let converted = Material {
            base_color: glam::Vec4::new(0.2, 0.3, 0.4, 1.0),
            metallic: 0.0,
            roughness: 1.0 - 0.7,
            specular: 1.0,
            specular_color: colour,
            ior: 0.0,
            ..Material::default()
        };
        let Bsdf::MetalRough(b) =
            bsdf(&textures, &converted, &SurfacePoint::PLAIN, true, [1.0; 2], false)
        else {
            panic!("a metal-rough BSDF");
        };
        assert_eq!(b.schlick_fresnel(1.0).0, colour, "F0 is the specular colour");
        let roughness =
            |m: &Material| match bsdf(&textures, m, &SurfacePoint::PLAIN, true, [1.0; 2], false) {
                Bsdf::MetalRough(b) => b.ggx.alpha,
                other => panic!("{other:?}"),
            };
        let rough = Material { glossiness_texture: tex(0), ..converted.clone() };
        let glossy = Material { glossiness_texture: tex(1), ..converted.clone() };
        assert_eq!(roughness(&rough), 1.0, "alpha 0: glossiness 0");
        assert_eq!(roughness(&glossy), roughness(&converted), "alpha 1: the factor's");
    }
}
