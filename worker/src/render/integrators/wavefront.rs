//! The wavefront renderer: the same path tracer as `path::li`, run on 8 (AVX2) or 16
//! (AVX-512) paths at once, its shading arithmetic in SIMD across the paths.
//!
//! For the scenes `wavefront_tables::Tables::new` accepts (nothing moving, no dispersion, no
//! scattering medium; the others render on the scalar path tracer, and `prepare` logs why
//! once), it shades diffuse and glTF metal-rough materials (the lobes of
//! `bsdf::metal_rough`, thin-walled transmission included), textured, normal-mapped,
//! vertex-coloured and alpha-tested or not, under any lights and environment, chosen by the
//! mixture or the light tree (the Cornell box, the furnaces, Veach's glossy plates and the
//! damaged helmet among them). A layered material keeps its paths: a clear coat and a sheen
//! over the (anisotropic or isotropic) metal-rough base are shaded on the vectors
//! (`bsdf::layered::generic::Coated`); with a thin film, or at a dielectric boundary (glass,
//! smooth or rough), the BSDF at the point is evaluated, weighed and sampled one lane at a time
//! by the scalar `Bsdf` (`shared::surface_bsdf`), and the rest of the bounce runs on the
//! vectors. In a scene with volumes (`Tables::media`) each lane tracks the media its path is
//! inside, from those the camera lies in, as `path::li` does: Beer-Lambert along each segment,
//! false interfaces passed without a bounce (`shared::meet_surface`), the relative index of the
//! two media at a boundary, the refracting frame, the far side's medium for a shadow ray, and
//! eta² in Russian roulette. An unlit material ends its paths with its base colour, one lane at
//! a time. Every material is shaded here (`wavefront_tables::wavefront_bsdf` names every field
//! of `Material`, so a new one is decided before it compiles). At a textured (or vertex-coloured) material, the point's
//! emission, shading frame and BSDF parameters are found one lane at a time by the scalar
//! renderer's calls (`material`, `shared::shading_frame`, `shared::hit_weight`), and a
//! textured emitter is sampled by `Light::sample_li` and `shared::light_radiance`. Each lane holds one
//! path; a lane whose path ends takes the task's next sample at once (one whose ray escapes,
//! before the shading), so that the vectors stay full whatever the path lengths. Ray casting,
//! the start of a sample (its film and lens numbers), the light choice (and under the tree, the
//! probability of the light a path hits, from the lane's previous vertex), samples of lights
//! other than emissive triangles and what escaping rays see stay scalar, one lane at a time,
//! through the scalar renderer's own calls. The numbers each bounce draws come from
//! `LaneSampler`, the sampler's integer arithmetic in all lanes at once, and the shading (hit
//! point, frame, BSDF evaluation and sampling, MIS weights, light sampling, ray origins,
//! roulette) is the scalar renderer's own routines instantiated on vectors (`lanes::Real`: the
//! `generic` modules of `geometry`, `sampling`, `bsdf::diffuse`, `bsdf::metal_rough`, `light`
//! and `shared`), so every lane computes the scalar path's bits, and samples reach the film in
//! the scalar order: the images are bit for bit those of `path::li` on every CPU (a test
//! compares them). A batch in which no lane is glossy does none of the metal-rough arithmetic.
//!
//! `pulp` picks AVX-512 or AVX2 at run time; a CPU with neither uses the scalar renderer.

use arrayvec::ArrayVec;
use common::{film::TileAccum, protocol::TaskSpec};
use glam::{UVec2, Vec2, Vec3};
use pulp::{Arch, Simd, WithSimd};

use super::{
    super::{
        bsdf::{
            diffuse::generic as lambert,
            layered::generic::{CoatLanes, Coated, SheenLanes},
            metal_rough::generic::{self as metal_rough, Lobes, Seen},
            Bsdf, MetalRough,
        },
        geometry::{
            self,
            generic::{frame_from_z, interpolation_error, offset_ray_origin},
            Frame, Ray,
        },
        lanes::{F, M, V3},
        light::{
            generic::{pdf_li as triangle_pdf_li, sample_li as triangle_sample_li, TriangleSample},
            Light, ShadingContext, CHOOSE_BATCH,
        },
        material,
        media::{self, transmittance, MediumStack},
        sampler::{LaneSampler, Sampler},
        sampling::generic::{Aniso, Iso},
        scene::PreparedScene,
        wavefront_tables::Tables,
    },
    shared::{
        environment_hit,
        generic::{power_heuristic, roulette_end, same_side},
        hit_error, hit_weight, light_radiance, meet_surface, mis_pdf, shading_frame, surface_bsdf,
        Meeting, Stats, RR_MIN_DEPTH, SHADOW_T_MAX, UNWEIGHTED,
    },
};

/// The most lanes a vector has (AVX-512's 16 f32s).
const MAX_LANES: usize = 16;
// The light choice takes all lanes in one batch.
const _: () = assert!(MAX_LANES <= CHOOSE_BATCH);

/// Samples that may be in flight or finished but not yet added to the film: a lane waits
/// rather than run further ahead of the oldest unfinished sample.
const WINDOW: usize = 4096;

/// Paths the wavefront runs at once on this CPU (16 with AVX-512, 8 with AVX2), or 0 when
/// it has neither and the scalar renderer runs instead.
pub fn lanes() -> usize {
    match Arch::new() {
        Arch::V3(s) => lanes_of(s),
        Arch::V4(s) => lanes_of(s),
        _ => 0,
    }
}

fn lanes_of<S: Simd>(_: S) -> usize {
    S::F32_LANES.min(MAX_LANES)
}

/// Renders rows `first, first + step, ...` of the task's tile with the wavefront, or returns
/// `None` when this CPU has neither AVX2 nor AVX-512 (the caller then renders them scalar).
pub fn render_rows(
    scene: &PreparedScene,
    tables: &Tables,
    seed: u64,
    task: &TaskSpec,
    first: u32,
    step: u32,
) -> Option<(TileAccum, Stats)> {
    let arch = Arch::new();
    if matches!(arch, Arch::Scalar) {
        return None;
    }
    Some(arch.dispatch(Job { scene, tables, seed, task, first, step }))
}

