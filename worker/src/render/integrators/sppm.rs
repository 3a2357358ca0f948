//! Stochastic progressive photon mapping (Hachisuka and Jensen 2009), in the probabilistic
//! formulation of Knaus and Zwicker 2011 so that its passes are independent of one another.
//!
//! Sample index `i` of every pixel is photon pass `i`: the pass traces each pixel's camera path
//! to its first surface that gathers photons (`Bsdf::gathers_photons`: a diffuse component or a
//! broad glossy lobe; near-mirrors and smooth refraction are followed by BSDF sampling), its
//! visible point, adding the direct light at each vertex on the way and at the visible point (a
//! light sample and a BSDF sample weighted by the power heuristic, as the path tracer does); then it traces `photons` photon paths from the lights and adds, at
//! every visible point within the pass's radius r_i of a photon that arrived after at least one
//! bounce, f x the photon's flux / (pi r_i² photons). The pass's radius follows the progressive
//! rule r_i² = r_{i-1}² (i + alpha) / (i + 1) (`SppmParams::radius`): each pass alone is a biased
//! estimate, their bias shrinks as r_i² and their variance grows more slowly than their number,
//! so the mean over passes, which is the film's mean over samples, converges to the solution.
//! Hachisuka and Jensen shrink each pixel's radius by the photons it has gathered; this global
//! sequence is that rule's expected shrinking (Knaus and Zwicker), and it makes a pass a function
//! of (scene, settings, seed, pass) alone, which the farm splits like any other sample range.
//!
//! Each path is counted once: light reaching the camera path's vertices up to its visible point
//! straight from a light by the camera path (its light and BSDF samples, weighted against each
//! other), and everything that bounced at least once on its way from the light to the visible
//! point by the photons (those that arrive with no bounce are left out). A photon counts at a
//! visible point only if the whole path stays within `max_depth` bounces.
//!
//! Determinism: camera paths are per pixel; photon `j` of pass `i` starts from point
//! `i / 2 * photons + j` of a frame-wide low-discrepancy sequence (`photon_start`) and draws its
//! further numbers as sample `i` of pseudo-pixel (j, u32::MAX); photons are traced in chunks of
//! `CHUNK` whose gathered sums are added in chunk order, whatever the number of threads.
//!
//! Motion blur: each pass is one instant of the shutter (`pass_numbers`), the same for its camera
//! paths and its photons, so a pass is a photon map of a still scene and the mean over passes
//! the mean over the shutter.
//!
//! Dispersion: each pass is also one wavelength (`pass_numbers`), which every dispersive
//! boundary of its camera paths and photons bends light by, so that a photon and a visible point
//! are two halves of one path of that light; a path through a dispersive vertex on either half
//! takes that light's colour once (`At::tint`), and the mean over passes is the mean over
//! wavelengths, as it is over the shutter.
//!
//! Lights at infinity: photons leave them as bidirectional light subpaths do (through a disk of
//! the scene's radius); a camera path that leaves the scene sees the environment, weighted
//! against its light samples.
//!
//! Volumes: camera paths and photons cross boundaries and lose light to absorption as
//! bidirectional subpaths do (`bdpt::surface_vertex`); photons refract carrying flux.
//!
//! Scattering media: camera paths and photons sample free flights as bidirectional subpaths do
//! (the pass's hero channel for all of them), and a camera path follows a scattering by its
//! phase function as the path tracer does, never gathering there; photons scattered in a medium
//! are gathered where they land on surfaces, weighed with the visible point by the densities of
//! the whole path (`bdpt::spectral_weight`).
//!
//! Emitters that move within the shutter are not in the light list (no light sample reaches
//! them): a camera path counts its hits on one in full, as the path tracer does, and photons
//! leave them too (`photon_path`), from where they are at the pass's instant.

use std::sync::atomic::{AtomicUsize, Ordering};

use common::{film::TileAccum, protocol::TaskSpec};
use glam::{DVec3, IVec3, UVec2, Vec2, Vec3};

use super::{
    super::{
        geometry::{offset_ray_origin, Ray},
        light::{Light, ShadingContext, TriangleLight},
        sampler::{mix64, Sampler},
        scene::{PreparedScene, SppmParams, NONE},
    },
    bdpt::{
        cross_after, frame_start, leave_light, leave_still_light, sample_light, scatter,
        spectral_weight, surface_vertex, At, FrameSequences, FrameStart, Kind, SharedNumbers,
        Vertex, LIGHT_DIMENSION,
    },
    shared::{
        environment_hit, hit_weight, mis_pdf, power_heuristic, roulette, same_side, Stats,
        UNWEIGHTED,
    },
};

