//! Rays, shading frames and robust ray origins: the small geometric vocabulary of the renderer.
//!
//! World coordinates here are camera-relative f32 (see `scene::prepare`), so precision is best
//! where the camera looks. Secondary rays leave surfaces through `offset_ray_origin`, which moves
//! them past a conservative bound on the hit point's rounding error (pbrt-v4) instead of a fixed
//! epsilon, so it works at any scene scale.

use glam::Vec3;

use super::lanes::{Real, V3};

/// A ray `origin + t * dir` for `t` in `[0, t_max)`.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Start point.
    pub origin: Vec3,
    /// Direction (unit length for camera and bounce rays).
    pub dir: Vec3,
    /// Whether the origin lies inside a medium, on no surface: the intersector then finds
    /// surfaces however close, instead of taking hits within its rounding-error bound for the
    /// surface a ray leaves (which would let a ray scattered just inside a volume slip out
    /// through its boundary).
    pub interior: bool,
}

impl Ray {
    /// A ray from a camera or a surface.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir, interior: false }
    }

    /// A ray from a point inside a medium (a scattering event), on no surface.
    pub fn interior(origin: Vec3, dir: Vec3) -> Self {
        Ray { origin, dir, interior: true }
    }
}

/// An orthonormal basis whose `z` is the given normal.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Tangent.
    pub x: Vec3,
    /// Bitangent.
    pub y: Vec3,
    /// Normal.
    pub z: Vec3,
}

impl Frame {
    /// A frame around unit vector `n` (Duff et al. 2017, branchless).
    #[inline]
    pub fn from_z(n: Vec3) -> Self {
        let (x, y) = generic::frame_from_z(n.into());
        Frame { x: x.into(), y: y.into(), z: n }
    }

    /// A frame from a normal and an approximate tangent (Gram-Schmidt); falls back to `from_z`
    /// when the tangent is parallel to the normal.
    #[inline]
    pub fn from_z_and_tangent(n: Vec3, tangent: Vec3) -> Self {
        let t = tangent - n * n.dot(tangent);
        let len2 = t.length_squared();
        if !(len2 > 1e-12) {
            return Frame::from_z(n);
        }
        let x = t / len2.sqrt();
        Frame { x, y: n.cross(x), z: n }
    }

    /// World to local coordinates.
    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.x), v.dot(self.y), v.dot(self.z))
    }

    /// Local to world coordinates.
    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.x * v.x + self.y * v.y + self.z * v.z
    }
}

/// gamma(n) of Higham's error analysis: a bound on n rounding errors.
#[inline]
pub fn gamma(n: i32) -> f32 {
    let e = f32::EPSILON * 0.5;
    n as f32 * e / (1.0 - n as f32 * e)
}

/// Conservative absolute error of a point interpolated from triangle vertices with barycentrics
/// `b` (pbrt-v4 `Triangle::InteractionFromIntersection`).
#[inline]
pub fn interpolation_error(p: [Vec3; 3], b: [f32; 3]) -> Vec3 {
    generic::interpolation_error(p.map(V3::from), b).into()
}

/// Moves surface point `p`, known within `p_error` per axis, off the surface along normal `n` to
/// the side of direction `w`: just past the error bound, then one more float step away. The
/// offset scales with the coordinates involved, so it works at any scene scale (pbrt-v4
/// `OffsetRayOrigin`).
#[inline]
pub fn offset_ray_origin(p: Vec3, p_error: Vec3, n: Vec3, w: Vec3) -> Vec3 {
    generic::offset_ray_origin(p.into(), p_error.into(), n.into(), w.into()).into()
}

/// The routines above written once over `Real`: for one path (`f32`, through the `Vec3`
/// functions above) and for a vector of paths (the wavefront).
pub(crate) mod generic {
    /// `super::reflect`: `2 (v.n) n - v`.
    #[inline(always)]
    pub(crate) fn reflect<R: Real>(v: V3<R>, n: V3<R>) -> V3<R> {
        n.scale(v.x.konst(2.0) * v.dot(n)) - v
    }

    use super::{gamma, Real, V3};

