//! The farm's user side: scenes in, jobs created, listed (a page at a time), cancelled and
//! removed, and their images out. The worker side (leases and results) is in `mod.rs`.

use std::{collections::BTreeMap, path::PathBuf};

use serde::Serialize;

use common::{
    film::{Rect, TileAccum},
    settings::{Integrator, RenderSettings},
};

use super::store::TileReader;
use super::{
    error::{FarmError, FarmResult},
    job::{Job, JobState, JobStatus, JobSummary},
    lease::Event,
    random_id,
    validate::{check_settings, is_hash, SceneInfo},
    Farm,
};
use crate::output::{FrameImage, FrameInfo};

/// The longest job name, in characters.
pub const MAX_JOB_NAME_CHARS: usize = 200;

/// A job's name: text of 1 to [`MAX_JOB_NAME_CHARS`] characters, not all white space, without
/// control characters, line or paragraph separators, or bidirectional overrides (a name is
/// shown on one line, in tables and logs, and must not pass itself off as another).
pub fn validate_job_name(name: &str) -> FarmResult<()> {
    let chars = name.chars().count();
    if name.trim().is_empty() {
        return Err(FarmError::invalid("name: must not be empty or all white space"));
    }
    if chars > MAX_JOB_NAME_CHARS {
        return Err(FarmError::invalid(format!(
            "name: {chars} characters, over the limit of {MAX_JOB_NAME_CHARS}"
        )));
    }
    let breaks_the_line = |c: &char| {
        c.is_control()
            || matches!(c, '\u{2028}' | '\u{2029}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}')
    };
    if let Some(c) = name.chars().find(breaks_the_line) {
        return Err(FarmError::invalid(format!(
            "name: holds the control character U+{:04X} (a control, a line or paragraph \
             separator, or a bidirectional override); a name is one line of text",
            c as u32
        )));
    }
    Ok(())
}

impl Farm {
    /// Checks and stores an upload (call [`super::validate_upload`] first, outside any lock).
    pub fn put_scene(&mut self, bytes: &[u8], info: &mut SceneInfo) -> FarmResult<()> {
        info.created = self.store.scene_format(&info.scene)?.is_none();
        self.store.put_scene(&info.scene, &info.format, bytes)?;
        Ok(())
    }

    /// Where a stored scene's bytes are (read them outside the farm lock: the file never
    /// changes, it is named by its content).
    pub fn scene_file(&self, hash: &str) -> FarmResult<PathBuf> {
        if !is_hash(hash) || self.store.scene_format(hash)?.is_none() {
            return Err(FarmError::not_found(format!("no scene {hash}")));
        }
        Ok(self.store.scene_path(hash))
    }

    /// Checks settings against the farm's limits (the scene-dependent checks are
    /// [`super::validate_job_scene`]).
    pub fn check_settings(&self, settings: &RenderSettings) -> FarmResult<()> {
        check_settings(settings, self.config.max_spp, self.config.max_pixels)
    }

    /// Creates a job on a stored scene.
    pub fn create_job(
        &mut self,
        scene: &str,
        settings: RenderSettings,
        priority: i32,
    ) -> FarmResult<JobStatus> {
        self.create_named_job(scene, settings, priority, None)
    }

    /// [`Farm::create_job`] with a name for people to know it by (`validate_job_name`).
    pub fn create_named_job(
        &mut self,
        scene: &str,
        settings: RenderSettings,
        priority: i32,
        name: Option<String>,
    ) -> FarmResult<JobStatus> {
        if let Some(name) = &name {
            validate_job_name(name)?;
        }
        self.check_settings(&settings)?;
        if !is_hash(scene) || self.store.scene_format(scene)?.is_none() {
            return Err(FarmError::not_found(format!(
                "no scene {scene}: upload it to /api/v1/scenes first"
            )));
        }
        let id = random_id();
        let now = self.clock.now();
        let created = self.clock.unix();
        let mut job =
            Job::new(id.clone(), self.next_seq, scene.to_string(), settings, priority, created)
                .map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
        job.name = name;
        self.store.insert_job(&job, now)?;
        self.next_seq += 1;
        let status = job.status(now);
        tracing::info!(job = %id, name = job.name.as_deref().unwrap_or(""), scene, priority, "job created");
        self.jobs.insert(id, job);
        Ok(status)
    }

