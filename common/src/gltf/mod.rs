//! glTF 2.0 loading: `.glb` and `.gltf` (data URIs or files inside the scene's own folder or
//! bundle) into a [`Scene`], with validation that names the offending object.
//! Start at [`load_path`], [`load_slice`] and [`check_renderable`].

// Files: mod.rs (public API, resolvers, loader state), glb.rs (binary container), json.rs (JSON
// layer, asset and extension checks), uri.rs (data URIs, confinement of file URIs), accessor.rs
// (buffers, views, accessors), meshopt.rs (EXT_meshopt_compression views), draco.rs
// (KHR_draco_mesh_compression primitives), mesh.rs (primitives), material.rs (materials, textures, images), basisu.rs (KTX2
// images of KHR_texture_basisu),
// nodes.rs (node tree, instances, cameras, lights, default camera), deform.rs (skins and morph
// targets of deforming placements), tangents.rs (MikkTSpace tangents where a file gives none),
// animation.rs (animation channels), tests*.rs.

mod accessor;
mod animation;
mod basisu;
mod deform;
mod draco;
mod glb;
pub use glb::build as build_glb;
mod json;
mod material;
mod mesh;
mod meshopt;
pub(crate) mod nodes;
pub use nodes::rigid;
mod tangents;
mod uri;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_assets;
#[cfg(test)]
mod tests_compression;
#[cfg(test)]
mod tests_deform;
#[cfg(test)]
mod tests_tangents;

use std::borrow::Cow;
use std::cell::{Cell, OnceCell, RefCell};
use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};

use glam::DMat4;

use crate::{
    budget::{self, SceneBudget},
    scene::{Camera, Instance, Mesh, PunctualLight, Scene, Texture},
    spread::{InOrder, Spread},
};

/// Why a scene could not be loaded. The message names the glTF object at fault.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SceneError(pub String);

/// Supplies the bytes of the files a `.gltf` refers to (buffers and images that are not `data:`
/// URIs): a folder ([`DirResolver`]), nothing ([`NoFiles`]), or an uploaded bundle.
///
/// The loader has already rejected absolute paths, schemes other than `data:` and `..` escapes
/// and percent-decoded the URI: `uri` is a relative path with `/` separators and no `.` or `..`
/// segments. An implementation must still never return bytes from outside its own root.
pub trait Resolver {
    /// Returns the whole content of the file at the relative path `uri`, or why it cannot.
    fn read(&self, uri: &str) -> Result<Vec<u8>, String>;
}

/// Resolves URIs inside one folder and never outside it (symbolic links included: the
/// canonical path of every file must lie under the canonical folder).
#[derive(Clone, Debug)]
pub struct DirResolver {
    dir: PathBuf,
}

impl DirResolver {
    /// A resolver for files inside `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        DirResolver { dir: dir.into() }
    }

    /// The folder files are resolved in.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

impl Resolver for DirResolver {
    fn read(&self, uri: &str) -> Result<Vec<u8>, String> {
        let rel = Path::new(uri);
        if !rel.components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir)) {
            return Err(format!("'{uri}' is not a plain relative path"));
        }
        let base = self
            .dir
            .canonicalize()
            .map_err(|e| format!("scene folder {}: {e}", self.dir.display()))?;
        let full =
            base.join(rel).canonicalize().map_err(|e| format!("cannot open '{uri}': {e}"))?;
        if !full.starts_with(&base) {
            return Err(format!("'{uri}' resolves outside the scene folder"));
        }
        if !full.is_file() {
            return Err(format!("'{uri}' is not a file"));
        }
        std::fs::read(&full).map_err(|e| format!("cannot read '{uri}': {e}"))
    }
}

/// A resolver with no files at all: only `data:` URIs and the GLB BIN chunk can be used.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoFiles;

impl Resolver for NoFiles {
    fn read(&self, uri: &str) -> Result<Vec<u8>, String> {
        Err(format!("external file '{uri}' is not available (this scene may only use data: URIs)"))
    }
}

/// Loads a `.gltf` or `.glb` file; external files are resolved only inside its folder.
///
/// The format is recognised from the magic bytes (`glTF` = binary); a file named `.glb` that
/// does not start with them is an error.
pub fn load_path(path: &Path) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path)
        .map_err(|e| SceneError(format!("{}: cannot read: {e}", path.display())))?;
    let named_glb = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb"));
    if named_glb && !glb::is_glb(&bytes) {
        return Err(SceneError(format!(
            "GLB: {} does not start with the magic bytes \"glTF\"",
            path.display()
        )));
    }
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    load_slice(&bytes, &DirResolver::new(dir))
}

