//! The scene model: plain data that the glTF loader produces and the renderer prepares.
//!
//! Geometry stays in each mesh's local space (f32, as glTF stores it) and every placement of a
//! mesh carries its world transform in f64, so that the renderer can move the world next to the
//! camera before rounding to f32 (a scene 1e6 units from the origin renders like one at it).
//! A mesh that deforms (a glTF skin, morph targets) carries a [`Deform`] record: its rest data,
//! from which [`Scene::set_time`] poses it again at any time; a skinned mesh's vertices are posed
//! in world space (relative to [`Skin::origin`]), so its instance carries only that translation.
//! Nothing here knows about rays, BVHs or sampling.

use glam::{DMat4, DVec3, Vec2, Vec3, Vec4};

/// A loaded scene: meshes, where they are placed, materials, textures, cameras and lights.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// Triangle meshes in their local space; one per glTF primitive that has triangles, shared
    /// by the nodes that place it, except that each deforming placement has its own.
    pub meshes: Vec<Mesh>,
    /// Placements of meshes in the world (a glTF node that references a mesh).
    pub instances: Vec<Instance>,
    /// Materials referenced by `Mesh::material`. Always ends with nothing special: a mesh without
    /// a material points at `Scene::default_material()` which the loader appends when needed.
    pub materials: Vec<Material>,
    /// Decoded textures referenced by `TextureRef::texture`.
    pub textures: Vec<Texture>,
    /// Cameras in scene order (the first is the default camera).
    pub cameras: Vec<Camera>,
    /// `KHR_lights_punctual` lights, placed in the world.
    pub lights: Vec<PunctualLight>,
    /// Node animation, when the file animates a node; instances and cameras are posed at its
    /// rest pose until [`Scene::set_time`] poses them at another time.
    pub animation: Option<crate::animation::Animation>,
    /// `KHR_materials_variants`: the names of the material variants, in file order
    /// (`Mesh::variant_materials` refers to them by index).
    pub variants: Vec<String>,
}

/// One glTF primitive's triangles in local space.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// `mesh name/primitive index`, for messages.
    pub name: String,
    /// Vertex positions (POSITION).
    pub positions: Vec<Vec3>,
    /// Vertex normals (NORMAL); `None` means flat shading from the geometric normal.
    pub normals: Option<Vec<Vec3>>,
    /// Vertex tangents with handedness in `w` (TANGENT, else MikkTSpace's where the material
    /// needs a tangent frame and the mesh has normals), used by normal maps and anisotropy.
    pub tangents: Option<Vec<Vec4>>,
    /// Texture coordinates TEXCOORD_0 and TEXCOORD_1, when present.
    pub uvs: [Option<Vec<Vec2>>; 2],
    /// Vertex colours (COLOR_0) as linear RGBA; multiplies the base colour.
    pub colors: Option<Vec<Vec4>>,
    /// Triangles as vertex indices, counter-clockwise = front face. All indices are in range.
    pub indices: Vec<[u32; 3]>,
    /// Index into `Scene::materials`.
    pub material: usize,
    /// `KHR_materials_variants` mappings: (index into `Scene::variants`, index into
    /// `Scene::materials`), the material the mesh takes in that variant (`material` in the
    /// others).
    pub variant_materials: Vec<(usize, usize)>,
    /// How the mesh deforms, for a placement with a skin or morph targets (`None`, costing
    /// nothing, for every other mesh). `positions`, `normals` and `tangents` then hold the
    /// current pose; each deforming placement has a mesh of its own, since two nodes may pose
    /// one glTF mesh differently.
    pub deform: Option<Box<Deform>>,
}

/// What a deforming mesh needs to be posed again at any time: its rest geometry, its morph
/// targets and weights, and its skin. Morph targets apply first, then the skin (glTF 2.0,
/// 3.7.3.3).
#[derive(Clone, Debug, Default)]
pub struct Deform {
    /// The glTF node that places the mesh: its `weights` (and their animation) and its skin
    /// apply.
    pub node: usize,
    /// That node as messages name it, e.g. `node 3 (arm)`.
    pub node_name: String,
    /// POSITION as the file gives it.
    pub rest_positions: Vec<Vec3>,
    /// NORMAL as loaded (unit length), when the mesh has normals.
    pub rest_normals: Option<Vec<Vec3>>,
    /// TANGENT as loaded, when the mesh keeps tangents.
    pub rest_tangents: Option<Vec<Vec4>>,
    /// The primitive's morph targets, in file order.
    pub targets: Vec<MorphTarget>,
    /// The weights when nothing animates them: the node's `weights`, else the mesh's, else 0;
    /// one per target.
    pub weights: Vec<f32>,
    /// The skin, for a node with one.
    pub skin: Option<Skin>,
}

