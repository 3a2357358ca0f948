//! The farm: scenes, jobs, leases and workers, kept in memory and persisted in the [`store`].
//! Synchronous and free of HTTP: the service wraps it in a mutex.
//!
//! A worker's request is one step of the lease machine ([`lease`]), which decides, followed by
//! the farm carrying out the step's effects on the jobs ([`job`]), the store, the counters and
//! the logs. Time comes from the [`clock`] the farm was opened with, read once per request.
//!
//! Exactly-once merging: a task has at most one live lease; a result is merged only for a live
//! lease held by the worker that sends it, and the merge turns the task merged and drops the
//! lease, so a duplicate, a result for an expired or reassigned lease, or one for a cancelled
//! job is refused (a conflict) without touching the sums.
//!
//! # Layout
//! - [`clock`]: monotonic time passed in ([`clock::Moment`]); the system's and a manual clock.
//! - [`error`]: [`FarmError`], a refusal's kind and message, free of HTTP.
//! - [`validate`]: checks of uploads and settings, outside the farm lock.
//! - [`job`]: one job's tiles and tasks, the merging of results, adaptive sampling.
//! - [`lease`]: the task-and-lease state machine, a pure transition function.
//! - [`workers`]: the registry of workers, kept by the lease machine.
//! - [`store`]: SQLite and the scene files.
//! - `jobs.rs`: the user side of [`Farm`] (scenes, jobs, images); this file: opening the farm
//!   and the worker side (leases, results, failures, time passing).
//!
//! Data flows one way: `clock`, `error` and `validate` use nothing else of the farm; `job` and
//! `store` use the clock; `workers` the clock and errors; `lease` those and `job`'s task keys;
//! `jobs.rs` and this file use them all.

pub mod clock;
pub mod error;
pub mod job;
mod jobs;
pub mod lease;
pub mod store;
pub mod validate;
pub mod workers;

pub use error::{ErrorKind, FarmError, FarmResult};
pub use jobs::{
    validate_job_name, FrameLayout, JobPage, JobQuery, ListOrder, TileCopy, TileMap, TileProgress,
    DEFAULT_LIST_LIMIT, MAX_JOB_NAME_CHARS, MAX_LIST_LIMIT,
};
pub use validate::{
    hex, is_hash, validate_job_scene, validate_upload, validate_upload_loaded, SceneInfo,
};
pub use workers::WorkerInfo;

use std::{collections::BTreeMap, path::PathBuf, sync::Arc, time::Duration};

use anyhow::Result;
use common::protocol::{JoinRequest, JoinResponse, LeaseGrant, TaskResult};
use serde::Serialize;

