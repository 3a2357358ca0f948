//! Hand-made glTF cases: malformed files give errors naming the object at fault, confinement
//! of file URIs, accessor features (sparse, normalised, strided, strips), materials, cameras,
//! lights, and the default camera.

use std::path::PathBuf;

use base64::Engine as _;
use glam::{DMat4, DVec3, Vec2, Vec3, Vec4};
use serde_json::{json, Value};

use super::*;
use crate::scene::{AlphaMode, Projection, PunctualKind, Wrap};

fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn u16_bytes(v: &[u16]) -> Vec<u8> {
    let mut out: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    out.resize(out.len().div_ceil(4) * 4, 0);
    out
}

const TRIANGLE: [f32; 9] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

/// One indexed triangle: buffer 0 = positions (36 bytes) + u16 indices (8 bytes with padding);
/// accessor 0 = POSITION, accessor 1 = indices; node 0 places mesh 0.
fn triangle_doc(positions: &[f32], indices: &[u16]) -> Value {
    let mut bin = f32_bytes(positions);
    let pos_len = bin.len();
    bin.extend(u16_bytes(indices));
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len() / 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": indices.len(), "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": indices.len() * 2}
        ],
        "buffers": [{"byteLength": bin.len(), "uri": data_uri(&bin)}]
    })
}

fn load(doc: &Value) -> Result<Scene, SceneError> {
    load_slice(doc.to_string().as_bytes(), &NoFiles)
}

fn load_err(doc: &Value) -> String {
    match load(doc) {
        Ok(_) => panic!("malformed document loaded: {doc}"),
        Err(e) => {
            assert!(!e.0.is_empty());
            e.0
        }
    }
}

fn assert_names(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "error {msg:?} does not contain {p:?}");
    }
}

/// A fresh folder under the system temp dir.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("common-gltf-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

#[test]
fn a_valid_triangle_loads() {
    let scene = load(&triangle_doc(&TRIANGLE, &[0, 1, 2])).expect("loads");
    assert_eq!(scene.meshes.len(), 1);
    assert_eq!(scene.meshes[0].indices, vec![[0, 1, 2]]);
    assert_eq!(scene.meshes[0].positions[1], Vec3::X);
    assert_eq!(scene.meshes[0].name, "mesh 0/0");
    assert!(scene.meshes[0].normals.is_none());
    assert_eq!(scene.instances.len(), 1);
    // No material: the default one is appended.
    assert_eq!(scene.materials.len(), 1);
    assert_eq!(scene.materials[0].name, "default");
    assert_eq!(scene.meshes[0].material, 0);
    check_renderable(&scene).expect("renderable");
}

#[test]
fn out_of_range_index_names_the_accessor() {
    let msg = load_err(&triangle_doc(&TRIANGLE, &[0, 1, 70]));
    assert_names(&msg, &["mesh 0 primitive 0", "accessor 1: index 70 out of range for 3 vertices"]);
}

#[test]
fn accessor_overrunning_its_view_names_the_accessor() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][0]["count"] = json!(4);
    assert_names(&load_err(&doc), &["accessor 0", "overrun buffer view 0"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][1]["byteOffset"] = json!(4);
    assert_names(&load_err(&doc), &["accessor 1", "overrun buffer view 1"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["bufferViews"][0]["byteStride"] = json!(8);
    assert_names(&load_err(&doc), &["accessor 0", "byteStride 8"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][0]["count"] = json!(u32::MAX);
    assert_names(&load_err(&doc), &["accessor 0"]);
}

#[test]
fn view_overrunning_its_buffer_names_both() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["bufferViews"][1]["byteLength"] = json!(1000);
    assert_names(&load_err(&doc), &["buffer view 1", "overrun buffer 0"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["buffers"][0]["byteLength"] = json!(1000);
    assert_names(&load_err(&doc), &["buffer 0", "byteLength is 1000"]);
}

#[test]
fn nan_position_names_the_accessor_and_element() {
    let mut p = TRIANGLE;
    p[7] = f32::NAN;
    assert_names(
        &load_err(&triangle_doc(&p, &[0, 1, 2])),
        &["accessor 0: non-finite position at element 2"],
    );
    p[7] = f32::INFINITY;
    assert_names(
        &load_err(&triangle_doc(&p, &[0, 1, 2])),
        &["accessor 0: non-finite position at element 2"],
    );
}

#[test]
fn missing_buffer_file_names_buffer_and_file() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["buffers"][0]["uri"] = json!("missing.bin");
    assert_names(&load_err(&doc), &["buffer 0", "missing.bin"]);
    let dir = temp_dir("missing");
    let path = dir.join("scene.gltf");
    std::fs::write(&path, doc.to_string()).expect("write");
    let msg = load_path(&path).expect_err("missing file").0;
    assert_names(&msg, &["buffer 0", "missing.bin"]);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn bad_base64_names_the_buffer() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["buffers"][0]["uri"] = json!("data:application/octet-stream;base64,AAAA@@@@");
    assert_names(&load_err(&doc), &["buffer 0", "base64"]);
}

#[test]
fn uris_never_leave_the_scene_folder() {
    let outer = temp_dir("escape");
    let inner = outer.join("scene");
    std::fs::create_dir_all(inner.join("sub")).expect("mkdir");
    let doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    let bin = base64::engine::general_purpose::STANDARD
        .decode(
            doc["buffers"][0]["uri"]
                .as_str()
                .unwrap_or_default()
                .split(',')
                .nth(1)
                .unwrap_or_default(),
        )
        .expect("decode");
    std::fs::write(outer.join("secret.bin"), &bin).expect("write");
    std::fs::write(inner.join("sub").join("my file.bin"), &bin).expect("write");

    let load_with_uri = |uri: &str| {
        let mut doc = doc.clone();
        doc["buffers"][0]["uri"] = json!(uri);
        let path = inner.join("scene.gltf");
        std::fs::write(&path, doc.to_string()).expect("write");
        load_path(&path)
    };
    // Percent-decoded, normalised relative URIs inside the folder work.
    load_with_uri("sub/my%20file.bin").expect("relative URI");
    load_with_uri("./sub/../sub/my%20file.bin").expect("normalised URI");
    // Escapes, absolute paths and other schemes do not, even when the file exists.
    let secret = outer.join("secret.bin");
    let absolute = secret.to_string_lossy().to_string();
    let file_url = format!("file://{absolute}");
    for uri in [
        "../secret.bin",
        "%2E%2E/secret.bin",
        "sub/../../secret.bin",
        "..\\secret.bin",
        &absolute,
        &file_url,
        "http://example.com/x.bin",
    ] {
        let msg = load_with_uri(uri).expect_err(uri).0;
        assert_names(&msg, &["buffer 0"]);
    }
    assert_names(&load_with_uri("../secret.bin").unwrap_err().0, &["escapes"]);
    assert_names(&load_with_uri(&absolute).unwrap_err().0, &["absolute"]);
    // A symbolic link pointing outside is caught by the canonical-prefix check.
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(&secret, inner.join("link.bin")).expect("symlink");
        assert_names(&load_with_uri("link.bin").unwrap_err().0, &["buffer 0", "outside"]);
    }
    // The resolver on its own refuses too.
    let r = DirResolver::new(&inner);
    assert!(r.read("../secret.bin").is_err());
    assert!(r.read(&absolute).is_err());
    assert!(r.read("sub/my file.bin").is_ok());
    assert!(NoFiles.read("sub/my file.bin").unwrap_err().contains("sub/my file.bin"));
    let _ = std::fs::remove_dir_all(outer);
}

#[test]
fn unsupported_required_extension_is_named() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["extensionsUsed"] = json!(["EXT_texture_avif", "KHR_materials_sheen"]);
    doc["extensionsRequired"] = json!(["EXT_texture_avif"]);
    assert_names(&load_err(&doc), &["EXT_texture_avif"]);
    // Optional unknown extensions are ignored; supported ones may be required.
    doc["extensionsRequired"] = json!(["KHR_texture_transform", "KHR_materials_specular"]);
    load(&doc).expect("supported required extensions");
}

#[test]
fn node_cycles_and_multiple_parents_are_errors() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["nodes"] = json!([{"mesh": 0}, {"children": [2]}, {"children": [1]}]);
    assert_names(&load_err(&doc), &["node 1", "cycle"]);
    doc["nodes"] = json!([{"mesh": 0, "children": [0]}]);
    assert_names(&load_err(&doc), &["node 0", "cycle"]);
    doc["nodes"] = json!([{"children": [1]}, {"children": [0]}]);
    assert_names(&load_err(&doc), &["node 0", "cycle"]);
    doc["nodes"] = json!([{"children": [2]}, {"children": [2]}, {"mesh": 0}]);
    doc["scenes"] = json!([{"nodes": [0, 1]}]);
    assert_names(&load_err(&doc), &["node 2: has two parents, node 0 and node 1"]);
    doc["nodes"] = json!([{"children": [1]}, {"mesh": 0}]);
    doc["scenes"] = json!([{"nodes": [0, 1]}]);
    assert_names(&load_err(&doc), &["scene 0: node 1 is not a root"]);
    doc["nodes"] = json!([{"children": [5]}]);
    assert_names(&load_err(&doc), &["node 0: child 5 does not exist"]);
    doc["nodes"] = json!([{"mesh": 3}]);
    doc["scenes"] = json!([{"nodes": [0]}]);
    assert_names(&load_err(&doc), &["node 0: mesh 3 does not exist"]);
}

