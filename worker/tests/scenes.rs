//! Whole-scene estimator tests: analytic furnaces, convergence to the independent Cornell box
//! reference, exact merging of split sample ranges, and numerical robustness (scale, distance
//! from the origin, degenerate triangles). Tolerances come from the films' measured variance.

mod support;

use common::{
    film::{Film, Rect, TileAccum},
    protocol::{SampleRange, TaskKind, TaskSpec},
    settings::RenderSettings,
};
use glam::Vec3;
use serde_json::json;
use support::*;
use worker::render::{
    integrators::wavefront,
    light::{Light, LightChoice},
    render_task,
    scene::{prepare, prepare_with_light_choice, PreparedScene},
};

/// Reference noise of `ref/cornell-box.exr` per value (its `noise_rmse_est`, squared).
const CORNELL_REF_VAR: f64 = 0.001_251_854 * 0.001_251_854;

fn downsample(w: usize, h: usize, img: &[[f32; 3]], f: usize) -> Vec<[f32; 3]> {
    let (ow, oh) = (w / f, h / f);
    let mut out = vec![[0.0f32; 3]; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            let mut acc = [0.0f64; 3];
            for dy in 0..f {
                for dx in 0..f {
                    let p = img[(y * f + dy) * w + x * f + dx];
                    for c in 0..3 {
                        acc[c] += p[c] as f64;
                    }
                }
            }
            out[y * ow + x] = acc.map(|v| (v / (f * f) as f64) as f32);
        }
    }
    out
}

fn assert_matches(what: &str, film: &Film, expected: &[[f32; 3]], expected_var: f64) -> Comparison {
    assert_eq!(film.rejected, 0, "{what}: non-finite samples");
    let cmp = compare(film, expected, expected_var, 16);
    let z_block = sidak_z(0.01, cmp.blocks);
    eprintln!("{what}: {cmp:?} (block limit {z_block:.2})");
    assert!(cmp.z_image.abs() < 4.0, "{what}: image-level bias, z = {:.2}", cmp.z_image);
    assert!(cmp.z_block_max < z_block, "{what}: a block is off by {:.2} sigma", cmp.z_block_max);
    cmp
}

/// The furnace's centre pixel sees the sphere: 0.8 within its own confidence interval.
fn assert_centre_is_albedo(film: &Film) {
    let centre = film.pixels[(film.height / 2 * film.width + film.width / 2) as usize];
    let (m, v) = (centre.mean()[1], centre.variance_of_mean()[1]);
    assert!((m - 0.8).abs() <= 4.0 * v.sqrt() + 1e-6, "centre {m} +- {}", v.sqrt());
}

#[test]
fn furnace_sphere_is_its_albedo_within_noise() {
    let scene = load("furnace.gltf");
    let mut settings = settings("furnace");
    settings.spp = 16;
    let film = render(&scene, &settings);
    let (w, h, reference) = read_rgb(&scenes().join("ref/furnace.exr"));
    assert_eq!((w as u32, h as u32), (settings.width, settings.height));
    assert_matches("furnace", &film, &reference, 0.0);
    // Background pixels see the environment directly: exactly 1 with no variance.
    assert_eq!(film.pixels[0].mean(), [1.0; 3]);
    assert_centre_is_albedo(&film);
}

#[test]
fn closed_furnace_is_one_everywhere() {
    let scene = load("furnace-closed.gltf");
    let settings = settings("furnace-closed");
    let film = render(&scene, &settings);
    let ones = vec![[1.0f32; 3]; (settings.width * settings.height) as usize];
    let cmp = assert_matches("furnace-closed", &film, &ones, 0.0);
    assert!(cmp.rmse < 0.05, "rmse {}", cmp.rmse);
}

#[test]
fn cornell_box_converges_to_the_independent_reference() {
    let scene = load("cornell-box.gltf");
    let mut settings = settings("cornell-box");
    settings.spp = 64;
    let film = render(&scene, &settings);
    let (_, _, reference) = read_rgb(&scenes().join("ref/cornell-box.exr"));
    let cmp = assert_matches("cornell", &film, &reference, CORNELL_REF_VAR);
    let ratio = cmp.predicted_rmse / cmp.rmse;
    assert!(
        (0.5..=2.0).contains(&ratio),
        "estimated error {:.4} vs real {:.4}",
        cmp.predicted_rmse,
        cmp.rmse
    );
}

