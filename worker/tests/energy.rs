//! Materials that keep energy, through the whole renderer in the white furnace: the shipped
//! furnace sphere given a white glTF material (base colour 1, the default specular and IOR), lit
//! by a uniform white environment. A lossless white surface reflects all it receives, so every
//! pixel that sees the sphere is 1: a white metal at every roughness (single-scattering GGX plus
//! Kulla and Conty's multiple-scattering lobe), and a white dielectric, whose diffuse base takes
//! exactly what its specular layer does not reflect (albedo scaling from the same tables).
//! The tolerance is each pixel's own noise plus the albedo tables' interpolation error.
//! These materials render on the wavefront where the CPU has one (`worker/tests/scenes.rs`
//! checks its bits against the scalar path tracer's).

mod support;

use serde_json::json;
use support::*;
use worker::render::scene::prepare;

/// The furnace sphere with a white material of the given metalness and roughness and the
/// default specular layer.
fn white_sphere(metallic: f64, roughness: f64) -> common::scene::Scene {
    let tag = format!("energy-{metallic}-{roughness}");
    let path = edited_scene("furnace", &tag, |json| {
        let m = &mut json["materials"][0];
        m["pbrMetallicRoughness"] = json!({
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "metallicFactor": metallic,
            "roughnessFactor": roughness
        });
        m.as_object_mut().unwrap().remove("extensions");
    });
    common::gltf::load_path(&path).unwrap()
}

/// Renders `scene` in the white furnace; checks that every pixel that sees the sphere is 1 in
/// every channel within 5 of its standard errors plus `tolerance`, and returns the sphere's
/// mean and its smallest and largest pixel.
fn white_in_the_furnace(
    name: &str,
    scene: &common::scene::Scene,
    tolerance: f64,
) -> (f64, f64, f64) {
    let mut settings = settings("furnace");
    (settings.width, settings.height, settings.spp) = (24, 24, 256);
    let prepared = prepare(scene, &settings).expect("prepare");
    let film = render_prepared(&prepared, &settings);
    let (mut sum, mut n, mut lo, mut hi) = (0.0, 0, f64::MAX, f64::MIN);
    for (i, p) in film.pixels.iter().enumerate() {
        for k in 0..3 {
            let (m, se) = (p.mean()[k], p.variance_of_mean()[k].sqrt());
            assert!(
                (m - 1.0).abs() <= 5.0 * se + tolerance,
                "{name}: pixel {i} channel {k} is {m} +- {se}"
            );
        }
        if p.variance_of_mean()[0] > 0.0 {
            let m = p.mean()[0];
            (sum, n, lo, hi) = (sum + m, n + 1, lo.min(m), hi.max(m));
        }
    }
    assert!(n > 0, "{name}: the sphere is in view");
    (sum / n as f64, lo, hi)
}

#[test]
fn a_white_metal_reflects_all_it_receives_at_every_roughness() {
    for roughness in [0.2, 0.5, 0.8, 1.0] {
        let name = format!("metal r{roughness}");
        let (mean, lo, hi) = white_in_the_furnace(&name, &white_sphere(1.0, roughness), 0.01);
        println!("{name}: mean {mean:.4}, pixels {lo:.4} .. {hi:.4}");
        assert!((mean - 1.0).abs() < 4e-3, "{name}: the sphere's mean is {mean}");
    }
}

#[test]
fn a_white_dielectric_reflects_all_it_receives_at_every_roughness() {
    for roughness in [0.0, 0.2, 0.5, 1.0] {
        let name = format!("dielectric r{roughness}");
        let (mean, lo, hi) = white_in_the_furnace(&name, &white_sphere(0.0, roughness), 0.01);
        println!("{name}: mean {mean:.4}, pixels {lo:.4} .. {hi:.4}");
        assert!((mean - 1.0).abs() < 4e-3, "{name}: the sphere's mean is {mean}");
    }
}
