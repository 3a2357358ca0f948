//! One job's scheduling state: its frames, their tiles, and each tile's tasks.
//!
//! Task `k` of a tile covers samples `[k * samples_per_task, min((k + 1) * samples_per_task,
//! spp))`. A task is open (to be leased), leased, or merged; a result is accepted only for a
//! leased task, which it turns merged, so no sample is ever counted twice. A tile's results are
//! added to its sums in task order (floating-point merging is deterministic only in a fixed
//! order): a result that arrives before its predecessors waits in the tile's `pending` map until
//! they are in, so the sums are the same whatever order results arrive in.
//!
//! Adaptive sampling (`target_rel_error` T, a relative RMSE) spends samples where they lower
//! the image's relative MSE most. Every tile first takes a pilot of [`MIN_ADAPTIVE_SAMPLES`]
//! per pixel. When a frame's whole pilot is merged, the frame's stopping scale is fixed from it:
//! with e_t the estimated relative MSE of tile t after n samples per pixel and v_t = e_t n its
//! per-sample relative variance, the fewest samples reaching a mean error of T² give tile t
//! n_t ∝ sqrt(v_t) (Lagrange), i.e. stop when e_t <= c² n with c = T² A / Σ a_t sqrt(v_t)
//! (a_t tile areas, A their sum). After that, a tile's task `k` is decided
//! from the fixed scale and that tile's tasks `0..k`, all merged. Every decision reads only
//! completed data, so the image is the same whatever the timing and the number of workers.
//! A photon-mapping frame is one tile, which stops once its own estimate reaches T² (its
//! passes' variance grows as the gather radius shrinks, so the pilot's does not scale); its
//! tasks then run one at a time, each on all of a worker's threads.
//!
//! A bidirectional frame's image is each camera tile plus the light tile (light tracing, over
//! the whole frame): two independent estimates with their own sample counts, each unbiased
//! whatever the other's count (the MIS weights of a path sum to one over the strategies, and
//! each strategy is averaged over its own samples). So each tile, the light tile included, has
//! its own count, and e_t is the error that tile's part adds to the sum's: its variance over
//! the sum's squared means *as the pilot merged them* (`Frame::pilot`, fixed and stored with
//! the scale, so that a decision reads only the deciding tile's data and the image stays the
//! same bits whatever the timing and after a restart). The light tile enters the Lagrange sum as
//! a tile of the frame's area whose sample costs r = `bdpt.light_paths` camera samples (a pixel
//! sample's light samples are that many light subpaths, each about a camera sample's work),
//! but not in the area A the error is averaged over: with costs the fewest-work allocation is
//! n_t ∝ sqrt(v_t / r_t), so c = T² A / Σ a_t sqrt(v_t r_t) and a tile stops when e_t <= r_t c² n.

mod restore;
mod status;

use std::collections::{BTreeMap, BTreeSet};

use common::{
    film::{ErrorEstimate, Rect, TileAccum},
    protocol::{SampleRange, TaskKind, TaskSpec},
    settings::{Integrator, RenderSettings},
};
use serde::Serialize;

use super::clock::Moment;
use crate::{output::FrameImage, split::tiles};

pub use status::{
    ErrorPoint, FrameProgress, JobStatus, JobSummary, HISTORY_POINTS, HISTORY_STEP_S,
};

/// A tile's error estimate is trusted for stopping from this many samples per pixel on.
pub const MIN_ADAPTIVE_SAMPLES: u32 = 16;

/// The life of a job.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum JobState {
    /// Waiting for its first task to be leased.
    Queued,
    /// At least one task has been leased.
    Running,
    /// Every frame is complete.
    Done,
    /// Stopped by an error (see the job's `error`).
    Failed,
    /// Stopped by a user.
    Cancelled,
}

