//! The farm's state machine: scenes, jobs, leases and workers, kept in memory and persisted in
//! the [`store`]. Synchronous and free of HTTP: the service wraps it in a mutex. Time comes from
//! the [`clock`] the farm was opened with, read once per request and passed on.
//!
//! Exactly-once merging: a task has at most one live lease; a result is merged only for a live
//! lease held by the worker that sends it, and the merge turns the task merged and drops the
//! lease, so a duplicate, a result for an expired or reassigned lease, or one for a cancelled
//! job is refused (a conflict) without touching the sums.

pub mod clock;
pub mod error;
pub mod job;
pub mod store;
pub mod validate;

pub use error::{ErrorKind, FarmError, FarmResult};
pub use validate::{hex, is_hash, validate_job_scene, validate_upload, SceneInfo};

use std::{
    collections::{BTreeMap, HashMap},
    path::PathBuf,
    sync::Arc,
    time::Duration,
};

use anyhow::Result;
use common::{
    protocol::{JoinRequest, JoinResponse, LeaseGrant, TaskResult},
    settings::RenderSettings,
};
use serde::Serialize;

use clock::{Clock, Moment, SystemClock};
use job::{Job, JobState, JobStatus, TaskKey};
use store::Store;
use validate::check_settings;

fn random_id() -> String {
    format!("{:016x}", rand::random::<u64>())
}

/// Tunables of the farm.
#[derive(Clone, Debug)]
pub struct FarmConfig {
    /// Where the database and scenes live.
    pub data_dir: PathBuf,
    /// A lease not renewed for this long is given to another worker.
    pub lease_timeout: Duration,
    /// No lease lives longer than this, heartbeats or not.
    pub max_lease_lifetime: Duration,
    /// A task whose worker reports failure this many times fails its job.
    pub max_task_failures: u32,
    /// A task whose lease expires this many times fails its job.
    pub max_task_expiries: u32,
    /// Largest accepted `spp`.
    pub max_spp: u32,
    /// Largest accepted width x height.
    pub max_pixels: u64,
    /// Whether committed results must survive a crash (write-ahead log, synced). Only the
    /// one-shot local render, whose data folder is temporary, turns this off.
    pub durable: bool,
}

impl FarmConfig {
    /// Defaults for a data folder.
    pub fn new(data_dir: PathBuf) -> Self {
        FarmConfig {
            data_dir,
            lease_timeout: Duration::from_secs(30),
            max_lease_lifetime: Duration::from_secs(6 * 3600),
            max_task_failures: 3,
            max_task_expiries: 5,
            max_spp: 65536,
            max_pixels: 16384 * 16384,
            durable: true,
        }
    }
}

struct Lease {
    job: String,
    key: TaskKey,
    worker: String,
    deadline: Moment,
    /// Heartbeats do not renew a lease past this (a worker whose render hangs keeps
    /// heartbeating; the task must go to someone else eventually).
    last_renewal: Moment,
}

/// A worker as the coordinator sees it.
#[derive(Clone, Debug, Serialize)]
pub struct WorkerInfo {
    /// Its id.
    pub id: String,
    /// Its name.
    pub name: String,
    /// Render threads.
    pub threads: u32,
    /// Its version.
    pub version: String,
    /// Seconds since it joined.
    pub joined_s_ago: f64,
    /// Seconds since it was last heard from.
    pub last_seen_s_ago: f64,
    /// Tasks it has had merged.
    pub tasks_done: u64,
    /// Pixel samples it has had merged.
    pub samples_done: u64,
    /// Leases it holds now.
    pub leases: u32,
    #[serde(skip)]
    joined: Option<Moment>,
    #[serde(skip)]
    last_seen: Option<Moment>,
}