/// Loads a glTF asset from memory: binary (`glTF` magic) or JSON. `files` supplies the files its
/// URIs name.
///
/// The loader follows the default scene's node tree (`scene`, else scene 0, else every root
/// node) and reads only the meshes, accessors, buffers, materials, textures and images that the
/// tree uses, so an unused broken object (an image in an unknown format, a buffer on the web) does
/// not stop a scene from loading; everything it does read is checked, and a malformed file gives
/// a [`SceneError`] naming the object ("accessor 3: ...", "mesh 2 primitive 0: ...") rather than a
/// panic. [`Scene::materials`] holds the used glTF materials in file order, then the glTF default
/// material ([`Material::default`](crate::scene::Material)) if some primitive has no material;
/// [`Scene::textures`] holds the textures those materials use. A file without a camera gets a
/// default perspective camera named "default" (40 degrees, seeing the whole scene from +z).
pub fn load_slice(bytes: &[u8], files: &dyn Resolver) -> Result<Scene, SceneError> {
    load_slice_within(bytes, files, &SceneBudget::default())
}

/// [`load_slice`] within `budget`: decoded texels are counted from the images' headers before
/// they are decoded, and triangles as meshes are placed, before their instances are made.
pub fn load_slice_within(
    bytes: &[u8],
    files: &dyn Resolver,
    budget: &SceneBudget,
) -> Result<Scene, SceneError> {
    load_slice_spread(bytes, files, budget, &InOrder)
}

/// [`load_slice_within`], decoding the images on the threads `spread` lends (the same scene
/// whatever the threads).
pub fn load_slice_spread(
    bytes: &[u8],
    files: &dyn Resolver,
    budget: &SceneBudget,
    spread: &dyn Spread,
) -> Result<Scene, SceneError> {
    let (json_bytes, bin) = if glb::is_glb(bytes) {
        let g = glb::parse(bytes)?;
        (g.json, g.bin)
    } else {
        (bytes, None)
    };
    let doc = json::parse(json_bytes)?;
    let mut loader = Loader::new(&doc, bin, files);
    loader.scene_budget = *budget;
    loader.spread = spread;
    loader.load()
}

/// Checks that a loaded scene has something to render.
pub fn check_renderable(scene: &Scene) -> Result<(), SceneError> {
    if scene.triangle_count() == 0 {
        return Err(SceneError("scene has no triangles".into()));
    }
    Ok(())
}

/// Shorthand for an error message.
fn fail<T>(msg: impl Into<String>) -> Result<T, SceneError> {
    Err(SceneError(msg.into()))
}

/// Prefixes an error with the object that was being loaded when it happened.
trait Context<T> {
    fn context(self, what: impl FnOnce() -> String) -> Result<T, SceneError>;
}

impl<T> Context<T> for Result<T, SceneError> {
    fn context(self, what: impl FnOnce() -> String) -> Result<T, SceneError> {
        self.map_err(|e| SceneError(format!("{}: {}", what(), e.0)))
    }
}

/// An image as its header gives it, its texels charged to the budget.
struct Image {
    width: u32,
    height: u32,
}

/// An image read and checked, waiting to be decoded (`Loader::decode_images`).
struct PendingImage {
    index: usize,
    bytes: Vec<u8>,
    format: ImageFormat,
    width: u32,
    height: u32,
}

/// How an image's bytes are encoded.
#[derive(Clone, Copy, Debug)]
enum ImageFormat {
    /// PNG, JPEG or WebP, decoded by the `image` crate.
    Image(image::ImageFormat),
    /// KTX2 with Basis Universal data (`KHR_texture_basisu`).
    Ktx2,
}