impl JobState {
    /// The name used in the API and the database.
    pub fn name(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Done => "done",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    /// Parses [`JobState::name`].
    pub fn parse(s: &str) -> Option<JobState> {
        Some(match s {
            "queued" => JobState::Queued,
            "running" => JobState::Running,
            "done" => JobState::Done,
            "failed" => JobState::Failed,
            "cancelled" => JobState::Cancelled,
            _ => return None,
        })
    }

    /// True once nothing more will happen to the job.
    pub fn is_final(self) -> bool {
        matches!(self, JobState::Done | JobState::Failed | JobState::Cancelled)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum TaskState {
    Open,
    Leased,
    Merged,
}

/// Names one task of a job: frame index (0 = the first frame of the range), tile, task number.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TaskKey {
    /// Index into the job's frames.
    pub frame: u32,
    /// Index into the frame's tiles.
    pub tile: u32,
    /// Task number within the tile.
    pub k: u32,
}

/// One tile's merged sums and task states.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Sums of tasks `0..prefix`, added in task order.
    pub sums: TileAccum,
    tasks: Vec<TaskState>,
    /// Number of accepted tasks (in `sums` or `pending`).
    pub merged: u32,
    /// Tasks `0..prefix` are added to `sums`.
    pub prefix: u32,
    /// Accepted results waiting for an earlier task, by task number.
    pub pending: BTreeMap<u32, TileAccum>,
    /// Adaptive sampling stopped this tile.
    pub converged: bool,
    /// Estimated relative MSE of the merged sums: against their own means, or in a
    /// bidirectional frame the share of the image's that this tile's part adds (its variance over
    /// the image's squared means: the pilot's under adaptive sampling, else the current ones), so
    /// that the tiles' shares, weighed by area, add up to the image's.
    pub rel_mse: f64,
    /// A bidirectional frame's camera tile without a pilot image: the light tile's share over
    /// this tile's pixels (the light tile's `rel_mse` is their mean).
    pub light_share: f64,
    /// Bidirectional path tracing's light tile: the whole frame, whose tasks are light tasks
    /// (`TaskKind::Light`) and whose image adds to the other tiles' (the frame's last tile).
    pub light: bool,
}

impl Tile {
    fn first_open(&self) -> Option<u32> {
        self.tasks.iter().position(|&t| t == TaskState::Open).map(|k| k as u32)
    }

    /// Whether no more of its tasks are needed: all merged, or adaptive sampling stopped it.
    pub fn is_complete(&self) -> bool {
        self.converged || self.prefix as usize == self.tasks.len()
    }