/// One morph target's per-vertex displacements (each as long as the mesh's vertices, or `None`
/// where the target does not move that attribute).
#[derive(Clone, Debug, Default)]
pub struct MorphTarget {
    /// POSITION displacements.
    pub positions: Option<Vec<Vec3>>,
    /// NORMAL displacements.
    pub normals: Option<Vec<Vec3>>,
    /// TANGENT displacements (xyz; the handedness never changes).
    pub tangents: Option<Vec<Vec3>>,
}

/// A glTF skin as one placement uses it: linear blend skinning, each vertex moved by
/// sum_i w_i (jointWorld_i x inverseBind_i).
#[derive(Clone, Debug, Default)]
pub struct Skin {
    /// The glTF skin's index, for messages.
    pub index: usize,
    /// The joints' glTF node indices.
    pub joints: Vec<usize>,
    /// One inverse bind matrix per joint (the identity where the file gives none).
    pub inverse_binds: Vec<DMat4>,
    /// Joint influences per vertex: 4 per JOINTS_n / WEIGHTS_n set.
    pub influences: usize,
    /// `influences` indices into `joints` per vertex, vertex after vertex.
    pub vertex_joints: Vec<u16>,
    /// The matching weights, not negative, summing to 1 per vertex (or all 0 for a vertex
    /// bound to nothing, which keeps its bind-pose position).
    pub vertex_weights: Vec<f32>,
    /// The world point the posed vertices are relative to (the first joint's rest position):
    /// the instance's transform is this translation, so that f32 vertices keep their precision
    /// far from the world origin.
    pub origin: DVec3,
    /// How many vertices' weights did not sum to one and were normalised (or were all 0).
    pub renormalised: usize,
}

/// A mesh placed in the world by a node.
#[derive(Clone, Debug)]
pub struct Instance {
    /// Index into `Scene::meshes`.
    pub mesh: usize,
    /// Index of the glTF node that places it.
    pub node: usize,
    /// Local-to-world transform, in f64 so that large translations survive.
    pub transform: DMat4,
    /// The placement relative to the node (`EXT_mesh_gpu_instancing`; else the identity):
    /// `transform` = the node's world transform x `offset`.
    pub offset: DMat4,
}

/// How alpha is interpreted (`alphaMode`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Alpha below the cutoff makes the surface invisible.
    Mask {
        /// `alphaCutoff`.
        cutoff: f32,
    },
    /// Alpha blending; rendered as stochastic transparency (coverage = alpha).
    Blend,
}

/// A `KHR_texture_transform`: uv' = offset + R(rotation) * (scale * uv).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TexTransform {
    /// `offset`.
    pub offset: Vec2,
    /// `rotation` in radians.
    pub rotation: f32,
    /// `scale`.
    pub scale: Vec2,
}

/// A reference from a material to a texture.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TextureRef {
    /// Index into `Scene::textures`.
    pub texture: usize,
    /// Which TEXCOORD set (0 or 1).
    pub tex_coord: u32,
    /// `KHR_texture_transform`, if any.
    pub transform: Option<TexTransform>,
}

/// The medium inside a `KHR_materials_volume` boundary, homogeneous. Light travelling a distance
/// `d` in it keeps `exp(-extinction * d)` of itself per channel unscattered (Beer-Lambert), where
/// `extinction = -ln(attenuationColor) / attenuationDistance`; of the light it stops, the share
/// `albedo` is scattered (`KHR_materials_volume_scatter`, by the Henyey-Greenstein phase function
/// of mean cosine `anisotropy`) and the rest absorbed. Without scattering the extinction is all
/// absorption, as `KHR_materials_volume` alone says.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Volume {
    /// Extinction coefficient sigma_t per channel, per unit of world distance (0: clear).
    pub extinction: Vec3,
    /// Single-scattering albedo sigma_s / sigma_t per channel, in [0, 1] (0: absorbs only).
    pub albedo: Vec3,
    /// The phase function's mean cosine g, in (-1, 1).
    pub anisotropy: f32,
}

/// The largest extinction a scattering medium gets, per unit of `attenuationDistance`: an
/// `attenuationColor` channel of 0 would stop light at once (infinite extinction), which an
/// absorbing medium can take but a random walk cannot; e^-16 (about 1e-7) of the light is left
/// after one `attenuationDistance` instead.
pub const MAX_SCATTERING_OPTICAL_DEPTH: f32 = 16.0;

