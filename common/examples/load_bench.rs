//! The load time of compressed assets against uncompressed ones: the same mesh (a wavy grid of
//! about a million triangles with normals and texture coordinates) written plain, with
//! `EXT_meshopt_compression` and with `KHR_draco_mesh_compression`, and the same 2048x2048 image
//! as a quad's texture in PNG, JPEG and lossless WebP (`EXT_texture_webp`). Each file is written
//! to a temporary folder as a GLB and loaded with `common::gltf::load_path` (the loader's own
//! decoders, on one thread) `--rounds` times; it prints CSV: the file's bytes, the fastest and the
//! median load, and what was loaded: triangles and their total area (the same within the
//! quantisation, which checks the decoding), or texels (`docs/perf/large-scenes.md`).
//!
//! `cargo run --release -p common --example load_bench -- [--side 708] [--texture 2048]
//! [--rounds 5]`
//!
//! KTX2 (`KHR_texture_basisu`) is left out: the Basis Universal encoder this repository can build
//! writes `.basis` files, not KTX2 containers.

use std::{path::Path, time::Instant};

use serde_json::{json, Value};

/// A GLB of `json` with `bin` as its BIN chunk (buffer 0).
fn glb(mut json: Value, bin: Vec<u8>) -> Vec<u8> {
    json["buffers"][0]["byteLength"] = json!(bin.len());
    common::gltf::build_glb(&serde_json::to_vec(&json).expect("json"), Some(&bin))
}

/// The grid: `side` x `side` vertices over [-1, 1]², displaced in z, with its exact normals, its
/// coordinates as texture coordinates, and two triangles per cell.
struct Grid {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    indices: Vec<u32>,
}

fn grid(side: usize) -> Grid {
    let mut g = Grid { positions: vec![], normals: vec![], uvs: vec![], indices: vec![] };
    for y in 0..side {
        for x in 0..side {
            let (u, v) = (x as f32 / (side - 1) as f32, y as f32 / (side - 1) as f32);
            let (px, py) = (2.0 * u - 1.0, 2.0 * v - 1.0);
            let z = 0.1 * (7.0 * px).sin() * (5.0 * py).cos();
            let (dx, dy) = (
                0.7 * (7.0 * px).cos() * (5.0 * py).cos(),
                -0.5 * (7.0 * px).sin() * (5.0 * py).sin(),
            );
            let len = (dx * dx + dy * dy + 1.0f32).sqrt();
            g.positions.push([px, py, z]);
            g.normals.push([-dx / len, -dy / len, 1.0 / len]);
            g.uvs.push([u, v]);
        }
    }
    for y in 0..side as u32 - 1 {
        for x in 0..side as u32 - 1 {
            let a = y * side as u32 + x;
            let (b, c, d) = (a + 1, a + side as u32, a + side as u32 + 1);
            g.indices.extend([a, b, c, b, d, c]);
        }
    }
    g
}

fn bytes_of<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

/// The accessors of the grid: POSITION (with its bounds), NORMAL, TEXCOORD_0, indices, each on
/// the buffer view of its own number where `views` (else none: Draco's).
fn accessors(g: &Grid, views: bool) -> Value {
    let n = g.positions.len();
    let (lo, hi) = g.positions.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
        (std::array::from_fn(|k| lo[k].min(p[k])), std::array::from_fn(|k| hi[k].max(p[k])))
    });
    let mut a = vec![
        json!({"componentType": 5126, "count": n, "type": "VEC3", "min": lo, "max": hi}),
        json!({"componentType": 5126, "count": n, "type": "VEC3"}),
        json!({"componentType": 5126, "count": n, "type": "VEC2"}),
        json!({"componentType": 5125, "count": g.indices.len(), "type": "SCALAR"}),
    ];
    if views {
        for (i, a) in a.iter_mut().enumerate() {
            a["bufferView"] = json!(i);
        }
    }
    Value::Array(a)
}

fn document(accessors: Value, views: Value, primitive: Value, buffers: Value) -> Value {
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [primitive]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": buffers,
    })
}

