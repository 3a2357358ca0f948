//! `bench`: run time against error. Renders the Cornell box at increasing sample counts and
//! prints CSV (seconds, samples/s, rays/s, RMSE and relative MSE against the reference), writes
//! a log-log SVG plot of error against time, and measures the large-geometry scene (load, BVH
//! build, render times, bytes per triangle).
//!
//! `cargo run --release -p coordinator --bin bench -- [--spp 1,4,16,64,256,1024] [--threads 2]
//! [--plot bench.svg] [--large] [--time-scenes]`; figures in the README come from this command.

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    time::Instant,
};

use anyhow::{Context, Result};
use clap::Parser;
use common::settings::RenderSettings;
use coordinator::{local::render_file, output::read_exr_rgb};
use worker::render::scene::prepare;

#[derive(Parser)]
#[command(about = "Run time against error on the Cornell box, and large-scene figures")]
struct Args {
    /// Sample counts to render.
    #[arg(long, value_delimiter = ',', default_value = "1,4,16,64,256,1024")]
    spp: Vec<u32>,
    /// Worker threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Where to write the log-log plot of relative MSE against seconds.
    #[arg(long, default_value = "bench.svg")]
    plot: PathBuf,
    /// Also load, build and render the ~1M-triangle MetalRoughSpheresNoTextures scene.
    #[arg(long)]
    large: bool,
    /// Also the motion-blur and depth-of-field scenes (`scenes/cornell-motion.*`,
    /// `scenes/cornell-dof.settings.json`), scored against 4096-spp renders of their own.
    #[arg(long)]
    time_scenes: bool,
    /// The shared folder with scenes and references.
    #[arg(long, default_value = "../shared")]
    shared: PathBuf,
}

struct Row {
    spp: u32,
    seconds: f64,
    rel_mse: f64,
}

fn metrics(image: &[[f32; 3]], reference: &[[f32; 3]]) -> (f64, f64) {
    let (mut se, mut rel) = (0.0, 0.0);
    for (a, b) in image.iter().zip(reference) {
        for c in 0..3 {
            let (x, r) = (a[c] as f64, b[c] as f64);
            let x = if x.is_finite() { x } else { 0.0 };
            se += (x - r) * (x - r);
            rel += (x - r) * (x - r) / (r * r + 0.01);
        }
    }
    let n = (image.len() * 3) as f64;
    ((se / n).sqrt(), rel / n)
}

