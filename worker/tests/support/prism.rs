//! A rainbow with a closed form: sunlight (a directional light) through a dispersive glass
//! prism onto a white Lambertian floor, seen from straight above.
//!
//! The prism is an equilateral triangle in the x-y plane (side `SIDE`, apex up, base at height
//! `BASE_Y`) drawn out along z over +-`HALF_LENGTH`; the light travels up and to the right, in the
//! x-y plane, at `ELEVATION_DEG` above the horizon, so that it meets the prism's left face and its
//! base, and each wavelength leaves the right face as a parallel beam bent down to the floor at
//! its own angle (blue more than red). The camera's view lies within the prism's length, so every
//! row of the image is the same and the image is a profile along x. With `max_depth` 3 the only
//! light on the floor came in through one face and out through another, or was reflected off the
//! base outside (a light ray that reflects inside the prism needs a fourth bounce), so the
//! profile is a sum over the entry points of both lit faces and over wavelengths of the flux each
//! carries, Fresnel-transmitted twice or reflected once, to where it lands (`expected`).

use worker::render::{bsdf::fresnel_dielectric, spectrum};

use super::base64;

/// The prism's side, the height of its base and its half length along z.
pub const SIDE: f64 = 0.3;
pub const BASE_Y: f64 = 0.6;
pub const HALF_LENGTH: f64 = 0.9;
/// The glass: index at 587.6 nm and `KHR_materials_dispersion` (20 / Abbe number).
pub const IOR: f64 = 1.5;
pub const DISPERSION: f64 = 2.0;
/// The sunlight's direction of travel above the horizon (the prism's minimum deviation near
/// 550 nm) and its irradiance.
pub const ELEVATION_DEG: f64 = 18.6;
pub const IRRADIANCE: f64 = 5.0;
/// The floor: albedo, and its extent in x (z: as the prism's), a little past the view.
pub const ALBEDO: f64 = 0.8;
pub const FLOOR_X: [f64; 2] = [1.25, 2.95];
/// The pinhole: above (`CAMERA_X`, `CAMERA_HEIGHT`, 0) looking straight down, seeing x within
/// `CAMERA_X` +- `VIEW_HALF` (and z as much).
pub const CAMERA_X: f64 = 2.1;
pub const CAMERA_HEIGHT: f64 = 2.0;
pub const VIEW_HALF: f64 = 0.8;

/// The prism's corners in the x-y plane: base left, base right, apex.
fn corners() -> [[f64; 2]; 3] {
    let h = SIDE * 3f64.sqrt() / 2.0;
    [[-SIDE / 2.0, BASE_Y], [SIDE / 2.0, BASE_Y], [0.0, BASE_Y + h]]
}

/// The direction the light travels.
fn light_dir() -> [f64; 2] {
    let a = ELEVATION_DEG.to_radians();
    [a.cos(), a.sin()]
}

