//! `farm_bench`: how much one coordinator can take. Starts `coordinator serve` as its own process
//! (with a join token, as a farm on a network runs), creates a job, and drives it with simulated
//! workers over real HTTP on loopback until every task is merged. Each simulated worker is a
//! thread with its own connection that does what `worker --join` does, without rendering: it
//! joins (`POST /api/v1/workers`), long-polls for a lease (`POST /api/v1/workers/{id}/lease`,
//! `--wait-s`), waits `--task-ms` in place of rendering (spread by `--task-jitter`) while it
//! renews the lease at the heartbeat interval the join answered, and hands in a pre-made result
//! (`POST /api/v1/leases/{lease}/result`, the `x-worker-id` header naming it). The clock starts
//! once every worker has joined. When the last task is merged the bench removes every worker
//! (`DELETE /api/v1/workers/{id}`, as a stopping worker leaves), which also ends the long polls
//! of the idle ones.
//!
//! Reports, per client count: tasks merged per second (over the run, and over the middle 80% of
//! the merges: the steady state), MB/s of results, p50/p99/max latency of the join, lease,
//! heartbeat and result calls (a lease that waited and found no work is counted apart), the
//! refusals and transport errors by call and status, connections the kernel dropped on a full
//! accept queue, the CPU time of the coordinator, of the bench and of the other processes (they
//! all share the machine), the coordinator's threads, and its resident memory (current and peak,
//! from /proc). Unless `--rounds` is given the job has enough rounds of tasks (16 samples each)
//! for 8 tasks per client, so that the steady state is measured. `--sweep` runs several client
//! counts, each against a fresh coordinator, and ends with a table; `--repeat` runs several jobs
//! against one coordinator (a leak shows as memory that grows from job to job).
//!
//! A thousand clients need a thousand threads (256 KiB stacks) and a socket each, here and in
//! the coordinator: `ulimit -n` is checked before starting, and the coordinator is given a
//! `--max-connections` above the client count.
//!
//! ```text
//! cargo run --release -p coordinator --bin farm_bench -- --width 1920 --height 1080 --tile 64
//! cargo run --release -p coordinator --bin farm_bench -- --clients 1000 --tile 32 --task-ms 1000
//! cargo run --release -p coordinator --bin farm_bench -- --sweep 10,100,1000 --tile 32
//! ```
//!
//! With `FARM_BENCH_DUMP=PATH` the first result is written to PATH (and its lease and worker to
//! PATH.lease) instead of being sent, and that client waits there for an hour, the coordinator
//! up: a real result to replay by hand.

use std::{
    collections::BTreeMap,
    path::{Path, PathBuf},
    process::{Child, Command, Stdio},
    sync::{
        atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering},
        Barrier, Mutex,
    },
    time::{Duration, Instant},
};

use anyhow::{bail, Context, Result};
use clap::Parser;
use common::{
    film::{PixelSums, TileAccum},
    protocol::{encode_result, JoinResponse, LeaseGrant, TaskResult, WORKER_HEADER},
};
use serde_json::{json, Value};

