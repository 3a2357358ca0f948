//! `bench`: run time against error. Renders the Cornell box at increasing sample counts and
//! prints CSV (seconds, samples/s, rays/s, RMSE and relative MSE against the reference), writes
//! a log-log SVG plot of error against time, and measures the large-geometry scene (load, BVH
//! build, render times, bytes per triangle).
//!
//! With `--peer-csv FILE` (the CSV of the peers harness's `run.py --csv`, any number of times)
//! it also prints, for each of our sample counts, every peer's relative MSE at our time (its runs
//! interpolated log-log) and our error over it: the equal-time ratios of `docs/perf/`. The
//! peers' curves go on the same plot.
//!
//! Like the peers harness, which renders each peer once untimed before its timed runs, the timed
//! renders follow an untimed 1-spp one (`--no-warmup` leaves it out).
//!
//! With `--many-lights` it measures the light choice instead, on a floor lit by N small
//! emitters (`worker::test_scenes::many_lights_gltf`): the tree against the power mixture at
//! equal samples for N = 4 to 1024, then at equal time for 1024 (`docs/perf/light-tree.md`);
//! `--lamp-height` and `--lamp-side` hang smaller lamps lower, each lighting its own pool;
//! `--lamp-meshes K` merges the lamps into K emissive meshes, one power class each.
//!
//! With `--light-choice SCENE` it measures the same two choices on any glTF file (`--size`,
//! 192x128 unless given; `--spp`, 16,64,256 unless given), scored against the tree at 4096 spp
//! with another seed, and says which the automatic choice takes.
//!
//! With `--materials` it renders the glass and the subsurface scene of `scenes/materials/`
//! instead, at the size of their Mitsuba references (`ref/<scene>-48.exr`), prints the same
//! columns plus the median pixel's relative error, the equal-time ratios against the peer runs of
//! the same scene (`scenes/materials/mitsuba_peer.py` writes Mitsuba's), and a plot per scene
//! (`bench-glass-smooth.svg`, `bench-subsurface.svg`; `docs/perf/materials.md`).
//!
//! With `--caustic` it renders the mirror caustic (`worker::test_scenes::MirrorCaustic`, the floor
//! lit only through a mirror by a small light) with each integrator (bidirectional path tracing
//! also with 16 light-traced paths per pixel sample, `bdpt:lp16`), scored against the closed
//! form, and prints each integrator's error at the path tracer's times (`docs/perf/integrators.md`),
//! and those of the `--peer-csv` runs of scene `mirror-caustic` (`scenes/caustic/luxcore_peer.py`,
//! scored against the closed form that `--caustic-reference` writes).
//!
//! With `--rainbow` it renders the prism's rainbow (`worker::test_scenes::PrismRainbow`, sunlight
//! split by a dispersive prism onto a floor, which the path tracer cannot find) with
//! bidirectional path tracing (1 and 16 light-traced paths per pixel sample) and photon mapping,
//! scored against the closed form, and prints the others' errors at bidirectional path
//! tracing's times (`docs/perf/integrators.md`).
//!
//! With `--deform` it renders deformation blur against rigid blur on the same geometry and
//! motion: the moving placements of `scenes/cornell-motion.gltf`, and DamagedHelmet spun 30
//! degrees within the shutter, each rendered as animated nodes (rigid) and as meshes skinned to
//! those nodes (deforming, posed at keys), scored against the rigid render at 1024 spp
//! (`docs/perf/motion-and-lens.md`).
//!
//! `cargo run --release -p coordinator --bin bench -- [--spp 1,4,16,64,256,1024] [--threads 2]
//! [--plot bench.svg] [--peer-csv peers.csv] [--large] [--time-scenes] [--many-lights
//! [--lamp-height 0.6] [--lamp-side 0.25] [--lamp-meshes K]] [--light-choice SCENE [--size WxH]]
//! [--materials] [--deform] [--caustic [--caustic-light 0.125] [--caustic-reference OUT.exr]
//! [--caustic-scene OUT.gltf]] [--rainbow]
//! [--no-warmup]`; the figures in `docs/perf/` come from this command.

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    time::Instant,
};

use anyhow::{Context, Result};
use clap::Parser;
use common::settings::RenderSettings;
use coordinator::{
    local::{render_file, RenderReport},
    output::read_exr_rgb,
};
use worker::render::scene::prepare;

#[derive(Parser)]
#[command(about = "Run time against error on the Cornell box, and large-scene figures")]
struct Args {
    /// Sample counts to render (default 1,4,16,64,256,1024; with `--materials` each scene's
    /// own, `MATERIAL_SCENES`).
    #[arg(long, value_delimiter = ',')]
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
    /// Only the light choice on many emitters: the tree against the mixture (no Cornell box).
    #[arg(long)]
    many_lights: bool,
    /// With `--many-lights`: the lamps' height over the floor (0.6 unless given; lower, each
    /// lamp lights its own pool: `worker::test_scenes::many_lights_gltf_at`).
    #[arg(long, value_name = "METRES", default_value_t = 0.6)]
    lamp_height: f64,
    /// With `--many-lights`: the side of the lamps' squares (0.25 unless given), each emitting
    /// the same power whatever its size.
    #[arg(long, value_name = "METRES", default_value_t = 0.25)]
    lamp_side: f64,
    /// With `--many-lights`: the lamps merged into this many emissive meshes, one power class
    /// each (`worker::test_scenes::many_lights_gltf_in`), instead of one node each.
    #[arg(long, value_name = "N")]
    lamp_meshes: Option<usize>,
    /// Only the light choice on this glTF file: the tree against the mixture at equal time.
    #[arg(long, value_name = "SCENE")]
    light_choice: Option<PathBuf>,
    /// With `--light-choice`: the image's size.
    #[arg(long, value_name = "WxH", default_value = "192x128")]
    size: String,
    /// Only the glass and subsurface scenes against their Mitsuba references (no Cornell box);
    /// `--peer-csv` files then hold runs of those scenes.
    #[arg(long)]
    materials: bool,
    /// Only deformation blur against rigid blur on the same geometry and motion (no Cornell
    /// box).
    #[arg(long)]
    deform: bool,
    /// Only the mirror caustic: the path tracer against bidirectional path tracing and photon
    /// mapping (no Cornell box).
    #[arg(long)]
    caustic: bool,
    /// With `--caustic`: also write the mirror caustic's closed form (64x64, an RGB EXR) here,
    /// for a peer's runs to be scored against (`scenes/caustic/luxcore_peer.py`).
    #[arg(long, value_name = "OUT.exr")]
    caustic_reference: Option<PathBuf>,
    /// With `--caustic`: the half side of the square light, in (0, 0.5] (its radiance scaled so
    /// that the caustic stays as bright: a smaller light is rarer for the path tracer to hit).
    #[arg(long, value_name = "METRES", default_value_t = 0.125)]
    caustic_light: f64,
    /// With `--caustic`: write the scene (a `.gltf` with its buffer inline) here, and its
    /// closed form where `--caustic-reference` says, then stop without rendering.
    #[arg(long, value_name = "OUT.gltf")]
    caustic_scene: Option<PathBuf>,
    /// Only the prism's rainbow: bidirectional path tracing and photon mapping against its
    /// closed form (the path tracer finds none of it).
    #[arg(long)]
    rainbow: bool,
    /// A peer harness CSV (`run.py --csv`) to compare with at equal time; repeatable.
    #[arg(long = "peer-csv")]
    peer_csv: Vec<PathBuf>,
    /// The repository's folder (the scenes and references in `scenes/`, the real assets in
    /// `tests/assets/`): the default runs from the repository's root.
    #[arg(long, default_value = ".")]
    repo: PathBuf,
    /// Skip the untimed 1-spp warm-up render (the peers harness gives each peer one too, for
    /// the page cache and its kernel cache; ours loads the scene, the program's code and the
    /// allocator's memory once before timing).
    #[arg(long)]
    no_warmup: bool,
}

