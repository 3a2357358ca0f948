//! MikkTSpace tangents: their direction and handedness on hand-made quads, vertices split at a
//! mirrored seam and nowhere else, a deforming mesh split consistently, which meshes get them,
//! and agreement with the tangents a real asset's exporter baked.

use glam::{Vec2, Vec3, Vec4};
use serde_json::{json, Value};

use super::*;
use super::{tangents::mikktspace, tests_deform::Bin};

/// One texel (255, 128, 255): a normal map for materials that need one.
const TEXEL_PNG: &str =
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAIAAACQd1PeAAAADElEQVR4nGP43/AfAAUAAn8gmLxdAAAAAElFTkSuQmCC";

/// The quad (-1,-1)-(1,1) at z = 0 facing +z, as two triangles.
const QUAD: [Vec3; 4] = [
    Vec3::new(-1.0, -1.0, 0.0),
    Vec3::new(1.0, -1.0, 0.0),
    Vec3::new(1.0, 1.0, 0.0),
    Vec3::new(-1.0, 1.0, 0.0),
];
const QUAD_TRIANGLES: [[u32; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
/// glTF's texture coordinates for the quad: u along +x, v down the image (along -y).
const QUAD_UVS: [Vec2; 4] =
    [Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 0.0)];

/// The tangent points along +u, and the bitangent, cross(normal, tangent) x w as glTF defines
/// it, along -v (up the image): mirroring u turns the tangent and flips w, mirroring v flips w
/// alone.
#[test]
fn the_tangent_runs_along_u_and_w_follows_the_mirroring() {
    let normals = [Vec3::Z; 4];
    let mirror_u = QUAD_UVS.map(|uv| Vec2::new(1.0 - uv.x, uv.y));
    let mirror_v = QUAD_UVS.map(|uv| Vec2::new(uv.x, 1.0 - uv.y));
    for (uvs, expected) in [
        (QUAD_UVS, Vec4::new(1.0, 0.0, 0.0, 1.0)),
        (mirror_u, Vec4::new(-1.0, 0.0, 0.0, -1.0)),
        (mirror_v, Vec4::new(1.0, 0.0, 0.0, -1.0)),
    ] {
        let split = mikktspace(&QUAD, &normals, &uvs, &QUAD_TRIANGLES).expect("tangents");
        assert_eq!(split.source, [0, 1, 2, 3], "one tangent per vertex: nothing split");
        assert_eq!(split.indices, QUAD_TRIANGLES);
        for t in &split.tangents {
            assert!((*t - expected).abs().max_element() < 1e-6, "{uvs:?}: {t} for {expected}");
            // The bitangent points where v decreases, whatever the mirroring.
            let bitangent = Vec3::Z.cross(t.truncate()) * t.w;
            let dv = uvs[3] - uvs[0]; // The texture coordinates' change along +y.
            assert_eq!(bitangent.y.signum(), -dv.y.signum(), "{uvs:?}");
        }
    }
}

/// Two quads side by side over 6 vertices, the right one's texture mirrored in u (as on a
/// symmetric model that maps both halves onto one half of the image): the two vertices on the
/// seam get a tangent for each side and are split; the same strip mapped without the mirror
/// splits nothing.
#[test]
fn a_mirrored_seam_splits_its_vertices_and_nothing_else_does() {
    let positions: Vec<Vec3> = [-1.0, 0.0, 1.0]
        .iter()
        .flat_map(|&x| [Vec3::new(x, 0.0, 0.0), Vec3::new(x, 1.0, 0.0)])
        .collect();
    let triangles = [[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3]];
    let normals = vec![Vec3::Z; 6];
    let mirrored: Vec<Vec2> =
        [0.0, 1.0, 0.0].iter().flat_map(|&u| [Vec2::new(u, 1.0), Vec2::new(u, 0.0)]).collect();
    let split = mikktspace(&positions, &normals, &mirrored, &triangles).expect("tangents");
    assert_eq!(split.source, [0, 1, 2, 3, 4, 5, 2, 3], "the seam's two vertices are copied");
    assert_eq!(split.indices, [[0, 2, 3], [0, 3, 1], [6, 4, 5], [6, 5, 7]]);
    let expected = |x: f32| {
        if x < 0.5 {
            Vec4::new(1.0, 0.0, 0.0, 1.0)
        } else {
            -Vec4::new(1.0, 0.0, 0.0, 1.0)
        }
    };
    for (v, t) in split.tangents.iter().enumerate() {
        let side = if v < 4 { 0.0 } else { 1.0 };
        assert!((*t - expected(side)).abs().max_element() < 1e-6, "vertex {v}: {t}");
    }

    let continuous: Vec<Vec2> =
        [0.0, 1.0, 2.0].iter().flat_map(|&u| [Vec2::new(u, 1.0), Vec2::new(u, 0.0)]).collect();
    let split = mikktspace(&positions, &normals, &continuous, &triangles).expect("tangents");
    assert_eq!(split.source, [0, 1, 2, 3, 4, 5], "corners that agree share their vertex");
    assert_eq!(split.indices, triangles);
    assert!(split
        .tangents
        .iter()
        .all(|t| (*t - Vec4::new(1.0, 0.0, 0.0, 1.0)).abs().max_element() < 1e-6));
}

/// Degenerate texture coordinates (a triangle mapped to one point, another to a line) and a
/// triangle whose corners are one vertex give finite unit tangents, never NaN.
#[test]
fn degenerate_triangles_get_finite_tangents() {
    let positions = [QUAD[0], QUAD[1], QUAD[2], QUAD[3], Vec3::new(3.0, 0.0, 0.0)];
    let normals = [Vec3::Z; 5];
    let uvs = [Vec2::ZERO, Vec2::ZERO, Vec2::ZERO, Vec2::new(1.0, 1.0), Vec2::new(2.0, 2.0)];
    let triangles = [[0, 1, 2], [0, 3, 4], [4, 4, 4]];
    let split = mikktspace(&positions, &normals, &uvs, &triangles).expect("tangents");
    for t in &split.tangents {
        assert!(t.is_finite() && (t.truncate().length() - 1.0).abs() < 1e-6, "{t}");
        assert!(t.w == 1.0 || t.w == -1.0, "{t}");
    }
}

/// The mirrored strip of [`a_mirrored_seam_splits_its_vertices_and_nothing_else_does`] as a
/// glTF primitive with NORMAL and TEXCOORD_0 (and more, by `edit`, on the buffer and the
/// primitive), material 0 normal-mapped by a one-texel image.
fn mirrored_strip(edit: impl FnOnce(&mut Bin, &mut Value)) -> Value {
    let mut bin = Bin::default();
    let positions: Vec<f32> =
        [-1.0f32, 0.0, 1.0].iter().flat_map(|&x| [x, 0.0, 0.0, x, 1.0, 0.0]).collect();
    let uvs: Vec<f32> = [0.0f32, 1.0, 0.0].iter().flat_map(|&u| [u, 1.0, u, 0.0]).collect();
    let position = bin.floats(&positions, 6, "VEC3");
    let normal = bin.floats(&[0.0, 0.0, 1.0].repeat(6), 6, "VEC3");
    let uv = bin.floats(&uvs, 6, "VEC2");
    let indices: Vec<u8> =
        [0u16, 2, 3, 0, 3, 1, 2, 4, 5, 2, 5, 3].iter().flat_map(|i| i.to_le_bytes()).collect();
    let indices = bin.accessor(&indices, 5123, 12, "SCALAR", json!({}));
    let mut primitive = json!({
        "attributes": {"POSITION": position, "NORMAL": normal, "TEXCOORD_0": uv},
        "indices": indices,
        "material": 0
    });
    let mut doc = json!({
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "materials": [{"normalTexture": {"index": 0}}],
        "textures": [{"source": 0}],
        "images": [{"uri": format!("data:image/png;base64,{TEXEL_PNG}")}]
    });
    edit(&mut bin, &mut primitive);
    doc["meshes"] = json!([{"primitives": [primitive]}]);
    bin.finish(doc)
}

fn load(doc: &Value) -> Scene {
    load_slice(doc.to_string().as_bytes(), &NoFiles).expect("loads")
}

/// A normal-mapped mesh without TANGENT gets tangents, split at its seam; one whose material
/// needs no tangents, one without normals and one with its own TANGENT are left as they are.
#[test]
fn the_loader_generates_tangents_only_where_a_material_needs_them() {
    let scene = load(&mirrored_strip(|_, _| {}));
    let mesh = &scene.meshes[0];
    assert_eq!(mesh.positions.len(), 8);
    assert_eq!(mesh.tangents.as_ref().map(Vec::len), Some(8));
    assert_eq!(mesh.uvs[0].as_ref().map(Vec::len), Some(8));
    assert_eq!(mesh.normals.as_ref().map(Vec::len), Some(8));
    assert_eq!(mesh.positions[6..], mesh.positions[2..4], "the seam's vertices copied");

    // Without the normal map: no tangents, no split.
    let mut plain = mirrored_strip(|_, _| {});
    plain["materials"] = json!([{}]);
    let mesh = &load(&plain).meshes[0];
    assert_eq!((mesh.positions.len(), mesh.tangents.is_some()), (6, false));

    // A KHR_materials_variants material with a normal map asks for them too.
    let mut variant = plain.clone();
    variant["materials"] = json!([{}, {"normalTexture": {"index": 0}}]);
    variant["extensions"] = json!({"KHR_materials_variants": {"variants": [{"name": "mapped"}]}});
    variant["meshes"][0]["primitives"][0]["extensions"] = json!({"KHR_materials_variants": {
        "mappings": [{"material": 1, "variants": [0]}]
    }});
    assert_eq!(load(&variant).meshes[0].tangents.as_ref().map(Vec::len), Some(8));

    // Without normals (flat shading), as before: the renderer orients the map per triangle.
    let mut flat = mirrored_strip(|_, _| {});
    flat["meshes"][0]["primitives"][0]["attributes"].as_object_mut().unwrap().remove("NORMAL");
    let mesh = &load(&flat).meshes[0];
    assert_eq!((mesh.positions.len(), mesh.tangents.is_some()), (6, false));

    // The map reads TEXCOORD_1, which the mesh lacks: nothing to orient by.
    let mut other_set = mirrored_strip(|_, _| {});
    other_set["materials"][0]["normalTexture"]["texCoord"] = json!(1);
    assert!(load(&other_set).meshes[0].tangents.is_none());

    // The file's own tangents are kept, as written.
    let given = mirrored_strip(|bin, primitive| {
        let t = bin.floats(&[0.0, 1.0, 0.0, -1.0].repeat(6), 6, "VEC4");
        primitive["attributes"]["TANGENT"] = json!(t);
    });
    let mesh = &load(&given).meshes[0];
    assert_eq!(mesh.positions.len(), 6);
    assert_eq!(mesh.tangents.as_deref(), Some(&[Vec4::new(0.0, 1.0, 0.0, -1.0); 6][..]));
}

/// A skinned mesh with a morph target is split with all it carries per vertex: every copy has
/// its original's rest position, texture coordinates, joints, weights and displacements, and is
/// posed where its original is.
#[test]
fn a_deforming_mesh_is_split_with_its_skin_and_morph_targets() {
    let build = |mapped: bool| {
        let mut doc = mirrored_strip(|bin, primitive| {
            let joints: Vec<u8> = (0..6u8).flat_map(|v| [v % 2, 1 - v % 2, 0, 0]).collect();
            let weights: Vec<f32> = (0..6)
                .flat_map(|v| [0.3 + 0.1 * v as f32, 0.7 - 0.1 * v as f32, 0.0, 0.0])
                .collect();
            let deltas: Vec<f32> = (0..18).map(|k| 0.01 * k as f32).collect();
            primitive["attributes"]["JOINTS_0"] =
                json!(bin.accessor(&joints, 5121, 6, "VEC4", json!({})));
            primitive["attributes"]["WEIGHTS_0"] = json!(bin.floats(&weights, 6, "VEC4"));
            primitive["targets"] = json!([{"POSITION": bin.floats(&deltas, 6, "VEC3")}]);
        });
        doc["nodes"] = json!([
            {"mesh": 0, "skin": 0},
            {"translation": [0.0, 2.0, 0.0], "children": [2]},
            {"translation": [1.0, 0.0, 0.0], "rotation": [0.0, 0.0, 0.38268343, 0.92387953]}
        ]);
        doc["scenes"] = json!([{"nodes": [0, 1]}]);
        doc["skins"] = json!([{"joints": [1, 2]}]);
        doc["meshes"][0]["weights"] = json!([0.5]);
        if !mapped {
            doc["materials"] = json!([{}]);
        }
        load(&doc)
    };
    let (mapped, plain) = (build(true), build(false));
    let (m, p) = (&mapped.meshes[0], &plain.meshes[0]);
    let (md, pd) = (m.deform.as_ref().unwrap(), p.deform.as_ref().unwrap());
    assert_eq!((m.positions.len(), p.positions.len()), (8, 6));
    assert_eq!(md.rest_tangents.as_ref().map(Vec::len), Some(8));
    assert!(m.tangents.as_ref().unwrap().iter().all(|t| t.is_finite() && t.w.abs() == 1.0));
    let (ms, ps) = (md.skin.as_ref().unwrap(), pd.skin.as_ref().unwrap());
    for v in 0..8 {
        // The original: the plain mesh's vertex at the same rest position (all differ).
        let o = pd.rest_positions.iter().position(|&r| r == md.rest_positions[v]).unwrap();
        assert!(v >= 6 || v == o, "the unsplit vertices keep their index");
        assert_eq!(m.uvs[0].as_ref().unwrap()[v], p.uvs[0].as_ref().unwrap()[o]);
        assert_eq!(m.normals.as_ref().unwrap()[v], p.normals.as_ref().unwrap()[o]);
        assert_eq!(ms.vertex_joints[v * 4..][..4], ps.vertex_joints[o * 4..][..4]);
        assert_eq!(ms.vertex_weights[v * 4..][..4], ps.vertex_weights[o * 4..][..4]);
        let delta =
            |d: &crate::scene::Deform, i: usize| d.targets[0].positions.as_ref().unwrap()[i];
        assert_eq!(delta(md, v), delta(pd, o));
        assert_eq!(m.positions[v], p.positions[o], "posed alike");
    }
    assert_eq!(m.indices.len(), p.indices.len());
}

/// LightsPunctualLamp's geometry (`tests/assets/tangents/`, its images left out) with its TANGENT
/// accessors or without, the images replaced by one texel each.
fn lamp(with_tangents: bool) -> Scene {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/assets/tangents/LightsPunctualLamp/glTF");
    let text = std::fs::read(dir.join("LightsPunctualLamp.gltf")).expect("the lamp");
    let mut doc: Value = serde_json::from_slice(&text).expect("JSON");
    for image in doc["images"].as_array_mut().expect("images") {
        *image = json!({"uri": format!("data:image/png;base64,{TEXEL_PNG}")});
    }
    for mesh in doc["meshes"].as_array_mut().expect("meshes") {
        for primitive in mesh["primitives"].as_array_mut().expect("primitives") {
            if !with_tangents {
                primitive["attributes"].as_object_mut().expect("attributes").remove("TANGENT");
            }
        }
    }
    load_slice(doc.to_string().as_bytes(), &DirResolver::new(dir)).expect("the lamp loads")
}

/// Tangents made for LightsPunctualLamp, whose three normal-mapped meshes (18,000 corners) come
/// with the tangents its tools baked (Blender, then RapidCompact), agree with those: w on every
/// corner, and the direction within 0.1 degree on 99% of them. Measured: w equal everywhere,
/// half the corners within 0.0001 degree and 99% within 0.035 (float rounding), 17,923 within
/// 0.1; 76 corners (0.4%) differ by 1 to 81 degrees, where the tools split or welded vertices
/// otherwise than the file has them. With the sign of texture space with v running up (w
/// negated) no corner would match.
#[test]
fn generated_tangents_match_the_ones_a_real_asset_baked() {
    let (baked, made) = (lamp(true), lamp(false));
    assert_eq!(baked.meshes.len(), 3);
    let (mut corners, mut close) = (0usize, 0usize);
    for (b, m) in baked.meshes.iter().zip(&made.meshes) {
        let (bt, mt) = (b.tangents.as_ref().expect("baked"), m.tangents.as_ref().expect("made"));
        assert!(m.positions.len() >= b.positions.len(), "{}: vertices are only ever added", m.name);
        assert!(m.positions.len() <= b.positions.len() + 3 * b.indices.len());
        for (tb, tm) in b.indices.iter().zip(&m.indices) {
            for (&vb, &vm) in tb.iter().zip(tm) {
                let (tb, tm) = (bt[vb as usize], mt[vm as usize]);
                assert_eq!(b.positions[vb as usize], m.positions[vm as usize], "{}", m.name);
                assert_eq!(tb.w, tm.w, "{}: handedness", m.name);
                let angle = tb.truncate().dot(tm.truncate()).clamp(-1.0, 1.0).acos();
                corners += 1;
                close += usize::from(angle.to_degrees() <= 0.1);
            }
        }
    }
    assert_eq!(corners, 18_000, "the lamp's corners");
    assert!(close as f64 >= 0.99 * corners as f64, "{close} of {corners} within 0.1 degree");
}
