//! The layered material extensions (`KHR_materials_clearcoat`, `KHR_materials_sheen`,
//! `KHR_materials_anisotropy`, `KHR_materials_iridescence`) through the whole renderer, in the white furnace: the shipped
//! furnace sphere made white Lambert (albedo exactly 1) under a sheen, a coat or both, lit by a
//! uniform white environment. The spec's albedo scaling takes from the base what a layer
//! reflects, so no pixel may exceed 1 beyond its noise; with a sheen alone (whose scaling is its
//! own albedo) the sphere stays white within the albedo table's error.
//! Such materials render on the wavefront where the CPU has one (`worker/tests/scenes.rs` checks
//! its bits against the scalar path tracer's).

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
    // Where the CPU has the wavefront, layered materials keep their paths on it.
    assert!(prepared.wavefront().is_some(), "{name}: the wavefront's tables");
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
fn a_coat_over_white_lambert_keeps_the_sphere_white() {
    for roughness in [0.3, 1.0] {
        let scene = layered_furnace(
            &format!("coat-{roughness}"),
            json!({"KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatRoughnessFactor": roughness}}),
        );
        let mean = furnace_mean("coat", &scene);
        println!("coat r{roughness}: the sphere's mean is {mean}");
        // The layer below takes what the coat's lobe does not reflect, its single-scattering
        // albedo included: the sphere stays white (a rough coat's lobe loses a third of what
        // its Fresnel weight takes at normal incidence, and more at grazing angles).
        assert!((mean - 1.0).abs() < 3e-3, "coat r{roughness}: the sphere's mean is {mean}");
    }
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

