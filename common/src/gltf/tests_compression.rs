//! Compressed files. `EXT_meshopt_compression`: scenes compressed here with meshoptimizer's
//! encoders, and by gltfpack itself, load to the same geometry as their uncompressed source
//! (bit for bit without a filter, within the quantisation error with one), fallback buffers
//! without a uri are accepted, and corrupt, truncated or inconsistent streams, unknown modes and
//! filters, and views too large for the budget are refused with errors that name the buffer view
//! and the extension. `KHR_texture_basisu`: KTX2 images written by Basis Universal's `basisu`
//! (ETC1S, UASTC, UASTC with Zstandard) transcode to their source's texels within the codec's
//! error, damaged ones are refused naming the image, and the budget is charged from the header.
//! `KHR_draco_mesh_compression`: the Khronos sample Box's Draco variant loads to Box's triangles
//! within Draco's quantisation, and damaged streams are errors, never panics.

use base64::Engine as _;
use glam::{Vec2, Vec3};
use serde_json::{json, Value};

use super::*;
use crate::budget::SceneBudget;

fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
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

/// How one buffer view is stored in the compressed file.
#[derive(Clone, Copy)]
enum Packing {
    /// ATTRIBUTES of elements of the view's stride, no filter.
    Attributes,
    /// TRIANGLES (u16 or u32 indices).
    Triangles,
    /// INDICES (u16 or u32 indices).
    Indices,
    /// ATTRIBUTES, then the filter named; the view's bytes are already the filter's input.
    Filtered(&'static str),
}

/// A glTF file written twice: plain (buffer 0 holds the views' bytes) and compressed (buffer 0
/// holds the compressed streams, buffer 1 is a fallback buffer without a uri that the views
/// refer to).
#[derive(Default)]
struct Twin {
    plain: Vec<u8>,
    packed: Vec<u8>,
    plain_views: Vec<Value>,
    packed_views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Twin {
    /// A buffer view of `data`, `count` elements of `stride` bytes, stored as `packing` says.
    fn view(&mut self, data: &[u8], count: usize, stride: usize, packing: Packing) -> usize {
        assert_eq!(data.len(), count * stride);
        self.plain.resize(self.plain.len().div_ceil(4) * 4, 0);
        let offset = self.plain.len();
        self.plain.extend_from_slice(data);
        let encoded = encode(data, count, stride, packing);
        self.packed.resize(self.packed.len().div_ceil(4) * 4, 0);
        let packed_offset = self.packed.len();
        self.packed.extend_from_slice(&encoded);
        let (mode, filter) = match packing {
            Packing::Attributes => ("ATTRIBUTES", "NONE"),
            Packing::Triangles => ("TRIANGLES", "NONE"),
            Packing::Indices => ("INDICES", "NONE"),
            Packing::Filtered(f) => ("ATTRIBUTES", f),
        };
        let mut view = json!({"buffer": 0, "byteOffset": offset, "byteLength": data.len()});
        if matches!(packing, Packing::Attributes | Packing::Filtered(_)) {
            view["byteStride"] = json!(stride);
        }
        self.plain_views.push(view.clone());
        view["buffer"] = json!(1);
        view["extensions"] = json!({"EXT_meshopt_compression": {
            "buffer": 0, "byteOffset": packed_offset, "byteLength": encoded.len(),
            "byteStride": stride, "count": count, "mode": mode, "filter": filter
        }});
        self.packed_views.push(view);
        self.plain_views.len() - 1
    }

    /// An accessor over a new view (see [`Twin::view`]).
    #[allow(clippy::too_many_arguments)]
    fn accessor(
        &mut self,
        data: &[u8],
        count: usize,
        stride: usize,
        packing: Packing,
        component: u32,
        ty: &str,
        normalized: bool,
    ) -> usize {
        let view = self.view(data, count, stride, packing);
        self.accessors.push(json!({"bufferView": view, "componentType": component,
            "count": count, "type": ty, "normalized": normalized}));
        self.accessors.len() - 1
    }

    /// Both files around `doc` (its meshes and nodes): (plain, compressed).
    fn finish(&self, doc: Value) -> (Value, Value) {
        let mut plain = doc;
        plain["asset"] = json!({"version": "2.0"});
        plain["accessors"] = Value::Array(self.accessors.clone());
        let mut packed = plain.clone();
        plain["bufferViews"] = Value::Array(self.plain_views.clone());
        plain["buffers"] = json!([{"byteLength": self.plain.len(), "uri": data_uri(&self.plain)}]);
        packed["bufferViews"] = Value::Array(self.packed_views.clone());
        packed["buffers"] = json!([
            {"byteLength": self.packed.len(), "uri": data_uri(&self.packed)},
            {"byteLength": self.plain.len(), "extensions": {"EXT_meshopt_compression": {"fallback": true}}}
        ]);
        packed["extensionsUsed"] = json!(["EXT_meshopt_compression", "KHR_mesh_quantization"]);
        packed["extensionsRequired"] = json!(["EXT_meshopt_compression", "KHR_mesh_quantization"]);
        (plain, packed)
    }
}

/// One element of `N` bytes, for the encoder (which takes the element size from the type).
#[derive(Clone, Copy)]
struct Element<const N: usize>([u8; N]);

fn encode_elements<const N: usize>(data: &[u8]) -> Vec<u8> {
    let elements: Vec<Element<N>> =
        data.chunks_exact(N).map(|c| Element(c.try_into().expect("N bytes"))).collect();
    // Format version 0, the one EXT_meshopt_compression specifies.
    ::meshopt::encode_vertex_buffer_level(&elements, 2, Some(0)).expect("encodes")
}

fn encode(data: &[u8], count: usize, stride: usize, packing: Packing) -> Vec<u8> {
    let indices = || -> Vec<u32> {
        match stride {
            2 => data.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]]) as u32).collect(),
            _ => data.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect(),
        }
    };
    match packing {
        Packing::Triangles => {
            let i = indices();
            ::meshopt::encode_index_buffer(&i, count).expect("encodes")
        }
        Packing::Indices => ::meshopt::encode_index_sequence(&indices(), count).expect("encodes"),
        Packing::Attributes | Packing::Filtered(_) => match stride {
            4 => encode_elements::<4>(data),
            8 => encode_elements::<8>(data),
            12 => encode_elements::<12>(data),
            16 => encode_elements::<16>(data),
            _ => panic!("no test uses stride {stride}"),
        },
    }
}

