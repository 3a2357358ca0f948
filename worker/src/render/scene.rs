//! `prepare`: turns the loaded scene model into what the integrator reads — camera-relative
//! world-space triangles in a BVH, per-triangle shading data in the same order, resolved
//! materials, and the lights.
//!
//! The world is translated so that the chosen camera sits at the origin, in f64, before rounding
//! to f32: precision is then best where the camera looks, whatever the scene's absolute position.

use std::{sync::Arc, time::Instant};

use common::{
    envmap::EnvMap,
    scene::{AlphaMode, Instance, Material, Projection, PunctualKind, Scene, Texture},
    settings::{Environment, Integrator, RenderSettings},
};
use glam::{DMat3, DMat4, DVec3, Mat3, Vec2, Vec3, Vec4};

use super::{
    accel::KeyedAccel,
    accel::{Accel, Hit},
    bvh_cache::{self, BvhCache},
    camera::{Camera, CameraModel, PixelSpread},
    geometry::{interpolation_error, offset_ray_origin, Ray},
    light::{
        DirectionalLight, Environment as EnvironmentLight, Light, LightChoice, LightSampler,
        MapEnvironment, PointLight, PowerMixture, SpotLight, TriangleLight,
    },
    material::{self, SurfacePoint},
    media::MediumStack,
    motion::{deform_keys, Deforming, Motion, MotionInstance, Place, Pose, Shape},
    sampler::{mix64, to_unit},
    wavefront_tables::Tables,
};

/// The emitting triangles that move within the shutter (`TriShading::light` `UNSAMPLED`), for
/// photon mapping: no light sample reaches them, so paths that hit them count them in full, and
/// photons leave them too, each pass from where they are at its instant (starting in the volumes
/// they lie inside at the shutter's opening). A
/// photon leaves one of them with probability `share` (their power's share of all, from 1% to
/// 99% beside lights that stay put, else 1), and a given one half by its power at the shutter's
/// opening, half uniformly.
#[derive(Clone, Debug)]
pub struct MovingEmitters {
    /// The triangles (BVH order).
    pub prims: Vec<u32>,
    /// Cumulative probability of choosing each: `prims.len() + 1` entries from 0 to 1.
    pub cdf: Vec<f32>,
    /// The probability that a photon leaves one of them rather than a light that stays put.
    pub share: f32,
    /// The volumes each lies inside at the shutter's opening (what moves placed there too),
    /// where its photons start (as `PreparedScene::light_media`; empty where the scene has no
    /// volumes).
    pub media: Vec<MediumStack>,
}

impl MovingEmitters {
    /// The moving emitters of a prepared scene with motion, or `None`.
    fn new(scene: &PreparedScene, scene_radius: f32) -> Option<MovingEmitters> {
        let motion = scene.motion.as_ref()?;
        let pose = Pose::new(motion, motion.time(0.0));
        let lum = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722)).max(0.0);
        let mut prims = Vec::new();
        let mut power = Vec::new();
        for (prim, tri) in scene.shading.iter().enumerate() {
            if tri.light == UNSAMPLED {
                let m = &scene.materials[tri.material as usize];
                let ([p0, p1, p2], _) = scene.triangle(prim as u32, Some(&pose));
                let area = 0.5 * (p1 - p0).cross(p2 - p0).length();
                let sides = if m.double_sided { 2.0 } else { 1.0 };
                let w = lum(m.emissive) * area * std::f32::consts::PI * sides;
                prims.push(prim as u32);
                power.push(if w.is_finite() { w } else { 0.0 });
            }
        }
        if prims.is_empty() {
            return None;
        }
        let moving: f64 = power.iter().map(|&w| w as f64).sum();
        let still: f64 = scene.lights.lights.iter().map(|l| l.power(scene_radius) as f64).sum();
        // Both kinds keep at least 1% of the photons: powers taken at one instant are a guess.
        let share = if still > 0.0 { (moving / (moving + still)).clamp(0.01, 0.99) } else { 1.0 };
        // Half by power, half uniformly (a triangle may have no area at the shutter's opening).
        let n = prims.len() as f64;
        let mut cdf = Vec::with_capacity(prims.len() + 1);
        let mut sum = 0.0f64;
        cdf.push(0.0);
        for &w in &power {
            let by_power = if moving > 0.0 { w as f64 / moving } else { 1.0 / n };
            sum += 0.5 * by_power + 0.5 / n;
            cdf.push(sum.min(1.0) as f32);
        }
        *cdf.last_mut().expect("not empty") = 1.0;
        let media = if scene.materials.iter().any(|m| m.bounds_medium()) {
            let at = |prim: u32| {
                let ([p0, p1, p2], _) = scene.triangle(prim, Some(&pose));
                let normal = (p1 - p0).cross(p2 - p0).try_normalize().unwrap_or(askew());
                media_at(scene, (p0 + p1 + p2) / 3.0, normal, prim, Some(&pose))
            };
            prims.iter().map(|&prim| at(prim)).collect()
        } else {
            Vec::new()
        };
        Some(MovingEmitters { prims, cdf, share: share as f32, media })
    }

    /// Chooses one with `u` in [0, 1): its index in `prims` and probability.
    pub fn choose(&self, u: f32) -> (usize, f32) {
        let i = self.cdf.partition_point(|&c| c <= u).clamp(1, self.prims.len()) - 1;
        (i, self.cdf[i + 1] - self.cdf[i])
    }
}

/// Marks "no such index" in the compact per-triangle tables.
pub const NONE: u32 = u32::MAX;
/// `TriShading::light` of an emitting triangle that moves within the shutter: its emission is
/// found by paths that hit it (weight 1), not by light sampling.
pub const UNSAMPLED: u32 = u32::MAX - 1;

/// Shading data of one triangle (BVH order).
#[derive(Clone, Copy, Debug)]
pub struct TriShading {
    /// Indices into `PreparedScene::normals` / `uvs` of its three vertices.
    pub vertices: [u32; 3],
    /// Index into `PreparedScene::materials`.
    pub material: u32,
    /// Index into `PreparedScene::lights.lights` when the triangle emits, else `NONE`.
    pub light: u32,
    /// Whether the mesh has vertex normals (else flat shading).
    pub smooth: bool,
    /// Whether the material is `Material::extended` (a volume, unlit, layers or anisotropy): the
    /// integrator tests this flag, which it loads with the rest of the triangle, before any of
    /// those (it fits in the struct's padding).
    pub extended: bool,
}

