//! What the API shows of a job: progress, samples saved by adaptive sampling, estimated error,
//! running time and time left, per frame ([`JobStatus`]), or the same without the per-frame
//! lists and the settings for a job in a list ([`JobSummary`]).

use common::settings::RenderSettings;
use serde::Serialize;

use super::{Job, JobState, Tile};
use crate::farm::clock::Moment;

/// The running seconds between the first points of a job's error history.
pub const HISTORY_STEP_S: f64 = 1.0;
/// The most points a job's error history keeps: once full, every other point goes and the
/// step doubles, so that it spans the whole run at an even spacing.
pub const HISTORY_POINTS: usize = 256;

/// A point of a job's estimated error against time (`JobStatus::history`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ErrorPoint {
    /// Running seconds.
    pub elapsed_s: f64,
    /// Pixel samples merged by then.
    pub samples_done: u64,
    /// The estimated relative error then (`None` while some tile has too few samples to say).
    pub est_rel_error: Option<f64>,
}

/// A job's public status.
#[derive(Clone, Debug, Serialize)]
pub struct JobStatus {
    /// The job id.
    pub id: String,
    /// Its name, where the submitter gave one.
    pub name: Option<String>,
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
    /// When it ended (done, failed or cancelled), seconds since the Unix epoch.
    pub finished_unix: Option<f64>,
    /// Its estimated error against its running time, oldest first: a point at its first merge,
    /// then one per [`HISTORY_STEP_S`] running seconds or more, and one at its end (the merge
    /// that finishes it, or its cancelling, failure or time limit); at most
    /// [`HISTORY_POINTS`], evenly thinned. Kept in memory: a restarted coordinator starts it
    /// anew.
    pub history: Vec<ErrorPoint>,
}

/// A job in a list: [`JobStatus`] without what grows with the frames (their numbers and
/// progress) and without the settings, so that a list of many long animations stays small.
#[derive(Clone, Debug, Serialize)]
pub struct JobSummary {
    /// The job id.
    pub id: String,
    /// Its name, where the submitter gave one.
    pub name: Option<String>,
    /// The scene hash.
    pub scene: String,
    /// Scheduling priority.
    pub priority: i32,
    /// `queued`, `running`, `done`, `failed` or `cancelled`.
    pub state: JobState,
    /// Fraction of the planned samples merged.
    pub progress: f64,
    /// Pixel samples merged.
    pub samples_done: u64,
    /// Pixel samples a uniform render would take.
    pub samples_planned: u64,
    /// Estimated relative RMSE of the merged image.
    pub est_rel_error: Option<f64>,
    /// Seconds spent running.
    pub elapsed_s: f64,
    /// Estimated seconds left.
    pub eta_s: Option<f64>,
    /// Why it failed.
    pub error: Option<String>,
    /// How many frames it has.
    pub frame_count: u64,
    /// The number of its first frame (the one a preview shows).
    pub first_frame: i64,
    /// Tasks leased now.
    pub tasks_in_flight: u32,
    /// Creation time, seconds since the Unix epoch.
    pub created_unix: f64,
    /// When it ended, seconds since the Unix epoch.
    pub finished_unix: Option<f64>,
}

/// What both views compute from every tile.
struct Totals {
    planned: u64,
    saved: u64,
    progress: f64,
    est_rel_error: Option<f64>,
    elapsed: f64,
    eta: Option<f64>,
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
    /// The kernels that rendered its tasks so far (`"path, AVX-512 x16"`, `"path, scalar"`...).
    pub kernels: Vec<String>,
}

