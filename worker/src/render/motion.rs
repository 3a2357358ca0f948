//! Motion blur: what moves within the shutter. Static geometry stays in the world BVH; each
//! animated mesh placement gets its own BVH in object space, entered through its transform at
//! the sample's time (evaluated from the glTF curves, so rotations blur along arcs), under a top
//! level of boxes that bound each placement over the whole shutter. A moving camera is placed
//! at the sample's time too. Only scenes that move within a non-empty shutter build any of this.

use std::{cell::RefCell, sync::Arc};

use common::animation::Animation;
use glam::{DMat4, DVec3, Mat3, Mat4, Vec3};

use super::{
    accel::{Accel, Hit},
    camera::{Camera, PlacedCamera},
    geometry::Ray,
};

/// Times at which a placement's transform is evaluated to bound it over the shutter (key times
/// inside the shutter are added).
const BOUND_SAMPLES: usize = 64;

/// One animated mesh placement.
pub struct MotionInstance {
    /// glTF node that moves it.
    pub node: usize,
    /// Placement relative to the node (`EXT_mesh_gpu_instancing`).
    pub offset: DMat4,
    /// Its triangles in object space.
    pub accel: Accel,
    /// Index of its first triangle in the scene's triangle numbering.
    pub prim_base: u32,
    /// Camera-relative box holding it at every time of the shutter.
    pub bounds: (Vec3, Vec3),
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
        let inst = &self.instances[i];
        DMat4::from_translation(-self.origin) * self.anim.world(inst.node, t) * inst.offset
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
        for node in &anim.nodes {
            if let Some(motion) = &node.motion {
                let keys = [
                    motion.translation.as_ref().map(|c| &c.times),
                    motion.rotation.as_ref().map(|c| &c.times),
                    motion.scale.as_ref().map(|c| &c.times),
                ];
                times.extend(keys.into_iter().flatten().flatten().filter(|&&k| k > t0 && k < t1));
            }
        }
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
            let hit = inst
                .accel
                .intersect_filtered(&local, limit, |h| accept(&Hit { prim: h.prim + base, ..*h }));
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
            inst.accel
                .occluded_filtered(&local, t_max, |h| accept(&Hit { prim: h.prim + base, ..*h }))
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