/// Renders rows `first, first + step, ...` with the wavefront on `lanes` emulated lanes (4, 8
/// or 16: `pulp`'s portable 128-, 256- and 512-bit vectors, plain per-lane code), whatever the
/// CPU: what tests use to check the 16-lane logic on a CPU without AVX-512. `None` for another
/// lane count.
pub fn render_rows_portable(
    scene: &PreparedScene,
    tables: &Tables,
    seed: u64,
    task: &TaskSpec,
    (first, step): (u32, u32),
    lanes: usize,
) -> Option<(TileAccum, Stats)> {
    let job = Job { scene, tables, seed, task, first, step };
    match lanes {
        4 => Some(job.with_simd(pulp::Scalar128b)),
        8 => Some(job.with_simd(pulp::Scalar256b)),
        16 => Some(job.with_simd(pulp::Scalar512b)),
        _ => None,
    }
}

struct Job<'a> {
    scene: &'a PreparedScene,
    tables: &'a Tables,
    seed: u64,
    task: &'a TaskSpec,
    first: u32,
    step: u32,
}

impl WithSimd for Job<'_> {
    type Output = (TileAccum, Stats);

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Self::Output {
        run(simd, self)
    }
}

/// The task's samples in the scalar renderer's order (rows, then pixels, then sample indices),
/// and the finished ones waiting for their turn to reach the film.
struct Stream {
    rows: Vec<u32>,
    width: u32,
    samples: std::ops::Range<u32>,
    /// Where the next item to start lies: index into `rows`, tile column, sample index.
    cursor: (usize, u32, u32),
    issued: u64,
    flushed: u64,
    /// Per item number modulo their count (`WINDOW`, or the task's items rounded up to a power
    /// of two when fewer: the window of a small task never fills, so its size changes nothing
    /// but the memory a task sets up).
    slots: Vec<Slot>,
}

/// A sample in flight or waiting for the film.
#[derive(Clone, Copy, Debug, Default)]
struct Slot {
    /// Tile column, tile row and sample index.
    at: (u32, u32, u32),
    /// The radiance, once the path has ended.
    rgb: Option<[f32; 3]>,
}

impl Stream {
    fn new(task: &TaskSpec, first: u32, step: u32) -> Self {
        let rows: Vec<u32> = (first..task.rect.height).step_by(step.max(1) as usize).collect();
        let items = rows.len() as u64 * task.rect.width as u64 * task.samples.len() as u64;
        let window = items.clamp(1, WINDOW as u64).next_power_of_two() as usize;
        Stream {
            rows,
            width: task.rect.width,
            samples: task.samples.start..task.samples.end,
            cursor: (0, 0, task.samples.start),
            issued: 0,
            flushed: 0,
            slots: vec![Slot::default(); window],
        }
    }

    /// Item `k`'s slot (the slot count is a power of two).
    #[inline]
    fn slot(&self, k: u64) -> usize {
        k as usize & (self.slots.len() - 1)
    }

    /// The next item to start: its number, tile column, tile row and sample index; `None` when
    /// all are started or the window is full.
    #[inline]
    fn next(&mut self) -> Option<(u64, u32, u32, u32)> {
        let (r, col, s) = self.cursor;
        if r == self.rows.len()
            || self.width == 0
            || self.samples.is_empty()
            || self.issued - self.flushed >= self.slots.len() as u64
        {
            return None;
        }
        let k = self.issued;
        let row = self.rows[r];
        let at = self.slot(k);
        self.slots[at] = Slot { at: (col, row, s), rgb: None };
        self.cursor = if s + 1 < self.samples.end {
            (r, col, s + 1)
        } else if col + 1 < self.width {
            (r, col + 1, self.samples.start)
        } else {
            (r + 1, 0, self.samples.start)
        };
        self.issued += 1;
        Some((k, col, row, s))
    }

    /// Records item `k`'s radiance and adds every finished item that is next in order.
    #[inline]
    fn finish(&mut self, k: u64, rgb: [f32; 3], tile: &mut TileAccum) {
        let at = self.slot(k);
        self.slots[at].rgb = Some(rgb);
        while self.flushed < self.issued {
            let at = self.slot(self.flushed);
            let slot = &mut self.slots[at];
            let Some(rgb) = slot.rgb.take() else { break };
            let (col, row, s) = slot.at;
            tile.add_sample(col, row, s, rgb);
            self.flushed += 1;
        }
    }
}

/// The per-lane state of the paths in flight.
struct Paths<S: Simd> {
    origin: V3<F<S>>,
    dir: V3<F<S>>,
    beta: V3<F<S>>,
    radiance: V3<F<S>>,
    prev_bsdf_pdf: F<S>,
    /// The previous vertex's point and shading normal, where a light's probability depends on
    /// them (`path::li`'s `prev_ctx`): kept only under the light tree.
    prev_p: V3<F<S>>,
    prev_n: V3<F<S>>,
    depth: [u32; MAX_LANES],
    item: [u64; MAX_LANES],
    alive: [bool; MAX_LANES],
    /// Each lane's sampler while its sample starts (film and lens numbers, drawn lane by lane).
    sampler: [Sampler; MAX_LANES],
    /// The same samplers as vectors, for the numbers every bounce draws in all lanes at once.
    draws: LaneSampler<S>,
    /// In a scene with volumes (`Tables::media`): the volumes each path is inside, the false
    /// interfaces it has passed, and the product of eta² over its refractions (`path::li`'s
    /// `media`, `passed` and `eta_scale`; 1 elsewhere).
    media: [MediumStack; MAX_LANES],
    passed: [u32; MAX_LANES],
    eta_scale: F<S>,
}

impl<S: Simd> Paths<S> {
    /// Lane `i`'s previous vertex as a light choice sees it.
    #[inline]
    fn prev_ctx(&self, i: usize) -> ShadingContext {
        ShadingContext { p: self.prev_p.lane(i), n: self.prev_n.lane(i) }
    }
}