/// Photons traced as one unit of work; their sums are added in this unit's order.
const CHUNK: u32 = 1024;

/// A pixel's visible point of one pass.
struct VisiblePoint {
    /// The camera path's vertex there (its throughput, BSDF, frame and direction to the eye).
    vertex: Vertex,
    /// Bounces before it (0: seen straight from the camera).
    depth: u32,
    /// Index of its pixel in the task's rectangle.
    pixel: u32,
    /// Its grid cell.
    cell: IVec3,
}

/// Renders a task (a rectangle of the frame x a range of passes) on `threads` threads; each
/// pass gives one sample of each of the rectangle's pixels. The result does not depend on
/// `threads`.
pub fn render_task(
    scene: &PreparedScene,
    params: &SppmParams,
    seed: u64,
    task: &TaskSpec,
    threads: usize,
) -> (TileAccum, Stats) {
    let rect = task.rect;
    let mut tile = TileAccum::new(rect);
    let mut stats = Stats::default();
    let threads = threads.max(1);
    let radii = params.radii(task.samples.start);
    for (pass, radius) in (task.samples.start..task.samples.end).zip(radii) {
        let u = pass_numbers(scene, seed, task.frame, pass);
        let (seen, points) = camera_pass(scene, seed, task, pass, u, radius, threads, &mut stats);
        let gathered = photon_pass(scene, params, seed, task, pass, u, radius, &points, threads);
        stats.rays += gathered.1;
        let scale = 1.0 / (std::f64::consts::PI * (radius as f64).powi(2) * params.photons as f64);
        let mut image = seen;
        for (vp, sum) in points.iter().zip(&gathered.0) {
            // Nothing gathered adds nothing (also where a radius too small for f32 has no area).
            if *sum == DVec3::ZERO {
                continue;
            }
            let add = vp.vertex.beta.as_dvec3() * *sum * scale;
            image[vp.pixel as usize] += add.as_vec3();
        }
        for row in 0..rect.height {
            for col in 0..rect.width {
                let l = image[(row * rect.width + col) as usize];
                tile.add_sample(col, row, pass, l.to_array());
            }
        }
    }
    (tile, stats)
}

/// The path of a photon from `start` (`photon_start`; the sampler at the photon's pixel
/// sample, whose numbers from `LIGHT_DIMENSION + 3` on it walks by): from a light that stays
/// put, chosen as light subpaths choose (`bdpt::choose_emitting`), or with probability
/// `MovingEmitters::share` from an emitting triangle that moves within the shutter, where it is
/// at the pass's instant (a point on it by area and a direction by cosine, as from any emitting
/// triangle). Each carries its flux over its whole choice's probability. The first, best
/// stratified pair of `start` goes to what spreads the light most: the direction, but a
/// directional light's point (`bdpt::leave_still_light`).
fn photon_path(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    start: PhotonStart,
    path: &mut Vec<Vertex>,
    stats: &mut Stats,
) {
    path.clear();
    sampler.set_dimension(LIGHT_DIMENSION + 3);
    let max = scene.max_depth;
    let mut u_choice = start[4];
    let mut scale = 1.0;
    if let Some(moving) = &scene.moving_emitters {
        let share = moving.share;
        if u_choice < share {
            let (i, pmf) = moving.choose(u_choice / share);
            let prim = moving.prims[i];
            let m = &scene.materials[scene.shading[prim as usize].material as usize];
            let (p, _) = scene.triangle(prim, at.pose);
            let Some(mut l) = TriangleLight::new(p, m.emissive, m.double_sided) else { return };
            l.prim = prim;
            l.textured = m.emissive_texture.is_some() || m.clearcoat.is_some();
            let light = Light::Triangle(l);
            let pmf = share * pmf;
            let media = moving.media.get(i).copied().unwrap_or_default();
            let u = (Vec2::new(start[0], start[1]), Vec2::new(start[2], start[3]));
            leave_light(scene, at, sampler, u, &light, None, pmf, media, max, path, stats);
            return;
        }
        // A light that stays put: the choice's number stretched back over [0, 1).
        u_choice = ((u_choice - share) / (1.0 - share)).min(1.0 - f32::EPSILON / 2.0);
        scale = 1.0 - share;
    }
    leave_still_light(scene, at, sampler, start, u_choice, scale, max, path, stats);
}

