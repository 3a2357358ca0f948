//! Ray-scene intersection: an `obvhs` compressed wide BVH over triangles, entered through a
//! watertight ray-triangle test (Woop, Benthin and Wald 2013, with pbrt-v4's conservative
//! distance bound) so that rays never slip through shared edges or re-hit their own surface.
//!
//! Triangles are reordered by `primitive_indices` once at build time; `Accel::build` returns the
//! order so that the caller can reorder its per-triangle shading data the same way.

use std::time::Duration;

use glam::{Vec3, Vec3A};
use obvhs::{
    cwbvh::{builder::build_cwbvh_from_tris, CwBvh},
    ray::{Ray as BvhRay, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};

use super::geometry::{gamma, Ray};

/// A closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Triangle index in build order (see `Accel::build`).
    pub prim: u32,
    /// Distance along the ray in units of its direction.
    pub t: f32,
    /// Barycentric weight of vertex 1.
    pub b1: f32,
    /// Barycentric weight of vertex 2.
    pub b2: f32,
}

/// The acceleration structure with its triangles.
pub struct Accel {
    bvh: CwBvh,
    /// Triangle vertices in BVH order.
    tris: Vec<[Vec3; 3]>,
    /// Length of the direction vectors handed to `obvhs`, a power of two about 2^-20 of the
    /// scene's size. `obvhs` skips boxes closer than t = 1e-4 along a ray (a fixed epsilon in
    /// its node test), which would lose contact shadows in small scenes; in these units that
    /// epsilon is 1e-10 of the scene size whatever its scale. Powers of two keep t exact.
    t_scale: f32,
}

/// Per-ray constants of the watertight test.
struct Shear {
    origin: Vec3,
    /// The axis along which the ray's direction is largest (it becomes z).
    kz: usize,
    s: Vec3,
}

/// Rotates coordinates so that axis `kz` becomes z (x and y follow cyclically).
#[inline(always)]
fn permute(v: Vec3, kz: usize) -> Vec3 {
    match kz {
        0 => Vec3::new(v.y, v.z, v.x),
        1 => Vec3::new(v.z, v.x, v.y),
        _ => v,
    }
}