#[inline(always)]
fn run<S: Simd>(s: S, job: Job<'_>) -> (TileAccum, Stats) {
    let Job { scene, tables, seed, task, first, step } = job;
    // The mixture's probabilities are baked into `tables.lights`; the tree's are asked per lane.
    let mixture = scene.lights.mixture();
    let lanes = S::F32_LANES.min(MAX_LANES);
    let mut tile = TileAccum::new(task.rect);
    let mut stats = Stats::default();
    let mut stream = Stream::new(task, first, step);
    let zero = F::splat(s, 0.0);
    let one = F::splat(s, 1.0);
    let z3 = V3::splat(s, Vec3::ZERO);
    let sampler = Sampler::new(seed, task.frame);
    let mut paths = Paths {
        origin: z3,
        dir: z3,
        beta: z3,
        radiance: z3,
        prev_bsdf_pdf: zero,
        prev_p: z3,
        prev_n: z3,
        depth: [0; MAX_LANES],
        item: [0; MAX_LANES],
        alive: [false; MAX_LANES],
        sampler: std::array::from_fn(|_| sampler.clone()),
        draws: LaneSampler::new(s),
        media: [scene.camera_media; MAX_LANES],
        passed: [0; MAX_LANES],
        eta_scale: one,
    };
    // Per-bounce data gathered lane by lane.
    let (mut t, mut b1, mut b2) = (zero, zero, zero);
    let mut tri = [z3; 3];
    let mut normals = [z3; 3];
    let mut smooth = [false; MAX_LANES];
    let (mut albedo, mut le) = (z3, z3);
    // The metal-rough BSDF of the lanes whose material is glossy.
    let mut glossy = [false; MAX_LANES];
    // The glossy lanes whose BSDF passes light through (thin-walled transmission).
    let mut transmits = [false; MAX_LANES];
    // The lanes whose material is textured (shaded per point, one lane at a time), and the
    // triangle each lane hit.
    let mut textured = [false; MAX_LANES];
    let mut prims = [0u32; MAX_LANES];
    // The lanes whose BSDF is layered without a thin film: a clear coat and a sheen (or
    // neither) over an anisotropic metal-rough base in `lobes` (`layered::generic::Coated`),
    // and their coats and sheens.
    let mut coated = [false; MAX_LANES];
    let (mut has_coat, mut has_sheen) = ([false; MAX_LANES], [false; MAX_LANES]);
    let (mut alpha_x, mut alpha_y) = (one, one);
    let mut coat = CoatLanes { weight: zero, alpha: one, normal: z3 };
    let mut sheen = SheenLanes { color: z3, alpha: one };
    // The lanes whose BSDF is layered with a thin film: evaluated, weighed and sampled one
    // lane at a time by the scalar renderer's `Bsdf`.
    let mut layered = [false; MAX_LANES];
    let mut layers = [None::<Bsdf>; MAX_LANES];
    // The shading normal of the lanes whose refracting frame replaced it (the facet's): the
    // light choice and the next hit's weight see the point by it, as in `path::li`.
    let mut unbent = [None::<Vec3>; MAX_LANES];
    // In a scene with volumes, the lanes at a volume's boundary (`shared::meet_surface`), those
    // of them that refract, the side each lane's ray meets, the geometric normal on that side,
    // the material hit and the medium beyond.
    let mut boundary = [false; MAX_LANES];
    let mut refracting = [false; MAX_LANES];
    let mut faces = [false; MAX_LANES];
    let mut ng_front = [Vec3::ZERO; MAX_LANES];
    let mut mats = [0u32; MAX_LANES];
    let mut beyond = [None::<u32>; MAX_LANES];
    let mut lobes = Lobes {
        base: z3,
        metallic: zero,
        f0: z3,
        specular: zero,
        transmission: zero,
        diffuse_transmission: zero,
        diffuse_transmission_color: z3,
        seen: None,
    };
    let mut alpha = one;
    let (mut l_normal, mut l_area, mut l_prob) = (z3, zero, zero);
    let mut hit_light = [false; MAX_LANES];
    let mut l_two_sided = [false; MAX_LANES];
    let mut live = [false; MAX_LANES];
    let mut first_bounce = [false; MAX_LANES];
    let mut cont = [false; MAX_LANES];
    let mut has_light = [false; MAX_LANES];
    let mut other_light = [false; MAX_LANES];
    let mut other_ok = [false; MAX_LANES];
    let mut at_infinity = [false; MAX_LANES];
    let mut delta = [false; MAX_LANES];
    let (mut o_wi, mut o_li, mut o_pdf) = (z3, z3, zero);
    let (mut o_point, mut o_normal, mut o_point_error) = (z3, z3, z3);
    let mut nee_two_sided = [false; MAX_LANES];
    let mut shadow = [false; MAX_LANES];
    let mut unblocked = [false; MAX_LANES];
    let mut roulette = [false; MAX_LANES];
    let mut survive = [false; MAX_LANES];
    let (mut ul_x, mut ul_y, mut choice_pdf) = (zero, zero, zero);
    let mut lp = [z3; 3];
    let (mut ln, mut la, mut lem) = (z3, zero, z3);
    loop {
        // Every lane gets a path with a hit to shade: idle lanes start the next sample
        // (`render::sample`, static scene) and cast, and a lane whose ray escapes takes the next
        // one at once, so that shading runs on full vectors however short the paths.
        live[..lanes].fill(false);
        // The lanes that hit a light which the tree chooses from their previous vertex: (lane,
        // that vertex, the light).
        let mut asks = ArrayVec::<(usize, ShadingContext, u32), MAX_LANES>::new();
        loop {
            for i in 0..lanes {
                if paths.alive[i] {
                    continue;
                }
                let Some((k, col, row, sample_idx)) = stream.next() else { continue };
                let pixel = UVec2::new(task.rect.x0 + col, task.rect.y0 + row);
                let sm = &mut paths.sampler[i];
                sm.start_pixel_sample(pixel, sample_idx);
                let film = pixel.as_vec2() + sm.next_2d();
                let lens = if scene.camera.has_lens() { sm.next_2d() } else { Vec2::ZERO };
                paths.draws.set_lane(i, sm);
                let ray = scene.camera.generate_ray(film, lens);
                paths.origin.set_lane(i, ray.origin);
                paths.dir.set_lane(i, ray.dir);
                paths.beta.set_lane(i, Vec3::ONE);
                paths.radiance.set_lane(i, Vec3::ZERO);
                paths.prev_bsdf_pdf.set_lane(i, UNWEIGHTED);
                paths.depth[i] = 0;
                paths.item[i] = k;
                paths.alive[i] = true;
                if tables.media {
                    paths.media[i] = scene.camera_media;
                    paths.passed[i] = 0;
                    paths.eta_scale.set_lane(i, 1.0);
                }
            }
            // Closest hits, and what shading needs of the triangles hit.
            let mut cast = false;
            for i in 0..lanes {
                if !paths.alive[i] || live[i] {
                    continue;
                }
                cast = true;
                stats.rays += 1;
                let ray = Ray::new(paths.origin.lane(i), paths.dir.lane(i));
                // `PreparedScene::intersect` for a static scene (all that `Tables::new`
                // accepts): without cut-outs the BVH alone, its traversal compiled into this
                // kernel for its instruction set (12% off a sample of the Cornell box on Zen 4).
                let found = if scene.alpha_tested {
                    scene.intersect(&ray, f32::INFINITY, None)
                } else {
                    scene.accel.intersect_inlined(&ray, f32::INFINITY)
                };
                if tables.media {
                    // Beer-Lambert along the segment inside the volume the path is in (an
                    // escape is endless).
                    let medium = paths.media[i].current();
                    if let Some(v) =
                        medium.and_then(|m| scene.materials[m as usize].volume.as_ref())
                    {
                        let distance = found.map_or(f32::INFINITY, |h| h.t * ray.dir.length());
                        paths.beta.set_lane(i, paths.beta.lane(i) * transmittance(v, distance));
                    }
                }
                let Some(hit) = found else {
                    // What the escaping ray sees (the path tracer's miss, one lane).
                    let seen = paths.depth[i] > 0 || scene.environment_visible;
                    if seen && scene.environment.is_some() {
                        let l = environment_hit(
                            scene,
                            paths.beta.lane(i),
                            ray.dir,
                            &paths.prev_ctx(i),
                            paths.prev_bsdf_pdf.lane(i),
                        );
                        paths.radiance.set_lane(i, paths.radiance.lane(i) + l);
                    }
                    paths.alive[i] = false;
                    stream.finish(paths.item[i], paths.radiance.lane(i).to_array(), &mut tile);
                    continue;
                };
                let shading = scene.shading[hit.prim as usize];
                boundary[i] = false;
                refracting[i] = false;
                // A material without volumes, layers or unlit is no boundary (one test).
                if tables.media && shading.extended {
                    // What the path meets as to its volumes: a false interface is passed
                    // without a bounce (the lane casts on from it), and a real boundary is
                    // shaded with the media on its two sides.
                    let (q, _) = scene.triangle(hit.prim, None);
                    // A degenerate triangle ends the path below, as the path tracer's does.
                    if let Some(ng) = (q[1] - q[0]).cross(q[2] - q[0]).try_normalize() {
                        let facing = ng.dot(-ray.dir) > 0.0;
                        let material = shading.material;
                        let (media, passed) = (&mut paths.media[i], &mut paths.passed[i]);
                        match meet_surface(scene, material, shading.extended, facing, media, passed)
                        {
                            Meeting::Surface { boundary: b, beyond: far } => {
                                boundary[i] = b;
                                faces[i] = facing;
                                ng_front[i] = if facing { ng } else { -ng };
                                mats[i] = material;
                                beyond[i] = far;
                                refracting[i] = b && scene.materials[material as usize].refracts();
                            }
                            Meeting::Passed => {
                                let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
                                let at = q[0] * b[0] + q[1] * b[1] + q[2] * b[2];
                                let error = hit_error(q, b, false);
                                let origin = geometry::offset_ray_origin(at, error, ng, ray.dir);
                                paths.origin.set_lane(i, origin);
                                continue;
                            }
                            Meeting::Stuck => {
                                paths.alive[i] = false;
                                let rgb = paths.radiance.lane(i).to_array();
                                stream.finish(paths.item[i], rgb, &mut tile);
                                continue;
                            }
                        }
                    }
                }
                if shading.extended && scene.materials[shading.material as usize].unlit {
                    let material = &scene.materials[shading.material as usize];
                    // `KHR_materials_unlit`: the base colour, seen as it is; nothing goes on
                    // from it (a degenerate triangle shows nothing, as in `path::li`).
                    let (q, _) = scene.triangle(hit.prim, None);
                    if (q[1] - q[0]).cross(q[2] - q[0]).try_normalize().is_some() {
                        let b = [1.0 - hit.b1 - hit.b2, hit.b1, hit.b2];
                        let sp = scene.shading_point(hit.prim, q, b);
                        let base = material::clamped_base_color(&scene.textures, material, &sp);
                        let radiance = paths.beta.lane(i) * base;
                        paths.radiance.set_lane(i, paths.radiance.lane(i) + radiance);
                    }
                    paths.alive[i] = false;
                    stream.finish(paths.item[i], paths.radiance.lane(i).to_array(), &mut tile);
                    continue;
                }
                live[i] = true;
                first_bounce[i] = paths.depth[i] == 0;
                t.set_lane(i, hit.t);
                b1.set_lane(i, hit.b1);
                b2.set_lane(i, hit.b2);
                let (p, _) = scene.triangle(hit.prim, None);
                for (v, q) in tri.iter_mut().zip(p) {
                    v.set_lane(i, q);
                }
                smooth[i] = shading.smooth;
                if shading.smooth {
                    for (v, &k) in normals.iter_mut().zip(&shading.vertices) {
                        v.set_lane(i, scene.normals[k as usize]);
                    }
                }
                albedo.set_lane(i, tables.albedo[shading.material as usize]);
                prims[i] = hit.prim;
                textured[i] = tables.textured[shading.material as usize];
                glossy[i] = false;
                coated[i] = false;
                layered[i] = false;
                transmits[i] = false;
                if let Some(b) = &tables.glossy[shading.material as usize] {
                    glossy[i] = true;
                    transmits[i] = b.transmits();
                    set_lobes(&mut lobes, &mut alpha, i, b);
                }
                le.set_lane(i, tables.emission[shading.material as usize]);
                // A textured material's emission is found with its shading, below.
                hit_light[i] = false;
                let light = tables.lights.get(shading.light as usize).and_then(Option::as_ref);
                if let (false, Some(l)) = (textured[i], light) {
                    hit_light[i] = true;
                    l_normal.set_lane(i, l.normal);
                    l_area.set_lane(i, l.area);
                    // Under the tree, the probability of choosing the light from the previous
                    // vertex (the first hit takes no weight, nor a light seen from behind).
                    // The tree's are asked for all lanes at once, below.
                    let behind = !l.two_sided && l.normal.dot(paths.dir.lane(i)) >= 0.0;
                    if mixture.is_some() || first_bounce[i] || behind {
                        l_prob.set_lane(i, l.probability);
                    } else {
                        asks.push((i, paths.prev_ctx(i), shading.light));
                    }
                    l_two_sided[i] = l.two_sided;
                }
            }
            if !cast {
                break;
            }
        }
        if !live[..lanes].iter().any(|&l| l) {
            break; // Every sample of the task is done.
        }
        if !asks.is_empty() {
            let (mut ctx, mut light) = ([ShadingContext::default(); MAX_LANES], [0; MAX_LANES]);
            for (k, &(_, c, l)) in asks.iter().enumerate() {
                (ctx[k], light[k]) = (c, l);
            }
            let mut prob = [0.0; MAX_LANES];
            let n = asks.len();
            scene.lights.pmf_batch(&ctx[..n], &light[..n], &mut prob[..n]);
            for (&(i, _, _), &p) in asks.iter().zip(&prob) {
                l_prob.set_lane(i, p);
            }
        }

        // The hit point, its emission, its frame.
        let livem = M::from_bools(s, &live);
        let b0 = (one - b1) - b2;
        let p = tri[0].scale(b0) + tri[1].scale(b1) + tri[2].scale(b2);
        let p_error = interpolation_error(tri, [b0, b1, b2]);
        let c = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
        let rcp = one / c.length_squared().sqrt();
        let ng_ok = rcp.is_finite() & rcp.gt(zero);
        let ng = c.scale(rcp);
        let dir = paths.dir;
        let wo = -dir;
        let emits = M::from_bools(s, &l_two_sided) | l_normal.dot(wo).gt(zero);
        let dist2 = (t * t) * dir.length_squared();
        let pdf_li = triangle_pdf_li(l_normal, l_area, dir, dist2);
        let weight = M::from_bools(s, &first_bounce)
            .select(one, power_heuristic(paths.prev_bsdf_pdf, l_prob * pdf_li));
        let add = livem & ng_ok & M::from_bools(s, &hit_light) & emits;
        paths.radiance =
            add.select3(paths.radiance + paths.beta.mul(le).scale(weight), paths.radiance);
        let ng = ng.dot(wo).lt(zero).select3(-ng, ng);
        // The shading normal: interpolated vertex normals turned to ng's side, else ng.
        let n = normals[0].scale(b0) + normals[1].scale(b1) + normals[2].scale(b2);
        let n_rcp = one / n.length_squared().sqrt();
        let n = n.scale(n_rcp);
        let n_dot = n.dot(ng);
        let use_n = M::from_bools(s, &smooth) & n_rcp.is_finite() & n_rcp.gt(zero);
        let ns = (use_n & n_dot.gt(zero)).select3(n, ng);
        let ns = (use_n & n_dot.lt(zero)).select3(-n, ns);
        let (fx, fy) = frame_from_z(ns);
        let (mut fx, mut fy, mut ns) = (fx, fy, ns);
        if tables.media {
            unbent[..lanes].fill(None);
        }
        // Textured materials, one lane at a time through the scalar renderer's calls: the
        // emission of the point, the shading frame (normal map) and the BSDF there.
        for i in (0..lanes).filter(|&i| live[i] && textured[i]) {
            let prim = prims[i];
            let shading = scene.shading[prim as usize];
            let m = &scene.materials[shading.material as usize];
            let b = [b0.lane(i), b1.lane(i), b2.lane(i)];
            let corners = [tri[0].lane(i), tri[1].lane(i), tri[2].lane(i)];
            let (dir_i, wo_i) = (dir.lane(i), wo.lane(i));
            let Some(ng_i) = c.lane(i).try_normalize() else { continue };
            let front = ng_i.dot(wo_i) > 0.0;
            let sp = scene.shading_point(prim, corners, b);
            if let Some(light) =
                scene.lights.lights.get(shading.light as usize).and_then(Light::on_surface)
            {
                if light.emits_toward(wo_i) {
                    let le = material::emission_toward(&scene.textures, m, &sp, ng_i, wo_i);
                    let dist2 = t.lane(i) * t.lane(i) * dir_i.length_squared();
                    let prev_pdf = paths.prev_bsdf_pdf.lane(i);
                    let ctx = paths.prev_ctx(i);
                    let weight = hit_weight(scene, shading.light, &ctx, dir_i, dist2, prev_pdf);
                    let radiance = paths.radiance.lane(i) + paths.beta.lane(i) * le * weight;
                    paths.radiance.set_lane(i, radiance);
                }
            }
            let ng_i = if front { ng_i } else { -ng_i };
            let (mut frame, ns_surface) =
                shading_frame(scene, prim, corners, b, ng_i, wo_i, &sp, None);
            let mut iors = [1.0; 2];
            if boundary[i] {
                // `path::li`'s refracting frame (the facet's where the interpolated normal
                // turns away from wo) and the relative index of the media on the two sides.
                if refracting[i] && frame.to_local(wo_i).z <= 0.0 {
                    unbent[i] = Some(frame.z);
                    frame = Frame::from_z(ng_i);
                }
                let other = if front { paths.media[i].current() } else { beyond[i] };
                let ior = |m| media::ior(&scene.materials, m, None);
                iors = [ior(Some(mats[i])), ior(other)];
            }
            fx.set_lane(i, frame.x);
            fy.set_lane(i, frame.y);
            ns.set_lane(i, frame.z);
            let at = (prim, corners, b);
            match surface_bsdf(scene, at, (&sp, front, iors), (&frame, ns_surface), None) {
                Bsdf::Diffuse(d) => albedo.set_lane(i, d.albedo),
                Bsdf::MetalRough(b) => {
                    glossy[i] = true;
                    transmits[i] = b.transmits();
                    set_lobes(&mut lobes, &mut alpha, i, &b);
                }
                Bsdf::Layered(l) if l.iridescence.is_none() => {
                    coated[i] = true;
                    transmits[i] = l.transmits();
                    set_base(&mut lobes, i, &l.base.lobes());
                    alpha_x.set_lane(i, l.base.ggx.alpha_x);
                    alpha_y.set_lane(i, l.base.ggx.alpha_y);
                    has_coat[i] = l.coat.is_some();
                    let c = l.coat.map_or(NO_COAT, |c| c.lanes());
                    coat.weight.set_lane(i, c.weight);
                    coat.alpha.set_lane(i, c.alpha);
                    coat.normal.set_lane(i, c.normal.into());
                    has_sheen[i] = l.sheen.is_some();
                    let (color, sheen_alpha) =
                        l.sheen.map_or((Vec3::ZERO, 1.0), |s| (s.color, s.alpha));
                    sheen.color.set_lane(i, color);
                    sheen.alpha.set_lane(i, sheen_alpha);
                }
                // A thin film, or a dielectric boundary: one lane at a time.
                bsdf @ (Bsdf::Layered(_) | Bsdf::Dielectric(_)) => {
                    layered[i] = true;
                    transmits[i] = bsdf.transmits();
                    albedo.set_lane(i, Vec3::ZERO);
                    layers[i] = Some(bsdf);
                }
            }
        }
        let wo_z = wo.dot(ns);
        let going = livem & ng_ok & !wo_z.le(zero);
        going.to_bools(&mut cont);
        // Whether any lane shades a glossy material: if none does (a diffuse scene, or a
        // diffuse batch), the metal-rough arithmetic is not done at all.
        let any_glossy = (0..lanes).any(|i| glossy[i] && live[i]);
        let glossym = M::from_bools(s, &glossy);
        // Whether any lane's BSDF passes light through: if none does, the far side's branch of
        // the metal-rough arithmetic is not done.
        let any_transmits = (0..lanes).any(|i| transmits[i] && live[i]);
        let transm = M::from_bools(s, &transmits);
        // The coated lanes, and the layered ones shaded one at a time (none in most batches).
        let any_coated = (0..lanes).any(|i| coated[i] && live[i]);
        let coatedm = M::from_bools(s, &coated);
        // The albedo tables for this bounce's `wo`, read once for all its calls: at the coated
        // lanes' anisotropic roughness (`Facets::albedo_alpha` of `Aniso`), the glossy lanes'
        // isotropic one elsewhere.
        lobes.seen = None;
        if any_glossy || any_coated {
            let table_alpha = coatedm.select(alpha_x.min(alpha_y), alpha);
            lobes.seen = Some(Seen::new(&lobes, table_alpha, wo_z));
        }
        let coated_bsdf = Coated {
            base: &lobes,
            facets: Aniso(alpha_x, alpha_y),
            coat: &coat,
            has_coat: M::from_bools(s, &has_coat),
            sheen: &sheen,
            has_sheen: M::from_bools(s, &has_sheen),
            coats: (0..lanes).any(|i| coated[i] && has_coat[i] && live[i]),
            sheens: (0..lanes).any(|i| coated[i] && has_sheen[i] && live[i]),
            transmits: any_transmits,
        };
        let any_layered = (0..lanes).any(|i| layered[i] && live[i]);
        let local_frame = any_glossy || any_coated || any_layered;
        let wo_l = if local_frame { V3::new(wo.dot(fx), wo.dot(fy), wo_z) } else { z3 };

        // The bounce's numbers, in `path::li`'s dimensions: the light's pair, the lobe's
        // number (a diffuse BSDF has one lobe: not drawn), the direction's pair, roulette's
        // number (drawn where roulette plays).
        let (u_light_x, u_light_y) = paths.draws.draw_2d(0);
        let u_lobe = if local_frame { paths.draws.draw_1d(1) } else { zero };
        let (ub_x, ub_y) = paths.draws.draw_2d(2);
        let u_rr = paths.draws.draw_1d(3);
        // The light choice: the tree's for all lanes at once.
        let mut choices = [None; MAX_LANES];
        for i in 0..lanes {
            if !live[i] {
                continue;
            }
            if paths.depth[i] >= scene.max_depth {
                cont[i] = false;
            }
            if !cont[i] {
                paths.alive[i] = false;
                stream.finish(paths.item[i], paths.radiance.lane(i).to_array(), &mut tile);
                continue;
            }
            roulette[i] = paths.depth[i] + 1 > RR_MIN_DEPTH;
            has_light[i] = false;
            other_light[i] = false;
            if let Some(m) = mixture {
                choices[i] = m.choose_remapped(u_light_x.lane(i));
            }
        }
        if mixture.is_none() {
            let (mut ctx, mut u, mut asked) =
                ([ShadingContext::default(); MAX_LANES], [0.0; MAX_LANES], [0; MAX_LANES]);
            let mut n = 0;
            for i in (0..lanes).filter(|&i| live[i] && cont[i]) {
                (ctx[n], u[n], asked[n]) = (
                    ShadingContext { p: p.lane(i), n: unbent[i].unwrap_or(ns.lane(i)) },
                    u_light_x.lane(i),
                    i,
                );
                n += 1;
            }
            let mut chosen = [None; MAX_LANES];
            scene.lights.choose_batch(&ctx[..n], &u[..n], &mut chosen[..n]);
            for (&i, &c) in asked[..n].iter().zip(&chosen) {
                choices[i] = c;
            }
        }
        for i in 0..lanes {
            if !live[i] || !cont[i] {
                continue;
            }
            let u_light = Vec2::new(u_light_x.lane(i), u_light_y.lane(i));
            if let Some((light, pdf, u_x)) = choices[i] {
                has_light[i] = true;
                choice_pdf.set_lane(i, pdf);
                ul_x.set_lane(i, u_x);
                ul_y.set_lane(i, u_light.y);
                let Some(l) = &tables.lights[light as usize] else {
                    // A punctual light or the environment: its own sampling routine.
                    other_light[i] = true;
                    let this = &scene.lights.lights[light as usize];
                    let ls = this.sample_li(p.lane(i), Vec2::new(u_x, u_light.y));
                    other_ok[i] = ls.is_some();
                    if let Some(ls) = ls {
                        o_wi.set_lane(i, ls.wi);
                        o_li.set_lane(i, light_radiance(scene, this, &ls));
                        o_pdf.set_lane(i, ls.pdf);
                        o_point.set_lane(i, ls.point.unwrap_or(Vec3::ZERO));
                        o_normal.set_lane(i, ls.normal);
                        o_point_error.set_lane(i, ls.point_error);
                        at_infinity[i] = ls.point.is_none();
                        delta[i] = ls.is_delta;
                    }
                    continue;
                };
                for (v, q) in lp.iter_mut().zip(l.p) {
                    v.set_lane(i, q);
                }
                ln.set_lane(i, l.normal);
                la.set_lane(i, l.area);
                lem.set_lane(i, l.emission);
                nee_two_sided[i] = l.two_sided;
            }
        }
        let contm = M::from_bools(s, &cont);
        paths.draws.advance(contm, 4);

        // Next-event estimation: `TriangleLight::sample_li`, then the shadow ray.
        let two_sided = M::from_bools(s, &nee_two_sided);
        let ts = triangle_sample_li(lp, ln, la, lem, two_sided, p, (ul_x, ul_y));
        let TriangleSample { wi, li, pdf: light_pdf, ok: sampled, point, point_error, .. } = ts;
        let mut li = li;
        // The lanes that sampled another kind of light take its sample.
        let other = M::from_bools(s, &other_light);
        let sampled = other.select_m(M::from_bools(s, &other_ok), sampled);
        let wi = other.select3(o_wi, wi);
        li = other.select3(o_li, li);
        let light_pdf = other.select(o_pdf, light_pdf);
        let point = other.select3(o_point, point);
        let point_error = other.select3(o_point_error, point_error);
        let ln = other.select3(o_normal, ln);
        let infinite = other & M::from_bools(s, &at_infinity);
        let is_delta = other & M::from_bools(s, &delta);
        let wi_z = wi.dot(ns);
        let f = lambert::eval(albedo, wo_z, wi_z).scale(wi_z.abs());
        let wi_l = if local_frame { V3::new(wi.dot(fx), wi.dot(fy), wi_z) } else { z3 };
        let mut f = if any_glossy {
            let fg =
                metal_rough::eval(&lobes, Iso(alpha), wo_l, wi_l, any_transmits).scale(wi_z.abs());
            glossym.select3(fg, f)
        } else {
            f
        };
        if any_coated {
            f = coatedm.select3(coated_bsdf.eval(wo_l, wi_l).scale(wi_z.abs()), f);
        }
        if any_layered {
            for i in (0..lanes).filter(|&i| layered[i] && cont[i] && has_light[i]) {
                let bsdf = layers[i].as_ref().expect("a layered lane's BSDF");
                let (wo_i, wi_i) = (wo_l.lane(i), wi_l.lane(i));
                f.set_lane(i, bsdf.eval(wo_i, wi_i) * wi_i.z.abs());
            }
        }
        let shadowm = contm
            & M::from_bools(s, &has_light)
            & sampled
            & same_side(wi_z, wi.dot(ng), transm)
            & !f.is_zero();
        shadowm.to_bools(&mut shadow);
        let s_origin = offset_ray_origin(p, p_error, ng, wi);
        let s_target = offset_ray_origin(point, point_error, ln, -wi);
        // Toward a point, a segment stopping short of it; toward infinity, a ray along wi.
        let s_dir = infinite.select3(wi, s_target - s_origin);
        let mut far = [false; MAX_LANES];
        infinite.to_bools(&mut far);
        for i in 0..lanes {
            unblocked[i] = false;
            if shadow[i] {
                stats.rays += 1;
                let ray = Ray::new(s_origin.lane(i), s_dir.lane(i));
                let t_max = if far[i] { f32::INFINITY } else { SHADOW_T_MAX };
                // `PreparedScene::occluded`, as for the closest hits above.
                unblocked[i] = if scene.alpha_tested {
                    !scene.occluded(&ray, t_max, None)
                } else {
                    !scene.accel.occluded_inlined(&ray, t_max)
                };
            }
        }
        if tables.media {
            // The light through the volume the shadow ray travels in: the far side's when it
            // crosses into a medium, else the path's.
            for i in (0..lanes).filter(|&i| unblocked[i]) {
                let through = if wi_z.lane(i) < 0.0 && boundary[i] {
                    if faces[i] {
                        Some(mats[i])
                    } else {
                        beyond[i]
                    }
                } else {
                    paths.media[i].current()
                };
                if let Some(v) = through.and_then(|m| scene.materials[m as usize].volume.as_ref()) {
                    let distance =
                        if far[i] { f32::INFINITY } else { (point.lane(i) - p.lane(i)).length() };
                    li.set_lane(i, li.lane(i) * transmittance(v, distance));
                }
            }
        }
        let nee_pdf = light_pdf * choice_pdf;
        let bsdf_pdf = lambert::pdf(wo_z, wi_z);
        let mut bsdf_pdf = if any_glossy {
            glossym
                .select(metal_rough::pdf(&lobes, Iso(alpha), wo_l, wi_l, any_transmits), bsdf_pdf)
        } else {
            bsdf_pdf
        };
        if any_coated {
            bsdf_pdf = coatedm.select(coated_bsdf.pdf(wo_l, wi_l), bsdf_pdf);
        }
        if any_layered {
            for i in (0..lanes).filter(|&i| layered[i] && unblocked[i]) {
                let bsdf = layers[i].as_ref().expect("a layered lane's BSDF");
                bsdf_pdf.set_lane(i, bsdf.pdf(wo_l.lane(i), wi_l.lane(i)));
            }
        }
        let w = is_delta.select(one, power_heuristic(nee_pdf, bsdf_pdf));
        let nee = paths.radiance + paths.beta.mul(f).mul(li).scale(w / nee_pdf);
        paths.radiance = M::from_bools(s, &unblocked).select3(nee, paths.radiance);

        // BSDF sampling, the next ray, Russian roulette.
        let sample = lambert::sample(albedo, wo_z, (ub_x, ub_y));
        let sample = if any_glossy {
            let g =
                metal_rough::sample(&lobes, Iso(alpha), wo_l, u_lobe, (ub_x, ub_y), any_transmits);
            take_sample(glossym, g, sample)
        } else {
            sample
        };
        let (local, f, pdf, sampled) = if any_coated {
            take_sample(coatedm, coated_bsdf.sample(wo_l, u_lobe, (ub_x, ub_y)), sample)
        } else {
            sample
        };
        // The density MIS weighs the next hit by (`shared::mis_pdf`: no lobe here is a delta).
        let mut mis = pdf;
        let (mut local, mut f, mut pdf, mut sampled) = (local, f, pdf, sampled);
        // The product of eta² as it stands after this bounce's refractions.
        let mut eta_scale = paths.eta_scale;
        if any_layered {
            let mut ok = [false; MAX_LANES];
            sampled.to_bools(&mut ok);
            for i in (0..lanes).filter(|&i| layered[i] && cont[i]) {
                let bsdf = layers[i].as_ref().expect("a layered lane's BSDF");
                let u = Vec2::new(ub_x.lane(i), ub_y.lane(i));
                ok[i] = false;
                if let Some(bs) = bsdf.sample(wo_l.lane(i), u_lobe.lane(i), u) {
                    ok[i] = true;
                    local.set_lane(i, bs.wi);
                    f.set_lane(i, bs.f);
                    pdf.set_lane(i, bs.pdf);
                    mis.set_lane(i, mis_pdf(&bs));
                    if bs.lobe.enters_far_side() {
                        eta_scale.set_lane(i, eta_scale.lane(i) * (bs.eta * bs.eta));
                    }
                }
            }
            sampled = M::from_bools(s, &ok);
        }
        let wi = fx.scale(local.x) + fy.scale(local.y) + ns.scale(local.z);
        let beta = paths.beta.mul(f.scale(local.z.abs() / pdf));
        // At a refractive boundary the facet, not the shading frame, says which side the ray
        // leaves by (`path::li`).
        let side = same_side(local.z, wi.dot(ng), transm);
        let side = if tables.media { side | M::from_bools(s, &refracting) } else { side };
        let ok = contm & sampled & side & beta.is_finite() & !beta.is_zero();
        let origin = offset_ray_origin(p, p_error, ng, wi);
        // eta² is 1 on every path of a scene without volumes.
        let q = if tables.media { roulette_end(beta, eta_scale) } else { roulette_end(beta, one) };
        let rr = M::from_bools(s, &roulette);
        let ended = rr & u_rr.lt(q);
        let beta = rr.select3(beta.div(one - q), beta);
        let go_on = ok & !ended;
        paths.beta = go_on.select3(beta, paths.beta);
        paths.origin = go_on.select3(origin, paths.origin);
        paths.dir = go_on.select3(wi, paths.dir);
        paths.prev_bsdf_pdf = go_on.select(mis, paths.prev_bsdf_pdf);
        if tables.media {
            paths.eta_scale = eta_scale;
        }
        if mixture.is_none() {
            paths.prev_p = go_on.select3(p, paths.prev_p);
            paths.prev_n = go_on.select3(ns, paths.prev_n);
        }
        go_on.to_bools(&mut survive);
        if tables.media && mixture.is_none() {
            for i in (0..lanes).filter(|&i| survive[i]) {
                if let Some(n) = unbent[i] {
                    paths.prev_n.set_lane(i, n);
                }
            }
        }
        for i in 0..lanes {
            if !cont[i] {
                continue;
            }
            if survive[i] {
                paths.depth[i] += 1;
                if boundary[i] {
                    // Crossing into the far side's medium or out of the volume.
                    let crosses = if refracting[i] {
                        wi.lane(i).dot(ng_front[i]) < 0.0
                    } else {
                        local.lane(i).z < 0.0
                    };
                    if crosses {
                        paths.media[i].cross(mats[i], faces[i]);
                    }
                }
            } else {
                paths.alive[i] = false;
                stream.finish(paths.item[i], paths.radiance.lane(i).to_array(), &mut tile);
            }
        }
    }
    (tile, stats)
}