#[test]
fn other_dangling_references_are_named() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"][0]["material"] = json!(4);
    assert_names(&load_err(&doc), &["mesh 0 primitive 0", "material 4 does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"][0]["indices"] = json!(9);
    assert_names(&load_err(&doc), &["mesh 0 primitive 0", "accessor 9: does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][0]["bufferView"] = json!(7);
    assert_names(&load_err(&doc), &["accessor 0", "buffer view 7: does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["bufferViews"][0]["buffer"] = json!(3);
    assert_names(&load_err(&doc), &["buffer 3: does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["scene"] = json!(2);
    assert_names(&load_err(&doc), &["scene 2: does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["nodes"][0]["camera"] = json!(0);
    assert_names(&load_err(&doc), &["node 0", "camera 0: does not exist"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][1]["componentType"] = json!(5126);
    assert_names(&load_err(&doc), &["accessor 1: indices must be SCALAR"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][0]["type"] = json!("VEC2");
    assert_names(&load_err(&doc), &["POSITION accessor 0 must be"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"][0].as_object_mut().expect("object").remove("componentType");
    assert_names(&load_err(&doc), &["accessor 0: missing field `componentType`"]);
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["nodes"][0]["rotation"] = json!([0.0, 0.0, 0.0, 0.0]);
    assert_names(&load_err(&doc), &["node 0", "rotation"]);
}

#[test]
fn malformed_glb_is_an_error_not_a_panic() {
    let doc = triangle_doc(&TRIANGLE, &[0, 1, 2]).to_string();
    let file = glb::build(doc.as_bytes(), None);
    load_slice(&file, &NoFiles).expect("GLB with data URIs");
    for cut in [0, 5, 12, 19, 30, file.len() - 1] {
        let e = load_slice(&file[..cut], &NoFiles).expect_err("truncated");
        assert!(!e.0.is_empty());
    }
    // A .glb name on a file without the magic is refused.
    let dir = temp_dir("glb-magic");
    let path = dir.join("x.glb");
    std::fs::write(&path, &doc).expect("write");
    assert_names(&load_path(&path).unwrap_err().0, &["GLB", "magic"]);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn glb_bin_chunk_backs_buffer_zero() {
    let mut bin = f32_bytes(&TRIANGLE);
    bin.extend(u16_bytes(&[0, 2, 1]));
    let mut doc = triangle_doc(&TRIANGLE, &[0, 2, 1]);
    doc["buffers"] = json!([{"byteLength": bin.len()}]);
    let file = glb::build(doc.to_string().as_bytes(), Some(&bin));
    let scene = load_slice(&file, &NoFiles).expect("GLB");
    assert_eq!(scene.meshes[0].indices, vec![[0, 2, 1]]);
    let file = glb::build(doc.to_string().as_bytes(), None);
    assert_names(&load_slice(&file, &NoFiles).unwrap_err().0, &["buffer 0", "BIN"]);
}

#[test]
fn empty_scenes_load_but_are_not_renderable() {
    let scene = load(&json!({"asset": {"version": "2.0"}})).expect("empty glTF is valid");
    assert_eq!(scene.cameras.len(), 1, "default camera added");
    assert_eq!(check_renderable(&scene).unwrap_err().0, "scene has no triangles");
    let scene =
        load(&json!({"asset": {"version": "2.0"}, "nodes": [{}], "scenes": [{"nodes": [0]}]}))
            .expect("loads");
    assert!(check_renderable(&scene).is_err());
}

#[test]
fn accessor_features_sparse_normalised_strided_and_no_buffer_view() {
    // Positions as normalised signed shorts with a stride of 8; sparse replaces vertex 2.
    let mut bin: Vec<u8> = Vec::new();
    for p in [[0i16, 0, 0], [32767, 0, 0], [0, -32768, 0]] {
        for c in p {
            bin.extend(c.to_le_bytes());
        }
        bin.extend([0u8; 2]);
    }
    let view1 = bin.len();
    bin.extend(u16_bytes(&[2])); // sparse index
    let view2 = bin.len();
    for c in [0i16, 16384, 0] {
        bin.extend(c.to_le_bytes());
    }
    bin.resize(bin.len().div_ceil(4) * 4, 0);
    let view3 = bin.len();
    bin.extend([255u8, 0, 0, 255, 0, 255, 0, 255, 0, 0, 255, 128]); // COLOR_0 unsigned byte normalised
    let doc = json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_mesh_quantization"],
        "extensionsRequired": ["KHR_mesh_quantization"],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "COLOR_0": 2}, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5122, "normalized": true, "count": 3, "type": "VEC3",
             "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
                        "values": {"bufferView": 2}}},
            {"componentType": 5126, "count": 3, "type": "VEC3",
             "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
                        "values": {"bufferView": 2}}},
            {"bufferView": 3, "componentType": 5121, "normalized": true, "count": 3, "type": "VEC4"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": view1, "byteStride": 8},
            {"buffer": 0, "byteOffset": view1, "byteLength": 2},
            {"buffer": 0, "byteOffset": view2, "byteLength": 6},
            {"buffer": 0, "byteOffset": view3, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bin.len(), "uri": data_uri(&bin)}]
    });
    // Accessor 1 (float, no buffer view) takes its sparse values from view 2 read as floats:
    // 6 bytes cannot hold one VEC3 of floats, so this must be an error naming accessor 1.
    assert_names(&load_err(&doc), &["accessor 1", "sparse values"]);
    let mut doc = doc;
    doc["meshes"][0]["primitives"][0]["attributes"]
        .as_object_mut()
        .expect("object")
        .remove("NORMAL");
    let scene = load(&doc).expect("loads");
    let m = &scene.meshes[0];
    assert_eq!(m.positions[1], Vec3::X);
    assert!(
        (m.positions[2] - Vec3::new(0.0, 16384.0 / 32767.0, 0.0)).length() < 1e-6,
        "{:?}",
        m.positions[2]
    );
    let colors = m.colors.as_ref().expect("colors");
    assert_eq!(colors[0], Vec4::new(1.0, 0.0, 0.0, 1.0));
    assert!((colors[2].w - 128.0 / 255.0).abs() < 1e-6);
    assert_eq!(m.indices, vec![[0, 1, 2]], "non-indexed");

    // An accessor without a buffer view and without sparse is all zeros.
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["accessors"]
        .as_array_mut()
        .expect("array")
        .push(json!({"componentType": 5126, "count": 3, "type": "VEC2"}));
    doc["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_1"] = json!(2);
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.meshes[0].uvs[1].as_deref(), Some(&[Vec2::ZERO; 3][..]));
    assert!(scene.meshes[0].uvs[0].is_none());
}

#[test]
fn strips_fans_and_skipped_modes() {
    let quad = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0];
    let mut doc = triangle_doc(&quad, &[0, 1, 2, 3]);
    doc["meshes"][0]["primitives"][0]["mode"] = json!(5);
    assert_eq!(load(&doc).expect("strip").meshes[0].indices, vec![[0, 1, 2], [1, 3, 2]]);
    doc["meshes"][0]["primitives"][0]["mode"] = json!(6);
    assert_eq!(load(&doc).expect("fan").meshes[0].indices, vec![[1, 2, 0], [2, 3, 0]]);
    doc["meshes"][0]["primitives"][0]["mode"] = json!(1);
    let scene = load(&doc).expect("lines load");
    assert!(scene.meshes.is_empty() && scene.instances.is_empty());
    doc["meshes"][0]["primitives"][0]["mode"] = json!(9);
    assert_names(&load_err(&doc), &["mesh 0 primitive 0: invalid mode"]);
}

#[test]
fn instancing_shares_meshes_and_composes_transforms_in_f64() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["nodes"] = json!([
        {"children": [1, 2], "translation": [123456789.125, 0.0, 0.0], "scale": [2.0, 2.0, 2.0]},
        {"mesh": 0, "translation": [0.25, 0.0, 0.0]},
        {"mesh": 0, "matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,5,1]}
    ]);
    doc["scenes"] = json!([{"nodes": [0]}]);
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.meshes.len(), 1);
    assert_eq!(scene.instances.len(), 2);
    let p = scene.instances[0].transform.transform_point3(DVec3::ZERO);
    assert_eq!(p, DVec3::new(123456789.625, 0.0, 0.0), "f64 all the way");
    let p = scene.instances[1].transform.transform_point3(DVec3::X);
    assert_eq!(p, DVec3::new(123456791.125, 0.0, 10.0));
    assert_eq!(scene.instances[1].node, 2);
    // Without `scene`, scene 0; without scenes, every root node.
    doc.as_object_mut().expect("object").remove("scene");
    assert_eq!(load(&doc).expect("loads").instances.len(), 2);
    doc.as_object_mut().expect("object").remove("scenes");
    assert_eq!(load(&doc).expect("loads").instances.len(), 2);
}

#[test]
fn materials_textures_and_extensions() {
    // A 2x1 PNG made with the png crate's encoder via the image crate.
    let mut png = Vec::new();
    {
        let img =
            image::RgbaImage::from_raw(2, 1, vec![255, 0, 0, 255, 0, 0, 255, 128]).expect("image");
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("encode");
    }
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"] = json!([
        {"attributes": {"POSITION": 0}, "indices": 1, "material": 2},
        {"attributes": {"POSITION": 0}, "indices": 1},
        {"attributes": {"POSITION": 0}, "indices": 1, "material": 1}
    ]);
    doc["extensionsUsed"] = json!([
        "KHR_materials_emissive_strength",
        "KHR_materials_specular",
        "KHR_materials_ior",
        "KHR_materials_transmission",
        "KHR_texture_transform"
    ]);
    doc["materials"] = json!([
        {"name": "unused", "pbrMetallicRoughness": {"baseColorTexture": {"index": 5}}},
        {"name": "plain"},
        {"name": "fancy",
         "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.25, 1.0, 0.75], "metallicFactor": 0.0, "roughnessFactor": 0.3,
            "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"offset": [0.5, 0.0], "rotation": 1.5, "scale": [2.0, 3.0], "texCoord": 1}}},
            "metallicRoughnessTexture": {"index": 1}},
         "normalTexture": {"index": 1, "scale": 0.5, "extensions": {"KHR_texture_transform": {"scale": [4.0, 4.0]}}},
         "emissiveFactor": [1.0, 0.5, 0.0],
         "emissiveTexture": {"index": 0, "texCoord": 1},
         "alphaMode": "MASK",
         "doubleSided": true,
         "extensions": {
            "KHR_materials_emissive_strength": {"emissiveStrength": 4.0},
            "KHR_materials_specular": {"specularFactor": 0.0, "specularColorFactor": [0.5, 0.5, 0.5],
                "specularTexture": {"index": 1}, "specularColorTexture": {"index": 0, "texCoord": 1}},
            "KHR_materials_ior": {"ior": 1.33},
            "KHR_materials_transmission": {"transmissionFactor": 0.9, "transmissionTexture": {"index": 1, "texCoord": 1}}
         }}
    ]);
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(&png))}]);
    doc["samplers"] =
        json!([{"magFilter": 9728, "minFilter": 9729, "wrapS": 33071, "wrapT": 33648}]);
    doc["textures"] = json!([{"source": 0, "sampler": 0}, {"source": 0}]);
    let scene = load(&doc).expect("loads");
    // Used materials in file order (1 "plain", 2 "fancy"), then the default.
    let names: Vec<&str> = scene.materials.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["plain", "fancy", "default"]);
    let mats: Vec<usize> = scene.meshes.iter().map(|m| m.material).collect();
    assert_eq!(mats, [1, 2, 0]);
    let m = &scene.materials[1];
    assert_eq!(m.base_color, Vec4::new(0.5, 0.25, 1.0, 0.75));
    assert_eq!((m.metallic, m.roughness), (0.0, 0.3));
    assert_eq!(m.emissive, Vec3::new(4.0, 2.0, 0.0));
    assert_eq!((m.specular, m.specular_color), (0.0, Vec3::splat(0.5)));
    let (specular, color) =
        (m.specular_texture.expect("specular"), m.specular_color_texture.expect("colour"));
    assert_eq!((specular.tex_coord, color.tex_coord), (0, 1));
    assert_ne!(specular.texture, color.texture, "glTF textures 1 and 0");
    assert_eq!((m.ior, m.transmission), (1.33, 0.9));
    assert_eq!(m.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    assert!(m.double_sided);
    let base = m.base_color_texture.expect("base colour texture");
    assert_eq!(base.tex_coord, 1, "texCoord override of KHR_texture_transform");
    let t = base.transform.expect("transform");
    assert_eq!((t.offset, t.rotation, t.scale), (Vec2::new(0.5, 0.0), 1.5, Vec2::new(2.0, 3.0)));
    let (normal, scale) = m.normal_texture.expect("normal texture");
    assert_eq!(scale, 0.5);
    assert_eq!(normal.transform.expect("transform").scale, Vec2::splat(4.0));
    assert_eq!(m.emissive_texture.expect("emissive").texture, base.texture);
    assert_eq!(m.emissive_texture.expect("emissive").tex_coord, 1);
    let transmission = m.transmission_texture.expect("transmission texture");
    assert_eq!((transmission.texture, transmission.tex_coord), (normal.texture, 1));
    assert_eq!(scene.textures.len(), 2, "one per glTF texture used");
    let tex = &scene.textures[base.texture];
    assert_eq!((tex.width, tex.height), (2, 1));
    assert_eq!(tex.texels.rgba8().expect("8 bits"), [[255, 0, 0, 255], [0, 0, 255, 128]]);
    assert_eq!(
        (tex.wrap_s, tex.wrap_t, tex.nearest, tex.mipmaps),
        (Wrap::ClampToEdge, Wrap::MirroredRepeat, true, false),
        "minFilter LINEAR asks for no mipmaps"
    );
    let other = &scene.textures[normal.texture];
    assert_eq!(
        (other.wrap_s, other.wrap_t, other.nearest, other.mipmaps),
        (Wrap::Repeat, Wrap::Repeat, false, true),
        "no sampler: repeat, bilinear, mipmapped"
    );
    let plain = &scene.materials[0];
    assert_eq!(
        (plain.specular, plain.ior, plain.transmission, plain.metallic),
        (1.0, 1.5, 0.0, 1.0)
    );
    assert!(plain.transmission_texture.is_none());
    assert!(plain.specular_texture.is_none() && plain.specular_color_texture.is_none());

    // An undecodable image is an error naming it.
    doc["images"] = json!([{"uri": data_uri(b"definitely not a PNG")}]);
    assert_names(&load_err(&doc), &["material 2", "image 0"]);
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(&png[..png.len() / 2]))}]);
    assert_names(&load_err(&doc), &["image 0", "decode"]);
}

