//! Motion blur: what moves within the shutter. Static geometry stays in the world BVH; each
//! animated mesh placement gets its own BVH in object space, entered through its transform at
//! the sample's time (evaluated from the glTF curves, so rotations blur along arcs), under a top
//! level of boxes that bound each placement over the whole shutter. A moving camera is placed
//! at the sample's time too. Only scenes that move within a non-empty shutter build any of this.
//!
//! A mesh that deforms within the shutter (a skin whose joints move, animated morph weights) is
//! posed at keys across the shutter ([`deform_keys`]): the shutter's ends, every curve key inside
//! it, and midpoints wherever the pose strays from the straight line between two keys by more
//! than [`KEY_TOLERANCE`] of the mesh's size. Between keys each vertex moves linearly (as in
//! Cycles' deformation blur), and a ray meets the mesh as it is at the ray's time
//! ([`KeyedAccel`]).

use std::{cell::RefCell, collections::HashMap, sync::Arc};

use common::{animation::Animation, scene::Mesh};
use glam::{DMat4, DVec3, Mat3, Mat4, Vec3, Vec4};

use super::{
    accel::{lerp, Accel, Between, Hit, KeyedAccel},
    camera::{Camera, PlacedCamera},
    geometry::Ray,
};

/// Times at which a placement's transform is evaluated to bound it over the shutter (key times
/// inside the shutter are added).
const BOUND_SAMPLES: usize = 64;

/// One animated mesh placement.
pub struct MotionInstance {
    /// Where it is at a time.
    pub place: Place,
    /// Its triangles in object space.
    pub shape: Shape,
    /// Index of its first triangle in the scene's triangle numbering.
    pub prim_base: u32,
    /// Camera-relative box holding it at every time of the shutter.
    pub bounds: (Vec3, Vec3),
}

/// Where a placement is over the shutter.
pub enum Place {
    /// Where its glTF node's animation puts it, times the placement relative to the node
    /// (`EXT_mesh_gpu_instancing`).
    Node { node: usize, offset: DMat4 },
    /// Still (camera-relative): a mesh that deforms on a node that does not move, or a skinned
    /// mesh, whose vertices the skin poses in world space.
    Fixed(DMat4),
}

/// A placement's triangles in object space.
pub enum Shape {
    /// The same at every time.
    Rigid(Accel),
    /// Deforming within the shutter.
    Deforming(Deforming),
}

/// A mesh that deforms within the shutter, at its keys.
pub struct Deforming {
    /// Its triangles at each key.
    pub accel: KeyedAccel,
    /// The keys' times in seconds, increasing, from the shutter's opening to its closing.
    pub times: Vec<f64>,
    /// Vertex normals at each key, when the mesh has normals.
    pub normals: Vec<Vec<Vec3>>,
    /// Vertex tangents at each key, when the scene keeps tangents and the mesh has them.
    pub tangents: Vec<Vec<Vec4>>,
    /// The scene's index of the mesh's first vertex (`TriShading::vertices` counts from it).
    pub vertex_base: u32,
}

impl Deforming {
    /// Where time `t` lies among the keys.
    pub fn between(&self, t: f64) -> Between {
        let n = self.times.len();
        if n < 2 {
            return Between { key: 0, f: 0.0 };
        }
        let key = self.times.partition_point(|&k| k <= t).saturating_sub(1).min(n - 2);
        let (t0, t1) = (self.times[key], self.times[key + 1]);
        Between { key, f: ((t - t0) / (t1 - t0)).clamp(0.0, 1.0) as f32 }
    }

    /// The normal of the scene's vertex `vertex` at `at` (object space, not normalised), or
    /// `None` without normals.
    fn normal(&self, vertex: u32, at: Between) -> Option<Vec3> {
        let v = (vertex - self.vertex_base) as usize;
        let (a, b) = (self.normals.get(at.key)?, self.normals.get(at.key + 1)?);
        Some(lerp(a[v], b[v], at.f))
    }

    /// The tangent of the scene's vertex `vertex` at `at` (object space, handedness in `w`).
    fn tangent(&self, vertex: u32, at: Between) -> Option<Vec4> {
        let v = (vertex - self.vertex_base) as usize;
        let (a, b) = (self.tangents.get(at.key)?, self.tangents.get(at.key + 1)?);
        Some(lerp(a[v].truncate(), b[v].truncate(), at.f).extend(a[v].w))
    }
}

/// The largest distance a deforming mesh's vertex may stray between two keys from the straight
/// line between them, as a share of the mesh's size (the diagonal of its box at the shutter's
/// opening), checked at each interval's midpoint.
pub const KEY_TOLERANCE: f64 = 2.5e-4;

