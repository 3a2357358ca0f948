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
    many_lights_gltf_at(n, 0.6, 0.25)
}

/// [`many_lights_gltf`] with its quads of side `side` (in (0, 0.5], their radiance scaled by
/// (0.25 / side)² so that each emits the same power) at `height` over the floor (in (0, 4]).
/// Lower and smaller, each lamp lights its own pool, seen from it in a small solid angle: at
/// 1,024 quads, 0.56 apart, a height of 0.15 and a side of 0.05 are street lamps about four
/// heights apart, as in a city at night.
pub fn many_lights_gltf_at(n: usize, height: f64, side: f64) -> String {
    many_lights_gltf_in(n, height, side, None)
}

/// [`many_lights_gltf_at`] with its lamps merged into `meshes` emissive meshes (`None`: each
/// lamp its own node), lamp `k` in mesh `k % meshes`, its corners written in place. Each mesh
/// is one power class: mesh `c`'s radiance is the lamps' times 2 (c + 1) / (meshes + 1), so
/// that the classes span a range and the mean lamp emits what an unmerged one does. One
/// placement holds many lamps, as when an exporter joins a street's lamps into one object.
pub fn many_lights_gltf_in(n: usize, height: f64, side: f64, meshes: Option<usize>) -> String {
    assert!(height > 0.0 && height <= 4.0, "lamp height {height} is outside (0, 4]");
    assert!(side > 0.0 && side <= 0.5, "lamp side {side} is outside (0, 0.5]");
    assert!(meshes.is_none_or(|m| m >= 1 && m <= n), "{meshes:?} meshes for {n} lamps");
    let floor: [[f32; 3]; 4] =
        [[-10.0, 0.0, -10.0], [10.0, 0.0, -10.0], [10.0, 0.0, 10.0], [-10.0, 0.0, 10.0]];
    let radiance = 8.0 * (0.25 / side).powi(2);
    let side = (side / 2.0) as f32;
    // Counter-clockwise seen from below: the quad emits downward.
    let quad: [[f32; 3]; 4] =
        [[-side, 0.0, -side], [side, 0.0, -side], [side, 0.0, side], [-side, 0.0, side]];
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
    let places: Vec<[f64; 3]> = (0..n)
        .map(|k| {
            let (i, j) = (k % grid, k / grid);
            let x = -9.0 + cell * (i as f64 + 0.15 + 0.7 * next());
            let z = -9.0 + cell * (j as f64 + 0.15 + 0.7 * next());
            [x, height, z]
        })
        .collect();
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
    // The floor first, then each lamp mesh: positions (f32) and u32 indices, each 4-aligned.
    let mut bytes: Vec<u8> = Vec::new();
    let (mut views, mut accessors, mut meshes_json) = (Vec::new(), Vec::new(), Vec::new());
    let mut add_mesh = |bytes: &mut Vec<u8>, corners: &[[f32; 3]], indices: &[u32], material| {
        let at = bytes.len();
        for v in corners.iter().flatten() {
            bytes.extend(v.to_le_bytes());
        }
        let mid = bytes.len();
        for i in indices {
            bytes.extend(i.to_le_bytes());
        }
        let (lo, hi) = corners.iter().fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), c| {
            (std::array::from_fn(|a| lo[a].min(c[a])), std::array::from_fn(|a| hi[a].max(c[a])))
        });
        let v = views.len();
        views.push(json!({"buffer": 0, "byteOffset": at, "byteLength": mid - at}));
        views.push(json!({"buffer": 0, "byteOffset": mid, "byteLength": bytes.len() - mid}));
        let a = accessors.len();
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": corners.len(), "type": "VEC3", "min": lo, "max": hi}));
        accessors.push(json!({"bufferView": v + 1, "componentType": 5125, "count": indices.len(), "type": "SCALAR"}));
        meshes_json.push(json!({"primitives": [{"attributes": {"POSITION": a}, "indices": a + 1, "material": material}]}));
    };
    // Floor: seen from above counter-clockwise; a lamp: seen from below.
    add_mesh(&mut bytes, &floor, &[0, 2, 1, 0, 3, 2], 0);
    let lamp = [0u32, 1, 2, 0, 2, 3];
    let mut nodes = vec![
        json!({"camera": 0, "translation": [0.0, 5.0, 0.0],
        "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}),
        json!({"mesh": 0}),
    ];
    let mut materials = vec![floor_material];
    match meshes {
        None => {
            add_mesh(&mut bytes, &quad, &lamp, 1);
            materials.push(lambert(0.0, radiance));
            nodes.extend(places.iter().map(|&t| json!({"mesh": 1, "translation": t})));
        }
        Some(m) => {
            for c in 0..m {
                let (mut corners, mut indices) = (Vec::new(), Vec::new());
                for place in places.iter().skip(c).step_by(m) {
                    let base = corners.len() as u32;
                    indices.extend(lamp.map(|i| base + i));
                    corners.extend(
                        quad.map(|q| std::array::from_fn(|a| (q[a] as f64 + place[a]) as f32)),
                    );
                }
                add_mesh(&mut bytes, &corners, &indices, 1 + c);
                let class = 2.0 * (c + 1) as f64 / (m + 1) as f64;
                materials.push(lambert(0.0, radiance * class));
                nodes.push(json!({"mesh": 1 + c}));
            }
        }
    }
    let json = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..nodes.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "cameras": [{"type": "orthographic", "orthographic": {"xmag": 10.0, "ymag": 10.0, "znear": 0.01, "zfar": 100.0}}],
        "meshes": meshes_json,
        "materials": materials,
        "extensionsUsed": ["KHR_materials_specular", "KHR_materials_emissive_strength"],
        "accessors": accessors,
        "bufferViews": views,
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

/// A rainbow with a closed form: sunlight (a directional light) through a dispersive glass prism
/// onto a white Lambertian floor, seen from straight above.
///
/// The prism is an equilateral triangle in the x-y plane (side `SIDE`, apex up, base at height
/// `BASE_Y`) drawn out along z over +-`HALF_LENGTH`; the light travels up and to the right, in the
/// x-y plane, at `ELEVATION_DEG` above the horizon, so that it meets the prism's left face and its
/// base, and each wavelength leaves the right face as a parallel beam bent down to the floor at
/// its own angle (blue more than red). The camera's view lies within the prism's length, so every
/// row of the image is the same and the image is a profile along x. With `max_depth` 3 the only
/// light on the floor came in through one face and out through another, or was reflected off the
/// base outside (a light ray that reflects inside the prism needs a fourth bounce), so the
/// profile is a sum over the entry points of both lit faces and over wavelengths of the flux each
/// carries, Fresnel-transmitted twice or reflected once, to where it lands (`profile`). The path
/// tracer finds none of it (a directional light seen through smooth glass); light tracing and
/// photons do.
#[derive(Clone, Copy, Debug)]
pub struct PrismRainbow;

impl PrismRainbow {
    /// The prism's side.
    pub const SIDE: f64 = 0.3;
    /// The height of the prism's base.
    pub const BASE_Y: f64 = 0.6;
    /// Half the prism's length along z (the floor's extent in z too).
    pub const HALF_LENGTH: f64 = 0.9;
    /// The glass's index at 587.6 nm.
    pub const IOR: f64 = 1.5;
    /// The glass's `KHR_materials_dispersion` (20 / Abbe number).
    pub const DISPERSION: f64 = 2.0;
    /// The sunlight's direction of travel above the horizon, in degrees (the prism's minimum
    /// deviation near 550 nm).
    pub const ELEVATION_DEG: f64 = 18.6;
    /// The sunlight's irradiance across its direction.
    pub const IRRADIANCE: f64 = 5.0;
    /// The floor's albedo.
    pub const ALBEDO: f64 = 0.8;
    /// The floor's extent in x, a little past the view.
    pub const FLOOR_X: [f64; 2] = [1.25, 2.95];
    /// The pinhole's x: above (`CAMERA_X`, `CAMERA_HEIGHT`, 0) looking straight down, it sees x
    /// within `CAMERA_X` +- `VIEW_HALF` (and z as much).
    pub const CAMERA_X: f64 = 2.1;
    /// The pinhole's height.
    pub const CAMERA_HEIGHT: f64 = 2.0;
    /// Half the side of the floor region the square image frames.
    pub const VIEW_HALF: f64 = 0.8;
    /// The `max_depth` the closed form is for.
    pub const MAX_DEPTH: u32 = 3;

    /// The prism's corners in the x-y plane: base left, base right, apex.
    fn corners() -> [[f64; 2]; 3] {
        let h = Self::SIDE * 3f64.sqrt() / 2.0;
        [
            [-Self::SIDE / 2.0, Self::BASE_Y],
            [Self::SIDE / 2.0, Self::BASE_Y],
            [0.0, Self::BASE_Y + h],
        ]
    }

    /// The direction the light travels.
    fn light_dir() -> [f64; 2] {
        let a = Self::ELEVATION_DEG.to_radians();
        [a.cos(), a.sin()]
    }

    /// The scene as glTF JSON with its buffer in a `data:` URI.
    pub fn gltf(&self) -> String {
        let [c0, c1, c2] = Self::corners().map(|[x, y]| [x as f32, y as f32]);
        let l = Self::HALF_LENGTH as f32;
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
        let [x0, x1] = Self::FLOOR_X.map(|x| x as f32);
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
        let [dx, dy] = Self::light_dir();
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let json = json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0, 1, 2, 3]}],
            "nodes": [
                {"mesh": 0},
                {"mesh": 1},
                {"camera": 0, "translation": [Self::CAMERA_X, Self::CAMERA_HEIGHT, 0.0], "rotation": [-s, 0.0, 0.0, s]},
                {"rotation": [dy * s, -dx * s, 0.0, s], "extensions": {"KHR_lights_punctual": {"light": 0}}}
            ],
            "cameras": [{"type": "perspective", "perspective": {
                "yfov": 2.0 * (Self::VIEW_HALF / Self::CAMERA_HEIGHT).atan(), "aspectRatio": 1.0, "znear": 0.01}}],
            "extensions": {"KHR_lights_punctual": {"lights": [
                {"type": "directional", "intensity": Self::IRRADIANCE, "color": [1.0, 1.0, 1.0]}
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
                        "KHR_materials_ior": {"ior": Self::IOR},
                        "KHR_materials_dispersion": {"dispersion": Self::DISPERSION}
                    }
                },
                {
                    "pbrMetallicRoughness": {"baseColorFactor": [Self::ALBEDO, Self::ALBEDO, Self::ALBEDO, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0},
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
        json.to_string()
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
        let c = Self::corners();
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
        for (i, (a, b, _)) in Self::faces().into_iter().enumerate() {
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

    /// The exact image's row, `width` pixels (every row is the same), per channel: the mean over
    /// each pixel of the floor's radiance, albedo / pi x the irradiance, the irradiance the flux
    /// (per unit z) of `entries` entry points on each lit face per wavelength, at wavelengths 0.5
    /// nm apart, weighted by each channel's colour of that light (`crate::render::spectrum::rgb_weights`).
    pub fn profile(width: u32, entries: u32) -> Vec<[f64; 3]> {
        let d = Self::light_dir();
        let pixel = 2.0 * Self::VIEW_HALF / width as f64;
        let left = Self::CAMERA_X - Self::VIEW_HALF;
        let mut sums = vec![[0.0f64; 3]; width as usize];
        let mut weight_sums = [0.0f64; 3];
        let steps = ((crate::render::spectrum::LAMBDA_MAX - crate::render::spectrum::LAMBDA_MIN)
            * 2.0) as u32;
        for k in 0..steps {
            let lambda = crate::render::spectrum::LAMBDA_MIN + (k as f32 + 0.5) * 0.5;
            let w = crate::render::spectrum::rgb_weights(lambda).as_dvec3().to_array();
            for c in 0..3 {
                weight_sums[c] += w[c];
            }
            let n = crate::render::spectrum::dispersive_ior(
                Self::IOR as f32,
                Self::DISPERSION as f32,
                lambda,
            ) as f64;
            let mut flux = vec![0.0f64; width as usize];
            // Adds `power` to the column where a ray from `o` along `dir` meets the floor.
            let land = |o: [f64; 2], dir: [f64; 2], power: f64, flux: &mut [f64]| {
                if dir[1] >= 0.0 {
                    return;
                }
                let x = o[0] + o[1] / -dir[1] * dir[0];
                let col = ((x - left) / pixel).floor();
                if (Self::FLOOR_X[0]..Self::FLOOR_X[1]).contains(&x)
                    && col >= 0.0
                    && col < width as f64
                {
                    flux[col as usize] += power;
                }
            };
            for (i, (a, b, normal)) in Self::faces().into_iter().enumerate() {
                let cos_in = -(d[0] * normal[0] + d[1] * normal[1]);
                if cos_in <= 0.0 {
                    continue; // In the face's shadow.
                }
                let len = (b[0] - a[0]).hypot(b[1] - a[1]);
                // Each entry point's share of the beam: its width across the light.
                let share = Self::IRRADIANCE * len * cos_in / entries as f64;
                let reflectance =
                    crate::render::bsdf::fresnel_dielectric(cos_in as f32, n as f32) as f64;
                let Some(inside) = Self::refract(d, normal, 1.0 / n) else { continue };
                // Reflected off the face outside (away from the prism, which is convex).
                let mirrored = [d[0] + 2.0 * cos_in * normal[0], d[1] + 2.0 * cos_in * normal[1]];
                for e in 0..entries {
                    let s = (e as f64 + 0.5) / entries as f64;
                    let o = [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])];
                    land(o, mirrored, share * reflectance, &mut flux);
                    let Some((t, j)) = Self::exit_face(o, inside, i) else { continue };
                    let q = [o[0] + t * inside[0], o[1] + t * inside[1]];
                    let out_normal = Self::faces()[j].2;
                    let cos_out = inside[0] * out_normal[0] + inside[1] * out_normal[1];
                    let Some(out) = Self::refract(inside, [-out_normal[0], -out_normal[1]], n)
                    else {
                        continue; // Reflected whole: a fourth bounce at least.
                    };
                    let t_out = 1.0
                        - crate::render::bsdf::fresnel_dielectric(cos_out as f32, (1.0 / n) as f32)
                            as f64;
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
                std::array::from_fn(|c| {
                    Self::ALBEDO / std::f64::consts::PI * s[c] / weight_sums[c] / pixel
                })
            })
            .collect()
    }

    /// The exact image, `width` x `width` pixels in row order (`profile` on every row).
    pub fn image(width: u32, entries: u32) -> Vec<[f64; 3]> {
        let row = Self::profile(width, entries);
        (0..width).flat_map(|_| row.iter().copied()).collect()
    }
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

/// The exact value of pixel (`col`, `row`) of a 60 x 60 image of an emissive bar of half-size
/// 1 x 0.05 at the origin that turns a quarter turn about z within the shutter, seen by an
/// orthographic camera 3 units wide: the share of the pixel's area x shutter time the bar
/// covers, by quadrature over `n` x `n` points of the pixel and 256 times.
pub fn quarter_turn_bar_coverage(col: usize, row: usize, n: usize) -> f64 {
    let times = 256;
    let mut covered = 0usize;
    for k in 0..times {
        let angle = std::f64::consts::FRAC_PI_2 * (k as f64 + 0.5) / times as f64;
        let (sin, cos) = angle.sin_cos();
        for j in 0..n {
            for i in 0..n {
                let x = -1.5 + 0.05 * (col as f64 + (i as f64 + 0.5) / n as f64);
                let y = 1.5 - 0.05 * (row as f64 + (j as f64 + 0.5) / n as f64);
                // Into the bar's frame.
                let (u, v) = (cos * x + sin * y, -sin * x + cos * y);
                covered += (u.abs() <= 1.0 && v.abs() <= 0.05) as usize;
            }
        }
    }
    covered as f64 / (n * n * times) as f64
}
