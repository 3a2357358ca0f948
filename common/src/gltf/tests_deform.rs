//! Skins and morph targets: posed vertices checked against hand-computed values, at rest and
//! after `Scene::set_time`; animated weights (LINEAR, STEP, CUBICSPLINE); bad input named; scenes
//! without deformation unchanged.

use base64::Engine as _;
use glam::{DMat4, DVec3, Vec3};
use serde_json::{json, Value};

use super::*;

/// Buffer 0 built piece by piece, each piece a buffer view (4-byte aligned) with its accessor
/// (the tangent tests build their documents with it too).
#[derive(Default)]
pub(super) struct Bin {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Bin {
    fn view(&mut self, data: &[u8]) -> usize {
        self.bytes.resize(self.bytes.len().div_ceil(4) * 4, 0);
        self.views
            .push(json!({"buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len()}));
        self.bytes.extend_from_slice(data);
        self.views.len() - 1
    }

    /// An accessor over a new view of `data`; `extra` is merged into it.
    pub(super) fn accessor(
        &mut self,
        data: &[u8],
        component: u32,
        count: usize,
        ty: &str,
        extra: Value,
    ) -> usize {
        let view = self.view(data);
        let mut acc =
            json!({"bufferView": view, "componentType": component, "count": count, "type": ty});
        if let Value::Object(extra) = extra {
            acc.as_object_mut().unwrap().extend(extra);
        }
        self.accessors.push(acc);
        self.accessors.len() - 1
    }

    pub(super) fn floats(&mut self, v: &[f32], count: usize, ty: &str) -> usize {
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        self.accessor(&bytes, 5126, count, ty, json!({}))
    }

    pub(super) fn finish(self, mut doc: Value) -> Value {
        let uri = format!(
            "data:application/octet-stream;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(&self.bytes)
        );
        doc["asset"] = json!({"version": "2.0"});
        doc["accessors"] = Value::Array(self.accessors);
        doc["bufferViews"] = Value::Array(self.views);
        doc["buffers"] = json!([{"byteLength": self.bytes.len(), "uri": uri}]);
        doc
    }
}

fn load(doc: &Value) -> Result<Scene, SceneError> {
    load_slice(doc.to_string().as_bytes(), &NoFiles)
}

fn load_err(doc: &Value) -> String {
    match load(doc) {
        Ok(_) => panic!("malformed document loaded"),
        Err(e) => e.0,
    }
}

fn assert_names(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error {msg:?} does not contain {p:?}");
    }
}

/// Vertex `v` of instance `i` in the world.
fn world(scene: &Scene, i: usize, v: usize) -> DVec3 {
    let inst = &scene.instances[i];
    inst.transform.transform_point3(scene.meshes[inst.mesh].positions[v].as_dvec3())
}

fn assert_at(scene: &Scene, i: usize, expected: &[[f64; 3]]) {
    for (v, e) in expected.iter().enumerate() {
        let p = world(scene, i, v);
        assert!((p - DVec3::from_array(*e)).length() < 1e-5, "vertex {v}: {p} vs {e:?}");
    }
}

/// The unit quad (0,0)-(1,1) at z = 0, skinned to two joints: node 1 (hip, at (0, 2, 0)) and its
/// child node 2 (knee, one unit along x, turned 90 degrees about z at rest). Vertices 0 and 3
/// follow the hip, vertex 1 the knee, vertex 2 both half and half. The skinned node 0 has its
/// own transform (translation 100, scale 3), which glTF says must be ignored. Accessors: 0
/// POSITION, 1 indices, 2 JOINTS_0 (unsigned byte), 3 WEIGHTS_0, 4 inverseBindMatrices, 5 NORMAL.
fn skinned_quad(joints: [[u8; 4]; 4], weights: [[f32; 4]; 4], animated: bool) -> Value {
    let (bin, doc) = skinned_quad_parts(joints, weights, animated);
    bin.finish(doc)
}

/// [`skinned_quad`] before its buffer is closed, for tests that add accessors.
fn skinned_quad_parts(
    joints: [[u8; 4]; 4],
    weights: [[f32; 4]; 4],
    animated: bool,
) -> (Bin, Value) {
    let mut bin = Bin::default();
    bin.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0], 4, "VEC3");
    let indices: Vec<u8> = [0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()).collect();
    bin.accessor(&indices, 5123, 6, "SCALAR", json!({}));
    bin.accessor(joints.as_flattened(), 5121, 4, "VEC4", json!({}));
    bin.floats(weights.as_flattened(), 4, "VEC4");
    // The knee's bind pose is one unit along x: its inverse bind moves back by -1.
    let mut ib = DMat4::IDENTITY.to_cols_array().to_vec();
    ib.extend(DMat4::from_translation(DVec3::NEG_X).to_cols_array());
    bin.floats(&ib.iter().map(|&v| v as f32).collect::<Vec<_>>(), 2, "MAT4");
    bin.floats(&[0.0, 0.0, 1.0].repeat(4), 4, "VEC3");
    let mut doc = json!({
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"mesh": 0, "skin": 0, "translation": [100.0, 0.0, 0.0], "scale": [3.0, 3.0, 3.0]},
            {"name": "hip", "translation": [0.0, 2.0, 0.0], "children": [2]},
            {"name": "knee", "translation": [1.0, 0.0, 0.0],
             "rotation": [0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::FRAC_1_SQRT_2]}
        ],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": 4}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3, "NORMAL": 5},
            "indices": 1
        }]}]
    });
    if animated {
        // The hip rises from y = 2 to 4 and the knee turns back from 90 degrees to 0 over
        // one second.
        let times = bin.floats(&[0.0, 1.0], 2, "SCALAR");
        let hip = bin.floats(&[0.0, 2.0, 0.0, 0.0, 4.0, 0.0], 2, "VEC3");
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let knee = bin.floats(&[0.0, 0.0, s, s, 0.0, 0.0, 0.0, 1.0], 2, "VEC4");
        doc["animations"] = json!([{
            "channels": [
                {"sampler": 0, "target": {"node": 1, "path": "translation"}},
                {"sampler": 1, "target": {"node": 2, "path": "rotation"}}
            ],
            "samplers": [{"input": times, "output": hip}, {"input": times, "output": knee}]
        }]);
    }
    (bin, doc)
}