impl Volume {
    /// An absorbing medium from `attenuationColor` (each in [0, 1]) and `attenuationDistance`
    /// (> 0, infinite for none).
    pub fn new(attenuation_color: Vec3, attenuation_distance: f32) -> Volume {
        let per_channel = |c: f32| {
            if !attenuation_distance.is_finite() {
                0.0
            } else if c > 0.0 {
                (-c.ln()).max(0.0) / attenuation_distance
            } else {
                // No colour left at any distance: absorbed at once.
                f32::MAX
            }
        };
        let extinction = Vec3::from_array(attenuation_color.to_array().map(per_channel));
        Volume { extinction, albedo: Vec3::ZERO, anisotropy: 0.0 }
    }

    /// The same medium scattering as `KHR_materials_volume_scatter` says: `multiscatterColor`
    /// (each in [0, 1]) is the colour the medium takes after many scatterings, mapped to the
    /// single-scattering albedo by [`single_scatter_albedo`]; `scatterAnisotropy` (in (-1, 1))
    /// is the phase function's mean cosine. `attenuation_distance` bounds an infinite
    /// extinction ([`MAX_SCATTERING_OPTICAL_DEPTH`]).
    pub fn with_scattering(
        self,
        multiscatter_color: Vec3,
        anisotropy: f32,
        attenuation_distance: f32,
    ) -> Volume {
        let albedo = Vec3::from_array(multiscatter_color.to_array().map(single_scatter_albedo));
        if albedo == Vec3::ZERO {
            return Volume { anisotropy, ..self };
        }
        let most = MAX_SCATTERING_OPTICAL_DEPTH / attenuation_distance;
        Volume { extinction: self.extinction.min(Vec3::splat(most)), albedo, anisotropy }
    }

    /// Whether the medium scatters light (else it only absorbs, or is clear).
    pub fn scatters(&self) -> bool {
        self.albedo != Vec3::ZERO && self.extinction != Vec3::ZERO
    }
}

/// The single-scattering albedo whose medium looks, after many scatterings, like the colour
/// `multiscatter` (Kulla and Conty 2017, the inversion `KHR_materials_volume_scatter` gives):
/// 1 - (4.09712 + 4.20863 a - sqrt(9.59217 + 41.6808 a + 17.7126 a²))². Increasing from 0 at 0
/// to 1 at 1 (to within rounding, clamped).
pub fn single_scatter_albedo(multiscatter: f32) -> f32 {
    let a = multiscatter.clamp(0.0, 1.0) as f64;
    if a == 0.0 || a == 1.0 {
        return a as f32; // The fit's ends, exactly.
    }
    let s = 4.09712 + 4.20863 * a - (9.59217 + 41.6808 * a + 17.7126 * a * a).sqrt();
    (1.0 - s * s).clamp(0.0, 1.0) as f32
}

/// `KHR_materials_clearcoat`: a clear GGX coat of index 1.5 over the material, weighted by
/// `factor` x `texture.r` and its Fresnel reflectance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clearcoat {
    /// `clearcoatFactor` in (0, 1].
    pub factor: f32,
    /// `clearcoatTexture` (R = factor, linear).
    pub texture: Option<TextureRef>,
    /// `clearcoatRoughnessFactor` in [0, 1] (perceptual; GGX alpha = roughness²).
    pub roughness: f32,
    /// `clearcoatRoughnessTexture` (G = roughness, linear).
    pub roughness_texture: Option<TextureRef>,
    /// `clearcoatNormalTexture` and its `scale`: the coat's own normal map (without one the
    /// coat follows the surface's normal before the base's normal map).
    pub normal_texture: Option<(TextureRef, f32)>,
}

/// `KHR_materials_sheen`: a layer of fibres (the "Charlie" microfacet sheen) over the material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sheen {
    /// `sheenColorFactor`, linear RGB, each in [0, 1], not all 0.
    pub color: Vec3,
    /// `sheenColorTexture` (RGB, sRGB encoded).
    pub color_texture: Option<TextureRef>,
    /// `sheenRoughnessFactor` in [0, 1].
    pub roughness: f32,
    /// `sheenRoughnessTexture` (A = roughness, linear).
    pub roughness_texture: Option<TextureRef>,
}