fn bytes_of<T: Copy>(v: &[T], to: impl Fn(T) -> Vec<u8>) -> Vec<u8> {
    v.iter().flat_map(|&x| to(x)).collect()
}

fn f32s(v: &[f32]) -> Vec<u8> {
    bytes_of(v, |x: f32| x.to_le_bytes().to_vec())
}

/// A UV sphere of `rings x segments` quads: positions, unit normals, uvs, triangle indices.
fn sphere(rings: u32, segments: u32) -> (Vec<Vec3>, Vec<Vec3>, Vec<Vec2>, Vec<u32>) {
    let (mut p, mut n, mut uv, mut idx) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for r in 0..=rings {
        for s in 0..=segments {
            let (v, u) = (r as f32 / rings as f32, s as f32 / segments as f32);
            let (theta, phi) = (v * std::f32::consts::PI, u * std::f32::consts::TAU);
            let d = Vec3::new(theta.sin() * phi.cos(), theta.cos(), theta.sin() * phi.sin());
            p.push(d * 2.5 + Vec3::new(0.1, -0.3, 7.0));
            n.push(d.normalize());
            uv.push(Vec2::new(u, v));
        }
    }
    for r in 0..rings {
        for s in 0..segments {
            let a = r * (segments + 1) + s;
            let b = a + segments + 1;
            idx.extend([a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    (p, n, uv, idx)
}

fn mesh_doc(primitives: Value) -> Value {
    json!({"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": primitives}]})
}

/// Lossless packings (no filter): the compressed file loads to exactly the plain file's scene,
/// with u16 and u32 indices, TRIANGLES and INDICES, interleaved and separate attributes.
#[test]
fn meshopt_without_filter_loads_bit_for_bit() {
    let (p, n, uv, idx) = sphere(12, 20);
    let count = p.len();
    let mut twin = Twin::default();
    // Primitive 0: separate float attributes, u16 TRIANGLES.
    let pos = twin.accessor(
        &f32s(&p.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>()),
        count,
        12,
        Packing::Attributes,
        5126,
        "VEC3",
        false,
    );
    let nrm = twin.accessor(
        &f32s(&n.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>()),
        count,
        12,
        Packing::Attributes,
        5126,
        "VEC3",
        false,
    );
    let tex = twin.accessor(
        &f32s(&uv.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>()),
        count,
        8,
        Packing::Attributes,
        5126,
        "VEC2",
        false,
    );
    let i16s = bytes_of(&idx, |i: u32| (i as u16).to_le_bytes().to_vec());
    let tri16 = twin.accessor(&i16s, idx.len(), 2, Packing::Triangles, 5123, "SCALAR", false);
    // Primitive 1: u32 INDICES over the same attributes.
    let i32s = bytes_of(&idx, |i: u32| i.to_le_bytes().to_vec());
    let seq32 = twin.accessor(&i32s, idx.len(), 4, Packing::Indices, 5125, "SCALAR", false);
    // Primitive 2: u32 TRIANGLES; positions (three floats) and uvs (two normalised u16)
    // interleaved in one view of stride 16.
    let mut interleaved = Vec::new();
    for (q, t) in p.iter().zip(&uv) {
        interleaved.extend(f32s(&q.to_array()));
        interleaved.extend(((t.x * 65535.0).round() as u16).to_le_bytes());
        interleaved.extend(((t.y * 65535.0).round() as u16).to_le_bytes());
    }
    let view = twin.view(&interleaved, count, 16, Packing::Attributes);
    twin.accessors
        .push(json!({"bufferView": view, "componentType": 5126, "count": count, "type": "VEC3"}));
    let ipos = twin.accessors.len() - 1;
    twin.accessors.push(json!({"bufferView": view, "byteOffset": 12, "componentType": 5123, "normalized": true, "count": count, "type": "VEC2"}));
    let iuv = twin.accessors.len() - 1;
    let tri32 = twin.accessor(&i32s, idx.len(), 4, Packing::Triangles, 5125, "SCALAR", false);
    let (plain, packed) = twin.finish(mesh_doc(json!([
        {"attributes": {"POSITION": pos, "NORMAL": nrm, "TEXCOORD_0": tex}, "indices": tri16},
        {"attributes": {"POSITION": pos, "NORMAL": nrm, "TEXCOORD_0": tex}, "indices": seq32},
        {"attributes": {"POSITION": ipos, "TEXCOORD_0": iuv}, "indices": tri32}
    ])));
    let a = load(&plain).expect("plain file");
    let b = load(&packed).expect("compressed file");
    assert_eq!(a.meshes.len(), 3);
    assert_eq!(a.meshes[0].indices.len(), 12 * 20 * 2);
    for (ma, mb) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(ma.positions, mb.positions, "{}", ma.name);
        assert_eq!(ma.normals, mb.normals, "{}", ma.name);
        assert_eq!(ma.uvs, mb.uvs, "{}", ma.name);
        assert_eq!(ma.indices, mb.indices, "{}", ma.name);
    }
    assert_eq!(a.meshes[0].positions, p, "the plain file holds the sphere");
    // The compressed streams are smaller than what they decode to.
    let plain_len = plain["buffers"][0]["byteLength"].as_u64().unwrap();
    let packed_len = packed["buffers"][0]["byteLength"].as_u64().unwrap();
    assert!(packed_len < plain_len, "{packed_len} >= {plain_len}");
}

/// Filters (octahedral 8 and 16 bits, exponential, quaternion): the loaded values are the source's
/// within the quantisation error of the encoding.
#[test]
fn meshopt_filters_decode_within_the_quantisation_error() {
    let (p, n, uv, idx) = sphere(10, 16);
    let count = p.len();
    let mut twin = Twin::default();
    // Positions: exponential, 15-bit mantissas sharing one exponent per vector.
    let exp = ::meshopt::encode_filter_exp(
        &p.iter().map(|v| v.to_array()).collect::<Vec<_>>(),
        15,
        ::meshopt::EncodeExpMode::SharedVector,
    );
    let pos = twin.accessor(
        &bytes_of(exp.as_flattened(), |x: u32| x.to_le_bytes().to_vec()),
        count,
        12,
        Packing::Filtered("EXPONENTIAL"),
        5126,
        "VEC3",
        false,
    );
    // Normals: octahedral, 8 bits (normalised bytes, stride 4) and 16 bits (shorts, stride 8).
    let n4: Vec<[f32; 4]> = n.iter().map(|v| v.extend(0.0).to_array()).collect();
    let oct8: Vec<[i8; 4]> = ::meshopt::encode_filter_oct(&n4, 8);
    let nrm8 = twin.accessor(
        &bytes_of(oct8.as_flattened(), |x: i8| vec![x as u8]),
        count,
        4,
        Packing::Filtered("OCTAHEDRAL"),
        5120,
        "VEC3",
        true,
    );
    let oct16: Vec<[i16; 4]> = ::meshopt::encode_filter_oct(&n4, 16);
    let nrm16 = twin.accessor(
        &bytes_of(oct16.as_flattened(), |x: i16| x.to_le_bytes().to_vec()),
        count,
        8,
        Packing::Filtered("OCTAHEDRAL"),
        5122,
        "VEC3",
        true,
    );
    let tex = twin.accessor(
        &f32s(&uv.iter().flat_map(|v| v.to_array()).collect::<Vec<_>>()),
        count,
        8,
        Packing::Attributes,
        5126,
        "VEC2",
        false,
    );
    let tri = twin.accessor(
        &bytes_of(&idx, |i: u32| (i as u16).to_le_bytes().to_vec()),
        idx.len(),
        2,
        Packing::Triangles,
        5123,
        "SCALAR",
        false,
    );
    // Quaternions (instance rotations, EXT_mesh_gpu_instancing): 12-bit components.
    let quats: Vec<[f32; 4]> = (0..16)
        .map(|k| {
            let axis = Vec3::new(1.0, k as f32 - 7.5, 0.3 * k as f32).normalize();
            glam::Quat::from_axis_angle(axis, 0.4 * k as f32).to_array()
        })
        .collect();
    let q = ::meshopt::encode_filter_quat(&quats, 12);
    let rot = twin.accessor(
        &bytes_of(q.as_flattened(), |x: i16| x.to_le_bytes().to_vec()),
        quats.len(),
        8,
        Packing::Filtered("QUATERNION"),
        5122,
        "VEC4",
        true,
    );
    let (_, mut packed) = twin.finish(mesh_doc(json!([
        {"attributes": {"POSITION": pos, "NORMAL": nrm8, "TEXCOORD_0": tex}, "indices": tri},
        {"attributes": {"POSITION": pos, "NORMAL": nrm16}, "indices": tri}
    ])));
    packed["nodes"][0]["extensions"] =
        json!({"EXT_mesh_gpu_instancing": {"attributes": {"ROTATION": rot}}});
    packed["extensionsUsed"].as_array_mut().unwrap().push(json!("EXT_mesh_gpu_instancing"));
    let s = load(&packed).expect("compressed file");
    let (m8, m16) = (&s.meshes[0], &s.meshes[1]);
    assert_eq!(m8.indices.len() * 3, idx.len());
    for (i, src) in p.iter().enumerate() {
        let err = (m8.positions[i] - *src).abs().max_element();
        // 15 mantissa bits for the largest component (at most ~9.5 here).
        assert!(err <= 9.5 / (1 << 14) as f32, "position {i}: {} vs {src}", m8.positions[i]);
    }
    let (n8, n16) = (m8.normals.as_ref().unwrap(), m16.normals.as_ref().unwrap());
    // The sine of the worst angle (f32's arccosine cannot tell angles under ~5e-4 rad apart).
    let worst =
        |got: &[Vec3]| got.iter().zip(&n).map(|(g, w)| g.cross(*w).length()).fold(0.0, f32::max);
    // 8-bit octahedral: about a degree; 16-bit: hundredths of one.
    assert!(worst(n8) < 0.02, "8-bit octahedral normals off by {} rad", worst(n8));
    assert!(worst(n16) < 2e-4, "16-bit octahedral normals off by {} rad", worst(n16));
    assert!(worst(n8) > 0.0, "the 8-bit encoding is lossy: the test must see it");
    assert_eq!(m8.uvs[0].as_ref().unwrap(), &uv, "the unfiltered uvs are exact");
    // The instances' rotations: q and -q are the same rotation.
    assert_eq!(s.instances.len(), 2 * quats.len());
    for (k, want) in quats.iter().enumerate() {
        let got = s.instances.iter().filter(|i| i.mesh == 0).nth(k).expect("instance");
        let (_, r, _) = got.offset.to_scale_rotation_translation();
        let want = glam::DQuat::from_array(want.map(f64::from));
        let d = r.dot(want).abs();
        assert!(d > 1.0 - 1e-5, "instance {k}: rotation {r:?} vs {want:?}");
    }
}

/// The smallest compressed file: one triangle, positions as ATTRIBUTES, u16 TRIANGLES.
fn compressed_triangle() -> Value {
    let mut twin = Twin::default();
    let p = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let pos = twin.accessor(&f32s(&p), 3, 12, Packing::Attributes, 5126, "VEC3", false);
    let idx = twin.accessor(&[0, 0, 1, 0, 2, 0], 3, 2, Packing::Triangles, 5123, "SCALAR", false);
    twin.finish(mesh_doc(json!([{"attributes": {"POSITION": pos}, "indices": idx}]))).1
}

fn ext_of(doc: &mut Value, view: usize) -> &mut Value {
    &mut doc["bufferViews"][view]["extensions"]["EXT_meshopt_compression"]
}

/// A fallback buffer without a uri is accepted when only compressed views refer to it; a plain
/// view that reads it gets an error naming the extension.
#[test]
fn meshopt_fallback_buffers() {
    let doc = compressed_triangle();
    assert!(doc["buffers"][1].get("uri").is_none());
    let s = load(&doc).expect("fallback buffer without a uri");
    assert_eq!(s.meshes[0].indices, vec![[0, 1, 2]]);
    assert_eq!(s.meshes[0].positions[2], Vec3::Y);
    // A view without the extension on the fallback buffer.
    let mut bad = doc.clone();
    bad["bufferViews"][0]["extensions"] = json!({});
    assert_names(
        &load_err(&bad),
        &["accessor 0", "buffer 1", "EXT_meshopt_compression", "fallback"],
    );
    // Compressed bytes taken from the fallback buffer itself.
    let mut bad = doc;
    ext_of(&mut bad, 0)["buffer"] = json!(1);
    assert_names(
        &load_err(&bad),
        &["buffer view 0", "EXT_meshopt_compression", "buffer 1", "fallback"],
    );
}

/// Corrupt and truncated streams, wrong counts and strides, unknown modes and filters: errors that
/// name the view and the extension; random damage never panics.
#[test]
fn meshopt_bad_streams_are_named() {
    let doc = compressed_triangle();
    let view_err = |edit: &dyn Fn(&mut Value), parts: &[&str]| {
        let mut bad = doc.clone();
        edit(&mut bad);
        let e = load_err(&bad);
        assert_names(&e, &["EXT_meshopt_compression"]);
        assert_names(&e, parts);
    };
    // Truncated: the stream cut short (vertex stream, then index stream).
    view_err(
        &|d| ext_of(d, 0)["byteLength"] = json!(10),
        &["buffer view 0", "ATTRIBUTES", "truncated"],
    );
    view_err(&|d| ext_of(d, 1)["byteLength"] = json!(3), &["buffer view 1", "TRIANGLES"]);
    // Corrupt header byte.
    let corrupt = |d: &mut Value| {
        let uri = d["buffers"][0]["uri"].as_str().unwrap().to_string();
        let b64 = uri.split(',').nth(1).unwrap();
        let mut bytes = base64::engine::general_purpose::STANDARD.decode(b64).unwrap();
        bytes[0] = 0x55;
        d["buffers"][0]["uri"] = json!(data_uri(&bytes));
    };
    view_err(&corrupt, &["buffer view 0", "header"]);
    // Wrong counts: not the view's byteLength, or one the stream does not hold.
    view_err(&|d| ext_of(d, 0)["count"] = json!(4), &["buffer view 0", "count 4", "byteLength 36"]);
    view_err(
        &|d| {
            ext_of(d, 0)["count"] = json!(300);
            d["bufferViews"][0]["byteLength"] = json!(3600);
        },
        &["buffer view 0", "ATTRIBUTES"],
    );
    view_err(&|d| ext_of(d, 1)["count"] = json!(4), &["buffer view 1", "count 4"]);
    // Strides the mode or filter does not allow, or that differ from the view's.
    view_err(&|d| ext_of(d, 0)["byteStride"] = json!(6), &["buffer view 0", "byteStride 6"]);
    view_err(
        &|d| d["bufferViews"][0]["byteStride"] = json!(16),
        &["buffer view 0", "byteStride 16"],
    );
    view_err(&|d| ext_of(d, 0)["filter"] = json!("QUATERNION"), &["byteStride 12", "QUATERNION"]);
    view_err(&|d| ext_of(d, 1)["filter"] = json!("OCTAHEDRAL"), &["TRIANGLES takes no filter"]);
    // Unknown mode and filter, missing fields, a compressed range outside its buffer.
    view_err(
        &|d| ext_of(d, 0)["mode"] = json!("STRIPS"),
        &["buffer view 0", "unknown mode \"STRIPS\""],
    );
    view_err(
        &|d| ext_of(d, 0)["filter"] = json!("COLOR"),
        &["buffer view 0", "unknown filter \"COLOR\""],
    );
    view_err(&|d| ext_of(d, 0)["mode"] = json!(0), &["buffer view 0", "mode"]);
    view_err(
        &|d| {
            ext_of(d, 0).as_object_mut().unwrap().remove("count");
        },
        &["count is missing"],
    );
    view_err(
        &|d| ext_of(d, 0)["byteOffset"] = json!(1u64 << 40),
        &["buffer view 0", "overrun buffer 0"],
    );
    view_err(&|d| ext_of(d, 0)["buffer"] = json!(7), &["buffer 7", "does not exist"]);

    // Random damage to the compressed bytes: an error or a scene, never a panic.
    let uri = doc["buffers"][0]["uri"].as_str().unwrap().to_string();
    let bytes =
        base64::engine::general_purpose::STANDARD.decode(uri.split(',').nth(1).unwrap()).unwrap();
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..500 {
        let mut damaged = bytes.clone();
        for _ in 0..3 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let at = (state % damaged.len() as u64) as usize;
            damaged[at] ^= (state >> 32) as u8 | 1;
        }
        let mut d = doc.clone();
        d["buffers"][0]["uri"] = json!(data_uri(&damaged));
        let _ = load(&d);
    }
}