#[derive(Parser)]
#[command(about = "Coordinator capacity: simulated workers over HTTP, throughput, latency, memory")]
struct Args {
    /// Frame width.
    #[arg(long, default_value_t = 1920)]
    width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 1080)]
    height: u32,
    /// Tile edge in pixels (a result is about 75 bytes a pixel: 0.3 MB at 64).
    #[arg(long, default_value_t = 64)]
    tile: u32,
    /// Tasks per tile (sample ranges of 16 samples); default: enough for 8 tasks per client,
    /// and at least 4.
    #[arg(long)]
    rounds: Option<u32>,
    /// Simulated workers (threads, each a registered worker with its own connection).
    #[arg(long, default_value_t = 4)]
    clients: usize,
    /// Several client counts, one run each against a fresh coordinator (overrides --clients).
    #[arg(long, value_delimiter = ',')]
    sweep: Vec<usize>,
    /// Simulated render time per task, in milliseconds, between the lease and the result.
    #[arg(long, default_value_t = 0)]
    task_ms: u64,
    /// Spread of the render times: each task takes --task-ms times 1 + F*u, u uniform in
    /// [-1, 1] (0: every task takes the same, and workers that start together stay in step).
    #[arg(long, default_value_t = 0.0)]
    task_jitter: f64,
    /// Longest a lease request waits for work (the long poll), in seconds; `worker` waits 20.
    #[arg(long, default_value_t = 20.0)]
    wait_s: f64,
    /// The coordinator's --max-connections (default: its own 4096, or twice the clients if more).
    #[arg(long)]
    max_connections: Option<usize>,
    /// Give up on a run after this many seconds and report what was merged.
    #[arg(long, default_value_t = 240.0)]
    timeout_s: f64,
    /// Seconds a real worker spends per task, for the "workers fed" figure.
    #[arg(long, default_value_t = 10.0)]
    task_seconds: f64,
    /// Jobs run one after another against the same coordinator, per client count (memory
    /// that grows from one to the next is a leak; memory that stays is the allocator's).
    #[arg(long, default_value_t = 1)]
    repeat: u32,
}

/// The join token the bench starts the coordinator with.
const TOKEN: &str = "farm-bench-token";

/// Stack of a simulated worker's thread: it holds a few small buffers and a connection.
const CLIENT_STACK: usize = 256 << 10;

fn proc_status(pid: u32) -> String {
    std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default()
}

/// A numeric field of /proc/PID/status (`VmRSS:` in KiB, `Threads:`).
fn status_field(status: &str, name: &str) -> u64 {
    status
        .lines()
        .find(|l| l.starts_with(name))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// Resident memory of `pid` now and at its peak, in KiB.
fn rss_kib(pid: u32) -> (u64, u64) {
    let status = proc_status(pid);
    (status_field(&status, "VmRSS:"), status_field(&status, "VmHWM:"))
}

/// CPU seconds (user and system, all threads) `pid` has used; "self" for this process.
/// Assumes the usual 100 clock ticks a second.
fn cpu_seconds(pid: &str) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // The fields after the command name, which is in parentheses and may hold spaces: the
    // state is the first, utime the 12th and stime the 13th.
    let fields: Vec<&str> = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest.split_whitespace().collect())
        .unwrap_or_default();
    let ticks =
        |i: usize| fields.get(i).and_then(|v| v.parse::<u64>().ok()).unwrap_or(0) as f64 / 100.0;
    ticks(11) + ticks(12)
}

/// CPU seconds the whole machine has spent on processes (user, nice and system time) or lost to
/// the hypervisor (steal), from /proc/stat: what other processes took while the bench ran is
/// this less the coordinator's and the bench's. Interrupt time is left out: it is mostly the
/// bench's own loopback traffic.
fn machine_busy_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let Some(line) = stat.lines().find(|l| l.starts_with("cpu ")) else { return 0.0 };
    let ticks: Vec<u64> = line.split_whitespace().skip(1).filter_map(|v| v.parse().ok()).collect();
    // user nice system idle iowait irq softirq steal ...
    let busy: u64 = [0, 1, 2, 7].iter().filter_map(|&i| ticks.get(i)).sum();
    busy as f64 / 100.0
}

/// Connections the kernel dropped, machine-wide, because a listening socket's accept queue was
/// full (`TcpExt: ListenOverflows`): a client's connection attempt then waits for its SYN to be
/// sent again, a second later.
fn listen_overflows() -> u64 {
    let netstat = std::fs::read_to_string("/proc/net/netstat").unwrap_or_default();
    let mut lines = netstat.lines().filter(|l| l.starts_with("TcpExt:"));
    let (Some(names), Some(values)) = (lines.next(), lines.next()) else { return 0 };
    names
        .split_whitespace()
        .zip(values.split_whitespace())
        .find(|(n, _)| *n == "ListenOverflows")
        .and_then(|(_, v)| v.parse().ok())
        .unwrap_or(0)
}