/// A floor quad with vertex normals and the given TANGENT (no texture coordinates), an
/// anisotropic rough metal rotated by `rotation`, lit by a point light off to one side and seen
/// straight down by an orthographic camera.
fn anisotropic_quad(tag: &str, tangent: [f32; 4], rotation: f64) -> common::scene::Scene {
    let positions: [[f32; 3]; 4] =
        [[-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 0.0, -1.0]];
    let mut bytes: Vec<u8> = positions.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend((0..4).flat_map(|_| [0.0f32, 1.0, 0.0]).flat_map(|v| v.to_le_bytes()));
    bytes.extend((0..4).flat_map(|_| tangent).flat_map(|v| v.to_le_bytes()));
    bytes.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|v| v.to_le_bytes()));
    let doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_materials_anisotropy", "KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": 3.0}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0},
            {"camera": 0, "translation": [0.0, 2.0, 0.0],
             "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]},
            {"extensions": {"KHR_lights_punctual": {"light": 0}}, "translation": [0.3, 0.6, 0.2]}
        ],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.01, "zfar": 10.0}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TANGENT": 2}, "indices": 3, "material": 0}]}],
        "materials": [{
            "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.9, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.4},
            "extensions": {"KHR_materials_anisotropy": {"anisotropyStrength": 0.9, "anisotropyRotation": rotation}}
        }],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1.0, 0.0, -1.0], "max": [1.0, 0.0, 1.0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 64},
            {"buffer": 0, "byteOffset": 160, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir = std::env::temp_dir().join(format!("renderfarm-aniso-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("quad.gltf");
    std::fs::write(&path, doc.to_string()).unwrap();
    common::gltf::load_path(&path).unwrap()
}

/// Anisotropy follows the mesh's TANGENT attribute where there are no texture coordinates to
/// derive a direction from: turning the tangent by a quarter turn about the normal draws the same
/// highlight as turning `anisotropyRotation` by a quarter turn, and a different one from the
/// untouched tangent.
#[test]
fn anisotropy_follows_the_mesh_tangents() {
    let mut settings = common::settings::RenderSettings {
        width: 32,
        height: 32,
        spp: 16,
        max_depth: 4,
        ..Default::default()
    };
    settings.seed = 7;
    let image = |tag: &str, tangent: [f32; 4], rotation: f64| {
        render(&anisotropic_quad(tag, tangent, rotation), &settings).mean_rgb()
    };
    let along_x = image("x", [1.0, 0.0, 0.0, 1.0], 0.0);
    let along_z = image("z", [0.0, 0.0, -1.0, 1.0], 0.0);
    let rotated = image("rotated", [1.0, 0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2);
    let diff = |a: &[[f32; 3]], b: &[[f32; 3]]| {
        a.iter().zip(b).map(|(p, q)| (p[0] - q[0]).abs() as f64).sum::<f64>() / a.len() as f64
    };
    let mean = along_x.iter().map(|p| p[0] as f64).sum::<f64>() / along_x.len() as f64;
    let (turned, same) = (diff(&along_x, &along_z), diff(&along_z, &rotated));
    eprintln!("mean {mean:.4}; tangent turned: {turned:.2e}; turned tangent against turned rotation: {same:.2e}");
    assert!(turned > 0.05 * mean, "turning the tangent changes the highlight ({turned} of {mean})");
    assert!(same < 1e-3 * mean, "a turned tangent is a turned rotation ({same} of {mean})");
}

/// A scene of two quads built in code: an emitting square (radiance 1) of half size `half` at
/// height `y`, facing `facing` (+1: up, -1: down), with a clear coat of `coat` (none at 0), and a
/// white Lambert floor at y = 0; an orthographic camera at height 2 looks straight down at the
/// square of half size `view` centred at x = `look_x`.
fn coated_emitter(
    tag: &str,
    coat: f64,
    y: f32,
    half: f32,
    facing: f32,
    look_x: f64,
) -> common::scene::Scene {
    let quad = |h: f32, y: f32, up: bool| -> Vec<[f32; 3]> {
        let mut q = vec![[-h, y, h], [h, y, h], [h, y, -h], [-h, y, -h]];
        if !up {
            q.reverse();
        }
        q
    };
    let mut bytes: Vec<u8> = Vec::new();
    for q in [quad(half, y, facing > 0.0), quad(5.0, 0.0, true)] {
        bytes.extend(q.iter().flatten().flat_map(|v| v.to_le_bytes()));
    }
    bytes.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|v| v.to_le_bytes()));
    let mut emitter = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0},
        "emissiveFactor": [1.0, 1.0, 1.0]
    });
    if coat > 0.0 {
        emitter["extensions"] = json!({"KHR_materials_clearcoat": {"clearcoatFactor": coat}});
    }
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0}, {"mesh": 1},
            {"camera": 0, "translation": [look_x, 2.0, 0.0],
             "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}
        ],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 0.1, "ymag": 0.1, "znear": 0.01, "zfar": 10.0}}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 1}, "indices": 2, "material": 1}]}
        ],
        "materials": [emitter, {
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0},
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
        }],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-half, y, -half], "max": [half, y, half]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-5.0, 0.0, -5.0], "max": [5.0, 0.0, 5.0]},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir = std::env::temp_dir().join(format!("renderfarm-coated-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("coated.gltf");
    std::fs::write(&path, doc.to_string()).unwrap();
    common::gltf::load_path(&path).unwrap()
}

/// A clear coat lies over emission and darkens it by its reflection (the extension's
/// emission x (1 - clearcoat x F_c)): an emitter seen head-on under a full coat is 0.96 of itself
/// exactly (camera rays and sampled bounces that hit an emitter share that evaluation), and a
/// floor lit by a small coated emitter overhead, almost all of it through light sampling, takes
/// 0.96 of the light it takes from the bare emitter (the same paths and numbers: exact to
/// rounding and to the coat's Fresnel at cosines above 0.92, about 2e-6).
#[test]
fn a_clear_coat_darkens_the_emission_below_it() {
    let settings = common::settings::RenderSettings {
        width: 8,
        height: 8,
        spp: 64,
        // Direct light only: the coat also reflects the lit floor back onto it, a little.
        max_depth: 1,
        ..Default::default()
    };
    let mean = |scene: &common::scene::Scene| {
        let film = render(scene, &settings);
        film.mean_rgb().iter().map(|p| p[0] as f64).sum::<f64>() / film.pixels.len() as f64
    };
    // Head-on: a large emitter facing the camera fills the view.
    let bare = mean(&coated_emitter("seen-bare", 0.0, 1.0, 3.0, 1.0, 0.0));
    let coated = mean(&coated_emitter("seen-coated", 1.0, 1.0, 3.0, 1.0, 0.0));
    assert_eq!(bare, 1.0);
    assert!((coated - 0.96).abs() < 1e-6, "seen head-on: {coated}");
    // A floor beside and below a small emitter facing down.
    let bare = mean(&coated_emitter("lit-bare", 0.0, 1.0, 0.05, -1.0, 0.3));
    let coated = mean(&coated_emitter("lit-coated", 1.0, 1.0, 0.05, -1.0, 0.3));
    eprintln!("floor: {bare:.6} bare, {coated:.6} coated, ratio {:.6}", coated / bare);
    assert!(bare > 0.0);
    assert!((coated / bare - 0.96).abs() < 2e-5, "lit: {coated} against {bare}");
}