/// A view's decoded size is charged to the budget from its JSON, before anything is decoded.
#[test]
fn meshopt_views_are_charged_before_decoding() {
    let mut doc = compressed_triangle();
    // Claims 16 M elements of 256 bytes (4 GiB) from a 40-byte stream.
    ext_of(&mut doc, 0)["count"] = json!(1u64 << 24);
    ext_of(&mut doc, 0)["byteStride"] = json!(256);
    doc["bufferViews"][0]["byteLength"] = json!(256u64 << 24);
    doc["bufferViews"][0]["byteStride"] = json!(256);
    doc["buffers"][1]["byteLength"] = json!(256u64 << 24);
    let e = load_err(&doc);
    assert_names(&e, &["buffer view 0", "bytes unpacked", "--max-scene-mib"]);
    // Within the budget, the decoded size is what is charged.
    let doc = compressed_triangle();
    let budget = SceneBudget { inflated_bytes: 36 + 6 - 1, ..SceneBudget::default() };
    let e = load_slice_within(doc.to_string().as_bytes(), &NoFiles, &budget).expect_err("tight");
    assert_names(&e.0, &["buffer view 1", "42 bytes unpacked"]);
    let budget = SceneBudget { inflated_bytes: 36 + 6, ..SceneBudget::default() };
    load_slice_within(doc.to_string().as_bytes(), &NoFiles, &budget).expect("fits");
}