/// The numbers a photon starts from (`bdpt::frame_start`).
type PhotonStart = FrameStart;

/// The frame-wide sequences photons start from, one for the even passes and one for the odd.
const PHOTON_SEQUENCES: FrameSequences = [0x7068_6f74_6f6e_0000, 0x7068_6f74_6f6e_0001];

/// Where photon `j` of pass `pass` starts: point `pass / 2 * photons + j` of its half's
/// frame-wide sequence (`bdpt::frame_start`). (Photons are pooled at every visible point; a
/// pixel's own subpaths, as bidirectional path tracing connects them, are not, and keep per-pixel
/// numbers.)
fn photon_start(sampler: &mut Sampler, photons: u32, j: u32, pass: u32) -> PhotonStart {
    frame_start(sampler, PHOTON_SEQUENCES, photons as u64, j as u64, pass)
}

/// The numbers of pass `pass` that all its camera paths and photons share (`At::sample`): where
/// it falls in the shutter, when something moves within it, its wavelength, in a scene with
/// dispersion, and its hero channel, in one with scattering media. So each pass is a photon map
/// of one instant and one wavelength, and the mean over passes is the mean over the shutter and
/// the wavelengths. They are the first three numbers of sample `pass` of a pseudo-pixel no photon
/// uses (each at its place whatever the scene needs), so the passes stratify each as a pixel's
/// samples do.
fn pass_numbers(scene: &PreparedScene, seed: u64, frame: i64, pass: u32) -> SharedNumbers {
    if scene.motion.is_none() && !scene.dispersive && !scene.scattering_media {
        return (None, None, None);
    }
    let mut sampler = Sampler::new(seed, frame);
    sampler.start_pixel_sample(UVec2::new(u32::MAX, u32::MAX), pass);
    let u_time = sampler.next_1d();
    let u_wavelength = sampler.next_1d();
    let u_hero = sampler.next_1d();
    (
        scene.motion.is_some().then_some(u_time),
        scene.dispersive.then_some(u_wavelength),
        scene.scattering_media.then_some(u_hero),
    )
}

/// The camera paths of one pass: each pixel's light seen before and at its visible point, and
/// the visible points (in pixel order).
#[allow(clippy::too_many_arguments)]
fn camera_pass(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    pass: u32,
    u: SharedNumbers,
    radius: f32,
    threads: usize,
    stats: &mut Stats,
) -> (Vec<Vec3>, Vec<VisiblePoint>) {
    let rect = task.rect;
    let rows: Vec<(Vec<(Vec3, Option<(Vertex, u32)>)>, Stats)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads as u32)
            .map(|t| {
                s.spawn(move || {
                    let mut sampler = Sampler::new(seed, task.frame);
                    let mut stats = Stats::default();
                    let mut out = Vec::new();
                    let mut pose = None;
                    let at = At::sample(scene, u, &mut pose);
                    let mut row = t;
                    while row < rect.height {
                        for col in 0..rect.width {
                            let pixel = UVec2::new(rect.x0 + col, rect.y0 + row);
                            let sampler = &mut sampler;
                            out.push(camera_path(scene, &at, sampler, pixel, pass, &mut stats));
                        }
                        row += threads as u32;
                    }
                    (out, stats)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().expect("sppm camera thread panicked")).collect()
    });
    let n = (rect.width * rect.height) as usize;
    let mut seen = vec![Vec3::ZERO; n];
    let mut by_pixel: Vec<Option<(Vertex, u32)>> = vec![None; n];
    for (t, (out, s)) in rows.into_iter().enumerate() {
        stats.rays += s.rays;
        let mut it = out.into_iter();
        let mut row = t as u32;
        while row < rect.height {
            for col in 0..rect.width {
                let i = (row * rect.width + col) as usize;
                let (l, vp) = it.next().expect("a result per pixel");
                seen[i] = l;
                by_pixel[i] = vp;
            }
            row += threads as u32;
        }
    }
    let points = by_pixel
        .into_iter()
        .enumerate()
        .filter_map(|(i, vp)| {
            vp.map(|(vertex, depth)| VisiblePoint {
                cell: cell_of(vertex.p, radius),
                vertex,
                depth,
                pixel: i as u32,
            })
        })
        .collect();
    (seen, points)
}