#[test]
fn cameras_drop_scale_and_lights_are_placed() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["extensionsUsed"] = json!(["KHR_lights_punctual"]);
    doc["extensions"] = json!({"KHR_lights_punctual": {"lights": [
        {"type": "spot", "color": [1.0, 0.5, 0.25], "intensity": 8.0, "name": "lamp"},
        {"type": "directional", "intensity": 2.0},
        {"type": "point", "range": 3.0, "spot": {"outerConeAngle": 0.3}}
    ]}});
    doc["cameras"] = json!([
        {"type": "perspective", "name": "persp", "perspective": {"yfov": 0.5, "znear": 0.1}},
        {"type": "orthographic", "orthographic": {"xmag": 2.0, "ymag": 1.0, "znear": 0.1, "zfar": 10.0}}
    ]);
    const H: f64 = std::f64::consts::FRAC_1_SQRT_2;
    doc["nodes"] = json!([
        {"mesh": 0},
        {"name": "rig", "scale": [3.0, 3.0, 3.0], "translation": [1.0, 2.0, 3.0], "children": [2, 3]},
        {"camera": 0, "rotation": [0.0, H, 0.0, H]},
        {"camera": 1, "extensions": {"KHR_lights_punctual": {"light": 0}}},
        {"extensions": {"KHR_lights_punctual": {"light": 1}}, "rotation": [-H, 0.0, 0.0, H]},
        {"extensions": {"KHR_lights_punctual": {"light": 2}}, "translation": [0.0, 5.0, 0.0]}
    ]);
    doc["scenes"] = json!([{"nodes": [0, 1, 4, 5]}]);
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.cameras.len(), 2);
    let c = &scene.cameras[0];
    assert_eq!(c.name, "persp", "node has no name, camera has");
    assert_eq!(c.node, Some(2));
    assert_eq!(c.projection, Projection::Perspective { yfov: 0.5 });
    assert!((c.position() - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    let expect = DMat4::from_rotation_translation(
        glam::DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2),
        DVec3::new(1.0, 2.0, 3.0),
    );
    assert!(c.transform.abs_diff_eq(expect, 1e-12), "{:?}", c.transform);
    assert_eq!(scene.cameras[1].name, "camera 1");
    assert_eq!(scene.cameras[1].projection, Projection::Orthographic { xmag: 2.0, ymag: 1.0 });

    assert_eq!(scene.lights.len(), 3);
    let spot = &scene.lights[0];
    assert_eq!(spot.name, "lamp");
    assert_eq!(
        spot.kind,
        PunctualKind::Spot { inner_cone: 0.0, outer_cone: std::f32::consts::FRAC_PI_4 }
    );
    assert_eq!(spot.intensity, Vec3::new(8.0, 4.0, 2.0));
    assert!((spot.position - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
    assert!((spot.direction - DVec3::NEG_Z).length() < 1e-12 && spot.range.is_none());
    let sun = &scene.lights[1];
    assert_eq!(sun.kind, PunctualKind::Directional);
    assert!((sun.direction - DVec3::NEG_Y).length() < 1e-12, "{:?}", sun.direction);
    let point = &scene.lights[2];
    assert_eq!(
        (point.kind, point.range, point.intensity),
        (PunctualKind::Point, Some(3.0), Vec3::ONE)
    );
    assert_eq!(point.position, DVec3::new(0.0, 5.0, 0.0));

    doc["extensions"]["KHR_lights_punctual"]["lights"][0]["spot"] =
        json!({"innerConeAngle": 1.0, "outerConeAngle": 0.5});
    assert_names(&load_err(&doc), &["light 0", "cone"]);
    doc["extensions"]["KHR_lights_punctual"]["lights"][0]["spot"] = json!({"outerConeAngle": 0.5});
    doc["nodes"][5]["extensions"]["KHR_lights_punctual"]["light"] = json!(7);
    assert_names(&load_err(&doc), &["light 7 does not exist"]);
}

#[test]
fn default_camera_sees_the_whole_scene() {
    // A box of 8 vertices far from the origin, stretched, placed by two nodes.
    let mut corners = Vec::new();
    for i in 0..8 {
        corners.extend([
            (i & 1) as f32 * 40.0,
            ((i >> 1) & 1) as f32 * 3.0,
            ((i >> 2) & 1) as f32 * 7.0,
        ]);
    }
    let mut doc = triangle_doc(&corners, &[0, 1, 2, 3, 4, 5, 6, 7, 0]);
    doc["nodes"] = json!([{"mesh": 0, "translation": [1.0e5, -20.0, 3.0]}, {"mesh": 0, "translation": [1.0e5 + 10.0, 50.0, -30.0]}]);
    doc["scenes"] = json!([{"nodes": [0, 1]}]);
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.cameras.len(), 1);
    let cam = &scene.cameras[0];
    assert_eq!((cam.name.as_str(), cam.node), ("default", None));
    let Projection::Perspective { yfov } = cam.projection else { panic!("perspective expected") };
    assert!((yfov as f64 - 40f64.to_radians()).abs() < 1e-6);
    let tan = (yfov as f64 * 0.5).tan();
    let to_cam = cam.transform.inverse();
    let (lo, hi) = scene.bounds().expect("bounds");
    for i in 0..8 {
        let corner = DVec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let q = to_cam.transform_point3(corner);
        assert!(q.z < 0.0, "corner {corner} behind the camera");
        assert!(
            q.x.abs() <= -q.z * tan && q.y.abs() <= -q.z * tan,
            "corner {corner} outside the view: {q}"
        );
    }
    // The camera looks down -z at the centre of the bounds.
    let centre = to_cam.transform_point3((lo + hi) * 0.5);
    assert!(centre.x.abs() < 1e-9 && centre.y.abs() < 1e-9 && centre.z < 0.0);

    // A file with a camera gets no default one.
    doc["cameras"] = json!([{"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}}]);
    doc["nodes"][1]["camera"] = json!(0);
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.cameras.len(), 1);
    assert_eq!(scene.cameras[0].name, "camera 0");
}

#[test]
fn bad_normals_and_tangents_are_tolerated_and_counts_checked() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    let mut extra = f32_bytes(&[0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    extra.extend(f32_bytes(&[2.0, 0.0, 0.0, -0.5, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0]));
    doc["buffers"]
        .as_array_mut()
        .expect("array")
        .push(json!({"byteLength": extra.len(), "uri": data_uri(&extra)}));
    doc["bufferViews"].as_array_mut().expect("array").extend([
        json!({"buffer": 1, "byteLength": 36}),
        json!({"buffer": 1, "byteOffset": 36, "byteLength": 48}),
    ]);
    doc["accessors"].as_array_mut().expect("array").extend([
        json!({"bufferView": 2, "componentType": 5126, "count": 3, "type": "VEC3"}),
        json!({"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC4"}),
    ]);
    doc["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(2);
    doc["meshes"][0]["primitives"][0]["attributes"]["TANGENT"] = json!(3);
    let scene = load(&doc).expect("loads");
    let m = &scene.meshes[0];
    assert_eq!(m.normals.as_deref(), Some(&[Vec3::Z; 3][..]), "normalised, zero one repaired");
    let t = m.tangents.as_ref().expect("tangents");
    assert_eq!(t[0], Vec4::new(1.0, 0.0, 0.0, -1.0));
    doc["accessors"][2]["count"] = json!(2);
    assert_names(&load_err(&doc), &["mesh 0 primitive 0", "NORMAL accessor 2 has 2 elements"]);
}

#[test]
fn a_small_file_cannot_make_the_loader_allocate_without_limit() {
    // 50 primitives sharing one 3-vertex accessor, against a budget of 100 components.
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    let prims: Vec<Value> =
        (0..50).map(|_| json!({"attributes": {"POSITION": 0}, "indices": 1})).collect();
    doc["meshes"][0]["primitives"] = Value::Array(prims);
    let parsed = json::parse(doc.to_string().as_bytes()).expect("parses");
    let loader = Loader::new(&parsed, None, &NoFiles);
    loader.budget.set(Budget { components: 100, ..Budget::FULL });
    let msg = loader.load().expect_err("over budget").0;
    assert_names(&msg, &["accessor", "too large"]);
    // The real budget takes it easily, and a huge all-zero accessor is refused before allocating.
    assert_eq!(load(&doc).expect("loads").meshes.len(), 50);
    doc["accessors"][0] = json!({"componentType": 5126, "count": 200_000_000u64, "type": "VEC3"});
    assert_names(&load_err(&doc), &["accessor 0", "too large"]);
}

/// A PNG of `size` x `size` RGBA texels, every byte `value`.
fn flat_png(size: u32, value: u8) -> Vec<u8> {
    let mut png = Vec::new();
    image::RgbaImage::from_raw(size, size, vec![value; (size * size * 4) as usize])
        .expect("image")
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("encode");
    png
}

/// `triangle_doc` drawn `n` times, primitive `k` with material `k`, whose base colour is
/// texture `k`.
fn textured_triangles(n: usize) -> Value {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    let prims: Vec<Value> = (0..n)
        .map(|m| json!({"attributes": {"POSITION": 0}, "indices": 1, "material": m}))
        .collect();
    doc["meshes"][0]["primitives"] = Value::Array(prims);
    doc["materials"] = Value::Array(
        (0..n)
            .map(|t| json!({"pbrMetallicRoughness": {"baseColorTexture": {"index": t}}}))
            .collect(),
    );
    doc
}

/// Textures that share one image share its decoded texels and are charged for them once, from
/// the image's header, before anything is decoded.
#[test]
fn one_image_is_decoded_once_and_charged_from_its_header() {
    let png = flat_png(64, 200);
    let mut doc = textured_triangles(8);
    doc["textures"] = Value::Array((0..8).map(|_| json!({"source": 0})).collect());
    let uri =
        format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(&png));
    doc["images"] = json!([{ "uri": uri }]);
    let parsed = json::parse(doc.to_string().as_bytes()).expect("parses");
    // A budget of exactly one image's texels takes eight textures of it.
    let mut loader = Loader::new(&parsed, None, &NoFiles);
    loader.scene_budget.texels = 64 * 64;
    let scene = loader.load().expect("one image, charged once");
    assert_eq!(scene.textures.len(), 8);
    assert!(scene.textures.iter().all(|t| t.texels.same_image(&scene.textures[0].texels)));
    // One texel less refuses it, naming the image and its size.
    let mut loader = Loader::new(&parsed, None, &NoFiles);
    loader.scene_budget.texels = 64 * 64 - 1;
    let msg = loader.load().expect_err("over budget").0;
    assert_names(
        &msg,
        &["4096 decoded texels (image 0, 64x64)", "budget of 4095", "--max-megatexels"],
    );
    // A header that claims 100000x100000 texels over a few bytes is refused from the header.
    let mut huge = png.clone();
    huge[16..20].copy_from_slice(&100_000u32.to_be_bytes());
    huge[20..24].copy_from_slice(&100_000u32.to_be_bytes());
    // The IHDR chunk's CRC-32 (over its type and data) made right again.
    let crc = huge[12..29].iter().fold(!0u32, |mut c, &b| {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
        c
    });
    huge[29..33].copy_from_slice(&(!crc).to_be_bytes());
    let uri = format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(&huge)
    );
    doc["images"] = json!([{ "uri": uri }]);
    assert_names(&load_err(&doc), &["10.00 G decoded texels (image 0, 100000x100000)"]);
}

/// Runs the jobs last first: a spread whose order is not the loader's.
struct Backwards;

impl crate::spread::Spread for Backwards {
    fn run<'a>(&self, jobs: Vec<crate::spread::Job<'a>>) {
        jobs.into_iter().rev().for_each(|job| job());
    }
}

/// Images are decoded after the materials are read, by whatever spread the caller lends: each
/// texture gets its own image's texels whatever order they decode in, and of several images
/// that fail to decode, the lowest-numbered is named.
#[test]
fn images_decode_the_same_in_any_order_and_the_first_failure_is_named() {
    // Three images of different sizes (decoded largest first) and colours.
    let images = [flat_png(4, 10), flat_png(8, 20), flat_png(16, 30)];
    let mut doc = textured_triangles(3);
    doc["textures"] = Value::Array((0..3).map(|i| json!({"source": i})).collect());
    let with = |images: &[Vec<u8>]| {
        let mut doc = doc.clone();
        doc["images"] = Value::Array(
            images
                .iter()
                .map(|b| {
                    let data = base64::engine::general_purpose::STANDARD.encode(b);
                    json!({ "uri": format!("data:image/png;base64,{data}") })
                })
                .collect(),
        );
        doc.to_string()
    };
    let budget = SceneBudget::default();
    let text = with(&images);
    let in_order = load_slice_spread(text.as_bytes(), &NoFiles, &budget, &InOrder).expect("loads");
    let backwards =
        load_slice_spread(text.as_bytes(), &NoFiles, &budget, &Backwards).expect("loads");
    for scene in [&in_order, &backwards] {
        let seen: Vec<(u32, u8)> =
            scene.textures.iter().map(|t| (t.width, t.texels.rgba8().unwrap()[0][0])).collect();
        assert_eq!(seen, [(4, 10), (8, 20), (16, 30)]);
        assert!(scene.textures.iter().all(|t| t.texels.len() == (t.width * t.height) as usize));
    }
    // Images 1 and 2 with their pixel data cut short (the headers intact): image 1 is named,
    // though image 2, the largest, is decoded first.
    let cut = |b: &Vec<u8>| {
        let idat = b.windows(4).position(|w| w == b"IDAT").expect("IDAT");
        let mut cut = b[..idat + 8].to_vec();
        cut.extend_from_slice(b"IEND");
        cut
    };
    let text = with(&[images[0].clone(), cut(&images[1]), cut(&images[2])]);
    for spread in [&InOrder as &dyn crate::spread::Spread, &Backwards] {
        let msg = load_slice_spread(text.as_bytes(), &NoFiles, &budget, spread)
            .expect_err("image 1 does not decode")
            .0;
        assert!(msg.starts_with("image 1: cannot decode Png"), "{msg}");
    }
}

/// `EXT_texture_webp`: a texture reads its WebP image in place of its PNG fallback (a lossless
/// WebP decodes to its source's texels exactly), loads with no fallback at all, and a WebP
/// stream cut short or a missing source is an error naming the image or texture.
#[test]
fn webp_textures_decode_to_their_source_texels() {
    let (w, h) = (7u32, 5u32);
    let texels: Vec<u8> = (0..w * h * 4).map(|i| (i * 37 % 251) as u8).collect();
    let mut webp = Vec::new();
    image::codecs::webp::WebPEncoder::new_lossless(&mut webp)
        .encode(&texels, w, h, image::ExtendedColorType::Rgba8)
        .expect("encode");
    let uri = |mime: &str, bytes: &[u8]| {
        format!("data:{mime};base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
    };
    let mut doc = textured_triangles(2);
    doc["extensionsUsed"] = json!(["EXT_texture_webp"]);
    doc["images"] =
        json!([{"uri": uri("image/png", &flat_png(2, 9))}, {"uri": uri("image/webp", &webp)}]);
    doc["textures"] = json!([
        {"source": 0, "extensions": {"EXT_texture_webp": {"source": 1}}},
        {"extensions": {"EXT_texture_webp": {"source": 1}}}
    ]);
    let scene = load(&doc).expect("loads");
    for t in &scene.textures {
        assert_eq!((t.width, t.height), (w, h), "the WebP image, not the fallback");
        assert_eq!(bytemuck::cast_slice::<[u8; 4], u8>(t.texels.rgba8().unwrap()), &texels[..]);
    }
    let mut cut = doc.clone();
    cut["images"][1]["uri"] = json!(uri("image/webp", &webp[..webp.len() - 9]));
    assert_names(&load_err(&cut), &["image 1", "WebP"]);
    let mut missing = doc.clone();
    missing["textures"][1]["extensions"]["EXT_texture_webp"] = json!({});
    assert_names(&load_err(&missing), &["texture 1", "EXT_texture_webp", "source"]);
}

/// A 16-bit PNG keeps its 16 bits (RGBA as stored; grey spread over RGB with an opaque alpha),
/// and an 8-bit one stays 8-bit.
#[test]
fn sixteen_bit_pngs_keep_their_bits() {
    let rgba: Vec<u16> = vec![0, 1, 257, 65535, 40000, 12345, 65534, 32768];
    let mut png16 = Vec::new();
    image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(2, 1, rgba.clone())
        .expect("image")
        .write_to(&mut std::io::Cursor::new(&mut png16), image::ImageFormat::Png)
        .expect("encode");
    let mut grey16 = Vec::new();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 1, vec![3u16, 60001])
        .expect("image")
        .write_to(&mut std::io::Cursor::new(&mut grey16), image::ImageFormat::Png)
        .expect("encode");
    let uri = |bytes: &[u8]| {
        format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
    };
    let mut doc = textured_triangles(3);
    doc["images"] =
        json!([{"uri": uri(&png16)}, {"uri": uri(&grey16)}, {"uri": uri(&flat_png(1, 7))}]);
    doc["textures"] = json!([{"source": 0}, {"source": 1}, {"source": 2}]);
    let scene = load(&doc).expect("loads");
    let texels: Vec<&crate::scene::Texels> = scene.textures.iter().map(|t| &t.texels).collect();
    assert_eq!(
        texels[0].rgba16().expect("16 bits"),
        [[0, 1, 257, 65535], [40000, 12345, 65534, 32768]]
    );
    assert_eq!(
        texels[1].rgba16().expect("16 bits"),
        [[3, 3, 3, 65535], [60001, 60001, 60001, 65535]]
    );
    assert_eq!(texels[2].rgba8().expect("8 bits"), [[7, 7, 7, 7]]);
}

#[test]
fn layered_extensions_load_and_bad_values_are_named() {
    let mut png = Vec::new();
    image::RgbaImage::from_raw(1, 1, vec![255, 128, 0, 255])
        .expect("image")
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("encode");
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"][0]["material"] = json!(0);
    doc["extensionsUsed"] =
        json!(["KHR_materials_clearcoat", "KHR_materials_sheen", "KHR_materials_anisotropy"]);
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(&png))}]);
    doc["textures"] = json!([{"source": 0}]);
    doc["materials"] = json!([{"name": "layers", "extensions": {
        "KHR_materials_clearcoat": {"clearcoatFactor": 0.8, "clearcoatTexture": {"index": 0},
            "clearcoatRoughnessFactor": 0.25, "clearcoatRoughnessTexture": {"index": 0},
            "clearcoatNormalTexture": {"index": 0, "scale": 0.5}},
        "KHR_materials_sheen": {"sheenColorFactor": [0.5, 0.25, 1.0], "sheenColorTexture": {"index": 0},
            "sheenRoughnessFactor": 0.3, "sheenRoughnessTexture": {"index": 0}},
        "KHR_materials_anisotropy": {"anisotropyStrength": 0.6, "anisotropyRotation": -1.5,
            "anisotropyTexture": {"index": 0}}
    }}]);
    let scene = load(&doc).expect("loads");
    let m = &scene.materials[0];
    let c = m.clearcoat.expect("clearcoat");
    assert_eq!((c.factor, c.roughness), (0.8, 0.25));
    assert!(c.texture.is_some() && c.roughness_texture.is_some());
    assert_eq!(c.normal_texture.map(|(_, scale)| scale), Some(0.5));
    let s = m.sheen.expect("sheen");
    assert_eq!((s.color, s.roughness), (Vec3::new(0.5, 0.25, 1.0), 0.3));
    assert!(s.color_texture.is_some() && s.roughness_texture.is_some());
    let a = m.anisotropy.expect("anisotropy");
    assert_eq!((a.strength, a.rotation), (0.6, -1.5));
    assert!(a.texture.is_some());

    // Factors of 0 (the defaults) disable each layer.
    let good = doc.clone();
    doc["materials"][0]["extensions"] = json!({
        "KHR_materials_clearcoat": {"clearcoatRoughnessFactor": 0.5},
        "KHR_materials_sheen": {"sheenRoughnessFactor": 0.5},
        "KHR_materials_anisotropy": {"anisotropyRotation": 1.0}
    });
    let scene = load(&doc).expect("loads");
    let m = &scene.materials[0];
    assert!(m.clearcoat.is_none() && m.sheen.is_none() && m.anisotropy.is_none());
    // A required extension is accepted.
    let mut required = good.clone();
    required["extensionsRequired"] = json!(["KHR_materials_clearcoat", "KHR_materials_sheen"]);
    load(&required).expect("required layered extensions load");

    // Out-of-range and malformed values are refused, naming the material, the extension and the
    // key.
    let bad = [
        ("KHR_materials_clearcoat", "clearcoatFactor", json!(-0.5)),
        ("KHR_materials_clearcoat", "clearcoatFactor", json!(1.5)),
        ("KHR_materials_clearcoat", "clearcoatRoughnessFactor", json!(2.0)),
        ("KHR_materials_clearcoat", "clearcoatFactor", json!("1")),
        ("KHR_materials_clearcoat", "clearcoatNormalTexture", json!({"index": 7})),
        ("KHR_materials_clearcoat", "clearcoatTexture", json!({"scale": 1})),
        ("KHR_materials_sheen", "sheenColorFactor", json!([0.5, -0.1, 0.2])),
        ("KHR_materials_sheen", "sheenColorFactor", json!([0.5, 0.2])),
        ("KHR_materials_sheen", "sheenRoughnessFactor", json!(-1)),
        ("KHR_materials_anisotropy", "anisotropyStrength", json!(1.01)),
        ("KHR_materials_anisotropy", "anisotropyStrength", json!(-0.2)),
        ("KHR_materials_anisotropy", "anisotropyRotation", json!(null)),
        ("KHR_materials_anisotropy", "anisotropyTexture", json!({"index": 9})),
    ];
    for (ext, key, value) in bad {
        let mut doc = good.clone();
        doc["materials"][0]["extensions"][ext][key] = value.clone();
        let err = load_err(&doc);
        assert_names(&err, &["material 0", ext, key]);
        println!("{ext}.{key} = {value}: {err}");
    }
}