    /// Its planned tasks.
    pub fn task_count(&self) -> u32 {
        self.tasks.len() as u32
    }
}

/// One frame of a job.
#[derive(Clone, Debug)]
pub struct Frame {
    /// The frame number (animation time = number / fps).
    pub number: i64,
    /// Its tiles, row-major.
    pub tiles: Vec<Tile>,
    /// Adaptive sampling: the stopping scale c, fixed once the pilot is merged.
    pub scale: Option<f64>,
    /// Adaptive sampling of a bidirectional frame: the image's means (each camera tile's plus
    /// the light tile's, row-major over the frame) when the pilot was merged, against which
    /// each tile's part of the error is measured. Fixed with the scale; stored with it.
    pub pilot: Option<Vec<[f32; 3]>>,
    /// Pixel samples accepted for this frame.
    pub samples_done: u64,
    /// The frame is complete and its sums left memory (they are in the database).
    pub evicted: bool,
    /// The kernels that rendered the tasks merged into it (`TaskResult::kernel`), by name.
    pub kernels: BTreeSet<String>,
}

/// A job and everything the scheduler knows about it.
#[derive(Debug)]
pub struct Job {
    /// Its id.
    pub id: String,
    /// Creation order (older jobs first among equals).
    pub seq: u64,
    /// SHA-256 of the scene bundle.
    pub scene: String,
    /// The settings, validated.
    pub settings: RenderSettings,
    /// Higher runs first.
    pub priority: i32,
    /// Where it is in its life.
    pub state: JobState,
    /// Why it failed.
    pub error: Option<String>,
    /// Creation time, seconds since the Unix epoch.
    pub created_unix: f64,
    /// Running seconds accumulated before the current run (coordinator restarts).
    pub elapsed_before: f64,
    /// When the current run started (the first lease since the coordinator started).
    running_since: Option<Moment>,
    /// The frames.
    pub frames: Vec<Frame>,
    /// Tasks per tile (the last one may cover fewer samples).
    pub tasks_per_tile: u32,
    /// Leases out now.
    pub in_flight: u32,
    /// Samples merged (pixel samples).
    pub samples_done: u64,
    /// Light tiles' samples merged (a pixel's light sample each, `bdpt.light_paths` per pixel
    /// sample): work, not pixel samples, counted in the progress only.
    pub light_samples_done: u64,
    tiles_open: usize,
    /// The time limit has passed: no more tasks are issued.
    pub time_up: bool,
    /// A finished job's sums were dropped from memory (they stay in the database).
    pub evicted: bool,
    /// When it ended (done, failed or cancelled), seconds since the Unix epoch: what
    /// `--retain-finished-hours` counts from. Noted by the farm, which reads the clock.
    pub finished_unix: Option<f64>,
    /// Its name, as the submitter gave it (`validate_job_name`).
    pub name: Option<String>,
    /// Its estimated error against its running time since this process took it up
    /// ([`Job::note_progress`]; not stored: a restarted coordinator starts it anew).
    pub history: Vec<status::ErrorPoint>,
    /// The running seconds between two points of `history` (doubled whenever it fills).
    history_step: f64,
}

/// A job refuses more than this many tasks (absurd settings would only fill memory).
pub const MAX_TASKS_PER_JOB: u64 = 4_000_000;

impl Job {
    /// A new job with nothing rendered. `settings` must be valid.
    pub fn new(
        id: String,
        seq: u64,
        scene: String,
        settings: RenderSettings,
        priority: i32,
        created_unix: f64,
    ) -> Result<Job, String> {
        let tasks_per_tile = settings.spp.div_ceil(settings.samples_per_task);
        let whole = Rect { x0: 0, y0: 0, width: settings.width, height: settings.height };
        // Photon mapping renders a pass over the whole frame at once (its photons land anywhere):
        // one tile, the frame, whose task `k` is the passes of sample range `k`.
        let mut rects = if settings.integrator == Integrator::Sppm {
            vec![whole]
        } else {
            tiles(settings.width, settings.height, settings.tile_size)
        };
        // Bidirectional path tracing adds a light tile per frame, the whole frame, last.
        let light = settings.integrator == Integrator::Bdpt;
        if light {
            rects.push(whole);
        }
        let n_rects = rects.len();
        let n_frames =
            (settings.frames.end as i128 - settings.frames.start as i128 + 1).max(0) as u128;
        let total = n_frames * rects.len() as u128 * tasks_per_tile as u128;
        if total > MAX_TASKS_PER_JOB as u128 {
            return Err(format!(
                "{total} tasks ({n_frames} frames x {} tiles x {tasks_per_tile} sample ranges) is over the limit of {MAX_TASKS_PER_JOB}: raise tile_size or samples_per_task",
                rects.len()
            ));
        }
        let frames: Vec<Frame> = (settings.frames.start..=settings.frames.end)
            .map(|number| Frame {
                number,
                tiles: rects
                    .iter()
                    .enumerate()
                    .map(|(i, &rect)| Tile {
                        // Pixels are allocated by the first result: a long animation holds
                        // only the frames in progress.
                        sums: TileAccum { rect, pixels: Vec::new(), rejected: 0 },
                        tasks: vec![TaskState::Open; tasks_per_tile as usize],
                        merged: 0,
                        prefix: 0,
                        pending: BTreeMap::new(),
                        converged: false,
                        rel_mse: f64::INFINITY,
                        light_share: 0.0,
                        light: light && i + 1 == n_rects,
                    })
                    .collect(),
                scale: None,
                pilot: None,
                samples_done: 0,
                evicted: false,
                kernels: BTreeSet::new(),
            })
            .collect();
        let tiles_open = frames.iter().map(|f| f.tiles.len()).sum();
        Ok(Job {
            id,
            seq,
            scene,
            settings,
            priority,
            state: JobState::Queued,
            error: None,
            created_unix,
            elapsed_before: 0.0,
            running_since: None,
            frames,
            tasks_per_tile,
            in_flight: 0,
            samples_done: 0,
            light_samples_done: 0,
            tiles_open,
            time_up: false,
            evicted: false,
            finished_unix: None,
            name: None,
            history: Vec::new(),
            history_step: status::HISTORY_STEP_S,
        })
    }

    /// The specification of task `key`.
    pub fn spec(&self, key: TaskKey) -> TaskSpec {
        let tile = &self.frames[key.frame as usize].tiles[key.tile as usize];
        // A light tile has `bdpt.light_paths` samples per pixel sample: its task `k` is the light
        // samples of pixel sample range `k` (as many tasks as a camera tile, so that the
        // frame-sized sums they return do not multiply).
        let (per_sample, kind) = if tile.light {
            (self.settings.light_paths(), TaskKind::Light)
        } else {
            (1, TaskKind::Camera)
        };
        let spt = self.settings.samples_per_task * per_sample;
        let start = key.k * spt;
        TaskSpec {
            frame: self.frames[key.frame as usize].number,
            rect: tile.sums.rect,
            samples: SampleRange { start, end: (start + spt).min(self.settings.spp * per_sample) },
            kind,
        }
    }