/// Pass `pass`'s camera path through `pixel`: the light it sees before and at its visible point
/// and the visible point with the bounces before it. Direct light is taken at every vertex that
/// is not a delta lobe by a light sample and a BSDF sample weighted by the power heuristic (the
/// path's next direction is a followed vertex's BSDF sample; a visible point traces one for it),
/// so that neither a small light on a rough surface nor a large one on a sharp lobe leaves heavy
/// tails. Each vertex takes 7 numbers, as a bidirectional camera subpath's do: the light
/// sample's 3, the lobe, the direction and the roulette (in a scene with scattering media, each
/// segment one more first, for its free flight).
fn camera_path(
    scene: &PreparedScene,
    at: &At<'_>,
    sampler: &mut Sampler,
    pixel: UVec2,
    pass: u32,
    stats: &mut Stats,
) -> (Vec3, Option<(Vertex, u32)>) {
    sampler.start_pixel_sample(pixel, pass);
    let film = pixel.as_vec2() + sampler.next_2d();
    let lens = if scene.camera.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
    let mut ray = at.camera.generate_ray(film, lens);
    let mut beta = Vec3::ONE;
    let mut seen = Vec3::ZERO;
    // The density of the BSDF sample that made `ray` (`UNWEIGHTED` for a camera ray, whose
    // emitter counts whole) and the point it left.
    let mut prev_pdf = UNWEIGHTED;
    let mut prev_ctx = ShadingContext::default();
    // The volumes the path is inside, at first those the camera lies inside.
    let mut media = scene.camera_media;
    // Whether the path passed a dispersive vertex (its light takes the pass's wavelength's
    // colour, `At::tint`).
    let mut tinted = false;
    // The path's free-flight densities per channel over their mean (`Vertex::ratios`).
    let mut ratios = Vec3::ONE;
    // The product of eta² over the refractions crossed (`shared::roulette`).
    let mut eta_scale = 1.0f32;
    for depth in 0..=scene.max_depth {
        // In a scene with scattering media each segment takes a number for its free flight.
        let u_flight = if scene.scattering_media { sampler.next_1d() } else { 0.0 };
        let next =
            surface_vertex(scene, at, &ray, &mut beta, u_flight, &mut ratios, stats, &mut media);
        let Some((mut v, unlit)) = next else {
            // The environment, straight from the camera only where the settings show it.
            if depth > 0 || scene.environment_visible {
                let l = environment_hit(scene, beta, ray.dir.normalize(), &prev_ctx, prev_pdf);
                seen += at.tint(l, tinted);
            }
            break;
        };
        // What the medium on the way let through.
        beta = v.beta;
        v.tinted = tinted;
        if v.kind == Kind::Medium {
            // A scattering inside a medium: followed by its phase function, sampled exactly, as
            // the path tracer follows it (no light sample: the medium's boundary stops shadow
            // rays), and never a visible point; what the new direction finds counts in full.
            if depth == scene.max_depth {
                break;
            }
            sampler.skip(4); // The light sample and the lobe, as at a surface.
            let wi = scatter(scene, &media, &v, sampler.next_2d());
            if !beta.is_finite()
                || beta == Vec3::ZERO
                || !roulette(sampler, depth + 1, &mut beta, eta_scale)
            {
                break;
            }
            prev_pdf = UNWEIGHTED;
            ray = Ray::interior(v.p, wi);
            continue;
        }
        if let Some(base) = unlit {
            seen += at.tint(beta * base, tinted);
            break;
        }
        if v.light != NONE {
            let l = beta * v.le(scene, v.wo) * emitter_weight(scene, &v, &prev_ctx, prev_pdf);
            seen += at.tint(l, tinted);
        }
        // An emitter that moves within the shutter: no light sample reaches it, so a hit counts
        // it in full.
        if v.moving_le != Vec3::ZERO {
            seen += at.tint(beta * v.moving_le, tinted);
        }
        // Light this vertex's BSDF scatters takes the wavelength's colour if it is dispersive.
        tinted = v.tints();
        if depth == scene.max_depth {
            break;
        }
        let u = sampler.next_2d();
        v.u_light = [sampler.next_1d(), u.x, u.y];
        let bsdf = v.bsdf.expect("a lit surface vertex has a BSDF");
        let wo_local = v.frame.to_local(v.wo);
        let ctx = ShadingContext { p: v.p, n: v.frame.z };
        if let Some((direct, light, light_pdf)) = sample_light(scene, at, &v, &ctx, stats) {
            let bsdf_pdf = v.dir_to(&light).map_or(0.0, |wi| v.pdf_dir(v.wo, wi));
            seen += at.tint(direct * power_heuristic(light_pdf, bsdf_pdf), tinted);
        }
        let u_lobe = sampler.next_1d();
        let u = sampler.next_2d();
        let sampled = if wo_local.z > 0.0 { bsdf.sample(wo_local, u_lobe, u) } else { None };
        let next = sampled.and_then(|bs| {
            let wi = v.frame.to_world(bs.wi);
            (v.refracting || same_side(bs.wi.z, wi.dot(v.ng), bsdf.transmits())).then_some((bs, wi))
        });
        if bsdf.gathers_photons() {
            // The BSDF's half of the direct light, then the path ends here.
            if let Some((bs, wi)) = next {
                let weight = beta * bs.f * (bs.wi.z.abs() / bs.pdf);
                let ray = Ray::new(offset_ray_origin(v.p, v.p_error, v.ng, wi), wi);
                let pdf = mis_pdf(&bs);
                let mut media = media;
                cross_after(&v, wi, bs.wi, &mut media);
                // Its free flight: where it scatters, no light arrives unscattered.
                let u_flight = if scene.scattering_media { sampler.next_1d() } else { 0.0 };
                let mut ratios = ratios;
                // What the media on the way let through, to an emitter or out of the scene.
                let mut through = weight;
                let probe = surface_vertex(
                    scene,
                    at,
                    &ray,
                    &mut through,
                    u_flight,
                    &mut ratios,
                    stats,
                    &mut media,
                );
                match probe {
                    Some((hit, None)) if hit.light != NONE && hit.kind == Kind::Surface => {
                        let l = through
                            * hit.le(scene, hit.wo)
                            * emitter_weight(scene, &hit, &ctx, pdf);
                        seen += at.tint(l, tinted);
                    }
                    Some((hit, None)) if hit.moving_le != Vec3::ZERO => {
                        seen += at.tint(through * hit.moving_le, tinted);
                    }
                    None => seen += at.tint(environment_hit(scene, through, wi, &ctx, pdf), tinted),
                    _ => {}
                }
            }
            return (seen, Some((v, depth)));
        }
        let Some((bs, wi)) = next else { break };
        beta *= bs.f * (bs.wi.z.abs() / bs.pdf);
        if !beta.is_finite() || beta == Vec3::ZERO {
            break;
        }
        if bs.lobe.enters_far_side() {
            eta_scale *= bs.eta * bs.eta;
        }
        if !roulette(sampler, depth + 1, &mut beta, eta_scale) {
            break;
        }
        prev_pdf = mis_pdf(&bs);
        prev_ctx = ctx;
        cross_after(&v, wi, bs.wi, &mut media);
        ray = Ray::new(offset_ray_origin(v.p, v.p_error, v.ng, wi), wi);
    }
    (seen, None)
}