/// Everything a worker needs to render tasks of one job, built once per (scene, settings).
pub struct PreparedScene {
    /// What moves within the shutter (`None` for static scenes and zero-length shutters).
    pub motion: Option<Motion>,
    /// World position (f64) of the renderer's origin: the camera.
    pub origin: DVec3,
    /// The camera at the origin.
    pub camera: Camera,
    /// Triangles and BVH (shared with the worker's `BvhCache`, where it came from one).
    pub accel: Arc<Accel>,
    /// Per-triangle shading data, indexed like `Hit::prim`.
    pub shading: Vec<TriShading>,
    /// World-space vertex normals (zero when the mesh has none).
    pub normals: Vec<Vec3>,
    /// World-space vertex tangents (TANGENT, or MikkTSpace's from the loader) with the
    /// bitangent's sign in `w`, kept only when a material is normal-mapped or anisotropic and a
    /// mesh has them (else empty); zero where a mesh has none.
    /// Those of moving placements stay in object space.
    pub tangents: Vec<Vec4>,
    /// Vertex texture coordinate sets 0 and 1; each is empty when no mesh has it, else one per
    /// vertex (zero where a mesh lacks it).
    pub uvs: [Vec<Vec2>; 2],
    /// Vertex colours (COLOR_0); empty when no mesh has them, else one per vertex.
    pub colors: Vec<Vec4>,
    /// Materials, as loaded.
    pub materials: Vec<Material>,
    /// Textures, as loaded, with mip levels where a material filters them
    /// (`material::filtered_textures`).
    pub textures: Vec<Texture>,
    /// The camera's pixel spread for texture footprints (`footprint`), where some texture has
    /// mip levels (`None`: every lookup reads the full-size texture, at no cost).
    pub spread: Option<PixelSpread>,
    /// Whether any material is alpha-tested per point (MASK with a texture or vertex colours),
    /// so that rays must ask the material before accepting a hit.
    pub alpha_tested: bool,
    /// Whether any material bounds a scattering medium, so that paths sample free flights
    /// (and each bounce takes the two sampler numbers for them).
    pub scattering_media: bool,
    /// Whether any refractive volume is dispersive, so that each path draws a number for the
    /// wavelength it takes on at its first dispersive boundary.
    pub dispersive: bool,
    /// Lights and the distribution to choose them.
    pub lights: LightSampler,
    /// What escaping rays see (also a light in `lights`), if anything.
    pub environment: Option<Arc<EnvironmentLight>>,
    /// Whether camera rays see the environment (`environment.visible`).
    pub environment_visible: bool,
    /// Maximum number of bounces.
    pub max_depth: u32,
    /// Seconds spent building the BVH (with a `BvhCache`: hashing its triangles, and building
    /// it where the cache holds none).
    pub build_seconds: f64,
    /// The light-transport algorithm the settings name, with what it prepared.
    pub transport: Transport,
    /// Light subpaths light-traced per pixel sample (`bdpt.light_paths`): the light-tracing
    /// strategy's sample count in bidirectional path tracing's MIS weights.
    pub light_paths: u32,
    /// The choice of the light a photon or a light subpath leaves, blind to any point (the power
    /// mixture), for photon mapping, and for bidirectional path tracing where `lights` chooses
    /// by the tree (`None` otherwise: `lights` is that mixture).
    pub emission: Option<PowerMixture>,
    /// The sphere holding the scene (centre, radius; what moves included): a light at infinity
    /// sends light subpaths and photons in through a disk of its radius.
    pub sphere: (Vec3, f32),
    /// The volumes each light (by index in `lights`) lies inside, for the light subpaths and
    /// photons that leave it (`bdpt::light_media`; empty where no light is inside one, or for
    /// the path tracer).
    pub light_media: Vec<MediumStack>,
    /// The emitting triangles that move within the shutter, which photons leave as well (photon
    /// mapping only; `None` where there are none).
    pub moving_emitters: Option<MovingEmitters>,
    /// The volumes the camera lies inside, where every camera path starts (air for most; found
    /// as the lights' are, from where the camera is at the frame's time, which it is taken to
    /// keep through the shutter and across a thin lens; among the volumes that stay put).
    pub camera_media: MediumStack,
}

/// The light-transport algorithm of a prepared scene (the settings' `integrator`) with what it
/// needs of the scene: one value, so that no two of them can apply at once.
#[derive(Clone, Debug)]
pub enum Transport {
    /// The path tracer, with the wavefront's tables when the scene is one the wavefront renders
    /// (`None`: every path is traced by the scalar path tracer).
    Path {
        /// What the wavefront renderer reads of the scene.
        wavefront: Option<Tables>,
    },
    /// Bidirectional path tracing.
    Bdpt,
    /// Stochastic progressive photon mapping, with its parameters.
    Sppm(SppmParams),
}

impl PreparedScene {
    /// The wavefront's tables, when the scene is rendered by the path tracer on the wavefront.
    pub fn wavefront(&self) -> Option<&Tables> {
        match &self.transport {
            Transport::Path { wavefront } => wavefront.as_ref(),
            _ => None,
        }
    }

    /// Drops the wavefront's tables: every path is then traced by the scalar path tracer (for
    /// comparisons and profiles).
    pub fn drop_wavefront(&mut self) {
        if let Transport::Path { wavefront } = &mut self.transport {
            *wavefront = None;
        }
    }
}

/// Stochastic progressive photon mapping's parameters for a prepared scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SppmParams {
    /// The first pass's gather radius in scene units.
    pub radius: f32,
    /// Photons traced per pass.
    pub photons: u32,
    /// The progressive rule's alpha.
    pub alpha: f64,
}

