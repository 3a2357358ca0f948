//! Surfaces one sees through, through the whole renderer.
//!
//! `KHR_materials_transmission`: a thin transmitting sheet between an orthographic camera and an
//! emitting plane. Everything the camera sees comes through the sheet (the world is black, the
//! emitter's surface black), so a pixel is exactly what the sheet passes: (1 - f0) x
//! transmission x baseColor x the emitted radiance, for a near-specular sheet seen at normal
//! incidence (f0 = 0.04 for ior 1.5), less the lobe's tiny single-scattering loss.
//!
//! `alphaMode` BLEND: alpha is coverage (the surface is there with probability alpha), so a
//! blended sheet passes 1 - alpha of what lies behind it, and a blended emitter lights a surface
//! as an opaque one of alpha times its radiance would.
//!
//! `alphaMode` MASK: a surface is there or not, point by point; an emitter that is there over half
//! its area (vertex alpha against the cutoff) lights a floor half as much as the whole one.

mod support;

use common::settings::RenderSettings;
use serde_json::{json, Value};
use support::*;

/// Half size of the square the camera sees (the planes are 30 times larger: seen from the sheet's
/// centre, the emitter fills all but the last two degrees above the horizon).
const HALF: f32 = 1.0;
const RES: u32 = 16;
const RADIANCE: f64 = 2.0;
const BASE: [f64; 3] = [0.5, 0.8, 1.0];

/// A horizontal plane at height `y`, facing up or down, with a material.
struct Plane {
    y: f32,
    up: bool,
    material: Value,
    /// COLOR_0 (RGBA) at the corners (-x -z, +x -z, +x +z, -x +z), if any.
    colors: Option<[[f32; 4]; 4]>,
}