/// Writes the scene (a glTF with its buffer inline) to a temporary folder tagged `tag`.
pub fn scene(tag: &str) -> std::path::PathBuf {
    let [c0, c1, c2] = corners().map(|[x, y]| [x as f32, y as f32]);
    let l = HALF_LENGTH as f32;
    let prism: Vec<[f32; 3]> = [c0, c1, c2]
        .iter()
        .map(|c| [c[0], c[1], -l])
        .chain([c0, c1, c2].iter().map(|c| [c[0], c[1], l]))
        .collect();
    // Caps and the three sides as two triangles each, then wound to face out.
    let mut tris: Vec<[u16; 3]> = vec![
        [0, 1, 2],
        [3, 4, 5],
        [0, 1, 4],
        [0, 4, 3],
        [1, 2, 5],
        [1, 5, 4],
        [2, 0, 3],
        [2, 3, 5],
    ];
    let centroid: [f32; 3] = [
        prism.iter().map(|p| p[0]).sum::<f32>() / 6.0,
        prism.iter().map(|p| p[1]).sum::<f32>() / 6.0,
        0.0,
    ];
    for t in &mut tris {
        let [a, b, c] = t.map(|i| glam::Vec3::from(prism[i as usize]));
        let out = (a + b + c) / 3.0 - glam::Vec3::from(centroid);
        if (b - a).cross(c - a).dot(out) < 0.0 {
            t.swap(1, 2);
        }
    }
    let [x0, x1] = FLOOR_X.map(|x| x as f32);
    // Counter-clockwise seen from above.
    let floor: [[f32; 3]; 4] = [[x0, 0.0, -l], [x0, 0.0, l], [x1, 0.0, l], [x1, 0.0, -l]];
    let floor_tris: [[u16; 3]; 2] = [[0, 1, 2], [0, 2, 3]];

    let mut bytes: Vec<u8> = prism.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    let prism_idx = bytes.len();
    bytes.extend(tris.iter().flatten().flat_map(|v| v.to_le_bytes()));
    let floor_pos = bytes.len();
    bytes.extend(floor.iter().flatten().flat_map(|v| v.to_le_bytes()));
    let floor_idx = bytes.len();
    bytes.extend(floor_tris.iter().flatten().flat_map(|v| v.to_le_bytes()));
    let bound = |ps: &[[f32; 3]], f: fn(f32, f32) -> f32| {
        [0, 1, 2].map(|k| ps.iter().map(|p| p[k]).reduce(f).unwrap())
    };
    // The light travels along its node's -z: a quarter turn about (dy, -dx, 0) takes -z there.
    let [dx, dy] = light_dir();
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1, 2, 3]}],
        "nodes": [
            {"mesh": 0},
            {"mesh": 1},
            {"camera": 0, "translation": [CAMERA_X, CAMERA_HEIGHT, 0.0], "rotation": [-s, 0.0, 0.0, s]},
            {"rotation": [dy * s, -dx * s, 0.0, s], "extensions": {"KHR_lights_punctual": {"light": 0}}}
        ],
        "cameras": [{"type": "perspective", "perspective": {
            "yfov": 2.0 * (VIEW_HALF / CAMERA_HEIGHT).atan(), "aspectRatio": 1.0, "znear": 0.01}}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "directional", "intensity": IRRADIANCE, "color": [1.0, 1.0, 1.0]}
        ]}},
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
            {"primitives": [{"attributes": {"POSITION": 2}, "indices": 3, "material": 1}]}
        ],
        "materials": [
            {
                "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.0},
                "extensions": {
                    "KHR_materials_transmission": {"transmissionFactor": 1.0},
                    "KHR_materials_volume": {"thicknessFactor": 1.0},
                    "KHR_materials_ior": {"ior": IOR},
                    "KHR_materials_dispersion": {"dispersion": DISPERSION}
                }
            },
            {
                "pbrMetallicRoughness": {"baseColorFactor": [ALBEDO, ALBEDO, ALBEDO, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
            }
        ],
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_ior", "KHR_materials_dispersion", "KHR_materials_specular"],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC3",
             "min": bound(&prism, f32::min), "max": bound(&prism, f32::max)},
            {"bufferView": 1, "componentType": 5123, "count": 24, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": bound(&floor, f32::min), "max": bound(&floor, f32::max)},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": prism_idx},
            {"buffer": 0, "byteOffset": prism_idx, "byteLength": floor_pos - prism_idx},
            {"buffer": 0, "byteOffset": floor_pos, "byteLength": floor_idx - floor_pos},
            {"buffer": 0, "byteOffset": floor_idx, "byteLength": bytes.len() - floor_idx}
        ],
        "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
    });
    let dir = std::env::temp_dir().join(format!("renderfarm-prism-{}-{tag}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("prism.gltf");
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    path
}

/// `d` refracted through a surface of unit normal `n` (facing against `d`), `eta` the index on
/// `d`'s side over the far side's; `None` past the critical angle.
fn refract(d: [f64; 2], n: [f64; 2], eta: f64) -> Option<[f64; 2]> {
    let c = -(d[0] * n[0] + d[1] * n[1]);
    let k = 1.0 - eta * eta * (1.0 - c * c);
    if k < 0.0 {
        return None;
    }
    let t = eta * c - k.sqrt();
    Some([eta * d[0] + t * n[0], eta * d[1] + t * n[1]])
}

/// The prism's faces as (start, end, outward unit normal).
fn faces() -> [([f64; 2], [f64; 2], [f64; 2]); 3] {
    let c = corners();
    let centre = [(c[0][0] + c[1][0] + c[2][0]) / 3.0, (c[0][1] + c[1][1] + c[2][1]) / 3.0];
    [(c[0], c[1]), (c[1], c[2]), (c[2], c[0])].map(|(a, b)| {
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let len = ex.hypot(ey);
        let mut n = [ey / len, -ex / len];
        let mid = [(a[0] + b[0]) / 2.0 - centre[0], (a[1] + b[1]) / 2.0 - centre[1]];
        if n[0] * mid[0] + n[1] * mid[1] < 0.0 {
            n = [-n[0], -n[1]];
        }
        (a, b, n)
    })
}

/// Where the ray from `o` along `d` first leaves the prism (from inside), past its entry face
/// `skip`: the distance and the face.
fn exit_face(o: [f64; 2], d: [f64; 2], skip: usize) -> Option<(f64, usize)> {
    let mut best: Option<(f64, usize)> = None;
    for (i, (a, b, _)) in faces().into_iter().enumerate() {
        if i == skip {
            continue;
        }
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let den = d[0] * -ey + d[1] * ex;
        if den.abs() < 1e-12 {
            continue;
        }
        let (rx, ry) = (a[0] - o[0], a[1] - o[1]);
        let t = (rx * -ey + ry * ex) / den;
        let u = (d[0] * ry - d[1] * rx) / den;
        if t > 1e-12 && (0.0..=1.0).contains(&u) && best.is_none_or(|(bt, _)| t < bt) {
            best = Some((t, i));
        }
    }
    best
}

/// Compares `ours` (`columns`) with `expected` column by column and channel by channel: the
/// largest, over them, of |difference| / (Sidak bound (1% over all of them) x the standard
/// error + `floor` x the brightest expected value), with where it is. Below 1 where they agree
/// within the noise; `floor` allows for the rare light that lands at the rainbow's faint ends,
/// which a few samples' variance does not see.
pub fn worst_column(
    ours: &[([f64; 3], [f64; 3])],
    expected: &[[f64; 3]],
    floor: f64,
) -> (f64, String) {
    let z_bound = super::sidak_z(0.01, 3 * ours.len());
    let peak = expected.iter().flatten().fold(0.0f64, |a, &b| a.max(b));
    let mut worst = (0.0f64, String::new());
    for (x, ((m, v), e)) in ours.iter().zip(expected).enumerate() {
        for c in 0..3 {
            let se = v[c].sqrt();
            let score = (m[c] - e[c]).abs() / (z_bound * se + floor * peak);
            if score > worst.0 {
                let z = (m[c] - e[c]) / se;
                worst = (
                    score,
                    format!("column {x}, channel {c}: {:.5} against {:.5}, z {z:.2}", m[c], e[c]),
                );
            }
        }
    }
    worst
}

/// The expected image, `width` columns (every row the same), per channel: the mean over each
/// pixel of the floor's radiance albedo / pi x irradiance, the irradiance the flux (per unit z)
/// of `entries` entry points on each lit face per wavelength, at wavelengths 0.5 nm apart,
/// weighted by each channel's colour of that light.
pub fn expected(width: u32, entries: u32) -> Vec<[f64; 3]> {
    let d = light_dir();
    let pixel = 2.0 * VIEW_HALF / width as f64;
    let left = CAMERA_X - VIEW_HALF;
    let mut sums = vec![[0.0f64; 3]; width as usize];
    let mut weight_sums = [0.0f64; 3];
    let steps = ((spectrum::LAMBDA_MAX - spectrum::LAMBDA_MIN) * 2.0) as u32;
    for k in 0..steps {
        let lambda = spectrum::LAMBDA_MIN + (k as f32 + 0.5) * 0.5;
        let w = spectrum::rgb_weights(lambda).as_dvec3().to_array();
        for c in 0..3 {
            weight_sums[c] += w[c];
        }
        let n = spectrum::dispersive_ior(IOR as f32, DISPERSION as f32, lambda) as f64;
        let mut flux = vec![0.0f64; width as usize];
        // Adds `power` to the column where a ray from `o` along `dir` meets the floor.
        let land = |o: [f64; 2], dir: [f64; 2], power: f64, flux: &mut [f64]| {
            if dir[1] >= 0.0 {
                return;
            }
            let x = o[0] + o[1] / -dir[1] * dir[0];
            let col = ((x - left) / pixel).floor();
            if (FLOOR_X[0]..FLOOR_X[1]).contains(&x) && col >= 0.0 && col < width as f64 {
                flux[col as usize] += power;
            }
        };
        for (i, (a, b, normal)) in faces().into_iter().enumerate() {
            let cos_in = -(d[0] * normal[0] + d[1] * normal[1]);
            if cos_in <= 0.0 {
                continue; // In the face's shadow.
            }
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            // Each entry point's share of the beam: its width across the light.
            let share = IRRADIANCE * len * cos_in / entries as f64;
            let reflectance = fresnel_dielectric(cos_in as f32, n as f32) as f64;
            let Some(inside) = refract(d, normal, 1.0 / n) else { continue };
            // Reflected off the face outside (away from the prism, which is convex).
            let mirrored = [d[0] + 2.0 * cos_in * normal[0], d[1] + 2.0 * cos_in * normal[1]];
            for e in 0..entries {
                let s = (e as f64 + 0.5) / entries as f64;
                let o = [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])];
                land(o, mirrored, share * reflectance, &mut flux);
                let Some((t, j)) = exit_face(o, inside, i) else { continue };
                let q = [o[0] + t * inside[0], o[1] + t * inside[1]];
                let out_normal = faces()[j].2;
                let cos_out = inside[0] * out_normal[0] + inside[1] * out_normal[1];
                let Some(out) = refract(inside, [-out_normal[0], -out_normal[1]], n) else {
                    continue; // Reflected whole: a fourth bounce at least.
                };
                let t_out = 1.0 - fresnel_dielectric(cos_out as f32, (1.0 / n) as f32) as f64;
                land(q, out, share * (1.0 - reflectance) * t_out, &mut flux);
            }
        }
        for (sum, f) in sums.iter_mut().zip(&flux) {
            for c in 0..3 {
                sum[c] += w[c] * f;
            }
        }
    }
    sums.iter()
        .map(|s| {
            std::array::from_fn(|c| ALBEDO / std::f64::consts::PI * s[c] / weight_sums[c] / pixel)
        })
        .collect()
}

/// Per column and channel, the mean over the image's rows of the pixels' means (`stats` as
/// `pixel_stats` gives them, `width` wide) and its variance.
pub fn columns(stats: &[([f64; 3], [f64; 3])], width: u32) -> Vec<([f64; 3], [f64; 3])> {
    let rows = stats.len() / width as usize;
    (0..width as usize)
        .map(|x| {
            let mut m = [0.0; 3];
            let mut v = [0.0; 3];
            for y in 0..rows {
                let (pm, pv) = &stats[y * width as usize + x];
                for c in 0..3 {
                    m[c] += pm[c] / rows as f64;
                    v[c] += pv[c] / (rows * rows) as f64;
                }
            }
            (m, v)
        })
        .collect()
}
