//! Bidirectional path tracing (Veach 1997; the structure of pbrt-v4's `bdpt`): a camera subpath
//! and a light subpath per sample, every connection of a prefix of one with a prefix of the other
//! weighted by multiple importance sampling (the balance heuristic over all the ways of making
//! the same path).
//!
//! The strategies are split between two kinds of farm task, so that each stays a tile of one
//! frame's film. A camera task (a tile x sample range, like the path tracer's) sums, for each
//! sample of its pixels, the strategies with at least two camera vertices: the camera subpath
//! hitting a light (s = 0), a light sampled from a camera vertex (s = 1) and the connections of
//! both subpaths (s, t >= 2). A light task (the whole frame x a sample range) traces, for each
//! sample index, a light subpath per pixel and connects each of its vertices to the camera
//! (t = 1, light tracing): the contribution lands on whatever pixel the connection passes
//! through, and the sum over the frame's light subpaths of one sample index is that sample of
//! the light-traced image. The two films add. A camera task's light subpath is a function of
//! (pixel, sample index) alone (its sampler dimensions start at `LIGHT_DIMENSION`); a light
//! task's starts from a frame-wide sequence (`light_film`) and is not the same one: each
//! strategy is unbiased on its own, whatever subpaths the others draw.
//!
//! Path vertices follow pbrt: `beta` is the throughput arriving at the vertex, `pdf_fwd` the
//! density (per unit area, or per solid angle for a vertex at infinity) of the vertex being
//! sampled by its own subpath, `pdf_rev` of it being sampled from the other end. The BSDF is
//! evaluated for light flowing along the path (radiance order), whichever subpath the vertex is
//! on, so that BSDFs that are not symmetric need no adjoint (only a sampled smooth refraction,
//! whose value comes from the sample, is corrected, see Volumes); a light subpath's throughput
//! takes the shading-normal correction of Veach's thesis (5.3.2).
//!
//! Motion blur: a sample's time is drawn as the path tracer draws it (after the film and lens
//! numbers) and both its subpaths and every connection see the scene and the camera at that
//! time (`At`); the light task draws the same number for the same sample. An emitter that moves
//! is not in the light list (as in the path tracer), so only the camera subpath hitting it
//! (s = 0) finds it, with weight 1.
//!
//! Lights at infinity (the environment, directional lights) follow pbrt: a light subpath leaves
//! one through a disk of the scene's radius across its direction (density per unit area of the
//! disk), a camera subpath that leaves the scene ends on a vertex of the environment (density
//! per solid angle), and the light's density as a subpath's origin is its direction's.
//!
//! Volumes: subpaths cross boundaries and lose light to absorption as the path tracer's paths
//! do (`surface_vertex`), connections carry the transmittance of the medium they run through
//! (`segment_transmittance`), and a light subpath refracting through a smooth boundary carries
//! flux, not radiance (pbrt-v4's importance transport: no 1 / eta²). A camera subpath starts in
//! the volumes the camera lies inside (`PreparedScene::camera_media`) and a light subpath (and a
//! photon) in those its light lies inside (`PreparedScene::light_media`), each found once per
//! scene by the boundaries a ray from it crosses on its way out.
//!
//! Dispersion: a sample draws one wavelength (after its time) that every dispersive boundary of
//! both subpaths bends light by (`At::wavelength`), so that a connection joins two halves of
//! one path of that light; a path through any dispersive vertex, on either subpath, takes that
//! light's colour once (`At::tint`; the path tracer's path takes it at its first), and the MIS
//! densities, all taken at the one wavelength, stay a partition of unity for it.
//!
//! Scattering media: a subpath inside one samples free flights as the path tracer's paths do,
//! by one channel's exponential (the sample's hero, shared by both subpaths) weighted by the
//! three channels' densities (`media::free_flight`), and a connection of two subpaths weighs its
//! light by the densities of the whole path (`spectral_weight`). A scattering is a vertex that
//! samples its phase function exactly and, like a mirror, ends no connection (the path tracer
//! samples no light from one either: the medium's boundary stops shadow rays), so the MIS weights
//! leave out the strategies that would join there; connections between surfaces inside a medium
//! carry its transmittance.
//!
//! Determinism: a camera task's light subpath draws the pixel sample's own numbers from
//! `LIGHT_DIMENSION` on; a light task's light subpaths start from a frame-wide sequence
//! (`frame_start`, `leave_still_light`, as photons do) and walk on by the pixel sample's numbers.
//! A light task renders each sample index's film on one thread and adds the films in sample
//! order, so its sums do not depend on the threads.

use common::{film::TileAccum, protocol::TaskSpec};
use glam::{UVec2, Vec2, Vec3};

use super::{
    super::{
        bsdf::{Bsdf, Dielectric},
        camera::PlacedCamera,
        geometry::{offset_ray_origin, Frame, Ray},
        light::{ChooseLight, Light, ShadingContext},
        material,
        media::{self, transmittance, MediumStack},
        motion::Pose,
        sampler::{Sampler, FRAME_DIMENSIONS},
        sampling::sample_henyey_greenstein,
        scene::{PreparedScene, NONE, UNSAMPLED},
        spectrum,
    },
    shared::{
        hit_error, light_radiance, meet_surface, roulette, same_side, shading_frame, surface_bsdf,
        surface_emission, Meeting, Stats, SHADOW_T_MAX,
    },
};

/// The sampler dimension a light subpath starts at (the camera subpath's come first and never
/// reach it: each bounce takes 7, and 8 in a scene with scattering media).
pub const LIGHT_DIMENSION: u32 = 1 << 16;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Kind {
    Camera,
    Light,
    Surface,
    /// A scattering inside a medium (no surface, no BSDF: see Scattering media).
    Medium,
}

/// A vertex of a subpath.
#[derive(Clone, Copy, Debug)]
pub(super) struct Vertex {
    pub(super) kind: Kind,
    pub(super) p: Vec3,
    pub(super) p_error: Vec3,
    /// Geometric normal: a surface's on the side it was reached from, an area light's front
    /// face's; zero for the camera and point lights (not on a surface).
    pub(super) ng: Vec3,
    /// Shading frame (surfaces), +z on `ng`'s side.
    pub(super) frame: Frame,
    /// The BSDF (surfaces that scatter).
    pub(super) bsdf: Option<Bsdf>,
    /// Unit direction toward the previous vertex of its own subpath (surfaces).
    pub(super) wo: Vec3,
    /// Throughput arriving at the vertex.
    pub(super) beta: Vec3,
    pub(super) pdf_fwd: f32,
    pub(super) pdf_rev: f32,
    /// Sampled from a delta lobe (no connection can reach it).
    pub(super) delta: bool,
    /// The light it lies on (light vertices, surfaces of emitters), else `NONE`.
    pub(super) light: u32,
    /// A point, spot or directional light's vertex.
    pub(super) delta_light: bool,
    /// A vertex on a light at infinity (the environment, a directional light): `wo` is the
    /// direction its light travels, `p` a point on the disk it enters the scene through (light
    /// subpaths) or far along the ray (camera subpaths), `ng` zero.
    pub(super) infinite: bool,
    /// Triangle and barycentrics (surfaces and area lights), for emission.
    pub(super) prim: u32,
    pub(super) b: [f32; 3],
    /// The numbers of the light sample taken from this camera vertex (s = 1).
    pub(super) u_light: [f32; 3],
    /// Radiance toward `wo` of an emitter that moves within the shutter (no light sample nor
    /// bidirectional light subpath starts on one, so a camera subpath that hits it counts it in
    /// full; photons do leave it, `sppm::photon_path`).
    pub(super) moving_le: Vec3,
    /// The medium on `wo`'s side (`None`: air) and on the other (a different one only on a
    /// volume's boundary): where a connection leaving the vertex travels.
    pub(super) medium: Option<u32>,
    pub(super) beyond: Option<u32>,
    /// The volume boundary the vertex lies on (its material, and whether it was reached through
    /// the front face), and whether it refracts.
    pub(super) boundary: Option<(u32, bool)>,
    pub(super) refracting: bool,
    /// A refractive boundary with a dispersive volume on either side: its BSDF is the sample's
    /// wavelength's, and a path through it is that light's colour (`At::wavelength`).
    pub(super) dispersive: bool,
    /// Whether the throughput arriving here passed a dispersive vertex of its subpath (`beta`
    /// leaves out the wavelength's colour, which a whole path takes once: `At::tint`).
    pub(super) tinted: bool,
    /// Each channel's density of the subpath's free flights up to here over their mean (1, 1, 1
    /// without any; `media::free_flight`): a connection of two subpaths weighs its light by
    /// the channels' densities of the whole path (`spectral_weight`).
    pub(super) ratios: Vec3,
}