const HIP: [u8; 4] = [0, 0, 0, 0];
const KNEE: [u8; 4] = [1, 0, 0, 0];
const BOTH: [u8; 4] = [0, 1, 0, 0];
const ONE: [f32; 4] = [1.0, 0.0, 0.0, 0.0];
const HALF: [f32; 4] = [0.5, 0.5, 0.0, 0.0];

fn quad(animated: bool) -> Value {
    skinned_quad([HIP, KNEE, BOTH, HIP], [ONE, ONE, HALF, ONE], animated)
}

#[test]
fn a_skinned_quad_is_posed_by_its_joints_not_its_node() {
    let scene = load(&quad(false)).expect("loads");
    assert!(scene.meshes[0].skinned());
    let skin = scene.meshes[0].deform.as_ref().unwrap().skin.as_ref().unwrap();
    assert_eq!((skin.joints.clone(), skin.influences, skin.renormalised), (vec![1, 2], 4, 0));
    // The instance carries the skin's origin (the hip's rest position), nothing of node 0.
    assert_eq!(scene.instances[0].transform, DMat4::from_translation(DVec3::new(0.0, 2.0, 0.0)));
    // Hip: + (0, 2, 0). Knee: back by 1 along x, turned 90 degrees ((x, y) -> (-y, x)), then
    // to (1, 2, 0): vertex 1 (1, 0) -> (0, 0) -> (0, 0) -> (1, 2); vertex 2 (1, 1) -> (0, 1) ->
    // (-1, 0) -> (0, 2), half with the hip's (1, 3): (0.5, 2.5).
    assert_at(&scene, 0, &[[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.5, 2.5, 0.0], [0.0, 3.0, 0.0]]);
    // Turning about z leaves the normals along z.
    for n in scene.meshes[0].normals.as_ref().unwrap() {
        assert!((*n - Vec3::Z).length() < 1e-6, "{n}");
    }
    // Static: nothing to pose again.
    assert!(!scene.is_animated());
}

