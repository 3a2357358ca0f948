//! The worker's loop, the same for `worker --join URL` (over HTTP) and for the local workers of
//! `coordinator render` (linked in-process): see [`crate::link`].
//!
//! Join, then loop: long-poll for a lease, fetch and cache the scene by hash (the BVH is built
//! once per scene and settings, not per task), render the task on all threads while another
//! thread renews the lease, and hand the partial sums in. While a short task renders, the next
//! one is already leased, and the last result is sent on a thread of its own. The worker keeps
//! nothing that matters: if it dies, its lease expires and the task goes to another worker.
//! When the coordinator forgets it (a restart), it joins again; when the coordinator is
//! unreachable, it retries with a growing pause. After `stop` is raised it finishes the task in
//! hand, sends it, leaves, and returns.

use std::{
    sync::{
        atomic::{AtomicBool, Ordering},
        Arc, Condvar, Mutex,
    },
    time::{Duration, Instant},
};

use anyhow::{bail, Result};
use common::{
    bundle::Bundle,
    envmap::EnvMap,
    error::ErrorKind,
    protocol::{FailReport, JoinRequest, JoinResponse, LeaseGrant, TaskKind, TaskResult},
    scene::Scene,
    settings::{Environment, Integrator},
};

use crate::{
    link::{CallError, HttpLink, Link},
    render::{
        bvh_cache::BvhCache,
        render_task_threads,
        scene::{prepare_frame_cached, PreparedScene},
    },
};

/// How a worker works, whatever links it to its coordinator.
#[derive(Clone, Debug)]
pub struct WorkerOptions {
    /// Render threads.
    pub threads: usize,
    /// Render threads for a task over the whole frame (a light task, a photon-mapping task;
    /// the same bits on any count): more than `threads` where one-thread workers of one process
    /// share the machine and such tasks come one at a time (adaptive sampling), the other
    /// workers then rendering what else there is, or idle. Usually `threads`.
    pub whole_frame_threads: usize,
    /// Name shown in the workers list.
    pub name: String,
    /// Longest a lease request waits for work, in seconds.
    pub wait_s: f64,
    /// While a task renders, the next one is leased ahead when the last task took less than
    /// this (the round trip is then worth hiding); a longer task is not followed by one held
    /// back from idle workers. Zero never leases ahead.
    pub prefetch_below: Duration,
}

/// How `worker --join` joins.
#[derive(Clone, Debug)]
pub struct JoinConfig {
    /// Base URL of the coordinator (`http://host:port`).
    pub url: String,
    /// The coordinator's join token, sent as a bearer token on every request.
    pub token: Option<String>,
    /// How the worker works.
    pub options: WorkerOptions,
    /// The most bytes of built BVHs the worker keeps for later jobs (`BvhCache`).
    pub bvh_cache_bytes: usize,
}

/// The default of [`WorkerOptions::prefetch_below`]: far above a round trip, so that what a
/// task held back can cost an idle worker stays small.
pub const PREFETCH_BELOW: Duration = Duration::from_millis(500);

/// What a worker did before it stopped.
#[derive(Clone, Debug, Default)]
pub struct WorkerStats {
    /// Results the coordinator merged.
    pub merged: u64,
    /// Results it refused (stale leases and the like).
    pub refused: u64,
}

/// Why a task could not be prepared; only a permanent failure is reported against the task.
struct Failure {
    transient: bool,
    message: String,
}

impl Failure {
    fn permanent(message: String) -> Self {
        Failure { transient: false, message }
    }
}

/// A scene as loaded, with its environment map.
struct Loaded {
    key: String,
    scene: Arc<Scene>,
    env: Option<Arc<EnvMap>>,
}

/// A scene its caller has loaded already: the bundle's hash, the scene, and the environment map
/// that the bundle holds under a name, if any ([`SceneCache::seeded`]).
struct Seed {
    hash: String,
    scene: Arc<Scene>,
    env: Option<(String, Arc<EnvMap>)>,
}