#[test]
fn split_sample_ranges_merge_in_order_deterministically() {
    let scene = load("cornell-box.gltf");
    let settings = RenderSettings { width: 48, height: 40, ..settings("cornell-box") };
    let prepared = prepare(&scene, &settings).unwrap();
    let rect = Rect { x0: 8, y0: 4, width: 24, height: 20 };
    let task = |start, end| TaskSpec {
        frame: 0,
        rect,
        samples: SampleRange { start, end },
        kind: TaskKind::Camera,
    };
    let whole = render_task(&prepared, 0, &task(0, 64)).tile;
    let in_order = || {
        let mut quarters = TileAccum::new(rect);
        for (s, e) in [(0, 16), (16, 32), (32, 48), (48, 64)] {
            quarters.merge(&render_task(&prepared, 0, &task(s, e)).tile);
        }
        quarters
    };
    let (a, b) = (in_order(), in_order());
    assert_eq!(a, b, "merging the same tasks in the same order must give the same bits");
    for (p, q) in whole.pixels.iter().zip(&a.pixels) {
        assert_eq!((p.n, p.n_odd), (q.n, q.n_odd));
        for c in 0..3 {
            assert!((p.mean[c] - q.mean[c]).abs() <= 1e-12 * p.mean[c].abs().max(1e-12));
            assert!(
                (p.mean_odd[c] - q.mean_odd[c]).abs() <= 1e-12 * p.mean_odd[c].abs().max(1e-12)
            );
            assert!((p.m2[c] - q.m2[c]).abs() <= 1e-9 * p.m2[c].abs().max(1e-12));
        }
    }
    // Rows spread over threads are merged into an empty tile: exact, whatever the thread count.
    for threads in [2, 3, 7] {
        let threaded =
            worker::render::render_task_threads(&prepared, 0, &task(0, 64), threads).tile;
        assert_eq!(whole, threaded, "{threads} threads");
    }
}

/// The Cornell box under a root transform must render like the original (camera included).
fn transformed_cornell_matches_reference(tag: &str, root: serde_json::Value) {
    let path = edited_scene("cornell-box", tag, |json| wrap_roots(json, root));
    let scene = common::gltf::load_path(&path).unwrap();
    let mut settings = settings("cornell-box");
    settings.width = 128;
    settings.height = 128;
    settings.spp = 16;
    let film = render(&scene, &settings);
    let (w, h, reference) = read_rgb(&scenes().join("ref/cornell-box.exr"));
    let reference = downsample(w, h, &reference, 2);
    assert_matches(tag, &film, &reference, CORNELL_REF_VAR / 4.0);
}

#[test]
fn cornell_box_at_original_placement() {
    transformed_cornell_matches_reference("identity", json!({"name": "root"}));
}

#[test]
fn cornell_box_scaled_down_1e3() {
    transformed_cornell_matches_reference("scale-1e-3", json!({"scale": [1e-3, 1e-3, 1e-3]}));
}

#[test]
fn cornell_box_scaled_up_1e3() {
    transformed_cornell_matches_reference("scale-1e3", json!({"scale": [1e3, 1e3, 1e3]}));
}

#[test]
fn cornell_box_moved_1e5_away() {
    transformed_cornell_matches_reference("offset-1e5", json!({"translation": [1e5, -1e5, 1e5]}));
}

#[test]
fn cornell_box_moved_1e6_away() {
    transformed_cornell_matches_reference("offset-1e6", json!({"translation": [1e6, 1e6, -1e6]}));
}

