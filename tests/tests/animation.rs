//! Animated frames through the real binary: `coordinator render --frames a..b` poses the scene at
//! each frame's time (frame / fps) and writes `OUT_####.exr`; an emissive square moved by a LINEAR
//! translation lands exactly where the animation puts it, frames are bitwise the same on one or
//! three workers, and real animated glTF samples render at several frames.

use std::{path::Path, process::Command};

use base64::Engine;
use serde_json::json;
use tests::*;

/// An animation channel: target path, key times, values (flattened).
struct Channel {
    path: &'static str,
    times: Vec<f32>,
    values: Vec<f32>,
}

/// An emissive rectangle of half-size (hx, hy) at the origin (node 0) and an orthographic camera
/// 3 units wide at z = 5 (node 1), each optionally animated (LINEAR).
fn emissive_scene(
    dir: &Path,
    name: &str,
    (hx, hy): (f32, f32),
    shape: Option<Channel>,
    camera: Option<Channel>,
) -> std::path::PathBuf {
    let positions: [[f32; 3]; 4] = [[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bin: Vec<u8> = Vec::new();
    bin.extend(positions.iter().flatten().flat_map(|v| v.to_le_bytes()));
    bin.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    bin.extend([0u8; 4]);
    let mut views = vec![
        json!({"buffer": 0, "byteOffset": 0, "byteLength": 48}),
        json!({"buffer": 0, "byteOffset": 48, "byteLength": 12}),
    ];
    let mut accessors = vec![
        json!({"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
               "min": [-hx, -hy, 0.0], "max": [hx, hy, 0.0]}),
        json!({"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}),
    ];
    let (mut samplers, mut channels) = (Vec::new(), Vec::new());
    for (node, channel) in [(0, shape), (1, camera)] {
        let Some(c) = channel else { continue };
        let width = c.values.len() / c.times.len();
        for (data, ty) in
            [(&c.times, "SCALAR"), (&c.values, if width == 4 { "VEC4" } else { "VEC3" })]
        {
            let offset = bin.len();
            bin.extend(data.iter().flat_map(|v| v.to_le_bytes()));
            views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len() * 4}));
            let mut acc = json!({"bufferView": views.len() - 1, "componentType": 5126, "count": c.times.len(), "type": ty});
            if ty == "SCALAR" {
                acc["min"] = json!([c.times[0]]);
                acc["max"] = json!([c.times[c.times.len() - 1]]);
            }
            accessors.push(acc);
        }
        samplers.push(json!({"input": accessors.len() - 2, "output": accessors.len() - 1, "interpolation": "LINEAR"}));
        channels
            .push(json!({"sampler": samplers.len() - 1, "target": {"node": node, "path": c.path}}));
    }
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let mut gltf = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "shape", "mesh": 0},
            {"name": "camera", "camera": 0, "translation": [0.0, 0.0, 5.0]}
        ],
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.5, "ymag": 1.5, "znear": 0.1, "zfar": 100.0}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"emissiveFactor": [1.0, 1.0, 1.0], "doubleSided": true,
                        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0]}}],
        "buffers": [{"uri": uri, "byteLength": bin.len()}],
        "bufferViews": views,
        "accessors": accessors
    });
    if !channels.is_empty() {
        gltf["animations"] = json!([{"channels": channels, "samplers": samplers}]);
    }
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, gltf.to_string()).unwrap();
    path
}

