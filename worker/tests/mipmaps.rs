//! Mipmapped textures: a far plane whose checker of single texels is much finer than the
//! pixels. Every pixel's exact value is the checker's mean; filtering by the footprint must keep
//! that mean and remove the noise that point-sampling the checker leaves at 4 samples per pixel.

mod support;

use common::settings::RenderSettings;
use serde_json::json;
use support::*;

/// Texels along each side of the checker.
const TEXELS: u32 = 128;
/// Pixels along each side of the image: 16 texels per pixel.
const RES: u32 = 8;

/// The checker plane (unlit, so that the image is the base colour itself, 0 or 1 in linear
/// values per texel) filling the image of `camera` ("orthographic" or "perspective", two units
/// above it, looking down), its texture's sampler mipmapped or, with `plain`, minified linearly
/// (`minFilter` LINEAR: no mipmaps).
fn checker_plane(camera: &str, plain: bool) -> common::scene::Scene {
    let texels: Vec<u8> = (0..TEXELS * TEXELS)
        .map(|i| if (i % TEXELS + i / TEXELS) % 2 == 0 { 0 } else { 255 })
        .collect();
    let png = grey_png(TEXELS, TEXELS, &texels);
    let projection = match camera {
        "orthographic" => json!({"type": "orthographic",
            "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.01, "zfar": 10.0}}),
        // tan(yfov / 2) = 1 / 2: the plane's edges at the image's edges.
        _ => json!({"type": "perspective",
            "perspective": {"yfov": 2.0 * 0.5f64.atan(), "aspectRatio": 1.0, "znear": 0.01}}),
    };
    let sampler = if plain { json!({"minFilter": 9729}) } else { json!({}) };
    let material = json!({
        "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
        "extensions": {"KHR_materials_unlit": {}}
    });
    let mut doc = square_seen_from_above(1.0, projection, material);
    doc["extensionsUsed"] = json!(["KHR_materials_unlit"]);
    doc["textures"] = json!([{"source": 0, "sampler": 0}]);
    doc["samplers"] = json!([sampler]);
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64(&png))}]);
    let dir = std::env::temp_dir()
        .join(format!("renderfarm-mipmaps-{}-{camera}-{plain}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("checker.gltf");
    std::fs::write(&path, serde_json::to_string(&doc).unwrap()).unwrap();
    common::gltf::load_path(&path).unwrap()
}

/// The image's mean and its root-mean-square distance from the exact 0.5 of every pixel.
fn mean_and_error(scene: &common::scene::Scene, spp: u32) -> (f64, f64) {
    let settings = RenderSettings { width: RES, height: RES, spp, seed: 7, ..Default::default() };
    let film = render(scene, &settings);
    let values: Vec<f64> = film.mean_rgb().iter().map(|p| p[0] as f64).collect();
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let error = (values.iter().map(|v| (v - 0.5) * (v - 0.5)).sum::<f64>() / n).sqrt();
    (mean, error)
}

/// Point-sampled at 4 samples per pixel, each pixel is the mean of 4 draws of texels of 0 and
/// 1 (bilinear blends of them): about 0.1 or more from 0.5. With mipmaps, the footprint at 4
/// samples per pixel (1/sqrt(4) of a pixel: 8 texels) reads level 3, whose texels are all the
/// checker's mean, so every pixel lands within the grey level's rounding to 8-bit sRGB (188 is
/// 0.5029) of 0.5. The mean of the image is kept in both: within that rounding with mipmaps, and
/// within 5 standard errors of the point-sampled image's pixels without.
#[test]
fn mipmaps_keep_the_mean_and_remove_texture_noise_at_low_sample_counts() {
    let rounding = 0.0035;
    for camera in ["orthographic", "perspective"] {
        let (plain_mean, plain_error) = mean_and_error(&checker_plane(camera, true), 4);
        let (mip_mean, mip_error) = mean_and_error(&checker_plane(camera, false), 4);
        let standard_error = plain_error / ((RES * RES) as f64).sqrt();
        assert!(
            (plain_mean - 0.5).abs() < 5.0 * standard_error,
            "{camera}: point-sampled mean {plain_mean} (standard error {standard_error})"
        );
        assert!((mip_mean - 0.5).abs() < rounding, "{camera}: mipmapped mean {mip_mean}");
        assert!(plain_error > 0.05, "{camera}: point sampling leaves noise ({plain_error})");
        assert!(mip_error < rounding, "{camera}: mipmapped error {mip_error}");
        // At 64 samples per pixel the footprint is an eighth of a pixel (2 texels, level 1):
        // the filtered image is still the checker's mean.
        let (mean, error) = mean_and_error(&checker_plane(camera, false), 64);
        assert!((mean - 0.5).abs() < rounding && error < rounding, "{camera}: {mean}, {error}");
    }
}
