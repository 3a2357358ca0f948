//! The light tree's choice alone: nanoseconds per `choose` at a million points on the floor of
//! `test_scenes::many_lights_gltf` (|x|, |z| <= 10 at y = 0, facing up), the fastest of seven
//! repetitions on one thread. `TREE_WALK_POINTS=N` takes N points and one repetition (for
//! `valgrind --tool=callgrind`). The scene of 1,024 lamps is the one `bench --many-lights`
//! writes (`$TMPDIR/renderfarm-bench-many-PID/many-1024.gltf`).
//! `cargo run --release -p worker --example tree_walk -- many-1024.gltf`
use std::time::Instant;

use common::settings::RenderSettings;
use glam::Vec3;
use worker::render::{
    light::{ChooseLight, LightChoice, ShadingContext},
    scene::prepare_with_light_choice,
};

fn main() {
    let path = std::env::args().nth(1).expect("usage: tree_walk SCENE.gltf");
    let scene = common::gltf::load_path(std::path::Path::new(&path)).expect("scene");
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
}