/// The multiple-importance weight of emitter vertex `hit` found by a direction sampled with
/// density `pdf` (per solid angle, or `UNWEIGHTED`) from the shading point `from`, against
/// sampling the light from there (`shared::hit_weight`).
fn emitter_weight(scene: &PreparedScene, hit: &Vertex, from: &ShadingContext, pdf: f32) -> f32 {
    hit_weight(scene, hit.light, from, -hit.wo, hit.p.distance_squared(from.p), pdf)
}

/// The grid cell of edge `radius` that holds `p`.
fn cell_of(p: Vec3, radius: f32) -> IVec3 {
    let c = (p / radius).floor();
    // Far outside any sensible grid the cells merge: only speed suffers, never the result.
    c.clamp(Vec3::splat(-1e9), Vec3::splat(1e9)).as_ivec3()
}

fn cell_hash(c: IVec3) -> u64 {
    mix64((c.x as u32 as u64) ^ ((c.y as u32 as u64) << 21) ^ ((c.z as u32 as u64) << 42))
}

/// The visible points by grid cell: a hash table of cells (collisions are told apart by each
/// point's own cell), each bucket's points in pixel order.
struct Grid {
    mask: u64,
    /// Bucket `b`'s points are `entries[starts[b]..starts[b + 1]]`.
    starts: Vec<u32>,
    entries: Vec<u32>,
}

