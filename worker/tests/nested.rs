//! Nested volumes through the whole renderer: a liquid in a glass, modelled as artists do (the
//! liquid's mesh overlaps the glass's inner wall a little), on scenes whose answer is known.
//!
//! - A layered slab at normal incidence (glass wall, liquid, glass wall) under an orthographic
//!   camera in a white environment: R + T of the incoherent multiple-reflection series of its
//!   three interfaces (air-glass, glass-liquid, liquid-glass, glass-air: relative indices from
//!   both media) with each layer's Beer-Lambert transmittance, computed by the adding method.
//!   Wrong relative indices (the liquid against air) or a false interface taken as real (the
//!   glass's inner wall inside the liquid) change the reflections, and the wrong medium's
//!   absorption changes the transmittance.
//! - A furnace: glass holding a liquid of another index holding a bubble of air, in a white
//!   environment, is exactly 1 in every pixel: the 1 / eta² radiance scales of the crossings
//!   telescope to 1 only if every interface's relative index is the two media's.

mod support;

use common::settings::RenderSettings;
use serde_json::{json, Value};
use support::*;

/// An axis-aligned box shell: its corners, and whether its faces look inward (a cavity).
#[derive(Clone)]
struct Shell {
    min: [f32; 3],
    max: [f32; 3],
    inward: bool,
}