    /// Seconds spent running at `now` (accumulated over coordinator restarts).
    pub fn elapsed(&self, now: Moment) -> f64 {
        self.elapsed_before + self.running_since.map_or(0.0, |t| now.since(t).as_secs_f64())
    }

    fn adaptive_target(&self) -> Option<f64> {
        self.settings.target_rel_error.map(|e| e * e)
    }

    fn min_adaptive_tasks(&self) -> u32 {
        MIN_ADAPTIVE_SAMPLES.div_ceil(self.settings.samples_per_task).max(1)
    }

    /// The task to lease next, if any: frame by frame (workers keep one frame's scene prepared),
    /// within a frame the lowest task number over all tiles (so the whole image refines
    /// progressively), among equals the tile with the highest estimated error, then the first. A
    /// tile under adaptive control gets task `k` only once tasks `0..k` are merged.
    pub fn next_task(&self) -> Option<TaskKey> {
        if self.state.is_final() || self.time_up {
            return None;
        }
        let adaptive = self.adaptive_target().is_some();
        let min_tasks = self.min_adaptive_tasks();
        let mut best: Option<(u32, f64, TaskKey)> = None;
        for (f, frame) in self.frames.iter().enumerate() {
            if best.is_some() {
                break; // an earlier frame still has work
            }
            for (t, tile) in frame.tiles.iter().enumerate() {
                if tile.converged {
                    continue;
                }
                let Some(k) = tile.first_open() else { continue };
                if adaptive && k >= min_tasks && (frame.scale.is_none() || tile.prefix != k) {
                    continue; // waiting for the data that decides this task
                }
                let better = match best {
                    None => true,
                    Some((bk, be, _)) => k < bk || (k == bk && tile.rel_mse > be),
                };
                if better {
                    best = Some((k, tile.rel_mse, TaskKey { frame: f as u32, tile: t as u32, k }));
                }
            }
        }
        best.map(|(_, _, key)| key)
    }

    /// Marks `key` leased at `now`.
    pub fn lease(&mut self, key: TaskKey, now: Moment) {
        let slot =
            &mut self.frames[key.frame as usize].tiles[key.tile as usize].tasks[key.k as usize];
        debug_assert_eq!(*slot, TaskState::Open);
        *slot = TaskState::Leased;
        self.in_flight += 1;
        if self.state == JobState::Queued {
            self.state = JobState::Running;
        }
        if self.running_since.is_none() {
            self.running_since = Some(now);
        }
    }

    /// Puts a leased task back to be leased again (its lease expired, failed or was given
    /// back; the lease machine counts those).
    pub fn give_back(&mut self, key: TaskKey, now: Moment) {
        let slot =
            &mut self.frames[key.frame as usize].tiles[key.tile as usize].tasks[key.k as usize];
        if *slot == TaskState::Leased {
            *slot = TaskState::Open;
            self.in_flight -= 1;
        }
        // Past the time limit nothing is leased again: the last lease out ends the job.
        self.finish_if_complete(now);
    }

    /// Notes that `kernel` rendered a task of frame index `f`.
    pub fn note_kernel(&mut self, f: usize, kernel: &str) {
        let kernels = &mut self.frames[f].kernels;
        if !kernels.contains(kernel) {
            kernels.insert(kernel.to_string());
        }
    }

    /// Accepts the sums of the leased task `key` (the caller has checked that they answer it):
    /// adds them to the tile in task order, or keeps them pending until their predecessors are in.
    pub fn merge(&mut self, key: TaskKey, tile: TileAccum, samples: u64, now: Moment) {
        let (width, height) = (self.settings.width, self.settings.height);
        let frame = &mut self.frames[key.frame as usize];
        let t = &mut frame.tiles[key.tile as usize];
        debug_assert_eq!(t.tasks[key.k as usize], TaskState::Leased);
        t.tasks[key.k as usize] = TaskState::Merged;
        t.merged += 1;
        t.pending.insert(key.k, tile);
        let is_light = t.light;
        if Self::drain_pending(t) {
            frame.update_rel_mse(key.tile as usize, width, height);
        }
        // Pixel samples count the camera's: a light task's add no pixel samples of their own.
        let (samples, light) = if is_light { (0, samples) } else { (samples, 0) };
        self.light_samples_done += light;
        self.in_flight -= 1;
        self.samples_done += samples;
        self.frames[key.frame as usize].samples_done += samples;
        self.update_adaptive(key.frame as usize);
        self.finish_if_complete(now);
    }