/// The most keys a deforming mesh gets within one shutter.
pub const MAX_KEYS: usize = 65;

/// The most triangles over all keys of one deforming mesh (about 40 bytes each): a larger mesh
/// gets fewer keys, never fewer than the shutter's two ends.
pub const MAX_KEY_TRIANGLES: usize = 1 << 24;

/// A deforming mesh posed at keys across `shutter` (see the module): (time, the mesh's
/// positions, normals and tangents then), in time order. `mesh` must carry its `Deform` record.
pub fn deform_keys(mesh: &Mesh, anim: &Animation, (open, close): (f64, f64)) -> Vec<(f64, Mesh)> {
    let deform = mesh.deform.as_deref().expect("a deforming mesh");
    let pose = |t: f64| {
        let mut posed = Mesh {
            positions: mesh.positions.clone(),
            normals: mesh.normals.clone(),
            tangents: mesh.tangents.clone(),
            ..Mesh::default()
        };
        let mut worlds = HashMap::new();
        for &j in deform.skin.iter().flat_map(|s| &s.joints) {
            anim.world_memo(j, t, &mut worlds);
        }
        deform.pose(&deform.weights_at(Some(anim), t), |j| worlds[&j], &mut posed);
        posed
    };
    let mut times: Vec<f64> = anim.key_times().filter(|&k| k > open && k < close).collect();
    times.extend([open, close]);
    times.sort_by(f64::total_cmp);
    times.dedup();
    let mut keys: Vec<(f64, Mesh)> = times.into_iter().map(|t| (t, pose(t))).collect();
    let (lo, hi) = keys[0]
        .1
        .positions
        .iter()
        .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), &p| {
            (lo.min(p), hi.max(p))
        });
    let size = if lo.x <= hi.x { (hi - lo).length() as f64 } else { 0.0 };
    let tolerance = KEY_TOLERANCE * size;
    let most = (MAX_KEY_TRIANGLES / mesh.indices.len().max(1)).clamp(2, MAX_KEYS);
    // The midpoint of each interval and how far it strays from the chord; the worst interval
    // is split first, so a mesh that reaches `most` keys has them where they matter.
    let midpoint = |a: &(f64, Mesh), b: &(f64, Mesh)| {
        let t = 0.5 * (a.0 + b.0);
        let posed = pose(t);
        let stray = (posed.positions.iter().zip(&a.1.positions).zip(&b.1.positions))
            .map(|((&p, &pa), &pb)| (p.as_dvec3() - 0.5 * (pa.as_dvec3() + pb.as_dvec3())).length())
            .fold(0.0, f64::max);
        // An interval too short to split in f64 is never split again.
        let splittable = t > a.0 && t < b.0;
        (if splittable { stray } else { 0.0 }, t, posed)
    };
    let mut mids: Vec<(f64, f64, Mesh)> = keys.windows(2).map(|w| midpoint(&w[0], &w[1])).collect();
    while keys.len() < most {
        let worst = mids.iter().enumerate().max_by(|a, b| a.1 .0.total_cmp(&b.1 .0));
        let Some((i, &(stray, ..))) = worst else { break };
        if !(stray > tolerance) {
            break;
        }
        let (_, t, posed) = mids.remove(i);
        keys.insert(i + 1, (t, posed));
        let halves = [midpoint(&keys[i], &keys[i + 1]), midpoint(&keys[i + 1], &keys[i + 2])];
        mids.splice(i..i, halves);
    }
    keys
}

/// Everything that moves within the shutter of one frame.
pub struct Motion {
    /// The scene's animation.
    pub anim: Arc<Animation>,
    /// World position of the renderer's origin.
    pub origin: DVec3,
    /// Shutter interval in seconds, [open, close).
    pub shutter: (f64, f64),
    /// Animated placements.
    pub instances: Vec<MotionInstance>,
    /// The camera's node when the camera moves, and the camera in its own space.
    pub camera: Option<(usize, Camera)>,
}

/// A placement's transform at one time: camera-relative object-to-world and its inverse.
#[derive(Clone, Copy, Debug)]
pub struct Placed {
    /// Object to camera-relative world.
    pub to_world: Mat4,
    /// Camera-relative world to object.
    pub to_object: Mat4,
    /// Normal matrix (inverse transpose of the linear part).
    pub normal: Mat3,
}

impl Motion {
    /// Camera-relative object-to-world transform of placement `i` at time `t`, in f64.
    fn transform(&self, i: usize, t: f64) -> DMat4 {
        match self.instances[i].place {
            Place::Node { node, offset } => {
                DMat4::from_translation(-self.origin) * self.anim.world(node, t) * offset
            }
            Place::Fixed(m) => m,
        }
    }