    fn job(&self, id: &str) -> FarmResult<&Job> {
        self.jobs.get(id).ok_or_else(|| FarmError::not_found(format!("no job {id}")))
    }

    /// Whether job `id` has ended (done, failed or cancelled) or is unknown.
    pub fn job_ended(&self, id: &str) -> bool {
        self.jobs.get(id).is_none_or(|j| j.state.is_final())
    }

    /// A job's status.
    pub fn status(&self, id: &str) -> FarmResult<JobStatus> {
        Ok(self.job(id)?.status(self.clock.now()))
    }

    /// One page of the jobs `query` selects, in its order, as summaries.
    pub fn list(&self, query: &JobQuery) -> JobPage {
        let now = self.clock.now();
        let newest_first = query.order == ListOrder::Newest;
        let mut jobs: Vec<&Job> = self
            .jobs
            .values()
            .filter(|j| query.states.as_ref().is_none_or(|s| s.contains(&j.state)))
            .filter(|j| match query.after {
                None => true,
                Some(after) if newest_first => j.seq < after,
                Some(after) => j.seq > after,
            })
            .collect();
        if newest_first {
            jobs.sort_by_key(|j| std::cmp::Reverse(j.seq));
        } else {
            jobs.sort_by_key(|j| j.seq);
        }
        let more = jobs.len() > query.limit;
        jobs.truncate(query.limit);
        let next = if more { jobs.last().map(|j| j.seq) } else { None };
        JobPage { jobs: jobs.into_iter().map(|j| j.summary(now)).collect(), next }
    }

