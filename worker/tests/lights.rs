//! Analytic checks of light units and falloff (PRODUCT.md conventions): a diffuse plane lit by a
//! point, spot or directional light, or emitting through an emissive texture, seen by an
//! orthographic camera looking straight down. Each pixel's expected value is computed in the
//! test by integrating the closed form over the pixel's area.

mod support;

use common::settings::RenderSettings;
use serde_json::{json, Value};
use support::*;

/// Half size of the square plane (it spans [-H, H] in x and z, at y = 0).
const HALF: f64 = 1.0;
const ALBEDO: f64 = 0.5;
const RES: u32 = 32;

/// A glTF with the plane (normal +y), an orthographic camera 2 units above looking down, and
/// `extra` merged into the root (lights, extensions).
fn plane_scene(
    tag: &str,
    light_node: Option<Value>,
    extra: impl FnOnce(&mut Value),
) -> std::path::PathBuf {
    let camera = json!({"type": "orthographic",
        "orthographic": {"xmag": HALF, "ymag": HALF, "znear": 0.01, "zfar": 10.0}});
    let material = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [ALBEDO, ALBEDO, ALBEDO, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
    });
    let mut json = square_seen_from_above(HALF as f32, camera, material);
    json["extensionsUsed"] = json!(["KHR_materials_specular"]);
    if let Some(node) = light_node {
        json["nodes"].as_array_mut().unwrap().push(node);
        json["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(2));
    }
    extra(&mut json);
    let dir = std::env::temp_dir().join(format!("renderfarm-lights-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("plane.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// Plane point (x, z) under pixel position (px, py) of the orthographic view (row 0 at -z).
fn plane_point(px: f64, py: f64) -> (f64, f64) {
    let sx = 2.0 * px / RES as f64 - 1.0;
    let sy = 1.0 - 2.0 * py / RES as f64;
    // Camera x is world x; camera y (up in the image) is world -z.
    (sx * HALF, -sy * HALF)
}

/// Expected image: `radiance(x, z)` averaged over each pixel (16 x 16 sub-points).
fn expected(radiance: impl Fn(f64, f64) -> f64) -> Vec<[f32; 3]> {
    let n = 16;
    let mut out = Vec::new();
    for y in 0..RES {
        for x in 0..RES {
            let mut sum = 0.0;
            for j in 0..n {
                for i in 0..n {
                    let (px, pz) = plane_point(
                        x as f64 + (i as f64 + 0.5) / n as f64,
                        y as f64 + (j as f64 + 0.5) / n as f64,
                    );
                    sum += radiance(px, pz);
                }
            }
            out.push([(sum / (n * n) as f64) as f32; 3]);
        }
    }
    out
}

fn settings() -> RenderSettings {
    RenderSettings { width: RES, height: RES, spp: 64, max_depth: 1, ..Default::default() }
}

/// Delta lights and an orthographic camera leave only pixel-area integration as noise, so the
/// tolerance is small: 5 sigma of the pixel's own estimate, plus 0.2% of the value, plus 1e-4 of
/// the brightest pixel (pixels that a cone edge barely touches are rare events for 64 samples,
/// and their sample variance says little).
fn check(tag: &str, path: &std::path::Path, want: &[[f32; 3]]) {
    let scene = common::gltf::load_path(path).unwrap();
    let film = render(&scene, &settings());
    let got = film.mean_rgb();
    let peak = want.iter().map(|w| w[0] as f64).fold(0.0, f64::max);
    let mut worst = 0.0f64;
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let var = film.pixels[i].variance_of_mean()[0];
        let err = (g[0] as f64 - w[0] as f64).abs();
        let allowed = 5.0 * var.sqrt() + 2e-3 * w[0] as f64 + 1e-4 * peak;
        worst = worst.max(err / allowed);
        assert!(err <= allowed, "{tag}: pixel {i}: got {} want {} (+- {allowed})", g[0], w[0]);
    }
    eprintln!("{tag}: worst error / allowed = {worst:.3}");
}

#[test]
fn point_light_intensity_is_radiant_intensity() {
    let (ly, intensity) = (0.7, 3.0);
    let path = plane_scene(
        "point",
        Some(
            json!({"name": "lamp", "translation": [0.2, ly, -0.1], "extensions": {"KHR_lights_punctual": {"light": 0}}}),
        ),
        |j| {
            j["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_lights_punctual"));
            j["extensions"] = json!({"KHR_lights_punctual": {"lights": [{"type": "point", "intensity": intensity, "color": [1.0, 1.0, 1.0]}]}});
        },
    );
    let want = expected(|x, z| {
        let (dx, dz) = (x - 0.2, z + 0.1);
        let d2 = dx * dx + ly * ly + dz * dz;
        let cos = ly / d2.sqrt();
        ALBEDO / std::f64::consts::PI * intensity * cos / d2
    });
    check("point", &path, &want);
}

#[test]
fn spot_light_falls_off_as_the_extension_says() {
    let (ly, intensity, inner, outer) = (0.8f64, 5.0, 0.3f64, 0.6f64);
    let path = plane_scene(
        "spot",
        // Spot lights shine along their node's -z: rotate -90 degrees about x to point down.
        Some(json!({"name": "spot", "translation": [0.0, ly, 0.0],
            "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2],
            "extensions": {"KHR_lights_punctual": {"light": 0}}})),
        |j| {
            j["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_lights_punctual"));
            j["extensions"] = json!({"KHR_lights_punctual": {"lights": [{"type": "spot", "intensity": intensity,
                "spot": {"innerConeAngle": inner, "outerConeAngle": outer}}]}});
        },
    );
    let want = expected(|x, z| {
        let d2 = x * x + ly * ly + z * z;
        let cos = ly / d2.sqrt();
        let scale = 1.0 / (inner.cos() - outer.cos()).max(0.001);
        let a = (cos * scale - outer.cos() * scale).clamp(0.0, 1.0);
        ALBEDO / std::f64::consts::PI * intensity * a * a * cos / d2
    });
    check("spot", &path, &want);
}

