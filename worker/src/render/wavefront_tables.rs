//! What the wavefront renderer reads of a scene it can render, built once when the scene is
//! prepared: the BSDF (Lambert, the glTF metal-rough BSDF, or per point for a textured or
//! layered one, or at a volume's boundary) and emission of each material, whether paths track
//! the volumes they are inside, and the emissive triangles (with
//! the mixture's probabilities where the scene chooses by it).
//! Below `scene` (which keeps the tables) and `wavefront` (which reads them), so that data flows
//! one way: `scene` does not depend on the renderers.

use common::scene::{AlphaMode, Material, Texture};
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
    /// Per material, whether it has textures or layers: its BSDF, shading frame (normal map,
    /// anisotropy) and emission are then those of each point, found one lane at a time by the
    /// scalar renderer's calls.
    pub(super) textured: Vec<bool>,
    /// Emitted radiance per material.
    pub(super) emission: Vec<Vec3>,
    /// Whether a material bounds a medium (a refractive or absorbing volume): each path then
    /// tracks the volumes it is inside, as `path::li` does (`media::MediumStack`); a scene
    /// without volumes does none of it.
    pub(super) media: bool,
    /// Every light, indexed like `LightSampler::lights`: the emissive triangles (the others
    /// are sampled by `Light::sample_li`, one lane at a time).
    pub(super) lights: Vec<Option<LightRec>>,
}

