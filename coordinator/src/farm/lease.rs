//! The task-and-lease state machine: which worker holds which task until when, which workers
//! are alive, and how often each task has failed or expired. One transition function,
//! [`Leases::step`], takes an [`Event`] and the time and returns the [`Effect`]s for the farm to
//! carry out (reopening and merging tasks, failing jobs, the database, logs and counters). It
//! does no I/O and reads no clock, so every edge below is tested (`lease/tests.rs`) on a
//! made-up timeline, without sleeping.
//!
//! The edges:
//! - `Lease`: a known worker is granted the task the scheduler offers, until
//!   `now + lease_timeout`, renewable until `now + max_lease_lifetime`.
//! - `Heartbeat`: the holder moves the deadline to `now + lease_timeout`; past the maximum
//!   lifetime it is refused (a worker whose render hangs keeps heartbeating, and the task must
//!   go to someone else eventually).
//! - `Result`: the holder's result, if it answers the task, ends the lease: the farm merges it.
//!   The lease is gone after, so nothing is merged twice.
//! - `Fail`, and `Tick` at or past a deadline: the lease ends without a result, the failure or
//!   expiry is counted against the task, and at `max_task_failures` or `max_task_expiries` the
//!   job fails and its other leases are dropped. This is the one failure path (`Leases::release`).
//! - `Leave`, `GiveBack`: leases end without a result and without being counted.
//! - `Cancel`: a job's leases are dropped.
//! - `Tick` also forgets the workers not heard from for three lease timeouts.
//!
//! Refusals: an unknown worker must join again (not found); a lease that is not live (expired,
//! answered, dropped, never granted, or granted before a restart) is a conflict; another
//! worker's lease is forbidden. A refusal changes nothing, except that a known worker was heard
//! from.

use std::{collections::HashMap, time::Duration};

use common::protocol::{TaskResult, TaskSpec};

use super::{
    clock::Moment,
    error::{FarmError, FarmResult},
    job::TaskKey,
    workers::{WorkerInfo, Workers},
};

/// The limits the machine enforces.
#[derive(Clone, Debug)]
pub struct Rules {
    /// A lease not renewed for this long expires.
    pub lease_timeout: Duration,
    /// No lease is renewed past this age.
    pub max_lease_lifetime: Duration,
    /// The failure report that fails a task's job.
    pub max_task_failures: u32,
    /// The expiry that fails a task's job.
    pub max_task_expiries: u32,
}

/// A live lease.
#[derive(Clone, Debug, PartialEq)]
pub struct Lease {
    /// The job of the task.
    pub job: String,
    /// The task.
    pub key: TaskKey,
    /// What the task asks for (its result must answer it).
    pub spec: TaskSpec,
    /// Who holds it.
    pub worker: String,
    /// It expires at this moment unless renewed.
    pub deadline: Moment,
    /// Heartbeats are refused from this moment on.
    pub renewable_until: Moment,
}

/// The task the scheduler picked for a lease request.
#[derive(Clone, Debug, PartialEq)]
pub struct Offer {
    /// The new lease's id.
    pub lease: String,
    /// The job of the task.
    pub job: String,
    /// The task.
    pub key: TaskKey,
    /// What the task asks for.
    pub spec: TaskSpec,
}

/// What happens to the machine.
#[derive(Debug)]
pub enum Event<'a> {
    /// `worker` asks for a task; `offer` is what the scheduler picked, if anything.
    Lease {
        /// Who asks.
        worker: &'a str,
        /// The task to grant.
        offer: Option<Offer>,
    },
    /// `worker` was heard from without asking for anything (a long poll that found no work).
    Seen {
        /// Who.
        worker: &'a str,
    },
    /// `worker` renews `lease`.
    Heartbeat {
        /// The lease.
        lease: &'a str,
        /// Who renews it.
        worker: &'a str,
    },
    /// `worker` hands in `result` for `lease`.
    Result {
        /// The lease.
        lease: &'a str,
        /// Who hands it in.
        worker: &'a str,
        /// The result.
        result: &'a TaskResult,
    },
    /// `worker` reports that it cannot render the task of `lease`.
    Fail {
        /// The lease.
        lease: &'a str,
        /// Who reports.
        worker: &'a str,
        /// Why, in the worker's words.
        error: &'a str,
    },
    /// A granted lease goes back without being counted (the grant could not be recorded).
    GiveBack {
        /// The lease.
        lease: &'a str,
    },
    /// `worker` leaves: its leases go back without being counted.
    Leave {
        /// Who.
        worker: &'a str,
    },
    /// `job` was cancelled: its leases are dropped.
    Cancel {
        /// The job.
        job: &'a str,
    },
    /// Time passed: leases at or past their deadline expire, silent workers are forgotten.
    Tick,
}