/// A scene of meshes, each made of box shells with one material and turned by `tilt` radians
/// about the z axis, seen straight down by an orthographic camera at height `camera_y` over a
/// 2 x 2 square. Returns the file's path.
fn shells_scene(
    tag: &str,
    meshes: Vec<(Vec<Shell>, Value)>,
    camera_y: f32,
    tilt: f64,
) -> std::path::PathBuf {
    let half_turn = (tilt / 2.0).sin_cos();
    let mut bytes: Vec<u8> = Vec::new();
    let (mut accessors, mut views, mut json_meshes, mut materials, mut nodes) =
        (vec![], vec![], vec![], vec![], vec![]);
    for (i, (shells, material)) in meshes.into_iter().enumerate() {
        let mut positions: Vec<[f32; 3]> = Vec::new();
        let mut indices: Vec<u32> = Vec::new();
        for s in &shells {
            let base = positions.len() as u32;
            for c in 0..8 {
                positions.push([
                    if c & 1 == 1 { s.max[0] } else { s.min[0] },
                    if c & 2 == 2 { s.max[1] } else { s.min[1] },
                    if c & 4 == 4 { s.max[2] } else { s.min[2] },
                ]);
            }
            // Each face counter-clockwise seen from outside the box.
            let faces: [[u32; 4]; 6] = [
                [0, 4, 6, 2],
                [1, 3, 7, 5],
                [0, 1, 5, 4],
                [2, 6, 7, 3],
                [0, 2, 3, 1],
                [4, 5, 7, 6],
            ];
            for q in faces {
                let tri = [[q[0], q[1], q[2]], [q[0], q[2], q[3]]];
                for mut t in tri {
                    if s.inward {
                        t.swap(1, 2);
                    }
                    indices.extend(t.map(|v| v + base));
                }
            }
        }
        let (lo, hi) = positions.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
            (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))
        });
        let p_start = bytes.len();
        bytes.extend(positions.iter().flatten().flat_map(|v| v.to_le_bytes()));
        let i_start = bytes.len();
        bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
        views.push(json!({"buffer": 0, "byteOffset": p_start, "byteLength": i_start - p_start}));
        views
            .push(json!({"buffer": 0, "byteOffset": i_start, "byteLength": bytes.len() - i_start}));
        accessors.push(json!({"bufferView": 2 * i, "componentType": 5126, "count": positions.len(), "type": "VEC3", "min": lo, "max": hi}));
        accessors.push(json!({"bufferView": 2 * i + 1, "componentType": 5125, "count": indices.len(), "type": "SCALAR"}));
        json_meshes.push(json!({"primitives": [{"attributes": {"POSITION": 2 * i}, "indices": 2 * i + 1, "material": i}]}));
        materials.push(material);
        nodes.push(json!({"mesh": i, "rotation": [0.0, 0.0, half_turn.0, half_turn.1]}));
    }
    let camera = nodes.len();
    nodes.push(json!({"camera": 0, "translation": [0.0, camera_y, 0.0],
        "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}));
    let json = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..=camera).collect::<Vec<_>>()}],
        "nodes": nodes,
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.01, "zfar": 100.0}}],
        "meshes": json_meshes,
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir = std::env::temp_dir().join(format!("renderfarm-nested-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("shells.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// A wide glass slab with a cavity between y = -half_liquid and half_liquid, walls `wall`
/// thick, and a liquid box overlapping the cavity's walls by `overlap`.
fn glass_with_liquid(half_liquid: f32, wall: f32, overlap: f32) -> (Vec<Shell>, Vec<Shell>) {
    let outer = half_liquid + wall;
    let glass = vec![
        Shell { min: [-50.0, -outer, -50.0], max: [50.0, outer, 50.0], inward: false },
        Shell { min: [-40.0, -half_liquid, -40.0], max: [40.0, half_liquid, 40.0], inward: true },
    ];
    let (l, h) = (40.0 + overlap, half_liquid + overlap);
    let liquid = vec![Shell { min: [-l, -h, -l], max: [l, h, l], inward: false }];
    (glass, liquid)
}

/// R + T at normal incidence of a stack of layers between air above and below, each (index,
/// transmittance through it), by the adding method for incoherent light: an interface between
/// indices a and b reflects r = ((a - b) / (a + b))² from either side, and a layer of
/// transmittance tau over a system that reflects R_b and transmits T_b gives, seen through the
/// interface above it, R = r + (1 - r)² tau² R_b / (1 - r tau² R_b) and
/// T = (1 - r) tau T_b / (1 - r tau² R_b).
fn stack_r_plus_t(layers: &[(f64, f64)]) -> f64 {
    let r_between = |a: f64, b: f64| ((a - b) / (a + b)).powi(2);
    let last = layers.last().unwrap().0;
    let (mut rb, mut tb) = (r_between(last, 1.0), 1.0 - r_between(last, 1.0));
    for (k, &(n, tau)) in layers.iter().enumerate().rev() {
        let above = if k == 0 { 1.0 } else { layers[k - 1].0 };
        let r = r_between(above, n);
        let denom = 1.0 - r * tau * tau * rb;
        (rb, tb) = (r + (1.0 - r).powi(2) * tau * tau * rb / denom, (1.0 - r) * tau * tb / denom);
    }
    rb + tb
}

/// Glass (1.5, tinted) holding water (1.33, tinted otherwise), overlapping the glass's inner
/// walls by 1e-4: each channel's image mean is the adding method's R + T within four standard
/// errors.
#[test]
fn a_liquid_in_glass_at_normal_incidence_gives_the_layered_fresnel_series() {
    let (n_glass, n_liquid) = (1.5f64, 1.33f64);
    let (glass_color, liquid_color, distance) = ([0.9, 0.7, 0.5], [0.4, 0.8, 0.95], 0.5);
    let (half_liquid, wall, overlap) = (0.15f32, 0.1f32, 1e-4f32);
    let (glass, liquid) = glass_with_liquid(half_liquid, wall, overlap);
    let path = shells_scene(
        "layered",
        vec![
            (glass, dielectric_material(n_glass, 1.0, Some((glass_color, distance)))),
            (liquid, dielectric_material(n_liquid, 1.0, Some((liquid_color, distance)))),
        ],
        2.0,
        0.0,
    );
    let scene = common::gltf::load_path(&path).unwrap();
    let film = render(&scene, &white_furnace(8, 512));
    let n = film.pixels.len() as f64;
    let means = film.mean_rgb();
    for c in 0..3 {
        let tau = |color: [f64; 3], thickness: f32| {
            (color[c].ln() / distance * thickness as f64).exp() // exp(-sigma d)
        };
        let expected = stack_r_plus_t(&[
            (n_glass, tau(glass_color, wall)),
            (n_liquid, tau(liquid_color, 2.0 * half_liquid)),
            (n_glass, tau(glass_color, wall)),
        ]);
        let mean = means.iter().map(|p| p[c] as f64).sum::<f64>() / n;
        let var: f64 = film.pixels.iter().map(|p| p.variance_of_mean()[c]).sum::<f64>() / n;
        let se = (var / n).sqrt();
        eprintln!("channel {c}: {mean:.5} against {expected:.5} (standard error {se:.1e})");
        assert!(
            (mean - expected).abs() < 4.0 * se + 2e-4,
            "channel {c}: {mean} against {expected}"
        );
    }
}

/// Clear glass holding clear water holding a bubble of air (ior 1), the liquid overlapping the
/// glass's inner walls, tilted so that light refracts at angles and totally reflects, in the
/// white furnace: every pixel is 1.
#[test]
fn glass_holding_water_holding_a_bubble_in_a_white_furnace_is_exactly_white() {
    let (glass, liquid) = glass_with_liquid(0.3, 0.15, 1e-3);
    let bubble = vec![Shell { min: [-0.2, -0.1, -0.15], max: [0.1, 0.15, 0.2], inward: false }];
    let path = shells_scene(
        "furnace",
        vec![
            (glass, dielectric_material(1.5, 1.0, None)),
            (liquid, dielectric_material(1.33, 1.0, None)),
            (bubble, dielectric_material(1.0, 1.0, None)),
        ],
        2.0,
        0.5,
    );
    let scene = common::gltf::load_path(&path).unwrap();
    let film = render(&scene, &white_furnace(16, 64));
    let worst = worst_from_white(&film);
    eprintln!("the worst pixel is {worst:.1e} away from 1");
    assert!(worst < 1e-4, "a pixel is {worst} away from 1");
}

/// A camera inside nested volumes: in an absorbing liquid held in an absorbing glass shell, both
/// of index 1 (no reflections), the liquid overlapping the glass's inner walls, looking straight
/// down into the white furnace from 0.1 above the cavity's middle. Every pixel sees the furnace
/// through the rest of the liquid (0.4) and the glass's wall (0.15, the overlap included: there the glass, entered last, is the
/// medium), each channel exactly T_liquid(0.4) T_glass(0.15), with each integrator. A camera
/// taken to be in air would see through the glass alone.
#[test]
fn a_camera_inside_nested_volumes_sees_through_their_media() {
    let (glass_color, liquid_color, distance) = ([0.9, 0.7, 0.5], [0.4, 0.8, 0.95], 0.5);
    let (glass, liquid) = glass_with_liquid(0.3, 0.15, 1e-3);
    let path = shells_scene(
        "camera-inside",
        vec![
            (glass, dielectric_material(1.0, 1.0, Some((glass_color, distance)))),
            (liquid, dielectric_material(1.0, 1.0, Some((liquid_color, distance)))),
        ],
        0.1,
        0.0,
    );
    let scene = common::gltf::load_path(&path).unwrap();
    let expected: [f64; 3] = std::array::from_fn(|c| {
        let tau = |color: [f64; 3], length: f64| (color[c].ln() / distance * length).exp();
        tau(liquid_color, 0.4) * tau(glass_color, 0.15)
    });
    let settings = white_furnace(8, 16);
    let (camera, light) = render_bdpt_with(&scene, &settings, None);
    let films = [
        ("path", render(&scene, &settings)),
        ("sppm", render_sppm_with(&scene, &settings, 8, 2, None)),
    ];
    let mut images: Vec<(&str, Vec<[f64; 3]>)> = films
        .iter()
        .map(|(name, f)| (*name, f.pixels.iter().map(|p| p.mean()).collect()))
        .collect();
    images.push(("bdpt", bdpt_sum(&camera, &light).into_iter().map(|(m, _)| m).collect()));
    let mut wrong = Vec::new();
    for (name, image) in images {
        let worst = image
            .iter()
            .flat_map(|p| (0..3).map(move |c| (p[c] - expected[c]).abs() / expected[c]))
            .fold(0.0, f64::max);
        eprintln!("{name}: {:?} against {expected:?}, worst {worst:.1e}", image[0]);
        if worst >= 1e-5 {
            wrong.push(format!("{name}: a pixel is {worst} away (relative)"));
        }
    }
    assert!(wrong.is_empty(), "{wrong:?} from {expected:?}");
}

/// The wavefront keeps paths through volumes on its vectors (each lane tracks its media, passes
/// false interfaces, refracts through the dielectric one lane at a time): its sums and ray counts
/// are the scalar path tracer's bit for bit, on the nested volumes above (overlaps, a bubble,
/// total internal reflection, the camera inside two media), on rough and tinted glass (the
/// liquid rough, the glass smooth), a wax-like volume entered by diffuse transmission, and the
/// Cornell box with water around the short block, around its light, and rough round the block
/// with a point light inside (shadow rays through the medium, from the surfaces in it and from
/// its rough surface into it), under a perspective camera and an environment; paths ended by
/// too many false interfaces (150 overlapping slabs of one medium), and a textured unlit block
/// inside a medium.
#[test]
fn the_wavefront_traces_paths_through_nested_volumes_bit_for_bit() {
    let (glass, liquid) = glass_with_liquid(0.3, 0.15, 1e-3);
    let bubble = vec![Shell { min: [-0.2, -0.1, -0.15], max: [0.1, 0.15, 0.2], inward: false }];
    let tint = |c: [f64; 3]| Some((c, 0.5));
    let mut rough_liquid = dielectric_material(1.33, 1.0, tint([0.4, 0.8, 0.95]));
    rough_liquid["pbrMetallicRoughness"]["roughnessFactor"] = json!(0.35);
    let wax = json!({
        "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.8, 0.6, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.5},
        "extensions": {
            "KHR_materials_diffuse_transmission": {"diffuseTransmissionFactor": 0.6},
            "KHR_materials_volume": {"thicknessFactor": 1.0, "attenuationDistance": 0.4, "attenuationColor": [0.9, 0.5, 0.3]}
        }
    });
    let scenes = [
        (
            "glass, water and a bubble, tilted",
            shells_scene(
                "wavefront-furnace",
                vec![
                    (glass.clone(), dielectric_material(1.5, 1.0, tint([0.9, 0.7, 0.5]))),
                    (liquid.clone(), rough_liquid),
                    (bubble.clone(), dielectric_material(1.0, 1.0, None)),
                ],
                2.0,
                0.5,
            ),
        ),
        (
            "a camera inside nested volumes",
            shells_scene(
                "wavefront-inside",
                vec![
                    (glass, dielectric_material(1.5, 1.0, tint([0.9, 0.7, 0.5]))),
                    (liquid, dielectric_material(1.33, 1.0, tint([0.4, 0.8, 0.95]))),
                ],
                0.1,
                0.3,
            ),
        ),
        ("wax", shells_scene("wavefront-wax", vec![(bubble, wax)], 2.0, 0.4)),
        // 150 slabs of one medium, each overlapping the next: a path down through them
        // meets two false interfaces a slab (into the next while inside one, out of the one
        // before while inside the next), more than it may pass (`MAX_FALSE_INTERFACES`), and
        // ends inside; paths past their side pass through fewer.
        (
            "too many false interfaces",
            shells_scene(
                "wavefront-stuck",
                vec![(
                    (0..150)
                        .map(|k| {
                            let y = -0.9 + 0.012 * k as f32;
                            Shell {
                                min: [-0.5, y, -0.5],
                                max: [0.5, y + 0.018, 0.5],
                                inward: false,
                            }
                        })
                        .collect(),
                    dielectric_material(1.0, 1.0, tint([0.98, 0.99, 1.0])),
                )],
                2.0,
                0.2,
            ),
        ),
    ];
    let sky = RenderSettings {
        environment: Some(common::settings::Environment::Color { color: [0.8, 0.9, 1.0] }),
        ..white_furnace(24, 6)
    };
    for (name, path) in &scenes {
        let scene = common::gltf::load_path(path).unwrap();
        assert_wavefront_renders_the_scalar_paths(name, &scene, &sky);
    }
    let cornell = RenderSettings { width: 24, height: 20, spp: 6, ..settings("cornell-box") };
    for (name, scene) in [
        ("water round the block", cornell_under_water()),
        ("a light in water", cornell_light_in_water()),
        ("a lamp in rough water", cornell_under_rough_water_with_a_lamp()),
        ("a textured unlit block in water", cornell_with_a_textured_unlit_block_under_water()),
    ] {
        assert_wavefront_renders_the_scalar_paths(name, &scene, &cornell);
        let with_sky = RenderSettings { width: 24, height: 20, max_depth: 4, ..sky.clone() };
        assert_wavefront_renders_the_scalar_paths(name, &scene, &with_sky);
    }
}