impl Vertex {
    fn new(kind: Kind, p: Vec3, beta: Vec3) -> Self {
        Vertex {
            kind,
            p,
            p_error: Vec3::ZERO,
            ng: Vec3::ZERO,
            frame: Frame::from_z(Vec3::Z),
            bsdf: None,
            wo: Vec3::ZERO,
            beta,
            pdf_fwd: 0.0,
            pdf_rev: 0.0,
            delta: false,
            light: NONE,
            delta_light: false,
            infinite: false,
            prim: NONE,
            b: [0.0; 3],
            u_light: [0.0; 3],
            moving_le: Vec3::ZERO,
            medium: None,
            beyond: None,
            boundary: None,
            refracting: false,
            dispersive: false,
            tinted: false,
            ratios: Vec3::ONE,
        }
    }

    #[inline]
    fn on_surface(&self) -> bool {
        self.ng != Vec3::ZERO
    }

    /// Unit direction from this vertex toward `other` (toward where a light at infinity shines
    /// from, or along its light from such a vertex).
    #[inline]
    pub(super) fn dir_to(&self, other: &Vertex) -> Option<Vec3> {
        if other.infinite {
            Some(-other.wo)
        } else if self.infinite {
            Some(self.wo)
        } else {
            (other.p - self.p).try_normalize()
        }
    }

    /// Whether a path using this vertex's BSDF takes its wavelength's colour: the throughput
    /// arriving here passed a dispersive vertex, or this one is dispersive.
    #[inline]
    pub(super) fn tints(&self) -> bool {
        self.tinted || self.dispersive
    }

    /// The shading normal (the geometric one off surfaces).
    fn ns(&self) -> Vec3 {
        if self.kind == Kind::Surface {
            self.frame.z
        } else {
            self.ng
        }
    }

    /// The BSDF for light arriving from unit direction `from` and leaving toward `to` (radiance
    /// order), zero where either direction lies between the shading and geometric surfaces.
    pub(super) fn f(&self, to: Vec3, from: Vec3) -> Vec3 {
        let Some(bsdf) = &self.bsdf else { return Vec3::ZERO };
        let (a, b) = (self.frame.to_local(to), self.frame.to_local(from));
        let transmits = bsdf.transmits();
        if !same_side(a.z, to.dot(self.ng), transmits)
            || !same_side(b.z, from.dot(self.ng), transmits)
        {
            return Vec3::ZERO;
        }
        let below = a.z < 0.0;
        let (a, b) = flip_below(a, b);
        match bsdf {
            Bsdf::Dielectric(d) if below => far_side(d).eval(a, b),
            _ => bsdf.eval(a, b),
        }
    }

    /// Density per solid angle of the BSDF sampling unit direction `to` given the path came
    /// from `from` (the BSDF samples "wi" for a "wo"; the frame is turned when `from` lies below).
    pub(super) fn pdf_dir(&self, from: Vec3, to: Vec3) -> f32 {
        let Some(bsdf) = &self.bsdf else { return 0.0 };
        let (a, b) = (self.frame.to_local(from), self.frame.to_local(to));
        let below = a.z < 0.0;
        let (a, b) = flip_below(a, b);
        match bsdf {
            Bsdf::Dielectric(d) if below => far_side(d).pdf(a, b),
            _ => bsdf.pdf(a, b),
        }
    }

    /// A solid-angle density at this vertex toward `next` to a density per unit area there (a
    /// vertex at infinity keeps the solid-angle density; from a light at infinity, `pdf` is the
    /// density per unit area of its disk, projected onto `next`).
    #[inline]
    fn convert_density(&self, pdf: f32, next: &Vertex) -> f32 {
        if next.infinite {
            return pdf;
        }
        if self.infinite {
            return if next.on_surface() { pdf * next.ng.dot(self.wo).abs() } else { pdf };
        }
        let w = next.p - self.p;
        let d2 = w.length_squared();
        if !(d2 > 0.0) {
            return 0.0;
        }
        let mut pdf = pdf / d2;
        if next.on_surface() {
            pdf *= next.ng.dot(w / d2.sqrt()).abs();
        }
        pdf
    }

    /// Density per unit area at `next` of this vertex sampling it, the path having come from
    /// `prev` (pbrt's `Vertex::Pdf`).
    fn pdf(
        &self,
        scene: &PreparedScene,
        camera: &PlacedCamera,
        prev: Option<&Vertex>,
        next: &Vertex,
    ) -> f32 {
        if self.kind == Kind::Light {
            return self.pdf_light(scene, next);
        }
        let Some(wn) = self.dir_to(next) else { return 0.0 };
        let pdf = match self.kind {
            Kind::Camera => camera.importance(self.p, wn).map_or(0.0, |i| i.pdf_dir),
            _ => {
                let Some(prev) = prev else { return 0.0 };
                let Some(wp) = self.dir_to(prev) else { return 0.0 };
                self.pdf_dir(wp, wn)
            }
        };
        self.convert_density(pdf, next)
    }

    /// Density per unit area at `next` of a light subpath leaving this light (or emitter's)
    /// vertex toward it.
    fn pdf_light(&self, scene: &PreparedScene, next: &Vertex) -> f32 {
        if self.light == NONE {
            return 0.0;
        }
        let light = &scene.lights.lights[self.light as usize];
        if self.infinite {
            // The density per unit area of the disk the light enters through, projected.
            return self.convert_density(light.pdf_le(self.wo, scene.sphere.1).pos, next);
        }
        let w = next.p - self.p;
        let d2 = w.length_squared();
        if !(d2 > 0.0) {
            return 0.0;
        }
        let w = w / d2.sqrt();
        let mut pdf = light.pdf_le(w, scene.sphere.1).dir / d2;
        if next.on_surface() {
            pdf *= next.ng.dot(w).abs();
        }
        pdf
    }

    /// Density of a light subpath starting at this point of its light: the light's choice
    /// (blind to any point) times the point's density per unit area (1 for a point light; for
    /// the environment, the density per solid angle of its direction, pbrt's convention for
    /// lights at infinity, whose disk point no other strategy chooses).
    pub(super) fn pdf_light_origin(&self, scene: &PreparedScene) -> f32 {
        if self.light == NONE {
            return 0.0;
        }
        let blind = ShadingContext::default();
        let pmf = match &scene.emission {
            Some(mixture) => mixture.pmf(&blind, self.light),
            None => scene.lights.pmf(&blind, self.light),
        };
        pmf * origin_density(&scene.lights.lights[self.light as usize], self.wo, scene.sphere.1)
    }

    /// Radiance an emitter's surface vertex sends toward unit direction `w`.
    pub(super) fn le(&self, scene: &PreparedScene, w: Vec3) -> Vec3 {
        if self.light == NONE {
            return Vec3::ZERO;
        }
        let light = &scene.lights.lights[self.light as usize];
        match light.on_surface() {
            Some(l) if l.emits_toward(w) => surface_emission(scene, l, self.b, w),
            Some(_) => Vec3::ZERO,
            None if self.infinite => light.radiance(self.wo),
            None => Vec3::ZERO,
        }
    }
}

/// The density of a light subpath's first vertex on `light` leaving along unit `wo` (pbrt's
/// convention: its position's per unit area, but for a light at infinity, whose disk point no
/// other strategy chooses, its direction's per solid angle), the choice of light excluded.
fn origin_density(light: &Light, wo: Vec3, radius: f32) -> f32 {
    let pdf = light.pdf_le(wo, radius);
    if light.is_infinite() {
        pdf.dir
    } else {
        pdf.pos
    }
}