impl SppmParams {
    /// The settings' parameters, with the defaults resolved: one photon per pixel, and a first
    /// radius of two pixel footprints where the scene's bounding box's centre lies (the width one
    /// pixel's rays spread to at that distance, the footprint an orthographic pixel has).
    fn new(settings: &RenderSettings, camera: &Camera, accel: &Accel, scene_radius: f32) -> Self {
        let p = settings.sppm.unwrap_or_default();
        let photons = p.photons_per_pass.unwrap_or(settings.width.saturating_mul(settings.height));
        let radius = p.radius.map(|r| r as f32).unwrap_or_else(|| {
            let centre = scene_centre(accel);
            let middle = Vec2::new(camera.width, camera.height) * 0.5;
            let (a, b) = (
                camera.generate_ray(middle, Vec2::ZERO),
                camera.generate_ray(middle + Vec2::X, Vec2::ZERO),
            );
            let t = (centre - a.origin).length().max(1e-3 * scene_radius);
            let footprint =
                ((b.origin + b.dir.normalize() * t) - (a.origin + a.dir.normalize() * t)).length();
            let r = 2.0 * footprint;
            if r.is_finite() && r > 0.0 {
                r
            } else {
                1e-3 * scene_radius
            }
        });
        SppmParams { radius, photons: photons.max(1), alpha: p.alpha }
    }

    /// The gather radius of pass `pass` (0 for the first): the squared radius shrinks by
    /// (i + alpha) / (i + 1) from pass i - 1 to pass i (Knaus and Zwicker 2011's sequence, the
    /// expected shrinking of Hachisuka and Jensen's per-pixel rule), as i^(alpha - 1) in the end.
    pub fn radius(&self, pass: u32) -> f32 {
        self.radii(pass).next().expect("an endless sequence")
    }

    /// The gather radii of passes `first`, `first + 1`, ...: the same numbers as `radius`, in
    /// time O(first) for the first and O(1) for each next.
    pub fn radii(&self, first: u32) -> impl Iterator<Item = f32> + '_ {
        let mut r2 = 1.0f64;
        for i in 1..=first as u64 {
            r2 *= self.step(i);
        }
        let mut pass = first as u64;
        std::iter::from_fn(move || {
            let r = (self.radius as f64 * r2.sqrt()) as f32;
            pass += 1;
            r2 *= self.step(pass);
            Some(r)
        })
    }

    /// The squared radius's factor from pass `i - 1` to pass `i`.
    fn step(&self, i: u64) -> f64 {
        (i as f64 + self.alpha) / (i as f64 + 1.0)
    }
}

/// The centre of the scene's bounding box.
fn scene_centre(accel: &Accel) -> Vec3 {
    scene_bounds(accel).map_or(Vec3::ZERO, |(lo, hi)| 0.5 * (lo + hi))
}

/// Why a scene cannot be prepared for these settings.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct PrepareError(pub String);

/// Builds the render-ready scene. A settings environment map must be given already decoded
/// (`env_map`; see `common::envmap::EnvMap::load`): preparing does no I/O.
pub fn prepare_with_environment(
    scene: &Scene,
    settings: &RenderSettings,
    env_map: Option<&EnvMap>,
) -> Result<PreparedScene, PrepareError> {
    prepare_inner(scene, settings, env_map, None, LightChoice::Auto, None)
}

/// `prepare` with the light choice given, for comparing the two (tests and benchmarks).
pub fn prepare_with_light_choice(
    scene: &Scene,
    settings: &RenderSettings,
    choice: LightChoice,
) -> Result<PreparedScene, PrepareError> {
    prepare_inner(scene, settings, None, None, choice, None)
}

