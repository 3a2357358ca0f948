//! Scenes built in code for tests and benchmarks, as glTF JSON with the buffer in a `data:` URI.
//! Nothing here is read by the renderer itself.

use glam::DVec3;
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

/// A caustic with a closed form: a diffuse floor lit only through a mirror by a small square
/// light (y is up, lengths in metres).
///
/// - Floor: the square |x|, |z| <= 3 at y = 0, facing up, Lambert of albedo
///   [`MirrorCaustic::FLOOR_ALBEDO`] (`KHR_materials_specular` factor 0).
/// - Mirror: the square |x|, |z| <= 3 at y = 1, facing down: metallic 1, roughness 0, base
///   colour 1. The renderer makes that GGX at its smallest alpha (1e-3) with a Fresnel of
///   exactly 1 (base + (1 - base) w): it reflects all the light but for Smith masking of order
///   alpha² (about 1e-6), spread about the mirror direction (a share 4 alpha² / theta² beyond
///   theta radians: 0.16% beyond 0.05). The spread only moves light between neighbouring
///   directions, over which a floor point's cosine is smooth, so where a floor point sees the
///   whole mirrored light its irradiance moves by the order of alpha² log(1 / alpha), 1e-5.
/// - Light: the square |x|, |z| <= `light_half_side` (at most 0.5) at y = 0.1, facing up toward
///   the mirror (single-sided, black base colour, white emission of `radiance`), so that the
///   floor, behind it, is lit only through the mirror. Its back is opaque.
/// - Camera: a pinhole at (1.2, 0.5, 0) looking straight down with a vertical field of view of
///   90 degrees: a square image frames the floor region 0.7 <= x <= 1.7, |z| <= 0.5 (the
///   measured region), image up being -z (row 0 at z = -0.5), and does not see the light. A
///   pinhole rather than an orthographic camera so that light-tracing strategies can connect
///   to it; as the floor is parallel to the image plane the pixel-to-floor map is still linear.
///
/// The floor's radiance at (x, 0, z) is albedo / pi x E, with E = radiance x the projected solid
/// angle of the part of the light's mirror image (the square at y = 2 - 0.1 = 1.9, facing down)
/// seen through the mirror's extent and not hidden by the light's back (Lambert's polygon
/// formula, [`projected_solid_angle`]). Seen from a floor point, the mirror and the light project
/// onto the image's plane as axis-aligned squares, so the visible part is a rectangle minus a
/// rectangle and the closed form is exact everywhere on the floor ([`Self::radiance_at`]). In the
/// measured region nothing clips or hides the image: the light's back hides part of it only
/// from points within `light_half_side` x (1 + k) / (1 - k) of the light's centre on each axis,
/// k = 0.1 / 1.9 (at most 0.556 < 0.7). Surfaces reflect on both faces, but the mirror's upper
/// face sees nothing (the camera is below it) and the light's back is black. The closed form is
/// that of `max_depth` 2, where every path that carries light is camera, floor, mirror, light;
/// a deeper limit adds the light the floor sends itself by way of the mirror (floor, mirror,
/// floor, mirror, light), which it leaves out.
#[derive(Clone, Copy, Debug)]
pub struct MirrorCaustic {
    /// Half the side of the square light, in (0, 0.5].
    pub light_half_side: f64,
    /// The light's radiance (`KHR_materials_emissive_strength`, white).
    pub radiance: f64,
}

impl MirrorCaustic {
    /// The floor's albedo.
    pub const FLOOR_ALBEDO: f64 = 0.5;
    /// Half the side of the floor and of the mirror, both centred on the y axis.
    pub const HALF_EXTENT: f64 = 3.0;
    /// The mirror's height.
    pub const MIRROR_HEIGHT: f64 = 1.0;
    /// The light's height.
    pub const LIGHT_HEIGHT: f64 = 0.1;
    /// The x of the camera and of the centre of the floor region it frames.
    pub const VIEW_CENTRE_X: f64 = 1.2;
    /// Half the side of the floor region a square image frames.
    pub const VIEW_HALF_SIDE: f64 = 0.5;
    /// The camera's height.
    pub const CAMERA_HEIGHT: f64 = 0.5;