/// What the farm must do after a step, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Effect {
    /// `lease` now holds task `key` of `job`: mark it leased.
    Granted {
        /// The lease.
        lease: String,
        /// The job.
        job: String,
        /// The task.
        key: TaskKey,
    },
    /// `lease` was renewed until `deadline`.
    Renewed {
        /// The lease.
        lease: String,
        /// Its new deadline.
        deadline: Moment,
    },
    /// The result for task `key` of `job` answers its lease, which has ended: merge it.
    Answered {
        /// The job.
        job: String,
        /// The task.
        key: TaskKey,
    },
    /// The lease of `worker` on task `key` of `job` ended without a result: the task is open
    /// again.
    Released {
        /// The job.
        job: String,
        /// The task.
        key: TaskKey,
        /// Who held it.
        worker: String,
        /// Why, and how it was counted.
        why: Release,
    },
    /// `job` fails for `reason`; its leases are already dropped.
    JobFailed {
        /// The job.
        job: String,
        /// Why, for its status.
        reason: String,
    },
}

/// Why a lease ended without a result.
#[derive(Clone, Debug, PartialEq)]
pub enum Release {
    /// Its worker reported a failure, the task's `count`th.
    Failed {
        /// Failures of the task so far.
        count: u32,
        /// The worker's words.
        error: String,
    },
    /// It was not renewed in time, the task's `count`th expiry.
    Expired {
        /// Expiries of the task so far.
        count: u32,
    },
    /// Its worker gave it back (it left, or the grant was withdrawn): not counted.
    GivenBack,
}

/// Failures and expiries counted against one task.
#[derive(Clone, Copy, Debug, Default)]
struct Strikes {
    failures: u32,
    expiries: u32,
}

/// Why [`Leases::release`] is called.
enum Cause<'a> {
    Failure(&'a str),
    Expiry,
}

/// The machine's state.
#[derive(Debug)]
pub struct Leases {
    rules: Rules,
    /// Who is alive; every worker event is checked against it first.
    workers: Workers,
    /// Live leases by id. A task has at most one, because only open tasks are offered.
    live: HashMap<String, Lease>,
    /// Strikes per task, by job. In memory only: a restart forgives them.
    strikes: HashMap<String, HashMap<TaskKey, Strikes>>,
}

impl Leases {
    /// No workers and no leases.
    pub fn new(rules: Rules) -> Self {
        Leases { rules, workers: Workers::default(), live: HashMap::new(), strikes: HashMap::new() }
    }

    /// The workers.
    pub fn workers(&self) -> &Workers {
        &self.workers
    }

    /// The workers, to add one or credit one with a merged task.
    pub fn workers_mut(&mut self) -> &mut Workers {
        &mut self.workers
    }

    /// Every worker as the API shows it at `now`, with the leases it holds.
    pub fn worker_infos(&self, now: Moment) -> Vec<WorkerInfo> {
        let mut held: HashMap<&str, u32> = HashMap::new();
        for l in self.live.values() {
            *held.entry(l.worker.as_str()).or_default() += 1;
        }
        self.workers.list(now, |id| held.get(id).copied().unwrap_or(0))
    }

    /// The live lease `id`.
    pub fn get(&self, id: &str) -> Option<&Lease> {
        self.live.get(id)
    }

    /// Live leases.
    pub fn len(&self) -> usize {
        self.live.len()
    }

    /// Whether no lease is live.
    pub fn is_empty(&self) -> bool {
        self.live.is_empty()
    }