/// Builds the render-ready scene; with a shutter (seconds), placements that move are kept apart.
/// The BVH over what stands still comes from `bvh` where given (built there once for the same
/// triangles).
fn prepare_inner(
    scene: &Scene,
    settings: &RenderSettings,
    env_map: Option<&EnvMap>,
    shutter: Option<(f64, f64)>,
    choice: LightChoice,
    bvh: Option<&BvhCache>,
) -> Result<PreparedScene, PrepareError> {
    scene.check_integrator(settings).map_err(|e| PrepareError(format!("settings.{e}")))?;
    // A material variant is part of the settings: the meshes it maps take its materials.
    let varied;
    let scene = match &settings.variant {
        Some(name) => {
            let mut s = scene.clone();
            s.apply_variant(name).map_err(|e| PrepareError(format!("settings.{e}")))?;
            varied = s;
            &varied
        }
        None => scene,
    };
    let camera_model = match &settings.camera {
        Some(name) => scene
            .cameras
            .iter()
            .find(|c| &c.name == name)
            .ok_or_else(|| PrepareError(format!("settings.camera: no camera named `{name}`")))?,
        None => {
            scene.cameras.first().ok_or_else(|| PrepareError("scene has no camera".to_string()))?
        }
    };
    scene.check_lens(settings).map_err(|e| PrepareError(format!("settings: {e}")))?;
    let camera_node = camera_model.node;
    let origin = camera_model.position();
    let to_world = {
        let m = DMat3::from_mat4(camera_model.transform);
        Mat3::from_cols(
            m.x_axis.normalize().as_vec3(),
            m.y_axis.normalize().as_vec3(),
            m.z_axis.normalize().as_vec3(),
        )
    };
    let model = match camera_model.projection {
        Projection::Perspective { yfov } => {
            CameraModel::Perspective { tan_half_fov: (0.5 * yfov).tan() }
        }
        Projection::Orthographic { ymag, .. } => CameraModel::Orthographic { ymag },
    };
    let camera = Camera {
        to_world,
        model,
        width: settings.width as f32,
        height: settings.height as f32,
        aperture_radius: settings.lens.aperture_radius as f32,
        focus_distance: settings.lens.focus_distance as f32,
    };

    let to_relative = DMat4::from_translation(-origin);
    let mut triangles: Vec<[Vec3; 3]> = Vec::with_capacity(scene.triangle_count());
    let mut shading: Vec<TriShading> = Vec::with_capacity(scene.triangle_count());
    let mut normals: Vec<Vec3> = Vec::new();
    // Tangents orient normal maps (the clear coat's too) and anisotropy.
    let oriented = |m: &Material| m.tangent_uv_set().is_some();
    let keep_tangents =
        scene.materials.iter().any(oriented) && scene.meshes.iter().any(|m| m.tangents.is_some());
    let mut tangents: Vec<Vec4> = Vec::new();
    let has_uvs = [0, 1].map(|k| scene.meshes.iter().any(|m| m.uvs[k].is_some()));
    let has_colors = scene.meshes.iter().any(|m| m.colors.is_some());
    let mut uvs: [Vec<Vec2>; 2] = [Vec::new(), Vec::new()];
    let mut colors: Vec<Vec4> = Vec::new();
    // With a shutter, placements that move or deform are kept apart (object space, see
    // `motion`).
    let deforms = |inst: &Instance| {
        let mesh = &scene.meshes[inst.mesh];
        let anim = scene.animation.as_ref();
        mesh.deform.as_ref().is_some_and(|d| anim.is_some_and(|a| d.animated(a)))
    };
    let moves =
        |inst: &Instance| shutter.is_some() && (scene.instance_moves(inst) || deforms(inst));
    let mut moving = Vec::new();
    // Which placement of which mesh each static triangle comes from: an emitter, for the light
    // choice (`LightSampler`).
    let mut emitter_of: Vec<u32> = Vec::with_capacity(scene.triangle_count());
    for (placement, inst) in scene.instances.iter().enumerate() {
        let mesh = &scene.meshes[inst.mesh];
        let material = &scene.materials[mesh.material];
        let invisible = match material.alpha_mode {
            AlphaMode::Mask { cutoff } => material.base_color.w < cutoff,
            AlphaMode::Blend => material.base_color.w <= 0.0,
            AlphaMode::Opaque => false,
        };
        if invisible && material.base_color_texture.is_none() {
            continue; // Entirely cut out (a vertex colour only scales alpha down).
        }
        if moves(inst) {
            moving.push(inst);
            continue;
        }
        let m = to_relative * inst.transform;
        let normal_m = DMat3::from_mat4(m).inverse().transpose();
        let flip = m.determinant() < 0.0;
        let base = normals.len() as u32;
        let world: Vec<Vec3> =
            mesh.positions.iter().map(|p| m.transform_point3(p.as_dvec3()).as_vec3()).collect();
        match &mesh.normals {
            Some(ns) => normals
                .extend(ns.iter().map(|n| (normal_m * n.as_dvec3()).normalize_or_zero().as_vec3())),
            None => normals.extend(std::iter::repeat_n(Vec3::ZERO, world.len())),
        }
        if keep_tangents {
            let linear = DMat3::from_mat4(m);
            let sign = if flip { -1.0 } else { 1.0 };
            match &mesh.tangents {
                Some(ts) => tangents.extend(ts.iter().map(|t| {
                    let v = (linear * t.truncate().as_dvec3()).normalize_or_zero().as_vec3();
                    v.extend(t.w * sign)
                })),
                None => tangents.extend(std::iter::repeat_n(Vec4::ZERO, world.len())),
            }
        }
        for k in 0..2 {
            if has_uvs[k] {
                match &mesh.uvs[k] {
                    Some(t) => uvs[k].extend_from_slice(t),
                    None => uvs[k].extend(std::iter::repeat_n(Vec2::ZERO, world.len())),
                }
            }
        }
        if has_colors {
            match &mesh.colors {
                Some(c) => colors.extend_from_slice(c),
                None => colors.extend(std::iter::repeat_n(Vec4::ONE, world.len())),
            }
        }
        for &[a, b, c] in &mesh.indices {
            let [a, b, c] = if flip { [a, c, b] } else { [a, b, c] };
            triangles.push([world[a as usize], world[b as usize], world[c as usize]]);
            emitter_of.push(placement as u32);
            shading.push(TriShading {
                vertices: [base + a, base + b, base + c],
                material: mesh.material as u32,
                light: NONE,
                smooth: mesh.normals.is_some(),
                extended: scene.materials[mesh.material].extended(),
            });
        }
    }

    let start = Instant::now();
    let (accel, order) = match bvh {
        Some(cache) => cache.get_or_build(&triangles),
        None => bvh_cache::build(&triangles),
    };
    let build_seconds = start.elapsed().as_secs_f64();
    drop(triangles);
    let mut shading: Vec<TriShading> = order.iter().map(|&i| shading[i as usize]).collect();

    let mut lights = Vec::new();
    // The emitter of each light: a placement of a mesh for emissive triangles, then one each.
    let mut emitters = Vec::new();
    // Mean emission of textured emitters, for choosing lights by power (computed once).
    let mut texture_means: Vec<Option<Vec4>> = vec![None; scene.textures.len()];
    for (prim, tri) in shading.iter_mut().enumerate() {
        let material = &scene.materials[tri.material as usize];
        if material.emissive.max_element() > 0.0 && !material.unlit {
            let p = accel.triangle(prim as u32);
            let (emission, textured) = match &material.emissive_texture {
                Some(r) => {
                    let mean = *texture_means[r.texture].get_or_insert_with(|| {
                        super::texture::mean(&scene.textures[r.texture], true)
                    });
                    (material.emissive * mean.truncate(), true)
                }
                None => (material.emissive, false),
            };
            if let Some(mut light) = TriangleLight::new(p, emission, material.double_sided) {
                light.prim = prim as u32;
                light.textured = textured || material.clearcoat.is_some();
                tri.light = lights.len() as u32;
                lights.push(Light::Triangle(light));
                emitters.push(emitter_of[order[prim] as usize]);
            }
        }
    }
    for l in &scene.lights {
        let position = (l.position - origin).as_vec3();
        let direction = l.direction.normalize().as_vec3();
        lights.push(match l.kind {
            PunctualKind::Point => Light::Point(PointLight { position, intensity: l.intensity }),
            PunctualKind::Spot { inner_cone, outer_cone } => Light::Spot(SpotLight {
                position,
                direction,
                intensity: l.intensity,
                cos_inner: inner_cone.cos(),
                cos_outer: outer_cone.cos(),
            }),
            PunctualKind::Directional => Light::Directional(DirectionalLight {
                to_light: -direction,
                irradiance: l.intensity,
            }),
        });
    }
    let (environment, environment_visible) = match &settings.environment {
        None => (None, true),
        Some(Environment::Color { color }) => {
            let radiance = Vec3::from_array(*color);
            ((radiance.max_element() > 0.0).then_some(EnvironmentLight::Uniform(radiance)), true)
        }
        Some(Environment::Map { map, intensity, rotation_deg, visible }) => {
            let decoded = env_map.ok_or_else(|| {
                PrepareError(format!("settings.environment: the map `{map}` was not loaded"))
            })?;
            let prepared = MapEnvironment::new(decoded, *intensity, *rotation_deg);
            ((prepared.mean_luminance() > 0.0).then_some(EnvironmentLight::Map(prepared)), *visible)
        }
    };
    let environment = environment.map(Arc::new);
    if let Some(env) = &environment {
        lights.push(Light::Environment(Arc::clone(env)));
    }
    let placements = scene.instances.len() as u32;
    emitters.extend((placements..).take(lights.len() - emitters.len()));
    let motion = match (shutter, &scene.animation) {
        (Some(shutter), Some(anim)) => {
            let anim = Arc::new(anim.clone());
            let mut instances = Vec::new();
            for inst in moving {
                let mesh = &scene.meshes[inst.mesh];
                let base = normals.len() as u32;
                let n = mesh.positions.len();
                match &mesh.normals {
                    Some(ns) => normals.extend_from_slice(ns),
                    None => normals.extend(std::iter::repeat_n(Vec3::ZERO, n)),
                }
                if keep_tangents {
                    match &mesh.tangents {
                        Some(ts) => tangents.extend_from_slice(ts),
                        None => tangents.extend(std::iter::repeat_n(Vec4::ZERO, n)),
                    }
                }
                for k in 0..2 {
                    if has_uvs[k] {
                        match &mesh.uvs[k] {
                            Some(t) => uvs[k].extend_from_slice(t),
                            None => uvs[k].extend(std::iter::repeat_n(Vec2::ZERO, n)),
                        }
                    }
                }
                if has_colors {
                    match &mesh.colors {
                        Some(c) => colors.extend_from_slice(c),
                        None => colors.extend(std::iter::repeat_n(Vec4::ONE, n)),
                    }
                }
                let flip = inst.transform.determinant() < 0.0;
                let triangles_of = |positions: &[Vec3]| -> Vec<[Vec3; 3]> {
                    let corners = |&[a, b, c]: &[u32; 3]| {
                        let [a, b, c] = if flip { [a, c, b] } else { [a, b, c] };
                        [a, b, c].map(|v| positions[v as usize])
                    };
                    mesh.indices.iter().map(corners).collect()
                };
                let place = if scene.instance_moves(inst) {
                    Place::Node { node: inst.node, offset: inst.offset }
                } else {
                    Place::Fixed(to_relative * inst.transform)
                };
                // The box of the mesh over the shutter (every key of a deforming one).
                let (mut lo, mut hi) =
                    (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
                let (shape, order) = if deforms(inst) {
                    let keys = deform_keys(mesh, &anim, shutter);
                    for p in keys.iter().flat_map(|(_, k)| &k.positions) {
                        (lo, hi) = (lo.min(p.as_dvec3()), hi.max(p.as_dvec3()));
                    }
                    let tris: Vec<Vec<[Vec3; 3]>> =
                        keys.iter().map(|(_, k)| triangles_of(&k.positions)).collect();
                    let (accel, order) = KeyedAccel::build(&tris);
                    drop(tris);
                    let (times, posed): (Vec<f64>, Vec<common::scene::Mesh>) =
                        keys.into_iter().unzip();
                    let deforming = Deforming {
                        accel,
                        times,
                        normals: posed.iter().filter_map(|k| k.normals.clone()).collect(),
                        tangents: if keep_tangents {
                            posed.into_iter().filter_map(|k| k.tangents).collect()
                        } else {
                            Vec::new()
                        },
                        vertex_base: base,
                    };
                    (Shape::Deforming(deforming), order)
                } else {
                    for p in &mesh.positions {
                        (lo, hi) = (lo.min(p.as_dvec3()), hi.max(p.as_dvec3()));
                    }
                    let (accel, order) = Accel::build(&triangles_of(&mesh.positions));
                    (Shape::Rigid(accel), order)
                };
                let prim_base = shading.len() as u32;
                let emits = scene.materials[mesh.material].emissive.max_element() > 0.0
                    && !scene.materials[mesh.material].unlit;
                for &o in &order {
                    let [a, b, c] = mesh.indices[o as usize];
                    let [a, b, c] = if flip { [a, c, b] } else { [a, b, c] };
                    shading.push(TriShading {
                        vertices: [base + a, base + b, base + c],
                        material: mesh.material as u32,
                        light: if emits { UNSAMPLED } else { NONE },
                        smooth: mesh.normals.is_some(),
                        extended: scene.materials[mesh.material].extended(),
                    });
                }
                let corners = std::array::from_fn(|k| {
                    DVec3::new(
                        if k & 1 == 0 { lo.x } else { hi.x },
                        if k & 2 == 0 { lo.y } else { hi.y },
                        if k & 4 == 0 { lo.z } else { hi.z },
                    )
                });
                let bounds = match place {
                    Place::Node { node, offset } => Motion::bound(&anim, shutter, &corners, |t| {
                        to_relative * anim.world(node, t) * offset
                    }),
                    Place::Fixed(m) => {
                        Motion::bound(&anim, (shutter.0, shutter.0), &corners, |_| m)
                    }
                };
                instances.push(MotionInstance { place, shape, prim_base, bounds });
            }
            let moving_camera = camera_node.filter(|&n| anim.moves(n));
            let camera = moving_camera.map(|n| (n, Camera { to_world: Mat3::IDENTITY, ..camera }));
            (!instances.is_empty() || camera.is_some()).then(|| Motion {
                anim,
                origin,
                shutter,
                instances,
                camera,
            })
        }
        _ => None,
    };
    let bounds = scene_bounds(&accel);
    let mut scene_radius = bounds.map_or(1.0, |(lo, hi)| 0.5 * (hi - lo).length()).max(1e-6);
    if let Some(m) = &motion {
        for inst in &m.instances {
            let (lo, hi) = inst.bounds;
            scene_radius = scene_radius.max(lo.abs().max(hi.abs()).length());
        }
    }
    // The sphere holding the scene, what moves over the whole shutter included.
    let sphere = {
        let moving = motion.iter().flat_map(|m| m.instances.iter().map(|i| i.bounds));
        let (lo, hi) = bounds.into_iter().chain(moving).fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), (a, b)| (lo.min(a), hi.max(b)),
        );
        if lo.x <= hi.x {
            (0.5 * (lo + hi), (0.5 * (hi - lo).length()).max(1e-6))
        } else {
            (Vec3::ZERO, 1.0)
        }
    };
    let varies = |m: &Material| m.base_color_texture.is_some() || has_colors;
    let alpha_tested = scene.materials.iter().any(|m| match m.alpha_mode {
        AlphaMode::Mask { .. } => varies(m),
        AlphaMode::Blend => m.base_color.w < 1.0 || varies(m),
        AlphaMode::Opaque => false,
    });
    let transport = match settings.integrator {
        Integrator::Path => Transport::Path { wavefront: None },
        Integrator::Bdpt => Transport::Bdpt,
        Integrator::Sppm => {
            Transport::Sppm(SppmParams::new(settings, &camera, &accel, scene_radius))
        }
    };
    let sppm = matches!(transport, Transport::Sppm(_));
    let bdpt = matches!(transport, Transport::Bdpt);
    let lights = LightSampler::with_choice(lights, &emitters, scene_radius, choice);
    // Light subpaths and photons leave a light chosen blind to any point (the power mixture);
    // light samples from a shaded point choose as the path tracer does (by the tree, in scenes
    // of many emitters). Bidirectional path tracing needs the mixture only where the two differ.
    let emission = (sppm || (bdpt && lights.uses_tree()))
        .then(|| PowerMixture::new(&lights.lights, &emitters, scene_radius));
    let dispersive = scene.materials.iter().any(|m| m.refracts() && m.dispersion > 0.0);
    let scattering_media = scene.materials.iter().any(scatters);
    let transport = match transport {
        Transport::Path { .. } => {
            // What the wavefront's paths cannot meet: motion changes what a ray hits, and
            // dispersion and scattering media change the numbers a path draws from its start.
            let scalar_only = if motion.is_some() {
                Some("something moves within the shutter")
            } else if dispersive {
                Some("a dispersive material")
            } else if scattering_media {
                Some("a scattering medium")
            } else {
                None
            };
            // With vertex colours every material varies over its surfaces, like a textured one.
            let tables = Tables::new(
                &scene.materials,
                &scene.textures,
                &lights,
                scalar_only,
                !colors.is_empty(),
                (alpha_tested, &|prim| shading[prim as usize].material as usize),
            );
            // Once per prepared scene: which kernel renders it, and why.
            match &tables {
                Err(why) => tracing::info!("the path tracer runs scalar on this scene: {why}"),
                Ok(_) => {}
            }
            Transport::Path { wavefront: tables.ok() }
        }
        other => other,
    };
    let mut textures = scene.textures.clone();
    let mut uses = Vec::new();
    for m in &scene.materials {
        material::filtered_textures(m, |t, d| uses.push((t, d)));
    }
    let filtered = super::texture::add_levels(&mut textures, uses);
    let spread = filtered.then(|| PixelSpread::new(&camera, settings.spp));
    let mut prepared = PreparedScene {
        origin,
        camera,
        accel,
        shading,
        normals,
        tangents,
        uvs,
        colors,
        materials: scene.materials.clone(),
        textures,
        spread,
        alpha_tested,
        dispersive,
        scattering_media,
        lights,
        environment,
        environment_visible,
        max_depth: settings.max_depth,
        build_seconds,
        motion,
        transport,
        light_paths: settings.light_paths(),
        emission,
        sphere,
        light_media: Vec::new(),
        camera_media: MediumStack::default(),
        moving_emitters: None,
    };
    if sppm {
        prepared.moving_emitters = MovingEmitters::new(&prepared, scene_radius);
    }
    if prepared.materials.iter().any(|m| m.bounds_medium()) {
        if bdpt || sppm {
            prepared.light_media = light_media(&prepared);
        }
        // The camera sits at the origin of the camera-relative world (an orthographic camera's
        // rays start across its film plane: taken to lie in the same volumes as its centre).
        prepared.camera_media = media_at(&prepared, Vec3::ZERO, askew(), NONE, None);
    }
    Ok(prepared)
}