#[test]
fn iridescence_loads_and_bad_values_are_named() {
    let mut png = Vec::new();
    image::RgbaImage::from_raw(1, 1, vec![255, 128, 0, 255])
        .expect("image")
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .expect("encode");
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"][0]["material"] = json!(0);
    doc["extensionsUsed"] = json!(["KHR_materials_iridescence"]);
    doc["extensionsRequired"] = json!(["KHR_materials_iridescence"]);
    doc["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64::engine::general_purpose::STANDARD.encode(&png))}]);
    doc["textures"] = json!([{"source": 0}]);
    doc["materials"] = json!([{"name": "film", "extensions": {
        "KHR_materials_iridescence": {"iridescenceFactor": 0.7, "iridescenceTexture": {"index": 0},
            "iridescenceIor": 1.8, "iridescenceThicknessMinimum": 250.0,
            "iridescenceThicknessMaximum": 120.0, "iridescenceThicknessTexture": {"index": 0}}
    }}]);
    let scene = load(&doc).expect("loads");
    let i = scene.materials[0].iridescence.expect("iridescence");
    // The minimum may exceed the maximum (the spec allows it).
    assert_eq!((i.factor, i.ior, i.thickness_min, i.thickness_max), (0.7, 1.8, 250.0, 120.0));
    assert!(i.texture.is_some() && i.thickness_texture.is_some());

    // The spec's defaults; a factor of 0 (the default) disables the film.
    let good = doc.clone();
    doc["materials"][0]["extensions"]["KHR_materials_iridescence"] =
        json!({"iridescenceFactor": 1.0});
    let i = load(&doc).expect("loads").materials[0].iridescence.expect("iridescence");
    assert_eq!((i.factor, i.ior, i.thickness_min, i.thickness_max), (1.0, 1.3, 100.0, 400.0));
    doc["materials"][0]["extensions"]["KHR_materials_iridescence"] = json!({"iridescenceIor": 2.0});
    assert!(load(&doc).expect("loads").materials[0].iridescence.is_none());

    let bad = [
        ("iridescenceFactor", json!(1.5)),
        ("iridescenceFactor", json!(-0.1)),
        ("iridescenceFactor", json!("1")),
        ("iridescenceIor", json!(0.9)),
        ("iridescenceIor", json!(-1.3)),
        ("iridescenceThicknessMinimum", json!(-1.0)),
        ("iridescenceThicknessMaximum", json!(-400.0)),
        ("iridescenceThicknessMaximum", json!(1e300)),
        ("iridescenceTexture", json!({"index": 4})),
        ("iridescenceThicknessTexture", json!({"texCoord": 0})),
    ];
    for (key, value) in bad {
        let mut doc = good.clone();
        doc["materials"][0]["extensions"]["KHR_materials_iridescence"][key] = value.clone();
        let err = load_err(&doc);
        assert_names(&err, &["material 0", "KHR_materials_iridescence", key]);
        println!("{key} = {value}: {err}");
    }
}

#[test]
fn material_variants_swap_materials_and_unknown_names_are_listed() {
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["extensionsUsed"] = json!(["KHR_materials_variants"]);
    doc["extensions"] =
        json!({"KHR_materials_variants": {"variants": [{"name": "red"}, {"name": "blue"}]}});
    doc["materials"] = json!([
        {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.0, 0.0, 1.0]}},
        {"name": "blue", "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 1.0, 1.0]}}
    ]);
    let prim = &mut doc["meshes"][0]["primitives"][0];
    prim["material"] = json!(0);
    prim["extensions"] = json!({"KHR_materials_variants": {"mappings": [
        {"material": 1, "variants": [1]},
        {"material": 0, "variants": [0]}
    ]}});
    let scene = load(&doc).expect("loads");
    assert_eq!(scene.variants, ["red", "blue"]);
    let color = |s: &Scene| s.materials[s.meshes[0].material].name.clone();
    // The blue material is loaded though no mesh uses it by default.
    assert_eq!(color(&scene), "red");
    let mut blue = scene.clone();
    blue.apply_variant("blue").expect("a known variant");
    assert_eq!(color(&blue), "blue");
    let mut red = scene.clone();
    red.apply_variant("red").expect("a known variant");
    assert_eq!(color(&red), "red");
    let err = scene.clone().apply_variant("green").expect_err("an unknown variant");
    assert_names(&err, &["green", "red, blue"]);

    // Bad mappings and names are refused naming the extension and what is wrong.
    let bad = [
        (
            "/meshes/0/primitives/0/extensions/KHR_materials_variants/mappings/0/variants/0",
            json!(2),
        ),
        ("/meshes/0/primitives/0/extensions/KHR_materials_variants/mappings/0/material", json!(5)),
        ("/extensions/KHR_materials_variants/variants/1/name", json!("red")),
        ("/extensions/KHR_materials_variants/variants", json!({})),
    ];
    for (pointer, value) in bad {
        let mut doc = doc.clone();
        *doc.pointer_mut(pointer).expect("pointer") = value;
        let err = load_err(&doc);
        assert_names(&err, &["KHR_materials_variants"]);
        println!("{pointer}: {err}");
    }
}