/// Turns a pair of local directions half a turn about the tangent when the first lies below the
/// surface, so that the BSDF sees its first direction above (BSDFs are written that way).
#[inline]
fn flip_below(a: Vec3, b: Vec3) -> (Vec3, Vec3) {
    if a.z < 0.0 {
        (Vec3::new(a.x, -a.y, -a.z), Vec3::new(b.x, -b.y, -b.z))
    } else {
        (a, b)
    }
}

/// A dielectric boundary seen from its far side: the reciprocal relative index (BSDFs are
/// written for a first direction above; `flip_below` turns a pair whose first lies below).
#[inline]
fn far_side(d: &Dielectric) -> Dielectric {
    Dielectric { eta: 1.0 / d.eta, ..*d }
}

/// Which way light travels along a subpath.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    /// A camera subpath: importance flows out from the camera.
    Radiance,
    /// A light subpath: light flows out from the light.
    Importance,
}

/// What one sample's time places: the geometry that moves (`None`: nothing does) and the
/// camera; and in a scene with dispersion, the sample's wavelength. Both subpaths of a sample,
/// and all its connections, see the same time and the same wavelength.
#[derive(Clone, Copy)]
pub(super) struct At<'p> {
    pub(super) pose: Option<&'p Pose<'p>>,
    pub(super) camera: PlacedCamera,
    /// The wavelength (nanometres) every dispersive boundary of the sample bends light by, and
    /// the colour of that light over its density (`spectrum::sample_wavelength`), which a path
    /// through any dispersive vertex takes once, as the path tracer's path takes it at its first.
    pub(super) wavelength: Option<(f32, Vec3)>,
    /// The colour channel whose exponential draws every free flight of the sample, on both
    /// subpaths (in a scene with scattering media), so that a connection's light can be weighed
    /// by the channels' densities of the whole path.
    pub(super) hero: usize,
}

impl<'p> At<'p> {
    /// A scene where nothing moves.
    pub(super) fn still(scene: &PreparedScene) -> Self {
        At { pose: None, camera: PlacedCamera::still(scene.camera), wavelength: None, hero: 0 }
    }

    /// The sample whose shared numbers are `u` (`SharedNumbers`): its time, wavelength and hero
    /// channel; `pose` is reset to the time.
    pub(super) fn sample<'s: 'p>(
        scene: &'s PreparedScene,
        (u_time, u_wavelength, u_hero): SharedNumbers,
        pose: &'p mut Option<Pose<'s>>,
    ) -> Self {
        At {
            wavelength: u_wavelength.map(spectrum::sample_wavelength),
            hero: u_hero.map_or(0, media::hero_channel),
            ..At::time(scene, u_time, pose)
        }
    }

    /// `l`, a path's contribution, in the colour of the sample's wavelength if the path passed a
    /// dispersive vertex (`tinted`).
    #[inline]
    pub(super) fn tint(&self, l: Vec3, tinted: bool) -> Vec3 {
        match self.wavelength {
            Some((_, colour)) if tinted => l * colour,
            _ => l,
        }
    }

    /// The scene at the time `u` (in [0, 1)) picks within the shutter, `pose` reset to it; the
    /// still scene when nothing moves.
    pub(super) fn time<'s: 'p>(
        scene: &'s PreparedScene,
        u: Option<f32>,
        pose: &'p mut Option<Pose<'s>>,
    ) -> Self {
        let (Some(m), Some(u)) = (&scene.motion, u) else { return At::still(scene) };
        let time = m.time(u);
        let pose = pose.get_or_insert_with(|| Pose::new(m, time));
        pose.set_time(time);
        At { pose: Some(pose), camera: m.camera_at(&scene.camera, time), wavelength: None, hero: 0 }
    }
}

/// The numbers all the paths of a sample (or of a photon pass) share, each only in a scene that
/// needs it: where it falls in the shutter (something moves within it), its wavelength
/// (dispersion) and its free flights' hero channel (scattering media).
pub(super) type SharedNumbers = (Option<f32>, Option<f32>, Option<f32>);

/// The start of pixel sample `s` of `pixel`: its film position and lens numbers (zero for a
/// pinhole) and its `SharedNumbers`, drawn in that order (the time as the path tracer draws it).
/// Camera and light tasks both start a sample here, so that they draw the same shared numbers.
fn start_sample(
    scene: &PreparedScene,
    sampler: &mut Sampler,
    pixel: UVec2,
    s: u32,
) -> (Vec2, Vec2, SharedNumbers) {
    sampler.start_pixel_sample(pixel, s);
    let film = pixel.as_vec2() + sampler.next_2d();
    let lens = if scene.camera.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
    (film, lens, shared_numbers(scene, sampler))
}

/// Draws a sample's `SharedNumbers` after its film and lens numbers (`start_sample`).
fn shared_numbers(scene: &PreparedScene, sampler: &mut Sampler) -> SharedNumbers {
    let u_time = scene.motion.is_some().then(|| sampler.next_1d());
    let u_wavelength = scene.dispersive.then(|| sampler.next_1d());
    let u_hero = scene.scattering_media.then(|| sampler.next_1d());
    (u_time, u_wavelength, u_hero)
}

/// A direction of travel after a scattering at medium vertex `v`, by its medium's
/// Henyey-Greenstein phase function from numbers `u` (sampled exactly: its value over its
/// density is 1), as the path tracer scatters.
pub(super) fn scatter(scene: &PreparedScene, media: &MediumStack, v: &Vertex, u: Vec2) -> Vec3 {
    let volume = media.current().and_then(|m| scene.materials[m as usize].volume);
    let g = volume.map_or(0.0, |volume| volume.anisotropy);
    Frame::from_z(-v.wo).to_world(sample_henyey_greenstein(g, u))
}

/// Per-thread storage for the two subpaths.
#[derive(Default)]
pub struct Paths {
    camera: Vec<Vertex>,
    light: Vec<Vertex>,
}