/// Whether a material bounds a medium that scatters light.
fn scatters(m: &Material) -> bool {
    m.bounds_medium() && m.volume.is_some_and(|v| v.scatters())
}

/// Most surfaces `media_at` passes from a point to infinity (past them, it warns and takes the
/// volumes crossed so far).
const MAX_MEDIA_HITS: usize = 4096;

/// The volumes each light of the scene lies inside (by index in `scene.lights`; `media_at` from
/// a triangle's centroid along its normal, from a point or spot light's position; lights at
/// infinity are in air), empty where every light is in air. Taken at the scene's rest pose:
/// a light that moves within the shutter is taken to stay in the volumes it starts in.
fn light_media(scene: &PreparedScene) -> Vec<MediumStack> {
    let media: Vec<MediumStack> = scene
        .lights
        .lights
        .iter()
        .map(|light| match light.placed() {
            Some((p, facing)) => {
                let prim = light.on_surface().map_or(NONE, |l| l.prim);
                media_at(scene, p, facing.unwrap_or_else(askew), prim, None)
            }
            None => MediumStack::default(),
        })
        .collect();
    if media.iter().all(|m| m.current().is_none()) {
        return Vec::new();
    }
    media
}

/// A direction askew to the axes, so as not to pass along a box's edges.
fn askew() -> Vec3 {
    Vec3::new(0.31, 0.87, 0.38).normalize()
}