/// A glTF of `planes` and an orthographic camera at height `camera_y` looking down. Returns the
/// file's path.
fn planes_scene(tag: &str, planes: &[Plane], camera_y: f32) -> std::path::PathBuf {
    let h = 30.0 * HALF;
    let mut bytes: Vec<u8> = Vec::new();
    let (mut accessors, mut views, mut meshes, mut nodes) = (vec![], vec![], vec![], vec![]);
    for (i, plane) in planes.iter().enumerate() {
        let y = plane.y;
        let positions = [[-h, y, -h], [h, y, -h], [h, y, h], [-h, y, h]];
        // Counter-clockwise seen from +y faces up.
        let indices: [u16; 6] = if plane.up { [0, 2, 1, 0, 3, 2] } else { [0, 1, 2, 0, 2, 3] };
        let start = bytes.len();
        bytes.extend(positions.iter().flatten().flat_map(|v: &f32| v.to_le_bytes()));
        bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
        views.push(json!({"buffer": 0, "byteOffset": start, "byteLength": 48}));
        views.push(json!({"buffer": 0, "byteOffset": start + 48, "byteLength": 12}));
        accessors.push(json!({"bufferView": views.len() - 2, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-h, y, -h], "max": [h, y, h]}));
        accessors.push(
            json!({"bufferView": views.len() - 1, "componentType": 5123, "count": 6, "type": "SCALAR"}),
        );
        let mut attributes = json!({"POSITION": accessors.len() - 2});
        let indices = accessors.len() - 1;
        if let Some(colors) = &plane.colors {
            let at = bytes.len();
            bytes.extend(colors.iter().flatten().flat_map(|v: &f32| v.to_le_bytes()));
            views.push(json!({"buffer": 0, "byteOffset": at, "byteLength": 64}));
            accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126, "count": 4, "type": "VEC4"}));
            attributes["COLOR_0"] = json!(accessors.len() - 1);
        }
        meshes.push(
            json!({"primitives": [{"attributes": attributes, "indices": indices, "material": i}]}),
        );
        nodes.push(json!({"mesh": i}));
    }
    nodes.push(json!({"name": "camera", "camera": 0, "translation": [0.0, camera_y, 0.0],
        "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}));
    let json = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": HALF, "ymag": HALF, "znear": 0.01, "zfar": 10.0}}],
        "meshes": meshes,
        "materials": planes.iter().map(|p| p.material.clone()).collect::<Vec<_>>(),
        "extensionsUsed": ["KHR_materials_emissive_strength", "KHR_materials_specular", "KHR_materials_transmission"],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir =
        std::env::temp_dir().join(format!("renderfarm-see-through-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("planes.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// A black, non-reflecting emitter of `radiance` (alpha `alpha`, BLEND when below 1).
fn emitter(radiance: f64, alpha: f64) -> Value {
    let mut m = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, alpha], "metallicFactor": 0.0},
        "emissiveFactor": [1.0, 1.0, 1.0],
        "extensions": {
            "KHR_materials_emissive_strength": {"emissiveStrength": radiance},
            "KHR_materials_specular": {"specularFactor": 0.0}
        }
    });
    if alpha < 1.0 {
        m["alphaMode"] = json!("BLEND");
    }
    m
}

/// The emitter at y = 0 (facing up), the transmitting sheet at y = 1 and the camera at y = 2.
fn sheet_scene(tag: &str, transmission: f64, roughness: f64) -> std::path::PathBuf {
    let sheet = json!({
        "pbrMetallicRoughness": {
            "baseColorFactor": [BASE[0], BASE[1], BASE[2], 1.0],
            "metallicFactor": 0.0,
            "roughnessFactor": roughness
        },
        "extensions": {"KHR_materials_transmission": {"transmissionFactor": transmission}}
    });
    let planes = [
        Plane { y: 0.0, up: true, material: emitter(RADIANCE, 1.0), colors: None },
        Plane { y: 1.0, up: true, material: sheet, colors: None },
    ];
    planes_scene(tag, &planes, 2.0)
}

/// The image mean per channel and its standard error (pixels are independent estimates).
fn render_mean(path: &std::path::Path) -> [(f64, f64); 3] {
    let scene = common::gltf::load_path(path).unwrap();
    let settings = RenderSettings { width: RES, height: RES, spp: 256, ..Default::default() };
    image_mean(&render(&scene, &settings))
}

/// What a near-specular sheet passes at normal incidence: (1 - f0) x transmission x base x L.
fn through(transmission: f64, channel: usize) -> f64 {
    (1.0 - 0.04) * transmission * BASE[channel] * RADIANCE
}

#[test]
fn a_thin_sheet_passes_the_light_behind_it_tinted_by_its_base_colour() {
    for transmission in [1.0, 0.5] {
        let path = sheet_scene(&format!("t{transmission}"), transmission, 0.1);
        let got = render_mean(&path);
        for (c, (mean, error)) in got.into_iter().enumerate() {
            let want = through(transmission, c);
            eprintln!(
                "transmission {transmission} channel {c}: {mean:.5} +- {error:.5}, want {want:.5}"
            );
            // Near-specular (alpha 0.01): the lobe's single-scattering loss is under 0.1%.
            assert!(
                (mean - want).abs() <= 4.0 * error + 1e-3 * want,
                "transmission {transmission} channel {c}: {mean} +- {error}, want {want}"
            );
        }
    }
}

#[test]
fn a_rough_sheet_passes_what_its_bsdf_says() {
    // Rough (alpha 0.25): next-event estimation through the sheet (`eval`, `pdf`) and paths that
    // sample the mirrored lobe must together give the BSDF's own transmitted albedo, estimated
    // here from `sample` alone.
    use glam::{Vec2, Vec3};
    use worker::render::bsdf::{Bsdf, MetalRough};
    let (transmission, roughness) = (1.0, 0.5);
    let base = Vec3::new(BASE[0] as f32, BASE[1] as f32, BASE[2] as f32);
    let bsdf = Bsdf::MetalRough(
        MetalRough::new(base, 0.0, roughness, 1.5, 1.0, Vec3::ONE).with_transmission(transmission),
    );
    let n = 1_000_000u64;
    let (mut sum, mut sum2) = ([0.0f64; 3], [0.0f64; 3]);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    for _ in 0..n {
        let (u0, u1, u2) = (next(), next(), next());
        let Some(s) = bsdf.sample(Vec3::Z, u0, Vec2::new(u1, u2)) else { continue };
        if s.wi.z < 0.0 {
            let w = s.f * (s.wi.z.abs() / s.pdf);
            for c in 0..3 {
                sum[c] += w[c] as f64;
                sum2[c] += (w[c] as f64).powi(2);
            }
        }
    }
    let path = sheet_scene("rough", transmission as f64, roughness as f64);
    for (c, (mean, error)) in render_mean(&path).into_iter().enumerate() {
        let albedo = sum[c] / n as f64;
        let albedo_error = ((sum2[c] / n as f64 - albedo * albedo).max(0.0) / n as f64).sqrt();
        let (want, want_error) = (albedo * RADIANCE, albedo_error * RADIANCE);
        eprintln!("rough channel {c}: {mean:.5} +- {error:.5}, want {want:.5} +- {want_error:.5}");
        let sigma = (error * error + want_error * want_error).sqrt();
        // 0.1%: the part of the lobe that passes beside the emitter, near the horizon (0.06%
        // measured, the same in every channel).
        assert!((mean - want).abs() <= 4.0 * sigma + 1e-3 * want, "channel {c}: {mean} vs {want}");
    }
}

#[test]
fn an_opaque_sheet_hides_the_light_behind_it() {
    // The same sheet without transmission: a black world reflected, a Lambertian base lit by
    // nothing on the camera's side.
    let path = sheet_scene("t0", 0.0, 0.1);
    for (c, (mean, _)) in render_mean(&path).into_iter().enumerate() {
        assert_eq!(mean, 0.0, "channel {c}");
    }
}

#[test]
fn a_blended_sheet_passes_one_minus_its_alpha() {
    // A black Lambertian sheet of alpha 0.3 over the emitter: 70% of the emitter shows.
    let sheet = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 0.3], "metallicFactor": 0.0},
        "alphaMode": "BLEND",
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
    });
    let planes = [
        Plane { y: 0.0, up: true, material: emitter(RADIANCE, 1.0), colors: None },
        Plane { y: 1.0, up: true, material: sheet, colors: None },
    ];
    let path = planes_scene("blend-sheet", &planes, 2.0);
    for (c, (mean, error)) in render_mean(&path).into_iter().enumerate() {
        let want = 0.7 * RADIANCE;
        eprintln!("blended sheet channel {c}: {mean:.5} +- {error:.5}, want {want:.5}");
        assert!((mean - want).abs() <= 4.0 * error + 1e-6, "channel {c}: {mean} vs {want}");
        assert!(error > 0.0, "coverage is decided per ray, so pixels are noisy");
    }
}

