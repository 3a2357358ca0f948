//! The embedded default, `coordinator render`: one process runs the farm service on a loopback
//! port (its state in a temporary folder), stores the scene in it as a bundle and creates the job
//! with the checks of the REST API's upload and job calls (`Running::create_job`, without HTTP),
//! and runs N local workers: the worker loop of `worker --join`, linked to
//! the farm in-process (`service::LocalLink`: the same leases, checks and merging as a cluster's,
//! without sockets or result encoding). The finished frames are written as EXR and PNG.

use std::{
    path::{Path, PathBuf},
    sync::{
        atomic::{AtomicBool, Ordering},
        Mutex,
    },
    time::{Duration, Instant},
};

use anyhow::{bail, Context, Result};
use common::{
    budget::SceneBudget,
    bundle::{Bundle, Format},
    envmap::EnvMap,
    gltf::{DirResolver, Resolver},
    settings::{Environment, RenderSettings},
};
use worker::client::{self, WorkerOptions};

use crate::{
    farm::job::{JobState, JobStatus},
    output::{write_frame, FrameInfo},
    service::ServiceConfig,
};

/// What `render_file` did.
#[derive(Clone, Debug)]
pub struct RenderReport {
    /// Files written (EXR then PNG per frame).
    pub outputs: Vec<PathBuf>,
    /// Seconds spent loading and parsing the scene (and packing its bundle).
    pub load_seconds: f64,
    /// Seconds spent building the BVH (0 when the workers build it, inside the render time).
    pub build_seconds: f64,
    /// Seconds spent rendering (all frames).
    pub render_seconds: f64,
    /// Seconds spent writing the EXR and PNG files.
    pub write_seconds: f64,
    /// Rays traced.
    pub rays: u64,
    /// Samples taken.
    pub samples: u64,
    /// The last frame's mean radiance, row-major RGB.
    pub mean_rgb: Vec<[f32; 3]>,
    /// The last frame's estimated relative MSE (infinite below 2 spp; `FrameImage::est_rel_mse`).
    pub est_rel_mse: f64,
    /// Samples refused (NaN, infinite or absurd) over all frames.
    pub rejected: u64,
    /// The kernels that rendered the frames (`TaskResult::kernel`), by name.
    pub kernels: Vec<String>,
}

/// Where a render is, for a progress display.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Reading the scene and packing its bundle.
    Loading,
    /// Waiting for a worker to take the job's first task.
    Queued,
    /// Workers fetch and prepare the scene (decoding, BVH); no sample is in yet.
    Preparing,
    /// Pixel samples merged, out of those planned.
    Rendering {
        /// Merged.
        done: u64,
        /// Planned (less what adaptive sampling saved).
        total: u64,
    },
}

/// Progress callback.
pub type Progress<'a> = &'a (dyn Fn(Stage) + Sync);

/// `out.exr` -> `out_0007.exr` for frame 7.
pub fn numbered(out: &Path, frame: i64) -> PathBuf {
    let stem = out.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = out.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or("exr".into());
    out.with_file_name(format!("{stem}_{frame:04}.{ext}"))
}

/// Resolves files in a folder (never outside it) and remembers what it handed out, so that
/// exactly the files a scene uses go into its bundle.
struct RecordingResolver {
    inner: DirResolver,
    read: Mutex<Vec<(String, Vec<u8>)>>,
}

impl Resolver for RecordingResolver {
    fn read(&self, uri: &str) -> std::result::Result<Vec<u8>, String> {
        let bytes = self.inner.read(uri)?;
        let mut read = self.read.lock().unwrap_or_else(|p| p.into_inner());
        if !read.iter().any(|(u, _)| u == uri) {
            read.push((uri.to_string(), bytes.clone()));
        }
        Ok(bytes)
    }
}

/// A scene as one uploadable bundle, with the settings that go with it.
pub struct SceneBundle {
    /// The bytes to upload: a `.glb`/`.gltf` as it is, or a zip.
    pub bytes: Vec<u8>,
    /// The settings, the environment map renamed to its place in the bundle.
    pub settings: RenderSettings,
    /// Whether anything gives light: an emissive surface, a punctual light, or an environment
    /// that is not black. Without any, the image is black.
    pub lit: bool,
    /// The scene as loaded to make the bundle (what a worker loads from it).
    pub scene: common::scene::Scene,
    /// The environment map the settings name, as decoded to check it.
    pub env: Option<EnvMap>,
}