/// `KHR_materials_anisotropy`: the specular lobe stretched along a direction in the tangent
/// plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Anisotropy {
    /// `anisotropyStrength` in (0, 1].
    pub strength: f32,
    /// `anisotropyRotation` in radians, counter-clockwise from the tangent.
    pub rotation: f32,
    /// `anisotropyTexture` (RG = direction in [-1, 1] in tangent space, B = strength, linear).
    pub texture: Option<TextureRef>,
}

/// `KHR_materials_iridescence`: a thin dielectric film on the material, whose interference
/// replaces the Fresnel reflectance of its specular lobes, mixed by `factor` x `texture.r`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Iridescence {
    /// `iridescenceFactor` in (0, 1].
    pub factor: f32,
    /// `iridescenceTexture` (R = factor, linear).
    pub texture: Option<TextureRef>,
    /// `iridescenceIor`: the film's index of refraction, at least 1.
    pub ior: f32,
    /// `iridescenceThicknessMinimum` in nanometres, at least 0: the thickness where the
    /// thickness texture reads 0.
    pub thickness_min: f32,
    /// `iridescenceThicknessMaximum` in nanometres, at least 0: the thickness where it reads 1,
    /// and everywhere without a texture.
    pub thickness_max: f32,
    /// `iridescenceThicknessTexture` (G = mix from the minimum to the maximum, linear).
    pub thickness_texture: Option<TextureRef>,
}

/// The glTF metallic-roughness material with the extensions the renderer honours.
#[derive(Clone, Debug)]
pub struct Material {
    /// Name for messages.
    pub name: String,
    /// `baseColorFactor`, linear RGBA.
    pub base_color: Vec4,
    /// `baseColorTexture` (sRGB encoded).
    pub base_color_texture: Option<TextureRef>,
    /// `metallicFactor`.
    pub metallic: f32,
    /// `roughnessFactor` (perceptual; GGX alpha = roughness²).
    pub roughness: f32,
    /// `metallicRoughnessTexture` (B = metallic, G = roughness, linear).
    pub metallic_roughness_texture: Option<TextureRef>,
    /// `normalTexture` and its `scale`.
    pub normal_texture: Option<(TextureRef, f32)>,
    /// `emissiveFactor` x `KHR_materials_emissive_strength.emissiveStrength`: emitted radiance.
    pub emissive: Vec3,
    /// `emissiveTexture` (sRGB encoded).
    pub emissive_texture: Option<TextureRef>,
    /// `KHR_materials_specular.specularFactor` (1 without the extension; 0 = pure Lambert).
    pub specular: f32,
    /// `KHR_materials_specular.specularColorFactor`.
    pub specular_color: Vec3,
    /// `KHR_materials_specular.specularTexture` (A = the factor, linear).
    pub specular_texture: Option<TextureRef>,
    /// `KHR_materials_specular.specularColorTexture` (sRGB encoded).
    pub specular_color_texture: Option<TextureRef>,
    /// A `KHR_materials_pbrSpecularGlossiness` material's `specularGlossinessTexture`, whose
    /// alpha scales its glossiness: the roughness at a point is 1 - (1 - `roughness`) x alpha.
    pub glossiness_texture: Option<TextureRef>,
    /// `KHR_materials_ior.ior` (1.5 without the extension).
    pub ior: f32,
    /// `KHR_materials_transmission.transmissionFactor` (0 without the extension): the share of
    /// the light that enters the surface (is not reflected by its specular layer) that passes
    /// through it instead of being diffused; the surface is thin-walled (no volume, no bending).
    pub transmission: f32,
    /// `KHR_materials_transmission.transmissionTexture` (R = transmission, linear).
    pub transmission_texture: Option<TextureRef>,
    /// `KHR_materials_diffuse_transmission.diffuseTransmissionFactor` (0 without the
    /// extension): the share of the diffuse light that passes to the far side (scattered as a
    /// thin translucent sheet: leaves, paper, lampshades) instead of being reflected.
    pub diffuse_transmission: f32,
    /// `diffuseTransmissionTexture` (A = the factor, linear).
    pub diffuse_transmission_texture: Option<TextureRef>,
    /// `diffuseTransmissionColorFactor`: the colour of the diffusely transmitted light.
    pub diffuse_transmission_color: Vec3,
    /// `diffuseTransmissionColorTexture` (sRGB encoded).
    pub diffuse_transmission_color_texture: Option<TextureRef>,
    /// `KHR_materials_volume` with `thicknessFactor > 0`: the mesh bounds a refractive volume
    /// (`None`: thin-walled, as without the extension).
    pub volume: Option<Volume>,
    /// `KHR_materials_dispersion.dispersion`, 20 / Abbe number (0: none): a refractive volume's
    /// index varies with the wavelength.
    pub dispersion: f32,
    /// `KHR_materials_clearcoat` with a factor above 0 (`None`: no coat).
    pub clearcoat: Option<Clearcoat>,
    /// `KHR_materials_sheen` with a colour factor above 0 (`None`: no sheen).
    pub sheen: Option<Sheen>,
    /// `KHR_materials_anisotropy` with a strength above 0 (`None`: isotropic).
    pub anisotropy: Option<Anisotropy>,
    /// `KHR_materials_iridescence` with a factor above 0 (`None`: no thin film).
    pub iridescence: Option<Iridescence>,
    /// `KHR_materials_unlit`: the surface shows its base colour (factor, texture, vertex colour)
    /// to whatever looks at it, whatever lights it; it reflects nothing and lights nothing.
    pub unlit: bool,
    /// `alphaMode` and `alphaCutoff`.
    pub alpha_mode: AlphaMode,
    /// `doubleSided`: emission leaves both faces when true, the front face only otherwise.
    pub double_sided: bool,
}