#[test]
fn degenerate_triangles_change_nothing() {
    // Zero-area, collinear and needle-thin triangles in the middle of the box.
    let positions: [[f32; 3]; 9] = [
        [0.3, 0.3, 0.3],
        [0.3, 0.3, 0.3],
        [0.3, 0.3, 0.3],
        [0.1, 0.2, 0.25],
        [0.2, 0.3, 0.25],
        [0.3, 0.4, 0.25],
        [0.25, 0.05, 0.2],
        [0.25, 0.5, 0.2],
        [0.25 + 1e-7, 0.5, 0.2],
    ];
    let bytes: Vec<u8> = positions.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let uri = format!("data:application/octet-stream;base64,{}", base64(&bytes));
    let path = edited_scene("cornell-box", "degenerate", |json| {
        let buffer = json["buffers"].as_array().unwrap().len();
        json["buffers"]
            .as_array_mut()
            .unwrap()
            .push(json!({"uri": uri, "byteLength": bytes.len()}));
        let view = json["bufferViews"].as_array().unwrap().len();
        json["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(json!({"buffer": buffer, "byteLength": bytes.len()}));
        let accessor = json["accessors"].as_array().unwrap().len();
        json["accessors"].as_array_mut().unwrap().push(json!({
            "bufferView": view, "componentType": 5126, "count": 9, "type": "VEC3",
            "min": [0.1, 0.05, 0.2], "max": [0.3, 0.5, 0.3]
        }));
        let mesh = json["meshes"].as_array().unwrap().len();
        json["meshes"]
            .as_array_mut()
            .unwrap()
            .push(json!({"primitives": [{"attributes": {"POSITION": accessor}, "material": 0}]}));
        let node = json["nodes"].as_array().unwrap().len();
        json["nodes"].as_array_mut().unwrap().push(json!({"name": "degenerate", "mesh": mesh}));
        json["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(node));
    });
    let scene = common::gltf::load_path(&path).unwrap();
    let mut settings = settings("cornell-box");
    settings.width = 128;
    settings.height = 128;
    settings.spp = 16;
    let film = render(&scene, &settings);
    let (w, h, reference) = read_rgb(&scenes().join("ref/cornell-box.exr"));
    assert_matches("degenerate", &film, &downsample(w, h, &reference, 2), CORNELL_REF_VAR / 4.0);
}

#[test]
fn extreme_roughness_metalness_and_radiance_produce_no_nan() {
    // The roughness/metalness sweep (roughness 0 to 1, metal and dielectric) lit by a very bright
    // small emitter and a dim environment: every sample must be finite.
    let path =
        assets().join("real/MetalRoughSpheresNoTextures/glTF/MetalRoughSpheresNoTextures.gltf");
    let mut scene = common::gltf::load_path(&path).unwrap();
    let mut bright = scene.materials[0].clone();
    bright.emissive = glam::Vec3::splat(1.0e7);
    bright.double_sided = true;
    scene.materials.push(bright);
    // Re-use the first instance's mesh as a tiny, very bright emitter far above the spheres.
    let emitter = scene.meshes[scene.instances[0].mesh].clone();
    scene.meshes.push(common::scene::Mesh { material: scene.materials.len() - 1, ..emitter });
    scene.instances.push(common::scene::Instance {
        mesh: scene.meshes.len() - 1,
        node: 0,
        offset: glam::DMat4::IDENTITY,
        transform: glam::DMat4::from_scale_rotation_translation(
            glam::DVec3::splat(1e-3),
            glam::DQuat::IDENTITY,
            glam::DVec3::new(0.0, 30.0, 30.0),
        ),
    });
    let settings = RenderSettings {
        width: 48,
        height: 48,
        spp: 16,
        environment: Some(common::settings::Environment::Color { color: [1e-3, 1e-3, 1e-3] }),
        ..Default::default()
    };
    let film = render(&scene, &settings);
    assert_eq!(film.rejected, 0, "non-finite or absurd samples");
    assert!(film.mean_rgb().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
    assert!(film.mean_rgb().iter().flatten().any(|v| *v > 1e-3), "the emitter lights the spheres");
}

#[test]
fn furnace_under_a_constant_environment_map_matches_the_uniform_one() {
    // A constant map is the uniform environment through the map code path: importance sampling,
    // direction lookup and MIS must give the furnace's exact answer; an invisible map must leave
    // the background black and the sphere unchanged.
    let scene = load("furnace.gltf");
    let map = common::envmap::EnvMap {
        width: 16,
        height: 8,
        texels: vec![glam::Vec3::splat(0.5); 16 * 8],
    };
    let map_settings = |visible: bool| RenderSettings {
        spp: 16,
        environment: Some(common::settings::Environment::Map {
            map: "constant".into(),
            intensity: 2.0,
            rotation_deg: 30.0,
            visible,
        }),
        ..settings("furnace")
    };
    let (_, _, reference) = read_rgb(&scenes().join("ref/furnace.exr"));
    let settings = map_settings(true);
    let prepared =
        worker::render::scene::prepare_with_environment(&scene, &settings, Some(&map)).unwrap();
    let film = render_prepared(&prepared, &settings);
    assert_matches("furnace-map", &film, &reference, 0.0);

    let settings = map_settings(false);
    let prepared =
        worker::render::scene::prepare_with_environment(&scene, &settings, Some(&map)).unwrap();
    let film = render_prepared(&prepared, &settings);
    assert_eq!(film.pixels[0].mean(), [0.0; 3], "an invisible map is not seen by camera rays");
    assert_centre_is_albedo(&film);
}

#[test]
fn every_real_asset_renders_without_nan() {
    // Every Khronos sample in tests/assets (textures, normal maps, vertex colours, instancing,
    // sparse accessors, cameras, animation, emissive strength) renders a small image with finite
    // values.
    let root = assets().join("real");
    let mut rendered = 0;
    for asset in std::fs::read_dir(&root).unwrap() {
        let asset = asset.unwrap().path();
        for variant in ["glTF", "glTF-Binary", "glTF-Embedded"] {
            let Ok(files) = std::fs::read_dir(asset.join(variant)) else { continue };
            for file in files {
                let path = file.unwrap().path();
                let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
                if ext != "gltf" && ext != "glb" {
                    continue;
                }
                let scene = common::gltf::load_path(&path)
                    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                let settings = RenderSettings {
                    width: 12,
                    height: 8,
                    spp: 2,
                    environment: Some(common::settings::Environment::Color { color: [0.5; 3] }),
                    ..Default::default()
                };
                let film = render(&scene, &settings);
                assert_eq!(film.rejected, 0, "{}: non-finite samples", path.display());
                assert!(
                    film.mean_rgb().iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
                    "{}",
                    path.display()
                );
                rendered += 1;
            }
        }
    }
    assert!(rendered >= 35, "only {rendered} assets found");
}

/// A normal-mapped plane, z = 0 facing +z, as a glTF document: `positions`, `normals` and
/// `uvs` per vertex, `tangents` as its TANGENT where given, lit by a directional light from
/// above and aside and seen by a camera at z = 3. Its one-texel normal map tilts the normal 45
/// degrees toward the tangent, so the tangents set where each point faces the light.
fn normal_mapped_plane(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: &[glam::Vec2],
    indices: &[[u32; 3]],
    tangents: Option<&[glam::Vec4]>,
) -> common::scene::Scene {
    let floats = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut parts = vec![
        floats(&positions.iter().flat_map(|p| p.to_array()).collect::<Vec<_>>()),
        floats(&normals.iter().flat_map(|n| n.to_array()).collect::<Vec<_>>()),
        floats(&uvs.iter().flat_map(|t| t.to_array()).collect::<Vec<_>>()),
        indices.iter().flatten().flat_map(|i| i.to_le_bytes()).collect(),
    ];
    let n = positions.len();
    let mut accessors = vec![
        json!({"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3"}),
        json!({"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC3"}),
        json!({"bufferView": 2, "componentType": 5126, "count": n, "type": "VEC2"}),
        json!({"bufferView": 3, "componentType": 5125, "count": indices.len() * 3, "type": "SCALAR"}),
    ];
    let mut attributes = json!({"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2});
    if let Some(t) = tangents {
        parts.push(floats(&t.iter().flat_map(|t| t.to_array()).collect::<Vec<_>>()));
        accessors.push(json!({"bufferView": 4, "componentType": 5126, "count": n, "type": "VEC4"}));
        attributes["TANGENT"] = json!(4);
    }
    let (mut bin, mut views) = (Vec::new(), Vec::new());
    for part in parts {
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": part.len()}));
        bin.extend(part);
    }
    // One texel (255, 128, 255): the tangent-space normal (1, 1/255, 1), normalised.
    let png = "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAIAAACQd1PeAAAADElEQVR4nGP43/AfAAUAAn8gmLxdAAAAAElFTkSuQmCC";
    let doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_lights_punctual"],
        "extensions": {"KHR_lights_punctual": {"lights": [{"type": "directional", "intensity": 3.0}]}},
        "scenes": [{"nodes": [0, 1, 2]}],
        "nodes": [
            {"mesh": 0},
            {"camera": 0, "translation": [0.0, 0.0, 3.0]},
            // The light turned 50 degrees about (1, 1, 0): it comes from above, aside in x and y.
            {"rotation": [0.29884, 0.29884, 0.0, 0.90631],
             "extensions": {"KHR_lights_punctual": {"light": 0}}}
        ],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.01}}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": 3, "material": 0}]}],
        "materials": [{
            "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0},
            "normalTexture": {"index": 0}
        }],
        "textures": [{"source": 0}],
        "images": [{"uri": format!("data:image/png;base64,{png}")}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bin))}]
    });
    common::gltf::load_slice(doc.to_string().as_bytes(), &common::gltf::NoFiles).expect("the plane")
}