/// The scenes a worker has prepared, most recent first (a few jobs, or a few frames of an
/// animation, at once), keyed by (scene, settings) and, for animated scenes, frame. Below them it
/// keeps the last scene loaded, for later jobs of the same scene and environment map (other
/// settings do not change what is loaded), and the BVHs built (`BvhCache`, bounded by
/// `--bvh-cache-mib`). Workers of one process can share one cache, so that the scene and its
/// BVH are held once however many of them run; a worker that needs a scene another is preparing
/// waits for it instead of building twice.
#[derive(Default)]
pub struct SceneCache {
    entries: Mutex<Vec<(String, Arc<PreparedScene>)>>,
    /// The BVHs built so far, by their triangles: a job whose settings differ from an earlier
    /// one's (samples, size, seed, integrator, lights) is prepared again but builds no BVH.
    bvh: BvhCache,
    loaded: Mutex<Option<Arc<Loaded>>>,
    seed: Option<Seed>,
    /// Scenes prepared so far (readable while one is being prepared).
    prepared: std::sync::atomic::AtomicUsize,
}

impl SceneCache {
    const CAPACITY: usize = 4;

    /// A cache that holds the scene of the bundle with hash `hash` as its caller loaded it (and
    /// `env`, the environment map the bundle holds under that name), so that workers in the
    /// caller's process take it instead of decoding the bundle again: `coordinator render`
    /// loads the scene from its files to bundle it, and its in-process workers render that
    /// bundle. The bundle holds the same bytes, so the scene is the one they would load.
    pub fn seeded(hash: String, scene: Scene, env: Option<(String, EnvMap)>) -> Self {
        let env = env.map(|(name, map)| (name, Arc::new(map)));
        SceneCache { seed: Some(Seed { hash, scene: Arc::new(scene), env }), ..Default::default() }
    }

    /// A cache that keeps at most `bytes` of built BVHs for later jobs.
    pub fn with_bvh_cache(bytes: usize) -> Self {
        SceneCache { bvh: BvhCache::new(bytes), ..Default::default() }
    }

    /// BVHs built so far, and those taken from the cache instead.
    pub fn bvh_builds_and_hits(&self) -> (usize, usize) {
        (self.bvh.builds(), self.bvh.hits())
    }

    /// How many scenes (or frames of an animated one) this cache has prepared so far.
    pub fn scenes_prepared(&self) -> usize {
        self.prepared.load(Ordering::Relaxed)
    }

    fn load(&self, link: &dyn Link, grant: &LeaseGrant, key: &str) -> Result<Arc<Loaded>, Failure> {
        let mut loaded = self.loaded.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(l) = loaded.as_ref().filter(|l| l.key == key) {
            return Ok(l.clone());
        }
        if let Some(seed) = self.seed.as_ref().filter(|s| s.hash == grant.scene) {
            let env = match &grant.settings.environment {
                Some(Environment::Map { map, .. }) => match &seed.env {
                    Some((name, env)) if name == map => Some(Some(env.clone())),
                    _ => None,
                },
                _ => Some(None),
            };
            // Another map than the seed's (not what `coordinator render` makes): loaded below.
            if let Some(env) = env {
                let l = Arc::new(Loaded { key: key.to_string(), scene: seed.scene.clone(), env });
                *loaded = Some(l.clone());
                return Ok(l);
            }
        }
        let bytes = link.scene(&grant.scene).map_err(|e| Failure {
            // Only the scene itself is worth reporting: a network error is not the task's.
            transient: matches!(
                e,
                CallError::Transport(_)
                    | CallError::Refused(ErrorKind::Internal | ErrorKind::Busy, _)
            ),
            message: format!("fetching scene {}: {e}", grant.scene),
        })?;
        let bundle = Bundle::open(&bytes, &grant.scene_budget)
            .map_err(|e| Failure::permanent(format!("scene {}: {e}", grant.scene)))?;
        let scene = bundle
            .load_scene_spread(&crate::spread::Threads::available())
            .map_err(|e| Failure::permanent(format!("scene {}: {e}", grant.scene)))?;
        let env = match &grant.settings.environment {
            Some(Environment::Map { map, .. }) => Some(
                bundle
                    .load_envmap(map)
                    .map_err(|e| Failure::permanent(format!("settings.environment.map: {e}")))?,
            ),
            _ => None,
        };
        let l = Arc::new(Loaded {
            key: key.to_string(),
            scene: Arc::new(scene),
            env: env.map(Arc::new),
        });
        *loaded = Some(l.clone());
        Ok(l)
    }

