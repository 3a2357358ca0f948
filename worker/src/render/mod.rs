//! The renderer: `render_task` path-traces one task (a tile x a sample range) of a prepared scene.
//!
//! Synchronous and free of I/O: no `.await`, no logging inside loops. Data flows one way, each
//! module using only modules before it: `geometry`, `sampling`, `lanes`, `texture` -> `sampler`
//! -> `sah_build` -> `accel`, `camera`, `bsdf`, `light` -> `material`, `motion` ->
//! `wavefront_tables` -> `scene` (`prepare`) -> `integrator` (`li`) -> `bdpt` -> `sppm`,
//! `wavefront` -> this module (`render_task`).

pub mod accel;
pub mod bsdf;
pub mod bvh_cache;
pub mod camera;
pub mod geometry;
pub mod integrators;
mod lanes;
pub mod light;
pub mod material;
pub mod media;
pub mod motion;
pub mod sah_build;
pub mod sampler;
pub mod sampling;
pub mod scene;
pub mod spectrum;
pub mod texture;
pub mod wavefront_tables;

#[cfg(test)]
mod tests;

use common::{
    film::{Rect, TileAccum},
    protocol::{TaskKind, TaskResult, TaskSpec},
};
use glam::{UVec2, Vec2};

use self::{
    integrators::{bdpt, path, sppm, wavefront, Stats},
    motion::Pose,
    sampler::Sampler,
    scene::{PreparedScene, Transport},
};

/// The kernel that renders the camera tasks of `scene` on this CPU: the integrator, and for the
/// path tracer whether it runs on the SIMD wavefront (`"path, AVX2 x8"`, `"path, AVX-512 x16"`)
/// or one path at a time (`"path, scalar"`; `prepare` logs why).
pub fn kernel(scene: &PreparedScene) -> &'static str {
    match &scene.transport {
        Transport::Path { wavefront: Some(_) } => match wavefront::lanes() {
            16 => "path, AVX-512 x16",
            8 => "path, AVX2 x8",
            _ => "path, scalar",
        },
        Transport::Path { wavefront: None } => "path, scalar",
        Transport::Bdpt => "bdpt, scalar",
        Transport::Sppm(_) => "sppm, scalar",
    }
}

/// Renders `task` with `seed` on the calling thread.
pub fn render_task(scene: &PreparedScene, seed: u64, task: &TaskSpec) -> TaskResult {
    render_task_threads(scene, seed, task, 1)
}

/// Renders `task` on `threads` threads (rows are interleaved between them). The result does not
/// depend on `threads`: sums are exact integers.
pub fn render_task_threads(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    threads: usize,
) -> TaskResult {
    let result = |tile, rays| TaskResult { spec: *task, tile, rays, kernel: kernel(scene).into() };
    // The one place that dispatches on the integrator.
    match (&scene.transport, task.kind) {
        (Transport::Sppm(params), _) => {
            let (tile, stats) = sppm::render_task(scene, params, seed, task, threads);
            return result(tile, stats.rays);
        }
        (_, TaskKind::Light) => {
            // Light tracing (bidirectional jobs' light tasks). A sample index's film per thread,
            // added in sample order: the same bits on any count.
            let (tile, stats) = bdpt::render_light_task(scene, seed, task, threads);
            return result(tile, stats.rays);
        }
        (Transport::Path { .. } | Transport::Bdpt, TaskKind::Camera) => {}
    }
    let rect = task.rect;
    let threads = threads.clamp(1, rect.height.max(1) as usize);
    if threads == 1 {
        let (tile, stats) = render_rows(scene, seed, task, 0, 1);
        return result(tile, stats.rays);
    }
    let parts: Vec<(TileAccum, Stats)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| s.spawn(move || render_rows(scene, seed, task, t as u32, threads as u32)))
            .collect();
        handles.into_iter().map(|h| h.join().expect("render thread panicked")).collect()
    });
    let mut tile = TileAccum::new(rect);
    let mut rays = 0;
    for (part, stats) in &parts {
        tile.merge(part);
        rays += stats.rays;
    }
    result(tile, rays)
}