/// A normal-mapped mesh without TANGENT renders exactly as the same mesh with the tangents the
/// loader made for it (MikkTSpace) written as its TANGENT, bit for bit, and otherwise than with
/// those tangents turned 90 degrees: the renderer shades by the generated tangents. The plane's
/// texture is mirrored at x = 0 and warped, so its vertices are split at the seam and its
/// tangents vary from vertex to vertex.
#[test]
fn generated_tangents_render_as_the_same_tangents_given_in_the_file() {
    let k = 8;
    let (mut positions, mut uvs) = (Vec::new(), Vec::new());
    for j in 0..=k {
        for i in 0..=k {
            let (x, y) = (2.0 * i as f32 / k as f32 - 1.0, 2.0 * j as f32 / k as f32 - 1.0);
            positions.push(Vec3::new(x, y, 0.0));
            uvs.push(glam::Vec2::new(
                0.6 * x.abs() + 0.3 * x * x + 0.1 * y * y,
                0.5 - 0.4 * y + 0.1 * x * x,
            ));
        }
    }
    let at = |i: u32, j: u32| j * (k + 1) + i;
    let indices: Vec<[u32; 3]> = (0..k)
        .flat_map(|j| {
            (0..k).flat_map(move |i| {
                [
                    [at(i, j), at(i + 1, j), at(i + 1, j + 1)],
                    [at(i, j), at(i + 1, j + 1), at(i, j + 1)],
                ]
            })
        })
        .collect();
    let normals = vec![Vec3::Z; positions.len()];
    let made = normal_mapped_plane(&positions, &normals, &uvs, &indices, None);
    let mesh = &made.meshes[0];
    let tangents = mesh.tangents.as_deref().expect("tangents made for the normal map");
    assert_eq!(mesh.positions.len(), positions.len() + k as usize + 1, "the seam's column split");
    let given = normal_mapped_plane(
        &mesh.positions,
        mesh.normals.as_deref().unwrap(),
        mesh.uvs[0].as_deref().unwrap(),
        &mesh.indices,
        Some(tangents),
    );
    assert_eq!(given.meshes[0].tangents.as_deref(), Some(tangents), "read back as written");
    let turned: Vec<glam::Vec4> =
        tangents.iter().map(|t| Vec3::Z.cross(t.truncate()).extend(t.w)).collect();
    let turned = normal_mapped_plane(
        &mesh.positions,
        mesh.normals.as_deref().unwrap(),
        mesh.uvs[0].as_deref().unwrap(),
        &mesh.indices,
        Some(&turned),
    );
    let settings = RenderSettings { width: 24, height: 24, spp: 4, ..Default::default() };
    let (made, given, turned) =
        (render(&made, &settings), render(&given, &settings), render(&turned, &settings));
    assert!(made.pixels == given.pixels, "the same tangents render the same image");
    let centre = |f: &Film| f.pixels[12 * 24 + 12].mean();
    assert!(centre(&made)[0] > 0.0, "the plane is lit");
    assert!(made.pixels != turned.pixels, "the tangents shade the image");
    assert_ne!(centre(&made), centre(&turned));
}