/// Counters for `/metrics`.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Counters {
    /// Tasks leased.
    pub tasks_leased: u64,
    /// Results merged.
    pub tasks_merged: u64,
    /// Leases that expired.
    pub tasks_expired: u64,
    /// Results refused.
    pub results_refused: u64,
    /// Failures reported by workers.
    pub tasks_failed: u64,
    /// Pixel samples merged.
    pub samples_merged: u64,
    /// Bytes of results merged.
    pub bytes_merged: u64,
    /// Seconds spent merging and committing results.
    pub merge_seconds: f64,
    /// Rays traced by merged tasks.
    pub rays: u64,
}

/// The whole state.
pub struct Farm {
    config: FarmConfig,
    /// Read once per request; every decision about time takes that reading.
    clock: Arc<dyn Clock>,
    store: Store,
    jobs: BTreeMap<String, Job>,
    next_seq: u64,
    leases: HashMap<String, Lease>,
    workers: HashMap<String, WorkerInfo>,
    /// Counters for `/metrics`.
    pub counters: Counters,
    started: Moment,
}

impl Farm {
    /// Opens the data folder and resumes every unfinished job from the database.
    pub fn open(config: FarmConfig) -> Result<Farm> {
        Self::open_with_clock(config, Arc::new(SystemClock::new()))
    }