impl Material {
    /// Whether the material is a refractive boundary: a volume, fully transmitting (the factor
    /// 1, not textured) and not metallic (the factor 0). Other volumes are rendered thin-walled
    /// for now (the loader warns).
    pub fn refracts(&self) -> bool {
        self.volume.is_some()
            && self.transmission >= 1.0
            && self.transmission_texture.is_none()
            && self.metallic == 0.0
    }

    /// Whether the material uses anything beyond the glTF metallic-roughness BSDF with thin-walled
    /// and diffuse transmission: a volume, `KHR_materials_unlit`, a clear coat, a sheen,
    /// anisotropy or a thin film. The renderer works this out once per triangle, so that a
    /// material without them costs one test per hit.
    pub fn extended(&self) -> bool {
        self.volume.is_some()
            || self.unlit
            || self.clearcoat.is_some()
            || self.sheen.is_some()
            || self.anisotropy.is_some()
            || self.iridescence.is_some()
    }

    /// The texture coordinate set whose tangent frame the material's shading needs: its normal
    /// map's, else its clear coat's normal map's, else set 0 for anisotropy (whose direction is
    /// given in that frame); `None` for a material that needs no tangents.
    pub fn tangent_uv_set(&self) -> Option<u32> {
        let coat = self.clearcoat.as_ref().and_then(|c| c.normal_texture);
        match self.normal_texture.or(coat) {
            Some((map, _)) => Some(map.tex_coord),
            None => self.anisotropy.is_some().then_some(0),
        }
    }

    /// Whether the mesh is the boundary of a medium that light enters through it: a refractive
    /// boundary, or a volume entered by diffuse transmission (no specular transmission), as
    /// `KHR_materials_volume_scatter` recommends for dense media (skin, wax).
    pub fn bounds_medium(&self) -> bool {
        self.refracts()
            || (self.volume.is_some()
                && self.transmission == 0.0
                && self.diffuse_transmission > 0.0)
    }
}

impl Default for Material {
    /// The glTF default material (spec 3.9.6): white, fully metallic, fully rough.
    fn default() -> Self {
        Material {
            name: "default".into(),
            base_color: Vec4::ONE,
            base_color_texture: None,
            metallic: 1.0,
            roughness: 1.0,
            metallic_roughness_texture: None,
            normal_texture: None,
            emissive: Vec3::ZERO,
            emissive_texture: None,
            specular: 1.0,
            specular_color: Vec3::ONE,
            specular_texture: None,
            specular_color_texture: None,
            glossiness_texture: None,
            ior: 1.5,
            transmission: 0.0,
            transmission_texture: None,
            diffuse_transmission: 0.0,
            diffuse_transmission_texture: None,
            diffuse_transmission_color: Vec3::ONE,
            diffuse_transmission_color_texture: None,
            volume: None,
            dispersion: 0.0,
            clearcoat: None,
            sheen: None,
            anisotropy: None,
            iridescence: None,
            unlit: false,
            alpha_mode: AlphaMode::Opaque,
            double_sided: false,
        }
    }
}

/// How a texture repeats outside [0, 1] (glTF sampler `wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Wrap {
    /// 10497
    #[default]
    Repeat,
    /// 33071
    ClampToEdge,
    /// 33648
    MirroredRepeat,
}