/// A scene's triangles in world space: three (position, normal) corners each.
fn world_triangles(s: &Scene) -> Vec<[(Vec3, Vec3); 3]> {
    let mut out = Vec::new();
    for inst in &s.instances {
        let mesh = &s.meshes[inst.mesh];
        let normals = mesh.normals.as_ref().expect("normals");
        let m = inst.transform;
        for t in &mesh.indices {
            out.push(t.map(|i| {
                let p = m.transform_point3(mesh.positions[i as usize].as_dvec3()).as_vec3();
                let n = m.transform_vector3(normals[i as usize].as_dvec3()).normalize().as_vec3();
                (p, n)
            }));
        }
    }
    out
}

/// Box's triangles match `want`'s (the same winding, in any order, from any corner) within
/// `dp` in position and `dn` in normal, each exactly once.
fn assert_same_triangles(what: &str, got: &Scene, want: &Scene, dp: f32, dn: f32) {
    let (got, want) = (world_triangles(got), world_triangles(want));
    assert_eq!(got.len(), want.len(), "{what}");
    let close = |a: &[(Vec3, Vec3); 3], b: &[(Vec3, Vec3); 3]| {
        (0..3).any(|r| {
            (0..3).all(|k| {
                let (pa, na) = a[k];
                let (pb, nb) = b[(k + r) % 3];
                (pa - pb).abs().max_element() <= dp && (na - nb).abs().max_element() <= dn
            })
        })
    };
    for (i, w) in want.iter().enumerate() {
        let matches = got.iter().filter(|g| close(w, g)).count();
        assert_eq!(matches, 1, "{what}: triangle {i} {w:?} is matched {matches} times");
    }
}