    /// Whether frame index `f` needs no more samples.
    pub fn frame_complete(&self, f: usize) -> bool {
        self.frames[f].tiles.iter().all(Tile::is_complete)
    }

    /// Drops a complete frame's sums from memory (call once they are committed, or queued for a
    /// commit that every later read of the database waits for).
    pub fn evict_frame(&mut self, f: usize) {
        let frame = &mut self.frames[f];
        for tile in &mut frame.tiles {
            tile.sums.pixels = Vec::new();
            tile.pending.clear();
        }
        frame.pilot = None;
        frame.evicted = true;
    }

    /// Adds the pending results that continue the tile's prefix, in task order; whether the
    /// prefix advanced.
    fn drain_pending(t: &mut Tile) -> bool {
        let mut advanced = false;
        while let Some(next) = t.pending.remove(&t.prefix) {
            if t.sums.pixels.is_empty() {
                t.sums = next; // the same bits as merging into an empty tile
            } else {
                t.sums.merge(&next);
            }
            t.prefix += 1;
            advanced = true;
        }
        advanced
    }

    /// Fixes the frame's stopping scale once its pilot is merged, and stops the tiles that the
    /// scale and their merged data say are done. Idempotent.
    fn update_adaptive(&mut self, f: usize) {
        let Some(target) = self.adaptive_target() else {
            self.count_open_tiles();
            return;
        };
        let min_tasks = self.min_adaptive_tasks();
        let spt = self.settings.samples_per_task;
        let spp = self.settings.spp;
        // A sample's cost in camera samples (see the module doc).
        let light_paths = self.settings.light_paths() as f64;
        let cost = |t: &Tile| if t.light { light_paths } else { 1.0 };
        let frame = &mut self.frames[f];
        if frame.scale.is_none() {
            let pilot_done =
                frame.tiles.iter().all(|t| t.prefix >= min_tasks.min(t.tasks.len() as u32));
            if !pilot_done {
                self.count_open_tiles();
                return;
            }
            if frame.tiles.iter().any(|t| t.light) {
                let (width, height) = (self.settings.width, self.settings.height);
                frame.pilot = Some(image_means(frame, width, height));
                frame.update_all_rel_mse(width, height);
            }
            let n = (min_tasks * spt).min(spp) as f64;
            let (mut area, mut weighted) = (0.0, 0.0);
            for t in &frame.tiles {
                let a = t.sums.rect.area() as f64;
                if !t.light {
                    area += a; // the light tile's pixels are the others' (see the module doc)
                }
                weighted += a * (t.rel_mse.max(0.0) * n * cost(t)).sqrt();
            }
            frame.scale = Some(if weighted > 0.0 { target * area / weighted } else { 1.0 });
        }
        let c = frame.scale.expect("set above");
        // Photon mapping's frame is one tile whose passes' variance grows as the radius shrinks,
        // so the pilot's variance per sample, which the scale assumes, understates the later
        // passes': its tile stops when its own estimate reaches the target.
        let photon_passes = self.settings.integrator == Integrator::Sppm;
        for t in &mut frame.tiles {
            let n = (t.prefix * spt).min(spp) as f64;
            let done =
                if photon_passes { t.rel_mse <= target } else { t.rel_mse <= cost(t) * c * c * n };
            if !t.converged && t.prefix >= min_tasks && (t.prefix as usize) < t.tasks.len() && done
            {
                t.converged = true;
            }
        }
        self.count_open_tiles();
    }

    fn count_open_tiles(&mut self) {
        self.tiles_open =
            self.frames.iter().flat_map(|f| &f.tiles).filter(|t| !t.is_complete()).count();
    }

    /// Moves the job to `Done` when no tile needs more samples, or when the time limit has
    /// passed and nothing is in flight.
    pub fn finish_if_complete(&mut self, now: Moment) {
        if self.state.is_final() {
            return;
        }
        if self.tiles_open == 0 || (self.time_up && self.in_flight == 0) {
            self.set_final(JobState::Done, None, now);
        }
    }