    /// The scene as glTF JSON with its buffer in a `data:` URI.
    pub fn gltf(&self) -> String {
        let s = self.light_half_side;
        assert!(s > 0.0 && s <= 0.5, "light_half_side {s} is outside (0, 0.5]");
        let (e, h, a) = (Self::HALF_EXTENT, Self::MIRROR_HEIGHT, Self::LIGHT_HEIGHT);
        let square = |half: f64, y: f64| -> [[f32; 3]; 4] {
            let (r, y) = (half as f32, y as f32);
            [[-r, y, -r], [r, y, -r], [r, y, r], [-r, y, r]]
        };
        let quads = [square(e, 0.0), square(e, h), square(s, a)];
        let mut bytes: Vec<u8> = Vec::new();
        for v in quads.iter().flatten().flatten() {
            bytes.extend(v.to_le_bytes());
        }
        // Counter-clockwise seen from above (faces up), then seen from below (faces down).
        for i in [0u16, 2, 1, 0, 3, 2, 0, 1, 2, 0, 2, 3] {
            bytes.extend(i.to_le_bytes());
        }
        let half_angle = std::f64::consts::FRAC_1_SQRT_2;
        let nodes = vec![
            // Looking down (-z turned to -y), image up along -z.
            json!({"camera": 0, "translation": [Self::VIEW_CENTRE_X, Self::CAMERA_HEIGHT, 0.0],
                   "rotation": [-half_angle, 0.0, 0.0, half_angle]}),
            json!({"mesh": 0}),
            json!({"mesh": 1}),
            json!({"mesh": 2}),
        ];
        let yfov = 2.0 * (Self::VIEW_HALF_SIDE / Self::CAMERA_HEIGHT).atan();
        let floor = json!({
            "pbrMetallicRoughness": {"baseColorFactor": [Self::FLOOR_ALBEDO, Self::FLOOR_ALBEDO, Self::FLOOR_ALBEDO, 1.0],
                                     "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0}}
        });
        let mirror = json!({
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 1.0, "roughnessFactor": 0.0}
        });
        let light = json!({
            "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "emissiveFactor": [1.0, 1.0, 1.0],
            "extensions": {"KHR_materials_specular": {"specularFactor": 0.0},
                           "KHR_materials_emissive_strength": {"emissiveStrength": self.radiance}}
        });
        let position = |k: usize, half: f64, y: f64| {
            json!({"bufferView": k, "componentType": 5126, "count": 4, "type": "VEC3",
                   "min": [-half, y, -half], "max": [half, y, half]})
        };
        let json = json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0, 1, 2, 3]}],
            "nodes": nodes,
            "cameras": [{"type": "perspective", "perspective": {"yfov": yfov, "aspectRatio": 1.0, "znear": 0.01}}],
            "meshes": [
                {"primitives": [{"attributes": {"POSITION": 0}, "indices": 3, "material": 0}]},
                {"primitives": [{"attributes": {"POSITION": 1}, "indices": 4, "material": 1}]},
                {"primitives": [{"attributes": {"POSITION": 2}, "indices": 3, "material": 2}]}
            ],
            "materials": [floor, mirror, light],
            "extensionsUsed": ["KHR_materials_specular", "KHR_materials_emissive_strength"],
            "accessors": [
                position(0, e, 0.0),
                position(1, e, h),
                position(2, s, a),
                {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
                {"bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR"}
            ],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 48},
                {"buffer": 0, "byteOffset": 48, "byteLength": 48},
                {"buffer": 0, "byteOffset": 96, "byteLength": 48},
                {"buffer": 0, "byteOffset": 144, "byteLength": 12},
                {"buffer": 0, "byteOffset": 156, "byteLength": 12}
            ],
            "buffers": [{"byteLength": bytes.len(), "uri": format!("data:application/octet-stream;base64,{}", base64(&bytes))}]
        });
        json.to_string()
    }

    /// The floor point (x, z) that image position `film` (in pixels, continuous, as the camera
    /// takes it) of a `width` x `height` image sees. Linear: the floor is parallel to the image.
    pub fn floor_point(&self, film: (f64, f64), width: u32, height: u32) -> (f64, f64) {
        let aspect = width as f64 / height as f64;
        let sx = 2.0 * film.0 / width as f64 - 1.0;
        let sy = 1.0 - 2.0 * film.1 / height as f64;
        (Self::VIEW_CENTRE_X + Self::VIEW_HALF_SIDE * aspect * sx, -Self::VIEW_HALF_SIDE * sy)
    }

    /// The floor's radiance at (x, 0, z) with `max_depth` 2, for a mirror that reflects all the
    /// light: albedo / pi x radiance x the projected solid angle of the visible part of the
    /// light's mirror image (see the type's documentation).
    pub fn radiance_at(&self, x: f64, z: f64) -> f64 {
        let (h, a, s) = (Self::MIRROR_HEIGHT, Self::LIGHT_HEIGHT, self.light_half_side);
        let image_height = 2.0 * h - a;
        // Central projection from the floor point onto the image's plane: a square at height y
        // centred on the axis, of half side r, becomes the rectangle centred on
        // p + (0 - p) t, of half side r t, with t = image_height / y.
        let project = |r: f64, y: f64| {
            let t = image_height / y;
            Rect {
                x0: x - (x + r) * t,
                x1: x - (x - r) * t,
                z0: z - (z + r) * t,
                z1: z - (z - r) * t,
            }
        };
        let image = Rect { x0: -s, x1: s, z0: -s, z1: s };
        let Some(seen) = image.intersect(&project(Self::HALF_EXTENT, h)) else { return 0.0 };
        let p = DVec3::new(x, 0.0, z);
        let mut omega = seen.projected_solid_angle(p, image_height);
        if let Some(hidden) = seen.intersect(&project(s, a)) {
            omega -= hidden.projected_solid_angle(p, image_height);
        }
        Self::FLOOR_ALBEDO / std::f64::consts::PI * self.radiance * omega.max(0.0)
    }

    /// The expected value of pixel (`px`, `py`) of a `width` x `height` image: the mean of
    /// [`Self::radiance_at`] over the pixel's footprint on the floor (a box filter), by 4 x 4
    /// Gauss-Legendre points (the radiance is smooth where the camera looks).
    pub fn pixel_radiance(&self, px: u32, py: u32, width: u32, height: u32) -> f64 {
        // Nodes and weights on [0, 1].
        const NODES: [f64; 4] = [
            0.069_431_844_202_973_71,
            0.330_009_478_207_571_9,
            0.669_990_521_792_428_1,
            0.930_568_155_797_026_3,
        ];
        const WEIGHTS: [f64; 4] = [
            0.173_927_422_568_726_9,
            0.326_072_577_431_273_1,
            0.326_072_577_431_273_1,
            0.173_927_422_568_726_9,
        ];
        let mut sum = 0.0;
        for (u, wu) in NODES.iter().zip(WEIGHTS) {
            for (v, wv) in NODES.iter().zip(WEIGHTS) {
                let (x, z) = self.floor_point((px as f64 + u, py as f64 + v), width, height);
                sum += wu * wv * self.radiance_at(x, z);
            }
        }
        sum
    }
}