    /// Counts of jobs by state.
    pub fn job_counts(&self) -> BTreeMap<&'static str, u64> {
        let mut out = BTreeMap::new();
        for s in ["queued", "running", "done", "failed", "cancelled"] {
            out.insert(s, 0);
        }
        for j in self.jobs.values() {
            *out.entry(j.state.name()).or_default() += 1;
        }
        out
    }

    /// Cancels a job: its leases are dropped and results for them refused.
    pub fn cancel(&mut self, id: &str) -> FarmResult<JobStatus> {
        let now = self.clock.now();
        let job =
            self.jobs.get_mut(id).ok_or_else(|| FarmError::not_found(format!("no job {id}")))?;
        if job.state.is_final() {
            return Err(FarmError::conflict(format!("job {id} is already {}", job.state.name())));
        }
        job.set_final(JobState::Cancelled, None, now);
        job.note_end(self.clock.unix());
        job.in_flight = 0;
        self.store.update_job(job, now)?;
        let status = job.status(now);
        self.leases.step(Event::Cancel { job: id }, now)?;
        self.evict_if_final(id);
        tracing::info!(job = %id, "job cancelled");
        Ok(status)
    }

    /// Removes job `id` entirely: a job still running is cancelled first (its leases end and
    /// results for them are refused), then its rows (job, tiles, pending results) leave the
    /// database and the job leaves memory. Its scene stays: other jobs may use it.
    pub fn remove_job(&mut self, id: &str) -> FarmResult<()> {
        let now = self.clock.now();
        let state = self.job(id)?.state;
        // The database first: if it fails, nothing has changed.
        self.store.delete_job(id)?;
        if !state.is_final() {
            self.leases.step(Event::Cancel { job: id }, now)?;
        }
        self.jobs.remove(id);
        self.counters.jobs_removed += 1;
        tracing::info!(job = %id, was = state.name(), "job removed");
        Ok(())
    }

    /// The merged film of frame `number` of job `id` (also while it runs), with its job's
    /// settings and scene hash.
    /// (Tests compare whole statistics with it; files are written from `image`.)
    #[cfg(test)]
    pub fn film(&self, id: &str, number: i64) -> FarmResult<(common::film::Film, JobStatus)> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        let status = job.status(self.clock.now());
        if !job.frames[f].evicted {
            return Ok((job.film(f), status));
        }
        let mut film = common::film::Film::new(job.settings.width, job.settings.height);
        let stored = self.stored_tiles(job, f)?;
        let sums: Vec<&TileAccum> = stored.iter().collect();
        for tile in super::job::frame_tiles(&sums, job.light_tile()) {
            film.merge_tile(&tile);
        }
        Ok((film, status))
    }

    /// The image of frame `number` of job `id` (also while it runs), with the job's status.
    pub fn image(&self, id: &str, number: i64) -> FarmResult<(FrameImage, JobStatus)> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        let status = job.status(self.clock.now());
        if !job.frames[f].evicted {
            return Ok((job.image(f), status));
        }
        let mut image = FrameImage::new(job.settings.width, job.settings.height);
        let stored = self.stored_tiles(job, f)?;
        let sums: Vec<&TileAccum> = stored.iter().collect();
        for tile in super::job::frame_tiles(&sums, job.light_tile()) {
            image.put_tile(&tile);
        }
        if let Some(light) = job.light_tile().map(|i| sums[i]) {
            image.rejected += light.rejected;
        }
        Ok((image, status))
    }

    /// What serving frame `number` of job `id` a tile at a time needs: its size, its tiles,
    /// where their sums are, and what its EXR header says of the job.
    pub fn frame_layout(&self, id: &str, number: i64) -> FarmResult<FrameLayout> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        let s = &job.settings;
        Ok(FrameLayout {
            job: job.id.clone(),
            f,
            size: (s.width, s.height),
            tiles: job.frames[f].tiles.iter().filter(|t| !t.light).map(|t| t.sums.rect).collect(),
            light_tile: job.light_tile(),
            // Photon mapping's one tile is the whole frame.
            tile_rows: if s.integrator == Integrator::Sppm { s.height } else { s.tile_size },
            stored: job.frames[f].evicted,
            info: FrameInfo {
                settings_json: serde_json::to_string(s).unwrap_or_default(),
                scene_hash: job.scene.clone(),
                render_seconds: job.elapsed(self.clock.now()),
                frame: number,
                kernels: job.frames[f].kernels.iter().cloned().collect(),
            },
        })
    }

    /// The tiles of frame `number` of job `id`: their progress and estimated error.
    pub fn tile_map(&self, id: &str, number: i64) -> FarmResult<TileMap> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        let s = &job.settings;
        let tiles = job.frames[f]
            .tiles
            .iter()
            .filter(|t| !t.light)
            .map(|t| {
                let r = t.sums.rect;
                TileProgress {
                    x: r.x0,
                    y: r.y0,
                    width: r.width,
                    height: r.height,
                    tasks_done: t.prefix,
                    tasks: t.task_count(),
                    samples: job.samples_summed(t),
                    est_rel_error: t.rel_mse.is_finite().then(|| t.rel_mse.max(0.0).sqrt()),
                    converged: t.converged,
                    complete: t.is_complete(),
                }
            })
            .collect();
        Ok(TileMap { frame: number, width: s.width, height: s.height, tiles })
    }

    /// A copy of the merged sums of tile `t` of frame index `f` of job `id`.
    pub fn tile_copy(&self, id: &str, f: usize, t: usize) -> FarmResult<TileCopy> {
        let frame = &self.job(id)?.frames[f];
        if frame.evicted {
            return Ok(TileCopy::Stored);
        }
        let tile = &frame.tiles[t].sums;
        Ok(if tile.pixels.is_empty() { TileCopy::Empty } else { TileCopy::Sums(tile.clone()) })
    }

    /// A reader of stored tiles that needs no lock on the farm (see [`TileReader`]).
    pub fn tile_reader(&self) -> FarmResult<TileReader> {
        Ok(self.store.tile_reader()?)
    }

    /// The summed tiles of frame index `f` of an evicted job, from the database, by tile index
    /// (a tile never stored has no sums).
    fn stored_tiles(&self, job: &Job, f: usize) -> FarmResult<Vec<TileAccum>> {
        let mut tiles: Vec<TileAccum> = job.frames[f]
            .tiles
            .iter()
            .map(|t| TileAccum { rect: t.sums.rect, pixels: Vec::new(), rejected: 0 })
            .collect();
        for (i, sums) in self.store.frame_sums(&job.id, f as u32)? {
            if let Some(slot) = tiles.get_mut(i as usize) {
                *slot = sums;
            }
        }
        Ok(tiles)
    }

    fn frame_index(job: &Job, number: i64) -> FarmResult<usize> {
        job.frames.iter().position(|f| f.number == number).ok_or_else(|| {
            FarmError::not_found(format!(
                "job {} has frames {}..={}, not {number}",
                job.id, job.settings.frames.start, job.settings.frames.end
            ))
        })
    }
}

