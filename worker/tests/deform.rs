//! Skinned meshes through the whole renderer: an emissive square bound to one joint that an
//! animation moves lands, frame after frame, where the joint puts it (and not where its own
//! node would), so a re-posed mesh is never rendered with a stale BVH.

mod support;

use common::settings::RenderSettings;
use serde_json::json;
use support::render_prepared;
use worker::render::scene::prepare_frame;

/// A 0.5 x 0.5 emissive square skinned to node 2, whose translation runs from x = -1 (t = 0) to
/// x = 1 (t = 2); the skinned node 0 sits at x = 100, which glTF says must be ignored. An
/// orthographic camera 3 units wide looks at it from z = 5.
fn skinned_square() -> common::scene::Scene {
    let h = 0.25f32;
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut piece = |bytes: Vec<u8>| {
        let at = bin.len();
        bin.extend(&bytes);
        bin.resize(bin.len().div_ceil(4) * 4, 0);
        views.push(json!({"buffer": 0, "byteOffset": at, "byteLength": bytes.len()}));
        views.len() - 1
    };
    let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let positions = piece(floats(&[-h, -h, 0.0, h, -h, 0.0, h, h, 0.0, -h, h, 0.0]));
    let indices = piece([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect());
    let joints = piece(vec![0u8; 16]);
    let weights = piece(floats(&[1.0, 0.0, 0.0, 0.0].repeat(4)));
    let times = piece(floats(&[0.0, 2.0]));
    let moves = piece(floats(&[-1.0, 0.0, 0.0, 1.0, 0.0, 0.0]));
    let uri = format!("data:application/octet-stream;base64,{}", support::base64(&bin));
    let gltf = json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"name": "skinned", "mesh": 0, "skin": 0, "translation": [100.0, 0.0, 0.0]},
            {"name": "camera", "camera": 0, "translation": [0.0, 0.0, 5.0]},
            {"name": "bone"}
        ],
        "skins": [{"joints": [2]}],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.5, "ymag": 1.5, "znear": 0.1, "zfar": 100.0}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3}, "indices": 1, "material": 0}]}],
        "materials": [{"emissiveFactor": [1.0, 1.0, 1.0], "doubleSided": true,
                        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0]}}],
        "animations": [{
            "channels": [{"sampler": 0, "target": {"node": 2, "path": "translation"}}],
            "samplers": [{"input": 4, "output": 5}]
        }],
        "buffers": [{"uri": uri, "byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": positions, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-h, -h, 0.0], "max": [h, h, 0.0]},
            {"bufferView": indices, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": joints, "componentType": 5121, "count": 4, "type": "VEC4"},
            {"bufferView": weights, "componentType": 5126, "count": 4, "type": "VEC4"},
            {"bufferView": times, "componentType": 5126, "count": 2, "type": "SCALAR",
             "min": [0.0], "max": [2.0]},
            {"bufferView": moves, "componentType": 5126, "count": 2, "type": "VEC3"}
        ]
    });
    common::gltf::load_slice(gltf.to_string().as_bytes(), &common::gltf::NoFiles).expect("loads")
}

#[test]
fn a_skinned_square_renders_where_its_joint_puts_it_at_each_frame() {
    let scene = skinned_square();
    // The joint moves, so the worker prepares the scene per frame.
    assert!(scene.is_animated());
    let settings = RenderSettings::from_json(
        &json!({"width": 60, "height": 60, "spp": 4, "max_depth": 0,
                "frames": {"fps": 2.0, "end": 4}})
        .to_string(),
    )
    .unwrap();
    // fps 2: frames 0, 2, 4 are t = 0, 1, 2, x = -1, 0, 1. Pixels are 0.05 wide from
    // x = -1.5: the square covers 10 columns from (x - 0.25 + 1.5) / 0.05, rows 25 to 34.
    for frame in [0i64, 2, 4] {
        let prepared = prepare_frame(&scene, &settings, None, frame).expect("prepare");
        let image = render_prepared(&prepared, &settings).mean_rgb();
        let lit: Vec<(usize, usize)> =
            (0..3600).filter(|&i| image[i][0] > 0.5).map(|i| (i % 60, i / 60)).collect();
        let span = |k: fn(&(usize, usize)) -> usize| {
            (lit.iter().map(k).min().unwrap(), lit.iter().map(k).max().unwrap())
        };
        let first = 5 + 10 * frame as usize;
        assert_eq!(
            (span(|p| p.0), span(|p| p.1), lit.len()),
            ((first, first + 9), (25, 34), 100),
            "frame {frame}"
        );
    }
}
