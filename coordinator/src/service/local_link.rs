//! The in-process link of `coordinator render`: its local workers run the same worker loop as
//! `worker --join` (leases, renewals, results, failures) but call the farm directly instead of
//! over HTTP, so that a one-process render pays no sockets, no HTTP and no result encoding. The
//! farm checks and merges their results exactly as it does a remote worker's.

use std::{
    sync::{
        atomic::{AtomicBool, Ordering},
        Arc, Condvar, Mutex, MutexGuard,
    },
    time::{Duration, Instant},
};

use common::{
    error::ErrorKind,
    protocol::{FailReport, JoinRequest, JoinResponse, LeaseGrant, TaskResult},
};
use tokio::sync::Notify;
use worker::link::{CallError, Link};

use crate::farm::{Farm, FarmError};

/// How often an idle local worker asks again while its lease request waits for work (sooner
/// when a hand-in or the end of the service wakes it).
const POLL: Duration = Duration::from_millis(1);

/// A result that ends no job wakes the waiter at most this often: on two cores each wake-up
/// takes a core from a renderer, and the waiter only redraws a progress bar.
const WAKE_EVERY: Duration = Duration::from_millis(20);

/// Counts what the local workers hand in (results, failures, departures), so that a thread of
/// this process can sleep until the next one instead of polling the farm.
#[derive(Debug, Default)]
pub(crate) struct Handins {
    count: Mutex<Count>,
    changed: Condvar,
}

#[derive(Debug, Default)]
struct Count {
    handins: u64,
    /// When the waiter was last woken (`None`: never).
    woken: Option<Instant>,
}

impl Handins {
    /// Counts a hand-in; wakes the waiter if `ends` (it ended a job or changed membership) or
    /// if it was last woken `WAKE_EVERY` ago.
    fn bump(&self, ends: bool) {
        let mut count = self.count.lock().unwrap_or_else(|p| p.into_inner());
        count.handins += 1;
        let now = Instant::now();
        if ends || count.woken.is_none_or(|w| now.duration_since(w) >= WAKE_EVERY) {
            count.woken = Some(now);
            self.changed.notify_all();
        }
    }

    /// Sleeps up to `timeout`: less if a hand-in wakes the waiters or `draining` is (or
    /// becomes) set. Checked under the lock that `wake_all` takes, so no wake-up is lost.
    fn nap(&self, timeout: Duration, draining: &AtomicBool) {
        let count = self.count.lock().unwrap_or_else(|p| p.into_inner());
        let _ = self
            .changed
            .wait_timeout_while(count, timeout, |_| !draining.load(Ordering::Relaxed))
            .unwrap_or_else(|p| p.into_inner());
    }

    /// Wakes every thread waiting on a hand-in or napping (the service is draining).
    pub(crate) fn wake_all(&self) {
        let _count = self.count.lock().unwrap_or_else(|p| p.into_inner());
        self.changed.notify_all();
    }

    /// Waits until more than `seen` hand-ins were counted and one of them woke it, or `timeout`
    /// passed; returns the count.
    pub(crate) fn wait_past(&self, seen: u64, timeout: Duration) -> u64 {
        let count = self.count.lock().unwrap_or_else(|p| p.into_inner());
        let (count, _) = self
            .changed
            .wait_timeout_while(count, timeout, |c| c.handins <= seen)
            .unwrap_or_else(|p| p.into_inner());
        count.handins
    }
}

/// A link from local workers to a running service's farm (see [`super::Running::local_link`]).
pub struct LocalLink {
    pub(super) farm: Arc<Mutex<Farm>>,
    /// Woken when work may have appeared, for the HTTP long polls of remote workers.
    pub(super) work: Arc<Notify>,
    pub(super) draining: Arc<AtomicBool>,
    pub(super) max_lease_wait: Duration,
    pub(super) handins: Arc<Handins>,
}

impl LocalLink {
    fn lock(&self) -> MutexGuard<'_, Farm> {
        self.farm.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The farm's refusal, of the kind the HTTP API would answer with.
fn refused(e: FarmError) -> CallError {
    CallError::Refused(e.kind, e.message)
}

impl Link for LocalLink {
    fn describe(&self) -> String {
        "in-process".into()
    }

    fn join(&self, req: &JoinRequest) -> Result<JoinResponse, CallError> {
        self.lock().join(req.clone()).map_err(refused)
    }