    /// Ends the job at `now`.
    pub fn set_final(&mut self, state: JobState, error: Option<String>, now: Moment) {
        if let Some(t) = self.running_since.take() {
            self.elapsed_before += now.since(t).as_secs_f64();
        }
        self.state = state;
        self.error = error;
    }

    /// Notes that the job ended at `unix` (seconds since the Unix epoch) if it has ended and no
    /// end is noted yet; returns true when it noted one. Call it after anything that may end
    /// the job.
    pub fn note_end(&mut self, unix: f64) -> bool {
        let noted = self.state.is_final() && self.finished_unix.is_none();
        if noted {
            self.finished_unix = Some(unix);
        }
        noted
    }

    /// Checks the time limit at `now`; returns true when it has just passed.
    pub fn check_time_limit(&mut self, now: Moment) -> bool {
        match self.settings.time_limit_s {
            Some(limit)
                if !self.time_up && !self.state.is_final() && self.elapsed(now) >= limit =>
            {
                self.time_up = true;
                self.finish_if_complete(now);
                true
            }
            _ => false,
        }
    }

    /// Whether task `key` is leased now.
    pub fn is_leased(&self, key: TaskKey) -> bool {
        self.frames
            .get(key.frame as usize)
            .and_then(|f| f.tiles.get(key.tile as usize))
            .and_then(|t| t.tasks.get(key.k as usize))
            .is_some_and(|&s| s == TaskState::Leased)
    }

    /// Whether task `key` is merged.
    pub fn is_merged(&self, key: TaskKey) -> bool {
        self.frames
            .get(key.frame as usize)
            .and_then(|f| f.tiles.get(key.tile as usize))
            .and_then(|t| t.tasks.get(key.k as usize))
            .is_some_and(|&s| s == TaskState::Merged)
    }

    /// Drops the sums of a finished job from memory; its images are then read from the database.
    pub fn evict(&mut self) {
        debug_assert!(self.state.is_final());
        for f in 0..self.frames.len() {
            self.evict_frame(f);
        }
        self.evicted = true;
    }

    /// The image of frame index `f` (what its files show), built tile by tile.
    pub fn image(&self, f: usize) -> FrameImage {
        let mut image = FrameImage::new(self.settings.width, self.settings.height);
        let sums: Vec<&TileAccum> = self.frames[f].tiles.iter().map(|t| &t.sums).collect();
        for tile in frame_tiles(&sums, self.light_tile()) {
            image.put_tile(&tile);
        }
        if let Some(light) = self.light_tile().map(|i| sums[i]) {
            image.rejected += light.rejected;
        }
        image
    }

    /// The index of each frame's light tile (bidirectional path tracing), if it has one.
    pub fn light_tile(&self) -> Option<usize> {
        self.frames.first().and_then(|f| f.tiles.iter().position(|t| t.light))
    }

    /// The merged film of frame index `f`.
    /// (Tests compare whole statistics with it; files are written from `image`.)
    #[cfg(test)]
    pub fn film(&self, f: usize) -> common::film::Film {
        let mut film = common::film::Film::new(self.settings.width, self.settings.height);
        let sums: Vec<&TileAccum> = self.frames[f].tiles.iter().map(|t| &t.sums).collect();
        for tile in frame_tiles(&sums, self.light_tile()) {
            film.merge_tile(&tile);
        }
        film
    }
}

impl Frame {
    /// Recomputes tile `i`'s estimated error after its sums changed; in a bidirectional frame
    /// without a pilot image, with the light tile's share (every tile's after the light tile's
    /// sums changed). See `Tile::rel_mse`.
    fn update_rel_mse(&mut self, i: usize, width: u32, height: u32) {
        let light = self.tiles.iter().position(|t| t.light);
        let Some(light) = light.filter(|_| self.pilot.is_none()) else {
            let sums = &self.tiles[i].sums;
            self.tiles[i].rel_mse = match &self.pilot {
                Some(pilot) => {
                    ErrorEstimate::rel_mse_against(&sums.pixels, sums.rect, pilot, width)
                }
                None => ErrorEstimate::of_pixels(&sums.pixels).rel_mse,
            };
            return;
        };
        let camera: Vec<usize> = if i == light {
            (0..self.tiles.len()).filter(|&t| t != light).collect()
        } else {
            vec![i]
        };
        for t in camera {
            let (own, lit) = shares(&self.tiles[t].sums, &self.tiles[light].sums, width);
            // Nothing is known of a tile's error before its first task is in.
            let known = !self.tiles[t].sums.pixels.is_empty();
            self.tiles[t].rel_mse = if known { own } else { f64::INFINITY };
            self.tiles[t].light_share = lit;
        }
        let area = width as f64 * height as f64;
        let cameras = self.tiles.iter().filter(|t| !t.light);
        let lit: f64 = cameras.map(|t| t.light_share * t.sums.rect.area() as f64).sum();
        // Nothing is known of the light tile's error before its first task is in.
        let known = !self.tiles[light].sums.pixels.is_empty();
        self.tiles[light].rel_mse = if known { lit / area } else { f64::INFINITY };
    }