impl Job {
    fn totals(&self, now: Moment) -> Totals {
        let pixels = self.settings.width as u64 * self.settings.height as u64;
        let planned = pixels * self.settings.spp as u64 * self.frames.len() as u64;
        let mut saved = 0u64;
        let mut light_saved = 0u64;
        let mut rel_sum = 0.0;
        let mut rel_known = true;
        for frame in &self.frames {
            for tile in &frame.tiles {
                let area = tile.sums.rect.area() as u64;
                if tile.converged {
                    let taken = self.samples_summed(tile) as u64;
                    // A light tile's samples are light samples, not the pixel samples planned.
                    let left = area * (self.settings.spp as u64 - taken);
                    if tile.light {
                        light_saved += left;
                    } else {
                        saved += left;
                    }
                }
                rel_known &= tile.rel_mse.is_finite();
                rel_sum += tile.rel_mse * area as f64;
            }
        }
        // The work: the pixel samples and a light tile's light samples (bidirectional path
        // tracing; `bdpt.light_paths` per pixel sample), one unit each.
        let light_planned = if self.light_tile().is_some() {
            (planned - light_saved) * self.settings.light_paths() as u64
        } else {
            0
        };
        let effective = planned - saved + light_planned;
        let done = self.samples_done + self.light_samples_done;
        let progress = if effective == 0 { 1.0 } else { done as f64 / effective as f64 };
        let elapsed = self.elapsed(now);
        let eta = match self.state {
            JobState::Running if done > 0 => {
                Some(elapsed * (effective - done.min(effective)) as f64 / done as f64)
            }
            s if s.is_final() => Some(0.0),
            _ => None,
        };
        let total_pixels = (pixels * self.frames.len() as u64).max(1) as f64;
        Totals {
            planned,
            saved,
            progress: progress.clamp(0.0, 1.0),
            est_rel_error: rel_known.then(|| (rel_sum / total_pixels).sqrt()),
            elapsed,
            eta,
        }
    }

    /// The job's status at `now`.
    pub fn status(&self, now: Moment) -> JobStatus {
        let t = self.totals(now);
        JobStatus {
            id: self.id.clone(),
            name: self.name.clone(),
            scene: self.scene.clone(),
            priority: self.priority,
            state: self.state,
            progress: t.progress,
            samples_done: self.samples_done,
            samples_planned: t.planned,
            samples_saved: t.saved,
            est_rel_error: t.est_rel_error,
            elapsed_s: t.elapsed,
            eta_s: t.eta,
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
                    kernels: f.kernels.iter().cloned().collect(),
                })
                .collect(),
            settings: self.settings.clone(),
            created_unix: self.created_unix,
            finished_unix: self.finished_unix,
            history: self.history_to(&t),
        }
    }

    /// The error history, with a point at the job's end where it ended after its last point
    /// (cancelled, failed, stopped by its time limit: no merge noted it).
    fn history_to(&self, t: &Totals) -> Vec<ErrorPoint> {
        let mut history = self.history.clone();
        let ended_later = history.last().is_some_and(|p| p.elapsed_s < t.elapsed);
        if self.state.is_final() && ended_later {
            history.push(ErrorPoint {
                elapsed_s: t.elapsed,
                samples_done: self.samples_done,
                est_rel_error: t.est_rel_error,
            });
        }
        history
    }

    /// The samples per pixel of `tile`'s tasks summed in order.
    pub fn samples_summed(&self, tile: &Tile) -> u32 {
        tile.prefix.saturating_mul(self.settings.samples_per_task).min(self.settings.spp)
    }

    /// Adds a point to the error history where one is due: at the first merge, once
    /// `history_step` running seconds passed since the last point, and at the merge that
    /// finishes the job (call it after each merge).
    pub fn note_progress(&mut self, now: Moment) {
        let elapsed = self.elapsed(now);
        let due = match self.history.last() {
            None => true,
            Some(last) => self.state.is_final() || elapsed - last.elapsed_s >= self.history_step,
        };
        if !due {
            return;
        }
        let point = ErrorPoint {
            elapsed_s: elapsed,
            samples_done: self.samples_done,
            est_rel_error: self.totals(now).est_rel_error,
        };
        self.history.push(point);
        if self.history.len() >= HISTORY_POINTS {
            // Every other point, the first and the newest kept.
            let newest = self.history.pop();
            let mut i = 0;
            self.history.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.history.extend(newest);
            self.history_step *= 2.0;
        }
    }

    /// The job as a list shows it at `now`.
    pub fn summary(&self, now: Moment) -> JobSummary {
        let t = self.totals(now);
        JobSummary {
            id: self.id.clone(),
            name: self.name.clone(),
            scene: self.scene.clone(),
            priority: self.priority,
            state: self.state,
            progress: t.progress,
            samples_done: self.samples_done,
            samples_planned: t.planned,
            est_rel_error: t.est_rel_error,
            elapsed_s: t.elapsed,
            eta_s: t.eta,
            error: self.error.clone(),
            frame_count: self.frames.len() as u64,
            first_frame: self.settings.frames.start,
            tasks_in_flight: self.in_flight,
            created_unix: self.created_unix,
            finished_unix: self.finished_unix,
        }
    }
}