    fn lease(&self, worker: &str, wait_s: f64) -> Result<Option<LeaseGrant>, CallError> {
        let wait = if wait_s.is_finite() { wait_s.max(0.0) } else { 0.0 };
        let deadline = Instant::now() + Duration::from_secs_f64(wait).min(self.max_lease_wait);
        loop {
            if self.draining.load(Ordering::Relaxed) {
                return Ok(None);
            }
            if let Some(grant) = self.lock().lease(worker).map_err(refused)? {
                return Ok(Some(grant));
            }
            let now = Instant::now();
            if now >= deadline {
                self.lock().seen(worker);
                return Ok(None);
            }
            self.handins.nap(POLL.min(deadline - now), &self.draining);
        }
    }

    fn scene(&self, hash: &str) -> Result<Vec<u8>, CallError> {
        let path = self.lock().scene_file(hash).map_err(refused)?;
        std::fs::read(&path).map_err(|e| {
            let message = format!("reading scene {hash} ({}): {e}", path.display());
            CallError::Refused(ErrorKind::Internal, message)
        })
    }

    fn heartbeat(&self, worker: &str, lease: &str) -> Result<(), CallError> {
        self.lock().heartbeat(lease, worker).map(|_| ()).map_err(refused)
    }

    fn submit(&self, worker: &str, lease: &str, result: TaskResult) -> Result<(), CallError> {
        let (merged, ended) = {
            let mut farm = self.lock();
            let job = farm.lease_job(lease).map(str::to_string);
            // No bytes crossed a wire: the merged-bytes counter is for results received.
            let merged = farm.submit_queued(lease, worker, result, 0);
            if let Err(e) = &merged {
                farm.result_refused();
                let reason = e.message.strip_prefix("result refused: ").unwrap_or(&e.message);
                tracing::warn!(worker, lease, kind = %e.kind, "result refused: {reason}");
            }
            (merged, job.is_none_or(|j| farm.job_ended(&j)))
        };
        // Committed outside the farm lock, with the merges queued meanwhile.
        let merged = merged.and_then(|commit| match commit {
            Some(commit) => commit.wait().map_err(|e| {
                tracing::error!("{e:#}");
                FarmError::from(e)
            }),
            None => Ok(()),
        });
        self.work.notify_waiters();
        self.handins.bump(ended);
        merged.map_err(refused)
    }

    fn fail(&self, worker: &str, lease: &str, report: &FailReport) -> Result<(), CallError> {
        let failed = self.lock().fail(lease, worker, &report.error);
        self.work.notify_waiters();
        self.handins.bump(true);
        failed.map_err(refused)
    }

    fn hands_in_inline(&self) -> bool {
        true
    }