fn main() -> Result<()> {
    let args = Args::parse();
    let scenes = args.shared.join("scenes");
    let cornell = scenes.join("cornell-box.gltf");
    let (_, _, reference) = read_exr_rgb(&scenes.join("ref/cornell-box.exr"))?;
    let base = RenderSettings::from_json(&std::fs::read_to_string(
        scenes.join("cornell-box.settings.json"),
    )?)
    .map_err(anyhow::Error::msg)?;
    let out_dir = std::env::temp_dir().join(format!("renderfarm-bench-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir)?;
    println!(
        "scene,spp,threads,seconds,write_seconds,samples_per_s,rays_per_s,rmse,relmse,est_relmse"
    );
    let mut rows = Vec::new();
    for &spp in &args.spp {
        let settings = RenderSettings { spp, ..base.clone() };
        let out = out_dir.join(format!("cornell-{spp}.exr"));
        let wall = Instant::now();
        let report = render_file(&cornell, &settings, args.threads, &out, &|_, _| {})?;
        // Like the peers' figures: loading and rendering, not writing the image files.
        let seconds = wall.elapsed().as_secs_f64() - report.write_seconds;
        let image = report.film.mean_rgb();
        let (rmse, rel_mse) = metrics(&image, &reference);
        println!(
            "cornell-box,{spp},{},{:.4},{:.4},{:.0},{:.0},{:.6},{:.6e},{:.6e}",
            args.threads,
            seconds,
            report.write_seconds,
            report.samples as f64 / report.render_seconds,
            report.rays as f64 / report.render_seconds,
            rmse,
            rel_mse,
            report.film.error_estimate().rel_mse
        );
        rows.push(Row { spp, seconds, rel_mse });
    }
    write_plot(&args.plot, &rows)?;
    eprintln!("plot: {}", args.plot.display());
    if args.large {
        large_scene(&scenes, args.threads, &out_dir)?;
    }
    if args.time_scenes {
        time_scenes(args.threads, &out_dir)?;
    }
    Ok(())
}

/// Motion blur and depth of field: time and error against a 4096-spp reference of the same
/// scene and settings (our own: no peer renders these glTF animations the same way).
fn time_scenes(threads: usize, out_dir: &Path) -> Result<()> {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes");
    for (name, scene, settings) in [
        ("cornell-motion", "cornell-motion.gltf", "cornell-motion.settings.json"),
        ("cornell-dof", "cornell-box.gltf", "cornell-dof.settings.json"),
    ] {
        let base = RenderSettings::from_json(&std::fs::read_to_string(repo.join(settings))?)
            .map_err(anyhow::Error::msg)?;
        let scene = repo.join(scene);
        let reference = {
            let settings = RenderSettings { spp: 4096, ..base.clone() };
            let report = render_file(
                &scene,
                &settings,
                threads,
                &out_dir.join(format!("{name}-ref.exr")),
                &|_, _| {},
            )?;
            report.film.mean_rgb()
        };
        for spp in [16, 64, 256] {
            let settings = RenderSettings { spp, ..base.clone() };
            let wall = Instant::now();
            let report = render_file(
                &scene,
                &settings,
                threads,
                &out_dir.join(format!("{name}-{spp}.exr")),
                &|_, _| {},
            )?;
            let seconds = wall.elapsed().as_secs_f64() - report.write_seconds;
            let (rmse, rel_mse) = metrics(&report.film.mean_rgb(), &reference);
            println!(
                "{name},{spp},{threads},{seconds:.4},{:.4},{:.0},{:.0},{rmse:.6},{rel_mse:.6e},{:.6e}",
                report.write_seconds,
                report.samples as f64 / report.render_seconds,
                report.rays as f64 / report.render_seconds,
                report.film.error_estimate().rel_mse
            );
        }
    }
    Ok(())
}

fn large_scene(scenes: &Path, threads: usize, out_dir: &Path) -> Result<()> {
    let path =
        scenes.join("real/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf");
    let start = Instant::now();
    let scene = common::gltf::load_path(&path).with_context(|| format!("{}", path.display()))?;
    let load = start.elapsed().as_secs_f64();
    let settings = RenderSettings { width: 256, height: 256, spp: 16, ..Default::default() };
    let prepared = prepare(&scene, &settings)?;
    let triangles = prepared.accel.len();
    println!(
        "large scene: {triangles} triangles, load {load:.3} s, BVH build {:.3} s, {:.1} bytes/triangle",
        prepared.build_seconds,
        prepared.memory_bytes() as f64 / triangles as f64
    );
    drop(prepared);
    drop(scene);
    let report = render_file(&path, &settings, threads, &out_dir.join("large.exr"), &|_, _| {})?;
    println!(
        "large scene: render 256x256 at 16 spp in {:.3} s ({:.0} samples/s, {:.0} rays/s)",
        report.render_seconds,
        report.samples as f64 / report.render_seconds,
        report.rays as f64 / report.render_seconds
    );
    Ok(())
}

/// A log-log plot of relative MSE against seconds, one point per sample count.
fn write_plot(path: &Path, rows: &[Row]) -> Result<()> {
    let (w, h, m) = (640.0, 420.0, 60.0);
    let pts: Vec<(f64, f64, u32)> = rows
        .iter()
        .filter(|r| r.seconds > 0.0 && r.rel_mse > 0.0)
        .map(|r| (r.seconds.log10(), r.rel_mse.log10(), r.spp))
        .collect();
    if pts.is_empty() {
        return Ok(());
    }
    let (x0, x1) = (
        pts.iter().map(|p| p.0).fold(f64::MAX, f64::min).floor(),
        pts.iter().map(|p| p.0).fold(f64::MIN, f64::max).ceil(),
    );
    let (y0, y1) = (
        pts.iter().map(|p| p.1).fold(f64::MAX, f64::min).floor(),
        pts.iter().map(|p| p.1).fold(f64::MIN, f64::max).ceil(),
    );
    let sx = |x: f64| m + (x - x0) / (x1 - x0).max(1e-9) * (w - 2.0 * m);
    let sy = |y: f64| h - m - (y - y0) / (y1 - y0).max(1e-9) * (h - 2.0 * m);
    let mut svg = format!(
        r##"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12"><rect width="100%" height="100%" fill="white"/>"##
    );
    for d in (x0 as i32)..=(x1 as i32) {
        let x = sx(d as f64);
        write!(
            svg,
            r##"<line x1="{x}" y1="{}" x2="{x}" y2="{}" stroke="#ddd"/><text x="{x}" y="{}" text-anchor="middle">1e{d} s</text>"##,
            m,
            h - m,
            h - m + 18.0
        )?;
    }
    for d in (y0 as i32)..=(y1 as i32) {
        let y = sy(d as f64);
        write!(
            svg,
            r##"<line x1="{m}" y1="{y}" x2="{}" y2="{y}" stroke="#ddd"/><text x="{}" y="{y}" text-anchor="end">1e{d}</text>"##,
            w - m,
            m - 6.0
        )?;
    }
    let line: Vec<String> = pts.iter().map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1))).collect();
    write!(
        svg,
        r##"<polyline points="{}" fill="none" stroke="#c33" stroke-width="2"/>"##,
        line.join(" ")
    )?;
    for p in &pts {
        write!(
            svg,
            r##"<circle cx="{:.1}" cy="{:.1}" r="3" fill="#c33"/><text x="{:.1}" y="{:.1}">{} spp</text>"##,
            sx(p.0),
            sy(p.1),
            sx(p.0) + 5.0,
            sy(p.1) - 5.0,
            p.2
        )?;
    }
    write!(
        svg,
        r##"<text x="{}" y="20" text-anchor="middle">Cornell box 256x256: relative MSE vs wall-clock seconds (log-log)</text></svg>"##,
        w / 2.0
    )?;
    std::fs::write(path, svg)?;
    Ok(())
}