/// The soft limit on open files of this process (the coordinator it starts inherits it).
fn open_files_limit() -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = limits.lines().find(|l| l.starts_with("Max open files"))?;
    line.split_whitespace().nth(3)?.parse().ok()
}

/// A result for `grant` as a worker would send it: 16 samples of value 0.5 in every pixel.
fn fake_result(grant: &LeaseGrant) -> Vec<u8> {
    let spec = grant.task;
    let mut pixel = PixelSums::default();
    for s in spec.samples.start..spec.samples.end {
        pixel.add(s, [0.5, 0.25, 0.125]);
    }
    let tile = TileAccum { rect: spec.rect, pixels: vec![pixel; spec.rect.area()], rejected: 0 };
    encode_result(&TaskResult { spec, tile, rays: 0, kernel: "path, scalar".into() })
}

/// What the simulated workers of one run share.
struct Shared<'a> {
    url: &'a str,
    auth: String,
    task: Duration,
    jitter: f64,
    wait_s: f64,
    /// Every client and the main thread: the clock starts once all have joined.
    joined: Barrier,
    /// Raised when the job is done (or the run gave up): clients stop.
    done: AtomicBool,
    merged: AtomicU64,
    bytes: AtomicU64,
    /// Clients still running.
    running: AtomicUsize,
    /// The ids of the workers joined, for the removal at the end.
    ids: Mutex<Vec<String>>,
    /// Merge times are measured from here.
    epoch: Instant,
}

/// What one simulated worker saw.
#[derive(Default)]
struct ClientLog {
    /// Latencies in microseconds, by call.
    join: Vec<u32>,
    lease: Vec<u32>,
    /// Lease requests that waited and found no work (their latency is the long poll).
    no_work: Vec<u32>,
    heartbeat: Vec<u32>,
    result: Vec<u32>,
    /// When each of its results was merged, in seconds since [`Shared::epoch`].
    merged_at: Vec<f64>,
    /// When each of its leases was granted, likewise.
    leased_at: Vec<f64>,
    /// Long polls that the removal of the workers at the end answered.
    ended_by_removal: u64,
    /// Failed calls by call and status ("result 409", "lease transport (Network Error)"): how
    /// many, and the first one's message.
    errors: BTreeMap<String, (u64, String)>,
}

impl ClientLog {
    fn failed(&mut self, call: &str, e: &ureq::Error) {
        let key = match e {
            ureq::Error::Status(code, _) => format!("{call} {code}"),
            ureq::Error::Transport(t) => format!("{call} transport ({})", t.kind()),
        };
        self.count(key, e.to_string());
    }

    fn count(&mut self, key: String, message: String) {
        self.errors.entry(key).or_insert((0, message)).0 += 1;
    }

    fn absorb(&mut self, other: ClientLog) {
        self.join.extend(other.join);
        self.lease.extend(other.lease);
        self.no_work.extend(other.no_work);
        self.heartbeat.extend(other.heartbeat);
        self.result.extend(other.result);
        self.merged_at.extend(other.merged_at);
        self.leased_at.extend(other.leased_at);
        self.ended_by_removal += other.ended_by_removal;
        for (k, (n, message)) in other.errors {
            self.errors.entry(k).or_insert((0, message)).0 += n;
        }
    }
}

fn micros(since: Instant) -> u32 {
    since.elapsed().as_micros().min(u32::MAX as u128) as u32
}