#[test]
fn a_blended_emitter_lights_as_an_opaque_one_of_alpha_times_its_radiance() {
    // A white Lambertian floor lit by a ceiling emitter, seen by a camera between them. Light
    // sampling of the emitter must count its coverage as paths that hit it do; nothing else
    // differs (the emitter's surface is black either way, and what passes it meets a black sky).
    let floor = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0},
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
    });
    let lit_by = |tag: &str, light: Value| {
        let planes = [
            Plane { y: 0.0, up: true, material: floor.clone(), colors: None },
            Plane { y: 1.0, up: false, material: light, colors: None },
        ];
        render_mean(&planes_scene(tag, &planes, 0.5))
    };
    let blended = lit_by("blend-light", emitter(RADIANCE, 0.4));
    let opaque = lit_by("dim-light", emitter(0.4 * RADIANCE, 1.0));
    for c in 0..3 {
        let ((a, ea), (b, eb)) = (blended[c], opaque[c]);
        eprintln!("floor channel {c}: blended light {a:.5} +- {ea:.5}, dimmer opaque light {b:.5} +- {eb:.5}");
        assert!(b > 0.3, "the floor is lit");
        assert!((a - b).abs() <= 4.0 * (ea * ea + eb * eb).sqrt(), "channel {c}: {a} vs {b}");
    }
}