/// An axis-aligned rectangle [x0, x1] x [z0, z1] in a horizontal plane.
#[derive(Clone, Copy, Debug)]
struct Rect {
    x0: f64,
    x1: f64,
    z0: f64,
    z1: f64,
}

impl Rect {
    fn intersect(&self, other: &Rect) -> Option<Rect> {
        let r = Rect {
            x0: self.x0.max(other.x0),
            x1: self.x1.min(other.x1),
            z0: self.z0.max(other.z0),
            z1: self.z1.min(other.z1),
        };
        (r.x0 < r.x1 && r.z0 < r.z1).then_some(r)
    }

    /// The projected solid angle of the rectangle at height `y` above `p`, for the normal +y.
    fn projected_solid_angle(&self, p: DVec3, y: f64) -> f64 {
        // Counter-clockwise about +y (from +z toward +x).
        let corners =
            [(self.x0, self.z0), (self.x0, self.z1), (self.x1, self.z1), (self.x1, self.z0)];
        projected_solid_angle(p, DVec3::Y, &corners.map(|(x, z)| DVec3::new(x, y, z)))
    }
}

/// The projected solid angle (the integral of the cosine to `n` over the solid angle) of a
/// planar polygon seen from `p`, by Lambert's formula: 1/2 x the sum over edges (v_i, v_i+1) of
/// the angle between v_i - p and v_i+1 - p times n . the unit normal of the plane through p and
/// the edge, (v_i - p) x (v_i+1 - p) normalised. Positive when the vertices turn
/// counter-clockwise about `n` (right-hand rule), negative the other way; the polygon must lie
/// wholly on `n`'s side of `p` (no horizon clipping). The irradiance from a Lambertian emitter
/// of radiance L filling the polygon is L times this.
pub fn projected_solid_angle(p: DVec3, n: DVec3, polygon: &[DVec3]) -> f64 {
    let mut sum = 0.0;
    for (i, v) in polygon.iter().enumerate() {
        let (a, b) = (*v - p, polygon[(i + 1) % polygon.len()] - p);
        let c = a.cross(b);
        let length = c.length();
        if length > 0.0 {
            sum += length.atan2(a.dot(b)) * n.dot(c) / length;
        }
    }
    0.5 * sum
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The projected solid angle of the rectangle [x0, x1] x [z0, z1] at height `y` seen from
    /// `p` (normal +y) by the midpoint rule on an `n` x `n` grid, counting only the points
    /// `visible` passes: the integral of cos_p cos_q / r² over the area.
    fn midpoint(p: DVec3, r: [f64; 4], y: f64, n: usize, visible: impl Fn(DVec3) -> bool) -> f64 {
        let [x0, x1, z0, z1] = r;
        let (dx, dz) = ((x1 - x0) / n as f64, (z1 - z0) / n as f64);
        let mut sum = 0.0;
        for i in 0..n {
            for j in 0..n {
                let q = DVec3::new(x0 + (i as f64 + 0.5) * dx, y, z0 + (j as f64 + 0.5) * dz);
                if visible(q) {
                    let d = q - p;
                    let cos = d.y / d.length();
                    sum += cos * cos / d.length_squared();
                }
            }
        }
        sum * dx * dz
    }

    #[test]
    fn lambert_formula_under_a_square_centre_is_the_view_factor() {
        // Four corner rectangles of a parallel square: pi F each, with the view factor
        // F = 1/(2 pi) [A / sqrt(1 + A²) atan(B / sqrt(1 + A²)) + (A <-> B)] at A = B = s / h.
        for (s, h) in [(0.5f64, 1.9f64), (1.0, 0.3), (0.05, 2.0)] {
            let a = s / h;
            let c = (1.0 + a * a).sqrt();
            let expected = 4.0 * a / c * (a / c).atan();
            let square = [(-s, -s), (-s, s), (s, s), (s, -s)].map(|(x, z)| DVec3::new(x, h, z));
            let omega = projected_solid_angle(DVec3::ZERO, DVec3::Y, &square);
            assert!((omega - expected).abs() <= 1e-12 * expected, "{omega} vs {expected}");
            // The other winding gives the opposite sign.
            let mut reversed = square;
            reversed.reverse();
            let back = projected_solid_angle(DVec3::ZERO, DVec3::Y, &reversed);
            assert!((back + expected).abs() <= 1e-12 * expected);
        }
    }

    #[test]
    fn lambert_formula_matches_a_numerical_integral() {
        for (p, r, y) in [
            (DVec3::new(1.2, 0.0, -0.3), [-0.5, 0.5, -0.5, 0.5], 1.9),
            (DVec3::new(0.1, 0.2, 0.4), [-2.0, 0.3, 0.5, 0.9], 0.7),
        ] {
            let [x0, x1, z0, z1] = r;
            let corners =
                [(x0, z0), (x0, z1), (x1, z1), (x1, z0)].map(|(x, z)| DVec3::new(x, y, z));
            let omega = projected_solid_angle(p, DVec3::Y, &corners);
            let reference = midpoint(p, r, y, 1000, |_| true);
            assert!((omega - reference).abs() <= 1e-5 * reference, "{omega} vs {reference}");
        }
    }

    #[test]
    fn mirror_caustic_radiance_matches_the_visibility_integral() {
        // The image of the light seen through the mirror's extent and past the light's back,
        // tested point by point on the unfolded ray from the floor point to the image.
        let caustic = MirrorCaustic { light_half_side: 0.5, radiance: 3.0 };
        let (h, a, s, e) = (
            MirrorCaustic::MIRROR_HEIGHT,
            MirrorCaustic::LIGHT_HEIGHT,
            caustic.light_half_side,
            MirrorCaustic::HALF_EXTENT,
        );
        let image_height = 2.0 * h - a;
        let scale = MirrorCaustic::FLOOR_ALBEDO / std::f64::consts::PI * caustic.radiance;
        // In the view (all seen), partly hidden by the light's back (on one axis, on both),
        // wholly hidden near and under it, and clipped by the mirror's edge (a point beyond the
        // floor, as if the floor went on: over the floor the mirror never clips).
        for (x, z) in [
            (1.2, 0.0),
            (0.7, -0.5),
            (0.54, 0.2),
            (0.52, 0.53),
            (0.45, 0.1),
            (0.0, 0.0),
            (-6.0, 0.3),
        ] {
            let p = DVec3::new(x, 0.0, z);
            let visible = |q: DVec3| {
                let at = |y: f64| p + (q - p) * (y / image_height);
                let m = at(h);
                let l = at(a);
                m.x.abs() <= e && m.z.abs() <= e && !(l.x.abs() < s && l.z.abs() < s)
            };
            let reference = scale * midpoint(p, [-s, s, -s, s], image_height, 2000, visible);
            let closed = caustic.radiance_at(x, z);
            // Well within the grid's error on the visibility edges (a row of cells, 1/2000 of
            // the largest value, 0.28 x scale).
            let tolerance = 1e-5 * scale * 0.28;
            assert!((closed - reference).abs() <= tolerance, "({x}, {z}): {closed} vs {reference}");
        }
        assert_eq!(caustic.radiance_at(0.0, 0.0), 0.0);
        // The measured region sees the whole image.
        let full = |x: f64, z: f64| {
            let square = [(-s, -s), (-s, s), (s, s), (s, -s)]
                .map(|(qx, qz)| DVec3::new(qx, image_height, qz));
            scale * projected_solid_angle(DVec3::new(x, 0.0, z), DVec3::Y, &square)
        };
        for (x, z) in [(0.7, -0.5), (0.7, 0.5), (1.7, 0.0), (1.2, 0.3)] {
            assert_eq!(caustic.radiance_at(x, z), full(x, z));
        }
    }

    #[test]
    fn mirror_caustic_pixels_map_to_the_framed_floor() {
        let caustic = MirrorCaustic { light_half_side: 0.25, radiance: 1.0 };
        assert_eq!(caustic.floor_point((0.0, 0.0), 32, 32), (0.7, -0.5));
        assert_eq!(caustic.floor_point((32.0, 32.0), 32, 32), (1.7, 0.5));
        assert_eq!(caustic.floor_point((16.0, 16.0), 32, 32), (1.2, 0.0));
        // A pixel's mean lies between its corners' values (the radiance falls away from x = 0).
        let v = caustic.pixel_radiance(3, 5, 32, 32);
        let (xa, za) = caustic.floor_point((3.0, 5.0), 32, 32);
        let (xb, zb) = caustic.floor_point((4.0, 6.0), 32, 32);
        assert!(caustic.radiance_at(xb, za) < v && v < caustic.radiance_at(xa, zb));
    }
}