    fn get_or_prepare(
        &self,
        link: &dyn Link,
        grant: &LeaseGrant,
    ) -> Result<Arc<PreparedScene>, Failure> {
        let mut entries = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        let base = format!(
            "{}/{}",
            grant.scene,
            serde_json::to_string(&grant.settings)
                .map_err(|e| Failure::permanent(e.to_string()))?
        );
        let frame_key = format!("{base}#{}", grant.task.frame);
        for key in [&frame_key, &base] {
            if let Some(i) = entries.iter().position(|(k, _)| k == key) {
                let entry = entries.remove(i);
                entries.insert(0, entry.clone());
                return Ok(entry.1);
            }
        }
        let start = Instant::now();
        // The scene as loaded depends on the bundle and the environment map it names, not on
        // the other settings: a later job with other settings takes it as it is.
        let map = match &grant.settings.environment {
            Some(Environment::Map { map, .. }) => Some(map.as_str()),
            _ => None,
        };
        let loaded = self.load(link, grant, &format!("{}/{map:?}", grant.scene))?;
        // An animated scene is posed and prepared per frame; a static one once.
        let animated = loaded.scene.is_animated();
        let scene = &loaded.scene;
        let prepared = prepare_frame_cached(
            scene,
            &grant.settings,
            loaded.env.as_deref(),
            grant.task.frame,
            &self.bvh,
        )
        .map_err(|e| Failure::permanent(format!("preparing scene {}: {e}", grant.scene)))?;
        let key = if animated { frame_key } else { base };
        tracing::info!(
            scene = %grant.scene,
            triangles = scene.triangle_count(),
            seconds = start.elapsed().as_secs_f64(),
            frame = grant.task.frame,
            kernel = crate::render::kernel(&prepared),
            "scene prepared"
        );
        let prepared = Arc::new(prepared);
        entries.insert(0, (key, prepared.clone()));
        entries.truncate(Self::CAPACITY);
        self.prepared.fetch_add(1, Ordering::Relaxed);
        Ok(prepared)
    }
}

/// Joins the coordinator at `config.url` over HTTP and renders tasks until `stop` is raised (then leaves
/// cleanly). Returns an error only for what retrying cannot fix (the coordinator refuses the
/// join).
pub fn run(config: &JoinConfig, stop: &Arc<AtomicBool>) -> Result<WorkerStats> {
    let link = HttpLink::new(&config.url, config.token.as_deref(), config.options.wait_s)
        .stop_waiting_on(stop.clone());
    run_linked(&link, &config.options, stop, &SceneCache::with_bvh_cache(config.bvh_cache_bytes))
}