impl Tables {
    /// The tables of a scene being prepared, or why the wavefront does not take it (the scalar
    /// renderer then renders it, with the same estimator): `scalar_only` names what the scene
    /// as a whole needs of the scalar renderer (something moving within the shutter,
    /// dispersion, scattering media); every material is shaded (`wavefront_bsdf`). `per_point`: the scene has vertex colours, so every material is shaded per
    /// point, as textured ones are. `alpha_tested`: the scene has cut-outs, so an emitter whose
    /// material is not opaque (`material_of` a triangle) is sampled with its coverage
    /// (`shared::light_radiance`) and its emission found where a path hits it, one lane at a
    /// time, as a textured emitter's is.
    pub fn new(
        materials: &[Material],
        textures: &[Texture],
        light_sampler: &LightSampler,
        scalar_only: Option<&str>,
        per_point: bool,
        (alpha_tested, material_of): (bool, &dyn Fn(u32) -> usize),
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
            let bsdf = wavefront_bsdf(textures, m);
            let bsdf = match bsdf {
                Shade::Lambert(_) | Shade::Glossy(_) if per_point => Shade::Textured,
                other => other,
            };
            textured.push(matches!(bsdf, Shade::Textured | Shade::Layered | Shade::Boundary));
            match bsdf {
                Shade::Lambert(a) => {
                    albedo.push(a);
                    glossy.push(None);
                }
                Shade::Glossy(b) => {
                    albedo.push(Vec3::ZERO);
                    glossy.push(Some(b));
                }
                Shade::Textured | Shade::Layered | Shade::Boundary | Shade::Unlit => {
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
            let material = material_of(l.prim);
            let partly_there = alpha_tested && materials[material].alpha_mode != AlphaMode::Opaque;
            if partly_there {
                textured[material] = true;
            }
            if l.textured || partly_there {
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
        let media = materials.iter().any(|m| m.volume.is_some() && m.bounds_medium());
        Ok(Tables { albedo, glossy, textured, emission, media, lights })
    }
}

/// The BSDF of a material as the wavefront shades it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Shade {
    /// Lambertian, of this albedo.
    Lambert(Vec3),
    /// The glTF metal-rough BSDF, thin-walled transmission included.
    Glossy(MetalRough),
    /// Textured: Lambertian or metal-rough (thin-walled) at each point, as its textures say.
    Textured,
    /// The layered glTF BSDF (clear coat, sheen, anisotropy, iridescence), textured or not:
    /// found at each point, as a textured material's BSDF is.
    Layered,
    /// The boundary of a volume (refractive glass, or a medium entered by diffuse
    /// transmission): found at each point with the indices of the media on its two sides, a
    /// dielectric evaluated and sampled one lane at a time by the scalar `Bsdf`.
    Boundary,
    /// `KHR_materials_unlit`: its base colour, seen as it is, where a path meets it (one lane
    /// at a time); no path goes on from it.
    Unlit,
}

/// How the wavefront shades a material. Every field of `Material` is named here, so that a
/// field added to it does not compile until the wavefront's handling of it is decided: what
/// varies over the surface (textures) is shaded per point, and the factors decide whether the
/// glTF BSDF is a Lambertian one or a metal-rough one (thin-walled where it transmits).
fn wavefront_bsdf(textures: &[Texture], m: &Material) -> Shade {
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
        specular_texture,
        specular_color_texture,
        glossiness_texture,
        ior: _,
        transmission: _,
        diffuse_transmission: _,
        diffuse_transmission_color: _,
        dispersion: _,
        // Alpha tests change what rays hit (`PreparedScene::intersect`) and what a light
        // sample brings (`shared::light_radiance`), not the BSDF.
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
        || diffuse_transmission_color_texture.is_some()
        || specular_texture.is_some()
        || specular_color_texture.is_some()
        || glossiness_texture.is_some();
    if *unlit {
        return Shade::Unlit;
    }
    // What textures do not change: whether the surface bounds a medium (only the factors can
    // make it; textures scale them).
    if volume.is_some() && m.bounds_medium() {
        return Shade::Boundary;
    }
    if clearcoat.is_some() || sheen.is_some() || anisotropy.is_some() || iridescence.is_some() {
        // The layered BSDF, found at each point as a textured material's is.
        return Shade::Layered;
    }
    if textured {
        return Shade::Textured;
    }
    match material::bsdf(textures, m, &SurfacePoint::PLAIN, true, [1.0; 2], m.extended()) {
        Bsdf::Diffuse(d) => Shade::Lambert(d.albedo),
        Bsdf::MetalRough(b) => Shade::Glossy(b),
        // A layered or refracting BSDF comes only from the extensions checked above.
        Bsdf::Layered(_) => Shade::Layered,
        Bsdf::Dielectric(_) => Shade::Boundary,
    }
}

#[cfg(test)]
mod tests {
    use common::scene::{Material, TextureRef};

    use super::*;

    fn lambert() -> Material {
        Material { metallic: 0.0, specular: 0.0, ..Material::default() }
    }

    /// Lambertian, reflecting metal-rough and layered materials pass, textured or not (a textured
    /// or layered one is shaded per point), and so do the boundaries of volumes (per point, the
    /// paths tracking their media), and unlit; what the whole scene needs of the scalar renderer
    /// keeps the wavefront off.
    #[test]
    fn the_wavefront_takes_every_material() {
        assert!(matches!(wavefront_bsdf(&[], &lambert()), Shade::Lambert(_)));
        let texture = Some(TextureRef { texture: 0, tex_coord: 0, transform: None });
        let textured = [
            Material { base_color_texture: texture, ..lambert() },
            Material { metallic_roughness_texture: texture, ..lambert() },
            Material { normal_texture: texture.map(|t| (t, 1.0)), ..lambert() },
            Material { emissive_texture: texture, ..lambert() },
            Material { specular_texture: texture, ..lambert() },
            Material { specular_color_texture: texture, ..lambert() },
            Material { transmission_texture: texture, ..lambert() },
            Material { diffuse_transmission_texture: texture, ..lambert() },
            Material { diffuse_transmission_color_texture: texture, ..lambert() },
        ];
        for m in &textured[..6] {
            assert_eq!(wavefront_bsdf(&[], m), Shade::Textured, "{m:?}");
        }
        // Textured transmission factors (thin-walled transmission) are shaded per point too.
        for m in &textured[6..] {
            assert_eq!(wavefront_bsdf(&[], m), Shade::Textured, "{m:?}");
            let thin = Material { transmission: 0.5, diffuse_transmission: 0.5, ..m.clone() };
            assert_eq!(wavefront_bsdf(&[], &thin), Shade::Textured, "{m:?}");
        }
        assert!(matches!(wavefront_bsdf(&[], &Material::default()), Shade::Glossy(_)));
        // A full metal passes no light through, whatever its transmission factor.
        let metal = Material { transmission: 0.5, ..Material::default() };
        assert!(matches!(wavefront_bsdf(&[], &metal), Shade::Glossy(_)));
        // Layers, textured or not, are shaded per point.
        use common::scene::{Anisotropy, Clearcoat, Iridescence, Sheen};
        let coat = Clearcoat {
            factor: 1.0,
            texture: None,
            roughness: 0.1,
            roughness_texture: None,
            normal_texture: None,
        };
        let sheen = Sheen {
            color: Vec3::ONE,
            color_texture: None,
            roughness: 0.5,
            roughness_texture: None,
        };
        let anisotropy = Anisotropy { strength: 0.5, rotation: 0.0, texture: None };
        let film = Iridescence {
            factor: 1.0,
            texture: None,
            ior: 1.3,
            thickness_min: 100.0,
            thickness_max: 400.0,
            thickness_texture: None,
        };
        let layered = [
            Material { clearcoat: Some(coat), ..lambert() },
            Material { sheen: Some(sheen), ..Material::default() },
            Material { anisotropy: Some(anisotropy), ..Material::default() },
            Material { iridescence: Some(film), base_color_texture: texture, ..lambert() },
        ];
        for m in &layered {
            assert_eq!(wavefront_bsdf(&[], m), Shade::Layered, "{m:?}");
        }
        let unlit = Material { unlit: true, ..lambert() };
        assert_eq!(wavefront_bsdf(&[], &unlit), Shade::Unlit);
        // Thin-walled transmission: the metal-rough BSDF's far side.
        for thin in [
            Material { transmission: 0.5, ..lambert() },
            Material { diffuse_transmission: 0.3, ..lambert() },
        ] {
            let shade = wavefront_bsdf(&[], &thin);
            assert!(matches!(shade, Shade::Glossy(b) if b.transmits()), "{shade:?}");
        }
        // A volume's boundary, refractive or entered by diffuse transmission, is shaded per
        // point, and makes the paths track their media; a volume that bounds no medium
        // (thin-walled: its transmission only partial) is an ordinary surface.
        let volume = Some(common::scene::Volume {
            extinction: Vec3::new(0.5, 1.0, 0.0),
            albedo: Vec3::ZERO,
            anisotropy: 0.0,
        });
        let glass = Material { transmission: 1.0, volume, ..lambert() };
        let wax = Material { diffuse_transmission: 0.5, volume, ..lambert() };
        let thin = Material { transmission: 0.5, volume, ..lambert() };
        assert_eq!(wavefront_bsdf(&[], &glass), Shade::Boundary);
        assert_eq!(wavefront_bsdf(&[], &wax), Shade::Boundary);
        assert!(matches!(wavefront_bsdf(&[], &thin), Shade::Glossy(_)));
        for (m, media) in [(&glass, true), (&wax, true), (&thin, false)] {
            let tables = Tables::new(
                &[lambert(), m.clone()],
                &[],
                &LightSampler::default(),
                None,
                false,
                (false, &|_| 0),
            )
            .unwrap();
            assert_eq!(tables.media, media, "{m:?}");
            assert_eq!(tables.textured[1], media, "a boundary is shaded per point");
        }
        let why = Tables::new(
            &[lambert()],
            &[],
            &LightSampler::default(),
            Some("a moving light"),
            false,
            (false, &|_| 0),
        );
        assert_eq!(why.unwrap_err(), "a moving light");
        let colours =
            Tables::new(&[lambert()], &[], &LightSampler::default(), None, true, (false, &|_| 0))
                .unwrap();
        assert_eq!(colours.textured, [true], "vertex colours: shaded per point");
    }
}