/// Decoded texels, row-major from the top row, as stored in the file (colour textures are sRGB
/// encoded; the renderer decodes at lookup): 8 bits a channel, or 16 where the image has 16
/// (a 16-bit PNG: normal and height maps baked at 16 bits band when cut to 8). Shared by every
/// texture that samples the same image (and by clones of the scene).
#[derive(Clone, Debug)]
pub enum Texels {
    /// 8-bit RGBA.
    Rgba8(std::sync::Arc<[[u8; 4]]>),
    /// 16-bit RGBA.
    Rgba16(std::sync::Arc<[[u16; 4]]>),
}

impl Texels {
    /// Number of texels.
    pub fn len(&self) -> usize {
        match self {
            Texels::Rgba8(t) => t.len(),
            Texels::Rgba16(t) => t.len(),
        }
    }

    /// True when there are none (a texture whose image is not decoded yet).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The 8-bit texels, when the image has 8 bits a channel.
    pub fn rgba8(&self) -> Option<&[[u8; 4]]> {
        match self {
            Texels::Rgba8(t) => Some(t),
            Texels::Rgba16(_) => None,
        }
    }

    /// The 16-bit texels, when the image has 16 bits a channel.
    pub fn rgba16(&self) -> Option<&[[u16; 4]]> {
        match self {
            Texels::Rgba16(t) => Some(t),
            Texels::Rgba8(_) => None,
        }
    }