/// A scene file (`.glb`, `.gltf`, or a `.zip` of a folder, as the REST API takes) and the
/// environment map the settings name, as one uploadable bundle: a self-contained file as it is,
/// else a zip of it and exactly the files it uses (a zip as it is, with the map added when the
/// settings name one). The scene is loaded within `budget`, its images decoded on every core.
/// Warns when nothing in the scene or its environment gives light.
pub fn bundle_scene(
    scene_path: &Path,
    settings: &RenderSettings,
    budget: &SceneBudget,
) -> Result<SceneBundle> {
    let threads = worker::spread::Threads::available();
    let bytes = std::fs::read(scene_path)
        .with_context(|| format!("reading scene {}", scene_path.display()))?;
    let at = || scene_path.display().to_string();
    let (scene, mut files, scene_dir) = if Format::detect(&bytes).ok() == Some(Format::Zip) {
        let bundle = Bundle::open(&bytes, budget).with_context(at)?;
        let scene = bundle.load_scene_spread(&threads).with_context(at)?;
        let dir = bundle.main_path.rfind('/').map_or("", |i| &bundle.main_path[..=i]).to_string();
        (scene, Some(Files::Zip(bundle)), dir)
    } else {
        let dir = match scene_path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let resolver =
            RecordingResolver { inner: DirResolver::new(dir), read: Mutex::new(Vec::new()) };
        let scene = common::gltf::load_slice_spread(&bytes, &resolver, budget, &threads)
            .with_context(|| format!("loading {}", scene_path.display()))?;
        common::gltf::check_renderable(&scene).with_context(at)?;
        let read = resolver.read.into_inner().unwrap_or_else(|p| p.into_inner());
        let mut files = None;
        if !read.is_empty() {
            let ext = if bytes.starts_with(b"glTF") { "glb" } else { "gltf" };
            let mut all = vec![(format!("scene.{ext}"), bytes.clone())];
            all.extend(read);
            files = Some(all);
        }
        (scene, files.map(Files::Loose), String::new())
    };
    let mut settings = settings.clone();
    let lit = scene.has_lights() || settings.environment.as_ref().is_some_and(|e| !e.is_black());
    if !lit {
        tracing::warn!(
            "{}: nothing lights this scene (no emissive material, no KHR_lights_punctual light) and the environment is {}, so the image will be black; light it with an environment map: --env FILE.hdr, or \"environment\": {{\"map\": \"FILE.hdr\"}} in the settings (\"environment\": {{\"color\": [1, 1, 1]}} for a uniform white sky)",
            scene_path.display(),
            if settings.environment.is_some() { "black" } else { "black (none is set)" }
        );
    }
    let mut env = None;
    if let Some(Environment::Map { map, .. }) = &mut settings.environment {
        let path = PathBuf::from(&*map);
        let env_bytes = std::fs::read(&path)
            .with_context(|| format!("settings.environment.map: reading {}", path.display()))?;
        env = Some(EnvMap::from_bytes(map, &env_bytes).context("settings.environment.map")?);
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        *map = format!("__environment__/{name}");
        let mut all = match files.take() {
            Some(Files::Zip(bundle)) => bundle.into_files(),
            Some(Files::Loose(all)) => all,
            None => {
                let ext = if bytes.starts_with(b"glTF") { "glb" } else { "gltf" };
                vec![(format!("scene.{ext}"), bytes.clone())]
            }
        };
        all.push((format!("{scene_dir}{map}"), env_bytes));
        files = Some(Files::Loose(all));
    }
    let bytes = match files {
        Some(Files::Loose(all)) => Bundle::pack(&all)?,
        Some(Files::Zip(_)) | None => bytes,
    };
    Ok(SceneBundle { bytes, settings, lit, scene, env })
}

/// What goes into a bundle besides the scene file as read.
enum Files {
    /// An uploaded zip, opened.
    Zip(Bundle),
    /// Files to pack, the scene file first.
    Loose(Vec<(String, Vec<u8>)>),
}

pub(crate) fn http_error(what: &str, e: ureq::Error) -> anyhow::Error {
    match e {
        ureq::Error::Status(code, resp) => {
            let text = resp.into_string().unwrap_or_default();
            let msg = serde_json::from_str::<serde_json::Value>(&text)
                .ok()
                .and_then(|v| v["error"].as_str().map(str::to_string))
                .unwrap_or(text);
            anyhow::anyhow!("{what}: {msg} (HTTP {code})")
        }
        other => anyhow::anyhow!("{what}: {other}"),
    }
}