/// Extends `path` (whose last vertex sent `ray`, with solid-angle density `pdf`) by up to
/// `max_vertices` vertices. Each vertex takes 7 sampler numbers: 3 for a light sample (camera
/// subpaths) or 2 for a lens point and one skipped (light subpaths, for light tracing), then the
/// lobe, the direction and the roulette; in a scene with scattering media each segment takes one
/// more first, for its free flight (a scattering's vertex takes the same 7, its phase function
/// sampled in the direction's two).
#[allow(clippy::too_many_arguments)]
fn walk(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    mut ray: Ray,
    mut beta: Vec3,
    mut pdf: f32,
    mode: Mode,
    max_vertices: u32,
    mut media: MediumStack,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
    unlit: &mut Vec3,
) {
    let mut bounces = 0u32;
    // The subpath's free-flight densities per channel over their mean (`Vertex::ratios`).
    let mut ratios = Vec3::ONE;
    // The product of eta² over the refractions a camera subpath crossed, which its radiance
    // took as 1 / eta² (a light subpath's flux takes no such scale): the roulette looks past it.
    let mut eta_scale = 1.0f32;
    while bounces < max_vertices {
        // In a scene with scattering media each segment takes a number for its free flight.
        let u_flight = if scene.scattering_media { sampler.next_1d() } else { 0.0 };
        let next =
            surface_vertex(scene, at, &ray, &mut beta, u_flight, &mut ratios, stats, &mut media);
        let Some((mut v, unlit_base)) = next else {
            if let (Mode::Radiance, Some(env)) = (mode, scene.lights.environment) {
                // The camera subpath leaves the scene: a vertex on the environment.
                let d = ray.dir.normalize();
                let far = 2.0 * (scene.sphere.1 + (ray.origin - scene.sphere.0).length());
                let mut v = Vertex::new(Kind::Light, ray.origin + d * far, beta);
                v.infinite = true;
                v.wo = -d;
                v.light = env;
                let prev = path.last().expect("a subpath starts with its camera vertex");
                v.pdf_fwd = prev.convert_density(pdf, &v);
                v.tinted = prev.tints();
                path.push(v);
            }
            break;
        };
        let prev = path.last().expect("a subpath starts with its camera or light vertex");
        v.pdf_fwd = prev.convert_density(pdf, &v);
        v.tinted = prev.tints();
        bounces += 1;
        // What the medium on the way let through.
        beta = v.beta;
        if let Some(base) = unlit_base {
            // Seen as its base colour by the camera, and by nothing else.
            if mode == Mode::Radiance {
                *unlit += at.tint(beta * base, v.tinted);
            }
            path.push(v);
            break;
        }
        if v.kind == Kind::Medium {
            // A scattering inside a medium: the phase function, sampled exactly (its value over
            // its density is 1), picks the next direction, as in the path tracer. Like a mirror,
            // it is no end of a connection (a light outside lies beyond the medium's boundary,
            // which no shadow ray crosses), so its vertex is marked delta and the MIS weights
            // leave out the strategies that would join there.
            v.delta = true;
            let p = v.p;
            sampler.skip(3); // The light sample's numbers (or the lens point's), as a surface's.
            path.push(v);
            if bounces >= max_vertices {
                break;
            }
            sampler.skip(1); // The lobe.
            let n = path.len();
            let wi = scatter(scene, &media, &path[n - 1], sampler.next_2d());
            // Neither side's density enters a weight (as after a delta lobe).
            path[n - 2].pdf_rev = 0.0;
            if !beta.is_finite()
                || beta == Vec3::ZERO
                || !roulette(sampler, bounces, &mut beta, eta_scale)
            {
                break;
            }
            pdf = 0.0;
            ray = Ray::interior(p, wi);
            continue;
        }
        let (p, ng, wo, frame) = (v.p, v.ng, v.wo, v.frame);
        let bsdf = v.bsdf.expect("a lit surface vertex has a BSDF");
        match mode {
            Mode::Radiance => {
                let u = sampler.next_2d();
                v.u_light = [sampler.next_1d(), u.x, u.y];
            }
            Mode::Importance => {
                let u = sampler.next_2d();
                v.u_light = [0.0, u.x, u.y];
                sampler.skip(1);
            }
        }
        path.push(v);
        if bounces >= max_vertices {
            break;
        }
        let wo_local = frame.to_local(wo);
        if wo_local.z <= 0.0 {
            break;
        }
        let u_lobe = sampler.next_1d();
        let u = sampler.next_2d();
        let Some(bs) = bsdf.sample(wo_local, u_lobe, u) else { break };
        let wi = frame.to_world(bs.wi);
        let refracting = path[path.len() - 1].refracting;
        if !refracting && !same_side(bs.wi.z, wi.dot(ng), bsdf.transmits()) {
            break;
        }
        let n = path.len();
        let delta = bs.lobe.is_delta();
        let f = match mode {
            // Light flows from `wo` toward `wi` on a light subpath.
            Mode::Importance if !delta => path[n - 1].f(wi, wo),
            // A smooth refraction's radiance carries 1 / eta² of the side it enters; the flux a
            // light subpath carries does not (pbrt-v4's TransportMode::Importance).
            Mode::Importance if bs.lobe.enters_far_side() => bs.f * (bs.eta * bs.eta),
            _ => bs.f,
        };
        beta *= f * (bs.wi.z.abs() / bs.pdf);
        if mode == Mode::Importance {
            // Shading normals make the adjoint BSDF differ by this factor (Veach 5.3.2).
            let denom = wo.dot(ng).abs() * wi.dot(frame.z).abs();
            beta *=
                if denom > 0.0 { wo.dot(frame.z).abs() * wi.dot(ng).abs() / denom } else { 0.0 };
        }
        let (pdf_fwd, pdf_rev) =
            if delta { (0.0, 0.0) } else { (bs.pdf, path[n - 1].pdf_dir(wi, wo)) };
        if delta {
            path[n - 1].delta = true;
        }
        let rev = path[n - 1].convert_density(pdf_rev, &path[n - 2]);
        path[n - 2].pdf_rev = rev;
        if !beta.is_finite() || beta == Vec3::ZERO {
            break;
        }
        if mode == Mode::Radiance && bs.lobe.enters_far_side() {
            eta_scale *= bs.eta * bs.eta;
        }
        // Russian roulette as in the path tracer (unbiased; the MIS weights leave it out, which
        // keeps them a partition of unity).
        if !roulette(sampler, bounces, &mut beta, eta_scale) {
            break;
        }
        pdf = pdf_fwd;
        cross_after(&path[n - 1], wi, bs.wi, &mut media);
        ray = Ray::new(offset_ray_origin(p, path[n - 1].p_error, ng, wi), wi);
    }
}

/// What `ray` meets first, as a vertex reached with throughput `beta` (its densities left for
/// the caller): a surface with its shading frame and BSDF (an unlit material's vertex has no
/// BSDF and comes with the base colour the camera sees), or in a scattering medium the point
/// where number `u_flight` puts the first scattering (`Kind::Medium`), the free flight drawn by
/// the sample's hero channel and `ratios` (the subpath's densities so far) carried on. `beta`
/// becomes what the media on the way let through, also when the ray leaves the scene (`None`).
#[allow(clippy::too_many_arguments)]
pub(super) fn surface_vertex(
    scene: &PreparedScene,
    at: &At<'_>,
    ray: &Ray,
    beta: &mut Vec3,
    u_flight: f32,
    ratios: &mut Vec3,
    stats: &mut Stats,
    media: &mut MediumStack,
) -> Option<(Vertex, Option<Vec3>)> {
    let mut ray = *ray;
    // False interfaces passed (bounded, as in the path tracer).
    let mut passed = 0u32;
    // In a scattering medium, the distance left to the scattering the flight drew (drawn once,
    // then carried past false interfaces).
    let mut flight: Option<f32> = None;
    loop {
        stats.rays += 1;
        let hit = scene.intersect(&ray, f32::INFINITY, at.pose);
        let volume = media.current().and_then(|m| scene.materials[m as usize].volume);
        match volume {
            Some(v) if scene.scattering_media && v.scatters() => {
                let len = ray.dir.length();
                let distance = hit.map_or(f32::INFINITY, |h| h.t * len);
                let t =
                    *flight.get_or_insert_with(|| media::flight_distance(&v, at.hero, u_flight));
                let (weight, scattered) = media::free_flight_at(&v, distance, t, ratios);
                *beta *= weight;
                if let Some(t) = scattered {
                    let dir = ray.dir / len;
                    let mut m = Vertex::new(Kind::Medium, ray.origin + dir * t, *beta);
                    m.wo = -dir;
                    m.medium = media.current();
                    m.beyond = m.medium;
                    m.ratios = *ratios;
                    return Some((m, None));
                }
                flight = Some(t - distance);
            }
            // Beer-Lambert along the segment inside the volume (an escape is endless).
            Some(v) => {
                let distance = hit.map_or(f32::INFINITY, |h| h.t * ray.dir.length());
                *beta *= transmittance(&v, distance);
            }
            None => {}
        }
        let hit = hit?;
        let tri = scene.shading[hit.prim as usize];
        let ([p0, p1, p2], moved) = scene.triangle(hit.prim, at.pose);
        let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
        let p = p0 * b[0] + p1 * b[1] + p2 * b[2];
        let winding = (p1 - p0).cross(p2 - p0).try_normalize()?;
        let wo = -ray.dir.normalize();
        let front = winding.dot(wo) > 0.0;
        let ng = if front { winding } else { -winding };
        let material = &scene.materials[tri.material as usize];
        let p_error = hit_error([p0, p1, p2], b, moved);
        // A volume's boundary, as the path tracer meets it: a false interface is passed
        // unchanged, a real one is between the current medium and the one beyond.
        let (boundary, beyond) =
            match meet_surface(scene, tri.material, tri.extended, front, media, &mut passed) {
                Meeting::Surface { boundary, beyond } => (boundary, beyond),
                Meeting::Passed => {
                    ray = Ray::new(offset_ray_origin(p, p_error, winding, ray.dir), ray.dir);
                    continue;
                }
                Meeting::Stuck => return None,
            };
        let sp = scene.shading_point(hit.prim, [p0, p1, p2], b);
        let mut v = Vertex::new(Kind::Surface, p, *beta);
        v.ratios = *ratios;
        v.p_error = p_error;
        v.ng = ng;
        v.wo = wo;
        v.prim = hit.prim;
        v.b = b;
        v.medium = media.current();
        v.beyond = beyond;
        v.boundary = boundary.then_some((tri.material, front));
        v.light = if tri.light == NONE || tri.light == UNSAMPLED { NONE } else { tri.light };
        if tri.light == UNSAMPLED && (material.double_sided || front) {
            v.moving_le = material::emission_toward(&scene.textures, material, &sp, winding, wo);
        }
        if tri.extended && material.unlit {
            return Some((v, Some(material::clamped_base_color(&scene.textures, material, &sp))));
        }
        let (mut frame, ns_surface) =
            shading_frame(scene, hit.prim, [p0, p1, p2], b, ng, wo, &sp, at.pose);
        v.refracting = boundary && material.refracts();
        if v.refracting && frame.to_local(wo).z <= 0.0 {
            // As in the path tracer: a refractive boundary shades with the facet's normal where
            // the interpolated one turns away from wo.
            frame = Frame::from_z(ng);
        }
        v.frame = frame;
        // A refractive boundary's relative index: the volume's against the medium on its other
        // side (the current one entering it, the one beyond leaving it), at the sample's
        // wavelength where either is dispersive (where the path tracer's path takes one on).
        let iors = if boundary {
            let other = if front { media.current() } else { beyond };
            let dispersive =
                |m: Option<u32>| m.is_some_and(|m| scene.materials[m as usize].dispersion > 0.0);
            v.dispersive = at.wavelength.is_some()
                && material.refracts()
                && (material.dispersion > 0.0 || dispersive(other));
            let lambda = at.wavelength.filter(|_| v.dispersive).map(|(lambda, _)| lambda);
            [
                media::ior(&scene.materials, Some(tri.material), lambda),
                media::ior(&scene.materials, other, lambda),
            ]
        } else {
            [1.0; 2]
        };
        let here = (hit.prim, [p0, p1, p2], b);
        let shading = (&sp, front, iors);
        v.bsdf = Some(surface_bsdf(scene, here, shading, (&frame, ns_surface), at.pose));
        return Some((v, None));
    }
}