impl Shear {
    #[inline]
    fn new(ray: &Ray) -> Self {
        let d = ray.dir;
        let a = d.abs();
        let kz = if a.x > a.y {
            if a.x > a.z {
                0
            } else {
                2
            }
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let d = permute(d, kz);
        Shear { origin: ray.origin, kz, s: Vec3::new(-d.x / d.z, -d.y / d.z, 1.0 / d.z) }
    }

    /// Returns (t, b1, b2) for a hit with `t` in (0, t_max).
    #[inline]
    fn intersect(&self, tri: &[Vec3; 3], t_max: f32) -> Option<(f32, f32, f32)> {
        let kz = self.kz;
        let rel = |p: Vec3| permute(p - self.origin, kz);
        let (mut p0, mut p1, mut p2) = (rel(tri[0]), rel(tri[1]), rel(tri[2]));
        let s = self.s;
        p0.x += s.x * p0.z;
        p0.y += s.y * p0.z;
        p1.x += s.x * p1.z;
        p1.y += s.y * p1.z;
        p2.x += s.x * p2.z;
        p2.y += s.y * p2.z;
        // Edge functions; exactly zero in f32 means the ray passes (nearly) through an edge or a
        // vertex, and the sign is then decided in f64 (Woop et al.): rays through a shared edge
        // see the same value with opposite signs from both triangles and never slip between.
        let mut e0 = p1.x * p2.y - p1.y * p2.x;
        let mut e1 = p2.x * p0.y - p2.y * p0.x;
        let mut e2 = p0.x * p1.y - p0.y * p1.x;
        if e0 == 0.0 || e1 == 0.0 || e2 == 0.0 {
            e0 = difference_of_products(p1.x, p2.y, p1.y, p2.x);
            e1 = difference_of_products(p2.x, p0.y, p2.y, p0.x);
            e2 = difference_of_products(p0.x, p1.y, p0.y, p1.x);
        }
        if (e0 < 0.0 || e1 < 0.0 || e2 < 0.0) && (e0 > 0.0 || e1 > 0.0 || e2 > 0.0) {
            return None;
        }
        let det = e0 + e1 + e2;
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let (z0, z1, z2) = (p0.z * s.z, p1.z * s.z, p2.z * s.z);
        let t_scaled = e0 * z0 + e1 * z1 + e2 * z2;
        if det < 0.0 && (t_scaled >= 0.0 || t_scaled < t_max * det) {
            return None;
        }
        if det > 0.0 && (t_scaled <= 0.0 || t_scaled > t_max * det) {
            return None;
        }
        let inv_det = 1.0 / det;
        let t = t_scaled * inv_det;
        // Conservative bound on t's rounding error (pbrt-v4): a hit closer than that may be the
        // surface the ray leaves from.
        let max_zt = z0.abs().max(z1.abs()).max(z2.abs());
        let delta_z = gamma(3) * max_zt;
        let max_xt = p0.x.abs().max(p1.x.abs()).max(p2.x.abs());
        let max_yt = p0.y.abs().max(p1.y.abs()).max(p2.y.abs());
        let delta_x = gamma(5) * (max_xt + max_zt);
        let delta_y = gamma(5) * (max_yt + max_zt);
        let delta_e = 2.0 * (gamma(2) * max_xt * max_yt + delta_y * max_xt + delta_x * max_yt);
        let max_e = e0.abs().max(e1.abs()).max(e2.abs());
        let delta_t =
            3.0 * (gamma(3) * max_e * max_zt + delta_e * max_zt + delta_z * max_e) * inv_det.abs();
        if t <= delta_t || t >= t_max {
            return None;
        }
        Some((t, e1 * inv_det, e2 * inv_det))
    }
}

/// a * b - c * d rounded once: f32 products are exact in f64.
#[inline]
fn difference_of_products(a: f32, b: f32, c: f32, d: f32) -> f32 {
    (a as f64 * b as f64 - c as f64 * d as f64) as f32
}

/// 1 / x, finite (keeps the slab test free of inf * 0). `x` is never -0.0 here.
#[inline]
fn finite_inverse(x: f32) -> f32 {
    let inv = 1.0 / x;
    if inv.is_finite() {
        inv
    } else {
        1e30f32.copysign(x)
    }
}

impl Accel {
    /// Builds the BVH. Returns the structure and `order`, where `order[i]` is the input index of
    /// the triangle that `Hit::prim == i` refers to.
    pub fn build(triangles: &[[Vec3; 3]]) -> (Accel, Vec<u32>) {
        if triangles.is_empty() {
            return (Accel { bvh: CwBvh::default(), tris: Vec::new(), t_scale: 1.0 }, Vec::new());
        }
        let bvh_tris: Vec<Triangle> = triangles
            .iter()
            .map(|t| Triangle { v0: t[0].into(), v1: t[1].into(), v2: t[2].into() })
            .collect();
        // Build quality against build time: large scenes must build in well under 2 s (1M
        // triangles: 0.75 s with `fast_build`); smaller ones get one triangle per leaf (5% faster
        // on the Cornell box than up to three; `very_slow_build` quality measured no faster).
        // Never `pre_split`: it lists a triangle in several leaves, and every triangle must have
        // exactly one index here (lights and shading data are per index).
        let params = if triangles.len() > 200_000 {
            BvhBuildParams::fast_build()
        } else {
            BvhBuildParams { max_prims_per_leaf: 1, ..BvhBuildParams::medium_build() }
        };
        let mut bvh = build_cwbvh_from_tris(&bvh_tris, params, &mut Duration::default());
        let order = std::mem::take(&mut bvh.primitive_indices);
        let tris = order.iter().map(|&i| triangles[i as usize]).collect();
        bvh.primitive_indices = (0..order.len() as u32).collect();
        let extent = (bvh.total_aabb.max - bvh.total_aabb.min).max_element();
        let extent = if extent.is_finite() && extent > 0.0 { extent } else { 1.0 };
        let t_scale = (extent.log2().round() - 20.0).clamp(-120.0, 100.0).exp2();
        (Accel { bvh, tris, t_scale }, order)
    }

    /// The `obvhs` ray for `ray` (direction scaled by `t_scale`, t in those units).
    #[inline]
    fn bvh_ray(&self, ray: &Ray, t_max: f32) -> BvhRay {
        // `+ 0.0` turns -0.0 into +0.0: obvhs picks slab ends by `direction < 0.0`, which must
        // agree with the sign of the inverse (1 / -0.0 is -inf).
        let d = ray.dir * self.t_scale + Vec3::ZERO;
        BvhRay {
            origin: Vec3A::from(ray.origin),
            direction: Vec3A::from(d),
            inv_direction: Vec3A::new(
                finite_inverse(d.x),
                finite_inverse(d.y),
                finite_inverse(d.z),
            ),
            tmin: 0.0,
            tmax: t_max / self.t_scale,
        }
    }