/// How `threads` render threads run locally, as (workers, threads each): as many local workers
/// of one thread each, or one worker of every thread where a job has fewer tasks over the whole
/// frame (photon mapping's ranges of passes, bidirectional path tracing's light tasks) than
/// twice the threads. A task renders on its worker's threads (the same bits on any count), so
/// one-thread workers would leave threads idle while so few such tasks run, and one such task
/// would run on one thread; where they are many, one-thread workers render them side by side
/// without the per-pass joins of threads within a task. A bidirectional camera task spreads its
/// rows over the threads. Under adaptive sampling of one frame whose pilot is one task a tile
/// (`samples_per_task` of at least `MIN_ADAPTIVE_SAMPLES`), where the whole-frame tasks come one
/// at a time, one-thread workers render each on every thread (the third value, threads for a
/// whole-frame task), the others rendering camera tasks, if any are left, or waiting; with more
/// frames or a longer pilot several could run at once, each on every thread.
fn local_workers(settings: &RenderSettings, threads: usize) -> (usize, usize, usize) {
    let threads = threads.max(1);
    let frames = (settings.frames.end as i128 - settings.frames.start as i128 + 1).max(1) as u128;
    let whole_frame_tasks = if settings.integrator.has_whole_frame_tasks() {
        frames * settings.spp.div_ceil(settings.samples_per_task.max(1)) as u128
    } else {
        u128::MAX
    };
    if whole_frame_tasks < 2 * threads as u128 {
        (1, threads, threads)
    } else if whole_frame_tasks != u128::MAX
        && settings.target_rel_error.is_some()
        && frames == 1
        && settings.samples_per_task >= crate::farm::job::MIN_ADAPTIVE_SAMPLES
    {
        (threads, 1, threads)
    } else {
        (threads, 1, 1)
    }
}

/// Renders `scene_path` with `settings` on `workers` local workers into `out` (frame ranges
/// write `OUT_####.exr`) through the farm: an in-process coordinator on a loopback port, the
/// workers linked to it in-process. A relative environment map path is relative to the working
/// directory. `progress` gets (samples done, samples planned).
pub fn render_file(
    scene_path: &Path,
    settings: &RenderSettings,
    workers: usize,
    out: &Path,
    progress: Progress<'_>,
) -> Result<RenderReport> {
    render_file_within(scene_path, settings, workers, SceneBudget::default(), out, progress)
}