/// [`run`] over any link, with a scene cache shared with other workers of this process.
pub fn run_linked(
    link: &dyn Link,
    options: &WorkerOptions,
    stop: &AtomicBool,
    cache: &SceneCache,
) -> Result<WorkerStats> {
    let request = JoinRequest {
        name: options.name.clone(),
        threads: options.threads as u32,
        version: env!("CARGO_PKG_VERSION").to_string(),
    };
    // Four threads: one leases (and keeps the next task ready while this one renders, so the
    // round trip to the coordinator is hidden), one renders, one sends results (at most one
    // waits while another is being sent), one renews the leases held. Over an in-process link,
    // whose calls cost less than waking a thread, the leasing thread renders each task and
    // hands its result in itself, and only the renewer runs beside it.
    let renewer = Renewer::default();
    std::thread::scope(|s| -> Result<WorkerStats> {
        let renewer = &renewer;
        let renewing = s.spawn(move || renewer.run(link));
        // On every way out of here, a panic of the leasing or rendering thread included, the
        // renewer stops: otherwise it would keep renewing leases that nobody renders (the
        // coordinator would never hand those tasks to another worker) and the scope would wait
        // for it forever.
        let stop_renewing = QuitOnDrop(renewer);
        let (me, stats) = if link.hands_in_inline() {
            let mut stats = WorkerStats::default();
            let mut deliver = |g: Granted<'_>| -> Result<()> {
                if let Some(out) = render_granted(link, options, cache, g) {
                    hand_in(link, out, &mut stats);
                }
                Ok(())
            };
            let me = lease_loop(options, stop, link, &request, &mut deliver, renewer);
            (me, stats)
        } else {
            let (outbox, inbox) = std::sync::mpsc::sync_channel::<Outgoing>(1);
            let sender = s.spawn(move || {
                let mut stats = WorkerStats::default();
                for out in inbox {
                    hand_in(link, out, &mut stats);
                }
                stats
            });
            // A rendezvous: a grant is handed over only when the renderer takes it.
            let (grants, granted) = std::sync::mpsc::sync_channel::<Granted<'_>>(0);
            let (finished, render_times) = std::sync::mpsc::channel::<Duration>();
            let renderer = s.spawn(move || {
                for g in granted {
                    let start = Instant::now();
                    let out = render_granted(link, options, cache, g);
                    let _ = finished.send(start.elapsed());
                    if out.is_some_and(|out| outbox.send(out).is_err()) {
                        return;
                    }
                }
            });
            // Unknown until a task has rendered: no lease ahead of the first one.
            let mut last_render = Duration::MAX;
            // Owns the rendezvous: dropping it after the loop ends the renderer's queue.
            let mut deliver = move |g| -> Result<()> {
                if grants.send(g).is_err() {
                    bail!("the renderer stopped");
                }
                // The renderer has taken this task, so it has finished every earlier one.
                last_render = render_times.try_iter().last().unwrap_or(last_render);
                if last_render >= options.prefetch_below {
                    last_render = render_times.recv().unwrap_or(last_render);
                }
                Ok(())
            };
            let me = lease_loop(options, stop, link, &request, &mut deliver, renewer);
            drop(deliver);
            renderer.join().expect("the renderer panicked");
            (me, sender.join().expect("the result sender panicked"))
        };
        drop(stop_renewing);
        renewing.join().expect("the lease renewer panicked");
        if let Some(j) = me? {
            match link.leave(&j.id) {
                Ok(()) => tracing::info!(worker = %j.id, "left the farm"),
                Err(e) => tracing::warn!("leaving: {e}"),
            }
        }
        Ok(stats)
    })
}

/// Stops a `Renewer` when dropped.
struct QuitOnDrop<'a>(&'a Renewer);

impl Drop for QuitOnDrop<'_> {
    fn drop(&mut self) {
        self.0.quit();
    }
}

/// A rendered result on its way to the coordinator.
struct Outgoing {
    worker: String,
    lease: String,
    result: TaskResult,
}

/// A leased task on its way to the renderer, its lease already being renewed.
struct Granted<'a> {
    worker: String,
    grant: LeaseGrant,
    renewing: Renewing<'a>,
}

