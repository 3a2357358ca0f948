//! `coordinator`: command-line entry point (flags only; the work is in the library).

use std::{
    io::IsTerminal,
    path::{Path, PathBuf},
};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use common::settings::{Environment, RenderSettings};
use coordinator::local::render_file;
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Parser)]
#[command(version, about = "Distributed path-tracing render farm: coordinator")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a glTF scene on this machine and write OUT.exr (+ OUT.png).
    Render {
        /// The scene (.gltf or .glb).
        scene: PathBuf,
        /// Output EXR path.
        #[arg(short, long)]
        output: PathBuf,
        /// Samples per pixel.
        #[arg(long)]
        spp: Option<u32>,
        /// Image width.
        #[arg(long)]
        width: Option<u32>,
        /// Image height.
        #[arg(long)]
        height: Option<u32>,
        /// Sampler seed.
        #[arg(long)]
        seed: Option<u64>,
        /// Maximum path depth (bounces).
        #[arg(long)]
        max_depth: Option<u32>,
        /// Local worker threads (default: one per core).
        #[arg(long)]
        workers: Option<usize>,
        /// Render settings JSON file; flags override it.
        #[arg(long)]
        settings: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "coordinator=info,worker=info,common=info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match cli.command {
        Command::Render {
            scene,
            output,
            spp,
            width,
            height,
            seed,
            max_depth,
            workers,
            settings,
        } => {
            let mut s = match settings {
                Some(path) => {
                    let text = std::fs::read_to_string(&path)
                        .with_context(|| format!("reading {}", path.display()))?;
                    let mut s = RenderSettings::from_json(&text)
                        .map_err(anyhow::Error::msg)
                        .with_context(|| format!("{}", path.display()))?;
                    // A map named in a settings file is relative to that file.
                    if let Some(Environment::Map { map, .. }) = &mut s.environment {
                        if Path::new(map.as_str()).is_relative() {
                            let dir = path.parent().unwrap_or(Path::new("."));
                            *map = dir.join(&*map).to_string_lossy().into_owned();
                        }
                    }
                    s
                }
                None => RenderSettings::default(),
            };
            s.spp = spp.unwrap_or(s.spp);
            s.width = width.unwrap_or(s.width);
            s.height = height.unwrap_or(s.height);
            s.seed = seed.unwrap_or(s.seed);
            s.max_depth = max_depth.unwrap_or(s.max_depth);
            let workers = workers.unwrap_or_else(|| {
                std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
            });
            let bar = std::io::stderr().is_terminal().then(|| {
                let bar = ProgressBar::new(0);
                bar.set_style(
                    ProgressStyle::with_template("{bar:40} {pos}/{len} tasks {elapsed} eta {eta}")
                        .expect("valid template"),
                );
                bar
            });
            let progress = |done: usize, total: usize| {
                if let Some(bar) = &bar {
                    bar.set_length(total as u64);
                    bar.set_position(done as u64);
                }
            };
            let report = render_file(&scene, &s, workers, &output, &progress)?;
            if let Some(bar) = bar {
                bar.finish_and_clear();
            }
            let est = report.film.error_estimate();
            if report.film.rejected > 0 {
                tracing::warn!(
                    rejected = report.film.rejected,
                    "samples were NaN, infinite or absurdly large and were counted as zero; reproduce one with `worker debug-sample`"
                );
            }
            let est_text = if est.rel_mse.is_finite() {
                format!("{:.3e}", est.rel_mse)
            } else {
                "unknown (needs 2 spp)".to_string()
            };
            eprintln!(
                "rendered {} samples in {:.2} s ({:.2} Msamples/s, {:.2} Mrays/s); load {:.3} s, BVH {:.3} s; estimated relMSE {}; wrote {}",
                report.samples,
                report.render_seconds,
                report.samples as f64 / report.render_seconds / 1e6,
                report.rays as f64 / report.render_seconds / 1e6,
                report.load_seconds,
                report.build_seconds,
                est_text,
                report.outputs.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
            );
            Ok(())
        }
    }
}