impl Grid {
    fn new(points: &[VisiblePoint]) -> Grid {
        let buckets = (2 * points.len()).next_power_of_two().max(1);
        let mask = buckets as u64 - 1;
        let mut starts = vec![0u32; buckets + 1];
        for vp in points {
            starts[(cell_hash(vp.cell) & mask) as usize + 1] += 1;
        }
        for b in 0..buckets {
            starts[b + 1] += starts[b];
        }
        let mut fill = starts.clone();
        let mut entries = vec![0u32; points.len()];
        for (i, vp) in points.iter().enumerate() {
            let b = (cell_hash(vp.cell) & mask) as usize;
            entries[fill[b] as usize] = i as u32;
            fill[b] += 1;
        }
        Grid { mask, starts, entries }
    }

    /// Calls `visit` with each visible point within `radius` of `p`, cell by cell.
    fn near(
        &self,
        points: &[VisiblePoint],
        p: Vec3,
        radius: f32,
        mut visit: impl FnMut(u32, &VisiblePoint),
    ) {
        let centre = cell_of(p, radius);
        let r2 = radius * radius;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let cell = centre + IVec3::new(dx, dy, dz);
                    let b = (cell_hash(cell) & self.mask) as usize;
                    for &i in &self.entries[self.starts[b] as usize..self.starts[b + 1] as usize] {
                        let vp = &points[i as usize];
                        if vp.cell == cell && vp.vertex.p.distance_squared(p) < r2 {
                            visit(i, vp);
                        }
                    }
                }
            }
        }
    }
}

/// Traces pass `pass`'s photons and returns, per visible point, the sum over the photons within
/// `radius` of f x flux (and the rays traced).
#[allow(clippy::too_many_arguments)]
fn photon_pass(
    scene: &PreparedScene,
    params: &SppmParams,
    seed: u64,
    task: &TaskSpec,
    pass: u32,
    u: SharedNumbers,
    radius: f32,
    points: &[VisiblePoint],
    threads: usize,
) -> (Vec<DVec3>, u64) {
    let mut sums = vec![DVec3::ZERO; points.len()];
    if points.is_empty() {
        return (sums, 0);
    }
    let grid = Grid::new(points);
    let chunks = params.photons.div_ceil(CHUNK) as usize;
    // A wave of chunks at a time, so that the gathered sums held at once stay bounded (each
    // chunk's at most one visible point's worth of 16 bytes: `Gathered`).
    let wave = threads * 4;
    let mut rays = 0;
    let mut first = 0;
    while first < chunks {
        let last = (first + wave).min(chunks);
        let next = AtomicUsize::new(first);
        let done: Vec<(Vec<(usize, Gathered)>, u64)> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..threads)
                .map(|_| {
                    s.spawn(|| {
                        let mut sampler = Sampler::new(seed, task.frame);
                        let mut stats = Stats::default();
                        let mut path = Vec::new();
                        let mut out = Vec::new();
                        let mut pose = None;
                        let at = At::sample(scene, u, &mut pose);
                        loop {
                            let c = next.fetch_add(1, Ordering::Relaxed);
                            if c >= last {
                                break;
                            }
                            let mut gathered = Gathered::List(Vec::new());
                            let start = c as u32 * CHUNK;
                            for j in start..(start + CHUNK).min(params.photons) {
                                sampler.start_pixel_sample(UVec2::new(j, u32::MAX), pass);
                                let start = photon_start(&mut sampler, params.photons, j, pass);
                                photon_path(scene, &at, &mut sampler, start, &mut path, &mut stats);
                                deposit(scene, &at, &grid, points, &path, radius, &mut gathered);
                            }
                            out.push((c, gathered));
                        }
                        (out, stats.rays)
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().expect("sppm photon thread panicked")).collect()
        });
        let mut lists: Vec<(usize, Gathered)> = Vec::with_capacity(last - first);
        for (out, r) in done {
            rays += r;
            lists.extend(out);
        }
        lists.sort_unstable_by_key(|(c, _)| *c);
        for (_, gathered) in lists {
            match gathered {
                Gathered::List(list) => {
                    for (i, add) in list {
                        sums[i as usize] += add.as_dvec3();
                    }
                }
                Gathered::Dense(dense) => {
                    for (sum, add) in sums.iter_mut().zip(dense) {
                        *sum += add.as_dvec3();
                    }
                }
            }
        }
        first = last;
    }
    (sums, rays)
}

