//! What the wavefront renderer reads of a scene it can render, built once when the scene is
//! prepared: the BSDF (Lambert, or the glTF metal-rough BSDF) and emission of each material and
//! the emissive triangles (with the mixture's probabilities where the scene chooses by it).
//! Below `scene` (which keeps the tables) and `wavefront` (which reads them), so that data flows
//! one way: `scene` does not depend on the renderers.

use common::scene::{Material, Texture};
use glam::Vec3;

use super::{
    bsdf::{Bsdf, MetalRough},
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
    /// Lambert albedo per material (zero for a glossy one).
    pub(super) albedo: Vec<Vec3>,
    /// The metal-rough BSDF per material, for the glossy ones.
    pub(super) glossy: Vec<Option<MetalRough>>,
    /// Per material, whether it has textures: its BSDF, shading frame (normal map) and emission
    /// are then those of each point, found one lane at a time by the scalar renderer's calls.
    pub(super) textured: Vec<bool>,
    /// Emitted radiance per material.
    pub(super) emission: Vec<Vec3>,
    /// Every light, indexed like `LightSampler::lights`: the emissive triangles (the others
    /// are sampled by `Light::sample_li`, one lane at a time).
    pub(super) lights: Vec<Option<LightRec>>,
}

impl Tables {
    /// The tables of a scene being prepared, or why the wavefront does not take it (the scalar
    /// renderer then renders it, with the same estimator): `scalar_only` names what the scene
    /// as a whole needs of the scalar renderer (something moving within the shutter, an alpha
    /// test), and every material must be one the wavefront takes (`wavefront_bsdf`, an
    /// allow-list). `per_point`: the scene has vertex colours, so every material is shaded per
    /// point, as textured ones are.
    pub fn new(
        materials: &[Material],
        textures: &[Texture],
        light_sampler: &LightSampler,
        scalar_only: Option<&str>,
        per_point: bool,
    ) -> Result<Tables, String> {
        let mixture = light_sampler.mixture();
        if let Some(why) = scalar_only {
            return Err(why.to_string());
        }
        let mut albedo = Vec::with_capacity(materials.len());
        let mut glossy = Vec::with_capacity(materials.len());
        let mut textured = Vec::with_capacity(materials.len());
        let mut emission = Vec::with_capacity(materials.len());
        for m in materials {
            let bsdf = wavefront_bsdf(textures, m)
                .map_err(|why| format!("material '{}' has {why}", m.name))?;
            let bsdf = match bsdf {
                Shade::Lambert(_) | Shade::Glossy(_) if per_point => Shade::Textured,
                other => other,
            };
            textured.push(bsdf == Shade::Textured);
            match bsdf {
                Shade::Lambert(a) => {
                    albedo.push(a);
                    glossy.push(None);
                }
                Shade::Glossy(b) => {
                    albedo.push(Vec3::ZERO);
                    glossy.push(Some(b));
                }
                Shade::Textured => {
                    albedo.push(Vec3::ZERO);
                    glossy.push(None);
                }
            }
            // Without textures or vertex colours every point of the material is this one.
            emission.push(material::emission(textures, m, &SurfacePoint::PLAIN));
        }
        let mut lights = Vec::with_capacity(light_sampler.lights.len());
        for (i, light) in light_sampler.lights.iter().enumerate() {
            let Light::Triangle(l) = light else {
                lights.push(None);
                continue;
            };
            if l.textured {
                // Sampled by `Light::sample_li`, its radiance by `shared::light_radiance`.
                lights.push(None);
                continue;
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
        Ok(Tables { albedo, glossy, textured, emission, lights })
    }
}

/// The BSDF of a material as the wavefront shades it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shade {
    /// Lambertian, of this albedo.
    Lambert(Vec3),
    /// The glTF metal-rough BSDF, reflecting only.
    Glossy(MetalRough),
    /// Textured: Lambertian or metal-rough (reflecting only) at each point, as its textures
    /// say.
    Textured,
}

/// The BSDF of a material the wavefront takes, or what it has that the wavefront does not. An
/// allow-list: every field of `Material` is named here (a field added to it does not compile
/// until it is decided), the textures and extensions the wavefront does not read send the scene
/// to the scalar renderer, and the factors must make the glTF BSDF a Lambertian one or a
/// metal-rough one that does not transmit.
fn wavefront_bsdf(textures: &[Texture], m: &Material) -> Result<Shade, &'static str> {
    let Material {
        // What the wavefront reads, through the BSDF and the emission below.
        name: _,
        base_color: _,
        emissive: _,
        double_sided: _,
        // What decides that the BSDF is Lambertian (checked below).
        metallic: _,
        roughness: _,
        specular: _,
        specular_color: _,
        ior: _,
        transmission: _,
        diffuse_transmission: _,
        diffuse_transmission_color: _,
        dispersion: _,
        // Alpha tests send the whole scene to the scalar renderer (`scalar_only`).
        alpha_mode: _,
        base_color_texture,
        metallic_roughness_texture,
        normal_texture,
        emissive_texture,
        transmission_texture,
        diffuse_transmission_texture,
        diffuse_transmission_color_texture,
        volume,
        clearcoat,
        sheen,
        anisotropy,
        iridescence,
        unlit,
    } = m;
    let textured = base_color_texture.is_some()
        || metallic_roughness_texture.is_some()
        || normal_texture.is_some()
        || emissive_texture.is_some()
        || transmission_texture.is_some()
        || diffuse_transmission_texture.is_some()
        || diffuse_transmission_color_texture.is_some();
    if volume.is_some() && m.bounds_medium() {
        return Err("a volume");
    }
    if clearcoat.is_some() || sheen.is_some() || anisotropy.is_some() || iridescence.is_some() {
        return Err("a layer (clear coat, sheen, anisotropy or iridescence)");
    }
    if *unlit {
        return Err("KHR_materials_unlit");
    }
    if textured {
        // What textures do not change: whether the surface is a refractive boundary, and
        // whether light passes through it (only the factors can make it; textures scale them).
        if m.extended() && m.refracts() {
            return Err("a refractive boundary");
        }
        if m.transmission > 0.0 || m.diffuse_transmission > 0.0 {
            return Err("thin-walled transmission");
        }
        return Ok(Shade::Textured);
    }
    match material::bsdf(textures, m, &SurfacePoint::PLAIN, true, [1.0; 2], m.extended()) {
        Bsdf::Diffuse(d) => Ok(Shade::Lambert(d.albedo)),
        Bsdf::MetalRough(b) if b.transmits() => Err("thin-walled transmission"),
        Bsdf::MetalRough(b) => Ok(Shade::Glossy(b)),
        Bsdf::Layered(_) => Err("a layer (clear coat, sheen, anisotropy or iridescence)"),
        Bsdf::Dielectric(_) => Err("a refractive boundary"),
    }
}

