//! The layered material extensions (`KHR_materials_clearcoat`, `KHR_materials_sheen`,
//! `KHR_materials_anisotropy`, `KHR_materials_iridescence`) through the whole renderer, in the white furnace: the shipped
//! furnace sphere made white Lambert (albedo exactly 1) under a sheen, a coat or both, lit by a
//! uniform white environment. The spec's albedo scaling takes from the base what a layer
//! reflects, so no pixel may exceed 1 beyond its noise; with a sheen alone (whose scaling is its
//! own albedo) the sphere stays white within the albedo table's error.
//! Such materials are rendered by the scalar path tracer only.

mod support;

use serde_json::{json, Value};
use support::*;
use worker::render::scene::prepare;

/// The furnace sphere, white Lambert, with `extensions` added to its material.
fn layered_furnace(tag: &str, extensions: Value) -> common::scene::Scene {
    let path = edited_scene("furnace", tag, |json| {
        let m = &mut json["materials"][0];
        m["pbrMetallicRoughness"]["baseColorFactor"] = json!([1.0, 1.0, 1.0, 1.0]);
        for (k, v) in extensions.as_object().unwrap() {
            m["extensions"][k] = v.clone();
        }
        json["extensionsUsed"] = json!([
            "KHR_materials_specular",
            "KHR_materials_sheen",
            "KHR_materials_clearcoat",
            "KHR_materials_anisotropy",
            "KHR_materials_iridescence"
        ]);
    });
    common::gltf::load_path(&path).unwrap()
}

/// Renders `scene` in the white furnace and checks every pixel's every channel against 1;
/// returns the mean of the first channel over the pixels that see the sphere.
fn furnace_mean(name: &str, scene: &common::scene::Scene) -> f64 {
    let mut settings = settings("furnace");
    (settings.width, settings.height, settings.spp) = (24, 24, 128);
    let prepared = prepare(scene, &settings).expect("prepare");
    assert!(prepared.wavefront.is_none(), "{name}: layered materials take the scalar path");
    let film = render_prepared(&prepared, &settings);
    let (mut sum, mut n) = (0.0, 0);
    for (i, p) in film.pixels.iter().enumerate() {
        for k in 0..3 {
            let (m, se) = (p.mean()[k], p.variance_of_mean()[k].sqrt());
            assert!(m <= 1.0 + 5.0 * se + 2e-3, "{name}: pixel {i} channel {k} is {m} +- {se}");
        }
        let se = p.variance_of_mean()[0].sqrt();
        if se > 0.0 {
            sum += p.mean()[0];
            n += 1;
        }
    }
    assert!(n > 0, "{name}: the sphere is in view");
    sum / n as f64
}

#[test]
fn a_white_sheen_over_white_lambert_stays_white() {
    for roughness in [0.2, 0.7] {
        let scene = layered_furnace(
            &format!("sheen-{roughness}"),
            json!({"KHR_materials_sheen": {"sheenColorFactor": [1.0, 1.0, 1.0], "sheenRoughnessFactor": roughness}}),
        );
        let mean = furnace_mean("sheen", &scene);
        assert!((mean - 1.0).abs() < 5e-3, "sheen r{roughness}: the sphere's mean is {mean}");
    }
}

#[test]
fn a_coat_over_white_lambert_makes_no_light() {
    let scene = layered_furnace(
        "coat",
        json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatRoughnessFactor": 0.3}}),
    );
    let mean = furnace_mean("coat", &scene);
    // A smooth-ish coat loses only what its single-scattering GGX does: the sphere stays
    // nearly white.
    assert!(mean <= 1.0 + 2e-3 && mean > 0.97, "coat: the sphere's mean is {mean}");
}

#[test]
fn every_layer_at_once_makes_no_light() {
    let scene = layered_furnace(
        "all",
        json!({
            "KHR_materials_sheen": {"sheenColorFactor": [0.9, 1.0, 0.8], "sheenRoughnessFactor": 0.5},
            "KHR_materials_clearcoat": {"clearcoatFactor": 0.7, "clearcoatRoughnessFactor": 0.1},
            "KHR_materials_anisotropy": {"anisotropyStrength": 0.9, "anisotropyRotation": 0.4}
        }),
    );
    let mean = furnace_mean("all", &scene);
    assert!(mean <= 1.0 + 2e-3, "all layers: the sphere's mean is {mean}");
}

#[test]
fn an_iridescent_film_makes_no_light() {
    // A film over a white metal (whose film Fresnel is at most 1 in every channel) under a coat,
    // and over the white Lambert base without a specular layer (the film alone reflects there,
    // and the base below loses the largest channel of what it reflects).
    for (tag, metallic, film) in [
        (
            "metal",
            1.0,
            json!({"iridescenceFactor": 0.8, "iridescenceIor": 1.3, "iridescenceThicknessMaximum": 700.0}),
        ),
        ("lambert", 0.0, json!({"iridescenceFactor": 1.0, "iridescenceIor": 1.8})),
    ] {
        let mut scene = layered_furnace(
            &format!("film-{tag}"),
            json!({
                "KHR_materials_iridescence": film,
                "KHR_materials_clearcoat": {"clearcoatFactor": 0.5, "clearcoatRoughnessFactor": 0.2}
            }),
        );
        let m = &mut scene.materials[0];
        (m.metallic, m.roughness) = (metallic, 0.4);
        assert!(m.iridescence.is_some(), "{tag}: the film is loaded");
        let mean = furnace_mean(tag, &scene);
        println!("film over {tag}: the sphere's mean is {mean}");
        assert!(mean <= 1.0 + 2e-3, "film over {tag}: the sphere's mean is {mean}");
    }
}