#[test]
fn an_animated_skin_is_posed_again_at_any_time() {
    let mut scene = load(&quad(true)).expect("loads");
    assert!(scene.is_animated());
    // Until set_time, the rest pose.
    assert_at(&scene, 0, &[[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.5, 2.5, 0.0], [0.0, 3.0, 0.0]]);
    // t = 1: the hip at y = 4, the knee straight: everything 4 up.
    scene.set_time(1.0);
    assert_at(&scene, 0, &[[0.0, 4.0, 0.0], [1.0, 4.0, 0.0], [1.0, 5.0, 0.0], [0.0, 5.0, 0.0]]);
    // t = 0.5: the hip at y = 3, the knee at 45 degrees: vertex 2's knee part (0, 1) turns to
    // (-s, s) then moves to (1 - s, 3 + s); half with the hip's (1, 4).
    scene.set_time(0.5);
    let s = std::f64::consts::FRAC_1_SQRT_2;
    assert_at(
        &scene,
        0,
        &[[0.0, 3.0, 0.0], [1.0, 3.0, 0.0], [1.0 - s / 2.0, 3.5 + s / 2.0, 0.0], [0.0, 4.0, 0.0]],
    );
    // The skinned node's transform is still ignored, and the instance did not move.
    assert_eq!(scene.instances[0].transform, DMat4::from_translation(DVec3::new(0.0, 2.0, 0.0)));
}

#[test]
fn skin_weights_are_normalised_and_bad_skins_named() {
    // Weights summing to 2 on vertex 1 are normalised (counted once for the mesh).
    let scene =
        load(&skinned_quad([HIP, KNEE, BOTH, HIP], [ONE, [2.0, 0.0, 0.0, 0.0], HALF, ONE], false))
            .expect("loads");
    assert_eq!(scene.meshes[0].deform.as_ref().unwrap().skin.as_ref().unwrap().renormalised, 1);
    assert_at(&scene, 0, &[[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.5, 2.5, 0.0], [0.0, 3.0, 0.0]]);
    // A joint index beyond the skin's two joints, with a weight.
    let e = load_err(&skinned_quad([HIP, [5, 0, 0, 0], BOTH, HIP], [ONE, ONE, HALF, ONE], false));
    assert_names(
        &e,
        &["node 0", "skin 0", "JOINTS_0 accessor 2", "vertex 1", "joint 5", "2 joints"],
    );
    // The same index with weight 0 binds nothing and loads.
    load(&skinned_quad([HIP, [1, 5, 0, 0], BOTH, HIP], [ONE, ONE, HALF, ONE], false))
        .expect("loads");
    // A negative weight.
    let e = load_err(&skinned_quad(
        [HIP, KNEE, BOTH, HIP],
        [ONE, ONE, [1.5, -0.5, 0.0, 0.0], ONE],
        false,
    ));
    assert_names(&e, &["node 0", "skin 0", "WEIGHTS_0 accessor 3", "vertex 2", "-0.5"]);
    // Joints empty, or naming a node that does not exist.
    let mut doc = quad(false);
    doc["skins"][0]["joints"] = json!([]);
    assert_names(&load_err(&doc), &["node 0", "skin 0", "joints is empty"]);
    let mut doc = quad(false);
    doc["skins"][0]["joints"] = json!([1, 99]);
    assert_names(&load_err(&doc), &["skin 0", "joint 1 is node 99", "the file has 3 nodes"]);
    let mut doc = quad(false);
    doc["nodes"][0]["skin"] = json!(4);
    assert_names(&load_err(&doc), &["node 0", "skin 4", "does not exist"]);
    // Fewer inverse bind matrices than joints.
    let mut doc = quad(false);
    doc["accessors"][4]["count"] = json!(1);
    assert_names(
        &load_err(&doc),
        &["skin 0", "inverseBindMatrices accessor 4 has 1 matrices for 2 joints"],
    );
    // No inverse bind matrices: the identity (the knee's vertex 1 then sits one unit further).
    let mut doc = quad(false);
    doc["skins"][0].as_object_mut().unwrap().remove("inverseBindMatrices");
    let scene = load(&doc).expect("loads");
    assert_eq!(world(&scene, 0, 1), DVec3::new(1.0, 3.0, 0.0));
    // A JOINTS accessor shorter than the vertices, and one of the wrong type.
    let mut doc = quad(false);
    doc["accessors"][2]["count"] = json!(3);
    assert_names(&load_err(&doc), &["JOINTS_0 accessor 2 has 3 elements", "4 vertices"]);
    let mut doc = quad(false);
    doc["accessors"][2]["normalized"] = json!(true);
    assert_names(&load_err(&doc), &["JOINTS_0 accessor 2 must be VEC4 of unsigned byte or short"]);
    // A skinned mesh without JOINTS_0.
    let mut doc = quad(false);
    let attributes = doc["meshes"][0]["primitives"][0]["attributes"].as_object_mut().unwrap();
    attributes.remove("JOINTS_0");
    assert_names(&load_err(&doc), &["node 0", "WEIGHTS_0 without JOINTS_0"]);
    // A skin with GPU instancing.
    let mut doc = quad(false);
    doc["nodes"][0]["extensions"] =
        json!({"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": 0}}});
    assert_names(&load_err(&doc), &["node 0", "skin 0", "EXT_mesh_gpu_instancing"]);
}