    /// Bytes held by the BVH nodes and the triangle vertices.
    pub fn memory_bytes(&self) -> usize {
        self.bvh.nodes.len() * std::mem::size_of::<obvhs::cwbvh::node::CwBvhNode>()
            + self.tris.len() * std::mem::size_of::<[Vec3; 3]>()
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.tris.len()
    }

    /// True when there is nothing to hit.
    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Vertices of triangle `prim` (build order).
    #[inline]
    pub fn triangle(&self, prim: u32) -> &[Vec3; 3] {
        &self.tris[prim as usize]
    }

    /// The closest hit with `t` in (0, t_max).
    #[inline]
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        self.intersect_filtered(ray, t_max, |_| true)
    }

    /// The closest hit with `t` in (0, t_max) that `accept` keeps (alpha-tested surfaces).
    #[inline]
    pub fn intersect_filtered(
        &self,
        ray: &Ray,
        t_max: f32,
        accept: impl Fn(&Hit) -> bool,
    ) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        let shear = Shear::new(ray);
        let mut best: Option<Hit> = None;
        let mut hit = RayHit::none();
        let scale = self.t_scale;
        self.bvh.ray_traverse(self.bvh_ray(ray, t_max), &mut hit, |bvh_ray, id| {
            match shear.intersect(&self.tris[id], bvh_ray.tmax * scale) {
                Some((t, b1, b2)) => {
                    let candidate = Hit { prim: id as u32, t, b1, b2 };
                    if !accept(&candidate) {
                        return f32::INFINITY;
                    }
                    best = Some(candidate);
                    t / scale
                }
                None => f32::INFINITY,
            }
        });
        best
    }

    /// Whether anything blocks the ray for `t` in (0, t_max). Stops at the first blocker.
    #[inline]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        self.occluded_filtered(ray, t_max, |_| true)
    }

    /// Whether anything that `accept` keeps blocks the ray for `t` in (0, t_max).
    #[inline]
    pub fn occluded_filtered(&self, ray: &Ray, t_max: f32, accept: impl Fn(&Hit) -> bool) -> bool {
        if self.tris.is_empty() {
            return false;
        }
        let shear = Shear::new(ray);
        let scale = self.t_scale;
        !self.bvh.ray_traverse_miss(self.bvh_ray(ray, t_max), |bvh_ray, id| {
            match shear.intersect(&self.tris[id], bvh_ray.tmax * scale) {
                Some((t, b1, b2)) if accept(&Hit { prim: id as u32, t, b1, b2 }) => t / scale,
                _ => f32::INFINITY,
            }
        })
    }

    /// Brute-force closest hit over every triangle (reference for tests and tiny scenes).
    pub fn intersect_brute_force(&self, ray: &Ray, t_max: f32) -> Option<Hit> {
        let shear = Shear::new(ray);
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        for (i, tri) in self.tris.iter().enumerate() {
            if let Some((t, b1, b2)) = shear.intersect(tri, t_best) {
                t_best = t;
                best = Some(Hit { prim: i as u32, t, b1, b2 });
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::sampler::mix64;

    struct Rng(u64);
    impl Rng {
        fn f(&mut self) -> f32 {
            self.0 = mix64(self.0.wrapping_add(0x9e37_79b9_7f4a_7c15));
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }
        fn v(&mut self, scale: f32) -> Vec3 {
            Vec3::new(self.f() - 0.5, self.f() - 0.5, self.f() - 0.5) * scale
        }
    }

    #[test]
    fn bvh_agrees_with_brute_force_on_random_soups() {
        let mut rng = Rng(42);
        for soup in 0..8 {
            let n = [1, 2, 7, 50, 300, 1000, 3000, 5000][soup];
            let mut tris: Vec<[Vec3; 3]> = (0..n)
                .map(|_| {
                    let c = rng.v(10.0);
                    let size = 0.1 + rng.f() * 2.0;
                    [c + rng.v(size), c + rng.v(size), c + rng.v(size)]
                })
                .collect();
            // Degenerate ones too: a point, a needle, collinear vertices.
            let c = rng.v(5.0);
            tris.push([c, c, c]);
            tris.push([c, c + Vec3::X, c + 2.0 * Vec3::X]);
            tris.push([c, c + Vec3::Y * 3.0, c + Vec3::Y * 3.0 + Vec3::X * 1e-7]);
            let (accel, order) = Accel::build(&tris);
            assert_eq!(order.len(), tris.len());
            for _ in 0..2000 {
                let o = rng.v(14.0);
                let dir = (rng.v(2.0) + Vec3::splat(1e-4)).normalize();
                let ray = Ray::new(o, dir);
                let t_max = if rng.f() < 0.3 { rng.f() * 10.0 } else { f32::INFINITY };
                let a = accel.intersect(&ray, t_max);
                let b = accel.intersect_brute_force(&ray, t_max);
                match (a, b) {
                    (None, None) => {}
                    (Some(a), Some(b)) => {
                        assert_eq!(a.t, b.t, "soup {soup}: t differs");
                    }
                    _ => panic!("soup {soup}: bvh {a:?} vs brute force {b:?}"),
                }
                assert_eq!(accel.occluded(&ray, t_max), b.is_some(), "soup {soup}: occlusion");
            }
        }
    }

    #[test]
    fn rays_through_a_shared_edge_never_leak() {
        // A square of two triangles; rays aimed exactly at the diagonal must hit one of them.
        let quad = [
            [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0)],
            [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 0.0)],
        ];
        let (accel, _) = Accel::build(&quad);
        let mut rng = Rng(5);
        for i in 0..10_000 {
            // Points strictly inside the diagonal (its end points are the square's corners,
            // where a ray may legitimately graze past).
            let s = (i as f32 + 0.5) / 10_000.0;
            let target = Vec3::new(s, s, 0.0);
            let o = Vec3::new(rng.f() * 4.0 - 2.0, rng.f() * 4.0 - 2.0, 1.0 + rng.f());
            let ray = Ray::new(o, (target - o).normalize());
            assert!(accel.intersect(&ray, f32::INFINITY).is_some(), "leak at {target}");
        }
    }

    #[test]
    fn barycentrics_reconstruct_the_hit_point() {
        let tri =
            [Vec3::new(-1.0, -1.0, -3.0), Vec3::new(2.0, -1.0, -3.0), Vec3::new(0.0, 2.0, -3.5)];
        let (accel, _) = Accel::build(&[tri]);
        let ray = Ray::new(Vec3::ZERO, Vec3::new(0.1, 0.05, -1.0).normalize());
        let hit = accel.intersect(&ray, f32::INFINITY).unwrap();
        let p = tri[0] * (1.0 - hit.b1 - hit.b2) + tri[1] * hit.b1 + tri[2] * hit.b2;
        assert!((p - (ray.origin + ray.dir * hit.t)).length() < 1e-5);
    }

    #[test]
    fn nearby_hits_are_found_at_every_scale() {
        // Two triangles facing each other a tiny distance apart: the BVH must find the hit
        // however small the scene (obvhs alone skips boxes closer than t = 1e-4).
        for scale in [1e-6f32, 1e-3, 1.0, 1e4] {
            let floor =
                [Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 0.0, -1.0), Vec3::new(0.0, 0.0, 1.0)];
            let roof = floor.map(|p| (p + Vec3::Y * 1e-3) * scale);
            let floor = floor.map(|p| p * scale);
            let (accel, _) = Accel::build(&[floor, roof]);
            let ray = Ray::new(Vec3::new(0.0, 5e-4, 0.0) * scale, Vec3::Y);
            let hit = accel.intersect(&ray, f32::INFINITY).expect("hit");
            assert!((hit.t - 5e-4 * scale).abs() < 1e-6 * scale, "scale {scale}: t {}", hit.t);
            let down = Ray::new(ray.origin, -Vec3::Y);
            assert!(accel.intersect(&down, f32::INFINITY).is_some(), "scale {scale}: down");
            assert!(accel.occluded(&down, f32::INFINITY), "scale {scale}: occlusion");
        }
    }

    #[test]
    fn empty_scene_hits_nothing() {
        let (accel, _) = Accel::build(&[]);
        let ray = Ray::new(Vec3::ZERO, Vec3::Z);
        assert!(accel.intersect(&ray, f32::INFINITY).is_none());
        assert!(!accel.occluded(&ray, f32::INFINITY));
    }
}