    /// `Frame::from_z`'s tangent and bitangent of unit normal `n`.
    #[inline(always)]
    pub(crate) fn frame_from_z<R: Real>(n: V3<R>) -> (V3<R>, V3<R>) {
        let one = n.z.konst(1.0);
        let sign = one.copysign(n.z);
        let a = n.z.konst(-1.0) / (sign + n.z);
        let b = n.x * n.y * a;
        let x = V3::new(one + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let y = V3::new(b, sign + n.y * n.y * a, -n.y);
        (x, y)
    }

    /// `super::interpolation_error`.
    #[inline(always)]
    pub(crate) fn interpolation_error<R: Real>(p: [V3<R>; 3], b: [R; 3]) -> V3<R> {
        (p[0].scale(b[0]).abs() + p[1].scale(b[1]).abs() + p[2].scale(b[2]).abs())
            .scale(b[0].konst(gamma(7)))
    }

    /// `super::offset_ray_origin`.
    #[inline(always)]
    pub(crate) fn offset_ray_origin<R: Real>(
        p: V3<R>,
        p_error: V3<R>,
        n: V3<R>,
        w: V3<R>,
    ) -> V3<R> {
        let d = n.abs().dot(p_error);
        let offset = n.scale(d);
        let offset = V3::select(w.dot(n).lt(d.konst(0.0)), -offset, offset);
        let po = p + offset;
        V3::new(step_away(po.x, offset.x), step_away(po.y, offset.y), step_away(po.z, offset.z))
    }

    /// One float step from `v` in the direction of `o`'s sign (none when `o` is zero).
    ///
    /// Written with selects, not branches: the sign of an offset is as likely one way as the
    /// other, and a mispredicted branch here cost more than the arithmetic (three per ray origin).
    #[inline(always)]
    pub(crate) fn step_away<R: Real>(v: R, o: R) -> R {
        let zero = v.konst(0.0);
        let bits = v.to_bits();
        let one = v.konst_bits(1);
        // Moving away from zero adds one to the magnitude's bits; toward zero subtracts one.
        let away = !(v.ge(zero) ^ o.gt(zero));
        let stepped = R::select_bits(away, R::bits_add(bits, one), R::bits_sub(bits, one));
        // From zero the step is the smallest subnormal on `o`'s side.
        let from_zero = R::select_bits(o.gt(zero), one, v.konst_bits(0x8000_0001));
        let stepped = R::select_bits(v.eq(zero), from_zero, stepped);
        let keep = o.eq(zero) | !v.is_finite();
        R::from_bits(R::select_bits(keep, bits, stepped))
    }
}

/// The smallest float greater than `v`.
#[inline]
pub fn next_float_up(v: f32) -> f32 {
    if v.is_infinite() && v > 0.0 {
        return v;
    }
    let v = if v == -0.0 { 0.0 } else { v };
    let bits = v.to_bits();
    f32::from_bits(if v >= 0.0 { bits + 1 } else { bits - 1 })
}

/// The largest float less than `v`.
#[inline]
pub fn next_float_down(v: f32) -> f32 {
    -next_float_up(-v)
}

/// Reflects `v` about `n` (both pointing away from the surface).
#[inline]
pub fn reflect(v: Vec3, n: Vec3) -> Vec3 {
    generic::reflect(v.into(), n.into()).into()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal() {
        for n in [Vec3::Z, -Vec3::Z, Vec3::X, Vec3::new(0.3, -0.5, 0.81).normalize()] {
            let f = Frame::from_z(n);
            assert!(f.x.dot(f.y).abs() < 1e-6 && f.x.dot(f.z).abs() < 1e-6);
            assert!((f.x.length() - 1.0).abs() < 1e-6 && (f.y.length() - 1.0).abs() < 1e-6);
            let v = Vec3::new(0.2, 0.4, -0.7);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-6);
            assert!(f.x.cross(f.y).dot(f.z) > 0.99, "right-handed");
        }
    }

    #[test]
    fn offset_moves_to_the_normal_side_at_every_scale() {
        for scale in [1e-4f32, 1e-2, 1.0, 1e3, 1e5] {
            let tri = [
                Vec3::new(0.37, -0.81, 0.55),
                Vec3::new(0.5, -0.8, 0.55),
                Vec3::new(0.4, -0.6, 0.55),
            ]
            .map(|p| p * scale);
            let b = [0.2, 0.3, 0.5];
            let p = tri[0] * b[0] + tri[1] * b[1] + tri[2] * b[2];
            let err = interpolation_error(tri, b);
            let n = Vec3::Z;
            let q = offset_ray_origin(p, err, n, n);
            assert!(q.z > p.z + err.z, "scale {scale}: {q} not past the error bound of {p}");
            assert!((q.z - p.z) <= 1e-5 * scale, "scale {scale}: offset too large");
            let below = offset_ray_origin(p, err, n, -n);
            assert!(below.z < p.z - err.z);
        }
    }

    #[test]
    fn a_step_away_moves_one_float_toward_the_offset() {
        let tiny = f32::from_bits(1);
        let cases = [
            (1.0, 1.0, next_float_up(1.0)),
            (1.0, -1.0, next_float_down(1.0)),
            (-1.0, 1.0, next_float_up(-1.0)),
            (-1.0, -1.0, next_float_down(-1.0)),
            (0.0, 2.0, tiny),
            (-0.0, 2.0, tiny),
            (0.0, -2.0, -tiny),
            (-0.0, -2.0, -tiny),
            (3.5, 0.0, 3.5),
            (3.5, -0.0, 3.5),
            (f32::INFINITY, 1.0, f32::INFINITY),
            (f32::MAX, 1.0, f32::INFINITY),
        ];
        for (v, o, want) in cases {
            assert_eq!(generic::step_away(v, o).to_bits(), want.to_bits(), "step_away({v}, {o})");
        }
        assert!(generic::step_away(f32::NAN, 1.0).is_nan());
    }
}
