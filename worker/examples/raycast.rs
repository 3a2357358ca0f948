//! Ray casts alone, on rays shaped like a path tracer's: camera rays, cosine-distributed bounce
//! rays from the camera rays' hits, and shadow rays from those hits to points on the emitters.
//! Each figure is the fastest of several repetitions on one thread.
//! `cargo run --release -p worker --example raycast -- scenes/cornell-box.gltf`
//! `RAYCAST_REPEAT=1` runs each set once (for `valgrind --tool=callgrind`).
use std::time::Instant;

use common::settings::RenderSettings;
use glam::{UVec2, Vec2, Vec3};
use worker::render::{
    geometry::{Frame, Ray},
    light::Light,
    sampler::Sampler,
    sampling::{sample_cosine_hemisphere, sample_uniform_triangle},
    scene::prepare,
};

fn fastest(mut f: impl FnMut() -> u64) -> (f64, u64) {
    let repeat = std::env::var("RAYCAST_REPEAT").ok().and_then(|r| r.parse().ok()).unwrap_or(7);
    let mut best = f64::INFINITY;
    let mut out = 0;
    for _ in 0..repeat {
        let t = Instant::now();
        out = f();
        best = best.min(t.elapsed().as_secs_f64());
    }
    (best, out)
}

fn main() -> anyhow::Result<()> {
    let path = std::env::args().nth(1).expect("scene path");
    let scene = common::gltf::load_path(path.as_ref())?;
    let settings = RenderSettings { width: 256, height: 256, ..Default::default() };
    let prepared = prepare(&scene, &settings)?;
    let emitters: Vec<[Vec3; 3]> = prepared
        .lights
        .lights
        .iter()
        .filter_map(|l| if let Light::Triangle(t) = l { Some(t.p) } else { None })
        .collect();

    let mut sampler = Sampler::new(1, 0);
    let (mut camera, mut bounce, mut shadow) = (Vec::new(), Vec::new(), Vec::new());
    for y in 0..settings.height {
        for x in 0..settings.width {
            sampler.start_pixel_sample(UVec2::new(x, y), 0);
            let film = Vec2::new(x as f32, y as f32) + sampler.next_2d();
            let ray = prepared.camera.generate_ray(film, Vec2::ZERO);
            camera.push(ray);
            let Some(hit) = prepared.intersect(&ray, f32::INFINITY, None) else { continue };
            let (tri, _) = prepared.triangle(hit.prim, None);
            let mut n = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize();
            if n.dot(ray.dir) > 0.0 {
                n = -n;
            }
            let p = ray.origin + ray.dir * hit.t + n * 1e-4;
            let frame = Frame::from_z(n);
            bounce.push(Ray::new(p, frame.to_world(sample_cosine_hemisphere(sampler.next_2d()))));
            if let Some(light) = emitters.get(y as usize * 7 % emitters.len().max(1)) {
                let (b1, b2) = sample_uniform_triangle(sampler.next_2d());
                let target = light[0] * (1.0 - b1 - b2) + light[1] * b1 + light[2] * b2;
                shadow.push(Ray::new(p, target - p));
            }
        }
    }
    let time = |name: &str, what: &str, rays: &[Ray], cast: &dyn Fn(&Ray) -> bool| {
        let (secs, found) = fastest(|| rays.iter().map(|r| cast(r) as u64).sum());
        let per_ray = secs / rays.len() as f64 * 1e9;
        println!("{name}: {per_ray:.1} ns/ray ({found} of {} {what})", rays.len());
    };
    let closest = |r: &Ray| prepared.intersect(r, f32::INFINITY, None).is_some();
    time("camera closest hit", "hit", &camera, &closest);
    time("bounce closest hit", "hit", &bounce, &closest);
    time("shadow ray", "blocked", &shadow, &|r| prepared.occluded(r, 0.999, None));
    Ok(())
}
