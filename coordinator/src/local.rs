//! The embedded default: one process renders a job with N local worker threads and writes the
//! EXR and PNG. Workers pull tasks in progressive order; results merge exactly, so the image is
//! the same for any number of workers.

use std::{
    path::{Path, PathBuf},
    sync::{
        atomic::{AtomicUsize, Ordering},
        Mutex,
    },
    time::Instant,
};

use anyhow::{bail, Context, Result};
use common::{
    envmap::EnvMap,
    film::Film,
    settings::{Environment, RenderSettings},
};
use sha2::{Digest, Sha256};
use worker::render::{render_task, scene::prepare_with_environment};

use crate::{
    output::{write_exr, write_png, FrameInfo},
    split::frame_tasks,
};

/// What `render_file` did.
#[derive(Clone, Debug)]
pub struct RenderReport {
    /// Files written (EXR then PNG per frame).
    pub outputs: Vec<PathBuf>,
    /// Seconds spent loading and parsing the scene.
    pub load_seconds: f64,
    /// Seconds spent building the BVH.
    pub build_seconds: f64,
    /// Seconds spent rendering (all frames).
    pub render_seconds: f64,
    /// Seconds spent writing the EXR and PNG files.
    pub write_seconds: f64,
    /// Rays traced.
    pub rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// The last frame's film.
    pub film: Film,
}

/// Progress callback: (tasks done, tasks total).
pub type Progress<'a> = &'a (dyn Fn(usize, usize) + Sync);

/// Renders `scene_path` with `settings` on `workers` threads into `out` (frame ranges write
/// `OUT_####.exr`). A relative environment map path is relative to the working directory.
pub fn render_file(
    scene_path: &Path,
    settings: &RenderSettings,
    workers: usize,
    out: &Path,
    progress: Progress<'_>,
) -> Result<RenderReport> {
    settings.validate()?;
    let start = Instant::now();
    let bytes = std::fs::read(scene_path)
        .with_context(|| format!("reading scene {}", scene_path.display()))?;
    let scene_hash = hex(&Sha256::digest(&bytes));
    let scene = common::gltf::load_path(scene_path)
        .with_context(|| format!("loading {}", scene_path.display()))?;
    common::gltf::check_renderable(&scene).with_context(|| format!("{}", scene_path.display()))?;
    let env_map = match &settings.environment {
        Some(Environment::Map { map, .. }) => {
            Some(EnvMap::load(Path::new(map)).context("loading settings.environment.map")?)
        }
        _ => None,
    };
    let load_seconds = start.elapsed().as_secs_f64();
    let prepared = prepare_with_environment(&scene, settings, env_map.as_ref())
        .context("preparing the scene")?;
    drop(env_map);
    let build_seconds = prepared.build_seconds;
    drop(scene);

    let frames = settings.frames.start..=settings.frames.end;
    let multi = settings.frames.end > settings.frames.start;
    let mut outputs = Vec::new();
    let mut render_seconds = 0.0;
    let mut write_seconds = 0.0;
    let mut rays = 0;
    let mut samples = 0;
    let mut film = Film::new(settings.width, settings.height);
    for frame in frames {
        if frame != settings.frames.start && settings.frames.start != settings.frames.end {
            bail!("animated frame ranges need node animation, which is not supported yet");
        }
        let tasks = frame_tasks(settings, frame);
        let frame_start = Instant::now();
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        let merged = Mutex::new((Film::new(settings.width, settings.height), 0u64));
        std::thread::scope(|s| {
            for _ in 0..workers.max(1) {
                s.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(task) = tasks.get(i) else { break };
                    let result = render_task(&prepared, settings.seed, task);
                    let mut guard = merged.lock().expect("film lock poisoned");
                    guard.0.merge_tile(&result.tile);
                    guard.1 += result.rays;
                    drop(guard);
                    progress(done.fetch_add(1, Ordering::Relaxed) + 1, tasks.len());
                });
            }
        });
        let (frame_film, frame_rays) = merged.into_inner().expect("film lock poisoned");
        let seconds = frame_start.elapsed().as_secs_f64();
        render_seconds += seconds;
        rays += frame_rays;
        samples += frame_film.total_samples();
        let exr_path = if multi { numbered(out, frame) } else { out.to_path_buf() };
        let info = FrameInfo {
            settings_json: serde_json::to_string(settings)?,
            scene_hash: scene_hash.clone(),
            render_seconds: seconds,
            frame,
        };
        let write_start = Instant::now();
        write_exr(&exr_path, &frame_film, &info)?;
        let png_path = exr_path.with_extension("png");
        write_png(&png_path, &frame_film, 0.0)?;
        write_seconds += write_start.elapsed().as_secs_f64();
        outputs.push(exr_path);
        outputs.push(png_path);
        film = frame_film;
    }
    Ok(RenderReport {
        outputs,
        load_seconds,
        build_seconds,
        render_seconds,
        write_seconds,
        rays,
        samples,
        film,
    })
}

/// `out.exr` -> `out_0007.exr` for frame 7.
fn numbered(out: &Path, frame: i64) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = out.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or("exr".into());
    out.with_file_name(format!("{stem}_{frame:04}.{ext}"))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