/// Renders rows `first, first + step, ...` of the task's tile.
fn render_rows(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    first: u32,
    step: u32,
) -> (TileAccum, Stats) {
    match &scene.transport {
        Transport::Bdpt => bdpt::render_rows(scene, seed, task, first, step),
        Transport::Path { wavefront: Some(tables) } => {
            wavefront::render_rows(scene, tables, seed, task, first, step)
                .unwrap_or_else(|| render_rows_scalar(scene, seed, task, first, step))
        }
        Transport::Path { wavefront: None } | Transport::Sppm(_) => {
            render_rows_scalar(scene, seed, task, first, step)
        }
    }
}

/// Renders rows `first, first + step, ...` of the task's tile one path at a time.
pub fn render_rows_scalar(
    scene: &PreparedScene,
    seed: u64,
    task: &TaskSpec,
    first: u32,
    step: u32,
) -> (TileAccum, Stats) {
    let mut stats = Stats::default();
    let mut sampler = Sampler::new(seed, task.frame);
    let mut pose = None;
    let tile = render_rows_with(task, first, step, |pixel, s| {
        sample(scene, &mut sampler, pixel, s, &mut stats, &mut pose).radiance
    });
    (tile, stats)
}

/// The sums of rows `first, first + step, ...` of the task's tile, each pixel's samples in index
/// order, each the radiance `trace(pixel, sample index)` returns.
#[inline]
pub(crate) fn render_rows_with(
    task: &TaskSpec,
    first: u32,
    step: u32,
    mut trace: impl FnMut(UVec2, u32) -> glam::Vec3,
) -> TileAccum {
    let rect: Rect = task.rect;
    let mut tile = TileAccum::new(rect);
    let mut row = first;
    while row < rect.height {
        for col in 0..rect.width {
            let pixel = UVec2::new(rect.x0 + col, rect.y0 + row);
            for s in task.samples.start..task.samples.end {
                let l = trace(pixel, s);
                tile.add_sample(col, row, s, l.to_array());
            }
        }
        row += step;
    }
    tile
}

/// One traced sample, with the numbers that made it (for `worker debug-sample`).
pub struct Sample {
    /// Film position in pixels.
    pub film: Vec2,
    /// Time in seconds, when something moves within the shutter.
    pub time: Option<f64>,
    /// Radiance along the camera ray.
    pub radiance: glam::Vec3,
}

/// Traces sample `s` of `pixel`: film position, lens position (thin lens only), time (only when
/// something moves within the shutter), then the path. `pose` is the calling thread's storage
/// for placements at the sample's time (filled on first use, reused by later samples).
#[inline]
pub fn sample<'a>(
    scene: &'a PreparedScene,
    sampler: &mut Sampler,
    pixel: UVec2,
    s: u32,
    stats: &mut Stats,
    pose: &mut Option<Pose<'a>>,
) -> Sample {
    sampler.start_pixel_sample(pixel, s);
    let film = pixel.as_vec2() + sampler.next_2d();
    let lens = if scene.camera.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
    let Some(m) = &scene.motion else {
        let ray = scene.camera.generate_ray(film, lens);
        let radiance = path::li(scene, ray, sampler, stats, None);
        return Sample { film, time: None, radiance };
    };
    let time = m.time(sampler.next_1d());
    let ray = match &m.camera {
        Some((_, local)) => m.camera_ray(local.generate_ray(film, lens), time),
        None => scene.camera.generate_ray(film, lens),
    };
    let pose = pose.get_or_insert_with(|| Pose::new(m, time));
    pose.set_time(time);
    let radiance = path::li(scene, ray, sampler, stats, Some(pose));
    Sample { film, time: Some(time), radiance }
}
