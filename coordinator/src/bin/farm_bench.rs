//! `farm_bench`: how much one coordinator can take. Starts `coordinator serve` as its own process,
//! creates a job, and feeds it pre-made results from simulated workers (threads that lease and
//! answer at once, no rendering) until the job is done. Reports tasks merged per second, MB/s of
//! results merged, the coordinator's resident memory (current and peak, from /proc) per pixel,
//! and how many real workers at a given seconds-per-task that throughput could feed.
//!
//! `cargo run --release -p coordinator --bin farm_bench -- --width 1920 --height 1080 --tile 64`

use std::{
    path::PathBuf,
    process::{Command, Stdio},
    sync::atomic::{AtomicU64, Ordering},
    time::{Duration, Instant},
};

use anyhow::{bail, Context, Result};
use clap::Parser;
use common::{
    film::{PixelSums, TileAccum},
    protocol::{encode_result, LeaseGrant, TaskResult},
};
use serde_json::{json, Value};

#[derive(Parser)]
#[command(about = "Coordinator capacity: tasks merged per second and memory per pixel")]
struct Args {
    /// Frame width.
    #[arg(long, default_value_t = 1920)]
    width: u32,
    /// Frame height.
    #[arg(long, default_value_t = 1080)]
    height: u32,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 64)]
    tile: u32,
    /// Tasks per tile (sample ranges of 16 samples).
    #[arg(long, default_value_t = 4)]
    rounds: u32,
    /// Simulated workers (threads).
    #[arg(long, default_value_t = 4)]
    clients: usize,
    /// Seconds a real worker spends per task, for the "workers fed" figure.
    #[arg(long, default_value_t = 10.0)]
    task_seconds: f64,
}