/// The Cornell box's sample counts when `--spp` is not given.
const CORNELL_SPP: [u32; 6] = [1, 4, 16, 64, 256, 1024];

/// The scenes of `--materials` (`scenes/materials/<name>.gltf`) and their sample counts when
/// `--spp` is not given: about 0.05 to 10 seconds each on 2 threads.
const MATERIAL_SCENES: [(&str, &[u32]); 2] =
    [("glass-smooth", &[16, 64, 256, 1024, 4096]), ("subsurface", &[16, 64, 256, 1024])];

/// The CSV columns of a timed render (`csv_row`).
const CSV_HEADER: &str =
    "scene,spp,threads,seconds,write_seconds,samples_per_s,rays_per_s,rmse,relmse,est_relmse";

/// One of our timed renders.
struct Row {
    spp: u32,
    seconds: f64,
    /// The relative MSE, or in `materials`' second table the median pixel's error.
    error: f64,
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

/// The median over pixels of each pixel's relative squared error (the mean over its channels of
/// the terms of `metrics`' relative MSE): the error of a typical pixel, which the rare bright
/// samples that dominate a heavy-tailed relative MSE do not sway.
fn median_rel_error(image: &[[f32; 3]], reference: &[[f32; 3]]) -> f64 {
    let mut errors: Vec<f64> = image
        .iter()
        .zip(reference)
        .map(|(a, b)| {
            (0..3)
                .map(|c| {
                    let (x, r) = (a[c] as f64, b[c] as f64);
                    let x = if x.is_finite() { x } else { 0.0 };
                    (x - r) * (x - r) / (r * r + 0.01)
                })
                .sum::<f64>()
                / 3.0
        })
        .collect();
    if errors.is_empty() {
        return f64::NAN;
    }
    errors.sort_by(f64::total_cmp);
    let mid = errors.len() / 2;
    if errors.len() % 2 == 1 {
        errors[mid]
    } else {
        0.5 * (errors[mid - 1] + errors[mid])
    }
}

/// Renders `scene` with `settings` into `out`; the seconds are loading and rendering, not writing
/// the image files (like the peers' figures).
fn timed_render(
    scene: &Path,
    settings: &RenderSettings,
    threads: usize,
    out: &Path,
) -> Result<(f64, RenderReport)> {
    let wall = Instant::now();
    let report = render_file(scene, settings, threads, out, &|_| {})?;
    Ok((wall.elapsed().as_secs_f64() - report.write_seconds, report))
}

/// One line of `CSV_HEADER`'s columns.
fn csv_row(
    name: &str,
    spp: u32,
    threads: usize,
    seconds: f64,
    report: &RenderReport,
    (rmse, rel_mse): (f64, f64),
) -> String {
    format!(
        "{name},{spp},{threads},{seconds:.4},{:.4},{:.0},{:.0},{rmse:.6},{rel_mse:.6e},{:.6e}",
        report.write_seconds,
        report.samples as f64 / report.render_seconds,
        report.rays as f64 / report.render_seconds,
        report.est_rel_mse
    )
}

fn main() -> Result<()> {
    let args = Args::parse();
    if args.many_lights {
        return many_lights(args.threads, args.lamp_height, args.lamp_side, args.lamp_meshes);
    }
    if let Some(scene) = &args.light_choice {
        return light_choice(scene, &args);
    }
    if args.caustic {
        return caustic(&args);
    }
    if args.rainbow {
        return rainbow(args.threads);
    }
    if args.materials {
        return materials(&args);
    }
    if args.deform {
        return deform(&args);
    }
    let scenes = args.repo.join("scenes");
    let cornell = scenes.join("cornell-box.gltf");
    let (_, _, reference) = read_exr_rgb(&scenes.join("ref/cornell-box.exr"))?;
    let base = RenderSettings::from_json(&std::fs::read_to_string(
        scenes.join("cornell-box.settings.json"),
    )?)
    .map_err(anyhow::Error::msg)?;
    // Read the peers first: a bad file fails before minutes of rendering.
    let mut peers = Vec::new();
    for path in &args.peer_csv {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        peers
            .extend(peer_curves(&text, "cornell-box").with_context(|| path.display().to_string())?);
    }
    let out_dir = std::env::temp_dir().join(format!("renderfarm-bench-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir)?;
    println!("{CSV_HEADER}");
    if !args.no_warmup {
        let settings = RenderSettings { spp: 1, ..base.clone() };
        render_file(&cornell, &settings, args.threads, &out_dir.join("warmup.exr"), &|_| {})?;
    }
    let mut rows = Vec::new();
    let spps = if args.spp.is_empty() { &CORNELL_SPP[..] } else { &args.spp };
    for &spp in spps {
        let settings = RenderSettings { spp, ..base.clone() };
        let out = out_dir.join(format!("cornell-{spp}.exr"));
        let (seconds, report) = timed_render(&cornell, &settings, args.threads, &out)?;
        let errors = metrics(&report.mean_rgb, &reference);
        println!("{}", csv_row("cornell-box", spp, args.threads, seconds, &report, errors));
        rows.push(Row { spp, seconds, error: errors.1 });
    }
    print_equal_time("cornell-box", "relmse", &rows, &peers);
    write_plot(&args.plot, "Cornell box 256x256", &with_peers(&rows, peers))?;
    eprintln!("plot: {}", args.plot.display());
    if args.large {
        large_scene(&args.repo.join("tests/assets"), args.threads, &out_dir)?;
    }
    if args.time_scenes {
        time_scenes(args.threads, &out_dir)?;
    }
    Ok(())
}

/// Each peer's error (the CSV column `metric`) at our seconds, and ours over it (below 1 we win).
fn print_equal_time(scene: &str, metric: &str, rows: &[Row], peers: &[Series]) {
    if peers.is_empty() {
        return;
    }
    println!("scene,spp,seconds,{metric},peer,peer_{metric}_at_our_seconds,ratio");
    for peer in peers {
        for row in rows {
            let theirs = peer.rel_mse_at(row.seconds);
            println!(
                "{scene},{},{:.4},{:.6e},{},{:.6e},{:.3}",
                row.spp,
                row.seconds,
                row.error,
                peer.name,
                theirs,
                row.error / theirs
            );
        }
    }
}

/// Our runs as the plot's first curve, then the peers'.
fn with_peers(rows: &[Row], peers: Vec<Series>) -> Vec<Series> {
    let ours = Series {
        name: "renderfarm".into(),
        points: rows.iter().map(|r| (r.seconds, r.error, r.spp)).collect(),
    };
    std::iter::once(ours).chain(peers).collect()
}

/// Glass and subsurface scattering (`MATERIAL_SCENES`): time and error against the Mitsuba
/// references of `scenes/materials/ref/`, rendered at their size with each scene's settings
/// otherwise (`max_depth` 1024, the sky), the median pixel's error beside the relative MSE (which
/// is heavy-tailed on the subsurface scene: `docs/perf/materials.md`), the equal-time ratios
/// against the peers' runs of the same scene (of the median too where their CSV has a
/// `median_relmse` column, as `scenes/materials/mitsuba_peer.py` writes), and a plot per scene
/// beside `--plot`.
fn materials(args: &Args) -> Result<()> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/materials");
    // Read the peers first: a bad file fails before minutes of rendering. Per scene: the curves
    // of the relative MSE and of the median pixel's error.
    let mut peers: Vec<(Vec<Series>, Vec<Series>)> =
        MATERIAL_SCENES.iter().map(|_| (Vec::new(), Vec::new())).collect();
    for path in &args.peer_csv {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let has_median = text
            .lines()
            .next()
            .is_some_and(|header| split_csv(header).iter().any(|h| h == "median_relmse"));
        let mut found = false;
        for ((curves, medians), (name, _)) in peers.iter_mut().zip(MATERIAL_SCENES) {
            let runs =
                peer_runs(&text, name, "relmse").with_context(|| path.display().to_string())?;
            found |= !runs.is_empty();
            curves.extend(runs);
            if has_median {
                medians.extend(
                    peer_runs(&text, name, "median_relmse")
                        .with_context(|| path.display().to_string())?,
                );
            }
        }
        let names = MATERIAL_SCENES.map(|(name, _)| name).join("` or `");
        anyhow::ensure!(found, "{}: no runs of scene `{names}`", path.display());
    }
    let out_dir = std::env::temp_dir().join(format!("renderfarm-bench-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir)?;
    println!("{CSV_HEADER},median_relmse");
    for ((name, default_spp), (peers, peer_medians)) in MATERIAL_SCENES.into_iter().zip(peers) {
        let scene = dir.join(format!("{name}.gltf"));
        let (width, height, reference) = read_exr_rgb(&dir.join(format!("ref/{name}-48.exr")))?;
        let base = RenderSettings {
            width: width.try_into()?,
            height: height.try_into()?,
            ..RenderSettings::from_json(&std::fs::read_to_string(
                dir.join(format!("{name}.settings.json")),
            )?)
            .map_err(anyhow::Error::msg)?
        };
        if !args.no_warmup {
            let settings = RenderSettings { spp: 1, ..base.clone() };
            render_file(&scene, &settings, args.threads, &out_dir.join("warmup.exr"), &|_| {})?;
        }
        let (mut rows, mut medians) = (Vec::new(), Vec::new());
        let spps = if args.spp.is_empty() { default_spp } else { &args.spp[..] };
        for &spp in spps {
            let settings = RenderSettings { spp, ..base.clone() };
            let out = out_dir.join(format!("{name}-{spp}.exr"));
            let (seconds, report) = timed_render(&scene, &settings, args.threads, &out)?;
            let errors = metrics(&report.mean_rgb, &reference);
            let median = median_rel_error(&report.mean_rgb, &reference);
            println!("{},{median:.6e}", csv_row(name, spp, args.threads, seconds, &report, errors));
            rows.push(Row { spp, seconds, error: errors.1 });
            medians.push(Row { spp, seconds, error: median });
        }
        print_equal_time(name, "relmse", &rows, &peers);
        print_equal_time(name, "median_relmse", &medians, &peer_medians);
        let stem = args.plot.file_stem().and_then(|s| s.to_str()).unwrap_or("bench");
        let plot = args.plot.with_file_name(format!("{stem}-{name}.svg"));
        write_plot(&plot, &format!("{name} {width}x{height}"), &with_peers(&rows, peers))?;
        eprintln!("plot: {}", plot.display());
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
                &|_| {},
            )?;
            report.mean_rgb
        };
        for spp in [16, 64, 256] {
            let settings = RenderSettings { spp, ..base.clone() };
            let out = out_dir.join(format!("{name}-{spp}.exr"));
            let (seconds, report) = timed_render(&scene, &settings, threads, &out)?;
            let errors = metrics(&report.mean_rgb, &reference);
            println!("{}", csv_row(name, spp, threads, seconds, &report, errors));
        }
    }
    Ok(())
}

fn large_scene(assets: &Path, threads: usize, out_dir: &Path) -> Result<()> {
    let path =
        assets.join("real/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf");
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
    let report = render_file(&path, &settings, threads, &out_dir.join("large.exr"), &|_| {})?;
    println!(
        "large scene: render 256x256 at 16 spp in {:.3} s ({:.0} samples/s, {:.0} rays/s)",
        report.render_seconds,
        report.samples as f64 / report.render_seconds,
        report.rays as f64 / report.render_seconds
    );
    Ok(())
}

/// Deformation blur against rigid blur: each scene's moving placements rendered as animated
/// nodes (`Shape::Rigid`) and as the same meshes skinned to those nodes with weight 1 (posed at
/// keys, `Shape::Deforming`), the same motion either way. Seconds count preparing and rendering;
/// errors are against the rigid render at 1024 spp.
fn deform(args: &Args) -> Result<()> {
    use common::{
        animation::{AnimNode, Animation, Curve, Interpolation, NodeMotion, Trs},
        scene::{Deform, Scene, Skin},
        settings::Environment,
    };
    use glam::{DMat4, DQuat, DVec3};
    use worker::render::{motion::Shape, scene::prepare_frame};

    // The scene with every moving placement's mesh skinned to its node instead.
    let skinned = |scene: &Scene| -> Scene {
        let mut out = scene.clone();
        for (inst, original) in out.instances.iter_mut().zip(&scene.instances) {
            if !scene.instance_moves(original) {
                continue;
            }
            let mut mesh = scene.meshes[inst.mesh].clone();
            let n = mesh.positions.len();
            mesh.deform = Some(Box::new(Deform {
                node: inst.node,
                node_name: format!("node {}", inst.node),
                rest_positions: mesh.positions.clone(),
                rest_normals: mesh.normals.clone(),
                rest_tangents: mesh.tangents.clone(),
                skin: Some(Skin {
                    joints: vec![inst.node],
                    inverse_binds: vec![inst.offset],
                    influences: 4,
                    vertex_joints: vec![0; 4 * n],
                    vertex_weights: [1.0, 0.0, 0.0, 0.0].repeat(n),
                    ..Skin::default()
                }),
                ..Deform::default()
            }));
            out.meshes.push(mesh);
            inst.mesh = out.meshes.len() - 1;
            inst.transform = DMat4::IDENTITY;
            inst.offset = DMat4::IDENTITY;
        }
        out
    };
    let cornell = {
        let scenes = args.repo.join("scenes");
        let scene = common::gltf::load_path(&scenes.join("cornell-motion.gltf"))?;
        let settings = RenderSettings::from_json(&std::fs::read_to_string(
            scenes.join("cornell-motion.settings.json"),
        )?)
        .map_err(anyhow::Error::msg)?;
        ("cornell-motion", scene, settings)
    };
    let helmet = {
        let path = args.repo.join("tests/assets/real/DamagedHelmet/glTF-Binary/DamagedHelmet.glb");
        let mut scene = common::gltf::load_path(&path)?;
        // Every placement's node turns 30 degrees about the world's y axis over [0, 1].
        let count = scene.instances.iter().map(|i| i.node + 1).max().unwrap_or(0);
        let still = AnimNode {
            parent: None,
            rest: DMat4::IDENTITY,
            rest_trs: Trs {
                translation: DVec3::ZERO,
                rotation: DQuat::IDENTITY,
                scale: DVec3::ONE,
            },
            motion: None,
            weights: None,
        };
        let mut nodes = vec![still; count];
        for inst in &scene.instances {
            let (scale, rotation, translation) = inst.transform.to_scale_rotation_translation();
            let turned = DQuat::from_rotation_y(30f64.to_radians()) * rotation;
            nodes[inst.node] = AnimNode {
                parent: None,
                rest: inst.transform,
                rest_trs: Trs { translation, rotation, scale },
                motion: Some(NodeMotion {
                    rotation: Some(Curve {
                        times: vec![0.0, 1.0],
                        values: vec![rotation, turned],
                        interpolation: Interpolation::Linear,
                    }),
                    ..NodeMotion::default()
                }),
                weights: None,
            };
        }
        scene.animation = Some(Animation { nodes, start: 0.0, end: 1.0 });
        let mut settings = RenderSettings { width: 128, height: 128, ..Default::default() };
        settings.environment = Some(Environment::Color { color: [1.0, 1.0, 1.0] });
        settings.shutter.close = 1.0;
        settings.frames.fps = 1.0;
        ("helmet-spin", scene, settings)
    };
    println!("scene,blur,spp,seconds,prepare_seconds,relmse,keys,triangles");
    for (name, rigid, base) in [cornell, helmet] {
        let deforming = skinned(&rigid);
        let frame = base.frames.start;
        let reference = {
            let settings = RenderSettings { spp: 1024, ..base.clone() };
            let prepared = prepare_frame(&rigid, &settings, None, frame)?;
            render_prepared(&prepared, &settings, args.threads)
        };
        let spps = if args.spp.is_empty() { &[16, 64, 256][..] } else { &args.spp };
        for &spp in spps {
            for (blur, scene) in [("rigid", &rigid), ("deforming", &deforming)] {
                let settings = RenderSettings { spp, ..base.clone() };
                let start = Instant::now();
                let prepared = prepare_frame(scene, &settings, None, frame)?;
                let prepare_seconds = start.elapsed().as_secs_f64();
                let image = render_prepared(&prepared, &settings, args.threads);
                let seconds = start.elapsed().as_secs_f64();
                let (_, rel_mse) = metrics(&image, &reference);
                let moving = prepared.motion.iter().flat_map(|m| &m.instances);
                let (mut keys, mut triangles) = (0, 0);
                for inst in moving {
                    match &inst.shape {
                        Shape::Rigid(a) => triangles += a.len(),
                        Shape::Deforming(d) => {
                            keys = keys.max(d.times.len());
                            triangles += d.accel.len();
                        }
                    }
                }
                println!(
                    "{name},{blur},{spp},{seconds:.4},{prepare_seconds:.4},{rel_mse:.6e},{keys},{triangles}"
                );
            }
        }
    }
    Ok(())
}

/// Renders frame 0 of a prepared scene on `threads` threads, in 32-pixel tiles.
fn render_prepared(
    prepared: &worker::render::scene::PreparedScene,
    settings: &RenderSettings,
    threads: usize,
) -> Vec<[f32; 3]> {
    use common::{
        film::{Film, Rect},
        protocol::{SampleRange, TaskKind, TaskSpec},
    };
    let mut tasks = Vec::new();
    for y0 in (0..settings.height).step_by(32) {
        for x0 in (0..settings.width).step_by(32) {
            let rect = Rect {
                x0,
                y0,
                width: 32.min(settings.width - x0),
                height: 32.min(settings.height - y0),
            };
            let samples = SampleRange { start: 0, end: settings.spp };
            tasks.push(TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera });
        }
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let film = std::sync::Mutex::new(Film::new(settings.width, settings.height));
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(task) = tasks.get(i) else { break };
                let result = worker::render::render_task(prepared, settings.seed, task);
                film.lock().expect("film lock").merge_tile(&result.tile);
            });
        }
    });
    film.into_inner().expect("film lock").mean_rgb()
}

