//! Where a sample spends its time, on one thread: whole samples against bare ray casts. Each
//! figure is the fastest of several repetitions (the least disturbed by other load).
//! `cargo run --release -p worker --example hotpath -- scenes/cornell-box.gltf` (the
//! render size comes from `SCENE.settings.json` beside the scene when there is one, else 256x256).
//! `HOTPATH_REPEAT=1` runs each measurement once (for instruction counts under
//! `valgrind --tool=callgrind`, which are steadier than times on a shared machine);
//! `HOTPATH_ALL=1` prints every repetition's time; `HOTPATH_SAMPLES_ONLY=1` stops after the first
//! measurement (whole samples), for quick alternating runs of two builds; `HOTPATH_SPP=N` renders
//! N samples per pixel instead of 4 (a pixel's samples one after another, as a task does);
//! `HOTPATH_SCALAR=1` makes `render_task_threads` trace one path at a time where it would use
//! the wavefront renderer (the whole-sample figure is always the scalar `li`).
use std::time::Instant;

use common::settings::RenderSettings;
use glam::{UVec2, Vec2, Vec3};
use worker::render::{
    geometry::Ray,
    integrators::{path::li, Stats},
    sampler::Sampler,
    scene::{prepare, PreparedScene},
};

const REPEAT: usize = 7;
/// Samples per pixel (`HOTPATH_SPP`, default 4).
fn spp() -> u32 {
    std::env::var("HOTPATH_SPP").ok().and_then(|s| s.parse().ok()).filter(|&s| s > 0).unwrap_or(4)
}

/// Fastest of `REPEAT` runs of `f`, in seconds.
fn fastest(mut f: impl FnMut() -> u64) -> (f64, u64) {
    let mut best = f64::INFINITY;
    let mut out = 0;
    let repeat =
        std::env::var("HOTPATH_REPEAT").ok().and_then(|r| r.parse().ok()).unwrap_or(REPEAT);
    for _ in 0..repeat {
        let t = Instant::now();
        out = f();
        best = best.min(t.elapsed().as_secs_f64());
        if std::env::var_os("HOTPATH_ALL").is_some() {
            eprintln!("  run: {:.4} s", t.elapsed().as_secs_f64());
        }
    }
    (best, out)
}

fn camera_rays(scene: &PreparedScene, w: u32, h: u32, spp: u32, mut f: impl FnMut(Ray)) {
    let mut sampler = Sampler::new(1, 0);
    for y in 0..h {
        for x in 0..w {
            for s in 0..spp {
                sampler.start_pixel_sample(UVec2::new(x, y), s);
                let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                f(scene.camera.generate_ray(film, Vec2::ZERO));
            }
        }
    }
}

fn main() -> anyhow::Result<()> {
    let path = std::env::args().nth(1).expect("scene path");
    let scene = common::gltf::load_path(path.as_ref())?;
    let settings = match std::fs::read_to_string(
        std::path::Path::new(&path).with_extension("settings.json"),
    ) {
        Ok(text) => RenderSettings::from_json(&text).map_err(anyhow::Error::msg)?,
        Err(_) => RenderSettings { width: 256, height: 256, ..Default::default() },
    };
    let mut prepared = prepare(&scene, &settings)?;
    if std::env::var_os("HOTPATH_SCALAR").is_some() {
        prepared.drop_wavefront();
    }
    let (w, h) = (settings.width, settings.height);
    let spp = spp();
    let n = (w * h * spp) as f64;

    let (secs, rays) = fastest(|| {
        let mut sampler = Sampler::new(1, 0);
        let mut stats = Stats::default();
        let mut acc = Vec3::ZERO;
        for y in 0..h {
            for x in 0..w {
                for s in 0..spp {
                    sampler.start_pixel_sample(UVec2::new(x, y), s);
                    let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                    let ray = prepared.camera.generate_ray(film, Vec2::ZERO);
                    acc += li(&prepared, ray, &mut sampler, &mut stats, None);
                }
            }
        }
        std::hint::black_box(acc);
        stats.rays
    });
    println!("samples: {:.3} us/sample, {:.2} rays/sample", secs / n * 1e6, rays as f64 / n);
    if std::env::var_os("HOTPATH_SAMPLES_ONLY").is_some() {
        return Ok(());
    }
    let (secs, _) = fastest(|| {
        let mut sampler = Sampler::new(1, 0);
        let mut stats = Stats::default();
        let mut tile =
            common::film::TileAccum::new(common::film::Rect { x0: 0, y0: 0, width: w, height: h });
        for y in 0..h {
            for x in 0..w {
                for s in 0..spp {
                    sampler.start_pixel_sample(UVec2::new(x, y), s);
                    let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
                    let ray = prepared.camera.generate_ray(film, Vec2::ZERO);
                    let l = li(&prepared, ray, &mut sampler, &mut stats, None);
                    tile.add_sample(x, y, s, l.to_array());
                }
            }
        }
        std::hint::black_box(&tile);
        stats.rays
    });
    println!("samples into a film: {:.3} us/sample", secs / n * 1e6);
    for threads in [1, 2] {
        let task = common::protocol::TaskSpec {
            frame: 0,
            rect: common::film::Rect { x0: 0, y0: 0, width: w, height: h },
            samples: common::protocol::SampleRange { start: 0, end: spp },
            kind: common::protocol::TaskKind::Camera,
        };
        let (secs, _) =
            fastest(|| worker::render::render_task_threads(&prepared, 1, &task, threads).rays);
        println!("render_task_threads, {threads} thread(s): {:.3} us/sample", secs / n * 1e6);
    }
    let (secs, found) = fastest(|| {
        let mut k = 0;
        camera_rays(&prepared, w, h, spp, |r| {
            k += prepared.intersect(&r, f32::INFINITY, None).is_some() as u64
        });
        k
    });
    println!("camera closest hit: {:.1} ns/ray ({found} hits)", secs / n * 1e9);
    let mut hits = Vec::new();
    camera_rays(&prepared, w, h, spp, |r| {
        if let Some(hit) = prepared.intersect(&r, f32::INFINITY, None) {
            hits.push(r.origin + r.dir * hit.t * 0.999);
        }
    });
    let mut sampler = Sampler::new(2, 0);
    let dirs: Vec<Vec3> = (0..hits.len())
        .map(|i| {
            sampler.start_pixel_sample(UVec2::new(i as u32, 0), 0);
            let u = sampler.next_2d();
            let z = 1.0 - 2.0 * u.x;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = std::f32::consts::TAU * u.y;
            Vec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect();
    let m = hits.len() as f64;
    let (secs, found) = fastest(|| {
        hits.iter()
            .zip(&dirs)
            .map(|(p, d)| {
                prepared.intersect(&Ray::new(*p, *d), f32::INFINITY, None).is_some() as u64
            })
            .sum()
    });
    println!("secondary closest hit: {:.1} ns/ray ({found} hits)", secs / m * 1e9);
    let light = prepared.camera.generate_ray(Vec2::new(w as f32 / 2.0, 2.0), Vec2::ZERO).dir * 0.5;
    let (secs, blocked) = fastest(|| {
        hits.iter().map(|p| prepared.occluded(&Ray::new(*p, light - *p), 0.999, None) as u64).sum()
    });
    println!("shadow rays: {:.1} ns/ray ({blocked} blocked)", secs / m * 1e9);
    Ok(())
}