#[test]
fn every_joints_and_weights_set_counts_and_quantised_weights_read_as_the_spec_says() {
    // Set 0 as normalised unsigned bytes (vertex 2: 128 / 255 hip, 127 / 255 knee); set 1
    // moves vertex 3's weight to the knee half and half with set 0's hip.
    let (mut bin, mut doc) = skinned_quad_parts([HIP, KNEE, BOTH, HIP], [ONE; 4], false);
    let bytes = [[255u8, 0, 0, 0], [255, 0, 0, 0], [128, 127, 0, 0], [128, 0, 0, 0]];
    let weights0 = bin.accessor(bytes.as_flattened(), 5121, 4, "VEC4", json!({"normalized": true}));
    let joints1 =
        bin.accessor([[0u8; 4], [0; 4], [0; 4], KNEE].as_flattened(), 5121, 4, "VEC4", json!({}));
    let weights1 = bin.floats(
        &[[0.0f32; 4], [0.0; 4], [0.0; 4], [127.0 / 255.0, 0.0, 0.0, 0.0]].concat(),
        4,
        "VEC4",
    );
    let attributes = &mut doc["meshes"][0]["primitives"][0]["attributes"];
    attributes["WEIGHTS_0"] = json!(weights0);
    attributes["JOINTS_1"] = json!(joints1);
    attributes["WEIGHTS_1"] = json!(weights1);
    let scene = load(&bin.finish(doc)).expect("loads");
    let skin = scene.meshes[0].deform.as_ref().unwrap().skin.as_ref().unwrap();
    assert_eq!((skin.influences, skin.renormalised), (8, 0));
    // Vertex 2: 128/255 (1, 3, 0) + 127/255 (0, 2, 0). Vertex 3 (0, 1): the hip's (0, 3, 0)
    // and the knee's ((-1, 1) turned to (-1, -1), plus (1, 2): (0, 1, 0)).
    let (a, b) = (128.0 / 255.0, 127.0 / 255.0);
    assert_at(
        &scene,
        0,
        &[[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [a, 3.0 * a + 2.0 * b, 0.0], [0.0, 3.0 * a + b, 0.0]],
    );
}

/// One triangle with two morph targets: target 0 lifts every vertex by (0, 0, 1); target 1
/// (sparse) moves vertex 0 by (1, 0, 0). Mesh weights [0.5, 0]; node 0 overrides them with
/// [0.25, 1]; node 1 places the same mesh with the mesh's weights. With `channel`, a weights
/// channel animates node 0 with that interpolation over keys at t = 0 and 2.
fn morphing_triangle(channel: Option<&str>) -> Value {
    let mut bin = Bin::default();
    bin.floats(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], 3, "VEC3");
    bin.floats(&[0.0, 0.0, 1.0].repeat(3), 3, "VEC3");
    // Target 1: all zero but for a sparse element 0 = (1, 0, 0).
    let sparse_indices = bin.view(&[0, 0, 0, 0]);
    let sparse_values =
        bin.view(&[1.0f32, 0.0, 0.0].iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>());
    bin.accessors.push(json!({"componentType": 5126, "count": 3, "type": "VEC3", "sparse": {
        "count": 1,
        "indices": {"bufferView": sparse_indices, "componentType": 5125},
        "values": {"bufferView": sparse_values}
    }}));
    let mut doc = json!({
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "weights": [0.25, 1.0]}, {"mesh": 0, "translation": [0.0, 0.0, 10.0]}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0},
            "targets": [{"POSITION": 1}, {"POSITION": 2}]
        }], "weights": [0.5, 0.0]}]
    });
    if let Some(interpolation) = channel {
        let times = bin.floats(&[0.0, 2.0], 2, "SCALAR");
        let values: &[f32] = if interpolation == "CUBICSPLINE" {
            // Per key: in-tangents, values, out-tangents, one per target; all tangents 0.
            &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0]
        } else {
            &[0.0, 0.0, 1.0, 0.5]
        };
        let output = bin.floats(values, values.len(), "SCALAR");
        doc["animations"] = json!([{
            "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
            "samplers": [{"input": times, "output": output, "interpolation": interpolation}]
        }]);
    }
    bin.finish(doc)
}