/// The volumes point `p` lies inside: the boundaries a ray from it along `dir` crosses on its way
/// out of the scene (triangle `skip`, the light's own, left out), crossed backwards from air, as
/// a subpath that came in from outside would have crossed them (the outermost entered first).
/// What moves within the shutter is met where `pose` places it, and not at all without one.
fn media_at(
    scene: &PreparedScene,
    p: Vec3,
    dir: Vec3,
    skip: u32,
    pose: Option<&Pose<'_>>,
) -> MediumStack {
    let mut crossed = Vec::new();
    let mut ray = Ray::new(p, dir);
    let mut passed = 0;
    while let Some(hit) = scene.intersect(&ray, f32::INFINITY, pose) {
        passed += 1;
        if passed > MAX_MEDIA_HITS {
            tracing::warn!(
                "the volumes a light or the camera lies in: more than {MAX_MEDIA_HITS} surfaces \
                 on the way out of the scene; taking the {} volume boundaries crossed before them",
                crossed.len()
            );
            break;
        }
        let ([p0, p1, p2], _) = scene.triangle(hit.prim, pose);
        let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
        let q = p0 * b[0] + p1 * b[1] + p2 * b[2];
        let normal = (p1 - p0).cross(p2 - p0).try_normalize();
        let tri = scene.shading[hit.prim as usize];
        let material = &scene.materials[tri.material as usize];
        let boundary = tri.extended && material.volume.is_some() && material.bounds_medium();
        if let (Some(winding), true) = (normal, boundary && hit.prim != skip) {
            crossed.push((tri.material, winding.dot(dir) < 0.0));
        }
        // Past the surface, on the ray's side beyond it (along the ray for a degenerate one).
        let side = normal.map_or(dir, |n| if n.dot(dir) > 0.0 { n } else { -n });
        ray = Ray::new(offset_ray_origin(q, interpolation_error([p0, p1, p2], b), side, dir), dir);
    }
    let mut media = MediumStack::default();
    for &(m, front) in crossed.iter().rev() {
        media.cross(m, !front);
    }
    media
}