fn plain_mesh(g: &Grid) -> Vec<u8> {
    let mut bin = Vec::new();
    let mut views = vec![];
    for (data, stride) in [
        (bytes_of(&g.positions), Some(12)),
        (bytes_of(&g.normals), Some(12)),
        (bytes_of(&g.uvs), Some(8)),
        (bytes_of(&g.indices), None),
    ] {
        let mut view = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": data.len()});
        if let Some(s) = stride {
            view["byteStride"] = json!(s);
        }
        views.push(view);
        bin.extend(data);
    }
    let primitive =
        json!({"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3});
    glb(document(accessors(g, true), Value::Array(views), primitive, json!([{}])), bin)
}

/// `EXT_meshopt_compression` as gltfpack writes it: the compressed streams in the BIN chunk
/// (buffer 0), the views over a fallback buffer without data (buffer 1), and the vertex codec's
/// format version 0, the one the extension specifies (meshoptimizer's encoder defaults to 1).
fn meshopt_mesh(g: &Grid) -> Vec<u8> {
    let n = g.positions.len();
    let vertices = |v: &[[f32; 3]]| meshopt::encode_vertex_buffer_level(v, 2, Some(0));
    let streams: [(Vec<u8>, usize, usize, usize, &str); 4] = [
        (vertices(&g.positions).expect("meshopt"), 12, n, n * 12, "ATTRIBUTES"),
        (vertices(&g.normals).expect("meshopt"), 12, n, n * 12, "ATTRIBUTES"),
        (
            meshopt::encode_vertex_buffer_level(&g.uvs, 2, Some(0)).expect("meshopt"),
            8,
            n,
            n * 8,
            "ATTRIBUTES",
        ),
        (
            meshopt::encode_index_buffer(&g.indices, n).expect("meshopt"),
            4,
            g.indices.len(),
            g.indices.len() * 4,
            "TRIANGLES",
        ),
    ];
    let (mut bin, mut views, mut fallback) = (Vec::new(), vec![], 0usize);
    for (data, stride, count, length, mode) in &streams {
        let mut view = json!({
            "buffer": 1, "byteOffset": fallback, "byteLength": length,
            "extensions": {"EXT_meshopt_compression": {
                "buffer": 0, "byteOffset": bin.len(), "byteLength": data.len(),
                "byteStride": stride, "count": count, "mode": mode
            }}
        });
        if *mode == "ATTRIBUTES" {
            view["byteStride"] = json!(stride);
        }
        views.push(view);
        bin.extend(data);
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        fallback += length;
    }
    let buffers = json!([{}, {"byteLength": fallback, "extensions": {"EXT_meshopt_compression": {"fallback": true}}}]);
    let primitive =
        json!({"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3});
    let mut doc = document(accessors(g, true), Value::Array(views), primitive, buffers);
    doc["extensionsUsed"] = json!(["EXT_meshopt_compression"]);
    doc["extensionsRequired"] = json!(["EXT_meshopt_compression"]);
    glb(doc, bin)
}

/// `KHR_draco_mesh_compression` at Draco's default speed, positions quantised to 14 bits,
/// normals to 10 and texture coordinates to 12 (gltf-transform's defaults).
fn draco_mesh(g: &Grid) -> Vec<u8> {
    use draco_core::{
        DataType, EncoderBuffer, EncoderOptions, FaceIndex, GeometryAttributeType, Mesh,
        MeshEncoder, PointAttribute,
    };
    let n = g.positions.len();
    let mut mesh = Mesh::new();
    for (kind, components, data) in [
        (GeometryAttributeType::Position, 3, bytes_of(&g.positions)),
        (GeometryAttributeType::Normal, 3, bytes_of(&g.normals)),
        (GeometryAttributeType::TexCoord, 2, bytes_of(&g.uvs)),
    ] {
        let mut attribute = PointAttribute::new();
        attribute.init(kind, components, DataType::Float32, false, n);
        attribute.buffer_mut().write(0, data);
        mesh.add_attribute(attribute);
    }
    mesh.set_num_faces(g.indices.len() / 3);
    for (f, t) in g.indices.chunks_exact(3).enumerate() {
        mesh.set_face(FaceIndex(f as u32), [t[0].into(), t[1].into(), t[2].into()]);
    }
    let mut options = EncoderOptions::new();
    for (attribute, bits) in [(0, 14), (1, 10), (2, 12)] {
        options.set_attribute_int(attribute, "quantization_bits", bits);
    }
    let mut encoder = MeshEncoder::new();
    encoder.set_mesh(mesh);
    let mut buffer = EncoderBuffer::new();
    encoder.encode(&options, &mut buffer).expect("draco encoding");
    let bin = buffer.data().to_vec();
    let views = json!([{"buffer": 0, "byteOffset": 0, "byteLength": bin.len()}]);
    let attributes = json!({"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2});
    let primitive = json!({
        "attributes": attributes, "indices": 3,
        "extensions": {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": attributes}}
    });
    let mut doc = document(accessors(g, false), views, primitive, json!([{}]));
    doc["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
    doc["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
    glb(doc, bin)
}

/// A `size` x `size` RGB image: smooth ramps and waves with a little noise, as a photograph's
/// texture is neither flat nor random.
fn image(size: u32) -> image::RgbImage {
    image::RgbImage::from_fn(size, size, |x, y| {
        let h =
            (x.wrapping_mul(0x9e37_79b9) ^ y.wrapping_mul(0x85eb_ca6b)).wrapping_mul(0xc2b2_ae35);
        let noise = (h >> 28) as f32;
        let (u, v) = (x as f32 / size as f32, y as f32 / size as f32);
        let wave = 0.5 + 0.5 * (40.0 * u + 10.0 * (6.0 * v).sin()).sin();
        image::Rgb([
            (200.0 * u + noise) as u8,
            (200.0 * v + noise) as u8,
            (220.0 * wave + noise) as u8,
        ])
    })
}

/// A textured quad whose image is `bytes` of `mime` (WebP through `EXT_texture_webp`).
fn textured_quad(bytes: &[u8], mime: &str) -> Vec<u8> {
    let positions: [[f32; 3]; 4] =
        [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]];
    let uvs: [[f32; 2]; 4] = [[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]];
    let indices: [u32; 6] = [0, 1, 2, 0, 2, 3];
    let mut bin = Vec::new();
    let mut views = vec![];
    for data in [bytes_of(&positions), bytes_of(&uvs), bytes_of(&indices), bytes] {
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": data.len()}));
        bin.extend(data);
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
    }
    let webp = mime == "image/webp";
    let texture = if webp {
        json!({"extensions": {"EXT_texture_webp": {"source": 0}}})
    } else {
        json!({"source": 0})
    };
    let mut doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [texture],
        "images": [{"bufferView": 3, "mimeType": mime}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1.0, -1.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5125, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": views,
        "buffers": [{}],
    });
    if webp {
        doc["extensionsUsed"] = json!(["EXT_texture_webp"]);
        doc["extensionsRequired"] = json!(["EXT_texture_webp"]);
    }
    glb(doc, bin)
}

fn encoded(img: &image::RgbImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    match format {
        image::ImageFormat::Jpeg => {
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
                .encode_image(img)
                .expect("jpeg")
        }
        image::ImageFormat::WebP => image::codecs::webp::WebPEncoder::new_lossless(&mut out)
            .encode(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
            .expect("webp"),
        _ => img.write_to(&mut out, format).expect("png"),
    }
    out.into_inner()
}

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map(|v| v.parse().expect("a number"))
        .unwrap_or(default)
}

/// Loads `path` `rounds` times: the fastest and the median seconds, and what it loaded (its
/// triangles, their total area, and its texels).
fn time_loads(path: &Path, rounds: usize) -> (f64, f64, usize, f64, usize) {
    let mut times = Vec::new();
    let (mut triangles, mut area, mut texels) = (0, 0.0, 0);
    for _ in 0..rounds {
        let start = Instant::now();
        let scene =
            common::gltf::load_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        times.push(start.elapsed().as_secs_f64());
        triangles = scene.triangle_count();
        area = scene
            .meshes
            .iter()
            .flat_map(|m| m.indices.iter().map(|t| t.map(|i| m.positions[i as usize].as_dvec3())))
            .map(|[a, b, c]| 0.5 * (b - a).cross(c - a).length())
            .sum();
        texels = scene.textures.iter().map(|t| t.width as usize * t.height as usize).sum();
    }
    times.sort_by(f64::total_cmp);
    (times[0], times[times.len() / 2], triangles, area, texels)
}

fn main() {
    let (side, size, rounds) =
        (arg("--side", 708), arg("--texture", 2048) as u32, arg("--rounds", 5));
    let dir = std::env::temp_dir().join(format!("renderfarm-load-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary folder");
    let g = grid(side);
    let img = image(size);
    let files: Vec<(&str, Vec<u8>)> = vec![
        ("mesh plain", plain_mesh(&g)),
        ("mesh EXT_meshopt_compression", meshopt_mesh(&g)),
        ("mesh KHR_draco_mesh_compression", draco_mesh(&g)),
        ("texture PNG", textured_quad(&encoded(&img, image::ImageFormat::Png), "image/png")),
        ("texture JPEG q90", textured_quad(&encoded(&img, image::ImageFormat::Jpeg), "image/jpeg")),
        (
            "texture WebP lossless",
            textured_quad(&encoded(&img, image::ImageFormat::WebP), "image/webp"),
        ),
    ];
    println!("file,bytes,load_min_s,load_median_s,triangles,area,texels");
    for (k, (name, bytes)) in files.iter().enumerate() {
        let path = dir.join(format!("{k}.glb"));
        std::fs::write(&path, bytes).expect("writing");
        let (min, median, triangles, area, texels) = time_loads(&path, rounds);
        println!("{name},{},{min:.4},{median:.4},{triangles},{area:.6},{texels}", bytes.len());
    }
    std::fs::remove_dir_all(&dir).ok();
}