/// After a vertex's BSDF sampled the unit direction `wi` (`wi_local` in its frame), crosses the
/// volume boundary the vertex lies on if `wi` leaves through it.
pub(super) fn cross_after(v: &Vertex, wi: Vec3, wi_local: Vec3, media: &mut MediumStack) {
    let Some((material, front)) = v.boundary else { return };
    // Which side the ray leaves by: the shading frame's, except at a refractive boundary, where
    // the facet's decides.
    let crosses = if v.refracting { wi.dot(v.ng) < 0.0 } else { wi_local.z < 0.0 };
    if crosses {
        media.cross(material, front);
    }
}

/// The transmittance of the straight segment from vertex `a` to vertex `b` (a connection): the
/// medium `a` leaves into along it, over their distance; 1 in air.
#[inline]
pub(super) fn segment_transmittance(scene: &PreparedScene, a: &Vertex, b: &Vertex) -> Vec3 {
    if a.medium.is_none() && a.beyond.is_none() {
        return Vec3::ONE;
    }
    let Some(w) = a.dir_to(b) else { return Vec3::ONE };
    let medium = if a.kind == Kind::Surface && w.dot(a.ng) < 0.0 { a.beyond } else { a.medium };
    let Some(volume) = medium.and_then(|m| scene.materials[m as usize].volume) else {
        return Vec3::ONE;
    };
    let d = if b.infinite { f32::INFINITY } else { a.p.distance(b.p) };
    transmittance(&volume, d)
}

/// The factor that weighs the light of a path joined from two subpaths ending at `a` and `b` by
/// the channels' densities of all its free flights (spectral MIS over the whole path, as
/// `media::free_flight` weighs one subpath's): each subpath's throughput is divided by the mean
/// of its own densities, so the whole path's needs 1 / mean(ratios_a ratios_b). Exactly 1 where
/// either subpath had no free flight.
#[inline]
pub(super) fn spectral_weight(a: &Vertex, b: &Vertex) -> f32 {
    let mean = (a.ratios * b.ratios).element_sum() / 3.0;
    if mean > 0.0 {
        1.0 / mean
    } else {
        0.0
    }
}

/// The camera subpath of a sample whose film position and lens numbers are drawn: up to
/// `max_depth + 2` vertices, the camera's first.
fn camera_subpath(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    film: Vec2,
    lens: Vec2,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
) -> Vec3 {
    path.clear();
    let ray = at.camera.generate_ray(film, lens);
    // An orthographic camera's direction is fixed: its density never enters a weight (no light
    // subpath connects to it).
    let pdf_dir = at.camera.importance(ray.origin, ray.dir).map_or(1.0, |i| i.pdf_dir);
    path.push(Vertex::new(Kind::Camera, ray.origin, Vec3::ONE));
    let mut unlit = Vec3::ZERO;
    walk(
        scene,
        at,
        sampler,
        ray,
        Vec3::ONE,
        pdf_dir,
        Mode::Radiance,
        scene.max_depth + 1,
        scene.camera_media,
        path,
        stats,
        &mut unlit,
    );
    unlit
}

/// The light subpath of the current pixel sample: the light's vertex and up to `max_vertices`
/// surface vertices (a camera task's strategies use `max_depth - 1`). Draws from
/// `LIGHT_DIMENSION` on (the
/// light, its point, its direction, then the walk's numbers); a shorter limit gives the same
/// first vertices.
///
/// Its numbers are the pixel sample's own, stratified over that pixel's samples: the strategies
/// that join a camera subpath to its own light subpath need each pixel's light subpaths to cover
/// the lights' points and directions. (A frame-wide sequence indexed by sample and pixel, as
/// photons use, puts one pixel's light subpaths in the same few strata of its first dimensions,
/// so that a pixel's connections would settle on its scramble's value.) Light tracing, which
/// pools every pixel's light subpaths, starts them from a frame-wide sequence instead
/// (`light_film`).
pub(super) fn light_subpath(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    max_vertices: u32,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
) {
    path.clear();
    sampler.set_dimension(LIGHT_DIMENSION);
    let u_choice = sampler.next_1d();
    let (u_pos, u_dir) = (sampler.next_2d(), sampler.next_2d());
    let Some((idx, pmf)) = choose_emitting(scene, u_choice) else { return };
    let light = &scene.lights.lights[idx as usize];
    let media = scene.light_media.get(idx as usize).copied().unwrap_or_default();
    let u = (u_pos, u_dir);
    leave_light(scene, at, sampler, u, light, Some(idx), pmf, media, max_vertices, path, stats);
}

/// The frame-wide sequences (`Sampler::frame_point`) of a set of light subpaths that are pooled
/// (light tracing's, photons'), one for the even sample indices or passes and one for the odd,
/// which stay independent estimates.
pub(super) type FrameSequences = [u64; 2];

/// The start of light subpath `j` of `per_pass` of sample index or pass `pass`: point
/// `pass / 2 * per_pass + j` of its half's frame-wide sequence, so that a pass's subpaths (and
/// the passes of a half together) leave the lights as one low-discrepancy set and land evenly,
/// each on its own as random as an independent one. Two pairs, the first the better stratified,
/// then the light's choice (`leave_still_light`).
pub(super) fn frame_start(
    sampler: &mut Sampler,
    sequences: FrameSequences,
    per_pass: u64,
    j: u64,
    pass: u32,
) -> FrameStart {
    sampler.frame_point(sequences[(pass & 1) as usize], (pass / 2) as u64 * per_pass + j)
}

/// The numbers a pooled light subpath starts from (`frame_start`).
pub(super) type FrameStart = [f32; FRAME_DIMENSIONS];

/// The subpath of a light that stays put from `start` (`frame_start`), as `light_subpath`'s but
/// for its first numbers: the light chosen by `u_choice` (`choose_emitting`, its probability
/// times `scale`; `start[4]`, or what is left of it after a choice among moving emitters), and
/// the first, best stratified pair of `start` given to what spreads the light most, the
/// direction, but a directional light's point. The sampler must be at its walk's numbers.
#[allow(clippy::too_many_arguments)]
pub(super) fn leave_still_light(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    start: FrameStart,
    u_choice: f32,
    scale: f32,
    max_vertices: u32,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
) {
    path.clear();
    let (first, second) = (Vec2::new(start[0], start[1]), Vec2::new(start[2], start[3]));
    let Some((idx, pmf)) = choose_emitting(scene, u_choice) else { return };
    let light = &scene.lights.lights[idx as usize];
    let u = (first, second);
    let media = scene.light_media.get(idx as usize).copied().unwrap_or_default();
    let pmf = pmf * scale;
    leave_light(scene, at, sampler, u, light, Some(idx), pmf, media, max_vertices, path, stats);
}