/// The leasing loop: joins, leases and hands each grant to `deliver` (the renderer's rendezvous,
/// or rendering it on this thread) until `stop`. Returns the membership to leave with.
fn lease_loop<'a>(
    options: &WorkerOptions,
    stop: &AtomicBool,
    link: &dyn Link,
    request: &JoinRequest,
    deliver: &mut dyn FnMut(Granted<'a>) -> Result<()>,
    renewer: &'a Renewer,
) -> Result<Option<JoinResponse>> {
    let mut me: Option<JoinResponse> = None;
    let mut backoff = Duration::from_millis(200);
    while !stop.load(Ordering::Relaxed) {
        let Some(joined) = &me else {
            match link.join(request) {
                Ok(j) => {
                    tracing::info!(worker = %j.id, coordinator = %link.describe(), "joined");
                    me = Some(j);
                    backoff = Duration::from_millis(200);
                }
                Err(CallError::Refused(kind, msg))
                    if !matches!(kind, ErrorKind::Internal | ErrorKind::Busy) =>
                {
                    bail!("the coordinator refused to let this worker join ({kind}): {msg}");
                }
                Err(e) => {
                    tracing::warn!("joining: {e}; retrying in {backoff:?}");
                    pause(stop, backoff);
                    backoff = (backoff * 2).min(Duration::from_secs(5));
                }
            }
            continue;
        };
        let worker = joined.id.clone();
        let heartbeat = Duration::from_secs_f64(joined.heartbeat_s.max(0.05));
        let asked = Instant::now();
        match link.lease(&worker, options.wait_s) {
            Ok(None) => {}
            Ok(Some(grant)) => {
                backoff = Duration::from_millis(200);
                let leased = asked.elapsed();
                // Renewed from the start: the task may wait for the renderer, and fetching
                // and preparing a scene can take longer than the lease.
                let renewing = renewer.begin(&worker, &grant.lease, heartbeat);
                tracing::trace!(lease_s = leased.as_secs_f64(), "task leased");
                deliver(Granted { worker, grant, renewing })?;
            }
            Err(CallError::Refused(ErrorKind::NotFound, msg)) => {
                tracing::info!("coordinator forgot this worker ({msg}); joining again");
                me = None;
            }
            Err(e) => {
                tracing::warn!("leasing: {e}; retrying in {backoff:?}");
                pause(stop, backoff);
                backoff = (backoff * 2).min(Duration::from_secs(5));
            }
        }
    }
    Ok(me)
}

/// Sleeps up to `d`, waking early when `stop` is raised.
fn pause(stop: &AtomicBool, d: Duration) {
    let end = Instant::now() + d;
    while !stop.load(Ordering::Relaxed) && Instant::now() < end {
        std::thread::sleep(Duration::from_millis(50).min(end - Instant::now()));
    }
}

/// Renews the leases a worker holds (the task rendering and the one waiting for it) while they
/// are prepared and rendered: one thread for the worker's whole life (a thread per task costs
/// more than a small task's render).
#[derive(Default)]
struct Renewer {
    state: Mutex<RenewState>,
    changed: Condvar,
}

#[derive(Default)]
struct RenewState {
    held: Vec<Renewal>,
    quit: bool,
    /// When the renewing thread looks at `held` again by itself: `None` while it waits for a
    /// change without a timeout (or has not started). A lease due later needs no wake-up.
    looks_by: Option<Instant>,
}

struct Renewal {
    worker: String,
    lease: String,
    every: Duration,
    /// When it was last renewed (or taken).
    renewed: Instant,
    lost: Arc<AtomicBool>,
}

/// A lease being renewed until this is ended or dropped.
struct Renewing<'a> {
    renewer: &'a Renewer,
    lease: String,
    lost: Arc<AtomicBool>,
}

impl Renewing<'_> {
    /// Stops renewing; returns whether the coordinator said the lease was lost meanwhile.
    fn end(self) -> bool {
        self.lost.load(Ordering::Relaxed)
    }
}

impl Drop for Renewing<'_> {
    fn drop(&mut self) {
        // No wake-up: the renewing thread finds the lease gone when it next looks.
        self.renewer.lock().held.retain(|r| r.lease != self.lease);
    }
}