/// The loader's state: the parsed document, lazily loaded buffers and images, and the scene
/// being built.
struct Loader<'a> {
    root: &'a ::gltf::json::Root,
    raw: &'a serde_json::Value,
    bin: Option<&'a [u8]>,
    files: &'a dyn Resolver,
    buffers: Vec<OnceCell<Cow<'a, [u8]>>>,
    /// The decoded bytes of each `EXT_meshopt_compression` buffer view, on first use.
    decoded_views: Vec<OnceCell<Vec<u8>>>,
    /// The bytes of each accessor decoded from a `KHR_draco_mesh_compression` stream, tightly
    /// packed in the accessor's component type.
    draco: RefCell<HashMap<usize, std::rc::Rc<[u8]>>>,
    images: HashMap<usize, Image>,
    /// The images to decode once the materials are read, and which texture takes which.
    pending_images: Vec<PendingImage>,
    texture_images: Vec<(usize, usize)>,
    /// Who decodes them.
    spread: &'a dyn Spread,

    meshes: Vec<Mesh>,
    /// The glTF material of each entry of `meshes` (`None` = default material).
    mesh_materials: Vec<Option<usize>>,
    /// The `KHR_materials_variants` mappings of each entry of `meshes`: (variant, glTF material).
    mesh_variant_materials: Vec<Vec<(usize, usize)>>,
    /// The root's `KHR_materials_variants` names.
    variants: Vec<String>,
    /// (glTF mesh, primitive) -> index in `meshes`, `None` when the primitive has no triangles.
    mesh_map: HashMap<(usize, usize), Option<usize>>,
    instances: Vec<Instance>,
    cameras: Vec<Camera>,
    lights: Vec<PunctualLight>,
    textures: Vec<Texture>,
    /// glTF texture -> index in `textures`, `None` when it has no usable source.
    texture_map: HashMap<usize, Option<usize>>,
    /// What is left of the [`Budget`] for this file.
    budget: Cell<Budget>,
    /// The scene's budgets (texels, triangles), and what the file has used of them so far.
    scene_budget: SceneBudget,
    texels_used: Cell<u64>,
    triangles_used: Cell<u64>,
    /// Bytes decoded from compressed buffer views (charged to `inflated_bytes`, apart from what
    /// a `.zip` bundle inflated to).
    decoded_bytes: Cell<u64>,
    /// The `animations` array of the JSON, as written.
    animations: Option<&'a serde_json::Value>,
    /// Each node's parent (set by `load_nodes`), for the joints' rest transforms.
    parents: Vec<Option<usize>>,
    /// Rest world transforms of the nodes skins have needed so far.
    rest_worlds: HashMap<usize, DMat4>,
}

/// Limits on what one file may make the loader allocate, far above any real scene, so that a
/// small malicious file (thousands of primitives sharing one big accessor, millions of GPU
/// instances) gives an error instead of exhausting memory. Texels and triangles have the scene's
/// own budgets ([`SceneBudget`]), set by the farm.
#[derive(Clone, Copy, Debug)]
struct Budget {
    /// Accessor components read (4 bytes each), over all accessors.
    components: u64,
    /// Mesh instances.
    instances: u64,
}

impl Budget {
    const FULL: Budget = Budget { components: 1 << 28, instances: 1 << 24 };
}

impl Loader<'_> {
    /// Counts `amount` texels, triangles or decoded bytes against the scene's budget; `at` names the object
    /// that takes the count over.
    fn charge_scene(
        &self,
        line: budget::Line,
        amount: u64,
        at: impl FnOnce() -> String,
    ) -> Result<(), SceneError> {
        let (used, limit) = match line {
            budget::Line::Texels => (&self.texels_used, self.scene_budget.texels),
            budget::Line::Triangles => (&self.triangles_used, self.scene_budget.triangles),
            budget::Line::InflatedBytes => (&self.decoded_bytes, self.scene_budget.inflated_bytes),
            budget::Line::Entries => unreachable!("the loader opens no archive"),
        };
        let total = used.get().saturating_add(amount);
        if total > limit {
            return Err(budget::over_budget(line, total, limit, &at()));
        }
        used.set(total);
        Ok(())
    }

    /// Takes `amount` from one budget line; `what` names the object for the error.
    fn charge(
        &self,
        amount: u64,
        line: fn(&mut Budget) -> &mut u64,
        what: impl FnOnce() -> String,
    ) -> Result<(), SceneError> {
        let mut b = self.budget.get();
        let left = line(&mut b);
        if amount > *left {
            return fail(format!("{}: the scene is too large for this loader's limits", what()));
        }
        *left -= amount;
        self.budget.set(b);
        Ok(())
    }
}