#[test]
fn node_weights_override_mesh_weights_per_placement() {
    let scene = load(&morphing_triangle(None)).expect("loads");
    // One mesh per deforming placement, each in its node's local space as before.
    assert_eq!(scene.meshes.len(), 2);
    assert_eq!(scene.instances[0].transform, DMat4::IDENTITY);
    assert_eq!(scene.meshes[0].deform.as_ref().unwrap().weights, vec![0.25, 1.0]);
    assert!(!scene.meshes[0].skinned());
    // Node 0: vertex 0 moves by 0.25 (0, 0, 1) + 1 (1, 0, 0).
    assert_at(&scene, 0, &[[1.0, 0.0, 0.25], [1.0, 0.0, 0.25], [0.0, 1.0, 0.25]]);
    // Node 1: the mesh's weights, 0.5 of target 0, under its translation.
    assert_at(&scene, 1, &[[0.0, 0.0, 10.5], [1.0, 0.0, 10.5], [0.0, 1.0, 10.5]]);
    assert!(!scene.is_animated());
}

#[test]
fn animated_weights_pose_the_mesh_at_any_time() {
    let mut linear = load(&morphing_triangle(Some("LINEAR"))).expect("loads");
    assert!(linear.is_animated());
    // Until set_time, the node's weights.
    assert_at(&linear, 0, &[[1.0, 0.0, 0.25]]);
    // t = 0.5: a quarter of the way from [0, 0] to [1, 0.5]: [0.25, 0.125].
    linear.set_time(0.5);
    assert_at(&linear, 0, &[[0.125, 0.0, 0.25], [1.0, 0.0, 0.25]]);
    // Node 1 has no channel: the mesh's weights still.
    assert_at(&linear, 1, &[[0.0, 0.0, 10.5]]);
    let mut step = load(&morphing_triangle(Some("STEP"))).expect("loads");
    step.set_time(1.9);
    assert_at(&step, 0, &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]);
    step.set_time(2.0);
    assert_at(&step, 0, &[[0.5, 0.0, 1.0], [1.0, 0.0, 1.0]]);
    // Zero tangents: halfway, the Hermite basis gives half of each value: [0.5, 0.25].
    let mut cubic = load(&morphing_triangle(Some("CUBICSPLINE"))).expect("loads");
    cubic.set_time(1.0);
    assert_at(&cubic, 0, &[[0.25, 0.0, 0.5], [1.0, 0.0, 0.5]]);
}