/// A frame's tiles as the dashboard's heat map shows them ([`Farm::tile_map`]).
#[derive(Clone, Debug, Serialize)]
pub struct TileMap {
    /// The frame number.
    pub frame: i64,
    /// The frame's width and height.
    pub width: u32,
    pub height: u32,
    /// Its image tiles, row-major (bidirectional path tracing's frame-wide light tile left out).
    pub tiles: Vec<TileProgress>,
}

/// One tile's progress and estimated error.
#[derive(Clone, Debug, Serialize)]
pub struct TileProgress {
    /// Its rectangle in pixels.
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
    /// Its tasks merged in order, of `tasks` planned.
    pub tasks_done: u32,
    pub tasks: u32,
    /// Samples per pixel merged in order.
    pub samples: u32,
    /// The estimated relative error of its pixels (the root of its relative MSE; under
    /// bidirectional path tracing the camera part of its share of the image's, without the
    /// light tracing's); `None` until it can be estimated.
    pub est_rel_error: Option<f64>,
    /// Adaptive sampling stopped it.
    pub converged: bool,
    /// No more of its tasks are needed.
    pub complete: bool,
}

/// Where a frame's tiles are and what its files say of it ([`Farm::frame_layout`]).
#[derive(Clone, Debug)]
pub struct FrameLayout {
    /// The job's id.
    pub job: String,
    /// The frame's index in the job.
    pub f: usize,
    /// Width and height.
    pub size: (u32, u32),
    /// Its tiles, row-major: a tile row is `tile_rows` high.
    pub tiles: Vec<Rect>,
    /// The height of a row of tiles (the last may be lower).
    pub tile_rows: u32,
    /// The sums left memory for the database (read them with [`Farm::tile_reader`]).
    pub stored: bool,
    /// What the frame's EXR header says.
    pub info: FrameInfo,
    /// The index of bidirectional path tracing's light tile, the whole frame, whose pixels add
    /// to every tile's (it is not in `tiles`, which it follows).
    pub light_tile: Option<usize>,
}

/// A tile's sums as [`Farm::tile_copy`] found them.
pub enum TileCopy {
    /// Its merged sums.
    Sums(TileAccum),
    /// No task of it is merged yet.
    Empty,
    /// The frame's sums left memory: they are in the database.
    Stored,
}

/// The order of a job list.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ListOrder {
    /// Oldest first (creation order).
    #[default]
    Oldest,
    /// Newest first.
    Newest,
}

/// Which jobs a list shows, and how many.
#[derive(Clone, Debug, PartialEq)]
pub struct JobQuery {
    /// Only jobs in these states (`None`: every state).
    pub states: Option<Vec<JobState>>,
    /// The order.
    pub order: ListOrder,
    /// Only jobs after this one in that order (a [`JobPage::next`] cursor: a creation number).
    pub after: Option<u64>,
    /// At most this many.
    pub limit: usize,
}

impl Default for JobQuery {
    fn default() -> Self {
        JobQuery { states: None, order: ListOrder::Oldest, after: None, limit: DEFAULT_LIST_LIMIT }
    }
}

/// Jobs a list shows when it does not say how many.
pub const DEFAULT_LIST_LIMIT: usize = 100;

/// The most jobs one list may show.
pub const MAX_LIST_LIMIT: usize = 1000;

/// One page of a job list.
#[derive(Clone, Debug)]
pub struct JobPage {
    /// The jobs, in the query's order.
    pub jobs: Vec<JobSummary>,
    /// The cursor of the next page (pass it as `after`); `None` on the last page.
    pub next: Option<u64>,
}