    /// Whether both are the same decoded image (not a copy).
    pub fn same_image(&self, other: &Texels) -> bool {
        match (self, other) {
            (Texels::Rgba8(a), Texels::Rgba8(b)) => std::sync::Arc::ptr_eq(a, b),
            (Texels::Rgba16(a), Texels::Rgba16(b)) => std::sync::Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl From<Vec<[u8; 4]>> for Texels {
    fn from(texels: Vec<[u8; 4]>) -> Self {
        Texels::Rgba8(texels.into())
    }
}

/// A decoded texture, row 0 at the top (v = 0).
#[derive(Clone, Debug)]
pub struct Texture {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width * height` texels.
    pub texels: Texels,
    /// Wrap mode along u.
    pub wrap_s: Wrap,
    /// Wrap mode along v.
    pub wrap_t: Wrap,
    /// Nearest filtering (magFilter 9728); bilinear otherwise.
    pub nearest: bool,
    /// Mipmapped minification (a `minFilter` of the `*_MIPMAP_*` kinds, or none given): the
    /// renderer filters lookups over a footprint. `minFilter` NEAREST or LINEAR asks for no
    /// mipmaps.
    pub mipmaps: bool,
    /// The mip levels past this one, each half the last's size down to 1x1, where a renderer
    /// built them (empty as loaded).
    pub levels: Vec<Texture>,
}

/// A camera's projection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Perspective with a vertical field of view in radians.
    Perspective {
        /// `yfov`.
        yfov: f32,
    },
    /// Orthographic with half extents of the view volume.
    Orthographic {
        /// `xmag`.
        xmag: f32,
        /// `ymag`.
        ymag: f32,
    },
}

/// A camera placed in the world. It looks down its local -z axis with +y up.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Name of the camera node (falls back to the camera's name).
    pub name: String,
    /// Index of the node that holds it, if it came from the file.
    pub node: Option<usize>,
    /// Camera-to-world transform, rigid (scale removed by the loader).
    pub transform: DMat4,
    /// Projection.
    pub projection: Projection,
}

impl Camera {
    /// The camera's position in the world.
    pub fn position(&self) -> DVec3 {
        self.transform.w_axis.truncate()
    }
}

/// The kinds of `KHR_lights_punctual` light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PunctualKind {
    /// `intensity` is irradiance (W/m² in RGB units) on a surface facing the light.
    Directional,
    /// `intensity` is radiant intensity (W/sr).
    Point,
    /// A point light limited to a cone, smooth between the two angles (radians).
    Spot {
        /// `innerConeAngle`.
        inner_cone: f32,
        /// `outerConeAngle`.
        outer_cone: f32,
    },
}

/// A punctual light placed in the world.
#[derive(Clone, Debug)]
pub struct PunctualLight {
    /// Name for messages.
    pub name: String,
    /// Its kind.
    pub kind: PunctualKind,
    /// `color` x `intensity`.
    pub intensity: Vec3,
    /// World position (ignored for directional lights).
    pub position: DVec3,
    /// World direction the light points to (its node's -z), unit length.
    pub direction: DVec3,
    /// `range`, if given (the renderer ignores it, as the spec allows for physically based renderers).
    pub range: Option<f32>,
    /// The glTF node that places it.
    pub node: Option<usize>,
}

impl Scene {
    /// Poses animated instances, cameras and punctual lights at time `t` (seconds). Nothing
    /// moves in a scene without animation.
    ///
    /// Deforming meshes that the animation drives (a joint that moves, animated weights) are
    /// posed again: a renderer must rebuild what it built from their vertices. A skinned mesh's
    /// instance never moves with its node (glTF ignores the skinned node's transform).
    pub fn set_time(&mut self, t: f64) {
        let Some(anim) = &self.animation else { return };
        let meshes = &self.meshes;
        for inst in &mut self.instances {
            if anim.moves(inst.node) && !meshes[inst.mesh].skinned() {
                inst.transform = anim.world(inst.node, t) * inst.offset;
            }
        }
        // The world transforms of the joints, each node worked out once for all skins.
        let mut worlds = std::collections::HashMap::new();
        for mesh in &mut self.meshes {
            let Some(deform) = mesh.deform.take() else { continue };
            if deform.animated(anim) {
                let weights = deform.weights_at(Some(anim), t);
                for &j in deform.skin.iter().flat_map(|s| &s.joints) {
                    anim.world_memo(j, t, &mut worlds);
                }
                deform.pose(&weights, |joint| worlds[&joint], mesh);
            }
            mesh.deform = Some(deform);
        }
        for light in &mut self.lights {
            if let Some(node) = light.node.filter(|&n| anim.moves(n)) {
                let world = anim.world(node, t);
                light.position = world.w_axis.truncate();
                if let Some(d) = world.transform_vector3(DVec3::NEG_Z).try_normalize() {
                    light.direction = d;
                }
            }
        }
        for cam in &mut self.cameras {
            if let Some(node) = cam.node.filter(|&n| anim.moves(n)) {
                if let Some(m) = crate::gltf::nodes::rigid(anim.world(node, t)) {
                    cam.transform = m;
                }
            }
        }
    }

    /// Whether the settings' lens fits the camera they render from (the one `camera` names, the
    /// first by default): a thin lens (`lens.aperture_radius > 0`) needs a perspective camera.
    /// An orthographic camera has no lens model here, and dropping the setting would render
    /// everything sharp with no word.
    pub fn check_lens(&self, settings: &crate::settings::RenderSettings) -> Result<(), String> {
        if !(settings.lens.aperture_radius > 0.0) {
            return Ok(());
        }
        let camera = match &settings.camera {
            Some(wanted) => self.cameras.iter().find(|c| &c.name == wanted),
            None => self.cameras.first(),
        };
        match camera {
            Some(c) if matches!(c.projection, Projection::Orthographic { .. }) => Err(format!(
                "lens.aperture_radius: the orthographic camera '{}' has no lens (depth of field needs a \
                 perspective camera): remove `lens`, or name a perspective camera with `camera`",
                c.name
            )),
            _ => Ok(()),
        }
    }

    /// The scene-dependent checks of the settings' integrator: the light bidirectional path
    /// tracing and photon mapping must start paths from, and more light-traced paths than one per
    /// sample where the camera is orthographic (light tracing cannot reach it). `Ok` for the path
    /// tracer.
    pub fn check_integrator(
        &self,
        settings: &crate::settings::RenderSettings,
    ) -> Result<(), String> {
        use crate::settings::Integrator;
        let name = settings.integrator;
        if name == Integrator::Path {
            return Ok(());
        }
        if name == Integrator::Bdpt && settings.light_paths() > 1 {
            // The camera the settings name (the first by default).
            let camera = match &settings.camera {
                Some(wanted) => self.cameras.iter().find(|c| &c.name == wanted),
                None => self.cameras.first(),
            };
            if let Some(c) =
                camera.filter(|c| matches!(c.projection, Projection::Orthographic { .. }))
            {
                return Err(format!(
                    "bdpt.light_paths: {} light paths per sample with the orthographic camera \
                     '{}', which light tracing cannot reach: they would only cost time (use 1, \
                     or a perspective camera)",
                    settings.light_paths(),
                    c.name
                ));
            }
        }
        let emissive = self.instances.iter().any(|inst| {
            let m = &self.materials[self.meshes[inst.mesh].material];
            m.emissive.max_element() > 0.0 && !m.unlit
        });
        let punctual = self.lights.iter().any(|l| l.intensity.max_element() > 0.0);
        if !emissive && !punctual && settings.environment.is_none() {
            return Err(format!(
                "integrator: {name} traces paths from the lights, and the scene has none (no \
                 emissive material, no KHR_lights_punctual light)"
            ));
        }
        Ok(())
    }

    /// Whether instance `inst` moves with its node's animation (a skinned mesh never does: its
    /// vertices are posed in world space).
    pub fn instance_moves(&self, inst: &Instance) -> bool {
        self.animation.as_ref().is_some_and(|a| a.moves(inst.node))
            && !self.meshes[inst.mesh].skinned()
    }

    /// Gives every mesh the material its `KHR_materials_variants` mapping names for variant
    /// `name` (meshes without one keep their default material); an unknown name is an error
    /// listing the scene's variants.
    pub fn apply_variant(&mut self, name: &str) -> Result<(), String> {
        let index = self.variant_index(name)?;
        for mesh in &mut self.meshes {
            if let Some(&(_, material)) = mesh.variant_materials.iter().find(|(v, _)| *v == index) {
                mesh.material = material;
            }
        }
        Ok(())
    }

    /// The index of the material variant `name`, or an error listing the scene's variants.
    pub fn variant_index(&self, name: &str) -> Result<usize, String> {
        let Some(index) = self.variants.iter().position(|v| v == name) else {
            let names = if self.variants.is_empty() {
                "the scene has none".to_string()
            } else {
                format!("the scene has: {}", self.variants.join(", "))
            };
            return Err(format!("variant: no material variant named '{name}' ({names})"));
        };
        Ok(index)
    }

    /// Whether anything in the scene moves or deforms over time (a renderer prepares such a
    /// scene again for each frame).
    pub fn is_animated(&self) -> bool {
        self.animation.as_ref().is_some_and(|a| {
            self.instances.iter().any(|i| self.instance_moves(i))
                || self.meshes.iter().any(|m| m.deform.as_ref().is_some_and(|d| d.animated(a)))
                || self.cameras.iter().any(|c| c.node.is_some_and(|n| a.moves(n)))
                || self.lights.iter().any(|l| l.node.is_some_and(|n| a.moves(n)))
        })
    }

    /// World-space bounds of all instanced geometry, or `None` for an empty scene.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for inst in &self.instances {
            for &p in &self.meshes[inst.mesh].positions {
                let w = inst.transform.transform_point3(p.as_dvec3());
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
        (lo.x <= hi.x).then_some((lo, hi))
    }

    /// Number of triangles over all instances.
    pub fn triangle_count(&self) -> usize {
        self.instances.iter().map(|i| self.meshes[i.mesh].indices.len()).sum()
    }

    /// Whether anything in the scene itself gives light: a placed mesh with an emissive
    /// material, or a punctual light of non-zero intensity. Without either, only the
    /// environment lights the scene.
    pub fn has_lights(&self) -> bool {
        let emits = |m: &Material| m.emissive != Vec3::ZERO;
        self.instances.iter().any(|i| emits(&self.materials[self.meshes[i.mesh].material]))
            || self.lights.iter().any(|l| l.intensity != Vec3::ZERO)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_albedo_inversion_is_monotonic_from_zero_to_one() {
        assert_eq!(single_scatter_albedo(0.0), 0.0);
        assert_eq!(single_scatter_albedo(1.0), 1.0);
        let mut last = 0.0;
        for i in 1..1000 {
            let a = single_scatter_albedo(i as f32 / 1000.0);
            assert!(a > last && a < 1.0, "{i}: {a}");
            // Scattering many times darkens: the single-scattering albedo is the lighter.
            assert!(a >= i as f32 / 1000.0, "{i}: {a}");
            last = a;
        }
    }

    #[test]
    fn a_scattering_volume_bounds_an_infinite_extinction() {
        let v = Volume::new(Vec3::new(0.0, 0.5, 1.0), 2.0);
        assert_eq!(v.extinction.x, f32::MAX);
        assert!(!v.scatters());
        let s = v.with_scattering(Vec3::splat(0.5), 0.3, 2.0);
        assert!(s.scatters());
        assert_eq!(
            s.extinction,
            Vec3::new(MAX_SCATTERING_OPTICAL_DEPTH / 2.0, 0.5f32.ln() / -2.0, 0.0)
        );
        assert_eq!(s.anisotropy, 0.3);
        // Black multiscatter: absorbing as before, the extinction untouched.
        assert_eq!(v.with_scattering(Vec3::ZERO, 0.0, 2.0), v);
    }
}
