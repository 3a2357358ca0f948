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
    common::gltf::load_path(&white_sphere_file(metallic, roughness, "")).unwrap()
}

/// [`white_sphere`]'s file (`tag` tells test files apart).
fn white_sphere_file(metallic: f64, roughness: f64, tag: &str) -> std::path::PathBuf {
    let tag = format!("energy-{metallic}-{roughness}{tag}");
    edited_scene("furnace", &tag, |json| {
        let m = &mut json["materials"][0];
        m["pbrMetallicRoughness"] = json!({
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "metallicFactor": metallic,
            "roughnessFactor": roughness
        });
        m.as_object_mut().unwrap().remove("extensions");
    })
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
    for roughness in [0.05, 0.2, 0.5, 0.8, 1.0] {
        let name = format!("metal r{roughness}");
        let (mean, lo, hi) = white_in_the_furnace(&name, &white_sphere(1.0, roughness), 0.01);
        println!("{name}: mean {mean:.4}, pixels {lo:.4} .. {hi:.4}");
        assert!((mean - 1.0).abs() < 4e-3, "{name}: the sphere's mean is {mean}");
    }
}

#[test]
fn a_white_dielectric_reflects_all_it_receives_at_every_roughness() {
    for roughness in [0.0, 0.05, 0.2, 0.5, 1.0] {
        let name = format!("dielectric r{roughness}");
        let (mean, lo, hi) = white_in_the_furnace(&name, &white_sphere(0.0, roughness), 0.01);
        println!("{name}: mean {mean:.4}, pixels {lo:.4} .. {hi:.4}");
        assert!((mean - 1.0).abs() < 4e-3, "{name}: the sphere's mean is {mean}");
    }
}

/// The BSDFs are reciprocal (the albedo scaling and the multiple-scattering lobe are symmetric
/// in `wo` and `wi`), so light tracing and photon mapping, which evaluate them from the light's
/// side, see the same white spheres: the image's mean within 4 standard errors plus 0.2% of 1
/// (the sphere fills about 40% of it) under `bdpt` (through a perspective camera, which light
/// tracing reaches) and `sppm`.
#[test]
fn bidirectional_and_photon_mapping_see_the_same_white_spheres() {
    for (metallic, roughness) in [(1.0, 1.0), (1.0, 0.05), (0.0, 0.2), (0.0, 1.0)] {
        let path = white_sphere_file(metallic, roughness, "-perspective");
        with_perspective_camera(&path, 2.0 * (1.0f64 / 3.0).atan());
        let scene = common::gltf::load_path(&path).unwrap();
        let furnace = white_furnace(16, 256);
        let (camera, light) = render_bdpt_with(&scene, &furnace, None);
        let sum = bdpt_sum(&camera, &light);
        let n = sum.len() as f64;
        let means = [0, 1, 2].map(|c| {
            let mean = sum.iter().map(|p| p.0[c]).sum::<f64>() / n;
            (mean, (sum.iter().map(|p| p.1[c]).sum::<f64>() / (n * n)).sqrt())
        });
        assert_white(&format!("bdpt m{metallic} r{roughness}"), means, 2e-3);
        let film = render_sppm_with(&scene, &furnace, 64, 2, None);
        assert_white(&format!("sppm m{metallic} r{roughness}"), image_mean(&film), 2e-3);
    }
}