/// Prepares frame `frame` of a scene: a static scene once for all frames; an animated one posed at
/// the frame's time, with what moves or deforms inside a non-empty shutter kept apart for motion
/// blur.
pub fn prepare_frame(
    scene: &Scene,
    settings: &RenderSettings,
    env_map: Option<&EnvMap>,
    frame: i64,
) -> Result<PreparedScene, PrepareError> {
    prepare_frame_in(scene, settings, env_map, frame, None)
}

/// `prepare_frame` with the BVH of the geometry that stands still taken from `bvh`, or built
/// there and kept: the same preparation bit for bit, its BVH built once for every job and
/// frame whose triangles are the same.
pub fn prepare_frame_cached(
    scene: &Scene,
    settings: &RenderSettings,
    env_map: Option<&EnvMap>,
    frame: i64,
    bvh: &BvhCache,
) -> Result<PreparedScene, PrepareError> {
    prepare_frame_in(scene, settings, env_map, frame, Some(bvh))
}

fn prepare_frame_in(
    scene: &Scene,
    settings: &RenderSettings,
    env_map: Option<&EnvMap>,
    frame: i64,
    bvh: Option<&BvhCache>,
) -> Result<PreparedScene, PrepareError> {
    if !scene.is_animated() {
        return prepare_inner(scene, settings, env_map, None, LightChoice::Auto, bvh);
    }
    let mut posed = scene.clone();
    posed.set_time(settings.frame_time(frame));
    let (open, close) = (settings.shutter.open, settings.shutter.close);
    let shutter = (open < close).then(|| {
        let f = frame as f64;
        ((f + open) / settings.frames.fps, (f + close) / settings.frames.fps)
    });
    prepare_inner(&posed, settings, env_map, shutter, LightChoice::Auto, bvh)
}

/// Builds the render-ready scene for settings without an environment map.
pub fn prepare(scene: &Scene, settings: &RenderSettings) -> Result<PreparedScene, PrepareError> {
    prepare_with_environment(scene, settings, None)
}

impl PreparedScene {
    /// Bytes of geometry the renderer keeps per scene: BVH, triangles, shading data, vertices.
    pub fn memory_bytes(&self) -> usize {
        self.memory_parts().iter().map(|(_, bytes)| bytes).sum()
    }

    /// `memory_bytes` by structure (the BVH's parts, then the shading data and each vertex
    /// attribute).
    pub fn memory_parts(&self) -> Vec<(&'static str, usize)> {
        let mut parts = self.accel.memory_parts().to_vec();
        parts.extend([
            ("shading of each triangle", self.shading.len() * std::mem::size_of::<TriShading>()),
            ("normals", self.normals.len() * std::mem::size_of::<Vec3>()),
            ("tangents", self.tangents.len() * std::mem::size_of::<Vec4>()),
            (
                "texture coordinates",
                (self.uvs[0].len() + self.uvs[1].len()) * std::mem::size_of::<Vec2>(),
            ),
            ("vertex colours", self.colors.len() * std::mem::size_of::<Vec4>()),
        ]);
        parts
    }
}

impl PreparedScene {
    /// Texture coordinates and vertex colour of triangle `prim` at barycentrics `b`.
    #[inline]
    pub fn surface_point(&self, prim: u32, b: [f32; 3]) -> SurfacePoint {
        let tri = &self.shading[prim as usize];
        let [i0, i1, i2] = tri.vertices.map(|v| v as usize);
        let mut sp = SurfacePoint::PLAIN;
        for k in 0..2 {
            if let Some(uv) = self.uvs.get(k).filter(|uv| !uv.is_empty()) {
                sp.uvs[k] = uv[i0] * b[0] + uv[i1] * b[1] + uv[i2] * b[2];
            }
        }
        if !self.colors.is_empty() {
            sp.color = self.colors[i0] * b[0] + self.colors[i1] * b[1] + self.colors[i2] * b[2];
        }
        sp
    }

    /// The point of triangle `prim` (its corners at the pose's time, barycentrics `b`) as a
    /// material sees it: `surface_point`, with the footprint of each texture coordinate set
    /// where some texture has mip levels.
    #[inline]
    pub fn shading_point(&self, prim: u32, corners: [Vec3; 3], b: [f32; 3]) -> SurfacePoint {
        let mut sp = self.surface_point(prim, b);
        if let Some(spread) = &self.spread {
            sp.footprint = self.footprint(spread, prim, corners, b);
        }
        sp
    }

