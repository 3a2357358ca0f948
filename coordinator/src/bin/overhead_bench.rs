//! `overhead_bench`: what the farm costs over one process. Times `coordinator render --workers N`
//! against `coordinator serve` with N separate `worker --join --threads 1` processes rendering the
//! same job (timed from job creation to the fetched EXR; the workers have joined beforehand, as
//! on a farm), checks that both images are identical, and prints the ratio (median of runs).
//!
//! `cargo run --release -p coordinator --bin overhead_bench -- --spp 256 --workers 2 --runs 3`

use std::{
    path::PathBuf,
    process::{Child, Command, Stdio},
    time::{Duration, Instant},
};

use anyhow::{bail, ensure, Context, Result};
use clap::Parser;
use serde_json::{json, Value};

#[derive(Parser)]
#[command(about = "Farm overhead: serve + N workers vs coordinator render")]
struct Args {
    /// Samples per pixel.
    #[arg(long, default_value_t = 256)]
    spp: u32,
    /// Image width and height.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Workers (threads for render, processes for serve).
    #[arg(long, default_value_t = 2)]
    workers: u32,
    /// Runs of each (the median is reported).
    #[arg(long, default_value_t = 3)]
    runs: usize,
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<()> {
    let args = Args::parse();
    let bin = std::env::current_exe()?.with_file_name("coordinator");
    let worker = std::env::current_exe()?.with_file_name("worker");
    ensure!(bin.exists() && worker.exists(), "build first: cargo build --release");
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let tmp = tempfile::tempdir()?;
    let settings =
        json!({"width": args.size, "height": args.size, "spp": args.spp, "max_depth": 128});
    let settings_path = tmp.path().join("settings.json");
    std::fs::write(&settings_path, settings.to_string())?;
    let local_exr = tmp.path().join("local.exr");
    let mut render_times = Vec::new();
    for _ in 0..args.runs {
        let start = Instant::now();
        let status = Command::new(&bin)
            .args(["render", "scenes/cornell-box.gltf", "-o"])
            .arg(&local_exr)
            .arg("--settings")
            .arg(&settings_path)
            .args(["--workers", &args.workers.to_string()])
            .current_dir(&repo)
            .status()?;
        ensure!(status.success(), "coordinator render failed");
        render_times.push(start.elapsed().as_secs_f64());
    }

    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = Killed(
        Command::new(&bin)
            .args(["serve", "--listen", &format!("127.0.0.1:{port}"), "--data"])
            .arg(tmp.path().join("data"))
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .spawn()?,
    );
    let agent = ureq::AgentBuilder::new().timeout(Duration::from_secs(600)).build();
    let end = Instant::now() + Duration::from_secs(20);
    while agent.get(&format!("{url}/healthz")).call().is_err() {
        ensure!(Instant::now() < end, "the coordinator did not come up");
        std::thread::sleep(Duration::from_millis(20));
    }
    let _workers: Vec<Killed> = (0..args.workers)
        .map(|_| {
            Command::new(&worker)
                .args(["--join", &url, "--threads", "1"])
                .env("RUST_LOG", "warn")
                .spawn()
                .map(Killed)
        })
        .collect::<std::io::Result<_>>()?;
    let bundle = coordinator::local::bundle_scene(
        &repo.join("scenes/cornell-box.gltf"),
        &Default::default(),
        &Default::default(),
    )?
    .bytes;
    let scene: Value = agent
        .post(&format!("{url}/api/v1/scenes"))
        .set("content-type", "application/octet-stream")
        .send_bytes(&bundle)?
        .into_json()?;
    let mut serve_times = Vec::new();
    let mut farm_exr = Vec::new();
    for _ in 0..args.runs {
        let start = Instant::now();
        let job: Value = agent
            .post(&format!("{url}/api/v1/jobs"))
            .send_json(json!({"scene": scene["scene"], "settings": settings}))?
            .into_json()?;
        let id = job["id"].as_str().context("no job id")?;
        loop {
            let status: Value =
                agent.get(&format!("{url}/api/v1/jobs/{id}")).call()?.into_json()?;
            match status["state"].as_str() {
                Some("done") => break,
                Some("failed" | "cancelled") => bail!("job ended: {status}"),
                _ => std::thread::sleep(Duration::from_millis(10)),
            }
        }
        let resp = agent.get(&format!("{url}/api/v1/jobs/{id}/frames/0.exr")).call()?;
        farm_exr.clear();
        std::io::Read::read_to_end(&mut resp.into_reader(), &mut farm_exr)?;
        serve_times.push(start.elapsed().as_secs_f64());
    }
    let same = rgb(&std::fs::read(&local_exr)?)? == rgb(&farm_exr)?;
    let (render, serve) = (median(render_times), median(serve_times));
    println!(
        "cornell box {0}x{0}, {1} spp, {2} workers: coordinator render {render:.2} s, serve + {2} worker processes {serve:.2} s, ratio {3:.3}; images identical: {same}",
        args.size,
        args.spp,
        args.workers,
        serve / render
    );
    ensure!(same, "the images differ");
    Ok(())
}

fn rgb(exr: &[u8]) -> Result<Vec<u32>> {
    let (_, _, texels) = common::envmap::read_exr_rgb(exr, u64::MAX).map_err(anyhow::Error::msg)?;
    Ok(texels.iter().flat_map(|t| t.to_array().map(f32::to_bits)).collect())
}
