//! Scenes built in code for tests and benchmarks, as glTF JSON with the buffer in a `data:` URI.
//! Nothing here is read by the renderer itself.

use serde_json::json;

/// A floor lit by `n` small emitters: a 20 x 20 Lambertian floor (albedo 0.5, facing up) at
/// y = 0 and `n` quads of side 0.25 at y = 0.6 facing down (radiance 8, black, single-sided),
/// each its own node (so its own emitter), on a jittered grid over [-9, 9]², seen from above by
/// an orthographic camera that frames the floor. The positions come from a fixed hash of the
/// index, so the scene is the same on every call.
pub fn many_lights_gltf(n: usize) -> String {
    let floor: [[f32; 3]; 4] =
        [[-10.0, 0.0, -10.0], [10.0, 0.0, -10.0], [10.0, 0.0, 10.0], [-10.0, 0.0, 10.0]];
    // Counter-clockwise seen from below: the quad emits downward.
    let side = 0.125f32;
    let quad: [[f32; 3]; 4] =
        [[-side, 0.0, -side], [side, 0.0, -side], [side, 0.0, side], [-side, 0.0, side]];
    let mut bytes: Vec<u8> = Vec::new();
    for v in floor.iter().chain(&quad).flatten() {
        bytes.extend(v.to_le_bytes());
    }
    // Floor: seen from above counter-clockwise; quad: seen from below.
    for i in [0u16, 2, 1, 0, 3, 2, 0, 1, 2, 0, 2, 3] {
        bytes.extend(i.to_le_bytes());
    }
    let grid = (n as f64).sqrt().ceil() as usize;
    let cell = 18.0 / grid as f64;
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        // SplitMix64: a fixed sequence, so the scene is the same on every call.
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut nodes = vec![
        json!({"camera": 0, "translation": [0.0, 5.0, 0.0],
        "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}),
        json!({"mesh": 0}),
    ];
    for k in 0..n {
        let (i, j) = (k % grid, k / grid);
        let x = -9.0 + cell * (i as f64 + 0.15 + 0.7 * next());
        let z = -9.0 + cell * (j as f64 + 0.15 + 0.7 * next());
        nodes.push(json!({"mesh": 1, "translation": [x, 0.6, z]}));
    }
    let lambert = |color: f64, emission: f64| {
        json!({
            "pbrMetallicRoughness": {"baseColorFactor": [color, color, color, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "emissiveFactor": [1.0, 1.0, 1.0],
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0},
                           "KHR_materials_emissive_strength": {"emissiveStrength": emission}}
        })
    };
    let mut floor_material = lambert(0.5, 0.0);
    floor_material["emissiveFactor"] = json!([0.0, 0.0, 0.0]);
    floor_material["extensions"]
        .as_object_mut()
        .map(|e| e.remove("KHR_materials_emissive_strength"));
    let json = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 10.0, "ymag": 10.0, "znear": 0.01, "zfar": 100.0}}],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 2, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 1}, "indices": 3, "material": 1}]}
        ],
        "materials": [floor_material, lambert(0.0, 8.0)],
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_emissive_strength"],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-10.0, 0.0, -10.0], "max": [10.0, 0.0, 10.0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-side, 0.0, -side], "max": [side, 0.0, side]},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 12},
            {"buffer": 0, "byteOffset": 108, "byteLength": 12}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    json.to_string()
}

/// Standard base64 with padding.
fn base64(bytes: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(TABLE[(v >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}
