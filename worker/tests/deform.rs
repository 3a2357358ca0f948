//! Skinned meshes through the whole renderer: an emissive square bound to one joint that an
//! animation moves lands, frame after frame, where the joint puts it (and not where its own
//! node would), so a re-posed mesh is never rendered with a stale BVH; and a bar whose joint
//! turns within the shutter blurs along the arc, to its exact time-averaged coverage.

mod support;

use common::settings::RenderSettings;
use serde_json::json;
use support::render_prepared;
use worker::render::{
    motion::{deform_keys, KEY_TOLERANCE, MAX_KEYS},
    scene::prepare_frame,
};

/// A 0.5 x 0.5 emissive square skinned to node 2, whose translation runs from x = -1 (t = 0) to
/// x = 1 (t = 2); the skinned node 0 sits at x = 100, which glTF says must be ignored. An
/// orthographic camera 3 units wide looks at it from z = 5.
fn skinned_square() -> common::scene::Scene {
    skinned_rect((0.25, 0.25), "translation", &[0.0, 2.0], &[-1.0, 0.0, 0.0, 1.0, 0.0, 0.0])
}

/// An emissive rectangle of half-size `(hx, hy)` skinned to node 2, which a LINEAR channel on
/// `path` animates (`times`, `values`); otherwise as `skinned_square`.
fn skinned_rect(
    (hx, hy): (f32, f32),
    path: &str,
    key_times: &[f32],
    key_values: &[f32],
) -> common::scene::Scene {
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
    let positions = piece(floats(&[-hx, -hy, 0.0, hx, -hy, 0.0, hx, hy, 0.0, -hx, hy, 0.0]));
    let indices = piece([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect());
    let joints = piece(vec![0u8; 16]);
    let weights = piece(floats(&[1.0, 0.0, 0.0, 0.0].repeat(4)));
    let times = piece(floats(key_times));
    let moves = piece(floats(key_values));
    let width = key_values.len() / key_times.len();
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
            "channels": [{"sampler": 0, "target": {"node": 2, "path": path}}],
            "samplers": [{"input": 4, "output": 5}]
        }],
        "buffers": [{"uri": uri, "byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": [
            {"bufferView": positions, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-hx, -hy, 0.0], "max": [hx, hy, 0.0]},
            {"bufferView": indices, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": joints, "componentType": 5121, "count": 4, "type": "VEC4"},
            {"bufferView": weights, "componentType": 5126, "count": 4, "type": "VEC4"},
            {"bufferView": times, "componentType": 5126, "count": key_times.len(), "type": "SCALAR",
             "min": [key_times[0]], "max": [key_times[key_times.len() - 1]]},
            {"bufferView": moves, "componentType": 5126, "count": key_times.len(),
             "type": if width == 4 { "VEC4" } else { "VEC3" }}
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

/// A bar 2 x 0.1 skinned to a joint that turns a quarter turn about z over the shutter [0, 1):
/// the pose is not linear in time, so the mesh gets keys until the chords stray less than
/// `KEY_TOLERANCE` of its size, and the image is the bar's exact time-averaged coverage (a
/// chord between the shutter's ends alone would shrink the bar to 1/sqrt(2) half-way).
#[test]
fn a_bar_whose_joint_turns_blurs_along_the_arc_to_its_exact_coverage() {
    let (s, c) = (std::f32::consts::FRAC_PI_4.sin(), std::f32::consts::FRAC_PI_4.cos());
    let scene =
        skinned_rect((1.0, 0.05), "rotation", &[0.0, 1.0], &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, s, c]);
    // The keys: more than the shutter's two ends, each chord within the tolerance.
    let anim = scene.animation.as_ref().expect("animated");
    let keys = deform_keys(&scene.meshes[0], anim, (0.0, 1.0));
    let size = 2.0f64.hypot(0.1);
    assert!(keys.len() > 4 && keys.len() < MAX_KEYS, "{} keys", keys.len());
    for pair in keys.windows(2) {
        let ((t0, a), (t1, b)) = (&pair[0], &pair[1]);
        for k in 1..8 {
            let f = k as f64 / 8.0;
            let mut posed = scene.meshes[0].clone();
            let t = t0 + (t1 - t0) * f;
            let mut worlds = std::collections::HashMap::new();
            let deform = posed.deform.take().unwrap();
            let joint = anim.world_memo(2, t, &mut worlds);
            deform.pose(&deform.weights_at(Some(anim), t), |_| joint, &mut posed);
            for ((p, pa), pb) in posed.positions.iter().zip(&a.positions).zip(&b.positions) {
                let line = pa.as_dvec3() + (pb.as_dvec3() - pa.as_dvec3()) * f;
                let stray = (p.as_dvec3() - line).length();
                assert!(stray <= 1.01 * KEY_TOLERANCE * size, "{stray} at t = {t}");
            }
        }
    }
    let settings = RenderSettings::from_json(
        &json!({"width": 60, "height": 60, "spp": 256, "max_depth": 0,
                "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0}})
        .to_string(),
    )
    .unwrap();
    let prepared = prepare_frame(&scene, &settings, None, 0).expect("prepare");
    let film = render_prepared(&prepared, &settings);
    let image = film.mean_rgb();
    let exact = |col, row| worker::test_scenes::quarter_turn_bar_coverage(col, row, 12);
    let mut worst = 0.0f64;
    for row in (0..60).step_by(3) {
        for col in (0..60).step_by(3) {
            let i = row * 60 + col;
            let (v, e) = (image[i][0] as f64, exact(col, row));
            let sigma = film.pixels[i].variance_of_mean()[0].sqrt();
            assert!((v - e).abs() <= 4.0 * sigma + 0.02, "pixel ({col}, {row}): {v} vs exact {e}");
            worst = worst.max((v - e).abs());
        }
    }
    eprintln!("turning bar: {} keys, largest pixel error {worst:.4}", keys.len());
    // Near the tip on the diagonal (radius 0.95) the arc passes and the chord between the
    // shutter's ends would not.
    let (col, row) = (43, 16);
    let tip = image[row * 60 + col][0] as f64;
    assert!(tip > 0.03, "the bar's tip does not sweep the arc: {tip}");
    assert!((tip - exact(col, row)).abs() <= 0.02, "tip {tip} vs exact {}", exact(col, row));
}