impl Renewer {
    fn lock(&self) -> std::sync::MutexGuard<'_, RenewState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn update(&self, f: impl FnOnce(&mut RenewState)) {
        f(&mut self.lock());
        self.changed.notify_all();
    }

    fn begin(&self, worker: &str, lease: &str, every: Duration) -> Renewing<'_> {
        let lost = Arc::new(AtomicBool::new(false));
        let renewal = Renewal {
            worker: worker.to_string(),
            lease: lease.to_string(),
            every,
            renewed: Instant::now(),
            lost: lost.clone(),
        };
        let due = renewal.renewed + every;
        let mut st = self.lock();
        st.held.push(renewal);
        // Woken only if it would otherwise look too late: a thread per task's hand-offs cost
        // a short task more than its render.
        if st.looks_by.is_none_or(|t| t > due) {
            self.changed.notify_all();
        }
        drop(st);
        Renewing { renewer: self, lease: lease.to_string(), lost }
    }

    fn quit(&self) {
        self.update(|st| st.quit = true);
    }

    /// The renewing thread: a heartbeat for each lease held, every `every` since it was taken or
    /// last renewed.
    fn run(&self, link: &dyn Link) {
        let mut st = self.lock();
        while !st.quit {
            let now = Instant::now();
            // A lease the coordinator called lost is not asked about again.
            let live = st.held.iter_mut().filter(|r| !r.lost.load(Ordering::Relaxed));
            let Some(r) = live.min_by_key(|r| r.renewed + r.every) else {
                st.looks_by = None;
                st = self.changed.wait(st).unwrap_or_else(|p| p.into_inner());
                st.looks_by = Some(Instant::now());
                continue;
            };
            let due = r.renewed + r.every;
            if due > now {
                st.looks_by = Some(due);
                st = self.changed.wait_timeout(st, due - now).unwrap_or_else(|p| p.into_inner()).0;
                st.looks_by = Some(Instant::now());
                continue;
            }
            r.renewed = now;
            let (worker, lease, lost) = (r.worker.clone(), r.lease.clone(), r.lost.clone());
            drop(st);
            match link.heartbeat(&worker, &lease) {
                Ok(()) => {}
                Err(CallError::Refused(
                    kind @ (ErrorKind::Forbidden | ErrorKind::NotFound | ErrorKind::Conflict),
                    msg,
                )) => {
                    tracing::warn!(lease = %lease, "lease lost ({kind}: {msg})");
                    lost.store(true, Ordering::Relaxed);
                }
                Err(e) => tracing::warn!(lease = %lease, "heartbeat: {e}"),
            }
            st = self.lock();
        }
    }
}

/// Renders one leased task. Ok(None): the lease was lost meanwhile
/// (nothing to send).
fn render(
    link: &dyn Link,
    worker: &str,
    grant: &LeaseGrant,
    threads: usize,
    cache: &SceneCache,
    renewal: Renewing<'_>,
) -> Result<Option<TaskResult>, String> {
    let rendered = cache.get_or_prepare(link, grant).map(|prepared| {
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            render_task_threads(&prepared, grant.settings.seed, &grant.task, threads)
        }))
    });
    let lost = renewal.end();
    let rendered = match rendered {
        Ok(r) => r,
        Err(Failure { transient: true, message }) => {
            // Not the task's fault: let the lease lapse (or be renewed by nobody) and go on.
            return Err(format!("{message}; the task is left to its lease timeout"));
        }
        Err(Failure { transient: false, message }) => {
            let report = FailReport { error: message.clone() };
            let _ = link.fail(worker, &grant.lease, &report);
            return Err(message);
        }
    };
    let result = match rendered {
        Ok(r) => r,
        Err(panic) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            let report = FailReport { error: format!("the renderer panicked: {msg}") };
            let _ = link.fail(worker, &grant.lease, &report);
            return Err(report.error);
        }
    };
    if lost {
        return Ok(None);
    }
    Ok(Some(result))
}

/// Renders a granted task; the result to hand in, if there is one (none when the lease was lost
/// or the task failed, which `render` has reported).
fn render_granted(
    link: &dyn Link,
    options: &WorkerOptions,
    cache: &SceneCache,
    g: Granted<'_>,
) -> Option<Outgoing> {
    let whole_frame =
        g.grant.task.kind == TaskKind::Light || g.grant.settings.integrator == Integrator::Sppm;
    let threads = if whole_frame { options.whole_frame_threads } else { options.threads };
    match render(link, &g.worker, &g.grant, threads, cache, g.renewing) {
        Ok(Some(result)) => Some(Outgoing { worker: g.worker, lease: g.grant.lease, result }),
        Ok(None) => None,
        Err(e) => {
            tracing::warn!(lease = %g.grant.lease, "{e}");
            None
        }
    }
}