    /// [`Farm::open`], with time read from `clock`.
    pub fn open_with_clock(config: FarmConfig, clock: Arc<dyn Clock>) -> Result<Farm> {
        let now = clock.now();
        let store = Store::open(&config.data_dir, config.durable)?;
        let mut jobs = BTreeMap::new();
        let mut next_seq = 0;
        for stored in store.jobs()? {
            next_seq = next_seq.max(stored.seq + 1);
            let mut job = match Job::new(
                stored.id.clone(),
                stored.seq,
                stored.scene,
                stored.settings,
                stored.priority,
                stored.created_unix,
            ) {
                Ok(job) => job,
                Err(e) => {
                    tracing::error!(job = %stored.id, "cannot restore job: {e}");
                    continue;
                }
            };
            job.elapsed_before = stored.elapsed_s;
            for tile in store.tiles(&stored.id)? {
                job.restore_tile(tile.frame, tile.tile, tile.prefix, tile.sums, tile.pending)
                    .map_err(|e| anyhow::anyhow!("job {}: {e}", stored.id))?;
            }
            job.restore_adaptive(&stored.scales);
            if job.frames.len() > 1 {
                for f in 0..job.frames.len() {
                    if job.frame_complete(f) {
                        job.evict_frame(f);
                    }
                }
            }
            if stored.state.is_final() {
                job.set_final(stored.state, stored.error, now);
                job.evict();
            } else {
                job.state = if job.samples_done > 0 { JobState::Running } else { JobState::Queued };
                job.finish_if_complete(now);
                tracing::info!(job = %job.id, samples = job.samples_done, "resuming job");
            }
            jobs.insert(stored.id, job);
        }
        Ok(Farm {
            config,
            clock,
            store,
            jobs,
            next_seq,
            leases: HashMap::new(),
            workers: HashMap::new(),
            counters: Counters::default(),
            started: now,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &FarmConfig {
        &self.config
    }

    /// Seconds since this process opened the farm.
    pub fn uptime(&self) -> f64 {
        self.clock.now().since(self.started).as_secs_f64()
    }

    /// Checks and stores an upload (call [`validate_upload`] first, outside any lock).
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
    /// [`validate_job_scene`]).
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
        self.check_settings(&settings)?;
        if !is_hash(scene) || self.store.scene_format(scene)?.is_none() {
            return Err(FarmError::not_found(format!(
                "no scene {scene}: upload it to /api/v1/scenes first"
            )));
        }
        let id = random_id();
        let now = self.clock.now();
        let created = self.clock.unix();
        let job =
            Job::new(id.clone(), self.next_seq, scene.to_string(), settings, priority, created)
                .map_err(|e| FarmError::invalid(format!("settings: {e}")))?;
        self.store.insert_job(&job, now)?;
        self.next_seq += 1;
        let status = job.status(now);
        tracing::info!(job = %id, scene, priority, "job created");
        self.jobs.insert(id, job);
        Ok(status)
    }

    fn job(&self, id: &str) -> FarmResult<&Job> {
        self.jobs.get(id).ok_or_else(|| FarmError::not_found(format!("no job {id}")))
    }

    /// The job a live lease belongs to.
    pub fn lease_job(&self, lease: &str) -> Option<&str> {
        self.leases.get(lease).map(|l| l.job.as_str())
    }

    /// Whether job `id` has ended (done, failed or cancelled) or is unknown.
    pub fn job_ended(&self, id: &str) -> bool {
        self.jobs.get(id).is_none_or(|j| j.state.is_final())
    }

    /// A job's status.
    pub fn status(&self, id: &str) -> FarmResult<JobStatus> {
        Ok(self.job(id)?.status(self.clock.now()))
    }

    /// Every job's status, oldest first.
    pub fn list(&self) -> Vec<JobStatus> {
        let mut jobs: Vec<&Job> = self.jobs.values().collect();
        jobs.sort_by_key(|j| j.seq);
        let now = self.clock.now();
        jobs.into_iter().map(|j| j.status(now)).collect()
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

    /// The merged film of frame `number` of job `id` (also while it runs), with its job's
    /// settings and scene hash.
    /// (Tests compare whole statistics with it; files are written from `image`.)
    #[cfg(test)]
    pub fn film(&self, id: &str, number: i64) -> FarmResult<(common::film::Film, JobStatus)> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        if !job.frames[f].evicted {
            return Ok((job.film(f), job.status(self.clock.now())));
        }
        let mut film = common::film::Film::new(job.settings.width, job.settings.height);
        for tile in self.stored_tiles(job, f)? {
            film.merge_tile(&tile);
        }
        Ok((film, job.status(self.clock.now())))
    }

    /// The summed tiles of frame index `f` of an evicted job, from the database.
    fn stored_tiles(&self, job: &Job, f: usize) -> FarmResult<Vec<common::film::TileAccum>> {
        Ok(self.store.frame_sums(&job.id, f as u32)?)
    }

    /// Persists and evicts a job that a lease going back just finished (time limit reached).
    fn settle(&mut self, id: &str, now: Moment) {
        if let Some(job) = self.jobs.get(id) {
            if job.state.is_final() && !job.evicted {
                if let Err(e) = self.store.update_job(job, now) {
                    tracing::error!(job = id, "recording the job's end failed: {e:#}");
                }
                self.evict_if_final(id);
            }
        }
    }

    /// Notes that a worker was heard from (a long poll that ended without work).
    pub fn seen(&mut self, worker: &str) {
        let _ = self.touch(worker, self.clock.now());
    }

    /// Drops a finished job's sums from memory. A scratch store (the one-shot render: one job
    /// in one process that reads its images at the end) keeps them: writing them out only to
    /// read them back would cost time and nothing else.
    fn evict_if_final(&mut self, id: &str) {
        if !self.config.durable {
            return;
        }
        if let Some(job) = self.jobs.get_mut(id) {
            if job.state.is_final() && !job.evicted {
                job.evict();
            }
        }
    }

    /// The image of frame `number` of job `id` (also while it runs), with the job's status.
    pub fn image(
        &self,
        id: &str,
        number: i64,
    ) -> FarmResult<(crate::output::FrameImage, JobStatus)> {
        let job = self.job(id)?;
        let f = Self::frame_index(job, number)?;
        if !job.frames[f].evicted {
            return Ok((job.image(f), job.status(self.clock.now())));
        }
        let mut image = crate::output::FrameImage::new(job.settings.width, job.settings.height);
        for tile in self.stored_tiles(job, f)? {
            image.put_tile(&tile);
        }
        Ok((image, job.status(self.clock.now())))
    }

    fn frame_index(job: &Job, number: i64) -> FarmResult<usize> {
        job.frames.iter().position(|f| f.number == number).ok_or_else(|| {
            FarmError::not_found(format!(
                "job {} has frames {}..={}, not {number}",
                job.id, job.settings.frames.start, job.settings.frames.end
            ))
        })
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
        job.in_flight = 0;
        self.store.update_job(job, now)?;
        let status = job.status(now);
        self.drop_leases_of(id);
        self.evict_if_final(id);
        tracing::info!(job = %id, "job cancelled");
        Ok(status)
    }

    fn drop_leases_of(&mut self, job: &str) {
        let dropped: Vec<String> =
            self.leases.iter().filter(|(_, l)| l.job == job).map(|(id, _)| id.clone()).collect();
        for id in dropped {
            if let Some(l) = self.leases.remove(&id) {
                if let Some(w) = self.workers.get_mut(&l.worker) {
                    w.leases = w.leases.saturating_sub(1);
                }
            }
        }
    }

    /// A worker joins.
    pub fn join(&mut self, req: JoinRequest) -> FarmResult<JoinResponse> {
        if req.threads == 0 || req.threads > 4096 {
            return Err(FarmError::invalid(format!("threads: {} is not in 1..=4096", req.threads)));
        }
        let id = random_id();
        let now = self.clock.now();
        tracing::info!(worker = %id, name = %req.name, threads = req.threads, "worker joined");
        self.workers.insert(
            id.clone(),
            WorkerInfo {
                id: id.clone(),
                name: req.name,
                threads: req.threads,
                version: req.version,
                joined_s_ago: 0.0,
                last_seen_s_ago: 0.0,
                tasks_done: 0,
                samples_done: 0,
                leases: 0,
                joined: Some(now),
                last_seen: Some(now),
            },
        );
        let timeout = self.config.lease_timeout.as_secs_f64();
        Ok(JoinResponse { id, lease_timeout_s: timeout, heartbeat_s: timeout / 4.0 })
    }

    /// A worker leaves: its leases are given back at once (not counted against the tasks).
    pub fn leave(&mut self, worker: &str) -> FarmResult<()> {
        let now = self.clock.now();
        if self.workers.remove(worker).is_none() {
            return Err(FarmError::not_found(format!("unknown worker {worker}")));
        }
        let held: Vec<String> = self
            .leases
            .iter()
            .filter(|(_, l)| l.worker == worker)
            .map(|(id, _)| id.clone())
            .collect();
        for id in held {
            let l = self.leases.remove(&id).expect("listed above");
            if let Some(job) = self.jobs.get_mut(&l.job) {
                job.give_back(l.key, now);
            }
            self.settle(&l.job, now);
        }
        tracing::info!(worker, "worker left");
        Ok(())
    }

    fn touch(&mut self, worker: &str, now: Moment) -> FarmResult<&mut WorkerInfo> {
        let w = self.workers.get_mut(worker).ok_or_else(|| {
            FarmError::not_found(format!(
                "unknown worker {worker}: join again (POST /api/v1/workers)"
            ))
        })?;
        w.last_seen = Some(now);
        Ok(w)
    }

    /// Leases the most urgent task to `worker`: the highest-priority job first; among equal
    /// priorities the job with the fewest leases out (fair sharing), then the oldest.
    pub fn lease(&mut self, worker: &str) -> FarmResult<Option<LeaseGrant>> {
        let now = self.clock.now();
        self.touch(worker, now)?;
        let mut best: Option<(&Job, TaskKey)> = None;
        for job in self.jobs.values() {
            let Some(key) = job.next_task() else { continue };
            let better = match best {
                None => true,
                Some((b, _)) => {
                    (job.priority, std::cmp::Reverse(job.in_flight), std::cmp::Reverse(job.seq))
                        > (b.priority, std::cmp::Reverse(b.in_flight), std::cmp::Reverse(b.seq))
                }
            };
            if better {
                best = Some((job, key));
            }
        }
        let Some((job, key)) = best else { return Ok(None) };
        let job_id = job.id.clone();
        let job = self.jobs.get_mut(&job_id).expect("found above");
        let was_queued = job.state == JobState::Queued;
        job.lease(key, now);
        let grant = LeaseGrant {
            lease: random_id(),
            job: job_id.clone(),
            scene: job.scene.clone(),
            settings: job.settings.clone(),
            task: job.spec(key),
            lease_timeout_s: self.config.lease_timeout.as_secs_f64(),
        };
        if was_queued {
            if let Err(e) = self.store.update_job(job, now) {
                job.give_back(key, now);
                return Err(e.into());
            }
        }
        self.leases.insert(
            grant.lease.clone(),
            Lease {
                job: job_id,
                key,
                worker: worker.to_string(),
                deadline: now + self.config.lease_timeout,
                last_renewal: now + self.config.max_lease_lifetime,
            },
        );
        self.counters.tasks_leased += 1;
        if let Some(w) = self.workers.get_mut(worker) {
            w.leases += 1;
        }
        Ok(Some(grant))
    }

    fn live_lease(&self, lease: &str, worker: &str) -> FarmResult<&Lease> {
        let l = self.leases.get(lease).ok_or_else(|| {
            FarmError::conflict(format!("lease {lease} is not live (expired, already answered, its job ended, or the coordinator restarted)"),
            )
        })?;
        if l.worker != worker {
            return Err(FarmError::forbidden(format!("lease {lease} belongs to another worker")));
        }
        Ok(l)
    }

    /// Renews a lease; returns seconds until it expires.
    pub fn heartbeat(&mut self, lease: &str, worker: &str) -> FarmResult<f64> {
        let now = self.clock.now();
        self.touch(worker, now)?;
        self.live_lease(lease, worker)?;
        let timeout = self.config.lease_timeout;
        let l = self.leases.get_mut(lease).expect("checked");
        if now >= l.last_renewal {
            return Err(FarmError::conflict(format!(
                "lease {lease} has reached its maximum lifetime of {} s and will not be renewed",
                self.config.max_lease_lifetime.as_secs()
            )));
        }
        l.deadline = now + timeout;
        Ok(timeout.as_secs_f64())
    }

    /// Merges the result of a live lease, exactly once, and commits it before returning.
    pub fn submit(
        &mut self,
        lease: &str,
        worker: &str,
        result: TaskResult,
        bytes: u64,
    ) -> FarmResult<()> {
        let now = self.clock.now();
        self.touch(worker, now)?;
        let (job_id, key) = {
            let l = self.live_lease(lease, worker)?;
            (l.job.clone(), l.key)
        };
        let job = self.jobs.get_mut(&job_id).expect("a live lease has a job");
        result
            .check_answers(&job.spec(key))
            .map_err(|e| FarmError::invalid(format!("result refused: {e}")))?;
        let samples: u64 = result.tile.pixels.iter().map(|p| p.n as u64).sum();
        let rays = result.rays;
        job.merge(key, result.tile, samples, now);
        self.leases.remove(lease);
        let job = &self.jobs[&job_id];
        // A scratch store writes a frame when it leaves memory instead (`keep_frame`).
        if self.config.durable {
            if let Err(e) = self.store.commit_task(job, key.frame, key.tile, key.k, now) {
                // The sums in memory are ahead of the database: fail loudly rather than go on.
                tracing::error!("committing a merged result failed: {e:#}");
                return Err(e.into());
            }
        }
        if job.state == JobState::Done {
            tracing::info!(job = %job_id, samples = job.samples_done, seconds = job.elapsed(now), "job done");
        }
        self.evict_if_final(&job_id);
        if let Some(job) = self.jobs.get_mut(&job_id) {
            let f = key.frame as usize;
            if !job.frames[f].evicted && job.frames.len() > 1 && job.frame_complete(f) {
                // Committed (above, or by `keep_frame`): its images are read back from SQLite.
                if keep_frame(&mut self.store, self.config.durable, job, f, now) {
                    job.evict_frame(f);
                }
            }
        }
        let c = &mut self.counters;
        c.tasks_merged += 1;
        c.samples_merged += samples;
        c.bytes_merged += bytes;
        c.rays += rays;
        c.merge_seconds += self.clock.now().since(now).as_secs_f64();
        if let Some(w) = self.workers.get_mut(worker) {
            w.tasks_done += 1;
            w.samples_done += samples;
            w.leases = w.leases.saturating_sub(1);
        }
        Ok(())
    }

    /// A worker could not render its task: the task is leased again, or after
    /// `max_task_failures` reports its job fails with the reason.
    pub fn fail(&mut self, lease: &str, worker: &str, error: &str) -> FarmResult<()> {
        let now = self.clock.now();
        self.touch(worker, now)?;
        let (job_id, key) = {
            let l = self.live_lease(lease, worker)?;
            (l.job.clone(), l.key)
        };
        self.leases.remove(lease);
        if let Some(w) = self.workers.get_mut(worker) {
            w.leases = w.leases.saturating_sub(1);
        }
        self.counters.tasks_failed += 1;
        let max = self.config.max_task_failures;
        let job = self.jobs.get_mut(&job_id).expect("a live lease has a job");
        let spec = job.spec(key);
        let n = job.release(key, true, now);
        tracing::warn!(job = %job_id, worker, "task failed ({n}/{max}): {error}");
        if n >= max {
            let reason = format!(
                "task frame {} tile ({}, {}) samples {}..{} failed {n} times; last error: {error}",
                spec.frame, spec.rect.x0, spec.rect.y0, spec.samples.start, spec.samples.end
            );
            job.set_final(JobState::Failed, Some(reason), now);
            self.store.update_job(job, now)?;
            self.drop_leases_of(&job_id);
            self.evict_if_final(&job_id);
        }
        self.settle(&job_id, now);
        Ok(())
    }

    /// Expires overdue leases, applies time limits and forgets silent workers. Returns true when
    /// tasks became available.
    pub fn tick(&mut self) -> bool {
        let now = self.clock.now();
        let mut freed = false;
        let overdue: Vec<String> = self
            .leases
            .iter()
            .filter(|(_, l)| l.deadline <= now)
            .map(|(id, _)| id.clone())
            .collect();
        for id in overdue {
            let l = self.leases.remove(&id).expect("listed above");
            self.counters.tasks_expired += 1;
            if let Some(w) = self.workers.get_mut(&l.worker) {
                w.leases = w.leases.saturating_sub(1);
            }
            let max = self.config.max_task_expiries;
            let Some(job) = self.jobs.get_mut(&l.job) else { continue };
            let spec = job.spec(l.key);
            let n = job.release(l.key, false, now);
            tracing::warn!(job = %l.job, worker = %l.worker, "lease expired ({n}/{max})");
            freed = true;
            if n >= max {
                let reason = format!(
                    "task frame {} tile ({}, {}) samples {}..{}: its lease expired {n} times (workers died or hung on it)",
                    spec.frame, spec.rect.x0, spec.rect.y0, spec.samples.start, spec.samples.end
                );
                job.set_final(JobState::Failed, Some(reason), now);
                let _ = self.store.update_job(job, now);
                self.drop_leases_of(&l.job);
                self.evict_if_final(&l.job);
            }
            self.settle(&l.job, now);
        }
        for job in self.jobs.values_mut() {
            if job.check_time_limit(now) {
                tracing::info!(job = %job.id, "time limit reached: no more tasks are issued");
                let _ = self.store.update_job(job, now);
                if job.state.is_final() {
                    job.evict();
                }
            }
        }
        let silent = self.config.lease_timeout * 3;
        self.workers.retain(|_, w| w.last_seen.is_some_and(|t| now.since(t) < silent));
        freed
    }

    /// The workers, with their ages filled in.
    pub fn workers(&self) -> Vec<WorkerInfo> {
        let now = self.clock.now();
        let mut out: Vec<WorkerInfo> = self
            .workers
            .values()
            .map(|w| {
                let mut w = w.clone();
                w.joined_s_ago = w.joined.map_or(0.0, |t| now.since(t).as_secs_f64());
                w.last_seen_s_ago = w.last_seen.map_or(0.0, |t| now.since(t).as_secs_f64());
                w
            })
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name).then(a.id.cmp(&b.id)));
        out
    }