fn rss_kib(pid: u32) -> (u64, u64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// A result for `grant` as a worker would send it: 16 samples of value 0.5 in every pixel.
fn fake_result(grant: &LeaseGrant) -> Vec<u8> {
    let spec = grant.task;
    let mut pixel = PixelSums::default();
    for s in spec.samples.start..spec.samples.end {
        pixel.add(s, [0.5, 0.25, 0.125]);
    }
    let tile = TileAccum { rect: spec.rect, pixels: vec![pixel; spec.rect.area()], rejected: 0 };
    encode_result(&TaskResult { spec, tile, rays: 0 })
}

fn main() -> Result<()> {
    let args = Args::parse();
    let exe = std::env::current_exe()?;
    let coordinator = exe.with_file_name("coordinator");
    if !coordinator.exists() {
        bail!("{} not found: cargo build --release -p coordinator first", coordinator.display());
    }
    let data = tempfile::Builder::new().prefix("farm-bench-").tempdir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let url = format!("http://127.0.0.1:{port}");
    let mut child = Command::new(&coordinator)
        .args(["serve", "--listen", &format!("127.0.0.1:{port}"), "--data"])
        .arg(data.path())
        .env("RUST_LOG", std::env::var("COORDINATOR_LOG").unwrap_or_else(|_| "warn".into()))
        .stdout(Stdio::null())
        .spawn()
        .context("starting the coordinator")?;
    let pid = child.id();
    let result = run(&args, &url, pid);
    if let Ok(Some(status)) = child.try_wait() {
        eprintln!("the coordinator exited: {status}");
    }
    let _ = child.kill();
    let _ = child.wait();
    result
}

fn run(args: &Args, url: &str, pid: u32) -> Result<()> {
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
    let settings = json!({
        "width": args.width, "height": args.height, "tile_size": args.tile,
        "spp": 16 * args.rounds, "samples_per_task": 16
    });
    let job: Value = agent
        .post(&format!("{url}/api/v1/jobs"))
        .send_json(json!({"scene": scene["scene"], "settings": settings}))?
        .into_json()?;
    let id = job["id"].as_str().context("no job id")?.to_string();
    let (rss_job, _) = rss_kib(pid);
    let merged = AtomicU64::new(0);
    let bytes = AtomicU64::new(0);
    let start = Instant::now();
    std::thread::scope(|s| -> Result<()> {
        let mut handles = Vec::new();
        for i in 0..args.clients {
            let (agent, merged, bytes) = (&agent, &merged, &bytes);
            handles.push(s.spawn(move || -> Result<()> {
                let me: Value = agent
                    .post(&format!("{url}/api/v1/workers"))
                    .send_json(json!({"name": format!("sim-{i}"), "threads": 1}))?
                    .into_json()?;
                let wid = me["id"].as_str().context("no worker id")?.to_string();
                loop {
                    let resp =
                        agent.post(&format!("{url}/api/v1/workers/{wid}/lease?wait_s=0")).call()?;
                    if resp.status() == 204 {
                        return Ok(());
                    }
                    let grant: LeaseGrant = resp.into_json()?;
                    let body = fake_result(&grant);
                    if let Ok(path) = std::env::var("FARM_BENCH_DUMP") {
                        std::fs::write(&path, &body)?;
                        std::fs::write(format!("{path}.lease"), format!("{} {wid}", grant.lease))?;
                        std::thread::sleep(Duration::from_secs(3600));
                    }
                    agent
                        .post(&format!("{url}/api/v1/leases/{}/result", grant.lease))
                        .set("content-type", "application/octet-stream")
                        .set("x-worker-id", &wid)
                        .send_bytes(&body)?;
                    merged.fetch_add(1, Ordering::Relaxed);
                    bytes.fetch_add(body.len() as u64, Ordering::Relaxed);
                }
            }));
        }
        for h in handles {
            h.join().map_err(|_| anyhow::anyhow!("a client panicked"))??;
        }
        Ok(())
    })?;
    let seconds = start.elapsed().as_secs_f64();
    let status: Value = agent.get(&format!("{url}/api/v1/jobs/{id}")).call()?.into_json()?;
    if status["state"] != "done" {
        bail!("the job did not finish: {status}");
    }
    let (rss_done, peak) = rss_kib(pid);
    let fetch = Instant::now();
    let exr = agent.get(&format!("{url}/api/v1/jobs/{id}/frames/0.exr")).call()?;
    let mut exr_bytes = Vec::new();
    std::io::Read::read_to_end(&mut exr.into_reader(), &mut exr_bytes)?;
    let fetch_seconds = fetch.elapsed().as_secs_f64();
    let (_, peak_after_fetch) = rss_kib(pid);
    let tasks = merged.load(Ordering::Relaxed);
    let mb = bytes.load(Ordering::Relaxed) as f64 / 1e6;
    let pixels = args.width as f64 * args.height as f64;
    let rate = tasks as f64 / seconds;
    println!(
        "frame {}x{}, tiles {}px, {} tasks, {} simulated workers",
        args.width, args.height, args.tile, tasks, args.clients
    );
    println!(
        "merged {rate:.1} tasks/s, {:.1} MB/s of results ({:.2} MB per task), {seconds:.2} s",
        mb / seconds,
        mb / tasks as f64
    );
    println!(
        "=> feeds {:.0} workers at {} s per task",
        rate * args.task_seconds,
        args.task_seconds
    );
    println!(
        "coordinator RSS: idle {:.1} MB, job created {:.1} MB, peak while merging {:.1} MB ({:.1} B/pixel over idle), job done (sums evicted to the database) {:.1} MB; EXR fetch {fetch_seconds:.2} s, peak with the fetch {:.1} MB",
        rss_idle as f64 / 1024.0,
        rss_job as f64 / 1024.0,
        peak as f64 / 1024.0,
        peak.saturating_sub(rss_idle) as f64 * 1024.0 / pixels,
        rss_done as f64 / 1024.0,
        peak_after_fetch as f64 / 1024.0
    );
    Ok(())
}