/// The light a light subpath or photon leaves, from `u`, and its probability: blind to any point
/// (the power mixture where light samples choose by the tree).
pub(super) fn choose_emitting(scene: &PreparedScene, u: f32) -> Option<(u32, f32)> {
    let choice = match &scene.emission {
        Some(mixture) => ChooseLight::choose(mixture, &ShadingContext::default(), u),
        None => scene.lights.choose(&ShadingContext::default(), u),
    };
    choice.map(|(idx, pmf, _)| (idx, pmf))
}

/// The subpath of `light`, chosen with probability `pmf` (`idx`, its index in `scene.lights`;
/// `None` for an emitter that moves within the shutter, posed at the sample's time), starting
/// in the volumes `media`: its vertex on the light, where `Light::sample_le` leaves by the
/// numbers `u` (the better stratified pair first), and the walk from there (`light_subpath`).
/// The sampler must be at its walk's numbers.
#[allow(clippy::too_many_arguments)]
pub(super) fn leave_light(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    u: (Vec2, Vec2),
    light: &Light,
    idx: Option<u32>,
    pmf: f32,
    media: MediumStack,
    max_vertices: u32,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
) {
    path.clear();
    let Some(mut ls) = light.sample_le(u.0, u.1, scene.sphere) else { return };
    let mut v = match light.on_surface() {
        Some(l) => {
            if l.textured {
                ls.le = surface_emission(scene, l, ls.barycentrics, ls.dir);
            }
            if scene.alpha_tested {
                ls.le *= scene.coverage(l.prim, ls.barycentrics);
            }
            let mut v = Vertex::new(Kind::Light, ls.p, ls.le);
            v.p_error = ls.p_error;
            v.ng = l.normal;
            v.prim = l.prim;
            v.b = ls.barycentrics;
            v
        }
        None => Vertex::new(Kind::Light, ls.p, ls.le),
    };
    let beta = ls.beta(light, pmf);
    let origin = match light.on_surface() {
        Some(l) => {
            let side = if l.normal.dot(ls.dir) > 0.0 { l.normal } else { -l.normal };
            offset_ray_origin(ls.p, ls.p_error, side, ls.dir)
        }
        None => ls.p,
    };
    let ray = Ray::new(origin, ls.dir);
    // Lights at infinity: the walk's first density is the disk's per unit area.
    let pdf_dir = if light.is_infinite() { ls.pdf_pos } else { ls.pdf_dir };
    if light.is_infinite() {
        v.infinite = true;
        v.wo = ls.dir;
    }
    v.light = idx.unwrap_or(NONE);
    v.delta_light = light.is_delta();
    // No MIS weight asks a moving emitter's density (photons carry no weights).
    v.pdf_fwd = if idx.is_some() { v.pdf_light_origin(scene) } else { 0.0 };
    v.medium = media.current();
    path.push(v);
    if beta == Vec3::ZERO || !beta.is_finite() {
        return;
    }
    let mut unlit = Vec3::ZERO;
    walk(
        scene,
        at,
        sampler,
        ray,
        beta,
        pdf_dir,
        Mode::Importance,
        max_vertices,
        media,
        path,
        stats,
        &mut unlit,
    );
}

/// The balance-heuristic weight of the strategy with `s` light and `t` camera vertices, where
/// `sampled` replaces the last light vertex (s = 1) or the camera vertex (t = 1) (pbrt's
/// `MISWeight`): one over the sum, over every strategy that could make the same path, of its
/// density over this one's.
///
/// Where lights are chosen by the tree, the strategy that samples the light from the path's
/// vertex next to it (s = 1) chooses it with the tree's probability there, and every strategy
/// whose light subpath starts on it (s >= 2) with the point-blind mixture's: the ratios between
/// the two kinds carry the quotient of those probabilities (pbrt-v4's BDPT sidesteps this by
/// choosing blind for both).
///
/// Light tracing (t = 1) takes `bdpt.light_paths` samples per pixel sample (the light tile has
/// that many times the samples), every other strategy one: its ratios carry that count (Veach's
/// balance heuristic with sample counts, n_i p_i over the sum of n_j p_j).
fn mis_weight(
    scene: &PreparedScene,
    view: &PlacedCamera,
    camera: &[Vertex],
    light: &[Vertex],
    sampled: Option<&Vertex>,
    s: usize,
    t: usize,
) -> f32 {
    if s + t == 2 {
        return 1.0;
    }
    let pt: &Vertex =
        if t == 1 { sampled.expect("t = 1 samples the camera") } else { &camera[t - 1] };
    let qs: Option<&Vertex> = match s {
        0 => None,
        1 => Some(sampled.expect("s = 1 samples the light")),
        _ => Some(&light[s - 1]),
    };
    let pt_minus = (t > 1).then(|| &camera[t - 2]);
    let qs_minus = (s > 1).then(|| &light[s - 2]);
    // The densities the connection changes: of pt and qs sampled from the other side, and of
    // their predecessors.
    let pt_rev = match &qs {
        Some(qs) => qs.pdf(scene, view, qs_minus, &pt),
        None => pt.pdf_light_origin(scene),
    };
    let pt_minus_rev = pt_minus.map_or(0.0, |pm| match &qs {
        Some(qs) => pt.pdf(scene, view, Some(qs), pm),
        None => pt.pdf_light(scene, pm),
    });
    let qs_rev = qs.as_ref().map_or(0.0, |qs| pt.pdf(scene, view, pt_minus, qs));
    let qs_minus_rev = match (&qs, qs_minus) {
        (Some(qs), Some(qm)) => qs.pdf(scene, view, Some(&pt), qm),
        _ => 0.0,
    };
    let remap = |f: f32| if f != 0.0 { f } else { 1.0 };
    let light_tracing = view.camera.connectable();
    // The tree's choice of the path's light from the vertex next to it over the mixture's: the
    // s = 1 strategy's light density over the others' (1 where both choose by the mixture).
    let tree = scene.emission.as_ref().map_or(1.0, |mixture| {
        let (on_light, next) = match s {
            0 => (pt, &camera[t - 2]),
            1 => (qs.expect("s = 1 samples the light"), pt),
            _ => (&light[0], &light[1]),
        };
        let ctx = ShadingContext { p: next.p, n: next.ns() };
        let blind = mixture.pmf(&ShadingContext::default(), on_light.light);
        let ratio = scene.lights.pmf(&ctx, on_light.light) / blind;
        if ratio.is_finite() {
            ratio
        } else {
            0.0
        }
    });
    let light_paths = scene.light_paths as f32;
    let mut sum = 0.0f32;
    let mut ri = 1.0f32;
    for i in (1..t).rev() {
        let (fwd, rev, delta) = if i == t - 1 {
            (pt.pdf_fwd, pt_rev, false)
        } else if i + 2 == t {
            (camera[i].pdf_fwd, pt_minus_rev, camera[i].delta)
        } else {
            (camera[i].pdf_fwd, camera[i].pdf_rev, camera[i].delta)
        };
        ri *= remap(rev) / remap(fwd);
        if !delta && !camera[i - 1].delta && (i > 1 || light_tracing) {
            // The strategy with s + t - i light vertices, against this one.
            let r = match s {
                0 if i == t - 1 => ri * tree,
                1 => ri / tree,
                _ => ri,
            };
            // Light tracing (i = 1) has `light_paths` samples to this strategy's one.
            sum += if i == 1 { r * light_paths } else { r };
        }
    }
    ri = 1.0;
    let light0_delta = match s {
        0 => false,
        1 => qs.is_some_and(|q| q.delta_light),
        _ => light[0].delta_light,
    };
    for i in (0..s).rev() {
        let (fwd, rev, delta) = if i == s - 1 {
            (qs.expect("s > 0").pdf_fwd, qs_rev, false)
        } else if i + 2 == s {
            (light[i].pdf_fwd, qs_minus_rev, light[i].delta)
        } else {
            (light[i].pdf_fwd, light[i].pdf_rev, light[i].delta)
        };
        ri *= remap(rev) / remap(fwd);
        let before_delta = if i > 0 { light[i - 1].delta } else { light0_delta };
        if !delta && !before_delta {
            // The strategy with i light vertices, against this one.
            let r = if i == 1 { ri * tree } else { ri };
            // This strategy is light tracing: `light_paths` samples to the other's one.
            sum += if t == 1 { r / light_paths } else { r };
        }
    }
    1.0 / (1.0 + sum)
}