#[test]
fn directional_light_intensity_is_irradiance() {
    let irradiance = 2.0;
    let path = plane_scene(
        "sun",
        // Pointing down and tilted: -z rotated by 60 degrees about x from the horizontal.
        Some(json!({"name": "sun", "rotation": [-0.5, 0.0, 0.0, 0.8660254037844386],
            "extensions": {"KHR_lights_punctual": {"light": 0}}})),
        |j| {
            j["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_lights_punctual"));
            j["extensions"] = json!({"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": irradiance}]}});
        },
    );
    // The light's direction (0, -sin 60, -cos 60) makes cos = sin 60 with the plane's normal.
    let cos = 60f64.to_radians().sin();
    let want = expected(|_, _| ALBEDO / std::f64::consts::PI * irradiance * cos);
    check("sun", &path, &want);
}

#[test]
fn emissive_texture_is_seen_one_to_one() {
    // A 2x2 emissive texture (nearest filtering) over the plane, strength 3: each quadrant of the
    // image reads emissiveFactor x strength x the texel's linear value.
    let png = two_by_two_png();
    let path = plane_scene("emissive", None, |j| {
        j["materials"][0]["emissiveFactor"] = json!([1.0, 1.0, 1.0]);
        j["materials"][0]["emissiveTexture"] = json!({"index": 0});
        j["materials"][0]["extensions"]["KHR_materials_emissive_strength"] =
            json!({"emissiveStrength": 3.0});
        j["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_materials_emissive_strength"));
        j["textures"] = json!([{"source": 0, "sampler": 0}]);
        j["samplers"] = json!([{"magFilter": 9728, "minFilter": 9728}]);
        j["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64(&png))}]);
    });
    let srgb = |c: f64| if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) };
    let texel = |u: f64, v: f64| -> f64 {
        let values = [[0.0, 64.0], [128.0, 255.0]]; // rows (v) then columns (u)
        srgb(values[(v >= 0.5) as usize][(u >= 0.5) as usize] / 255.0)
    };
    // uv = ((x + H) / 2H, (z + H) / 2H) from the vertex layout.
    let want = expected(|x, z| 3.0 * texel((x + HALF) / (2.0 * HALF), (z + HALF) / (2.0 * HALF)));
    let scene = common::gltf::load_path(&path).unwrap();
    let film = render(&scene, &RenderSettings { max_depth: 0, ..settings() });
    for (i, (g, w)) in film.mean_rgb().iter().zip(&want).enumerate() {
        // Pixels straddling a texel edge mix two values; the rest are exact.
        assert!(
            (g[0] as f64 - w[0] as f64).abs() <= 0.02 * (w[0] as f64).max(0.05),
            "pixel {i}: {} vs {}",
            g[0],
            w[0]
        );
    }
}

/// A 2x2 greyscale PNG with texels 0, 64 (top row) and 128, 255 (bottom row), uncompressed.
fn two_by_two_png() -> Vec<u8> {
    grey_png(2, 2, &[0, 64, 128, 255])
}