    /// Leases out now.
    pub fn leases_out(&self) -> usize {
        self.leases.len()
    }
}

/// Makes sure frame `f` of `job` is in the database before it leaves memory: a durable store
/// committed every result already; a scratch store writes the frame now. False when that write
/// failed (the frame then stays in memory).
fn keep_frame(store: &mut Store, durable: bool, job: &Job, f: usize, now: Moment) -> bool {
    if durable {
        return true;
    }
    match store.commit_frame(job, f as u32, now) {
        Ok(()) => true,
        Err(e) => {
            tracing::error!(job = %job.id, frame = f, "writing a frame to the scratch store failed: {e:#}");
            false
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use clock::ManualClock;
    use common::{film::TileAccum, protocol::TaskResult};

    /// A result with the counts `grant` asks for (values from `v`), as a worker would send.
    pub(crate) fn result_for(grant: &LeaseGrant, v: f32) -> TaskResult {
        let spec = grant.task;
        let mut tile = TileAccum::new(spec.rect);
        for y in 0..spec.rect.height {
            for x in 0..spec.rect.width {
                for s in spec.samples.start..spec.samples.end {
                    tile.add_sample(x, y, s, [v + s as f32 * 0.01; 3]);
                }
            }
        }
        TaskResult { spec, tile, rays: 0 }
    }

    /// A result accepted out of order survives a restart as pending: counted once, never
    /// leased again, and added in task order once its predecessor arrives.
    #[test]
    fn pending_results_survive_a_restart_and_merge_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let settings = RenderSettings {
            width: 8,
            height: 8,
            tile_size: 8,
            spp: 8,
            samples_per_task: 4,
            ..Default::default()
        };
        let hash = "ab".repeat(32);
        let (id, first, second) = {
            let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
            farm.store.put_scene(&hash, "glb", b"scene").unwrap();
            let id = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
            let w = farm
                .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
                .unwrap()
                .id;
            let first = farm.lease(&w).unwrap().unwrap();
            let second = farm.lease(&w).unwrap().unwrap();
            assert_eq!((first.task.samples.start, second.task.samples.start), (0, 4));
            farm.submit(&second.lease, &w, result_for(&second, 0.5), 0).unwrap();
            let status = farm.status(&id).unwrap();
            assert_eq!(status.samples_done, 64 * 4);
            (id, first, second)
        };
        let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
        assert_eq!(farm.status(&id).unwrap().samples_done, 64 * 4, "the pending result was lost");
        let w = farm
            .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
            .unwrap()
            .id;
        let again = farm.lease(&w).unwrap().unwrap();
        assert_eq!(again.task, first.task, "only the unanswered task is leased again");
        assert!(farm.lease(&w).unwrap().is_none());
        farm.submit(&again.lease, &w, result_for(&again, 0.5), 0).unwrap();
        let status = farm.status(&id).unwrap();
        assert_eq!((status.state, status.samples_done), (JobState::Done, 64 * 8));
        // The same bits as merging in order without any restart.
        let mut expected = TileAccum::new(first.task.rect);
        expected.merge(&result_for(&first, 0.5).tile);
        expected.merge(&result_for(&second, 0.5).tile);
        let (film, _) = farm.film(&id, 0).unwrap();
        assert_eq!(film.pixels, expected.pixels);
    }

    /// A scratch store writes nothing per result, yet the frames it evicts (each frame of a
    /// multi-frame job as it finishes) read back with the same bits as a durable store's.
    #[test]
    fn a_scratch_store_keeps_evicted_frames_bit_for_bit() {
        let settings = RenderSettings {
            width: 16,
            height: 8,
            tile_size: 8,
            spp: 8,
            samples_per_task: 4,
            frames: common::settings::Frames { start: 0, end: 1, fps: 24.0 },
            ..Default::default()
        };
        let hash = "ef".repeat(32);
        let films = [true, false].map(|durable| {
            let dir = tempfile::tempdir().unwrap();
            let mut config = FarmConfig::new(dir.path().into());
            config.durable = durable;
            let mut farm = Farm::open(config).unwrap();
            farm.store.put_scene(&hash, "glb", b"scene").unwrap();
            let id = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
            let w = farm
                .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
                .unwrap()
                .id;
            let mut grants = Vec::new();
            while let Some(g) = farm.lease(&w).unwrap() {
                grants.push(g);
            }
            assert_eq!(grants.len(), 8, "2 frames x 2 tiles x 2 sample ranges");
            // Later sample ranges first, so that results wait as pending before they merge.
            for (i, g) in grants.iter().enumerate().rev() {
                farm.submit(&g.lease, &w, result_for(g, i as f32 * 0.1), 0).unwrap();
            }
            let job = &farm.jobs[&id];
            assert_eq!(job.state, JobState::Done);
            // Each frame of a multi-frame job leaves memory as it finishes, in both modes.
            assert!(job.frames.iter().all(|f| f.evicted), "durable {durable}");
            [0, 1].map(|f| farm.film(&id, f).unwrap().0)
        });
        assert_eq!(films[0], films[1]);
        assert!(films[1].iter().all(|f| f.pixels.iter().all(|p| p.n == 8)));
    }

    /// A worker whose render hangs keeps heartbeating; at the lease's maximum lifetime the
    /// heartbeats are refused, and at its last deadline the task goes back to the queue.
    #[test]
    fn a_hung_worker_loses_its_lease_at_the_maximum_lifetime() {
        let dir = tempfile::tempdir().unwrap();
        let mut config = FarmConfig::new(dir.path().into());
        config.lease_timeout = Duration::from_millis(40);
        config.max_lease_lifetime = Duration::from_millis(100);
        let clock = ManualClock::new();
        let mut farm = Farm::open_with_clock(config, Arc::new(clock.clone())).unwrap();
        let hash = "cd".repeat(32);
        farm.store.put_scene(&hash, "glb", b"scene").unwrap();
        let settings = RenderSettings { width: 8, height: 8, spp: 4, ..Default::default() };
        let id = farm.create_job(&hash, settings, 0).unwrap().id;
        let w = farm
            .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
            .unwrap()
            .id;
        let grant = farm.lease(&w).unwrap().unwrap();
        for _ in 0..4 {
            clock.advance(Duration::from_millis(20));
            farm.heartbeat(&grant.lease, &w).unwrap();
        }
        // At 100 ms, renewed last at 80 ms until 120 ms.
        clock.advance(Duration::from_millis(20));
        let refused = farm.heartbeat(&grant.lease, &w).unwrap_err();
        assert_eq!(refused.kind, ErrorKind::Conflict);
        assert!(refused.message.contains("maximum lifetime"), "{}", refused.message);
        clock.advance(Duration::from_millis(19));
        assert!(!farm.tick(), "the lease expired before its deadline");
        clock.advance(Duration::from_millis(1));
        assert!(farm.tick(), "the lease did not expire at its deadline");
        assert_eq!(farm.status(&id).unwrap().tasks_in_flight, 0);
        assert_eq!(farm.counters.tasks_expired, 1);
        assert!(farm.lease(&w).unwrap().is_some(), "the task is leased again");
    }
}
