//! `worker`: command-line entry point. `worker --join URL` renders tasks for a coordinator until
//! SIGTERM or SIGINT (then finishes the task in hand, if any, and leaves; an idle worker leaves
//! at once, without waiting out its long poll); `worker debug-sample`
//! reproduces a single sample for debugging.

use std::{
    path::PathBuf,
    sync::{atomic::AtomicBool, Arc},
};

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use common::settings::RenderSettings;
use glam::UVec2;
use worker::render::{integrators, sampler::Sampler, scene::prepare_frame};

#[derive(Parser)]
#[command(version, about = "Distributed path-tracing render farm: worker")]
struct Cli {
    /// Join the coordinator at this URL (e.g. http://coordinator:8080) and render its tasks.
    #[arg(long, value_name = "URL")]
    join: Option<String>,
    /// Render threads (default: one per core).
    #[arg(long)]
    threads: Option<usize>,
    /// Name shown in the coordinator's workers list (default: host name and process id).
    #[arg(long)]
    name: Option<String>,
    /// The coordinator's join token.
    #[arg(long, env = "RENDERFARM_TOKEN", hide_env_values = true)]
    token: Option<String>,
    /// Longest a lease request waits for work, in seconds.
    #[arg(long, default_value_t = 20.0)]
    wait: f64,
    /// Lease the next task while one renders when tasks take less than this many seconds
    /// (hides the round trip to the coordinator); 0 never leases ahead.
    #[arg(long, default_value_t = worker::client::PREFETCH_BELOW.as_secs_f64())]
    prefetch_below: f64,
    /// The most memory, in MiB, that built BVHs are kept in for later jobs of the same
    /// geometry (least recently used dropped first); 0 keeps none.
    #[arg(long, value_name = "MIB", default_value_t = (worker::render::bvh_cache::DEFAULT_BUDGET >> 20) as u64)]
    bvh_cache_mib: u64,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Trace one sample of one pixel and print its radiance (reproduces a bad sample exactly).
    DebugSample {
        /// The scene (.gltf or .glb).
        scene: PathBuf,
        /// Pixel column.
        x: u32,
        /// Pixel row (0 = top).
        y: u32,
        /// Sample index.
        sample: u32,
        /// Render settings JSON (width, height, seed, ... must match the job).
        #[arg(long)]
        settings: Option<PathBuf>,
        /// Frame number.
        #[arg(long, default_value_t = 0)]
        frame: i64,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "worker=info,common=info".into()),
        )
        .with_writer(std::io::stderr)
        // A log that can no longer be written (stderr piped into `head`, a closed terminal) is
        // dropped; the default would print a complaint to that same stderr, which panics.
        .log_internal_errors(false)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let cli = Cli::parse();
    let command = match (cli.command, cli.join) {
        (Some(_), Some(_)) => bail!("--join and a subcommand cannot be used together"),
        (None, None) => bail!("nothing to do: use --join URL, or a subcommand (see --help)"),
        (None, Some(url)) => {
            let threads = cli.threads.unwrap_or_else(|| {
                std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
            });
            let name = cli.name.unwrap_or_else(|| {
                let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
                    .map(|h| h.trim().to_string())
                    .unwrap_or_else(|_| "worker".into());
                format!("{host}-{}", std::process::id())
            });
            let stop = Arc::new(AtomicBool::new(false));
            for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
                signal_hook::flag::register(signal, stop.clone())
                    .context("installing the signal handler")?;
            }
            let token = cli.token.filter(|t| !t.trim().is_empty());
            if !(cli.prefetch_below.is_finite() && cli.prefetch_below >= 0.0) {
                anyhow::bail!("--prefetch-below must be a non-negative number of seconds");
            }
            let config = worker::client::JoinConfig {
                url,
                token,
                options: worker::client::WorkerOptions {
                    threads,
                    whole_frame_threads: threads,
                    name,
                    wait_s: cli.wait,
                    prefetch_below: std::time::Duration::from_secs_f64(cli.prefetch_below),
                },
                bvh_cache_bytes: usize::try_from(cli.bvh_cache_mib.saturating_mul(1 << 20))
                    .unwrap_or(usize::MAX),
            };
            let stats = worker::client::run(&config, &stop)?;
            tracing::info!(merged = stats.merged, refused = stats.refused, "worker stopped");
            return Ok(());
        }
        (Some(command), None) => command,
    };
    match command {
        Command::DebugSample { scene, x, y, sample, settings, frame } => {
            let settings = match settings {
                Some(path) => RenderSettings::from_json(
                    &std::fs::read_to_string(&path)
                        .with_context(|| format!("reading {}", path.display()))?,
                )
                .map_err(anyhow::Error::msg)?,
                None => RenderSettings::default(),
            };
            anyhow::ensure!(
                x < settings.width && y < settings.height,
                "pixel ({x}, {y}) is outside the {}x{} image",
                settings.width,
                settings.height
            );
            let loaded = common::gltf::load_path(&scene)
                .with_context(|| format!("loading {}", scene.display()))?;
            let prepared = prepare_frame(&loaded, &settings, None, frame)?;
            let mut sampler = Sampler::new(settings.seed, frame);
            let mut stats = integrators::Stats::default();
            let traced = worker::render::sample(
                &prepared,
                &mut sampler,
                UVec2::new(x, y),
                sample,
                &mut stats,
                &mut None,
            );
            let (film, radiance) = (traced.film, traced.radiance);
            let time = traced.time.map(|t| format!(" time {t:.6} s")).unwrap_or_default();
            println!(
                "pixel ({x}, {y}) sample {sample}: film ({:.6}, {:.6}){time} radiance [{:e}, {:e}, {:e}] rays {}",
                film.x, film.y, radiance.x, radiance.y, radiance.z, stats.rays
            );
            Ok(())
        }
    }
}