/// Joins; records the latency or the failure.
fn join(
    agent: &ureq::Agent,
    sh: &Shared<'_>,
    i: usize,
    log: &mut ClientLog,
) -> Option<JoinResponse> {
    let t = Instant::now();
    let answer = agent
        .post(&format!("{}/api/v1/workers", sh.url))
        .set("authorization", &sh.auth)
        .send_json(json!({"name": format!("sim-{i}"), "threads": 1, "version": "farm_bench"}));
    match answer.map(|r| r.into_json::<JoinResponse>()) {
        Ok(Ok(me)) => {
            log.join.push(micros(t));
            sh.ids.lock().unwrap().push(me.id.clone());
            Some(me)
        }
        Ok(Err(e)) => {
            log.count("join bad body".into(), e.to_string());
            None
        }
        Err(e) => {
            log.failed("join", &e);
            None
        }
    }
}

/// One simulated worker: join, then lease, wait, hand in, until the bench says stop.
fn client(i: usize, sh: &Shared<'_>) -> ClientLog {
    // One connection, kept alive, like a worker's (which keeps one per thread that calls).
    let agent = ureq::AgentBuilder::new()
        .max_idle_connections(1)
        .max_idle_connections_per_host(1)
        .timeout_connect(Duration::from_secs(5))
        .timeout_read(Duration::from_secs_f64(sh.wait_s + 60.0))
        .timeout_write(Duration::from_secs(60))
        .build();
    let mut log = ClientLog::default();
    let mut me = join(&agent, sh, i, &mut log);
    sh.joined.wait();
    while !sh.done.load(Ordering::Relaxed) {
        let Some(j) = &me else {
            std::thread::sleep(Duration::from_millis(100));
            if !sh.done.load(Ordering::Relaxed) {
                me = join(&agent, sh, i, &mut log);
            }
            continue;
        };
        let t = Instant::now();
        let answer = agent
            .post(&format!("{}/api/v1/workers/{}/lease?wait_s={}", sh.url, j.id, sh.wait_s))
            .set("authorization", &sh.auth)
            .call();
        let grant: LeaseGrant = match answer {
            Ok(r) if r.status() == 204 => {
                log.no_work.push(micros(t));
                continue;
            }
            Ok(r) => match r.into_json() {
                Ok(g) => {
                    log.lease.push(micros(t));
                    log.leased_at.push(sh.epoch.elapsed().as_secs_f64());
                    g
                }
                Err(e) => {
                    log.count("lease bad body".into(), e.to_string());
                    continue;
                }
            },
            // The bench removed this worker at the end: its long poll answers "unknown worker".
            Err(_) if sh.done.load(Ordering::Relaxed) => {
                log.ended_by_removal += 1;
                break;
            }
            Err(e) => {
                log.failed("lease", &e);
                if matches!(e, ureq::Error::Status(404, _)) {
                    me = None; // forgotten: join again, as a worker does
                } else {
                    std::thread::sleep(Duration::from_millis(100));
                }
                continue;
            }
        };
        // The render: renew the lease at the interval the join answered, as the worker does.
        let every = Duration::from_secs_f64(j.heartbeat_s.max(0.05));
        let spread = if sh.jitter > 0.0 { rand::random_range(-sh.jitter..=sh.jitter) } else { 0.0 };
        let end = Instant::now() + sh.task.mul_f64(1.0 + spread);
        loop {
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            std::thread::sleep(left.min(every));
            if Instant::now() < end {
                let t = Instant::now();
                let renewed = agent
                    .post(&format!("{}/api/v1/leases/{}/heartbeat", sh.url, grant.lease))
                    .set("authorization", &sh.auth)
                    .set(WORKER_HEADER, &j.id)
                    .call();
                match renewed {
                    Ok(_) => log.heartbeat.push(micros(t)),
                    Err(e) => log.failed("heartbeat", &e),
                }
            }
        }
        let body = fake_result(&grant);
        if let Ok(path) = std::env::var("FARM_BENCH_DUMP") {
            let _ = std::fs::write(&path, &body);
            let _ = std::fs::write(format!("{path}.lease"), format!("{} {}", grant.lease, j.id));
            std::thread::sleep(Duration::from_secs(3600));
            break;
        }
        let t = Instant::now();
        let sent = agent
            .post(&format!("{}/api/v1/leases/{}/result", sh.url, grant.lease))
            .set("authorization", &sh.auth)
            .set("content-type", "application/octet-stream")
            .set(WORKER_HEADER, &j.id)
            .send_bytes(&body);
        match sent {
            Ok(_) => {
                log.result.push(micros(t));
                log.merged_at.push(sh.epoch.elapsed().as_secs_f64());
                sh.merged.fetch_add(1, Ordering::Relaxed);
                sh.bytes.fetch_add(body.len() as u64, Ordering::Relaxed);
            }
            Err(_) if sh.done.load(Ordering::Relaxed) => break,
            Err(e) => log.failed("result", &e),
        }
    }
    log
}