/// The Khronos sample Box's Draco variant (`real/Box/glTF-Draco`, written by the glTF pipeline's
/// Draco encoder) loads to Box's triangles within its quantisation (positions on 14 bits over
/// the unit box, normals on 10); damaged streams are errors naming the extension, never panics;
/// the decoded size is charged to the budget before decoding.
#[test]
fn draco_box_loads_to_box() {
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets/real/Box");
    let source = load_path(&assets.join("glTF/Box.gltf")).expect("Box.gltf");
    let draco = load_path(&assets.join("glTF-Draco/Box.gltf")).expect("Box-Draco");
    assert_same_triangles("Box-Draco", &draco, &source, 1e-4, 2e-3);

    // The stream damaged at random, in a copy with its buffer inlined.
    let dir = assets.join("glTF-Draco");
    let mut doc: Value =
        serde_json::from_slice(&std::fs::read(dir.join("Box.gltf")).expect("gltf")).expect("json");
    let bin = std::fs::read(dir.join(doc["buffers"][0]["uri"].as_str().unwrap())).expect("bin");
    let ext = doc["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"].clone();
    let view = &doc["bufferViews"][ext["bufferView"].as_u64().unwrap() as usize];
    let at = view["byteOffset"].as_u64().unwrap_or(0) as usize;
    let len = view["byteLength"].as_u64().unwrap() as usize;
    doc["buffers"][0]["uri"] = json!(data_uri(&bin));
    load(&doc).expect("inlined");
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let (mut errors, mut loaded) = (0, 0);
    for i in 0..2000 {
        let mut damaged = bin.clone();
        for _ in 0..1 + i % 3 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            damaged[at + (state % len as u64) as usize] ^= (state >> 40) as u8 | 1;
        }
        let mut d = doc.clone();
        d["buffers"][0]["uri"] = json!(data_uri(&damaged));
        match load(&d) {
            Ok(_) => loaded += 1,
            Err(e) => {
                errors += 1;
                assert!(e.0.contains("KHR_draco_mesh_compression") || e.0.contains("index"), "{e}");
            }
        }
    }
    assert!(errors > 0, "{loaded} loaded, {errors} refused");
    // A stream cut short; an attribute id the stream lacks.
    let mut cut = doc.clone();
    cut["bufferViews"][ext["bufferView"].as_u64().unwrap() as usize]["byteLength"] = json!(len / 2);
    assert_names(&load_err(&cut), &["mesh 0 primitive 0", "KHR_draco_mesh_compression", "decode"]);
    let mut bad = doc.clone();
    bad["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]["attributes"]
        ["NORMAL"] = json!(9);
    assert_names(&load_err(&bad), &["KHR_draco_mesh_compression", "no attribute 9"]);
    // Too small a budget for the accessors' sizes: refused before decoding.
    let budget = SceneBudget { inflated_bytes: 100, ..SceneBudget::default() };
    let e = load_slice_within(doc.to_string().as_bytes(), &NoFiles, &budget).expect_err("budget");
    assert_names(&e.0, &["KHR_draco_mesh_compression", "bytes unpacked", "24 points"]);
}