    /// Recomputes every tile's estimated error.
    fn update_all_rel_mse(&mut self, width: u32, height: u32) {
        match self.tiles.iter().position(|t| t.light).filter(|_| self.pilot.is_none()) {
            // The light tile's update is every camera tile's too.
            Some(light) => self.update_rel_mse(light, width, height),
            None => {
                for i in 0..self.tiles.len() {
                    self.update_rel_mse(i, width, height);
                }
            }
        }
    }
}

/// The shares of a bidirectional image's relative MSE over a camera tile's pixels (`sums`) that
/// its camera part and the light tile's part (`light`, the frame `width` wide) add, each's
/// variance over the image's current squared means there (each camera tile's plus the light
/// tile's); pixels not yet sampled by a part count zero for it.
fn shares(sums: &TileAccum, light: &TileAccum, width: u32) -> (f64, f64) {
    let r = sums.rect;
    let (mut own, mut lit) = (0.0, 0.0);
    for row in 0..r.height {
        for col in 0..r.width {
            let c = sums.pixels.get((row * r.width + col) as usize);
            let l = light.pixels.get(((r.y0 + row) * width + r.x0 + col) as usize);
            let (cm, lm) = (c.map(|p| p.mean()), l.map(|p| p.mean()));
            let (cm, lm) = (cm.unwrap_or_default(), lm.unwrap_or_default());
            let mean = [0, 1, 2].map(|k| cm[k] + lm[k]);
            if let Some(c) = c {
                ErrorEstimate::add_relative(&mut own, c.estimated_variance(), mean);
            }
            if let Some(l) = l {
                ErrorEstimate::add_relative(&mut lit, l.estimated_variance(), mean);
            }
        }
    }
    let n = (r.area() * 3).max(1) as f64;
    (own / n, lit / n)
}

/// A bidirectional frame's image means as its tiles' sums hold them: each camera tile's mean
/// plus the light tile's, row-major over the frame.
fn image_means(frame: &Frame, width: u32, height: u32) -> Vec<[f32; 3]> {
    let mut sum = vec![[0f64; 3]; width as usize * height as usize];
    for t in frame.tiles.iter().filter(|t| !t.light).chain(frame.tiles.iter().filter(|t| t.light)) {
        let r = t.sums.rect;
        for (i, p) in t.sums.pixels.iter().enumerate() {
            let (row, col) = (i as u32 / r.width, i as u32 % r.width);
            let px = &mut sum[((r.y0 + row) * width + r.x0 + col) as usize];
            let m = p.mean();
            for c in 0..3 {
                px[c] += m[c];
            }
        }
    }
    sum.into_iter().map(|p| p.map(|v| v as f32)).collect()
}

/// The tiles a frame's image is made of, from its merged sums (`sums`, by tile index; those
/// with no samples yet are left out): each tile's own, or with a light tile (`light`, its index)
/// each other tile plus the light tile's pixels (`TileAccum::plus_frame_wide`).
pub fn frame_tiles<'a>(
    sums: &'a [&'a TileAccum],
    light: Option<usize>,
) -> impl Iterator<Item = std::borrow::Cow<'a, TileAccum>> + 'a {
    let light_sums = light.map(|i| sums[i]).filter(|l| !l.pixels.is_empty());
    sums.iter().enumerate().filter_map(move |(i, t)| {
        if Some(i) == light {
            return None;
        }
        match light_sums {
            Some(l) => Some(std::borrow::Cow::Owned(t.plus_frame_wide(l))),
            None if t.pixels.is_empty() => None,
            None => Some(std::borrow::Cow::Borrowed(*t)),
        }
    })
}

#[cfg(test)]
mod tests;
