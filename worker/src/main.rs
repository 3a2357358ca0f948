//! `worker`: command-line entry point. Today it reproduces single samples for debugging
//! (`worker debug-sample`); joining a coordinator over HTTP comes with the farm service.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use common::settings::RenderSettings;
use glam::{UVec2, Vec2};
use worker::render::{integrator, sampler::Sampler, scene::prepare};

#[derive(Parser)]
#[command(version, about = "Distributed path-tracing render farm: worker")]
struct Cli {
    #[command(subcommand)]
    command: Command,
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
        .init();
    match Cli::parse().command {
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
            let prepared = prepare(&loaded, &settings)?;
            let mut sampler = Sampler::new(settings.seed, frame);
            let pixel = UVec2::new(x, y);
            sampler.start_pixel_sample(pixel, sample);
            let film = pixel.as_vec2() + sampler.next_2d();
            let lens = if prepared.camera.has_lens() { sampler.next_2d() } else { Vec2::ZERO };
            let ray = prepared.camera.generate_ray(film, lens);
            let mut stats = integrator::Stats::default();
            let radiance = integrator::li(&prepared, ray, &mut sampler, &mut stats);
            println!(
                "pixel ({x}, {y}) sample {sample}: film ({:.6}, {:.6}) radiance [{:e}, {:e}, {:e}] rays {}",
                film.x, film.y, radiance.x, radiance.y, radiance.z, stats.rays
            );
            Ok(())
        }
    }
}