/// [`render_file`] within a scene budget other than the default (`coordinator render
/// --max-scene-mib`, `--max-megatexels`, `--max-megatriangles`).
pub fn render_file_within(
    scene_path: &Path,
    settings: &RenderSettings,
    workers: usize,
    budget: SceneBudget,
    out: &Path,
    progress: Progress<'_>,
) -> Result<RenderReport> {
    settings.validate()?;
    let start = Instant::now();
    progress(Stage::Loading);
    let bundle = bundle_scene(scene_path, settings, &budget)?;
    let load_seconds = start.elapsed().as_secs_f64();
    let data = tempfile::Builder::new().prefix("renderfarm-").tempdir()?;
    let mut config = ServiceConfig::new(data.path().to_path_buf());
    config.farm.max_spp = common::settings::MAX_SPP;
    config.farm.scene_budget = budget;
    // The data folder is deleted when the render ends: nothing to keep across a crash.
    config.farm.durable = false;
    let service = crate::service::spawn("127.0.0.1:0", config)?;
    let map_name = match &bundle.settings.environment {
        Some(Environment::Map { map, .. }) => Some(map.clone()),
        _ => None,
    };
    // The farm's checks read the scene and map as loaded above rather than decode them again.
    let (scene_hash, id) = service
        .create_loaded_job(&bundle.bytes, &bundle.scene, bundle.env.is_some(), bundle.settings, 0)
        .map_err(|e| anyhow::anyhow!("{} ({})", e.message, e.kind))?;
    let render_start = Instant::now();
    let stop = AtomicBool::new(false);
    // The local workers take the scene and map as loaded above rather than decode them again.
    let env = map_name.zip(bundle.env);
    let cache = client::SceneCache::seeded(scene_hash.clone(), bundle.scene, env);
    let link = service.local_link();
    let (workers, threads, whole_frame_threads) = local_workers(settings, workers);
    let status = std::thread::scope(|s| -> Result<JobStatus> {
        let handles: Vec<_> = (0..workers)
            .map(|i| {
                let options = WorkerOptions {
                    threads,
                    whole_frame_threads,
                    name: format!("local-{i}"),
                    wait_s: 1.0,
                    prefetch_below: client::PREFETCH_BELOW,
                };
                let (stop, cache, link) = (&stop, &cache, &link);
                s.spawn(move || client::run_linked(link, &options, stop, cache))
            })
            .collect();
        let farm = service.farm();
        let mut handins = 0;
        let status = loop {
            let status = farm
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .status(&id)
                .map_err(|e| anyhow::anyhow!(e.message))?;
            progress(if status.samples_done == 0 && cache.scenes_prepared() == 0 {
                Stage::Preparing
            } else {
                // The job's progress (which counts a bidirectional job's light tile too) in its
                // pixel samples.
                let total = status.samples_planned - status.samples_saved;
                Stage::Rendering { done: (status.progress * total as f64).round() as u64, total }
            });
            if status.state.is_final() || handles.iter().all(|h| h.is_finished()) {
                break status;
            }
            // Woken by the next result (the last one ends the job), or after a while in case
            // the job ends otherwise (a time limit, a worker that stopped).
            handins = service.wait_for_handins(handins, Duration::from_millis(50));
        };
        stop.store(true, Ordering::Relaxed);
        service.drain();
        for h in handles {
            h.join().map_err(|_| anyhow::anyhow!("a local worker panicked"))??;
        }
        Ok(status)
    })?;
    let render_seconds = render_start.elapsed().as_secs_f64();
    match status.state {
        JobState::Done => {}
        JobState::Failed => bail!("the render failed: {}", status.error.unwrap_or_default()),
        other => bail!("the render stopped: job is {}", other.name()),
    }
    let multi = settings.frames.end > settings.frames.start;
    let write_start = Instant::now();
    let mut outputs = Vec::new();
    let (mut mean_rgb, mut est_rel_mse, mut rejected) = (Vec::new(), f64::INFINITY, 0);
    let farm = service.farm();
    let rays = farm.lock().unwrap_or_else(|p| p.into_inner()).counters.rays;
    let mut kernels = std::collections::BTreeSet::new();
    for (&frame, progress) in status.frames.iter().zip(&status.frame_progress) {
        kernels.extend(progress.kernels.iter().cloned());
        let (image, _) = farm
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .image(&id, frame)
            .map_err(|e| anyhow::anyhow!(e.message))?;
        rejected += image.rejected;
        if Some(&frame) == status.frames.last() {
            est_rel_mse = image.est_rel_mse();
            let [r, g, b] = &image.mean;
            mean_rgb = (0..r.len()).map(|i| [r[i], g[i], b[i]]).collect();
        }
        let exr_path = if multi { numbered(out, frame) } else { out.to_path_buf() };
        let info = FrameInfo {
            settings_json: serde_json::to_string(&status.settings)?,
            scene_hash: scene_hash.clone(),
            render_seconds: status.elapsed_s,
            frame,
            kernels: progress.kernels.clone(),
        };
        let png_path = exr_path.with_extension("png");
        write_frame(&exr_path, &png_path, image, &info)?;
        outputs.push(exr_path);
        outputs.push(png_path);
    }
    let write_seconds = write_start.elapsed().as_secs_f64();
    drop(farm);
    service.stop()?;
    Ok(RenderReport {
        outputs,
        load_seconds,
        build_seconds: 0.0,
        render_seconds,
        write_seconds,
        rays,
        samples: status.samples_done,
        mean_rgb,
        est_rel_mse,
        rejected,
        kernels: kernels.into_iter().collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use common::settings::Integrator;

    /// One worker of every thread where a photon-mapping or bidirectional job has fewer
    /// whole-frame tasks than twice the threads (counted over its frames); one-thread workers
    /// otherwise, and always for the path tracer; those of an adaptive photon-mapping or
    /// bidirectional job of one frame and a one-task pilot render a whole-frame task on every
    /// thread.
    #[test]
    fn few_whole_frame_tasks_render_on_one_worker_of_every_thread() {
        let job = |integrator: Integrator, spp: u32, frames: i64| RenderSettings {
            integrator,
            spp,
            samples_per_task: 64,
            frames: common::settings::Frames { start: 1, end: frames, ..Default::default() },
            ..Default::default()
        };
        for integrator in [Integrator::Sppm, Integrator::Bdpt] {
            assert_eq!(local_workers(&job(integrator, 64, 1), 4), (1, 4, 4));
            assert_eq!(local_workers(&job(integrator, 7 * 64, 1), 4), (1, 4, 4));
            assert_eq!(local_workers(&job(integrator, 8 * 64, 1), 4), (4, 1, 1));
            assert_eq!(local_workers(&job(integrator, 4 * 64, 2), 4), (4, 1, 1));
            assert_eq!(local_workers(&job(integrator, 64, 1), 0), (1, 1, 1));
            let adaptive =
                RenderSettings { target_rel_error: Some(0.1), ..job(integrator, 8 * 64, 1) };
            assert_eq!(local_workers(&adaptive, 4), (4, 1, 4));
            // Several whole-frame tasks at once (frames, or a pilot of several tasks a tile).
            let frames =
                RenderSettings { target_rel_error: Some(0.1), ..job(integrator, 8 * 64, 2) };
            assert_eq!(local_workers(&frames, 4), (4, 1, 1));
            let pilot = RenderSettings { samples_per_task: 8, ..adaptive };
            assert_eq!(local_workers(&pilot, 4), (4, 1, 1));
        }
        assert_eq!(local_workers(&job(Integrator::Path, 64, 1), 4), (4, 1, 1));
        let adaptive =
            RenderSettings { target_rel_error: Some(0.1), ..job(Integrator::Path, 8 * 64, 1) };
        assert_eq!(local_workers(&adaptive, 4), (4, 1, 1));
    }
}