/// p50, p99 and max of latencies in microseconds, in milliseconds.
struct Spread {
    n: usize,
    p50: f64,
    p99: f64,
    max: f64,
}

impl Spread {
    fn of(mut us: Vec<u32>) -> Spread {
        us.sort_unstable();
        let at = |p: f64| {
            if us.is_empty() {
                return f64::NAN;
            }
            us[((us.len() - 1) as f64 * p).round() as usize] as f64 / 1000.0
        };
        Spread { n: us.len(), p50: at(0.5), p99: at(0.99), max: at(1.0) }
    }
}

impl std::fmt::Display for Spread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.n == 0 {
            return write!(f, "none");
        }
        write!(
            f,
            "p50 {:.2} ms, p99 {:.2} ms, max {:.1} ms ({} calls)",
            self.p50, self.p99, self.max, self.n
        )
    }
}

/// What one run measured, for the sweep's table.
struct Summary {
    clients: usize,
    tasks: u64,
    rate: f64,
    steady: f64,
    mb_s: f64,
    lease: Spread,
    result: Spread,
    errors: u64,
    peak_mb: f64,
    coordinator_cores: f64,
    bench_cores: f64,
    other_cores: f64,
}

/// A running `coordinator serve`, stopped when dropped.
struct Coordinator {
    child: Child,
    url: String,
    _data: tempfile::TempDir,
}

