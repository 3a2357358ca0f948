//! The workers the farm knows: who joined, when each was last heard from, what each has had
//! merged, and how often its tasks failed or its leases expired (its health). Plain data in memory (a restart forgets every worker, and they join again); the
//! leases they hold are the lease table's ([`super::lease`]).

use std::{collections::HashMap, time::Duration};

use common::protocol::JoinRequest;
use serde::Serialize;

use super::{
    clock::Moment,
    error::{FarmError, FarmResult},
};

/// A worker as the farm keeps it.
#[derive(Clone, Debug)]
struct Worker {
    name: String,
    threads: u32,
    version: String,
    joined: Moment,
    /// Any request of the worker's renews this; a worker silent for long is forgotten.
    last_seen: Moment,
    tasks_done: u64,
    samples_done: u64,
    tasks_failed: u64,
    leases_expired: u64,
    last_error: Option<String>,
}

/// The longest failure message a worker's entry keeps, in characters.
const MAX_ERROR_CHARS: usize = 300;

/// A worker as the API shows it.
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
    /// Tasks it reported it could not render.
    pub tasks_failed: u64,
    /// Leases it held past their deadline without renewing them (it stalled, crashed or lost
    /// the network).
    pub leases_expired: u64,
    /// What it said of its last failed task (at most 300 characters).
    pub last_error: Option<String>,
}

/// The registry of workers, by id.
#[derive(Debug, Default)]
pub struct Workers {
    by_id: HashMap<String, Worker>,
}

impl Workers {
    /// Adds a worker under `id` (the caller makes ids unique).
    pub fn join(&mut self, id: &str, req: JoinRequest, now: Moment) -> FarmResult<()> {
        if req.threads == 0 || req.threads > 4096 {
            return Err(FarmError::invalid(format!("threads: {} is not in 1..=4096", req.threads)));
        }
        let worker = Worker {
            name: req.name,
            threads: req.threads,
            version: req.version,
            joined: now,
            last_seen: now,
            tasks_done: 0,
            samples_done: 0,
            tasks_failed: 0,
            leases_expired: 0,
            last_error: None,
        };
        self.by_id.insert(id.to_string(), worker);
        Ok(())
    }

    /// Notes that `id` was heard from; refuses a worker the farm does not know (never joined,
    /// left, forgotten, or joined before a restart), which must join again.
    pub fn touch(&mut self, id: &str, now: Moment) -> FarmResult<()> {
        let w = self.by_id.get_mut(id).ok_or_else(|| {
            FarmError::not_found(format!("unknown worker {id}: join again (POST /api/v1/workers)"))
        })?;
        w.last_seen = now;
        Ok(())
    }

    /// Whether `id` is known.
    pub fn knows(&self, id: &str) -> bool {
        self.by_id.contains_key(id)
    }

    /// Removes `id`; false if it was not known.
    pub fn remove(&mut self, id: &str) -> bool {
        self.by_id.remove(id).is_some()
    }

    /// Forgets the workers not heard from for `silence` or longer.
    pub fn forget_silent(&mut self, now: Moment, silence: Duration) {
        self.by_id.retain(|_, w| now.since(w.last_seen) < silence);
    }

    /// Credits `id` with a merged task of `samples` pixel samples.
    pub fn credit(&mut self, id: &str, samples: u64) {
        if let Some(w) = self.by_id.get_mut(id) {
            w.tasks_done += 1;
            w.samples_done += samples;
        }
    }

    /// Counts a task `id` reported it could not render, and keeps what it said.
    pub fn note_failure(&mut self, id: &str, error: &str) {
        if let Some(w) = self.by_id.get_mut(id) {
            w.tasks_failed += 1;
            w.last_error = Some(error.chars().take(MAX_ERROR_CHARS).collect());
        }
    }

    /// Counts a lease of `id`'s that expired.
    pub fn note_expiry(&mut self, id: &str) {
        if let Some(w) = self.by_id.get_mut(id) {
            w.leases_expired += 1;
        }
    }

    /// Every worker as the API shows it at `now`, by name then id; `leases` says how many
    /// leases a worker holds.
    pub fn list(&self, now: Moment, leases: impl Fn(&str) -> u32) -> Vec<WorkerInfo> {
        let mut out: Vec<WorkerInfo> = self
            .by_id
            .iter()
            .map(|(id, w)| WorkerInfo {
                id: id.clone(),
                name: w.name.clone(),
                threads: w.threads,
                version: w.version.clone(),
                joined_s_ago: now.since(w.joined).as_secs_f64(),
                last_seen_s_ago: now.since(w.last_seen).as_secs_f64(),
                tasks_done: w.tasks_done,
                samples_done: w.samples_done,
                leases: leases(id),
                tasks_failed: w.tasks_failed,
                leases_expired: w.leases_expired,
                last_error: w.last_error.clone(),
            })
            .collect();
        out.sort_by(|a, b| a.name.cmp(&b.name).then(a.id.cmp(&b.id)));
        out
    }
}