#[cfg(test)]
mod tests {
    use common::scene::{Material, TextureRef};

    use super::*;

    fn lambert() -> Material {
        Material { metallic: 0.0, specular: 0.0, ..Material::default() }
    }

    /// Lambertian and reflecting metal-rough materials pass, textured or not (a textured one is
    /// shaded per point); layers, transmission and unlit send the scene to the scalar renderer
    /// (with the reason).
    #[test]
    fn the_wavefront_takes_only_what_it_renders() {
        assert!(matches!(wavefront_bsdf(&[], &lambert()), Ok(Shade::Lambert(_))));
        let texture = Some(TextureRef { texture: 0, tex_coord: 0, transform: None });
        let textured = [
            Material { base_color_texture: texture, ..lambert() },
            Material { metallic_roughness_texture: texture, ..lambert() },
            Material { normal_texture: texture.map(|t| (t, 1.0)), ..lambert() },
            Material { emissive_texture: texture, ..lambert() },
            Material { transmission_texture: texture, ..lambert() },
            Material { diffuse_transmission_texture: texture, ..lambert() },
            Material { diffuse_transmission_color_texture: texture, ..lambert() },
        ];
        for m in &textured[..4] {
            assert_eq!(wavefront_bsdf(&[], m), Ok(Shade::Textured), "{m:?}");
        }
        // A texture on a transmission factor of zero changes nothing; on a positive one, the
        // scene takes the scalar renderer.
        for m in &textured[4..] {
            assert_eq!(wavefront_bsdf(&[], m), Ok(Shade::Textured), "{m:?}");
            let thin = Material { transmission: 0.5, diffuse_transmission: 0.5, ..m.clone() };
            assert_eq!(wavefront_bsdf(&[], &thin), Err("thin-walled transmission"), "{m:?}");
        }
        assert!(matches!(wavefront_bsdf(&[], &Material::default()), Ok(Shade::Glossy(_))));
        // A full metal passes no light through, whatever its transmission factor.
        let metal = Material { transmission: 0.5, ..Material::default() };
        assert!(matches!(wavefront_bsdf(&[], &metal), Ok(Shade::Glossy(_))));
        let unlit = Material { unlit: true, ..lambert() };
        assert_eq!(wavefront_bsdf(&[], &unlit), Err("KHR_materials_unlit"));
        let thin = Material { transmission: 0.5, ..lambert() };
        assert_eq!(wavefront_bsdf(&[], &thin), Err("thin-walled transmission"));
        let m = Material { name: "thin".into(), diffuse_transmission: 0.3, ..lambert() };
        let why =
            Tables::new(&[lambert(), m], &[], &LightSampler::default(), None, false).unwrap_err();
        assert_eq!(why, "material 'thin' has thin-walled transmission");
        let why =
            Tables::new(&[lambert()], &[], &LightSampler::default(), Some("a moving light"), false);
        assert_eq!(why.unwrap_err(), "a moving light");
        let colours = Tables::new(&[lambert()], &[], &LightSampler::default(), None, true).unwrap();
        assert_eq!(colours.textured, [true], "vertex colours: shaded per point");
    }
}
