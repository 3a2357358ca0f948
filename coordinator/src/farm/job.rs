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
//! (a_t tile areas, A their sum; with a 10% margin). After that, a tile's task `k` is decided
//! from the fixed scale and that tile's tasks `0..k`, all merged. Every decision reads only
//! completed data, so the image is the same whatever the timing and the number of workers.

use std::collections::BTreeMap;

use common::{
    film::{ErrorEstimate, TileAccum},
    protocol::{SampleRange, TaskSpec},
    settings::RenderSettings,
};
use serde::Serialize;

use super::clock::Moment;
use crate::{output::FrameImage, split::tiles};

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
    /// Estimated relative MSE of the merged sums.
    pub rel_mse: f64,
}

impl Tile {
    fn first_open(&self) -> Option<u32> {
        self.tasks.iter().position(|&t| t == TaskState::Open).map(|k| k as u32)
    }

    fn is_complete(&self) -> bool {
        self.converged || self.prefix as usize == self.tasks.len()
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
    /// Pixel samples accepted for this frame.
    pub samples_done: u64,
    /// The frame is complete and its sums left memory (they are in the database).
    pub evicted: bool,
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
    tiles_open: usize,
    /// The time limit has passed: no more tasks are issued.
    pub time_up: bool,
    /// A finished job's sums were dropped from memory (they stay in the database).
    pub evicted: bool,
}

/// A job's public status.
#[derive(Clone, Debug, Serialize)]
pub struct JobStatus {
    /// The job id.
    pub id: String,
    /// The scene hash.
    pub scene: String,
    /// Scheduling priority.
    pub priority: i32,
    /// `queued`, `running`, `done`, `failed` or `cancelled`.
    pub state: JobState,
    /// Fraction of the planned samples merged (tiles stopped by adaptivity count as complete).
    pub progress: f64,
    /// Pixel samples merged.
    pub samples_done: u64,
    /// Pixel samples a uniform render would take.
    pub samples_planned: u64,
    /// Pixel samples adaptive sampling did not need to take (so far: tiles already stopped).
    pub samples_saved: u64,
    /// Estimated relative RMSE (sqrt of the estimated relative MSE) of the merged image.
    pub est_rel_error: Option<f64>,
    /// Seconds spent running.
    pub elapsed_s: f64,
    /// Estimated seconds left.
    pub eta_s: Option<f64>,
    /// Why it failed.
    pub error: Option<String>,
    /// The frame numbers.
    pub frames: Vec<i64>,
    /// Tasks leased now.
    pub tasks_in_flight: u32,
    /// Progress of each frame, in frame order.
    pub frame_progress: Vec<FrameProgress>,
    /// The render settings.
    pub settings: RenderSettings,
    /// Creation time, seconds since the Unix epoch.
    pub created_unix: f64,
}

/// One frame's progress in a job's status.
#[derive(Clone, Debug, Serialize)]
pub struct FrameProgress {
    /// The frame number.
    pub frame: i64,
    /// Pixel samples accepted.
    pub samples_done: u64,
    /// Every tile of the frame is complete.
    pub done: bool,
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
        let rects = tiles(settings.width, settings.height, settings.tile_size);
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
                    .map(|&rect| Tile {
                        // Pixels are allocated by the first result: a long animation holds
                        // only the frames in progress.
                        sums: TileAccum { rect, pixels: Vec::new(), rejected: 0 },
                        tasks: vec![TaskState::Open; tasks_per_tile as usize],
                        merged: 0,
                        prefix: 0,
                        pending: BTreeMap::new(),
                        converged: false,
                        rel_mse: f64::INFINITY,
                    })
                    .collect(),
                scale: None,
                samples_done: 0,
                evicted: false,
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
            tiles_open,
            time_up: false,
            evicted: false,
        })
    }

    /// The specification of task `key`.
    pub fn spec(&self, key: TaskKey) -> TaskSpec {
        let spt = self.settings.samples_per_task;
        let start = key.k * spt;
        TaskSpec {
            frame: self.frames[key.frame as usize].number,
            rect: self.frames[key.frame as usize].tiles[key.tile as usize].sums.rect,
            samples: SampleRange { start, end: (start + spt).min(self.settings.spp) },
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

    /// Accepts the sums of the leased task `key` (the caller has checked that they answer it):
    /// adds them to the tile in task order, or keeps them pending until their predecessors are in.
    pub fn merge(&mut self, key: TaskKey, tile: TileAccum, samples: u64, now: Moment) {
        let t = &mut self.frames[key.frame as usize].tiles[key.tile as usize];
        debug_assert_eq!(t.tasks[key.k as usize], TaskState::Leased);
        t.tasks[key.k as usize] = TaskState::Merged;
        t.merged += 1;
        t.pending.insert(key.k, tile);
        Self::drain_pending(t);
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

    /// Drops a complete frame's sums from memory (call once they are committed).
    pub fn evict_frame(&mut self, f: usize) {
        let frame = &mut self.frames[f];
        for tile in &mut frame.tiles {
            tile.sums.pixels = Vec::new();
            tile.pending.clear();
        }
        frame.evicted = true;
    }

    /// Adds the pending results that continue the tile's prefix, in task order.
    fn drain_pending(t: &mut Tile) {
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
        if advanced {
            t.rel_mse = ErrorEstimate::of_pixels(&t.sums.pixels).rel_mse;
        }
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
        let frame = &mut self.frames[f];
        if frame.scale.is_none() {
            let pilot_done =
                frame.tiles.iter().all(|t| t.prefix >= min_tasks.min(t.tasks.len() as u32));
            if !pilot_done {
                self.count_open_tiles();
                return;
            }
            let n = (min_tasks * spt).min(spp) as f64;
            let (mut area, mut weighted) = (0.0, 0.0);
            for t in &frame.tiles {
                let a = t.sums.rect.area() as f64;
                area += a;
                weighted += a * (t.rel_mse.max(0.0) * n).sqrt();
            }
            frame.scale = Some(if weighted > 0.0 { target * area / weighted } else { 1.0 });
        }
        let c = frame.scale.expect("set above");
        for t in &mut frame.tiles {
            let n = (t.prefix * spt).min(spp) as f64;
            if !t.converged
                && t.prefix >= min_tasks
                && (t.prefix as usize) < t.tasks.len()
                && t.rel_mse <= c * c * n
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

    /// Restores a tile from the database: tasks `0..prefix` summed in `sums`, and the pending
    /// results. Call [`Job::restore_adaptive`] once every tile is restored.
    pub fn restore_tile(
        &mut self,
        frame: u32,
        tile: u32,
        prefix: u32,
        sums: Option<TileAccum>,
        pending: Vec<(u32, TileAccum)>,
    ) -> Result<(), String> {
        let t = self
            .frames
            .get_mut(frame as usize)
            .and_then(|f| f.tiles.get_mut(tile as usize))
            .ok_or_else(|| format!("stored tile {frame}/{tile} is not in the job"))?;
        let count = |a: &TileAccum| a.pixels.iter().map(|p| p.n as u64).sum::<u64>();
        let sums = sums.unwrap_or(TileAccum { rect: t.sums.rect, pixels: Vec::new(), rejected: 0 });
        if prefix as usize > t.tasks.len() || sums.rect != t.sums.rect {
            return Err(format!("stored tile {frame}/{tile} does not fit the job"));
        }
        for k in 0..prefix {
            t.tasks[k as usize] = TaskState::Merged;
        }
        let mut restored = count(&sums);
        t.sums = sums;
        t.prefix = prefix;
        for (k, acc) in pending {
            if k < prefix || k as usize >= t.tasks.len() {
                continue; // already in the sums (a crash between the two writes cannot happen,
                          // they share a transaction, but an old row must never count twice)
            }
            t.tasks[k as usize] = TaskState::Merged;
            restored += count(&acc);
            t.pending.insert(k, acc);
        }
        t.merged = prefix + t.pending.len() as u32;
        t.rel_mse = ErrorEstimate::of_pixels(&t.sums.pixels).rel_mse;
        self.samples_done += restored;
        self.frames[frame as usize].samples_done += restored;
        Ok(())
    }

    /// Restores the frames' stopping scales (as stored: they were fixed from the pilot alone,
    /// which the merged sums no longer show) and the tiles they stop.
    pub fn restore_adaptive(&mut self, scales: &[Option<f64>]) {
        for (frame, &scale) in self.frames.iter_mut().zip(scales) {
            frame.scale = scale;
        }
        for f in 0..self.frames.len() {
            self.update_adaptive(f);
        }
    }

    /// The frames' stopping scales, for the database.
    pub fn scales(&self) -> Vec<Option<f64>> {
        self.frames.iter().map(|f| f.scale).collect()
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
        for tile in self.frames[f].tiles.iter().filter(|t| !t.sums.pixels.is_empty()) {
            image.put_tile(&tile.sums);
        }
        image
    }

    /// The merged film of frame index `f`.
    /// (Tests compare whole statistics with it; files are written from `image`.)
    #[cfg(test)]
    pub fn film(&self, f: usize) -> common::film::Film {
        let mut film = common::film::Film::new(self.settings.width, self.settings.height);
        for tile in self.frames[f].tiles.iter().filter(|t| !t.sums.pixels.is_empty()) {
            film.merge_tile(&tile.sums);
        }
        film
    }

    /// The job's status at `now`.
    pub fn status(&self, now: Moment) -> JobStatus {
        let pixels = self.settings.width as u64 * self.settings.height as u64;
        let planned = pixels * self.settings.spp as u64 * self.frames.len() as u64;
        let mut saved = 0u64;
        let mut rel_sum = 0.0;
        let mut rel_known = true;
        for frame in &self.frames {
            for tile in &frame.tiles {
                let area = tile.sums.rect.area() as u64;
                if tile.converged {
                    let taken: u64 = (tile.prefix * self.settings.samples_per_task)
                        .min(self.settings.spp) as u64;
                    saved += area * (self.settings.spp as u64 - taken);
                }
                rel_known &= tile.rel_mse.is_finite();
                rel_sum += tile.rel_mse * area as f64;
            }
        }
        let effective = planned - saved;
        let progress =
            if effective == 0 { 1.0 } else { self.samples_done as f64 / effective as f64 };
        let elapsed = self.elapsed(now);
        let eta = match self.state {
            JobState::Running if self.samples_done > 0 => Some(
                elapsed * (effective - self.samples_done.min(effective)) as f64
                    / self.samples_done as f64,
            ),
            s if s.is_final() => Some(0.0),
            _ => None,
        };
        let total_pixels = (pixels * self.frames.len() as u64).max(1) as f64;
        JobStatus {
            id: self.id.clone(),
            scene: self.scene.clone(),
            priority: self.priority,
            state: self.state,
            progress: progress.clamp(0.0, 1.0),
            samples_done: self.samples_done,
            samples_planned: planned,
            samples_saved: saved,
            est_rel_error: rel_known.then(|| (rel_sum / total_pixels).sqrt()),
            elapsed_s: elapsed,
            eta_s: eta,
            error: self.error.clone(),
            frames: self.frames.iter().map(|f| f.number).collect(),
            tasks_in_flight: self.in_flight,
            frame_progress: self
                .frames
                .iter()
                .map(|f| FrameProgress {
                    frame: f.number,
                    samples_done: f.samples_done,
                    done: f.tiles.iter().all(Tile::is_complete),
                })
                .collect(),
            settings: self.settings.clone(),
            created_unix: self.created_unix,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every test runs at one moment except where time matters.
    const NOW: Moment = Moment::ZERO;

    fn job(spp: u32, spt: u32, target: Option<f64>) -> Job {
        let settings = RenderSettings {
            width: 64,
            height: 32,
            tile_size: 32,
            spp,
            samples_per_task: spt,
            target_rel_error: target,
            ..Default::default()
        };
        Job::new("j".into(), 0, "s".into(), settings, 0, 0.0).unwrap()
    }

    fn fake_result(job: &Job, key: TaskKey, value: f32) -> TileAccum {
        let spec = job.spec(key);
        let mut acc = TileAccum::new(spec.rect);
        for y in 0..spec.rect.height {
            for x in 0..spec.rect.width {
                for s in spec.samples.start..spec.samples.end {
                    acc.add_sample(x, y, s, [value; 3]);
                }
            }
        }
        acc
    }

    #[test]
    fn tasks_are_issued_progressively_and_complete_the_job() {
        let mut j = job(100, 32, None);
        let mut order = Vec::new();
        while let Some(key) = j.next_task() {
            j.lease(key, NOW);
            order.push(key);
        }
        assert_eq!(order.len(), 2 * 4);
        assert!(order.windows(2).all(|w| w[0].k <= w[1].k), "progressive order: {order:?}");
        for key in order {
            let r = fake_result(&j, key, 0.5);
            let n = r.pixels.iter().map(|p| p.n as u64).sum();
            j.merge(key, r, n, NOW);
        }
        assert_eq!(j.state, JobState::Done);
        assert_eq!(j.samples_done, 64 * 32 * 100);
        assert!(j.film(0).pixels.iter().all(|p| p.n == 100));
    }

    #[test]
    fn released_tasks_are_leased_again() {
        let mut j = job(64, 32, None);
        let a = j.next_task().unwrap();
        j.lease(a, NOW);
        j.give_back(a, NOW);
        assert_eq!(j.next_task(), Some(a));
        assert_eq!(j.in_flight, 0);
    }

    #[test]
    fn adaptive_stops_converged_tiles_from_merged_data_only() {
        // A constant image has zero estimated error: every tile stops at the minimum.
        let mut j = job(256, 8, Some(0.01));
        let mut leased = Vec::new();
        while let Some(key) = j.next_task() {
            j.lease(key, NOW);
            leased.push(key);
        }
        // Without merged data only the first MIN_ADAPTIVE_SAMPLES are issued.
        assert_eq!(leased.len(), 2 * 2);
        for key in leased {
            let r = fake_result(&j, key, 0.25);
            let n = r.pixels.iter().map(|p| p.n as u64).sum();
            j.merge(key, r, n, NOW);
        }
        assert_eq!(j.state, JobState::Done);
        let status = j.status(NOW);
        assert_eq!(status.samples_saved, 64 * 32 * (256 - 16));
        assert_eq!(status.progress, 1.0);
    }

    #[test]
    fn results_in_any_order_give_the_same_bits() {
        let run = |order: &[usize]| {
            let mut j = job(96, 32, None);
            let mut keys = Vec::new();
            while let Some(key) = j.next_task() {
                j.lease(key, NOW);
                keys.push(key);
            }
            for &i in order {
                let key = keys[i];
                // Values that differ per task so that the order of addition shows in the bits.
                let r = fake_result(&j, key, 0.1 + 0.37 * key.k as f32 + 0.011 * key.tile as f32);
                let n = r.pixels.iter().map(|p| p.n as u64).sum();
                j.merge(key, r, n, NOW);
            }
            assert_eq!(j.state, JobState::Done);
            assert!(j.frames[0].tiles.iter().all(|t| t.pending.is_empty()));
            j.film(0)
        };
        let forward = run(&[0, 1, 2, 3, 4, 5]);
        assert_eq!(forward, run(&[5, 4, 3, 2, 1, 0]));
        assert_eq!(forward, run(&[3, 0, 5, 1, 4, 2]));
    }

    #[test]
    fn past_the_time_limit_the_last_lease_to_lapse_ends_the_job() {
        let mut j = job(64, 32, None);
        j.settings.time_limit_s = Some(1e-9);
        let key = j.next_task().unwrap();
        j.lease(key, NOW);
        assert!(j.check_time_limit(NOW + std::time::Duration::from_micros(1)));
        assert_eq!(j.state, JobState::Running, "a lease is still out");
        assert_eq!(j.next_task(), None, "nothing more is issued");
        j.give_back(key, NOW);
        assert_eq!(j.state, JobState::Done, "the job must not wait for a lease that lapsed");
    }
}