/// What a chunk of photons left at the visible points, in the order it was found: a list of
/// (visible point, f x flux), or once the list would outgrow one value per visible point (a
/// radius that takes in many points per photon), a value per visible point. Which one depends on
/// the chunk's photons alone, so the sums stay the same whatever the threads.
enum Gathered {
    List(Vec<(u32, Vec3)>),
    Dense(Vec<Vec3>),
}

impl Gathered {
    fn add(&mut self, index: u32, value: Vec3, points: usize) {
        match self {
            Gathered::List(list) if list.len() < points => list.push((index, value)),
            Gathered::List(list) => {
                let mut dense = vec![Vec3::ZERO; points];
                for &(i, v) in list.iter() {
                    dense[i as usize] += v;
                }
                dense[index as usize] += value;
                *self = Gathered::Dense(dense);
            }
            Gathered::Dense(dense) => dense[index as usize] += value,
        }
    }
}

/// Adds a photon path's contributions at the visible points near its vertices: from its second
/// surface vertex on (the first is direct light, which the visible points sample themselves),
/// at surfaces that gather photons, where the whole path stays within `max_depth` bounces.
fn deposit(
    scene: &PreparedScene,
    at: &At<'_>,
    grid: &Grid,
    points: &[VisiblePoint],
    path: &[Vertex],
    radius: f32,
    gathered: &mut Gathered,
) {
    // path[0] is on the light; path[i] (i >= 1) is the photon's i-th surface, after i - 1
    // bounces.
    for (i, photon) in path.iter().enumerate().skip(2) {
        let Some(bsdf) = &photon.bsdf else { continue };
        if !bsdf.gathers_photons() {
            continue;
        }
        let bounces = i as u32 - 1;
        grid.near(points, photon.p, radius, |index, vp| {
            if vp.depth + 1 + bounces > scene.max_depth {
                return;
            }
            let v = &vp.vertex;
            // Light arrives from the photon's previous vertex and leaves toward the eye.
            let f = v.f(v.wo, photon.wo);
            let mut add = at.tint(f * photon.beta, v.tints() || photon.tinted);
            if scene.scattering_media {
                add *= spectral_weight(v, photon);
            }
            if add != Vec3::ZERO && add.is_finite() {
                gathered.add(index, add, points.len());
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_radius_shrinks_by_the_progressive_rule() {
        let p = SppmParams { radius: 2.0, photons: 10, alpha: 0.5 };
        assert_eq!(p.radius(0), 2.0);
        // r1² = r0² (1 + alpha) / 2, r2² = r1² (2 + alpha) / 3.
        assert!((p.radius(1) - 2.0 * 0.75f32.sqrt()).abs() < 1e-6);
        assert!((p.radius(2) - 2.0 * (0.75f32 * 2.5 / 3.0).sqrt()).abs() < 1e-6);
        // r_i² falls as i^(alpha - 1): from pass 1,000 to 10,000 by about 10^-0.5.
        let ratio = (p.radius(10_000) / p.radius(1_000)).powi(2);
        assert!((ratio - 10f32.powf(-0.5)).abs() < 0.01, "{ratio}");
        // A task's radii are the passes' own, bit for bit, wherever the task starts.
        let radii: Vec<f32> = p.radii(997).take(5).collect();
        assert_eq!(radii, (997..1002).map(|i| p.radius(i)).collect::<Vec<_>>());
    }

    #[test]
    fn cells_are_told_apart_in_a_shared_bucket() {
        let a = cell_of(Vec3::new(0.5, 0.5, 0.5), 1.0);
        let b = cell_of(Vec3::new(-0.5, 0.5, 0.5), 1.0);
        assert_eq!((a, b), (IVec3::ZERO, IVec3::new(-1, 0, 0)));
        assert_eq!(cell_of(Vec3::splat(1e30), 1e-9), IVec3::splat(1_000_000_000));
    }
}