#[test]
fn a_masked_emitter_lights_only_where_its_alpha_passes_the_cutoff() {
    // MASK makes a surface there or not there. An emitter whose alpha is below the cutoff is cut
    // out everywhere and lights nothing; one whose alpha passes is exactly the opaque emitter
    // (coverage 1: the same numbers). An emitter whose vertex alpha runs from 0 at -x to 1 at +x
    // is there only over x > 0: the floor's mean, over a square centred below it, is half of
    // what the whole emitter gives (by symmetry, E(x) + E(-x) is the whole emitter's E). Light
    // sampling must skip the cut-out half as the sampled paths that pass through it do.
    let floor = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "metallicFactor": 0.0},
        "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
    });
    let lit_by = |tag: &str, light: Value, colors: Option<[[f32; 4]; 4]>| {
        let planes = [
            Plane { y: 0.0, up: true, material: floor.clone(), colors: None },
            Plane { y: 1.0, up: false, material: light, colors },
        ];
        render_mean(&planes_scene(tag, &planes, 0.5))
    };
    let masked = |alpha: f64| {
        let mut m = emitter(RADIANCE, 1.0);
        m["pbrMetallicRoughness"]["baseColorFactor"][3] = json!(alpha);
        m["alphaMode"] = json!("MASK");
        m["alphaCutoff"] = json!(0.5);
        m
    };
    let (clear, solid) = ([1.0, 1.0, 1.0, 0.0], [1.0, 1.0, 1.0, 1.0]);
    let cut_out = lit_by("mask-out-light", masked(0.3), None);
    let kept = lit_by("mask-in-light", masked(0.7), None);
    let half = lit_by("mask-half-light", masked(1.0), Some([clear, solid, solid, clear]));
    let opaque = lit_by("opaque-light", emitter(RADIANCE, 1.0), None);
    for c in 0..3 {
        let ((h, eh), (o, eo)) = (half[c], opaque[c]);
        eprintln!(
            "floor channel {c}: cut-out light {:.5}, kept {:.5}, opaque {o:.5} +- {eo:.5}, \
             half-masked {h:.5} +- {eh:.5} (expected {:.5})",
            cut_out[c].0,
            kept[c].0,
            0.5 * o
        );
        assert!(o > 0.5, "the opaque light lights the floor");
        assert_eq!(cut_out[c].0, 0.0, "channel {c}: a cut-out emitter lit the floor");
        assert_eq!(kept[c].0, o, "channel {c}: a kept emitter differs from an opaque one");
        let sigma = (eh * eh + 0.25 * eo * eo).sqrt();
        assert!((h - 0.5 * o).abs() <= 4.0 * sigma, "channel {c}: half-masked {h} vs {}", 0.5 * o);
    }
}

/// `KHR_materials_unlit`: the surface shows its base colour exactly, in the dark and under a
/// white sky alike (lighting does not change it), and its emissive factor lights nothing.
#[test]
fn an_unlit_surface_shows_its_base_colour_whatever_lights_it() {
    let unlit = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [BASE[0], BASE[1], BASE[2], 1.0]},
        "emissiveFactor": [1.0, 1.0, 1.0],
        "extensions": {"KHR_materials_unlit": {}}
    });
    let planes = [Plane { y: 0.0, up: true, material: unlit, colors: None }];
    let path = planes_scene("unlit", &planes, 1.0);
    let scene = common::gltf::load_path(&path).unwrap();
    assert!(scene.materials[0].unlit);
    let prepared = worker::render::scene::prepare(&scene, &RenderSettings::default()).unwrap();
    assert!(prepared.lights.lights.is_empty(), "an unlit surface is no light");
    for environment in [None, Some(common::settings::Environment::Color { color: [1.0; 3] })] {
        let settings =
            RenderSettings { width: 8, height: 8, spp: 4, environment, ..Default::default() };
        let film = render(&scene, &settings);
        for p in film.mean_rgb() {
            for c in 0..3 {
                assert!((p[c] as f64 - BASE[c]).abs() < 1e-6, "{p:?}");
            }
        }
    }
}

/// `KHR_materials_diffuse_transmission`: a translucent sheet without a specular layer over the
/// emitter passes dt x colour of the light below, Lambertian (so a pixel is dt x colour x L, less
/// the sliver of sky the emitter leaves uncovered); out-of-range values are refused.
#[test]
fn a_translucent_sheet_passes_its_diffuse_transmission() {
    let (dt, color) = (0.6, [0.3, 0.9, 0.6]);
    let sheet = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0},
        "extensions": {
            "KHR_materials_specular": {"specularFactor": 0.0},
            "KHR_materials_diffuse_transmission": {
                "diffuseTransmissionFactor": dt,
                "diffuseTransmissionColorFactor": color
            }
        }
    });
    let planes = [
        Plane { y: 0.0, up: true, material: emitter(RADIANCE, 1.0), colors: None },
        Plane { y: 1.0, up: true, material: sheet.clone(), colors: None },
    ];
    let means = render_mean(&planes_scene("translucent", &planes, 2.0));
    for c in 0..3 {
        let expected = dt * color[c] * RADIANCE;
        let (mean, se) = means[c];
        assert!(
            mean <= expected * 1.0005 + 4.0 * se && mean >= expected * 0.995 - 4.0 * se,
            "channel {c}: {mean} +- {se} against {expected}"
        );
    }
    let mut bad = sheet;
    bad["extensions"]["KHR_materials_diffuse_transmission"]["diffuseTransmissionFactor"] =
        json!(1.5);
    let planes = [Plane { y: 0.0, up: true, material: bad, colors: None }];
    let e = common::gltf::load_path(&planes_scene("translucent-bad", &planes, 2.0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("diffuseTransmissionFactor 1.5"), "{e}");
}