/// Whether the segment between two vertices is clear.
fn visible(scene: &PreparedScene, at: &At<'_>, a: &Vertex, b: &Vertex, stats: &mut Stats) -> bool {
    if b.infinite {
        let w = -b.wo;
        let from = if a.on_surface() { offset_ray_origin(a.p, a.p_error, a.ng, w) } else { a.p };
        stats.rays += 1;
        return !scene.occluded(&Ray::new(from, w), f32::INFINITY, at.pose);
    }
    let w = b.p - a.p;
    let from = if a.on_surface() { offset_ray_origin(a.p, a.p_error, a.ng, w) } else { a.p };
    let to = if b.on_surface() { offset_ray_origin(b.p, b.p_error, b.ng, -w) } else { b.p };
    stats.rays += 1;
    !scene.occluded(&Ray::new(from, to - from), SHADOW_T_MAX, at.pose)
}

/// The camera task's part of one sample: every strategy with at least two camera vertices.
fn camera_strategies(scene: &PreparedScene, at: &At<'_>, paths: &Paths, stats: &mut Stats) -> Vec3 {
    let (camera, light) = (&paths.camera, &paths.light);
    let max_depth = scene.max_depth as usize;
    let mut total = Vec3::ZERO;
    for t in 2..=camera.len() {
        let pt = &camera[t - 1];
        if pt.infinite {
            // The camera subpath left the scene: the environment it sees (s = 0), straight from
            // the camera only where the settings show it.
            if t > 2 || scene.environment_visible {
                let l = at.tint(pt.beta * pt.le(scene, pt.wo), pt.tinted);
                if l != Vec3::ZERO && l.is_finite() {
                    total += l * mis_weight(scene, &at.camera, camera, light, None, 0, t);
                }
            }
            continue;
        }
        if pt.kind != Kind::Surface {
            continue;
        }
        if pt.moving_le != Vec3::ZERO {
            // An emitter that moves: only this strategy (s = 0) finds it.
            total += at.tint(pt.beta * pt.moving_le, pt.tinted);
        }
        for s in 0..=light.len() {
            if s + t - 2 > max_depth {
                break;
            }
            let (l, sampled) = match s {
                0 => {
                    // The camera subpath found a light.
                    let wo = (camera[t - 2].p - pt.p).normalize();
                    (at.tint(pt.beta * pt.le(scene, wo), pt.tinted), None)
                }
                1 => match sample_light(
                    scene,
                    at,
                    pt,
                    &ShadingContext { p: pt.p, n: pt.ns() },
                    stats,
                ) {
                    Some((l, v, _)) => (at.tint(l, pt.tints()), Some(v)),
                    None => continue,
                },
                _ => {
                    let qs = &light[s - 1];
                    if qs.bsdf.is_none() || pt.bsdf.is_none() {
                        continue;
                    }
                    let d = qs.p - pt.p;
                    let d2 = d.length_squared();
                    if !(d2 > 0.0) {
                        continue;
                    }
                    let w = d / d2.sqrt();
                    let g = qs.ns().dot(w).abs() * pt.ns().dot(w).abs() / d2;
                    let l = qs.beta * qs.f(-w, qs.wo) * pt.f(pt.wo, w) * pt.beta * g;
                    if l == Vec3::ZERO || !visible(scene, at, pt, qs, stats) {
                        continue;
                    }
                    let tinted = pt.tints() || qs.tints();
                    let mut l = at.tint(l * segment_transmittance(scene, pt, qs), tinted);
                    if scene.scattering_media {
                        l *= spectral_weight(pt, qs);
                    }
                    (l, None)
                }
            };
            if l == Vec3::ZERO || !l.is_finite() {
                continue;
            }
            total += l * mis_weight(scene, &at.camera, camera, light, sampled.as_ref(), s, t);
        }
    }
    total
}

/// The s = 1 strategy at camera vertex `pt`: a light sampled from it with its stored numbers
/// (chosen as the scene's light choice does at `ctx`, `pt`'s point and shading normal), the unoccluded contribution, the light's
/// vertex (its `pdf_fwd` that choice's density) and the sample's density per solid angle (the
/// light's choice included; infinite for a point or spot light).
pub(super) fn sample_light(
    scene: &PreparedScene,
    at: &At<'_>,
    pt: &Vertex,
    ctx: &ShadingContext,
    stats: &mut Stats,
) -> Option<(Vec3, Vertex, f32)> {
    pt.bsdf?;
    let [u_choice, ux, uy] = pt.u_light;
    let (idx, pmf, ls) = super::shared::sample_light(scene, ctx, u_choice, |_| Vec2::new(ux, uy))?;
    let light = &scene.lights.lights[idx as usize];
    let li = light_radiance(scene, light, &ls);
    let mut v = match ls.point {
        Some(point) => Vertex::new(Kind::Light, point, Vec3::ZERO),
        None => {
            let far = 2.0 * (scene.sphere.1 + (pt.p - scene.sphere.0).length());
            let mut v = Vertex::new(Kind::Light, pt.p + ls.wi * far, Vec3::ZERO);
            v.infinite = true;
            v.wo = -ls.wi;
            v
        }
    };
    v.light = idx;
    v.delta_light = ls.is_delta;
    if let Some(l) = light.on_surface() {
        v.ng = l.normal;
        v.p_error = ls.point_error;
        v.prim = l.prim;
        v.b = ls.barycentrics;
    }
    v.beta = li / (ls.pdf * pmf);
    v.pdf_fwd = if scene.lights.uses_tree() {
        pmf * origin_density(light, v.wo, scene.sphere.1)
    } else {
        v.pdf_light_origin(scene)
    };
    let l = pt.beta * pt.f(pt.wo, ls.wi) * v.beta * pt.ns().dot(ls.wi).abs();
    if l == Vec3::ZERO || !visible(scene, at, pt, &v, stats) {
        return None;
    }
    let l = l * segment_transmittance(scene, pt, &v);
    Some((l, v, if ls.is_delta { f32::INFINITY } else { ls.pdf * pmf }))
}

/// Renders rows `first, first + step, ...` of a camera task with bidirectional path tracing.
pub fn render_rows(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    first: u32,
    step: u32,
) -> (TileAccum, Stats) {
    let mut stats = Stats::default();
    let mut sampler = Sampler::new(seed, task.frame);
    let mut paths = Paths::default();
    let mut pose = None;
    let tile = super::super::render_rows_with(task, first, step, |pixel, s| {
        let (film, lens, shared) = start_sample(scene, &mut sampler, pixel, s);
        let at = At::sample(scene, shared, &mut pose);
        let (camera, light) = (&mut paths.camera, &mut paths.light);
        let unlit = camera_subpath(scene, &at, &mut sampler, film, lens, camera, &mut stats);
        // Its strategies (t >= 2) use at most `max_depth` light vertices: the light's and
        // `max_depth - 1` surface vertices (a longer one only light tracing would connect).
        light_subpath(
            scene,
            &at,
            &mut sampler,
            scene.max_depth.saturating_sub(1),
            light,
            &mut stats,
        );
        unlit + camera_strategies(scene, &at, &paths, &mut stats)
    });
    (tile, stats)
}