    /// The width in each texture coordinate set that a texture filter covers at a point of
    /// triangle `prim`: the largest of du/dx, dv/dx, du/dy and dv/dy, with dp/dx and dp/dy from
    /// the camera (`PixelSpread`) and the gradients of u and v over the triangle's plane; 0 for
    /// a degenerate triangle or a set the scene lacks. pbrt-v4 takes twice that: on
    /// DamagedHelmet at 128 x 128 under a map, this width has 30% less relative MSE against
    /// Cycles' converged image than twice it at 16 samples per pixel, and no more at 64 or 256
    /// (docs/perf/kernel.md).
    fn footprint(
        &self,
        spread: &PixelSpread,
        prim: u32,
        [q0, q1, q2]: [Vec3; 3],
        b: [f32; 3],
    ) -> [f32; 2] {
        let (e1, e2) = (q1 - q0, q2 - q0);
        let n = e1.cross(e2);
        let area2 = n.length_squared();
        if !(area2 > 0.0 && area2.is_finite()) {
            return [0.0; 2];
        }
        let p = q0 * b[0] + q1 * b[1] + q2 * b[2];
        let [dpdx, dpdy] = spread.dp(p, n);
        // The dual basis of (e1, e2) in the plane: g1.e1 = g2.e2 = 1, g1.e2 = g2.e1 = 0.
        let (g1, g2) = (e2.cross(n) / area2, n.cross(e1) / area2);
        let [i0, i1, i2] = self.shading[prim as usize].vertices.map(|v| v as usize);
        std::array::from_fn(|k| {
            let uv = &self.uvs[k];
            if uv.is_empty() {
                return 0.0;
            }
            let (d1, d2) = (uv[i1] - uv[i0], uv[i2] - uv[i0]);
            let (du, dv) = (g1 * d1.x + g2 * d2.x, g1 * d1.y + g2 * d2.y);
            let widest = du.dot(dpdx).abs().max(dv.dot(dpdx).abs());
            widest.max(du.dot(dpdy).abs()).max(dv.dot(dpdy).abs())
        })
    }

    /// The closest hit before `t_max`: the static BVH, then what moves (at the pose's time).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32, pose: Option<&Pose<'_>>) -> Option<Hit> {
        let accept = |h: &Hit| !self.is_cut_out(h, ray);
        let best = if self.alpha_tested {
            self.accel.intersect_filtered(ray, t_max, accept)
        } else {
            self.accel.intersect(ray, t_max)
        };
        let Some(pose) = pose else { return best };
        let all = |_: &Hit| true;
        let filter: &dyn Fn(&Hit) -> bool = if self.alpha_tested { &accept } else { &all };
        pose.intersect(ray, best.map_or(t_max, |h| h.t), filter).or(best)
    }

    /// Whether anything blocks the ray before `t_max`.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32, pose: Option<&Pose<'_>>) -> bool {
        let accept = |h: &Hit| !self.is_cut_out(h, ray);
        let blocked = if self.alpha_tested {
            self.accel.occluded_filtered(ray, t_max, accept)
        } else {
            self.accel.occluded(ray, t_max)
        };
        blocked
            || pose.is_some_and(|pose| {
                let all = |_: &Hit| true;
                let filter: &dyn Fn(&Hit) -> bool = if self.alpha_tested { &accept } else { &all };
                pose.occluded(ray, t_max, filter)
            })
    }

    /// A triangle's camera-relative world positions (at the pose's time if it moves), and
    /// whether it moves.
    #[inline]
    pub fn triangle(&self, prim: u32, pose: Option<&Pose<'_>>) -> ([Vec3; 3], bool) {
        if let Some((i, local)) = pose.and_then(|p| p.locate(prim)) {
            return (pose.expect("located").triangle(i, local), true);
        }
        (self.accel.triangle(prim), false)
    }

    /// A vertex tangent of triangle `prim` with the bitangent's sign in `w` (world space, at the
    /// pose's time if it moves); only when `tangents` is not empty.
    #[inline]
    pub fn vertex_tangent(&self, vertex: u32, prim: u32, pose: Option<&Pose<'_>>) -> Vec4 {
        let t = self.tangents[vertex as usize];
        match pose.and_then(|p| p.locate(prim)) {
            Some((i, _)) => pose.expect("located").tangent(i, vertex, t),
            None => t,
        }
    }

    /// A vertex normal of triangle `prim` (world space, at the pose's time if it moves).
    #[inline]
    pub fn vertex_normal(&self, vertex: u32, prim: u32, pose: Option<&Pose<'_>>) -> Vec3 {
        let n = self.normals[vertex as usize];
        match pose.and_then(|p| p.locate(prim)) {
            Some((i, _)) => pose.expect("located").normal(i, vertex, n),
            None => n,
        }
    }

    /// Whether `ray` passes through the surface at `hit`: always where a MASK material is cut
    /// out, with probability 1 - alpha on a BLEND material. The decision is a hash of the ray and
    /// the triangle, so it is the same every time this ray meets this triangle and, like every
    /// number of a sample, depends only on the sample.
    #[inline]
    pub fn is_cut_out(&self, hit: &super::accel::Hit, ray: &Ray) -> bool {
        let coverage = self.coverage(hit.prim, [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2]);
        coverage < 1.0 && coverage <= coverage_number(ray, hit.prim)
    }

    /// The probability that the surface of triangle `prim` is there at barycentrics `b`.
    #[inline]
    pub fn coverage(&self, prim: u32, b: [f32; 3]) -> f32 {
        let m = &self.materials[self.shading[prim as usize].material as usize];
        if m.alpha_mode == AlphaMode::Opaque {
            return 1.0;
        }
        material::coverage(&self.textures, m, &self.surface_point(prim, b))
    }
}

/// A uniform number in [0, 1) from a ray and a triangle (the stochastic coverage of BLEND).
#[inline]
fn coverage_number(ray: &Ray, prim: u32) -> f32 {
    let o = ray.origin.to_array().map(f32::to_bits);
    let d = ray.dir.to_array().map(f32::to_bits);
    let mut h = mix64((((o[0] as u64) << 32) | o[1] as u64) ^ 0x243f_6a88_85a3_08d3);
    h = mix64(h ^ (((o[2] as u64) << 32) | d[0] as u64));
    h = mix64(h ^ (((d[1] as u64) << 32) | d[2] as u64));
    to_unit((mix64(h ^ prim as u64) >> 32) as u32)
}

/// The scene's bounding box (`None` without triangles).
fn scene_bounds(accel: &Accel) -> Option<(Vec3, Vec3)> {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for i in 0..accel.len() as u32 {
        for p in accel.triangle(i) {
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    (lo.x <= hi.x).then_some((lo, hi))
}