impl<'a> Loader<'a> {
    fn new(doc: &'a json::Document, bin: Option<&'a [u8]>, files: &'a dyn Resolver) -> Self {
        Loader {
            root: &doc.root,
            raw: &doc.raw,
            bin,
            files,
            buffers: (0..doc.root.buffers.len()).map(|_| OnceCell::new()).collect(),
            decoded_views: (0..doc.root.buffer_views.len()).map(|_| OnceCell::new()).collect(),
            draco: RefCell::new(HashMap::new()),
            images: HashMap::new(),
            pending_images: Vec::new(),
            texture_images: Vec::new(),
            spread: &InOrder,
            meshes: Vec::new(),
            mesh_materials: Vec::new(),
            mesh_variant_materials: Vec::new(),
            variants: Vec::new(),
            mesh_map: HashMap::new(),
            instances: Vec::new(),
            cameras: Vec::new(),
            lights: Vec::new(),
            textures: Vec::new(),
            texture_map: HashMap::new(),
            budget: Cell::new(Budget::FULL),
            scene_budget: SceneBudget::default(),
            texels_used: Cell::new(0),
            triangles_used: Cell::new(0),
            decoded_bytes: Cell::new(0),
            animations: doc.animations.as_ref(),
            parents: Vec::new(),
            rest_worlds: HashMap::new(),
        }
    }

    /// The root's `KHR_materials_variants.variants` names (none without the extension); each
    /// must be a distinct string.
    fn variant_names(&self) -> Result<Vec<String>, SceneError> {
        let ext =
            self.root.extensions.as_ref().and_then(|e| e.others.get("KHR_materials_variants"));
        let Some(ext) = ext else { return Ok(Vec::new()) };
        let Some(list) = ext.get("variants").and_then(|v| v.as_array()) else {
            return fail("variants must be an array");
        };
        let mut names: Vec<String> = Vec::with_capacity(list.len());
        for (i, v) in list.iter().enumerate() {
            let Some(name) = v.get("name").and_then(|n| n.as_str()) else {
                return fail(format!("variants[{i}]: name must be a string"));
            };
            if names.iter().any(|n| n == name) {
                return fail(format!("variants[{i}]: the name '{name}' is used twice"));
            }
            names.push(name.to_string());
        }
        Ok(names)
    }

    fn load(mut self) -> Result<Scene, SceneError> {
        self.variants = self.variant_names().context(|| "KHR_materials_variants".into())?;
        self.load_nodes()?;
        let materials = self.load_materials()?;
        self.generate_tangents(&materials)?;
        self.decode_images()?;
        let parents = nodes::node_parents(self.root)?;
        let animation = self.load_animation(self.animations, &parents)?;
        let mut scene = Scene {
            animation,
            meshes: std::mem::take(&mut self.meshes),
            instances: std::mem::take(&mut self.instances),
            materials,
            textures: std::mem::take(&mut self.textures),
            cameras: std::mem::take(&mut self.cameras),
            lights: std::mem::take(&mut self.lights),
            variants: std::mem::take(&mut self.variants),
        };
        if scene.cameras.is_empty() {
            scene.cameras.push(nodes::default_camera(&scene));
        }
        for mesh in &scene.meshes {
            if scene.materials[mesh.material].refracts() {
                if let Some(open) = open_edges(mesh) {
                    tracing::warn!(
                        "mesh {}: a refractive volume whose mesh is not closed ({open} edges not shared by two faces wound the opposite way): light that leaves through a gap is taken to leave the volume",
                        mesh.name
                    );
                }
            }
        }
        Ok(scene)
    }
}

/// How many edges of `mesh` are not matched by the same edge run the other way in another
/// triangle (vertices compared by position, so that seams of split vertices count as joined);
/// `None` for a closed, consistently wound mesh: the boundary of a volume.
pub fn open_edges(mesh: &crate::scene::Mesh) -> Option<usize> {
    use std::collections::HashMap;
    let key = |i: u32| mesh.positions[i as usize].to_array().map(f32::to_bits);
    let mut edges: HashMap<([u32; 3], [u32; 3]), i32> = HashMap::new();
    for t in &mesh.indices {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let (a, b) = (key(a), key(b));
            if a == b {
                continue; // A degenerate edge bounds nothing.
            }
            // +1 for a -> b, -1 for b -> a, under the ordered pair's key.
            let (k, d) = if a < b { ((a, b), 1) } else { ((b, a), -1) };
            *edges.entry(k).or_default() += d;
        }
    }
    let open = edges.values().filter(|&&n| n != 0).count();
    (open > 0).then_some(open)
}