/// `KHR_materials_pbrSpecularGlossiness` becomes the metallic-roughness model with
/// `KHR_materials_specular`: diffuse as base colour, metallic 0, roughness 1 - glossiness, the
/// specular colour as the reflectance at normal incidence (ior 0), the specular-glossiness
/// texture as the specular colour's texture and the glossiness's; the material's own
/// metallic-roughness values give way. Out-of-range factors are refused naming the key.
#[test]
fn specular_glossiness_becomes_metal_rough_with_specular() {
    let mut png = Vec::new();
    {
        let img = image::RgbaImage::from_raw(1, 1, vec![200, 100, 50, 128]).expect("image");
        img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).expect("encode");
    }
    let mut doc = triangle_doc(&TRIANGLE, &[0, 1, 2]);
    doc["meshes"][0]["primitives"] = json!([
        {"attributes": {"POSITION": 0}, "indices": 1, "material": 0},
        {"attributes": {"POSITION": 0}, "indices": 1, "material": 1}
    ]);
    doc["extensionsUsed"] = json!(["KHR_materials_pbrSpecularGlossiness"]);
    doc["materials"] = json!([
        {"name": "factors",
         "pbrMetallicRoughness": {"metallicFactor": 1.0, "roughnessFactor": 0.9, "metallicRoughnessTexture": {"index": 0}},
         "extensions": {"KHR_materials_pbrSpecularGlossiness": {
            "diffuseFactor": [0.5, 0.25, 1.0, 0.75], "specularFactor": [0.04, 0.5, 1.0], "glossinessFactor": 0.8}}},
        {"name": "textured",
         "extensions": {"KHR_materials_pbrSpecularGlossiness": {
            "diffuseTexture": {"index": 0, "texCoord": 1}, "specularGlossinessTexture": {"index": 0}}}}
    ]);
    doc["images"] = json!([{"uri": data_uri(&png)}]);
    doc["textures"] = json!([{"source": 0}]);
    let scene = load(&doc).expect("loads");
    let m = &scene.materials[0];
    assert_eq!(m.base_color, Vec4::new(0.5, 0.25, 1.0, 0.75));
    assert_eq!((m.metallic, m.roughness, m.ior, m.specular), (0.0, 1.0 - 0.8, 0.0, 1.0));
    assert_eq!(m.specular_color, Vec3::new(0.04, 0.5, 1.0));
    assert!(m.metallic_roughness_texture.is_none(), "the metal-rough values give way");
    assert!(m.glossiness_texture.is_none() && m.specular_color_texture.is_none());
    let t = &scene.materials[1];
    assert_eq!((t.base_color, t.roughness, t.specular_color), (Vec4::ONE, 0.0, Vec3::ONE));
    assert_eq!(t.base_color_texture.expect("diffuse texture").tex_coord, 1);
    assert_eq!(t.specular_color_texture, t.glossiness_texture);
    assert!(t.glossiness_texture.is_some());
    for (key, value) in [
        ("diffuseFactor", json!([0.5, 0.5, 0.5, 1.5])),
        ("diffuseFactor", json!([0.5, 0.5])),
        ("specularFactor", json!([2.0, 0.0, 0.0])),
        ("glossinessFactor", json!(-0.5)),
    ] {
        let mut bad = doc.clone();
        bad["materials"][0]["extensions"]["KHR_materials_pbrSpecularGlossiness"][key] = value;
        let e = load(&bad).expect_err(key);
        assert!(e.0.contains("KHR_materials_pbrSpecularGlossiness") && e.0.contains(key), "{e}");
    }
}
