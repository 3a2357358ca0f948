//! Animated frames through the real binary: `coordinator render --frames a..b` poses the scene at
//! each frame's time (frame / fps) and writes `OUT_####.exr`; an emissive square moved by a LINEAR
//! translation lands exactly where the animation puts it, frames are bitwise the same on one or
//! three workers, and real animated glTF samples render at several frames.

use std::{path::Path, process::Command};

use base64::Engine;
use serde_json::json;
use tests::*;

/// A 0.5 x 0.5 emissive square translated from x = -1 (t = 0) to x = 1 (t = 2), seen by an
/// orthographic camera 3 units wide.
fn moving_square(dir: &Path) -> std::path::PathBuf {
    let positions: [[f32; 3]; 4] =
        [[-0.25, -0.25, 0.0], [0.25, -0.25, 0.0], [0.25, 0.25, 0.0], [-0.25, 0.25, 0.0]];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let times: [f32; 2] = [0.0, 2.0];
    let moves: [[f32; 3]; 2] = [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
    let mut bin: Vec<u8> = Vec::new();
    bin.extend(positions.iter().flatten().flat_map(|v| v.to_le_bytes()));
    bin.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    bin.extend([0u8; 4]);
    bin.extend(times.iter().flat_map(|v| v.to_le_bytes()));
    bin.extend(moves.iter().flatten().flat_map(|v| v.to_le_bytes()));
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let gltf = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "square", "mesh": 0},
            {"name": "camera", "camera": 0, "translation": [0.0, 0.0, 5.0]}
        ],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.5, "ymag": 1.5, "znear": 0.1, "zfar": 100.0}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"emissiveFactor": [1.0, 1.0, 1.0], "doubleSided": true,
                        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0]}}],
        "buffers": [{"uri": uri, "byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
            {"buffer": 0, "byteOffset": 64, "byteLength": 8},
            {"buffer": 0, "byteOffset": 72, "byteLength": 24}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-0.25, -0.25, 0.0], "max": [0.25, 0.25, 0.0]},
            {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0.0], "max": [2.0]},
            {"bufferView": 3, "componentType": 5126, "count": 2, "type": "VEC3"}
        ],
        "animations": [{
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
            "samplers": [{"input": 2, "output": 3, "interpolation": "LINEAR"}]
        }]
    });
    let path = dir.join("moving-square.gltf");
    std::fs::write(&path, gltf.to_string()).unwrap();
    path
}

fn render_frames(
    scene: &Path,
    settings: &serde_json::Value,
    frames: &str,
    workers: u32,
    out: &Path,
) {
    let settings_path = out.with_extension("json");
    std::fs::write(&settings_path, settings.to_string()).unwrap();
    let output = Command::new(bin_dir().join("coordinator"))
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(out)
        .arg("--settings")
        .arg(&settings_path)
        .args(["--frames", frames, "--workers", &workers.to_string()])
        .output()
        .unwrap();
    assert!(output.status.success(), "render failed: {}", String::from_utf8_lossy(&output.stderr));
}

fn frame_file(out: &Path, frame: i64) -> std::path::PathBuf {
    let stem = out.file_stem().unwrap().to_string_lossy().into_owned();
    out.with_file_name(format!("{stem}_{frame:04}.exr"))
}

fn red(exr: &[u8]) -> Vec<f32> {
    let ch = channels(exr);
    ch.iter().find(|(n, _)| n == "R").unwrap().1.iter().map(|&b| f32::from_bits(b)).collect()
}