/// Hands a result in and counts the answer.
fn hand_in(link: &dyn Link, out: Outgoing, stats: &mut WorkerStats) {
    match link.submit(&out.worker, &out.lease, out.result) {
        Ok(()) => stats.merged += 1,
        Err(CallError::Refused(ErrorKind::Conflict | ErrorKind::NotFound, msg)) => {
            tracing::info!(lease = %out.lease, "result not needed any more: {msg}");
            stats.refused += 1;
        }
        Err(CallError::Refused(kind, msg)) => {
            tracing::warn!(lease = %out.lease, "result refused ({kind}): {msg}");
        }
        Err(e) => tracing::warn!(lease = %out.lease, "sending the result: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A coordinator link that lets the worker join and then fails inside the lease call.
    struct PanicOnLease;

    impl Link for PanicOnLease {
        fn describe(&self) -> String {
            "a link that panics".into()
        }
        fn join(&self, _: &JoinRequest) -> Result<JoinResponse, CallError> {
            Ok(JoinResponse { id: "w".into(), lease_timeout_s: 30.0, heartbeat_s: 10.0 })
        }
        fn lease(&self, _: &str, _: f64) -> Result<Option<LeaseGrant>, CallError> {
            panic!("lease exploded")
        }
        fn scene(&self, _: &str) -> Result<Vec<u8>, CallError> {
            unreachable!("nothing was leased")
        }
        fn heartbeat(&self, _: &str, _: &str) -> Result<(), CallError> {
            Ok(())
        }
        fn submit(&self, _: &str, _: &str, _: TaskResult) -> Result<(), CallError> {
            unreachable!("nothing was leased")
        }
        fn fail(&self, _: &str, _: &str, _: &FailReport) -> Result<(), CallError> {
            unreachable!("nothing was leased")
        }
        fn leave(&self, _: &str) -> Result<(), CallError> {
            Ok(())
        }
    }

    /// A link that serves one scene bundle and counts how often it was asked for it.
    struct Serves {
        bundle: Vec<u8>,
        fetched: std::sync::atomic::AtomicUsize,
    }

    impl Link for Serves {
        fn describe(&self) -> String {
            "a link that serves one scene".into()
        }
        fn join(&self, _: &JoinRequest) -> Result<JoinResponse, CallError> {
            unreachable!()
        }
        fn lease(&self, _: &str, _: f64) -> Result<Option<LeaseGrant>, CallError> {
            unreachable!()
        }
        fn scene(&self, _: &str) -> Result<Vec<u8>, CallError> {
            self.fetched.fetch_add(1, Ordering::Relaxed);
            Ok(self.bundle.clone())
        }
        fn heartbeat(&self, _: &str, _: &str) -> Result<(), CallError> {
            unreachable!()
        }
        fn submit(&self, _: &str, _: &str, _: TaskResult) -> Result<(), CallError> {
            unreachable!()
        }
        fn fail(&self, _: &str, _: &str, _: &FailReport) -> Result<(), CallError> {
            unreachable!()
        }
        fn leave(&self, _: &str) -> Result<(), CallError> {
            unreachable!()
        }
    }

    /// A lease of a one-sample 4x4 task of frame 0 of scene `hash` under `settings`.
    fn grant_of(hash: &str, settings: common::settings::RenderSettings) -> LeaseGrant {
        LeaseGrant {
            lease: "l".into(),
            job: "j".into(),
            scene: hash.into(),
            settings,
            task: common::protocol::TaskSpec {
                frame: 0,
                rect: common::film::Rect { x0: 0, y0: 0, width: 4, height: 4 },
                samples: common::protocol::SampleRange { start: 0, end: 1 },
                kind: common::protocol::TaskKind::Camera,
            },
            lease_timeout_s: 30.0,
            scene_budget: Default::default(),
        }
    }

    /// A seeded cache prepares the scene it holds without fetching or decoding the bundle, and
    /// the prepared scene is the one the bundle gives; a job of another scene, or one that asks
    /// for another environment map, loads from the link as before.
    #[test]
    fn a_seeded_cache_takes_its_scene_and_loads_any_other() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.glb");
        let bundle = std::fs::read(&path).unwrap();
        let scene = common::gltf::load_path(&path).unwrap();
        let grant = |hash: &str, environment| {
            grant_of(hash, common::settings::RenderSettings { environment, ..Default::default() })
        };
        let link = Serves { bundle, fetched: Default::default() };
        let seeded = SceneCache::seeded("abc".into(), scene, None);
        let from_seed = seeded.get_or_prepare(&link, &grant("abc", None)).ok().unwrap();
        assert_eq!(link.fetched.load(Ordering::Relaxed), 0, "the seed's scene was fetched");
        let plain = SceneCache::default();
        let from_link = plain.get_or_prepare(&link, &grant("abc", None)).ok().unwrap();
        assert_eq!(link.fetched.load(Ordering::Relaxed), 1);
        assert_eq!(from_seed.shading.len(), from_link.shading.len());
        assert_eq!(format!("{:?}", from_seed.materials), format!("{:?}", from_link.materials));
        // Another scene, and a map the seed does not hold: from the link.
        seeded.get_or_prepare(&link, &grant("def", None)).ok().unwrap();
        assert_eq!(link.fetched.load(Ordering::Relaxed), 2);
        let sky = Some(Environment::Map {
            map: "sky.hdr".into(),
            intensity: 1.0,
            rotation_deg: 0.0,
            visible: true,
        });
        let refused = seeded.get_or_prepare(&link, &grant("abc", sky)).err().unwrap();
        assert!(refused.message.contains("sky.hdr"), "{}", refused.message);
        assert_eq!(link.fetched.load(Ordering::Relaxed), 3);
    }

    /// Jobs of one scene with other settings (samples, size, seed, integrator) are prepared
    /// again from the scene as first fetched and loaded, and take the first job's BVH; a cache
    /// of no bytes builds it every time.
    #[test]
    fn jobs_of_one_scene_share_its_bvh() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/cornell-box.glb");
        let bundle = std::fs::read(&path).unwrap();
        let grant = |settings| grant_of("abc", settings);
        let jobs = [
            common::settings::RenderSettings::default(),
            common::settings::RenderSettings { spp: 7, seed: 3, width: 40, ..Default::default() },
            common::settings::RenderSettings {
                integrator: common::settings::Integrator::Bdpt,
                ..Default::default()
            },
        ];
        let link = Serves { bundle, fetched: Default::default() };
        let cache = SceneCache::default();
        let prepared: Vec<_> = jobs
            .iter()
            .map(|s| cache.get_or_prepare(&link, &grant(s.clone())).ok().unwrap())
            .collect();
        assert_eq!(cache.scenes_prepared(), 3);
        assert_eq!(link.fetched.load(Ordering::Relaxed), 1, "the scene was fetched again");
        assert_eq!(cache.bvh_builds_and_hits(), (1, 2));
        assert!(prepared.iter().all(|p| Arc::ptr_eq(&p.accel, &prepared[0].accel)));
        let none = SceneCache::with_bvh_cache(0);
        for s in &jobs {
            none.get_or_prepare(&link, &grant(s.clone())).ok().unwrap();
        }
        assert_eq!(none.bvh_builds_and_hits(), (3, 0));
    }

    /// A panic in the worker loop ends `run_linked` (the panic reaches its caller) instead of
    /// leaving the lease renewer, and so the whole worker, waiting forever.
    #[test]
    fn a_panic_in_the_worker_loop_ends_the_worker() {
        let (done, ended) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let options = WorkerOptions {
                threads: 1,
                whole_frame_threads: 1,
                name: "test".into(),
                wait_s: 0.1,
                prefetch_below: PREFETCH_BELOW,
            };
            let stop = AtomicBool::new(false);
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                run_linked(&PanicOnLease, &options, &stop, &SceneCache::default())
            }));
            let _ = done.send(outcome.is_err());
        });
        let panicked = ended.recv_timeout(Duration::from_secs(60));
        assert_eq!(panicked, Ok(true), "run_linked hung or returned without the panic");
    }
}
