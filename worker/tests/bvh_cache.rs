//! The worker's cache of built BVHs (`render::bvh_cache`): a job prepared with a BVH taken from
//! the cache renders the bits of a fresh preparation; geometry that moved (a vertex, the camera
//! the renderer's space is centred on) builds again; the least recently used BVH is dropped
//! first when the cache is full.

mod support;

use common::{
    film::Rect,
    protocol::{SampleRange, TaskKind, TaskSpec},
    settings::{Integrator, RenderSettings},
};
use support::*;
use worker::render::{
    bvh_cache::BvhCache,
    render_task_threads,
    scene::{prepare_frame, prepare_frame_cached},
};

fn whole(settings: &RenderSettings) -> TaskSpec {
    TaskSpec {
        frame: 0,
        rect: Rect { x0: 0, y0: 0, width: settings.width, height: settings.height },
        samples: SampleRange { start: 0, end: settings.spp },
        kind: TaskKind::Camera,
    }
}

#[test]
fn a_cached_bvh_renders_the_bits_of_a_fresh_build() {
    let scene = repo_scene("cornell-box.gltf");
    let base = settings("cornell-box");
    let first = RenderSettings { width: 24, height: 20, spp: 2, ..base.clone() };
    let later = [
        RenderSettings { width: 32, height: 24, spp: 5, seed: 9, ..base.clone() },
        RenderSettings { width: 20, height: 16, spp: 3, integrator: Integrator::Bdpt, ..base },
    ];
    let cache = BvhCache::new(1 << 30);
    prepare_frame_cached(&scene, &first, None, 0, &cache).unwrap();
    for (k, settings) in later.iter().enumerate() {
        let cached = prepare_frame_cached(&scene, settings, None, 0, &cache).unwrap();
        assert_eq!((cache.builds(), cache.hits()), (1, k + 1));
        let fresh = prepare_frame(&scene, settings, None, 0).unwrap();
        let task = whole(settings);
        let (a, b) = (
            render_task_threads(&cached, settings.seed, &task, 2),
            render_task_threads(&fresh, settings.seed, &task, 2),
        );
        assert_eq!(format!("{:?}", a.tile), format!("{:?}", b.tile), "{settings:?}");
        assert_eq!(a.rays, b.rays);
    }
}

#[test]
fn moved_geometry_builds_again_and_the_least_recently_used_goes_first() {
    let scene = repo_scene("cornell-box.gltf");
    let mut moved = scene.clone();
    moved.meshes[3].positions[0].y += 0.01;
    // The renderer's space is centred on the camera: moving it moves every triangle there.
    let mut camera = scene.clone();
    camera.cameras[0].transform = glam::DMat4::from_translation(glam::DVec3::new(0.0, 0.0, 0.05))
        * camera.cameras[0].transform;
    let settings = RenderSettings { width: 16, height: 16, spp: 1, ..settings("cornell-box") };
    let prepare = |s: &common::scene::Scene, cache: &BvhCache| {
        prepare_frame_cached(s, &settings, None, 0, cache).unwrap();
    };
    let cache = BvhCache::new(1 << 30);
    for s in [&scene, &moved, &camera, &scene] {
        prepare(s, &cache);
    }
    assert_eq!((cache.builds(), cache.hits()), (3, 1));
    // Room for any two but not three: the least recently used goes first, so after scene,
    // moved, scene again and camera, `moved` builds again where first-in-first-out would keep it.
    let bytes = |s: &common::scene::Scene| {
        let c = BvhCache::new(1 << 30);
        prepare(s, &c);
        c.bytes()
    };
    let budget = bytes(&scene) + bytes(&moved) + bytes(&camera) - 1;
    let two = BvhCache::new(budget);
    for s in [&scene, &moved, &scene, &camera] {
        prepare(s, &two);
    }
    assert_eq!((two.builds(), two.hits()), (3, 1));
    prepare(&moved, &two);
    assert_eq!((two.builds(), two.hits()), (4, 1), "the least recently used was kept");
    prepare(&camera, &two);
    assert_eq!((two.builds(), two.hits()), (4, 2));
    assert!(two.bytes() <= budget);
    // A cache of no bytes keeps nothing.
    let none = BvhCache::new(0);
    prepare(&scene, &none);
    prepare(&scene, &none);
    assert_eq!((none.builds(), none.hits(), none.bytes()), (2, 0, 0));
}