/// Files written by the real gltfpack (`tests/assets/gltfpack/`, Box compressed with its
/// filters) load to Box's triangles (the same winding, in any order, from any corner) within
/// the quantisation error.
#[test]
fn meshopt_files_from_gltfpack_load_to_their_source() {
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets");
    let source = load_path(&assets.join("real/Box/glTF/Box.gltf")).expect("Box.gltf");
    let want = world_triangles(&source);
    assert_eq!(want.len(), 12);
    // (file, position tolerance: 14-bit over the unit box, or 12 float mantissa bits; normal
    // tolerance: 8- or 12-bit octahedral; the box's normals are axis-aligned, so nearly exact).
    for (file, dp, dn) in [("Box-cc.glb", 1e-4, 1e-2), ("Box-cc-vpf-vn12.glb", 2e-4, 1e-3)] {
        let s = load_path(&assets.join("gltfpack").join(file))
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let got = world_triangles(&s);
        assert_eq!(got.len(), want.len(), "{file}");
        let close = |a: &[(Vec3, Vec3); 3], b: &[(Vec3, Vec3); 3]| {
            (0..3).any(|r| {
                (0..3).all(|k| {
                    let (pa, na) = a[k];
                    let (pb, nb) = b[(k + r) % 3];
                    (pa - pb).abs().max_element() <= dp && (na - nb).abs().max_element() <= dn
                })
            })
        };
        for (i, w) in want.iter().enumerate() {
            let matches = got.iter().filter(|g| close(w, g)).count();
            assert_eq!(matches, 1, "{file}: Box triangle {i} {w:?} is matched {matches} times");
        }
    }
}