/// The wavefront renderer (8 or 16 paths at once, shading in SIMD) traces exactly the paths of
/// the scalar one: the same sums bit for bit and the same ray count, with a lens, with short
/// bounce limits, on an offset tile with an offset sample range, with an emitter that shines
/// from both faces, with glossy walls and glossy plates (the metal-rough BSDF), on textured
/// real assets (DamagedHelmet: base colour, metal-rough, normal and emissive maps, its emissive
/// parts lights sampled by the scalar routine; BoxTextured; VertexColorTest), with vertex
/// colours on an untextured material, with vertex normals, with point, spot and directional
/// lights, in uniform environments, the furnaces included, with cut-outs (alpha-blended, a light
/// among them), and with smooth and rough glass (a refractive, absorbing volume), layered,
/// thin-walled and unlit materials, all kept on the vectors; each with
/// its lights chosen by the mixture and by the light tree (whose probabilities depend on the
/// point).
#[test]
fn wavefront_renders_the_scalar_paths_bit_for_bit() {
    let real = |path: &str| {
        let path = assets().join("real").join(path);
        common::gltf::load_path(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    let two_sided = edited_scene("cornell-box", "two-sided-light", |json| {
        json["materials"][3]["doubleSided"] = json!(true);
    });
    let punctual = edited_scene("cornell-box", "punctual-lights", add_punctual_lights);
    // The walls glossy: a rough dielectric (specular layer over the diffuse base, the glTF
    // default), a smooth metal, a half-metal of another roughness, and a dielectric with a tinted
    // specular colour and another index: the metal-rough BSDF in every lane.
    let glossy = edited_scene("cornell-box", "glossy-walls", |json| {
        let walls = [
            json!({"metallicFactor": 0.0, "roughnessFactor": 0.3}),
            json!({"metallicFactor": 1.0, "roughnessFactor": 0.05}),
            json!({"metallicFactor": 0.5, "roughnessFactor": 0.7}),
        ];
        for (k, w) in walls.into_iter().enumerate() {
            let m = &mut json["materials"][k];
            m["pbrMetallicRoughness"]["metallicFactor"] = w["metallicFactor"].clone();
            m["pbrMetallicRoughness"]["roughnessFactor"] = w["roughnessFactor"].clone();
            m["extensions"] = json!({});
        }
        json["materials"][0]["extensions"] = json!({
            "KHR_materials_specular": {"specularFactor": 0.8, "specularColorFactor": [1.0, 0.6, 0.3]},
            "KHR_materials_ior": {"ior": 1.8}
        });
        json["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_materials_ior"));
    });
    // Vertex colours on the short block and the green wall (an untextured material shaded per
    // point), in a buffer of their own.
    let coloured = edited_scene("cornell-box", "vertex-colours", |json| {
        let colours: Vec<u8> = (0..24)
            .flat_map(|v| {
                let k = v as f32;
                [0.2 + 0.8 * (k * 0.37).sin().abs(), 0.5 + 0.5 * (k * 0.91).cos(), 0.9 - k / 30.0]
            })
            .flat_map(f32::to_le_bytes)
            .collect();
        let buffer = json["buffers"].as_array().unwrap().len();
        json["buffers"].as_array_mut().unwrap().push(json!({
            "byteLength": colours.len(),
            "uri": format!("data:application/octet-stream;base64,{}", base64(&colours)),
        }));
        for (mesh, first, count) in [(3, 0, 20), (1, 20, 4)] {
            let view = json["bufferViews"].as_array().unwrap().len();
            json["bufferViews"].as_array_mut().unwrap().push(
                json!({"buffer": buffer, "byteOffset": first * 12, "byteLength": count * 12}),
            );
            let accessor = json["accessors"].as_array().unwrap().len();
            json["accessors"].as_array_mut().unwrap().push(
                json!({"bufferView": view, "componentType": 5126, "count": count, "type": "VEC3"}),
            );
            json["meshes"][mesh]["primitives"][0]["attributes"]["COLOR_0"] = json!(accessor);
        }
    });
    // Materials the wavefront shades lane by lane beside ones it shades on vectors: a rough
    // glass tall block (a refractive, absorbing volume); layered ones, a short
    // block under a clear coat and sheen and white walls with a thin film and anisotropy; and
    // thin-walled walls, a glossy green one under a clear coat that passes half its light
    // through and a red one that diffuses some through.
    let glass_and_layers = edited_scene("cornell-box", "glass-and-layers", |json| {
        let materials = json["materials"].as_array_mut().unwrap();
        materials.push(json!({
            "name": "glass",
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.25},
            "extensions": {
                "KHR_materials_transmission": {"transmissionFactor": 1.0},
                "KHR_materials_volume": {"thicknessFactor": 0.3, "attenuationDistance": 0.5, "attenuationColor": [0.9, 0.7, 0.5]}
            }
        }));
        materials.push(json!({
            "name": "lacquer",
            "pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.3, 0.2, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.6},
            "extensions": {
                "KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatRoughnessFactor": 0.1},
                "KHR_materials_sheen": {"sheenColorFactor": [0.5, 0.5, 0.9], "sheenRoughnessFactor": 0.4}
            }
        }));
        materials.push(json!({
            "name": "film",
            "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.9, 0.8, 1.0], "metallicFactor": 0.5, "roughnessFactor": 0.35},
            "extensions": {
                "KHR_materials_iridescence": {"iridescenceFactor": 1.0, "iridescenceThicknessMaximum": 450.0},
                "KHR_materials_anisotropy": {"anisotropyStrength": 0.6, "anisotropyRotation": 0.5}
            }
        }));
        json["materials"][1]["extensions"]["KHR_materials_transmission"] =
            json!({"transmissionFactor": 0.5});
        json["materials"][1]["pbrMetallicRoughness"]["roughnessFactor"] = json!(0.4);
        json["materials"][1]["extensions"]["KHR_materials_specular"] = json!({});
        json["materials"][1]["extensions"]["KHR_materials_clearcoat"] =
            json!({"clearcoatFactor": 0.7, "clearcoatRoughnessFactor": 0.2});
        json["materials"][2]["extensions"]["KHR_materials_diffuse_transmission"] = json!({
            "diffuseTransmissionFactor": 0.4,
            "diffuseTransmissionColorFactor": [0.9, 0.5, 0.3]
        });
        json["meshes"][4]["primitives"][0]["material"] = json!(4);
        json["meshes"][3]["primitives"][0]["material"] = json!(5);
        json["meshes"][0]["primitives"][0]["material"] = json!(6);
        // Lights in different places, so that the light tree's choice depends on the shading
        // normal (the refracting frame's is not the one the choice sees).
        add_punctual_lights(json);
        for ext in [
            "KHR_materials_transmission",
            "KHR_materials_volume",
            "KHR_materials_clearcoat",
            "KHR_materials_sheen",
            "KHR_materials_iridescence",
            "KHR_materials_anisotropy",
            "KHR_materials_diffuse_transmission",
        ] {
            json["extensionsUsed"].as_array_mut().unwrap().push(json!(ext));
        }
    });
    // A smooth, clear glass tall block under the punctual lights: all its lobes are deltas.
    let smooth_glass = edited_scene("cornell-box", "smooth-glass", |json| {
        json["materials"].as_array_mut().unwrap().push(json!({
            "name": "clear glass",
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.0},
            "extensions": {
                "KHR_materials_transmission": {"transmissionFactor": 1.0},
                "KHR_materials_volume": {"thicknessFactor": 0.3}
            }
        }));
        json["meshes"][4]["primitives"][0]["material"] = json!(4);
        for ext in ["KHR_materials_transmission", "KHR_materials_volume"] {
            json["extensionsUsed"].as_array_mut().unwrap().push(json!(ext));
        }
        add_punctual_lights(json);
    });
    // An unlit short block (`KHR_materials_unlit`: its base colour, and no path goes on).
    let unlit = edited_scene("cornell-box", "unlit", |json| {
        json["materials"].as_array_mut().unwrap().push(json!({
            "name": "flat",
            "pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.4, 0.1, 1.0]},
            "extensions": {"KHR_materials_unlit": {}}
        }));
        json["meshes"][3]["primitives"][0]["material"] = json!(4);
        json["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_materials_unlit"));
    });
    // Cut-outs: the short block and the light half there (alpha blending, stochastic), so
    // rays pass through them at random and the light's samples are weighed by its coverage.
    let cut_outs = edited_scene("cornell-box", "cut-outs", |json| {
        let materials = json["materials"].as_array_mut().unwrap();
        let mut see_through = materials[0].clone();
        see_through["name"] = json!("see-through");
        see_through["alphaMode"] = json!("BLEND");
        see_through["pbrMetallicRoughness"]["baseColorFactor"] = json!([0.2, 0.6, 0.9, 0.5]);
        materials.push(see_through);
        json["materials"][3]["alphaMode"] = json!("BLEND");
        json["materials"][3]["pbrMetallicRoughness"]["baseColorFactor"] =
            json!([0.0, 0.0, 0.0, 0.6]);
        json["meshes"][3]["primitives"][0]["material"] = json!(4);
    });
    let scenes = [
        ("cornell-box", load("cornell-box.gltf")),
        ("cut-outs", common::gltf::load_path(&cut_outs).expect("edited scene")),
        ("glass and layers", common::gltf::load_path(&glass_and_layers).expect("edited scene")),
        ("smooth glass", common::gltf::load_path(&smooth_glass).expect("edited scene")),
        ("unlit", common::gltf::load_path(&unlit).expect("edited scene")),
        ("vertex colours", common::gltf::load_path(&coloured).expect("edited scene")),
        ("glossy walls", common::gltf::load_path(&glossy).expect("edited scene")),
        ("veach-mis", load("veach-mis.gltf")),
        ("damaged-helmet", real("DamagedHelmet/glTF-Binary/DamagedHelmet.glb")),
        ("box-textured", real("BoxTextured/glTF/BoxTextured.gltf")),
        ("vertex colour test", real("VertexColorTest/glTF-Binary/VertexColorTest.glb")),
        ("two-sided light", common::gltf::load_path(&two_sided).expect("edited scene")),
        ("punctual lights", common::gltf::load_path(&punctual).expect("edited scene")),
        ("furnace", load("furnace.gltf")),
        ("furnace-closed", load("furnace-closed.gltf")),
    ];
    let variants = [
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 3}"#,
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 5, "max_depth": 1}"#,
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 7, "max_depth": 3}"#,
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 9,
            "lens": {"aperture_radius": 0.03, "focus_distance": 1.15}}"#,
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 13,
            "environment": {"color": [0.3, 0.4, 0.5]}}"#,
        r#"{"width": 48, "height": 40, "spp": 6, "seed": 15, "max_depth": 2,
            "environment": {"color": [0.3, 0.4, 0.5]}}"#,
    ];
    eprintln!("wavefront lanes on this CPU: {}", wavefront::lanes());
    // Vertex normals bent away from the faces (some past the horizon, some flipped, some zero,
    // which falls back to the face normal), set on both preparations alike.
    let bend = |p: &mut PreparedScene| {
        let count = p.shading.iter().flat_map(|t| t.vertices).max().map_or(0, |v| v + 1);
        p.normals = (0..count)
            .map(|v| {
                let k = v as f32;
                match v % 7 {
                    0 => Vec3::ZERO,
                    1 => Vec3::new(0.3, -1.0, 0.2),
                    _ => Vec3::new((k * 0.77).sin(), (k * 1.31).cos(), (k * 0.53).sin() + 0.2),
                }
            })
            .collect();
        for t in &mut p.shading {
            t.smooth = true;
        }
    };
    let cases = scenes.iter().flat_map(|s| [(s, false), (s, true)]);
    let cases = cases.flat_map(|c| [(c, LightChoice::Mixture), (c, LightChoice::Tree)]);
    for (((name, scene), smooth), choice) in cases {
        for json in variants {
            let settings = RenderSettings::from_json(json).unwrap();
            let mut wavefront =
                prepare_with_light_choice(scene, &settings, choice).expect("prepare");
            let mut scalar = prepare_with_light_choice(scene, &settings, choice).expect("prepare");
            assert_eq!(wavefront.lights.uses_tree(), choice == LightChoice::Tree);
            if smooth {
                bend(&mut wavefront);
                bend(&mut scalar);
            }
            assert!(wavefront.wavefront().is_some(), "{name}: the wavefront applies");
            assert_eq!(wavefront.alpha_tested, *name == "cut-outs", "{name}");
            if *name == "punctual lights" {
                let punctual = wavefront
                    .lights
                    .lights
                    .iter()
                    .filter(|l| !matches!(l, Light::Triangle(_) | Light::Environment(_)));
                assert_eq!(punctual.count(), 3, "point, spot and directional lights");
            }
            assert_eq!(wavefront.environment.is_some(), json.contains("environment"));
            scalar.drop_wavefront();
            let name =
                format!("{name}{}, {choice:?}", if smooth { ", vertex normals" } else { "" });
            for (rect, samples) in [
                (Rect { x0: 0, y0: 0, width: 48, height: 40 }, SampleRange { start: 0, end: 6 }),
                (Rect { x0: 13, y0: 7, width: 21, height: 17 }, SampleRange { start: 5, end: 11 }),
            ] {
                let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
                assert_same_sums(
                    &format!("{name} {json}"),
                    &wavefront,
                    &scalar,
                    &task,
                    &[4, 8, 16],
                );
            }
        }
    }
}