#[test]
fn frames_pose_the_animation_at_frame_over_fps() {
    let dir = temp_dir("anim-frames");
    let scene = moving_square(&dir);
    // fps 2: frames 0..4 are t = 0, 0.5, 1, 1.5, 2, x = -1, -0.5, 0, 0.5, 1.
    let settings =
        json!({"width": 60, "height": 60, "spp": 4, "max_depth": 0, "frames": {"fps": 2.0}});
    let out = dir.join("square.exr");
    render_frames(&scene, &settings, "0..4", 2, &out);
    for frame in 0..=4i64 {
        let x = -1.0 + 0.5 * frame as f64;
        // Pixels are 0.05 wide from x = -1.5; the square covers [x - 0.25, x + 0.25].
        let first = ((x - 0.25 + 1.5) / 0.05).round() as usize;
        let image = red(&std::fs::read(frame_file(&out, frame)).unwrap());
        let lit: Vec<(usize, usize)> =
            (0..3600).filter(|&i| image[i] > 0.0).map(|i| (i % 60, i / 60)).collect();
        let cols = (lit.iter().map(|p| p.0).min(), lit.iter().map(|p| p.0).max());
        let rows = (lit.iter().map(|p| p.1).min(), lit.iter().map(|p| p.1).max());
        assert_eq!(
            (cols, rows),
            ((Some(first), Some(first + 9)), (Some(25), Some(34))),
            "frame {frame}: lit columns and rows"
        );
        for row in [25usize, 30, 34] {
            for col in 0..60 {
                let expected = if (first..first + 10).contains(&col) { 1.0 } else { 0.0 };
                let v = image[row * 60 + col];
                assert!(
                    (v - expected).abs() < 1e-6,
                    "frame {frame} pixel ({col}, {row}): {v}, expected {expected}"
                );
            }
        }
        for row in [0usize, 24, 35, 59] {
            assert!(
                image[row * 60..row * 60 + 60].iter().all(|&v| v == 0.0),
                "frame {frame} row {row}"
            );
        }
        assert!(frame_file(&out, frame).with_extension("png").exists());
    }
}

#[test]
fn animated_frames_are_identical_on_one_or_three_workers() {
    let dir = temp_dir("anim-determinism");
    let scene = moving_square(&dir);
    let settings = json!({"width": 40, "height": 40, "spp": 16, "samples_per_task": 4,
                          "tile_size": 16, "frames": {"fps": 3.0}, "environment": {"color": [0.2, 0.3, 0.4]}});
    let (one, three) = (dir.join("one.exr"), dir.join("three.exr"));
    render_frames(&scene, &settings, "1..3", 1, &one);
    render_frames(&scene, &settings, "1..3", 3, &three);
    for frame in 1..=3 {
        let a = std::fs::read(frame_file(&one, frame)).unwrap();
        let b = std::fs::read(frame_file(&three, frame)).unwrap();
        assert_same_image(&a, &b, &format!("frame {frame}"));
    }
    let (f1, f3) =
        (std::fs::read(frame_file(&one, 1)).unwrap(), std::fs::read(frame_file(&one, 3)).unwrap());
    assert_ne!(red(&f1), red(&f3), "the square did not move between frames");
}

#[test]
fn real_animated_samples_render_at_several_frames() {
    let dir = temp_dir("anim-real");
    let real = repo().join("../shared/scenes/real");
    for (name, path) in [
        ("box-animated", "BoxAnimated/glTF/BoxAnimated.gltf"),
        ("animated-cube", "AnimatedCube/glTF/AnimatedCube.gltf"),
        ("animated-triangle", "AnimatedTriangle/glTF-Embedded/AnimatedTriangle.gltf"),
    ] {
        let settings = json!({"width": 32, "height": 32, "spp": 4, "frames": {"fps": 2.0},
                              "environment": {"color": [1.0, 1.0, 1.0]}});
        let out = dir.join(format!("{name}.exr"));
        render_frames(&real.join(path), &settings, "0..2", 2, &out);
        let images: Vec<Vec<f32>> =
            (0..=2).map(|f| red(&std::fs::read(frame_file(&out, f)).unwrap())).collect();
        for (f, image) in images.iter().enumerate() {
            assert!(image.iter().all(|v| v.is_finite() && *v >= 0.0), "{name} frame {f}");
        }
        assert!(images[0] != images[1] || images[1] != images[2], "{name}: nothing moved");
    }
}

#[test]
fn motion_blur_of_an_animated_scene_is_refused_with_a_clear_message() {
    let dir = temp_dir("anim-blur");
    let scene = moving_square(&dir);
    let settings = dir.join("blur.json");
    std::fs::write(
        &settings,
        json!({"width": 16, "height": 16, "spp": 1, "shutter": {"open": 0.0, "close": 0.5}})
            .to_string(),
    )
    .unwrap();
    let output = Command::new(bin_dir().join("coordinator"))
        .arg("render")
        .arg(&scene)
        .arg("-o")
        .arg(dir.join("blur.exr"))
        .arg("--settings")
        .arg(&settings)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("motion blur") && stderr.contains("shutter"), "{stderr}");
}
