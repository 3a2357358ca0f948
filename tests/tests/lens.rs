//! Depth of field through the real binary: an emissive disk off the focal plane is imaged as
//! the exact thin-lens blur (the disk convolved with the circle of confusion PRODUCT.md's lens
//! model gives), and a disk in the focal plane stays sharp.

use std::{f64::consts::PI, path::Path, process::Command};

use base64::Engine;
use serde_json::json;
use tests::*;

const YFOV: f64 = 40.0 * PI / 180.0;
const SIZE: usize = 64;

/// An emissive disk of radius `r` facing the camera at depth `depth` (a 256-gon fan), and a
/// perspective camera at the origin looking down -z.
fn disk_scene(dir: &Path, name: &str, r: f32, depth: f32) -> std::path::PathBuf {
    let n = 256u16;
    let mut positions: Vec<f32> = vec![0.0, 0.0, -depth];
    for k in 0..n {
        let a = 2.0 * std::f32::consts::PI * k as f32 / n as f32;
        positions.extend([r * a.cos(), r * a.sin(), -depth]);
    }
    let indices: Vec<u16> = (0..n).flat_map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
    let mut bin: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    let index_offset = bin.len();
    bin.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&bin)
    );
    let gltf = json!({
        "asset": {"version": "2.0"},
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0}, {"camera": 0}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": YFOV, "znear": 0.01}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"emissiveFactor": [1.0, 1.0, 1.0], "doubleSided": true,
                        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0]}}],
        "buffers": [{"uri": uri, "byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": index_offset},
            {"buffer": 0, "byteOffset": index_offset, "byteLength": indices.len() * 2}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len() / 3, "type": "VEC3",
             "min": [-r, -r, -depth], "max": [r, r, -depth]},
            {"bufferView": 1, "componentType": 5123, "count": indices.len(), "type": "SCALAR"}
        ]
    });
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, gltf.to_string()).unwrap();
    path
}

fn render(dir: &Path, scene: &Path, aperture: f64, focus: f64) -> (Vec<f32>, Vec<f32>) {
    let settings = dir.join("settings.json");
    std::fs::write(
        &settings,
        json!({"width": SIZE, "height": SIZE, "spp": 512, "max_depth": 0,
               "lens": {"aperture_radius": aperture, "focus_distance": focus}})
        .to_string(),
    )
    .unwrap();
    let out = dir.join("lens.exr");
    let output = Command::new(bin_dir().join("coordinator"))
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(&out)
        .arg("--settings")
        .arg(&settings)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let ch = channels(&std::fs::read(&out).unwrap());
    let get = |name: &str| -> Vec<f32> {
        ch.iter().find(|(n, _)| n == name).unwrap().1.iter().map(|&b| f32::from_bits(b)).collect()
    };
    (get("R"), get("variance.R"))
}

/// The exact value of a pixel: the fraction of pixel area x lens disk whose thin-lens ray hits
/// the disk of radius `r` at depth `depth` (PRODUCT.md: the ray from lens point L through
/// F = focus * d meets z = -depth at L (1 - depth / focus) + depth * d).
fn exact(col: usize, row: usize, aperture: f64, focus: f64, r: f64, depth: f64) -> f64 {
    let tan = (0.5 * YFOV).tan();
    let (sub, rings, sectors) = (8, 24, 48);
    let mut hit = 0usize;
    for j in 0..sub {
        for i in 0..sub {
            let x = col as f64 + (i as f64 + 0.5) / sub as f64;
            let y = row as f64 + (j as f64 + 0.5) / sub as f64;
            let d = ((2.0 * x / SIZE as f64 - 1.0) * tan, (1.0 - 2.0 * y / SIZE as f64) * tan);
            for ring in 0..rings {
                // Equal-area rings.
                let rho = aperture * ((ring as f64 + 0.5) / rings as f64).sqrt();
                for s in 0..sectors {
                    let phi = 2.0 * PI * (s as f64 + 0.5) / sectors as f64;
                    let l = (rho * phi.cos(), rho * phi.sin());
                    let k = 1.0 - depth / focus;
                    let p = (l.0 * k + depth * d.0, l.1 * k + depth * d.1);
                    hit += (p.0 * p.0 + p.1 * p.1 <= r * r) as usize;
                }
            }
        }
    }
    hit as f64 / (sub * sub * rings * sectors) as f64
}