#[test]
fn bad_morph_targets_and_weights_are_named() {
    // A target with fewer elements than the vertices.
    let mut doc = morphing_triangle(None);
    doc["accessors"][1]["count"] = json!(2);
    assert_names(
        &load_err(&doc),
        &[
            "mesh 0 primitive 0",
            "morph target 0 POSITION",
            "accessor 1 has 2 elements",
            "3 vertices",
        ],
    );
    // Weights of the wrong length, on the node or the mesh.
    let mut doc = morphing_triangle(None);
    doc["nodes"][0]["weights"] = json!([1.0]);
    assert_names(&load_err(&doc), &["node 0", "weights has 1 values", "2 morph targets"]);
    let mut doc = morphing_triangle(None);
    doc["meshes"][0]["weights"] = json!([1.0, 2.0, 3.0]);
    assert_names(&load_err(&doc), &["mesh 0", "weights has 3 values", "2 morph targets"]);
    // A weights channel with one value per key instead of one per target.
    let mut doc = morphing_triangle(Some("LINEAR"));
    doc["accessors"][4]["count"] = json!(2);
    assert_names(&load_err(&doc), &["animation 0 sampler 0", "expected 4", "2 morph targets"]);
}

#[test]
fn meshes_that_do_not_deform_are_unchanged() {
    // A plain placement shares its mesh and keeps its node's transform, with no record.
    let mut doc = morphing_triangle(None);
    doc["meshes"][0]["primitives"][0].as_object_mut().unwrap().remove("targets");
    doc["meshes"][0].as_object_mut().unwrap().remove("weights");
    doc["nodes"][0].as_object_mut().unwrap().remove("weights");
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.meshes.len(), 1);
    assert!(scene.meshes[0].deform.is_none());
    assert_eq!(scene.instances[1].transform, DMat4::from_translation(DVec3::new(0.0, 0.0, 10.0)));
    assert_eq!(scene.meshes[0].positions[1], Vec3::X);
}

#[test]
fn real_assets_without_skins_load_as_before() {
    let real = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets/real");
    let scene = load_path(&real.join("Box/glTF/Box.gltf")).expect("loads");
    assert_eq!((scene.meshes.len(), scene.instances.len()), (1, 1));
    assert!(scene.meshes[0].deform.is_none());
    // The root's matrix (y up to z up), and no offset.
    let expected = DMat4::from_cols_array(&[
        1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ]);
    assert_eq!(scene.instances[0].transform, expected);
    assert_eq!(scene.instances[0].offset, DMat4::IDENTITY);
    assert!(!scene.is_animated());
    let mut animated = load_path(&real.join("BoxAnimated/glTF/BoxAnimated.gltf")).expect("loads");
    assert!(animated.meshes.iter().all(|m| m.deform.is_none()));
    assert!(animated.is_animated());
    let before: Vec<Vec<Vec3>> = animated.meshes.iter().map(|m| m.positions.clone()).collect();
    animated.set_time(1.0);
    let after: Vec<Vec<Vec3>> = animated.meshes.iter().map(|m| m.positions.clone()).collect();
    assert_eq!(before, after, "set_time moves placements, never the vertices of rigid meshes");
}