fn ktx2_asset(name: &str) -> Vec<u8> {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/assets/ktx2").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A triangle whose material's base colour is texture 0: the KTX2 `ktx2` by
/// `KHR_texture_basisu` (image 0), with a 2x2 PNG fallback (image 1).
fn ktx2_doc(ktx2: &[u8]) -> Value {
    let positions = f32s(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&[9; 16], 2, 2, image::ExtendedColorType::Rgba8)
        .expect("png");
    let uri = |mime: &str, bytes: &[u8]| {
        format!("data:{mime};base64,{}", base64::engine::general_purpose::STANDARD.encode(bytes))
    };
    json!({
        "asset": {"version": "2.0"},
        "extensionsUsed": ["KHR_texture_basisu"],
        "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 1, "extensions": {"KHR_texture_basisu": {"source": 0}}}],
        "images": [{"uri": uri("image/ktx2", ktx2)}, {"uri": uri("image/png", &png)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": data_uri(&positions)}]
    })
}

fn ktx2_texels(doc: &Value) -> Vec<[u8; 4]> {
    let s = load(doc).expect("loads");
    let t = &s.textures[0];
    assert_eq!((t.width, t.height), (32, 32), "the KTX2 image, not the 2x2 fallback");
    t.texels.rgba8().expect("8-bit").to_vec()
}

use image::ImageEncoder as _;

/// ETC1S, UASTC and UASTC with Zstandard, written by `basisu` from `gradient.png` (an RGBA
/// gradient with an alpha checkerboard): each transcodes to the source's texels within the
/// codec's error, alpha included; the Zstandard file to exactly the texels of the plain UASTC
/// one (the same blocks), and a KTX2 without a fallback loads as well.
#[test]
fn ktx2_textures_transcode_to_their_source_texels() {
    let source = image::load_from_memory(&ktx2_asset("gradient.png")).expect("png").into_rgba8();
    let source: Vec<[u8; 4]> = source.pixels().map(|p| p.0).collect();
    let mut uastc = Vec::new();
    // (file, mean and largest absolute error per channel allowed: ETC1S is a low-bitrate codec,
    // UASTC a high-quality one).
    for (file, mean, max) in
        [("etc1s.ktx2", 12.0, 96), ("uastc.ktx2", 4.0, 28), ("uastc-zstd.ktx2", 4.0, 28)]
    {
        let texels = ktx2_texels(&ktx2_doc(&ktx2_asset(file)));
        let diffs: Vec<i32> = texels
            .iter()
            .zip(&source)
            .flat_map(|(a, b)| (0..4).map(move |c| (a[c] as i32 - b[c] as i32).abs()))
            .collect();
        let got_mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
        let got_max = *diffs.iter().max().unwrap();
        println!("{file}: mean abs error {got_mean:.3}, largest {got_max}");
        assert!(got_mean <= mean && got_max <= max, "{file}: mean {got_mean}, max {got_max}");
        assert!(texels.iter().any(|t| t[3] < 255), "{file}: alpha is kept");
        if file.starts_with("uastc") {
            uastc.push(texels);
        }
    }
    assert_eq!(uastc[0], uastc[1], "Zstandard changes the storage, not the blocks");
    // ETC1S exactly as basisu itself unpacks it (through ETC2 RGBA, which holds ETC1S's colour
    // and alpha blocks without loss).
    let etc1s = ktx2_texels(&ktx2_doc(&ktx2_asset("etc1s.ktx2")));
    let unpacked = image::load_from_memory(&ktx2_asset("etc1s-unpacked-by-basisu.png"))
        .expect("png")
        .into_rgba8();
    assert!(etc1s.iter().zip(unpacked.pixels()).all(|(a, b)| *a == b.0), "ETC1S as basisu");
    // No fallback at all: the texture has only the extension's source.
    let mut only = ktx2_doc(&ktx2_asset("etc1s.ktx2"));
    only["textures"][0].as_object_mut().unwrap().remove("source");
    only["images"].as_array_mut().unwrap().pop();
    ktx2_texels(&only);
}

/// Damaged KTX2 files are refused naming the image and the extension; random damage is an
/// error or a texture, never a panic; the texels are charged from the header before anything
/// is decoded, so that a header claiming a huge image costs nothing.
#[test]
fn ktx2_damage_and_budget() {
    let err = |bytes: &[u8]| -> String {
        let e = load_err(&ktx2_doc(bytes));
        assert_names(&e, &["image 0", "KHR_texture_basisu"]);
        e
    };
    for file in ["etc1s.ktx2", "uastc.ktx2", "uastc-zstd.ktx2"] {
        let good = ktx2_asset(file);
        // Cut short: the container no longer holds its levels.
        err(&good[..good.len() - 10]);
        err(&good[..100]);
        // Not Basis Universal: an RGBA8 vkFormat.
        let mut raw = good.clone();
        raw[12..16].copy_from_slice(&37u32.to_le_bytes());
        assert_names(&err(&raw), &["vkFormat"]);
        // Too large a side, and a header claiming more texels than the budget.
        let mut big = good.clone();
        big[20..24].copy_from_slice(&16385u32.to_le_bytes());
        assert_names(&err(&big), &["16385", "at most 16384"]);
        let mut huge = good.clone();
        huge[20..28].copy_from_slice(&[0, 64, 0, 0, 0, 64, 0, 0]);
        assert_names(&load_err(&ktx2_doc(&huge)), &["image 0, 16384x16384", "decoded texels"]);
        // The level's bytes damaged at random.
        let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ good.len() as u64;
        let level_at = u64::from_le_bytes(good[80..88].try_into().unwrap()) as usize;
        for _ in 0..300 {
            let mut damaged = good.clone();
            for _ in 0..4 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let at = (state % damaged.len() as u64) as usize;
                damaged[at] ^= (state >> 40) as u8 | 1;
            }
            let _ = load(&ktx2_doc(&damaged));
            // Damage within the level data only (the headers intact).
            let mut level = good.clone();
            let at = level_at + (state % (good.len() - level_at) as u64) as usize;
            level[at] ^= 0x5a;
            let _ = load(&ktx2_doc(&level));
        }
    }
    // A Zstandard level that does not inflate.
    let mut zstd = ktx2_asset("uastc-zstd.ktx2");
    let level_at = u64::from_le_bytes(zstd[80..88].try_into().unwrap()) as usize;
    zstd[level_at..level_at + 4].copy_from_slice(b"junk");
    assert_names(&err(&zstd), &["Zstandard"]);
    // A budget one texel short refuses the image from its header.
    let budget = SceneBudget { texels: 32 * 32 - 1, ..SceneBudget::default() };
    let doc = ktx2_doc(&ktx2_asset("etc1s.ktx2")).to_string();
    let e = load_slice_within(doc.as_bytes(), &NoFiles, &budget).expect_err("over budget");
    assert_names(&e.0, &["image 0, 32x32", "decoded texels"]);
}