/// Renders a light task: for each of its sample indices, the light subpath of every pixel of
/// the frame connected to the camera, each contribution added to the pixel it lands on; the
/// frame's sums of one sample index are that sample of every pixel. `task.rect` is the whole
/// frame. The light tile's sample indices run over `bdpt.light_paths` times the pixel samples
/// (index `i` draws its shared numbers as pixel sample `i` and starts its light subpaths from
/// the frame-wide sequences, `light_film`).
///
/// A sample index's film is one thread's (its pixels' light subpaths added in pixel order), and
/// the films enter the sums in sample order, so the result is the same bits on any number of
/// `threads`; up to `threads` films are made at once (fewer where a frame's film is large:
/// `LIGHT_FILMS_BYTES`).
pub fn render_light_task(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    threads: usize,
) -> (TileAccum, Stats) {
    let rect = task.rect;
    let width = scene.camera.width as u32;
    let mut tile = TileAccum::new(rect);
    let mut stats = Stats::default();
    let film_bytes = (scene.camera.width * scene.camera.height) as usize * size_of::<Vec3>();
    let wave = threads.min(LIGHT_FILMS_BYTES / film_bytes.max(1)).max(1);
    let samples: Vec<u32> = (task.samples.start..task.samples.end).collect();
    for chunk in samples.chunks(wave) {
        let films: Vec<(Vec<Vec3>, Stats)> = if chunk.len() == 1 {
            vec![light_film(scene, seed, task.frame, chunk[0])]
        } else {
            std::thread::scope(|scope| {
                let handles: Vec<_> = chunk
                    .iter()
                    .map(|&s| scope.spawn(move || light_film(scene, seed, task.frame, s)))
                    .collect();
                handles.into_iter().map(|h| h.join().expect("light thread panicked")).collect()
            })
        };
        for (&s, (film, film_stats)) in chunk.iter().zip(films) {
            stats.rays += film_stats.rays;
            for row in 0..rect.height {
                for col in 0..rect.width {
                    let l = film[((rect.y0 + row) * width + rect.x0 + col) as usize];
                    tile.add_sample(col, row, s, l.to_array());
                }
            }
        }
    }
    (tile, stats)
}

/// Most bytes of light-tracing films a light task holds at once (a 4K frame's film is 100 MB).
const LIGHT_FILMS_BYTES: usize = 512 << 20;

/// The frame-wide sequences light-traced subpaths start from (`frame_start`).
const LIGHT_TRACING_SEQUENCES: FrameSequences = [0x6c74_7261_6365_0000, 0x6c74_7261_6365_0001];

/// The sampler dimension a light task's light subpath walks from: apart from the numbers of the
/// camera task's subpaths of the same pixel sample (a camera subpath takes at most 8 x 1,026 from
/// 0, its light subpath as many from `LIGHT_DIMENSION`, `max_depth` being at most 1,024), so
/// that the camera-traced and light-traced films are independent estimates but for the
/// sample's shared numbers.
const LIGHT_TRACING_DIMENSION: u32 = LIGHT_DIMENSION + (1 << 15);

/// Sample `s` of the light-traced image of frame `frame`: every pixel's light subpath of that
/// sample connected to the camera, added where each lands, in pixel order. The subpaths start
/// from one frame-wide sequence (`frame_start`, pixel `j` of the frame's pixels as photon `j` of
/// a pass), so that together they cover the lights' points and directions evenly and where they
/// land varies less than where independent subpaths would; they walk on by the pixel sample's
/// numbers from `LIGHT_TRACING_DIMENSION`. They are not the camera task's light subpaths of the
/// same samples: each strategy is an unbiased estimate on its own, whatever subpaths the others
/// draw.
fn light_film(scene: &PreparedScene, seed: u64, frame: i64, s: u32) -> (Vec<Vec3>, Stats) {
    let (width, height) = (scene.camera.width as u32, scene.camera.height as u32);
    let mut film = vec![Vec3::ZERO; (width * height) as usize];
    let mut stats = Stats::default();
    if !scene.camera.connectable() {
        return (film, stats);
    }
    let mut sampler = Sampler::new(seed, frame);
    let mut light = Vec::new();
    let mut pose = None;
    let pixels = (width * height) as u64;
    for y in 0..height {
        for x in 0..width {
            // The camera task's shared numbers for this sample (its film and lens numbers unused).
            let (_, _, shared) = start_sample(scene, &mut sampler, UVec2::new(x, y), s);
            let at = At::sample(scene, shared, &mut pose);
            let j = (y * width + x) as u64;
            let start = frame_start(&mut sampler, LIGHT_TRACING_SEQUENCES, pixels, j, s);
            sampler.set_dimension(LIGHT_TRACING_DIMENSION);
            let max = scene.max_depth;
            let (path, st) = (&mut light, &mut stats);
            leave_still_light(scene, &at, &mut sampler, start, start[4], 1.0, max, path, st);
            splat_light_path(scene, &at, &light, &mut film, &mut stats);
        }
    }
    (film, stats)
}

/// Connects each vertex of a light subpath (from the second on) to the camera (t = 1) and adds
/// the weighted contributions to the film; a thin lens's point comes from the numbers the vertex
/// drew for it (`u_light`).
fn splat_light_path(
    scene: &PreparedScene,
    at: &At<'_>,
    light: &[Vertex],
    film: &mut [Vec3],
    stats: &mut Stats,
) {
    let camera = &at.camera;
    let max_depth = scene.max_depth as usize;
    for s in 2..=light.len() {
        if s - 1 > max_depth {
            break;
        }
        let qs = &light[s - 1];
        if qs.bsdf.is_none() {
            continue;
        }
        let lens = camera.lens_point(Vec2::new(qs.u_light[1], qs.u_light[2]));
        let d = lens - qs.p;
        let d2 = d.length_squared();
        if !(d2 > 0.0) {
            continue;
        }
        let wi = d / d2.sqrt();
        let Some(imp) = camera.importance(lens, -wi) else { continue };
        let cos_cam = (camera.camera.to_world.transpose() * -wi).z.abs();
        let pdf = d2 / (cos_cam * camera.camera.lens_area());
        let mut v = Vertex::new(Kind::Camera, lens, Vec3::splat(imp.we / pdf));
        v.pdf_fwd = 0.0;
        let l = qs.beta * qs.f(wi, qs.wo) * v.beta * qs.ns().dot(wi).abs();
        if l == Vec3::ZERO || !l.is_finite() || !visible(scene, at, qs, &v, stats) {
            continue;
        }
        let l = at.tint(l * segment_transmittance(scene, qs, &v), qs.tints());
        let w = mis_weight(scene, camera, &[], light, Some(&v), s, 1);
        let (width, height) = (camera.camera.width as u32, camera.camera.height as u32);
        let px = imp.film.as_uvec2();
        let i = (px.y.min(height - 1) * width + px.x.min(width - 1)) as usize;
        film[i] += l * w;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// With one hero channel for both subpaths, a joined path's light is unbiased: averaged over
    /// the hero (drawn uniformly), the density of drawing all the path's free flights by it,
    /// times each subpath's weight (one over the mean of its own densities) and
    /// `spectral_weight`, is 1 whatever the subpaths' densities per channel. Without the factor
    /// it is not where the channels' densities move together (the joined path's mean of products
    /// against the product of means).
    #[test]
    fn spectral_weight_makes_a_shared_hero_unbiased() {
        let cases = [
            ([1.0, 2.0, 3.0], [3.0, 0.5, 0.1]),
            ([0.01, 5.0, 1.0], [2.0, 2.0, 2.0]),
            ([1e-3, 1.0, 1e3], [1e3, 1.0, 1e-3]),
            ([4.0, 1.0, 0.25], [4.0, 1.0, 0.25]),
        ];
        for (pa, pb) in cases {
            let (pa, pb) = (Vec3::from(pa), Vec3::from(pb));
            let (ma, mb) = (pa.element_sum() / 3.0, pb.element_sum() / 3.0);
            let mut a = Vertex::new(Kind::Surface, Vec3::ZERO, Vec3::ONE);
            let mut b = a;
            (a.ratios, b.ratios) = (pa / ma, pb / mb);
            let unweighted: f32 = (0..3).map(|h| pa[h] * pb[h] / (ma * mb) / 3.0).sum();
            let weighted = unweighted * spectral_weight(&a, &b);
            assert!((weighted - 1.0).abs() < 1e-5, "{pa} {pb}: {weighted}");
            if pa == pb {
                assert!(unweighted > 1.5, "{pa}: {unweighted}");
            }
        }
        // A subpath without free flights leaves the other's weight alone.
        let mut a = Vertex::new(Kind::Surface, Vec3::ZERO, Vec3::ONE);
        a.ratios = Vec3::new(0.5, 1.0, 1.5);
        let b = Vertex::new(Kind::Surface, Vec3::ZERO, Vec3::ONE);
        assert_eq!(spectral_weight(&a, &b), 1.0);
    }
}