    /// The time of a sample drawing `u` in [0, 1).
    pub fn time(&self, u: f32) -> f64 {
        self.shutter.0 + u as f64 * (self.shutter.1 - self.shutter.0)
    }

    /// A conservative camera-relative box of `corners` (object space) moved by `m(t)` over the
    /// shutter: the box of the corners at `BOUND_SAMPLES` times and at the key times inside the
    /// shutter, grown by half the largest step any corner takes between consecutive times (a
    /// path between two samples stays within half its length of them).
    pub fn bound(
        anim: &Animation,
        shutter: (f64, f64),
        corners: &[DVec3; 8],
        m: impl Fn(f64) -> DMat4,
    ) -> (Vec3, Vec3) {
        let (t0, t1) = shutter;
        let mut times: Vec<f64> =
            (0..=BOUND_SAMPLES).map(|k| t0 + (t1 - t0) * k as f64 / BOUND_SAMPLES as f64).collect();
        times.extend(anim.key_times().filter(|&k| k > t0 && k < t1));
        times.sort_by(f64::total_cmp);
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        let mut previous: Option<[DVec3; 8]> = None;
        let mut step: f64 = 0.0;
        for &t in &times {
            let mt = m(t);
            let placed = corners.map(|c| mt.transform_point3(c));
            for p in placed {
                lo = lo.min(p);
                hi = hi.max(p);
            }
            if let Some(prev) = previous {
                for (a, b) in prev.iter().zip(&placed) {
                    step = step.max(a.distance(*b));
                }
            }
            previous = Some(placed);
        }
        let pad = 0.5 * step + 1e-6 * (hi - lo).max_element().max(1e-6);
        ((lo - pad).as_vec3(), (hi + pad).as_vec3())
    }

    /// The camera as it is at time `t`: `still` when the camera does not move.
    pub fn camera_at(&self, still: &Camera, t: f64) -> PlacedCamera {
        let Some((node, local)) = &self.camera else { return PlacedCamera::still(*still) };
        let m = common::gltf::rigid(self.anim.world(*node, t)).unwrap_or(DMat4::IDENTITY);
        let rel = DMat4::from_translation(-self.origin) * m;
        let turn = Mat3::from_mat4(rel.as_mat4());
        PlacedCamera {
            camera: Camera { to_world: turn * local.to_world, ..*local },
            origin: Some(rel.w_axis.truncate().as_vec3()),
        }
    }

    /// A camera ray generated in camera space, placed where the camera is at time `t`.
    pub fn camera_ray(&self, ray: Ray, t: f64) -> Ray {
        let Some((node, _)) = self.camera else { return ray };
        let m = common::gltf::rigid(self.anim.world(node, t)).unwrap_or(DMat4::IDENTITY);
        let rel = DMat4::from_translation(-self.origin) * m;
        Ray::new(
            rel.transform_point3(ray.origin.as_dvec3()).as_vec3(),
            rel.transform_vector3(ray.dir.as_dvec3()).as_vec3(),
        )
    }
}

/// The placements at one sample's time, evaluated when first needed (one per render thread and
/// sample; not shared).
pub struct Pose<'a> {
    motion: &'a Motion,
    time: f64,
    placed: RefCell<Vec<Option<Placed>>>,
}

impl<'a> Pose<'a> {
    /// Placements of `motion` at time `time`.
    pub fn new(motion: &'a Motion, time: f64) -> Self {
        Pose { motion, time, placed: RefCell::new(vec![None; motion.instances.len()]) }
    }

    /// Moves the pose to another time (keeping its storage: one pose serves a thread's samples).
    pub fn set_time(&mut self, time: f64) {
        self.time = time;
        self.placed.get_mut().fill(None);
    }

    /// Placement `i` at this time.
    pub fn placed(&self, i: usize) -> Placed {
        if let Some(p) = self.placed.borrow()[i] {
            return p;
        }
        let m = self.motion.transform(i, self.time);
        let to_world = m.as_mat4();
        let p = Placed {
            to_world,
            to_object: m.inverse().as_mat4(),
            normal: Mat3::from_mat4(to_world).inverse().transpose(),
        };
        self.placed.borrow_mut()[i] = Some(p);
        p
    }

    /// The motion this pose belongs to.
    pub fn motion(&self) -> &Motion {
        self.motion
    }

    /// Which placement a scene triangle belongs to, and its index in that placement.
    pub fn locate(&self, prim: u32) -> Option<(usize, u32)> {
        let instances = &self.motion.instances;
        let i = instances.partition_point(|inst| inst.prim_base <= prim).checked_sub(1)?;
        Some((i, prim - instances[i].prim_base))
    }