    fn leave(&self, worker: &str) -> Result<(), CallError> {
        let left = self.lock().leave(worker);
        self.work.notify_waiters();
        self.handins.bump(true);
        left.map_err(refused)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use common::settings::RenderSettings;

    use super::*;
    use crate::{
        farm::{tests::result_for, validate_upload},
        local::bundle_scene,
        service::{spawn, ServiceConfig},
    };

    /// A waiter wakes at the hand-in, not at its timeout.
    #[test]
    fn a_handin_wakes_the_waiter() {
        let handins = Arc::new(Handins::default());
        let bumper = {
            let handins = handins.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(50));
                handins.bump(false);
            })
        };
        let asked = Instant::now();
        assert_eq!(handins.wait_past(0, Duration::from_secs(30)), 1);
        assert!(asked.elapsed() < Duration::from_secs(10), "woke only at the timeout");
        // Already past: no wait at all; nothing new: the timeout.
        assert_eq!(handins.wait_past(0, Duration::from_secs(30)), 1);
        let asked = Instant::now();
        assert_eq!(handins.wait_past(1, Duration::from_millis(20)), 1);
        assert!(asked.elapsed() >= Duration::from_millis(20));
        bumper.join().unwrap();
    }

    /// A hand-in that ends a job wakes the waiter at once, even right after another woke it
    /// (other hand-ins may wait up to `WAKE_EVERY`, but never past the waiter's timeout).
    #[test]
    fn a_handin_that_ends_a_job_always_wakes_the_waiter() {
        let handins = Arc::new(Handins::default());
        handins.bump(false);
        let bumper = {
            let handins = handins.clone();
            std::thread::spawn(move || handins.bump(true))
        };
        let asked = Instant::now();
        assert_eq!(handins.wait_past(1, Duration::from_secs(30)), 2);
        assert!(asked.elapsed() < Duration::from_secs(10), "woke only at the timeout");
        bumper.join().unwrap();
        // A hand-in that does not wake it is still counted when the waiter times out.
        handins.bump(false);
        assert_eq!(handins.wait_past(2, Duration::from_millis(50)), 3);
    }

    fn kind(e: Result<impl std::fmt::Debug, CallError>) -> ErrorKind {
        match e {
            Err(CallError::Refused(kind, _)) => kind,
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    /// The in-process link answers as the HTTP API does: the farm's checks refuse what they
    /// refuse over HTTP (and count it), a lease waits for work only as long as asked, and a
    /// draining service answers at once.
    #[test]
    fn the_local_link_keeps_the_protocol_of_the_http_api() {
        let dir = tempfile::tempdir().unwrap();
        let service = spawn("127.0.0.1:0", ServiceConfig::new(dir.path().into())).unwrap();
        let settings = RenderSettings {
            width: 8,
            height: 8,
            tile_size: 8,
            spp: 2,
            samples_per_task: 2,
            ..Default::default()
        };
        let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.gltf");
        let bundled = bundle_scene(&scene, &settings, &Default::default()).unwrap();
        let (bundle, settings) = (bundled.bytes, bundled.settings);
        let mut info = validate_upload(&bundle, None, &Default::default()).unwrap();
        let job = {
            let farm = service.farm();
            let mut farm = farm.lock().unwrap();
            farm.put_scene(&bundle, &mut info).unwrap();
            farm.create_job(&info.scene, settings, 0).unwrap().id
        };
        let link = service.local_link();
        assert_eq!(link.scene(&info.scene).unwrap(), bundle);
        assert_eq!(kind(link.scene(&"0".repeat(64))), ErrorKind::NotFound);

        let bad = JoinRequest { name: "w".into(), threads: 0, version: String::new() };
        assert_eq!(kind(link.join(&bad)), ErrorKind::Invalid);
        let w = link.join(&JoinRequest { threads: 1, ..bad }).unwrap().id;
        let grant = link.lease(&w, 0.0).unwrap().expect("the job's one task");
        link.heartbeat(&w, &grant.lease).unwrap();
        assert_eq!(kind(link.heartbeat("nobody", &grant.lease)), ErrorKind::NotFound);
        let other =
            link.join(&JoinRequest { name: "other".into(), threads: 1, version: String::new() });
        let other = other.unwrap().id;
        assert_eq!(kind(link.heartbeat(&other, &grant.lease)), ErrorKind::Forbidden);
        assert_eq!(
            kind(link.submit(&other, &grant.lease, result_for(&grant, 0.5))),
            ErrorKind::Forbidden
        );

        // A result for other samples than the lease's is refused and counted; the task stays
        // leased, and the true result is merged once.
        let mut forged = result_for(&grant, 0.5);
        forged.spec.samples.end += 1;
        assert_eq!(kind(link.submit(&w, &grant.lease, forged)), ErrorKind::Invalid);
        link.submit(&w, &grant.lease, result_for(&grant, 0.5)).unwrap();
        let again = link.submit(&w, &grant.lease, result_for(&grant, 0.5));
        assert!(
            matches!(again, Err(CallError::Refused(ErrorKind::NotFound | ErrorKind::Conflict, _))),
            "{again:?}"
        );
        {
            let farm = service.farm();
            let farm = farm.lock().unwrap();
            assert_eq!(farm.counters.results_refused, 3);
            assert_eq!(farm.status(&job).unwrap().samples_done, 64 * 2);
        }

        // No work left: the lease waits as long as asked, then answers none.
        let asked = Instant::now();
        assert!(link.lease(&w, 0.1).unwrap().is_none());
        assert!(asked.elapsed() >= Duration::from_millis(100));
        service.drain();
        let asked = Instant::now();
        assert!(link.lease(&w, 30.0).unwrap().is_none());
        assert!(asked.elapsed() < Duration::from_secs(5), "a draining service made it wait");
        link.leave(&w).unwrap();
        assert_eq!(kind(link.leave(&w)), ErrorKind::NotFound);
    }
}