use clock::{Clock, Moment, SystemClock};
use job::{Job, JobState, TaskKey};
use lease::{Effect, Event, Leases, Offer, Release, Rules};
use store::Store;

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
    /// What loading a scene may cost (inflated bytes, texels, triangles); workers are told.
    pub scene_budget: common::budget::SceneBudget,
    /// Whether committed results must survive a crash (write-ahead log, synced). Only the
    /// one-shot local render, whose data folder is temporary, turns this off.
    pub durable: bool,
    /// Finished jobs (done, failed, cancelled) are removed this long after they ended, by the
    /// tick; `None` keeps them forever.
    pub retain_finished: Option<Duration>,
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
            scene_budget: Default::default(),
            durable: true,
            retain_finished: None,
        }
    }

    fn lease_rules(&self) -> Rules {
        Rules {
            lease_timeout: self.lease_timeout,
            max_lease_lifetime: self.max_lease_lifetime,
            max_task_failures: self.max_task_failures,
            max_task_expiries: self.max_task_expiries,
        }
    }
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
    /// Jobs removed (by a user, or past `retain_finished`).
    pub jobs_removed: u64,
    /// Failures reported by workers.
    pub tasks_failed: u64,
    /// Pixel samples merged.
    pub samples_merged: u64,
    /// Bytes of results merged.
    pub bytes_merged: u64,
    /// Seconds spent merging results under the farm lock (their commits, in groups, are
    /// counted apart: [`Farm::commit_groups`]).
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
    /// The next job's creation order.
    next_seq: u64,
    /// Live leases, workers, and the tasks' failure and expiry counts.
    leases: Leases,
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
            job.finished_unix = stored.finished_unix;
            job.name = stored.name;
            for tile in store.tiles(&stored.id)? {
                job.restore_tile(tile.frame, tile.tile, tile.prefix, tile.sums, tile.pending)
                    .map_err(|e| anyhow::anyhow!("job {}: {e}", stored.id))?;
            }
            job.restore_adaptive(&stored.scales, store.pilots(&stored.id)?)
                .map_err(|e| anyhow::anyhow!("job {}: {e}", stored.id))?;
            for (frame, kernel) in store.kernels(&stored.id)? {
                if (frame as usize) < job.frames.len() {
                    job.note_kernel(frame as usize, &kernel);
                }
            }
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
            // A job that ended before its end was stored (an older database) counts from now,
            // so that retention never removes it sooner than promised.
            if job.note_end(clock.unix()) {
                store.update_job(&job, now)?;
            }
            jobs.insert(stored.id, job);
        }
        let leases = Leases::new(config.lease_rules());
        Ok(Farm {
            config,
            clock,
            store,
            jobs,
            next_seq,
            leases,
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

    /// A worker joins.
    pub fn join(&mut self, req: JoinRequest) -> FarmResult<JoinResponse> {
        let id = random_id();
        let (name, threads) = (req.name.clone(), req.threads);
        self.leases.workers_mut().join(&id, req, self.clock.now())?;
        tracing::info!(worker = %id, name = %name, threads, "worker joined");
        let timeout = self.config.lease_timeout.as_secs_f64();
        Ok(JoinResponse { id, lease_timeout_s: timeout, heartbeat_s: timeout / 4.0 })
    }

    /// A worker leaves: its leases are given back at once (not counted against the tasks).
    pub fn leave(&mut self, worker: &str) -> FarmResult<()> {
        let now = self.clock.now();
        let given_back = self.leases.step(Event::Leave { worker }, now)?;
        // Giving back fails no job, so there is no job's end to record.
        let _ = self.apply_releases(given_back, now);
        tracing::info!(worker, "worker left");
        Ok(())
    }

    /// Notes that a worker was heard from (a long poll that ended without work).
    pub fn seen(&mut self, worker: &str) {
        let _ = self.leases.step(Event::Seen { worker }, self.clock.now());
    }

    /// The workers, with their ages filled in.
    pub fn workers(&self) -> Vec<WorkerInfo> {
        self.leases.worker_infos(self.clock.now())
    }

    /// The transactions that committed merged results (each commits every merge queued
    /// meanwhile), and the seconds they took.
    pub fn commit_groups(&self) -> (u64, f64) {
        self.store.groups()
    }

    /// Leases out now.
    pub fn leases_out(&self) -> usize {
        self.leases.len()
    }

    /// The job a live lease belongs to.
    pub fn lease_job(&self, lease: &str) -> Option<&str> {
        self.leases.get(lease).map(|l| l.job.as_str())
    }

    /// Leases the most urgent task to `worker`: the highest-priority job first; among equal
    /// priorities the job with the fewest leases out (fair sharing), then the oldest.
    pub fn lease(&mut self, worker: &str) -> FarmResult<Option<LeaseGrant>> {
        let now = self.clock.now();
        let offer = self.most_urgent_task();
        let granted = self.leases.step(Event::Lease { worker, offer }, now)?;
        let [Effect::Granted { lease, job: job_id, key }] = granted.as_slice() else {
            return Ok(None);
        };
        let key = *key;
        let job = self.jobs.get_mut(job_id).expect("offered above");
        let was_queued = job.state == JobState::Queued;
        job.lease(key, now);
        let grant = LeaseGrant {
            lease: lease.clone(),
            job: job_id.clone(),
            scene: job.scene.clone(),
            settings: job.settings.clone(),
            task: job.spec(key),
            lease_timeout_s: self.config.lease_timeout.as_secs_f64(),
            scene_budget: self.config.scene_budget,
        };
        let recorded = if was_queued { self.store.update_job(job, now) } else { Ok(()) };
        if let Err(e) = recorded {
            let given_back = self.leases.step(Event::GiveBack { lease }, now)?;
            let _ = self.apply_releases(given_back, now);
            return Err(e.into());
        }
        self.counters.tasks_leased += 1;
        Ok(Some(grant))
    }

    /// The task to offer next, under a new lease id.
    fn most_urgent_task(&self) -> Option<Offer> {
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
        best.map(|(job, key)| Offer {
            lease: random_id(),
            job: job.id.clone(),
            key,
            spec: job.spec(key),
        })
    }

    /// Renews a lease; returns seconds until it expires.
    pub fn heartbeat(&mut self, lease: &str, worker: &str) -> FarmResult<f64> {
        self.leases.step(Event::Heartbeat { lease, worker }, self.clock.now())?;
        Ok(self.config.lease_timeout.as_secs_f64())
    }

    /// The most bytes a result for lease `id` can take, if `worker` holds it (see
    /// [`common::protocol::max_result_bytes`]); else the refusal the result would get.
    pub fn result_limit(&self, lease: &str, worker: &str) -> FarmResult<usize> {
        if !self.leases.workers().knows(worker) {
            // As the result itself would be: the worker is told to join again.
            return Err(FarmError::not_found(format!(
                "unknown worker {worker}: join again (POST /api/v1/workers)"
            )));
        }
        Ok(common::protocol::max_result_bytes(&self.leases.held(lease, worker)?.spec))
    }

    /// Merges the result of a live lease, exactly once, and commits it before returning.
    pub fn submit(
        &mut self,
        lease: &str,
        worker: &str,
        result: TaskResult,
        bytes: u64,
    ) -> FarmResult<()> {
        match self.submit_queued(lease, worker, result, bytes)? {
            Some(commit) => Ok(commit.wait()?),
            None => Ok(()),
        }
    }

    /// [`Farm::submit`], its database writes queued rather than committed: the result must not
    /// be answered "merged" before the returned [`Commit`] is waited for, which a caller does
    /// after letting go of the farm (group commit: one transaction for the merges queued
    /// meanwhile). `None` where nothing needs committing (a scratch store).
    pub fn submit_queued(
        &mut self,
        lease: &str,
        worker: &str,
        result: TaskResult,
        bytes: u64,
    ) -> FarmResult<Option<store::Commit>> {
        let now = self.clock.now();
        let answered = self.leases.step(Event::Result { lease, worker, result: &result }, now)?;
        let [Effect::Answered { job: job_id, key }] = answered.as_slice() else {
            unreachable!("an accepted result is answered: {answered:?}");
        };
        let key = *key;
        let samples: u64 = result.tile.pixels.iter().map(|p| p.n as u64).sum();
        let rays = result.rays;
        let job = self.jobs.get_mut(job_id).expect("a live lease has a job");
        job.note_kernel(key.frame as usize, &result.kernel);
        job.merge(key, result.tile, samples, now);
        job.note_end(self.clock.unix());
        job.note_progress(now);
        // A scratch store writes a frame when it leaves memory instead (`keep_frame`).
        let commit = self
            .config
            .durable
            .then(|| self.store.queue_task(job, key.frame, key.tile, key.k, now));
        if job.state == JobState::Done {
            tracing::info!(job = %job_id, samples = job.samples_done, seconds = job.elapsed(now), "job done");
        }
        self.evict_if_final(job_id);
        if let Some(job) = self.jobs.get_mut(job_id) {
            let f = key.frame as usize;
            if !job.frames[f].evicted && job.frames.len() > 1 && job.frame_complete(f) {
                // Queued (above; committed before the database is next read) or written by
                // `keep_frame`: its images are read back from SQLite.
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
        self.leases.workers_mut().credit(worker, samples);
        Ok(commit)
    }

    /// Counts a refused result (from the farm's checks, or from the service's before them: an
    /// unreadable body, a missing header) for `/metrics`; the service logs it.
    pub fn result_refused(&mut self) {
        self.counters.results_refused += 1;
    }

    /// A worker could not render its task: the task is leased again, or after
    /// `max_task_failures` reports its job fails with the reason.
    pub fn fail(&mut self, lease: &str, worker: &str, error: &str) -> FarmResult<()> {
        let now = self.clock.now();
        let released = self.leases.step(Event::Fail { lease, worker, error }, now)?;
        self.apply_releases(released, now)
    }

    /// Expires overdue leases, applies time limits and forgets silent workers. Returns true when
    /// tasks became available.
    pub fn tick(&mut self) -> bool {
        let now = self.clock.now();
        let expired = self.leases.step(Event::Tick, now).unwrap_or_default();
        let freed = !expired.is_empty();
        // Nobody waits on a tick: a job's end that cannot be recorded is logged by `settle`.
        let _ = self.apply_releases(expired, now);
        let unix = self.clock.unix();
        for job in self.jobs.values_mut() {
            if job.check_time_limit(now) {
                tracing::info!(job = %job.id, "time limit reached: no more tasks are issued");
                job.note_end(unix);
                let _ = self.store.update_job(job, now);
                if job.state.is_final() {
                    job.evict();
                }
            }
        }
        self.remove_expired_jobs(unix);
        freed
    }

    /// Removes the finished jobs that ended `retain_finished` or longer before `unix`.
    fn remove_expired_jobs(&mut self, unix: f64) {
        let Some(keep) = self.config.retain_finished else { return };
        let keep = keep.as_secs_f64();
        let expired: Vec<String> = self
            .jobs
            .values()
            .filter(|j| j.state.is_final() && j.finished_unix.is_some_and(|f| unix - f >= keep))
            .map(|j| j.id.clone())
            .collect();
        for id in expired {
            match self.remove_job(&id) {
                Ok(()) => {
                    tracing::info!(job = %id, hours = keep / 3600.0, "finished job removed after its retention time")
                }
                Err(e) => tracing::error!(job = %id, "removing a finished job failed: {e}"),
            }
        }
    }

    /// Carries out what a step decided about leases that ended without a result: their tasks
    /// go back to their jobs, a job that failed ends, and the counters and logs say so. Every
    /// effect is carried out; the first job's end that could not be recorded is returned.
    fn apply_releases(&mut self, effects: Vec<Effect>, now: Moment) -> FarmResult<()> {
        let mut recorded = Ok(());
        let mut touched = Vec::new();
        for effect in effects {
            match effect {
                Effect::Released { job, key, worker, why } => {
                    match why {
                        Release::Failed { count, error } => {
                            self.counters.tasks_failed += 1;
                            let max = self.config.max_task_failures;
                            let worker = worker.as_str();
                            tracing::warn!(job = %job, worker, "task failed ({count}/{max}): {error}");
                            self.leases.workers_mut().note_failure(worker, &error);
                        }
                        Release::Expired { count } => {
                            self.counters.tasks_expired += 1;
                            let max = self.config.max_task_expiries;
                            tracing::warn!(job = %job, worker = %worker, "lease expired ({count}/{max})");
                            self.leases.workers_mut().note_expiry(&worker);
                        }
                        Release::GivenBack => {}
                    }
                    if let Some(j) = self.jobs.get_mut(&job) {
                        j.give_back(key, now);
                    }
                    touched.push(job);
                }
                Effect::JobFailed { job, reason } => {
                    if let Some(j) = self.jobs.get_mut(&job) {
                        j.set_final(JobState::Failed, Some(reason), now);
                        j.note_end(self.clock.unix());
                        if let Err(e) = self.store.update_job(j, now) {
                            recorded = recorded.and(Err(e.into()));
                        }
                    }
                    self.evict_if_final(&job);
                }
                other => unreachable!("not the end of a lease without a result: {other:?}"),
            }
        }
        for job in touched {
            self.settle(&job, now);
        }
        recorded
    }

    /// Persists and evicts a job that a lease going back just finished (time limit reached).
    fn settle(&mut self, id: &str, now: Moment) {
        let unix = self.clock.unix();
        if let Some(job) = self.jobs.get_mut(id) {
            job.note_end(unix);
            if job.state.is_final() && !job.evicted {
                if let Err(e) = self.store.update_job(job, now) {
                    tracing::error!(job = id, "recording the job's end failed: {e:#}");
                }
                self.evict_if_final(id);
            }
        }
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
}

/// Makes sure frame `f` of `job` is in the database before it leaves memory: a durable store
/// has queued every result already (committed before the database is next read, or never read
/// again: a failed commit stops the database); a scratch store writes the frame now. False when
/// that write failed (the frame then stays in memory).
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
pub(crate) mod tests;