#[test]
fn a_disk_off_the_focal_plane_blurs_by_the_circle_of_confusion() {
    let dir = temp_dir("dof-blur");
    let (r, depth, aperture, focus) = (0.8, 8.0, 0.4, 4.0);
    let scene = disk_scene(&dir, "disk", r as f32, depth as f32);
    let (image, variance) = render(&dir, &scene, aperture, focus);
    let px_per_tan = SIZE as f64 / (2.0 * (0.5 * YFOV).tan());
    let image_radius = r / depth * px_per_tan;
    let coc_radius = aperture * (1.0 - depth / focus).abs() / depth * px_per_tan;
    eprintln!("image radius {image_radius:.2} px, circle of confusion radius {coc_radius:.2} px");
    let row = SIZE / 2;
    let mut worst = 0.0f64;
    for col in 0..SIZE {
        let (v, e) = (image[row * SIZE + col] as f64, exact(col, row, aperture, focus, r, depth));
        let sigma = (variance[row * SIZE + col] as f64).sqrt();
        assert!((v - e).abs() <= 4.0 * sigma + 0.02, "pixel ({col}, {row}): {v} vs exact {e}");
        worst = worst.max((v - e).abs());
        // Outside image radius + circle of confusion nothing can be seen.
        let dist = (col as f64 + 0.5 - SIZE as f64 / 2.0).abs();
        if dist > image_radius + coc_radius + 1.0 {
            assert_eq!(v, 0.0, "pixel ({col}, {row}) beyond the blur");
        }
    }
    eprintln!("largest error along the row {worst:.4}");
    // The blur is as wide as the lens says: lit out to about image + CoC radius, and the edge
    // ramps over the CoC diameter (a pinhole would give a sharp edge at the image radius).
    let lit = (0..SIZE).filter(|&c| image[row * SIZE + c] > 0.0).count() as f64;
    let predicted = 2.0 * (image_radius + coc_radius);
    assert!((lit - predicted).abs() <= 2.5, "lit width {lit} px, predicted {predicted:.1}");
    let ramp = (0..SIZE)
        .filter(|&c| {
            let v = image[row * SIZE + c];
            v > 0.05 && v < 0.95
        })
        .count() as f64
        / 2.0;
    assert!(
        (ramp - 2.0 * coc_radius).abs() <= 2.5,
        "edge ramp {ramp} px, CoC diameter {:.1}",
        2.0 * coc_radius
    );
}

#[test]
fn a_disk_in_the_focal_plane_stays_sharp() {
    let dir = temp_dir("dof-sharp");
    let (r, depth, aperture) = (0.4, 4.0, 0.4);
    let scene = disk_scene(&dir, "disk", r as f32, depth as f32);
    let (image, _) = render(&dir, &scene, aperture, depth);
    let px_per_tan = SIZE as f64 / (2.0 * (0.5 * YFOV).tan());
    let radius = r / depth * px_per_tan;
    for row in 0..SIZE {
        for col in 0..SIZE {
            let (cx, cy) = (col as f64 + 0.5 - 32.0, row as f64 + 0.5 - 32.0);
            let dist = (cx * cx + cy * cy).sqrt();
            let v = image[row * SIZE + col];
            if dist < radius - 0.75 {
                assert_eq!(v, 1.0, "pixel ({col}, {row}) inside the sharp disk");
            } else if dist > radius + 0.75 {
                assert_eq!(v, 0.0, "pixel ({col}, {row}) outside the sharp disk");
            }
        }
    }
}