impl Coordinator {
    fn start(exe: &Path, max_connections: usize) -> Result<Coordinator> {
        let data = tempfile::Builder::new().prefix("farm-bench-").tempdir()?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
        let child = Command::new(exe)
            .args(["serve", "--listen", &format!("127.0.0.1:{port}"), "--token", TOKEN])
            .args(["--max-connections", &max_connections.to_string(), "--data"])
            .arg(data.path())
            .env("RUST_LOG", std::env::var("COORDINATOR_LOG").unwrap_or_else(|_| "warn".into()))
            .stdout(Stdio::null())
            .spawn()
            .context("starting the coordinator")?;
        Ok(Coordinator { child, url: format!("http://127.0.0.1:{port}"), _data: data })
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        if let Ok(Some(status)) = self.child.try_wait() {
            eprintln!("the coordinator exited: {status}");
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn main() -> Result<()> {
    let args = Args::parse();
    let exe = std::env::current_exe()?.with_file_name("coordinator");
    if !exe.exists() {
        bail!("{} not found: cargo build --release -p coordinator first", exe.display());
    }
    let counts = if args.sweep.is_empty() { vec![args.clients] } else { args.sweep.clone() };
    let most = counts.iter().copied().max().unwrap_or(0);
    if let Some(limit) = open_files_limit().filter(|&l| l < most as u64 + 256) {
        bail!(
            "ulimit -n is {limit}: {most} clients need a socket each here and in the coordinator (raise it to {} or more)",
            most + 256
        );
    }
    let mut summaries = Vec::new();
    for &clients in &counts {
        let max_connections = args.max_connections.unwrap_or((2 * clients + 64).max(4096));
        let coordinator = Coordinator::start(&exe, max_connections)?;
        for _ in 0..args.repeat.max(1) {
            summaries.push(run(&args, clients, &coordinator)?);
        }
        drop(coordinator);
    }
    if summaries.len() > 1 {
        println!();
        println!("| clients | tasks | tasks/s | steady tasks/s | MB/s | lease p50 / p99 ms | result p50 / p99 ms | errors | coordinator peak MB | CPU cores coordinator / bench / others |");
        println!("|---:|---:|---:|---:|---:|---|---|---:|---:|---|");
        for s in &summaries {
            println!(
                "| {} | {} | {:.0} | {:.0} | {:.1} | {:.2} / {:.2} | {:.2} / {:.2} | {} | {:.0} | {:.2} / {:.2} / {:.2} |",
                s.clients,
                s.tasks,
                s.rate,
                s.steady,
                s.mb_s,
                s.lease.p50,
                s.lease.p99,
                s.result.p50,
                s.result.p99,
                s.errors,
                s.peak_mb,
                s.coordinator_cores,
                s.bench_cores,
                s.other_cores
            );
        }
    }
    Ok(())
}

/// One run: a job on `coordinator` driven by `clients` simulated workers.
fn run(args: &Args, clients: usize, coordinator: &Coordinator) -> Result<Summary> {
    let (url, pid) = (coordinator.url.as_str(), coordinator.pid());
    let agent = ureq::AgentBuilder::new().timeout(Duration::from_secs(120)).build();
    let end = Instant::now() + Duration::from_secs(20);
    while agent.get(&format!("{url}/healthz")).call().is_err() {
        if Instant::now() > end {
            bail!("the coordinator did not come up");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let scenes = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    let bundle = common::bundle::Bundle::pack(&[
        ("cornell-box.gltf".into(), std::fs::read(scenes.join("cornell-box.gltf"))?),
        ("cornell-box.bin".into(), std::fs::read(scenes.join("cornell-box.bin"))?),
    ])?;
    let scene: Value = agent
        .post(&format!("{url}/api/v1/scenes"))
        .set("content-type", "application/zip")
        .send_bytes(&bundle)?
        .into_json()?;
    let (rss_idle, _) = rss_kib(pid);
    let tiles = args.width.div_ceil(args.tile) as u64 * args.height.div_ceil(args.tile) as u64;
    let rounds = args.rounds.unwrap_or(((8 * clients as u64).div_ceil(tiles) as u32).max(4));
    let total = tiles * rounds as u64;
    let settings = json!({
        "width": args.width, "height": args.height, "tile_size": args.tile,
        "spp": 16 * rounds, "samples_per_task": 16
    });
    let job: Value = agent
        .post(&format!("{url}/api/v1/jobs"))
        .send_json(json!({"scene": scene["scene"], "settings": settings}))?
        .into_json()?;
    let id = job["id"].as_str().context("no job id")?.to_string();
    let (rss_job, _) = rss_kib(pid);
    let sh = Shared {
        url,
        auth: format!("Bearer {TOKEN}"),
        task: Duration::from_millis(args.task_ms),
        jitter: args.task_jitter.clamp(0.0, 1.0),
        wait_s: args.wait_s,
        joined: Barrier::new(clients + 1),
        done: AtomicBool::new(false),
        merged: AtomicU64::new(0),
        bytes: AtomicU64::new(0),
        running: AtomicUsize::new(clients),
        ids: Mutex::new(Vec::new()),
        epoch: Instant::now(),
    };
    let mut log = ClientLog::default();
    // CPU seconds of the coordinator, the bench and the machine, and the seconds they span.
    let (mut start, mut threads_peak, mut cpu) = (0.0, 0, (0.0, 0.0, 0.0, 0.0));
    let (mut timed_out, mut removal, mut released) = (false, 0.0, 0.0);
    let (mut removed, mut removal_errors) = (0, 0);
    let mut overflows = listen_overflows();
    std::thread::scope(|s| -> Result<()> {
        let mut handles = Vec::new();
        for i in 0..clients {
            let sh = &sh;
            let handle = std::thread::Builder::new()
                .name(format!("sim-{i}"))
                .stack_size(CLIENT_STACK)
                .spawn_scoped(s, move || {
                    let log = client(i, sh);
                    sh.running.fetch_sub(1, Ordering::Relaxed);
                    log
                })
                .context("starting a simulated worker")?;
            handles.push(handle);
        }
        sh.joined.wait();
        start = sh.epoch.elapsed().as_secs_f64();
        let cpu0 = (cpu_seconds(&pid.to_string()), cpu_seconds("self"), machine_busy_seconds());
        let measuring = Instant::now();
        overflows = listen_overflows().saturating_sub(overflows);
        let deadline = Instant::now() + Duration::from_secs_f64(args.timeout_s);
        loop {
            std::thread::sleep(Duration::from_millis(20));
            threads_peak = threads_peak.max(status_field(&proc_status(pid), "Threads:"));
            if sh.merged.load(Ordering::Relaxed) >= total || sh.running.load(Ordering::Relaxed) == 0
            {
                break;
            }
            if Instant::now() > deadline {
                timed_out = true;
                break;
            }
        }
        cpu = (
            cpu_seconds(&pid.to_string()) - cpu0.0,
            cpu_seconds("self") - cpu0.1,
            machine_busy_seconds() - cpu0.2,
            measuring.elapsed().as_secs_f64(),
        );
        // Stop: remove every worker, as a stopping worker leaves; the idle ones' long polls end.
        sh.done.store(true, Ordering::Relaxed);
        let stopping = Instant::now();
        let ids = std::mem::take(&mut *sh.ids.lock().unwrap());
        removed = ids.len();
        for wid in &ids {
            let left = agent
                .delete(&format!("{url}/api/v1/workers/{wid}"))
                .set("authorization", &sh.auth)
                .set(WORKER_HEADER, wid)
                .call();
            if left.is_err() {
                removal_errors += 1;
            }
        }
        removal = stopping.elapsed().as_secs_f64();
        for h in handles {
            log.absorb(h.join().map_err(|_| anyhow::anyhow!("a client panicked"))?);
        }
        released = stopping.elapsed().as_secs_f64();
        Ok(())
    })?;
    let tasks = sh.merged.load(Ordering::Relaxed);
    let mut merged_at = std::mem::take(&mut log.merged_at);
    merged_at.sort_by(f64::total_cmp);
    let last = merged_at.last().copied().unwrap_or(start);
    let last_grant = log.leased_at.iter().copied().fold(start, f64::max);
    let seconds = (last - start).max(1e-9);
    let rate = tasks as f64 / seconds;
    // The steady state: the merges from the 10th to the 90th percentile, without the ramp up
    // (every worker's first lease at once) and the tail (workers idle as the job runs out).
    let steady = if merged_at.len() >= 10 {
        let (a, b) = (merged_at.len() / 10, merged_at.len() * 9 / 10);
        (b - a) as f64 / (merged_at[b] - merged_at[a]).max(1e-9)
    } else {
        rate
    };
    let status: Value = agent.get(&format!("{url}/api/v1/jobs/{id}")).call()?.into_json()?;
    let (rss_done, peak) = rss_kib(pid);
    let fetch = Instant::now();
    let exr = agent.get(&format!("{url}/api/v1/jobs/{id}/frames/0.exr")).call();
    let fetched = exr.map_err(anyhow::Error::from).and_then(|exr| {
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut exr.into_reader(), &mut bytes)?;
        Ok(bytes.len())
    });
    let fetch_seconds = fetch.elapsed().as_secs_f64();
    let (_, peak_after_fetch) = rss_kib(pid);
    let mb = sh.bytes.load(Ordering::Relaxed) as f64 / 1e6;
    let pixels = args.width as f64 * args.height as f64;
    println!(
        "== {clients} simulated workers, {} ms per task (jitter {}), long poll {} s: frame {}x{}, tiles {}px, {rounds} rounds, {tasks} of {total} tasks merged{}",
        args.task_ms,
        args.task_jitter,
        args.wait_s,
        args.width,
        args.height,
        args.tile,
        if timed_out { " (gave up: --timeout-s)" } else { "" }
    );
    if status["state"] != "done" {
        println!("   the job did not finish: {}", status["state"]);
    }
    println!(
        "   merged {rate:.1} tasks/s ({steady:.1} in the steady state), {:.1} MB/s of results ({:.3} MB per task), {seconds:.2} s after {:.2} s of joins",
        mb / seconds,
        mb / tasks.max(1) as f64,
        start
    );
    if args.task_ms > 0 {
        let ideal = clients as f64 * 1000.0 / args.task_ms as f64;
        println!(
            "   {clients} workers at {} ms per task could hand in {ideal:.0} tasks/s: the farm kept them {:.0}% busy",
            args.task_ms,
            100.0 * rate / ideal
        );
    } else {
        println!(
            "   => feeds {:.0} workers at {} s per task",
            rate * args.task_seconds,
            args.task_seconds
        );
    }
    println!(
        "   the last lease was granted {:.2} s after the start, the last result merged {:.2} s after it",
        last_grant - start,
        (last - last_grant).max(0.0)
    );
    println!(
        "   join:      {} ({overflows} connections dropped on a full accept queue meanwhile, machine-wide)",
        Spread::of(std::mem::take(&mut log.join))
    );
    let lease = Spread::of(std::mem::take(&mut log.lease));
    println!("   lease:     {lease}");
    println!(
        "   no work:   {} (long polls that ended without work); {} more ended by the removal",
        Spread::of(std::mem::take(&mut log.no_work)),
        log.ended_by_removal
    );
    println!("   heartbeat: {}", Spread::of(std::mem::take(&mut log.heartbeat)));
    let result = Spread::of(std::mem::take(&mut log.result));
    println!("   result:    {result}");
    let errors: u64 = log.errors.values().map(|(n, _)| n).sum();
    if errors == 0 {
        println!("   errors: none");
    }
    for (k, (n, message)) in &log.errors {
        println!("   errors: {k}: {n}, the first: {message}");
    }
    println!(
        "   stop: {removed} workers removed in {removal:.2} s ({removal_errors} refused), every client ended {released:.2} s after the stop"
    );
    let cores = |seconds: f64| seconds / cpu.3.max(1e-9);
    let (coordinator_cores, bench_cores) = (cores(cpu.0), cores(cpu.1));
    let others = cores((cpu.2 - cpu.0 - cpu.1).max(0.0));
    println!(
        "   CPU: coordinator {:.1} s ({coordinator_cores:.2} cores), bench {:.1} s ({bench_cores:.2} cores), other processes {others:.2} cores, of {}; coordinator threads at most {threads_peak}",
        cpu.0,
        cpu.1,
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0)
    );
    println!(
        "   coordinator RSS: before the job {:.1} MB, job created {:.1} MB, peak while merging {:.1} MB ({:.1} B/pixel over idle), job done {:.1} MB; EXR fetch {fetch_seconds:.2} s{}, peak with the fetch {:.1} MB",
        rss_idle as f64 / 1024.0,
        rss_job as f64 / 1024.0,
        peak as f64 / 1024.0,
        peak.saturating_sub(rss_idle) as f64 * 1024.0 / pixels,
        rss_done as f64 / 1024.0,
        match fetched {
            Ok(_) => String::new(),
            Err(e) => format!(" (failed: {e})"),
        },
        peak_after_fetch as f64 / 1024.0
    );
    Ok(Summary {
        clients,
        tasks,
        rate,
        steady,
        mb_s: mb / seconds,
        lease,
        result,
        errors,
        peak_mb: peak as f64 / 1024.0,
        coordinator_cores,
        bench_cores,
        other_cores: others,
    })
}