/// Adds a point, a spot and a directional light to the Cornell box's glTF document.
fn add_punctual_lights(json: &mut serde_json::Value) {
    let lights = json!([
        {"type": "point", "intensity": 0.8, "color": [1.0, 0.9, 0.8]},
        {"type": "spot", "intensity": 3.0, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.6}},
        {"type": "directional", "intensity": 2.0, "color": [0.6, 0.7, 1.0]}
    ]);
    json["extensionsUsed"].as_array_mut().unwrap().push(json!("KHR_lights_punctual"));
    json["extensions"] = json!({"KHR_lights_punctual": {"lights": lights}});
    let nodes = json["nodes"].as_array_mut().unwrap();
    let first = nodes.len();
    for (k, t) in [[0.2, 0.3, 0.1], [-0.3, 0.6, 0.2], [0.0, 0.0, 3.0]].iter().enumerate() {
        nodes.push(json!({"translation": t, "extensions": {"KHR_lights_punctual": {"light": k}}}));
    }
    let roots = json["scenes"][0]["nodes"].as_array_mut().unwrap();
    roots.extend((first..first + 3).map(|n| json!(n)));
}

/// Every shipped scene (`scenes/`, `scenes/materials/`) and every real asset in `tests/assets`
/// under the studio HDR map: the wavefront's sums and ray counts are the scalar path tracer's,
/// bit for bit, at the CPU's lane count and at 8 and 16 lanes emulated. The wavefront applies
/// to all of them but the scenes that scatter light inside volumes (whose paths the renderer
/// keeps scalar as a whole: the list is checked, so that no scene drops off the wavefront
/// unnoticed).
#[test]
fn wavefront_renders_every_shipped_scene_and_real_asset_under_a_map_bit_for_bit() {
    let map =
        common::envmap::EnvMap::load(&assets().join("real/environments/studio_small_05_1k.hdr"))
            .expect("the studio map");
    let mut files = Vec::new();
    for dir in [scenes(), scenes().join("materials")] {
        for f in std::fs::read_dir(&dir).unwrap() {
            let path = f.unwrap().path();
            if path.extension().is_some_and(|e| e == "gltf") {
                files.push(path);
            }
        }
    }
    for asset in std::fs::read_dir(assets().join("real")).unwrap() {
        let asset = asset.unwrap().path();
        for variant in ["glTF", "glTF-Binary"] {
            let Ok(found) = std::fs::read_dir(asset.join(variant)) else { continue };
            for f in found {
                let path = f.unwrap().path();
                if path.extension().is_some_and(|e| e == "gltf" || e == "glb") {
                    files.push(path);
                }
            }
        }
    }
    files.sort();
    let settings = RenderSettings::from_json(
        r#"{"width": 24, "height": 16, "spp": 4, "seed": 21, "max_depth": 4,
            "environment": {"map": "studio", "intensity": 0.8, "rotation_deg": 40}}"#,
    )
    .unwrap();
    let mut scalar_only = Vec::new();
    for path in &files {
        let name = path.strip_prefix(scenes().parent().unwrap()).unwrap_or(path).display();
        let scene = common::gltf::load_path(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let prepare = || {
            worker::render::scene::prepare_with_environment(&scene, &settings, Some(&map))
                .unwrap_or_else(|e| panic!("{name}: {e}"))
        };
        let (wavefront, mut scalar) = (prepare(), prepare());
        if wavefront.wavefront().is_none() {
            scalar_only.push(path.file_name().unwrap().to_string_lossy().into_owned());
            continue;
        }
        scalar.drop_wavefront();
        let rect = Rect { x0: 0, y0: 0, width: 24, height: 16 };
        let samples = SampleRange { start: 0, end: 4 };
        let task = TaskSpec { frame: 0, rect, samples, kind: TaskKind::Camera };
        assert_same_sums(&name.to_string(), &wavefront, &scalar, &task, &[8, 16]);
    }
    assert!(files.len() >= 30, "only {} scenes found", files.len());
    assert_eq!(scalar_only, ["subsurface-matched.gltf", "subsurface.gltf"], "scenes kept scalar");
}
