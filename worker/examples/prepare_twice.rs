//! What a worker's BVH cache saves: a scene prepared for one job, then for a second job with
//! other settings (samples, seed), without the cache and with it (the second preparation takes
//! the first one's BVH). Prints the seconds of each preparation, the fastest of `ROUNDS`, and the
//! bytes a triangle of each structure the preparation keeps (`PreparedScene::memory_parts`).
//! `cargo run --release -p worker --example prepare_twice -- SCENE.gltf`
use std::time::Instant;

use common::settings::RenderSettings;
use worker::render::{
    bvh_cache::BvhCache,
    scene::{prepare_frame, prepare_frame_cached},
};

const ROUNDS: usize = 5;

fn main() {
    let path = std::env::args().nth(1).expect("usage: prepare_twice SCENE.gltf");
    let scene = common::gltf::load_path(std::path::Path::new(&path)).expect("scene");
    let first = RenderSettings::default();
    let second = RenderSettings { spp: 64, seed: 7, ..RenderSettings::default() };
    let time = |f: &mut dyn FnMut()| {
        (0..ROUNDS)
            .map(|_| {
                let start = Instant::now();
                f();
                start.elapsed().as_secs_f64()
            })
            .fold(f64::INFINITY, f64::min)
    };
    let fresh = time(&mut || {
        prepare_frame(&scene, &second, None, 0).expect("prepare");
    });
    let cache = BvhCache::default();
    let first_job = time(&mut || {
        let cache = BvhCache::default();
        prepare_frame_cached(&scene, &first, None, 0, &cache).expect("prepare");
    });
    prepare_frame_cached(&scene, &first, None, 0, &cache).expect("prepare");
    let second_job = time(&mut || {
        prepare_frame_cached(&scene, &second, None, 0, &cache).expect("prepare");
    });
    println!(
        "{} triangles: without the cache {fresh:.3} s; with it, the first job {first_job:.3} s, a later job {second_job:.3} s ({} BVH built, {:.1} MB kept)",
        scene.triangle_count(),
        cache.builds(),
        cache.bytes() as f64 / 1e6
    );
    let prepared = prepare_frame(&scene, &second, None, 0).expect("prepare");
    let triangles = prepared.accel.len() as f64;
    for (part, bytes) in prepared.memory_parts() {
        println!("{part}: {:.1} bytes a triangle", bytes as f64 / triangles);
    }
    println!("in all: {:.1} bytes a triangle", prepared.memory_bytes() as f64 / triangles);
}
