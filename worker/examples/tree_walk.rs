//! The light tree's choice alone: nanoseconds per `choose`, and per choice of `choose_batch` in
//! batches of 16 (as the wavefront asks), at a million points on the floor of
//! `test_scenes::many_lights_gltf` (|x|, |z| <= 10 at y = 0, facing up), the fastest of seven
//! repetitions on one thread. `TREE_WALK_POINTS=N` takes N points and one repetition (for
//! `valgrind --tool=callgrind`). The scene of 1,024 lamps is the one `bench --many-lights`
//! writes (`$TMPDIR/renderfarm-bench-many-PID/many-1024.gltf`), or a number of lamps writes it.
//! `cargo run --release -p worker --example tree_walk -- 1024`
use std::time::Instant;

use common::settings::RenderSettings;
use glam::Vec3;
use worker::render::{
    light::{ChooseLight, LightChoice, ShadingContext},
    scene::prepare_with_light_choice,
};

fn main() {
    let arg = std::env::args().nth(1).expect("usage: tree_walk SCENE.gltf|LAMPS");
    // A number: the scene of that many lamps, written here.
    let path = match arg.parse::<usize>() {
        Ok(n) => {
            let path = std::env::temp_dir().join(format!("tree-walk-{}.gltf", std::process::id()));
            std::fs::write(&path, worker::test_scenes::many_lights_gltf(n)).expect("writing");
            path
        }
        Err(_) => std::path::PathBuf::from(&arg),
    };
    let scene = common::gltf::load_path(&path).expect("scene");
    let settings = RenderSettings::default();
    let prepared =
        prepare_with_light_choice(&scene, &settings, LightChoice::Tree).expect("prepare");
    let lights = &prepared.lights;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        state =
            state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let count = std::env::var("TREE_WALK_POINTS").ok().and_then(|n| n.parse().ok());
    let points: Vec<(ShadingContext, f32)> = (0..count.unwrap_or(1_000_000))
        .map(|_| {
            let p = Vec3::new(next() * 20.0 - 10.0, 0.0, next() * 20.0 - 10.0);
            (ShadingContext { p, n: Vec3::Y }, next())
        })
        .collect();
    let mut best = f64::INFINITY;
    let mut check = 0.0f64;
    let repeat = if count.is_some() { 1 } else { 7 };
    for _ in 0..repeat {
        let start = Instant::now();
        let mut sum = 0.0f64;
        for (ctx, u) in &points {
            if let Some((i, pmf, r)) = lights.choose(ctx, *u) {
                sum += i as f64 + pmf as f64 + r as f64;
            }
        }
        best = best.min(start.elapsed().as_secs_f64());
        check = sum;
    }
    println!("{:.1} ns a choice (checksum {check:.6e})", best * 1e9 / points.len() as f64);
    let (ctx, u): (Vec<ShadingContext>, Vec<f32>) = points.iter().copied().unzip();
    let mut best = f64::INFINITY;
    for _ in 0..repeat {
        let start = Instant::now();
        let mut sum = 0.0f64;
        let mut out = [None; 16];
        for (ctx, u) in ctx.chunks(16).zip(u.chunks(16)) {
            let out = &mut out[..ctx.len()];
            lights.choose_batch(ctx, u, out);
            for &(i, pmf, r) in out.iter().flatten() {
                sum += i as f64 + pmf as f64 + r as f64;
            }
        }
        best = best.min(start.elapsed().as_secs_f64());
        check = sum;
    }
    println!(
        "{:.1} ns a choice in batches of 16 (checksum {check:.6e})",
        best * 1e9 / points.len() as f64
    );
}