/// The light tree against the power mixture on a floor lit by N small emitters: relative MSE
/// and seconds for each N at a few sample counts, and the mixture's error at the tree's time
/// (interpolated log-log) over the tree's; at 1,024 emitters also the path tracer, bidirectional
/// path tracing and photon mapping through the farm's code path. Each run's seconds count
/// preparing the scene (the tree's build) and rendering; the reference is the tree at 1024 spp
/// with another seed. The lamps, squares of side `lamp_side`, hang at `lamp_height`, each its
/// own node or merged into `lamp_meshes` meshes (N at least that many).
fn many_lights(
    threads: usize,
    lamp_height: f64,
    lamp_side: f64,
    lamp_meshes: Option<usize>,
) -> Result<()> {
    anyhow::ensure!(
        lamp_height > 0.0 && lamp_height <= 4.0,
        "--lamp-height {lamp_height} is not in (0, 4]"
    );
    anyhow::ensure!(
        lamp_side > 0.0 && lamp_side <= 0.5,
        "--lamp-side {lamp_side} is not in (0, 0.5]"
    );
    use worker::render::{light::LightChoice, scene::prepare_with_light_choice};
    let dir = std::env::temp_dir().join(format!("renderfarm-bench-many-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let base = RenderSettings { width: 128, height: 128, max_depth: 8, ..Default::default() };
    let run = |scene: &common::scene::Scene, choice: LightChoice, spp: u32, seed: u64| {
        let settings = RenderSettings { spp, seed, ..base.clone() };
        let start = Instant::now();
        let prepared = prepare_with_light_choice(scene, &settings, choice)?;
        let image = render_prepared(&prepared, &settings, threads);
        anyhow::Ok((start.elapsed().as_secs_f64(), image))
    };
    println!("emitters,sampler,spp,seconds,relmse");
    anyhow::ensure!(lamp_meshes.is_none_or(|m| m >= 1), "--lamp-meshes must be at least 1");
    for n in [4usize, 16, 64, 256, 1024] {
        let meshes = lamp_meshes.map(|m| m.min(n));
        let path = dir.join(format!("many-{n}.gltf"));
        let gltf = worker::test_scenes::many_lights_gltf_in(n, lamp_height, lamp_side, meshes);
        std::fs::write(&path, gltf)?;
        let scene = common::gltf::load_path(&path)?;
        let (_, reference) = run(&scene, LightChoice::Tree, 1024, 1)?;
        let spps: &[u32] = if n == 1024 { &[4, 16, 64, 256] } else { &[16, 64] };
        let run = |choice, spp, seed| run(&scene, choice, spp, seed);
        tree_against_mixture(run, &reference, spps, ("emitters,", &format!("{n},")))?;
        if n == 1024 {
            // The integrators on the same scene through the farm's code path (bidirectional
            // path tracing's and photon mapping's light samples choose by the tree, their light
            // subpaths and photons leave by the mixture), against the tree's reference.
            let prefix = format!("{n},");
            let curves = integrator_curves(
                &path,
                &base,
                threads,
                &reference,
                &[
                    ("path", &[4, 16, 64, 256]),
                    ("bdpt", &[1, 4, 16, 64]),
                    ("sppm", &[4, 16, 64, 256]),
                ],
                &prefix,
            )?;
            print_against_path(&curves, &prefix);
        }
    }
    Ok(())
}

/// The light tree against the power mixture on `scene` at `args.size`: relative MSE and seconds
/// (preparing the scene and rendering) at each of `args.spp` (16, 64, 256 unless given), and the
/// mixture's error at the tree's time over the tree's; the reference is the tree at 4096 spp with
/// another seed. Also which the automatic choice takes.
fn light_choice(scene: &Path, args: &Args) -> Result<()> {
    use worker::render::{light::LightChoice, scene::prepare_with_light_choice};
    let (width, height) = args
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
        .filter(|&(w, h)| (1..=4096).contains(&w) && (1..=4096).contains(&h))
        .with_context(|| format!("--size {} is not WIDTHxHEIGHT within 1..=4096", args.size))?;
    let loaded =
        common::gltf::load_path(scene).with_context(|| format!("loading {}", scene.display()))?;
    let base = RenderSettings { width, height, ..Default::default() };
    let run = |choice: LightChoice, spp: u32, seed: u64| {
        let settings = RenderSettings { spp, seed, ..base.clone() };
        let start = Instant::now();
        let prepared = prepare_with_light_choice(&loaded, &settings, choice)?;
        let image = render_prepared(&prepared, &settings, args.threads);
        anyhow::Ok((start.elapsed().as_secs_f64(), image))
    };
    let auto = prepare(&loaded, &base)?.lights.uses_tree();
    println!("automatic choice: {}", if auto { "tree" } else { "mixture" });
    let (_, reference) = run(LightChoice::Tree, 4096, 1)?;
    let spps = if args.spp.is_empty() { vec![16, 64, 256] } else { args.spp.clone() };
    println!("sampler,spp,seconds,relmse");
    tree_against_mixture(run, &reference, &spps, ("", ""))
}

/// The tree's and the mixture's renders by `run` (choice, spp, seed; seconds and the image) at
/// each of `spps` with seed 0: a CSV row each (sampler, spp, seconds, relative MSE against
/// `reference`), then for each of the tree's runs the mixture's error at its time over its own.
/// `columns`: the leading columns' names and this call's values, for the second table's header
/// and every row.
fn tree_against_mixture(
    run: impl Fn(worker::render::light::LightChoice, u32, u64) -> Result<(f64, Vec<[f32; 3]>)>,
    reference: &[[f32; 3]],
    spps: &[u32],
    (names, values): (&str, &str),
) -> Result<()> {
    use worker::render::light::LightChoice;
    let mut curves = Vec::new();
    for (name, choice) in [("tree", LightChoice::Tree), ("mixture", LightChoice::Mixture)] {
        let mut points = Vec::new();
        for &spp in spps {
            let (seconds, image) = run(choice, spp, 0)?;
            let (_, rel_mse) = metrics(&image, reference);
            println!("{values}{name},{spp},{seconds:.4},{rel_mse:.6e}");
            points.push((seconds, rel_mse, spp));
        }
        curves.push(Series { name: name.into(), points });
    }
    println!("{names}spp,tree_seconds,tree_relmse,mixture_relmse_at_tree_seconds,ratio");
    for &(seconds, rel_mse, spp) in &curves[0].points {
        let theirs = curves[1].rel_mse_at(seconds);
        println!("{values}{spp},{seconds:.4},{rel_mse:.6e},{theirs:.6e},{:.2}", theirs / rel_mse);
    }
    Ok(())
}

/// The mirror caustic (light half side `--caustic-light`, 0.125 unless given; 64x64, `max_depth`
/// 2) rendered by each integrator
/// (path, bdpt with 1 and 16 light-traced paths per pixel sample, sppm)
/// through `coordinator render`'s code path at increasing sample counts: seconds (loading and
/// rendering) and the relative MSE against the closed form, then each integrator's error at the
/// path tracer's times (interpolated log-log) over the path tracer's.
fn caustic(args: &Args) -> Result<()> {
    use worker::test_scenes::MirrorCaustic;
    let threads = args.threads;
    // Read the peers first: a bad file fails before minutes of rendering.
    let mut peers = Vec::new();
    for path in &args.peer_csv {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        peers.extend(
            peer_curves(&text, "mirror-caustic").with_context(|| path.display().to_string())?,
        );
    }
    let dir = std::env::temp_dir().join(format!("renderfarm-bench-caustic-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let half = args.caustic_light;
    anyhow::ensure!(half > 0.0 && half <= 0.5, "--caustic-light {half} is not in (0, 0.5]");
    // The peers' script renders the light of half side 0.125 (`scenes/caustic/luxcore_peer.py`).
    anyhow::ensure!(
        half == 0.125 || args.peer_csv.is_empty(),
        "--peer-csv runs are of the light of half side 0.125, not --caustic-light {half}"
    );
    let caustic = MirrorCaustic { light_half_side: half, radiance: 7.5 / (half * half) };
    let scene = dir.join("caustic.gltf");
    std::fs::write(&scene, caustic.gltf())?;
    let res = 64;
    let expected: Vec<[f32; 3]> = (0..res * res)
        .map(|i| [caustic.pixel_radiance(i % res, i / res, res, res) as f32; 3])
        .collect();
    if let Some(out) = &args.caustic_reference {
        let n = res as usize;
        exr::prelude::write_rgb_file(out, n, n, |x, y| {
            let [r, g, b] = expected[y * n + x];
            (r, g, b)
        })
        .with_context(|| format!("writing {}", out.display()))?;
    }
    if let Some(out) = &args.caustic_scene {
        std::fs::write(out, caustic.gltf())
            .with_context(|| format!("writing {}", out.display()))?;
        return Ok(());
    }
    let base =
        RenderSettings { width: res, height: res, max_depth: 2, seed: 5, ..Default::default() };
    let curves = integrator_curves(
        &scene,
        &base,
        threads,
        &expected,
        &[
            ("path", &[64, 256, 1024, 4096]),
            ("bdpt", &[4, 16, 64, 256]),
            ("bdpt:lp16", &[1, 4, 16, 64, 256]),
            ("sppm", &[16, 64, 256, 1024, 4096]),
        ],
        "",
    )?;
    let mut curves = curves;
    curves.extend(peers);
    print_against_path(&curves, "");
    Ok(())
}

/// The prism's rainbow (64x64, `max_depth` 3) rendered by the path tracer once (it finds none
/// of the light: a direction seen through smooth glass), bidirectional path tracing with 1 and
/// 16 light-traced paths per pixel sample, and photon mapping, through `coordinator render`'s
/// code path at increasing sample counts, scored against the closed form; then the others'
/// errors at bidirectional path tracing's times.
fn rainbow(threads: usize) -> Result<()> {
    use worker::test_scenes::PrismRainbow;
    let dir = std::env::temp_dir().join(format!("renderfarm-bench-rainbow-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let scene = dir.join("rainbow.gltf");
    std::fs::write(&scene, PrismRainbow.gltf())?;
    let res = 64;
    let expected: Vec<[f32; 3]> =
        PrismRainbow::image(res, 2000).iter().map(|p| p.map(|v| v as f32)).collect();
    let base = RenderSettings {
        width: res,
        height: res,
        max_depth: PrismRainbow::MAX_DEPTH,
        seed: 5,
        ..Default::default()
    };
    integrator_curves(&scene, &base, threads, &expected, &[("path", &[64])], "")?;
    let curves = integrator_curves(
        &scene,
        &base,
        threads,
        &expected,
        &[
            ("bdpt", &[16, 64, 256, 1024]),
            ("bdpt:lp16", &[4, 16, 64, 256]),
            ("sppm", &[16, 64, 256, 1024, 4096]),
        ],
        "",
    )?;
    print_against_path(&curves, "");
    Ok(())
}

/// Renders `scene` with each integrator at its sample counts through `coordinator render`'s
/// code path (`render_file`, `threads` local workers) and prints a CSV row per run (`prefix`
/// first): seconds (loading and rendering, not writing), the relative MSE against `expected` and
/// the film's estimate of it. The path tracer's curve comes first.
fn integrator_curves(
    scene: &Path,
    base: &RenderSettings,
    threads: usize,
    expected: &[[f32; 3]],
    runs: &[(&str, &[u32])],
    prefix: &str,
) -> Result<Vec<Series>> {
    let dir = scene.parent().unwrap_or(Path::new("."));
    println!("{prefix}integrator,spp,seconds,relmse,est_relmse");
    let mut curves = Vec::new();
    for &(name, spps) in runs {
        // `bdpt:lpK`: bidirectional path tracing with K light-traced paths per pixel sample.
        let (integrator, bdpt) = match name.split_once(":lp") {
            Some((integrator, k)) => {
                (integrator, Some(common::settings::Bdpt { light_paths: k.parse()? }))
            }
            None => (name, None),
        };
        let mut points = Vec::new();
        for &spp in spps {
            // A photon-mapping task is a range of passes over the whole frame: ranges small
            // enough to keep every worker busy. So are the light tasks of many light paths (each
            // a range of pixel samples over the whole frame, that many light paths a sample).
            let integrator: common::settings::Integrator =
                integrator.parse().map_err(|e: String| anyhow::anyhow!(e))?;
            let samples_per_task =
                if integrator == common::settings::Integrator::Sppm || bdpt.is_some() {
                    spp.div_ceil(4 * threads as u32).max(1)
                } else {
                    base.samples_per_task
                };
            let settings =
                RenderSettings { spp, samples_per_task, integrator, bdpt, ..base.clone() };
            let out = dir.join(format!("{}-{spp}.exr", name.replace(':', "-")));
            let wall = Instant::now();
            let report = render_file(scene, &settings, threads, &out, &|_| {})?;
            let seconds = wall.elapsed().as_secs_f64() - report.write_seconds;
            let (_, rel_mse) = metrics(&report.mean_rgb, expected);
            println!("{prefix}{name},{spp},{seconds:.4},{rel_mse:.6e},{:.6e}", report.est_rel_mse);
            points.push((seconds, rel_mse, spp));
        }
        curves.push(Series { name: name.into(), points });
    }
    Ok(curves)
}

/// Each curve after the first (the path tracer's, or the baseline's) at its runs' seconds against
/// the first's error there (interpolated log-log): the ratio above 1 is how much lower its error
/// is. The columns are named after the first curve.
fn print_against_path(curves: &[Series], prefix: &str) {
    let first = &curves[0].name;
    println!("{prefix}integrator,spp,seconds,relmse,{first}_relmse_at_its_seconds,{first}_over_it");
    for curve in &curves[1..] {
        for &(seconds, rel_mse, spp) in &curve.points {
            let path = curves[0].rel_mse_at(seconds);
            println!(
                "{prefix}{},{spp},{seconds:.4},{rel_mse:.6e},{path:.6e},{:.1}",
                curve.name,
                path / rel_mse
            );
        }
    }
}

/// One renderer's error against time: (seconds, relative MSE, spp), by increasing seconds.
#[derive(Debug)]
struct Series {
    name: String,
    points: Vec<(f64, f64, u32)>,
}

impl Series {
    /// Relative MSE (or the curve's other error) at `seconds`, interpolated log-log between the two runs around it, or
    /// extrapolated along the nearest two; a single run is extrapolated as 1 / time (Monte Carlo).
    /// Before the first run the error grows no faster than 1 / time: a peer's first runs often
    /// fall faster than that (its fixed costs shrink in share), and extrapolating that slope to
    /// times it never rendered at would flatter us.
    fn rel_mse_at(&self, seconds: f64) -> f64 {
        let p = &self.points;
        if p.len() == 1 {
            return p[0].1 * p[0].0 / seconds;
        }
        let i = p.iter().position(|q| q.0 >= seconds).unwrap_or(p.len()).clamp(1, p.len() - 1);
        let ((t0, e0, _), (t1, e1, _)) = (p[i - 1], p[i]);
        let mut slope = (e1 / e0).ln() / (t1 / t0).ln();
        if seconds < t0 {
            slope = slope.max(-1.0);
        }
        e0 * (slope * (seconds / t0).ln()).exp()
    }
}

/// The curves of a peer harness CSV for `scene` (`peer_runs` of the relative MSE); a file
/// without runs of it is an error.
fn peer_curves(text: &str, scene: &str) -> Result<Vec<Series>> {
    let curves = peer_runs(text, scene, "relmse")?;
    anyhow::ensure!(!curves.is_empty(), "no runs of scene `{scene}`");
    Ok(curves)
}

/// The curves of a peer harness CSV for `scene`, the error in column `metric`, one per `peer` (or
/// `renderer` and `variant`; runs of one peer from several rounds make one curve), none if it
/// has no runs of the scene.
/// Rows without seconds or error (the harness's `--eval` rows) and runs with none are skipped;
/// runs of equal seconds are averaged, so that the curve's seconds strictly increase.
fn peer_runs(text: &str, scene: &str, metric: &str) -> Result<Vec<Series>> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let header = split_csv(lines.next().context("empty CSV")?.1);
    let column = |name: &str| header.iter().position(|h| h == name);
    let need = |name: &str| column(name).with_context(|| format!("no `{name}` column"));
    let (c_scene, c_spp, c_seconds, c_rel) =
        (need("scene")?, need("spp")?, need("seconds")?, need(metric)?);
    let (c_peer, c_renderer, c_variant) = (column("peer"), column("renderer"), column("variant"));
    let mut curves: Vec<Series> = Vec::new();
    for (n, line) in lines {
        let f = split_csv(line);
        let field = |c: usize| f.get(c).map(|v| v.trim()).unwrap_or("");
        if field(c_scene) != scene || field(c_seconds).is_empty() || field(c_rel).is_empty() {
            continue;
        }
        let number = |c: usize| -> Result<f64> {
            field(c)
                .parse()
                .with_context(|| format!("line {}: `{}` is not a number", n + 1, field(c)))
        };
        let (seconds, rel) = (number(c_seconds)?, number(c_rel)?);
        let spp = if field(c_spp).is_empty() { 0 } else { number(c_spp)? as u32 };
        let name = match c_peer.map(field).filter(|p| !p.is_empty()) {
            Some(peer) => peer.to_string(),
            None => format!(
                "{}:{}",
                c_renderer.map(field).unwrap_or("peer"),
                c_variant.map(field).unwrap_or("")
            ),
        };
        if !(seconds > 0.0 && rel > 0.0 && seconds.is_finite() && rel.is_finite()) {
            continue;
        }
        match curves.iter_mut().find(|c| c.name == name) {
            Some(c) => c.points.push((seconds, rel, spp)),
            None => curves.push(Series { name, points: vec![(seconds, rel, spp)] }),
        }
    }
    for c in &mut curves {
        c.points.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut merged: Vec<(f64, f64, u32, u32)> = Vec::new();
        for &(t, e, spp) in &c.points {
            match merged.last_mut() {
                Some(m) if m.0 == t => {
                    m.1 += e;
                    m.3 += 1;
                }
                _ => merged.push((t, e, spp, 1)),
            }
        }
        c.points = merged.into_iter().map(|(t, e, spp, k)| (t, e / k as f64, spp)).collect();
    }
    Ok(curves)
}

/// The fields of one CSV line (double-quoted fields may hold commas and doubled quotes).
fn split_csv(line: &str) -> Vec<String> {
    let (mut fields, mut field, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.trim_end_matches('\r').chars().peekable();
    while let Some(ch) = chars.next() {
        match (ch, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => fields.push(std::mem::take(&mut field)),
            _ => field.push(ch),
        }
    }
    fields.push(field);
    fields
}

/// A log-log plot of relative MSE against seconds, one point per sample count and one line per
/// renderer (ours first).
fn write_plot(path: &Path, title: &str, series: &[Series]) -> Result<()> {
    const COLORS: [&str; 5] = ["#c33", "#36c", "#393", "#c93", "#939"];
    let (w, h, m) = (640.0, 420.0, 60.0);
    let logs: Vec<Vec<(f64, f64, u32)>> = series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .filter(|p| p.0 > 0.0 && p.1 > 0.0)
                .map(|p| (p.0.log10(), p.1.log10(), p.2))
                .collect()
        })
        .collect();
    let all = || logs.iter().flatten();
    if all().next().is_none() {
        return Ok(());
    }
    let (x0, x1) = (
        all().map(|p| p.0).fold(f64::MAX, f64::min).floor(),
        all().map(|p| p.0).fold(f64::MIN, f64::max).ceil(),
    );
    let (y0, y1) = (
        all().map(|p| p.1).fold(f64::MAX, f64::min).floor(),
        all().map(|p| p.1).fold(f64::MIN, f64::max).ceil(),
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
    for (k, (pts, s)) in logs.iter().zip(series).enumerate() {
        let color = COLORS[k % COLORS.len()];
        let line: Vec<String> =
            pts.iter().map(|p| format!("{:.1},{:.1}", sx(p.0), sy(p.1))).collect();
        write!(
            svg,
            r##"<polyline points="{}" fill="none" stroke="{color}" stroke-width="2"/>"##,
            line.join(" ")
        )?;
        for p in pts {
            write!(
                svg,
                r##"<circle cx="{:.1}" cy="{:.1}" r="3" fill="{color}"/>"##,
                sx(p.0),
                sy(p.1)
            )?;
            if k == 0 {
                write!(
                    svg,
                    r##"<text x="{:.1}" y="{:.1}">{} spp</text>"##,
                    sx(p.0) + 5.0,
                    sy(p.1) - 5.0,
                    p.2
                )?;
            }
        }
        let name = s.name.replace('&', "&amp;").replace('<', "&lt;");
        write!(
            svg,
            r##"<text x="{}" y="{}" fill="{color}" text-anchor="end">{name}</text>"##,
            w - m,
            m + 16.0 * k as f64
        )?;
    }
    let title = title.replace('&', "&amp;").replace('<', "&lt;");
    write!(
        svg,
        r##"<text x="{}" y="20" text-anchor="middle">{title}: relative MSE vs wall-clock seconds (log-log)</text></svg>"##,
        w / 2.0
    )?;
    std::fs::write(path, svg)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_time_error_follows_the_peer_curve_log_log() {
        // Runs on the power law e = 0.3 / t^1.2 give the law back between and after them;
        // before the first run the error grows only as 1 / time.
        let law = |t: f64| 0.3 * t.powf(-1.2);
        let points = [0.05, 0.2, 0.9, 4.0].map(|t| (t, law(t), 1)).to_vec();
        let curve = Series { name: "peer".into(), points };
        for t in [0.05, 0.1, 0.5, 2.0, 4.0, 30.0] {
            let got = curve.rel_mse_at(t);
            assert!((got / law(t) - 1.0).abs() < 1e-9, "t {t}: {got} against {}", law(t));
        }
        let before = curve.rel_mse_at(0.01);
        assert!((before / (law(0.05) * 5.0) - 1.0).abs() < 1e-9, "{before}");
        // A law that falls slower than 1 / time is followed before the first run too.
        let slow = |t: f64| 0.3 * t.powf(-0.8);
        let points = [0.05, 0.2, 0.9].map(|t| (t, slow(t), 1)).to_vec();
        let curve = Series { name: "slow".into(), points };
        assert!((curve.rel_mse_at(0.01) / slow(0.01) - 1.0).abs() < 1e-9);
        let single = Series { name: "one".into(), points: vec![(2.0, 0.01, 16)] };
        assert!((single.rel_mse_at(4.0) - 0.005).abs() < 1e-15);
    }

    #[test]
    fn peer_curves_come_from_the_harness_csv() {
        let csv = "renderer,version,variant,scene,spp,seconds,rmse,relmse,peer\n\
            mitsuba,3.9.1,llvm_ad_rgb,cornell-box,4,0.2,0.1,0.0758,mitsuba:llvm_ad_rgb\n\
            mitsuba,3.9.1,llvm_ad_rgb,cornell-box,1,0.05,0.2,0.298,mitsuba:llvm_ad_rgb\n\
            cycles,\"5.0.1, build x\",,cornell-box,1,0.5,0.2,0.3,\n\
            cycles,5.0.1,,other-scene,1,0.5,0.2,0.3,cycles\n";
        let curves = peer_curves(csv, "cornell-box").unwrap();
        assert_eq!(curves.len(), 2);
        assert_eq!(curves[0].name, "mitsuba:llvm_ad_rgb");
        assert_eq!(curves[0].points, vec![(0.05, 0.298, 1), (0.2, 0.0758, 4)]);
        assert_eq!(curves[1].name, "cycles:");
        assert_eq!(curves[1].points, vec![(0.5, 0.3, 1)]);
        let err = peer_curves("renderer,scene,spp,seconds\n", "cornell-box").unwrap_err();
        assert!(format!("{err:#}").contains("no `relmse` column"), "{err:#}");
        let err = peer_curves(csv, "kitchen").unwrap_err();
        assert!(format!("{err:#}").contains("no runs of scene `kitchen`"), "{err:#}");
        let bad = "scene,spp,seconds,relmse\n\ncornell-box,1,fast,0.3\n";
        let err = peer_curves(bad, "cornell-box").unwrap_err();
        assert!(format!("{err:#}").contains("line 3: `fast` is not a number"), "{err:#}");
        // Scored-only rows (no seconds) are skipped; runs of equal seconds are averaged, so the
        // curve never divides by a zero time span.
        let rounds = "scene,spp,seconds,relmse,peer\n\
            cornell-box,,,0.2,p\n\
            cornell-box,4,0.2,0.06,p\n\
            cornell-box,4,0.2,0.08,p\n\
            cornell-box,1,0.05,0.3,p\n";
        let curves = peer_curves(rounds, "cornell-box").unwrap();
        assert_eq!(curves[0].points.len(), 2);
        assert!((curves[0].points[1].1 - 0.07).abs() < 1e-12);
        assert!(curves[0].rel_mse_at(0.1).is_finite());
        // A file of other scenes has no runs of this one, which only `peer_curves` refuses.
        assert!(peer_runs(csv, "kitchen", "relmse").unwrap().is_empty());
        // Any error column makes the curves (`--materials` reads the median pixel's too).
        let rmse = peer_runs(csv, "cornell-box", "rmse").unwrap();
        assert_eq!(rmse[0].points, vec![(0.05, 0.2, 1), (0.2, 0.1, 4)]);
    }

    #[test]
    fn median_error_ignores_the_brightest_pixels() {
        let reference = [[0.9f32; 3]; 5];
        let mut image = [[1.0f32; 3]; 5];
        image[0] = [50.0; 3];
        image[1] = [f32::NAN; 3];
        let (_, rel_mse) = metrics(&image, &reference);
        let typical = 0.01 / (0.81 + 0.01);
        assert!((median_rel_error(&image, &reference) - typical).abs() < 1e-6);
        assert!(rel_mse > 100.0 * typical);
        // An even count takes the mean of the middle two.
        let median = median_rel_error(&image[1..], &reference[1..]);
        assert!((median - typical).abs() < 1e-6, "{median}");
    }
}