/// A 0.5 x 0.5 emissive square translated from x = -1 (t = 0) to x = 1 (t = 2), seen by an
/// orthographic camera 3 units wide.
fn moving_square(dir: &Path) -> std::path::PathBuf {
    let shape = Channel {
        path: "translation",
        times: vec![0.0, 2.0],
        values: vec![-1.0, 0.0, 0.0, 1.0, 0.0, 0.0],
    };
    emissive_scene(dir, "moving-square", (0.25, 0.25), Some(shape), None)
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
fn motion_blurred_frames_are_identical_on_one_or_three_workers() {
    let dir = temp_dir("anim-determinism");
    let scene = moving_square(&dir);
    let settings = json!({"width": 40, "height": 40, "spp": 16, "samples_per_task": 4,
                          "tile_size": 16, "frames": {"fps": 3.0}, "environment": {"color": [0.2, 0.3, 0.4]},
                          "shutter": {"open": 0.0, "close": 0.5}});
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
    let real = repo().join("tests/assets/real");
    for (name, path) in [
        ("box-animated", "BoxAnimated/glTF/BoxAnimated.gltf"),
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

/// R, G, B and variance.R of an EXR.
fn red_and_variance(exr: &[u8]) -> (Vec<f32>, Vec<f32>) {
    let ch = channels(exr);
    let get = |name: &str| -> Vec<f32> {
        ch.iter().find(|(n, _)| n == name).unwrap().1.iter().map(|&b| f32::from_bits(b)).collect()
    };
    (get("R"), get("variance.R"))
}

/// Checks the pixels (column, row) of a 60-wide image against their exact values: each within
/// 4 sigma + 0.01 of it (exactly 0 where it is 0), and their sum within 4 sigma of the exact
/// sum. Returns the largest pixel error, the sum and the exact sum.
fn assert_exact_pixels(
    image: &[f32],
    variance: &[f32],
    pixels: impl Iterator<Item = (usize, usize)>,
    exact: impl Fn(usize, usize) -> f64,
) -> (f64, f64, f64) {
    let (mut sum, mut exact_sum, mut var_sum, mut worst) = (0.0, 0.0, 0.0, 0.0f64);
    for (col, row) in pixels {
        let i = row * 60 + col;
        let (v, e) = (image[i] as f64, exact(col, row));
        if e == 0.0 {
            assert_eq!(v, 0.0, "pixel ({col}, {row}) lies outside the swept area");
        }
        let sigma = (variance[i] as f64).sqrt();
        assert!(
            (v - e).abs() <= 4.0 * sigma + 0.01,
            "pixel ({col}, {row}): {v} vs exact {e} (sigma {sigma})"
        );
        worst = worst.max((v - e).abs());
        sum += v;
        exact_sum += e;
        var_sum += variance[i] as f64;
    }
    assert!(
        (sum - exact_sum).abs() <= 4.0 * var_sum.sqrt() + 1e-3,
        "the pixels hold {sum}, exact {exact_sum}"
    );
    (worst, sum, exact_sum)
}

fn render_one(scene: &Path, settings: &serde_json::Value, dir: &Path, name: &str) -> Vec<u8> {
    let out = dir.join(format!("{name}.exr"));
    render_frames(scene, settings, "0", 2, &out);
    std::fs::read(&out).unwrap()
}

#[test]
fn a_translating_square_blurs_to_its_exact_shutter_coverage() {
    let dir = temp_dir("blur-translate");
    let scene = moving_square(&dir);
    // Frame 0 at fps 1 with the shutter open over [0, 1): the centre moves from x = -1 to 0.
    let settings = json!({"width": 60, "height": 60, "spp": 1024, "max_depth": 0,
                          "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0}});
    let (image, variance) = red_and_variance(&render_one(&scene, &settings, &dir, "blur"));
    let coverage = |col: usize| {
        let (a, w) = (-1.5 + 0.05 * col as f64, 0.05);
        let steps = 20_000;
        (0..steps)
            .map(|k| {
                let c = -1.0 + (k as f64 + 0.5) / steps as f64;
                ((a + w).min(c + 0.25) - a.max(c - 0.25)).max(0.0)
            })
            .sum::<f64>()
            / steps as f64
            / w
    };
    let rows = [25usize, 30, 34].into_iter().flat_map(|row| (0..60).map(move |col| (col, row)));
    let (worst, sum, expected_sum) =
        assert_exact_pixels(&image, &variance, rows, |col, _| coverage(col));
    eprintln!(
        "translation: largest pixel error {worst:.4}, rows sum {sum:.4} (exact {expected_sum:.4})"
    );
    assert!((expected_sum - 30.0).abs() < 1e-6, "each row holds 10 pixels of square");
    for row in [0usize, 24, 35, 59] {
        assert!(image[row * 60..row * 60 + 60].iter().all(|&v| v == 0.0), "row {row}");
    }
}

#[test]
fn a_spinning_bar_blurs_along_the_arc_not_the_chord() {
    let dir = temp_dir("blur-spin");
    let (s, c) = (std::f32::consts::FRAC_PI_4.sin(), std::f32::consts::FRAC_PI_4.cos());
    // A quarter turn about z during [0, 1).
    let spin = Channel {
        path: "rotation",
        times: vec![0.0, 1.0],
        values: vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, s, c],
    };
    let scene = emissive_scene(&dir, "bar", (1.0, 0.05), Some(spin), None);
    let settings = json!({"width": 60, "height": 60, "spp": 512, "max_depth": 0,
                          "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0}});
    let (image, variance) = red_and_variance(&render_one(&scene, &settings, &dir, "spin"));
    // The exact value: the fraction of pixel area x shutter time the rotating bar covers.
    let exact = |col, row| worker::test_scenes::quarter_turn_bar_coverage(col, row, 16);
    let (mut checked, mut worst) = (0, 0.0f64);
    for row in (0..60).step_by(3) {
        for col in (0..60).step_by(3) {
            let (v, e) = (image[row * 60 + col] as f64, exact(col, row));
            let sigma = (variance[row * 60 + col] as f64).sqrt();
            assert!((v - e).abs() <= 4.0 * sigma + 0.02, "pixel ({col}, {row}): {v} vs exact {e}");
            worst = worst.max((v - e).abs());
            checked += 1;
        }
    }
    assert_eq!(checked, 400);
    eprintln!("rotation: largest pixel error {worst:.4} over {checked} pixels");
    // Near the tip on the diagonal (radius 0.95) the arc passes and a chord would not: a bar
    // interpolated as a matrix shrinks to 1/sqrt(2) there half-way through the turn.
    let (col, row) = (43, 16);
    let tip = image[row * 60 + col] as f64;
    eprintln!("rotation: tip pixel {tip:.4}, exact {:.4}", exact(col, row));
    assert!(tip > 0.03, "the bar's tip does not sweep the arc: {tip}");
    assert!((tip - exact(col, row)).abs() <= 0.02);
}

#[test]
fn moving_the_camera_equals_moving_the_world_the_other_way() {
    let dir = temp_dir("blur-camera");
    let world = Channel {
        path: "translation",
        times: vec![0.0, 1.0],
        values: vec![-0.5, 0.1, 0.0, 0.5, 0.1, 0.0],
    };
    let by_object = emissive_scene(&dir, "object", (0.25, 0.25), Some(world), None);
    let camera = Channel {
        path: "translation",
        times: vec![0.0, 1.0],
        values: vec![0.5, -0.1, 5.0, -0.5, -0.1, 5.0],
    };
    let by_camera = emissive_scene(&dir, "camera", (0.25, 0.25), None, Some(camera));
    let settings = json!({"width": 48, "height": 48, "spp": 64, "max_depth": 0,
                          "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0}});
    let (a, var_a) = red_and_variance(&render_one(&by_object, &settings, &dir, "object"));
    let (b, var_b) = red_and_variance(&render_one(&by_camera, &settings, &dir, "camera"));
    assert!(a.iter().sum::<f32>() > 50.0, "the square is in view");
    for i in 0..a.len() {
        let sigma = ((var_a[i] + var_b[i]) as f64).sqrt();
        assert!(
            ((a[i] - b[i]) as f64).abs() <= 4.0 * sigma + 1e-3,
            "pixel {i}: {} vs {}",
            a[i],
            b[i]
        );
    }
}

#[test]
fn morphing_meshes_are_posed_per_frame_and_blur_to_their_exact_shutter_coverage() {
    let dir = temp_dir("anim-deform");
    let path = moving_square(&dir);
    let mut gltf: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    // One morph target displacing each vertex by its own position, its weight animated from 0
    // (t = 0) to 2 (t = 2) by the key times themselves (accessor 2): the square is (1 + t)
    // times its size at time t.
    gltf["meshes"][0]["primitives"][0]["targets"] = json!([{"POSITION": 0}]);
    gltf["animations"][0]["samplers"]
        .as_array_mut()
        .unwrap()
        .push(json!({"input": 2, "output": 2, "interpolation": "LINEAR"}));
    gltf["animations"][0]["channels"]
        .as_array_mut()
        .unwrap()
        .push(json!({"sampler": 1, "target": {"node": 0, "path": "weights"}}));
    let morphing = dir.join("morphing.gltf");
    std::fs::write(&morphing, gltf.to_string()).unwrap();
    // fps 2: frame 2 is t = 1, the square at x = 0 twice its size ([-0.5, 0.5], pixels 20..40
    // of 0.05 from -1.5); frame 0 is t = 0, at x = -1 at its own size (pixels 5..15).
    let settings =
        json!({"width": 60, "height": 60, "spp": 4, "max_depth": 0, "frames": {"fps": 2.0}});
    let out = dir.join("morph.exr");
    render_frames(&morphing, &settings, "0..2", 1, &out);
    for (frame, cols, rows) in [(0i64, (5, 14), (25, 34)), (2, (20, 39), (20, 39))] {
        let image = red(&std::fs::read(frame_file(&out, frame)).unwrap());
        let lit: Vec<(usize, usize)> =
            (0..3600).filter(|&i| image[i] > 0.5).map(|i| (i % 60, i / 60)).collect();
        let span = |k: fn(&(usize, usize)) -> usize| {
            (lit.iter().map(k).min().unwrap(), lit.iter().map(k).max().unwrap())
        };
        assert_eq!((span(|p| p.0), span(|p| p.1)), (cols, rows), "frame {frame}");
    }
    // Deformation blur: frame 0 at fps 1 with the shutter open over [0, 1). At time t the
    // square's centre is at x = -1 + t and its half-size 0.25 (1 + t): the node moves and the
    // mesh grows at once, each vertex linearly in t.
    let settings = json!({"width": 60, "height": 60, "spp": 256, "max_depth": 0,
                          "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0}});
    let (image, variance) = red_and_variance(&render_one(&morphing, &settings, &dir, "grow"));
    // The exact value: the pixel's area covered, averaged over the shutter.
    let exact = |col: usize, row: usize| {
        let (x0, y0, w) = (-1.5 + 0.05 * col as f64, 1.5 - 0.05 * (row as f64 + 1.0), 0.05);
        let overlap = |a: f64, lo: f64, hi: f64| ((a + w).min(hi) - a.max(lo)).max(0.0);
        let steps = 4000;
        let covered: f64 = (0..steps)
            .map(|k| {
                let t = (k as f64 + 0.5) / steps as f64;
                let (c, h) = (-1.0 + t, 0.25 * (1.0 + t));
                overlap(x0, c - h, c + h) * overlap(y0, -h, h)
            })
            .sum();
        covered / steps as f64 / (w * w)
    };
    let all = (0..60).flat_map(|row| (0..60).map(move |col| (col, row)));
    let (worst, sum, exact_sum) = assert_exact_pixels(&image, &variance, all, exact);
    eprintln!(
        "growing square: largest pixel error {worst:.4}, sum {sum:.3} (exact {exact_sum:.3})"
    );
    // The swept area: the integral of (2 h)^2 over the shutter, 7/12, in pixels of 0.0025.
    assert!((exact_sum - 7.0 / 12.0 / 0.0025).abs() < 0.05, "{exact_sum}");
    // A frozen pose would keep the square at its frame-time size: the blur must reach the
    // end of the shutter, where the square's right edge is at 0.5 (column 39).
    assert!(image[30 * 60 + 38] > 0.0, "the square does not grow within the shutter");
    // The same image on one or three workers.
    let small = json!({"width": 24, "height": 24, "spp": 8, "samples_per_task": 2, "tile_size": 8,
                       "shutter": {"open": 0.0, "close": 1.0}, "frames": {"fps": 1.0},
                       "environment": {"color": [0.2, 0.3, 0.4]}});
    let (one, three) = (dir.join("one.exr"), dir.join("three.exr"));
    render_frames(&morphing, &small, "0..1", 1, &one);
    render_frames(&morphing, &small, "0..1", 3, &three);
    for frame in 0..=1 {
        let a = std::fs::read(frame_file(&one, frame)).unwrap();
        let b = std::fs::read(frame_file(&three, frame)).unwrap();
        assert_same_image(&a, &b, &format!("deforming frame {frame}"));
    }
}