    /// The transition function: applies `event` at `now`. `Err` is a refusal, which changes
    /// nothing except that a known worker was heard from.
    pub fn step(&mut self, event: Event<'_>, now: Moment) -> FarmResult<Vec<Effect>> {
        match event {
            Event::Lease { worker, offer } => {
                self.workers.touch(worker, now)?;
                let Some(offer) = offer else { return Ok(Vec::new()) };
                let lease = Lease {
                    job: offer.job.clone(),
                    key: offer.key,
                    spec: offer.spec,
                    worker: worker.to_string(),
                    deadline: now + self.rules.lease_timeout,
                    renewable_until: now + self.rules.max_lease_lifetime,
                };
                self.live.insert(offer.lease.clone(), lease);
                Ok(vec![Effect::Granted { lease: offer.lease, job: offer.job, key: offer.key }])
            }
            Event::Seen { worker } => {
                self.workers.touch(worker, now)?;
                Ok(Vec::new())
            }
            Event::Heartbeat { lease, worker } => {
                self.workers.touch(worker, now)?;
                self.held(lease, worker)?;
                let timeout = self.rules.lease_timeout;
                let max_lifetime = self.rules.max_lease_lifetime;
                let l = self.live.get_mut(lease).expect("checked");
                if now >= l.renewable_until {
                    return Err(FarmError::conflict(format!(
                        "lease {lease} has reached its maximum lifetime of {} s and will not be renewed",
                        max_lifetime.as_secs()
                    )));
                }
                l.deadline = now + timeout;
                Ok(vec![Effect::Renewed { lease: lease.to_string(), deadline: l.deadline }])
            }
            Event::Result { lease, worker, result } => {
                self.workers.touch(worker, now)?;
                let l = self.held(lease, worker)?;
                result
                    .check_answers(&l.spec)
                    .map_err(|e| FarmError::invalid(format!("result refused: {e}")))?;
                let l = self.live.remove(lease).expect("checked");
                Ok(vec![Effect::Answered { job: l.job, key: l.key }])
            }
            Event::Fail { lease, worker, error } => {
                self.workers.touch(worker, now)?;
                self.held(lease, worker)?;
                let l = self.live.remove(lease).expect("checked");
                Ok(self.release(l, Cause::Failure(error)))
            }
            Event::GiveBack { lease } => {
                Ok(self.live.remove(lease).map(Self::given_back).into_iter().collect())
            }
            Event::Leave { worker } => {
                if !self.workers.remove(worker) {
                    return Err(FarmError::not_found(format!("unknown worker {worker}")));
                }
                let held = self.ids_where(|l| l.worker == worker);
                Ok(held
                    .iter()
                    .filter_map(|id| self.live.remove(id))
                    .map(Self::given_back)
                    .collect())
            }
            Event::Cancel { job } => {
                self.drop_job(job);
                Ok(Vec::new())
            }
            Event::Tick => {
                let mut effects = Vec::new();
                for id in self.ids_where(|l| l.deadline <= now) {
                    // An earlier expiry may have failed this lease's job and dropped it.
                    if let Some(l) = self.live.remove(&id) {
                        effects.extend(self.release(l, Cause::Expiry));
                    }
                }
                self.workers.forget_silent(now, self.rules.lease_timeout * 3);
                Ok(effects)
            }
        }
    }

    /// The live lease `id`, if `worker` holds it; else the refusal a call on it gets.
    pub fn held(&self, id: &str, worker: &str) -> FarmResult<&Lease> {
        let l = self.live.get(id).ok_or_else(|| {
            FarmError::conflict(format!(
                "lease {id} is not live (expired, already answered, its job ended, or the coordinator restarted)"
            ))
        })?;
        if l.worker != worker {
            return Err(FarmError::forbidden(format!("lease {id} belongs to another worker")));
        }
        Ok(l)
    }

    /// The ids of the live leases that `keep` selects, earliest deadline first (ties by id), so
    /// that a step's effects come in the same order every time.
    fn ids_where(&self, keep: impl Fn(&Lease) -> bool) -> Vec<String> {
        let mut ids: Vec<(Moment, &String)> =
            self.live.iter().filter(|(_, l)| keep(l)).map(|(id, l)| (l.deadline, id)).collect();
        ids.sort();
        ids.into_iter().map(|(_, id)| id.clone()).collect()
    }

    fn given_back(l: Lease) -> Effect {
        Effect::Released { job: l.job, key: l.key, worker: l.worker, why: Release::GivenBack }
    }

    /// The failure path: `lease` has ended without a result because of `cause`. Counts that
    /// against its task; at the limit the job fails (with a reason naming the task) and loses
    /// its other leases.
    fn release(&mut self, lease: Lease, cause: Cause<'_>) -> Vec<Effect> {
        let strikes = self.strikes.entry(lease.job.clone()).or_default().entry(lease.key);
        let strikes = strikes.or_default();
        let s = lease.spec;
        let task = format!(
            "task frame {} tile ({}, {}) samples {}..{}",
            s.frame, s.rect.x0, s.rect.y0, s.samples.start, s.samples.end
        );
        let (why, reason) = match cause {
            Cause::Failure(error) => {
                strikes.failures += 1;
                let n = strikes.failures;
                let reason = (n >= self.rules.max_task_failures)
                    .then(|| format!("{task} failed {n} times; last error: {error}"));
                (Release::Failed { count: n, error: error.to_string() }, reason)
            }
            Cause::Expiry => {
                strikes.expiries += 1;
                let n = strikes.expiries;
                let reason = (n >= self.rules.max_task_expiries).then(|| {
                    format!("{task}: its lease expired {n} times (workers died or hung on it)")
                });
                (Release::Expired { count: n }, reason)
            }
        };
        let job = lease.job.clone();
        let mut effects =
            vec![Effect::Released { job: lease.job, key: lease.key, worker: lease.worker, why }];
        if let Some(reason) = reason {
            self.drop_job(&job);
            effects.push(Effect::JobFailed { job, reason });
        }
        effects
    }

    /// Forgets an ended job: its leases and its tasks' strikes.
    fn drop_job(&mut self, job: &str) {
        self.live.retain(|_, l| l.job != job);
        self.strikes.remove(job);
    }
}

#[cfg(test)]
mod tests;