    /// Where placement `i`'s mesh is among its keys at this time, if it deforms.
    fn deforming(&self, i: usize) -> Option<(&'a Deforming, Between)> {
        match &self.motion.instances[i].shape {
            Shape::Deforming(d) => Some((d, d.between(self.time))),
            Shape::Rigid(_) => None,
        }
    }

    /// Triangle `local` of placement `i` (camera-relative world space) at this time.
    pub fn triangle(&self, i: usize, local: u32) -> [Vec3; 3] {
        let tri = match &self.motion.instances[i].shape {
            Shape::Rigid(accel) => accel.triangle(local),
            Shape::Deforming(d) => d.accel.triangle(local, d.between(self.time)),
        };
        let to_world = self.placed(i).to_world;
        tri.map(|p| to_world.transform_point3(p))
    }

    /// Placement `i`'s normal at the scene's vertex `vertex` (world space, not normalised),
    /// `rigid` being the vertex's normal in object space where the mesh does not deform.
    pub fn normal(&self, i: usize, vertex: u32, rigid: Vec3) -> Vec3 {
        let n = self.deforming(i).and_then(|(d, at)| d.normal(vertex, at)).unwrap_or(rigid);
        self.placed(i).normal * n
    }

    /// Placement `i`'s tangent at the scene's vertex `vertex` (world space, unit length, the
    /// handedness in `w` flipped by a mirroring placement), `rigid` being the vertex's tangent in
    /// object space where the mesh does not deform.
    pub fn tangent(&self, i: usize, vertex: u32, rigid: Vec4) -> Vec4 {
        let t = self.deforming(i).and_then(|(d, at)| d.tangent(vertex, at)).unwrap_or(rigid);
        let to_world = self.placed(i).to_world;
        let sign = if to_world.determinant() < 0.0 { -1.0 } else { 1.0 };
        to_world.transform_vector3(t.truncate()).normalize_or_zero().extend(t.w * sign)
    }

    /// The closest hit among the placements nearer than `t_max`, as a scene triangle.
    pub fn intersect(&self, ray: &Ray, t_max: f32, accept: &dyn Fn(&Hit) -> bool) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut limit = t_max;
        for (i, inst) in self.motion.instances.iter().enumerate() {
            if !slab(ray, inst.bounds, limit) {
                continue;
            }
            let p = self.placed(i);
            let local = Ray {
                origin: p.to_object.transform_point3(ray.origin),
                dir: p.to_object.transform_vector3(ray.dir),
                ..*ray
            };
            let base = inst.prim_base;
            let accept = |h: &Hit| accept(&Hit { prim: h.prim + base, ..*h });
            let hit = match &inst.shape {
                Shape::Rigid(accel) => accel.intersect_filtered(&local, limit, accept),
                Shape::Deforming(d) => {
                    d.accel.intersect_filtered(&local, limit, d.between(self.time), accept)
                }
            };
            if let Some(h) = hit {
                limit = h.t;
                best = Some(Hit { prim: h.prim + base, ..h });
            }
        }
        best
    }

    /// Whether any placement blocks the ray before `t_max`.
    pub fn occluded(&self, ray: &Ray, t_max: f32, accept: &dyn Fn(&Hit) -> bool) -> bool {
        self.motion.instances.iter().enumerate().any(|(i, inst)| {
            if !slab(ray, inst.bounds, t_max) {
                return false;
            }
            let p = self.placed(i);
            let local = Ray {
                origin: p.to_object.transform_point3(ray.origin),
                dir: p.to_object.transform_vector3(ray.dir),
                ..*ray
            };
            let base = inst.prim_base;
            let accept = |h: &Hit| accept(&Hit { prim: h.prim + base, ..*h });
            match &inst.shape {
                Shape::Rigid(accel) => accel.occluded_filtered(&local, t_max, accept),
                Shape::Deforming(d) => {
                    d.accel.occluded_filtered(&local, t_max, d.between(self.time), accept)
                }
            }
        })
    }
}

/// Whether the ray meets the box before `t_max`.
fn slab(ray: &Ray, (lo, hi): (Vec3, Vec3), t_max: f32) -> bool {
    let inv = ray.dir.recip();
    let t0 = (lo - ray.origin) * inv;
    let t1 = (hi - ray.origin) * inv;
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element().min(t_max);
    // NaN (a zero direction component on a slab's plane) counts as a hit: conservative.
    !(near > far * (1.0 + 4.0 * f32::EPSILON))
}