/// A BSDF sample in every lane: the local direction, f, its density, whether there is one.
type LaneSample<S> = (V3<F<S>>, V3<F<S>>, F<S>, M<S>);

/// `current` with the lanes `m` marks taken from a BSDF's `sample` (its direction, f,
/// density, whether it went to the far side, whether there is one).
#[inline(always)]
fn take_sample<S: Simd>(
    m: M<S>,
    (wi, f, pdf, _, ok): (V3<F<S>>, V3<F<S>>, F<S>, M<S>, M<S>),
    (c_wi, c_f, c_pdf, c_ok): LaneSample<S>,
) -> LaneSample<S> {
    (m.select3(wi, c_wi), m.select3(f, c_f), m.select(pdf, c_pdf), m.select_m(ok, c_ok))
}

/// A lane's coat where it has none (its values are never used).
const NO_COAT: CoatLanes<f32> =
    CoatLanes { weight: 0.0, alpha: 1.0, normal: V3 { x: 0.0, y: 0.0, z: 1.0 } };

/// Puts the metal-rough BSDF `b` in lane `i` of `lobes` and `alpha`.
#[inline(always)]
fn set_lobes<S: Simd>(lobes: &mut Lobes<F<S>>, alpha: &mut F<S>, i: usize, b: &MetalRough) {
    set_base(lobes, i, &b.lobes());
    alpha.set_lane(i, b.ggx.alpha);
}

/// Puts a metal-rough BSDF's parameters but its microfacets in lane `i` of `lobes`.
#[inline(always)]
fn set_base<S: Simd>(lobes: &mut Lobes<F<S>>, i: usize, l: &Lobes<f32>) {
    lobes.base.set_lane(i, l.base.into());
    lobes.metallic.set_lane(i, l.metallic);
    lobes.f0.set_lane(i, l.f0.into());
    lobes.specular.set_lane(i, l.specular);
    lobes.transmission.set_lane(i, l.transmission);
    lobes.diffuse_transmission.set_lane(i, l.diffuse_transmission);
    lobes.diffuse_transmission_color.set_lane(i, l.diffuse_transmission_color.into());
}
