//! `KHR_materials_variants` through the real programs: `coordinator render --variant NAME`
//! renders the named variant's materials, and an unknown name is refused with the scene's
//! variants, by `render` before it renders and by the service before any work is leased.

use std::{path::Path, process::Command};

use base64::Engine;
use serde_json::json;
use tests::*;

/// A square facing an orthographic camera and filling its view, red by default; the variants
/// "red" and "blue" map its material to an unlit red or an unlit blue.
fn variants_scene(dir: &Path) -> std::path::PathBuf {
    let positions: [[f32; 3]; 4] =
        [[-2.0, -2.0, 0.0], [2.0, -2.0, 0.0], [2.0, 2.0, 0.0], [-2.0, 2.0, 0.0]];
    let mut bytes: Vec<u8> = positions.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|v| v.to_le_bytes()));
    let unlit = |name: &str, color: [f32; 4]| {
        json!({"name": name, "pbrMetallicRoughness": {"baseColorFactor": color},
               "extensions": {"KHR_materials_unlit": {}}})
    };
    let doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_materials_variants", "KHR_materials_unlit"],
        "extensions": {"KHR_materials_variants": {"variants": [{"name": "red"}, {"name": "blue"}]}},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"camera": 0, "translation": [0.0, 0.0, 3.0]}],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.1, "zfar": 10.0}}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0}, "indices": 1, "material": 0,
            "extensions": {"KHR_materials_variants": {"mappings": [
                {"material": 0, "variants": [0]},
                {"material": 1, "variants": [1]}
            ]}}
        }]}],
        "materials": [unlit("red", [1.0, 0.0, 0.0, 1.0]), unlit("blue", [0.0, 0.0, 1.0, 1.0])],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-2.0, -2.0, 0.0], "max": [2.0, 2.0, 0.0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&bytes)
        )}]
    });
    let path = dir.join("variants.gltf");
    std::fs::write(&path, doc.to_string()).unwrap();
    path
}

/// `coordinator render` with `extra` arguments: its output.
fn render(scene: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(bin_dir().join("coordinator"))
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(out)
        .args(["--spp", "1", "--width", "4", "--height", "4", "--workers", "1"])
        .args(extra)
        .output()
        .unwrap()
}

/// The mean of channel `name` over the image.
fn channel_mean(exr: &[u8], name: &str) -> f32 {
    let ch = channels(exr);
    let values = &ch.iter().find(|(n, _)| n == name).unwrap().1;
    values.iter().map(|&b| f32::from_bits(b)).sum::<f32>() / values.len() as f32
}

#[test]
fn render_draws_the_named_variant_and_refuses_an_unknown_one() {
    let dir = temp_dir("variants-render");
    let scene = variants_scene(&dir);
    for (variant, expected) in
        [(None, [1.0, 0.0]), (Some("blue"), [0.0, 1.0]), (Some("red"), [1.0, 0.0])]
    {
        let out = dir.join(format!("{}.exr", variant.unwrap_or("default")));
        let extra: Vec<&str> = variant.map(|v| vec!["--variant", v]).unwrap_or_default();
        let output = render(&scene, &out, &extra);
        assert!(
            output.status.success(),
            "{variant:?}: {}",
            String::from_utf8_lossy(&output.stderr)
        );
        let exr = std::fs::read(&out).unwrap();
        let (r, b) = (channel_mean(&exr, "R"), channel_mean(&exr, "B"));
        assert_eq!([r, b], expected, "{variant:?}: R {r}, B {b}");
    }
    // The same through the settings file's key.
    let settings = dir.join("blue.json");
    std::fs::write(&settings, json!({"variant": "blue"}).to_string()).unwrap();
    let out = dir.join("settings-blue.exr");
    let output = render(&scene, &out, &["--settings", settings.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(channel_mean(&std::fs::read(&out).unwrap(), "B"), 1.0);

    let out = dir.join("green.exr");
    let output = render(&scene, &out, &["--variant", "green"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "an unknown variant rendered");
    assert!(stderr.contains("green") && stderr.contains("red, blue"), "{stderr}");
    assert!(!out.exists(), "no image for a refused variant");
}

#[test]
fn the_service_refuses_a_job_for_an_unknown_variant_before_leasing() {
    let dir = temp_dir("variants-serve");
    let scene = variants_scene(&dir);
    let port = free_port();
    let _coordinator = start_coordinator(&dir.join("data"), port, &[]);
    let url = format!("http://127.0.0.1:{port}");
    let hash = upload(&url, &std::fs::read(&scene).unwrap());
    let a = post_json(
        &format!("{url}/api/v1/jobs"),
        &json!({"scene": hash, "settings": {"variant": "green", "width": 4, "height": 4, "spp": 1}}),
    );
    assert_eq!(a.status, 422, "{}", a.error());
    assert!(a.error().contains("green") && a.error().contains("red, blue"), "{}", a.error());
    let jobs = get(&format!("{url}/api/v1/jobs")).json();
    assert_eq!(jobs["jobs"].as_array().map_or(0, |j| j.len()), 0, "{jobs}");
    // A known variant is taken.
    create_job(&url, &hash, &json!({"variant": "blue", "width": 4, "height": 4, "spp": 1}), 0);
}
