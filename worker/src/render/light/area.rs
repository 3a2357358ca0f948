//! Emissive triangles as area lights, sampled uniformly over their area and converted to solid
//! angle at the receiver.

use glam::{Vec2, Vec3};

use super::LightSample;
use crate::render::{
    geometry::Frame,
    lanes::V3,
    sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere, sample_uniform_triangle},
};

/// One emissive triangle.
#[derive(Clone, Copy, Debug)]
pub struct TriangleLight {
    /// Vertices (camera-relative world space).
    pub p: [Vec3; 3],
    /// Unit geometric normal of the front face (counter-clockwise winding).
    pub normal: Vec3,
    /// Area.
    pub area: f32,
    /// Emitted radiance.
    pub emission: Vec3,
    /// Emits from both faces (a `doubleSided` material).
    pub two_sided: bool,
    /// The triangle's index in the BVH order (to evaluate textured emission).
    pub prim: u32,
    /// Whether emission varies over the triangle or with direction (an emissive texture, a
    /// clear coat over it): `emission` is then its mean (without the coat), used for choosing
    /// lights, and the integrator evaluates the material's emission at the point.
    pub textured: bool,
}

impl TriangleLight {
    /// A light for triangle `p`; `None` for a degenerate triangle (no area, nothing emitted).
    pub fn new(p: [Vec3; 3], emission: Vec3, two_sided: bool) -> Option<Self> {
        let c = (p[1] - p[0]).cross(p[2] - p[0]);
        let len = c.length();
        if !(len > 0.0) || !len.is_finite() {
            return None;
        }
        Some(TriangleLight {
            p,
            normal: c / len,
            area: 0.5 * len,
            emission,
            two_sided,
            prim: u32::MAX,
            textured: false,
        })
    }

    /// Whether light leaves toward direction `w` (unit, pointing away from the light): the
    /// front face (counter-clockwise winding) only, unless the material is double-sided.
    #[inline]
    pub fn emits_toward(&self, w: Vec3) -> bool {
        self.two_sided || self.normal.dot(w) > 0.0
    }

    /// Radiance leaving toward direction `w` (the mean for textured emitters).
    #[inline]
    pub fn radiance(&self, w: Vec3) -> Vec3 {
        if self.emits_toward(w) {
            self.emission
        } else {
            Vec3::ZERO
        }
    }

    /// Samples a point uniformly over the area.
    #[inline]
    pub fn sample_li(&self, receiver: Vec3, u: Vec2) -> Option<LightSample> {
        let t = generic::sample_li(
            self.p.map(V3::from),
            self.normal.into(),
            self.area,
            self.emission.into(),
            self.two_sided,
            receiver.into(),
            (u.x, u.y),
        );
        t.ok.then(|| LightSample {
            li: t.li.into(),
            wi: t.wi.into(),
            point: Some(t.point.into()),
            normal: self.normal,
            point_error: t.point_error.into(),
            barycentrics: t.b,
            pdf: t.pdf,
            is_delta: false,
        })
    }

    /// Samples light leaving the triangle (for a light subpath): a point uniformly over the
    /// area (`u_pos`), then a direction cosine-distributed about the normal of an emitting face
    /// (`u_dir`; a two-sided light picks its face with `u_dir.x`). Returns the barycentrics, the
    /// direction and its density per solid angle (the point's is 1 / area).
    #[inline]
    pub fn sample_le(&self, u_pos: Vec2, u_dir: Vec2) -> Option<([f32; 3], Vec3, f32)> {
        let (b0, b1) = sample_uniform_triangle(u_pos);
        let b = [b0, b1, 1.0 - b0 - b1];
        let (mut n, mut u) = (self.normal, u_dir);
        if self.two_sided {
            if u.x < 0.5 {
                u.x *= 2.0;
            } else {
                u.x = (u.x - 0.5) * 2.0;
                n = -n;
            }
            u.x = u.x.min(1.0 - f32::EPSILON / 2.0);
        }
        let local = sample_cosine_hemisphere(u);
        let pdf = self.pdf_le(local.z);
        (pdf > 0.0).then(|| (b, Frame::from_z(n).to_world(local), pdf))
    }

    /// Density per solid angle of `sample_le` choosing a direction whose cosine to the emitting
    /// face's normal is `cos` (0 for a face that does not emit).
    #[inline]
    pub fn pdf_le(&self, cos: f32) -> f32 {
        if cos <= 0.0 && !self.two_sided {
            return 0.0;
        }
        let pdf = cosine_hemisphere_pdf(cos.abs());
        if self.two_sided {
            0.5 * pdf
        } else {
            pdf
        }
    }

    /// Density of `sample_li` at a point on the light seen along `wi` at distance² `dist2`.
    #[inline]
    pub fn pdf_li(&self, wi: Vec3, dist2: f32) -> f32 {
        generic::pdf_li(self.normal.into(), self.area, wi.into(), dist2)
    }
}

/// `TriangleLight::sample_li` and `pdf_li` written once over `Real`: for one receiver (`f32`) and for a
/// vector of them (the wavefront).
pub(crate) mod generic {
    use super::super::super::{
        geometry::generic::interpolation_error,
        lanes::{Real, V3},
        sampling::generic::sample_uniform_triangle,
    };

    /// A point sampled on an emitting triangle for a receiver.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct TriangleSample<R: Real> {
        /// Radiance arriving (the emission, or zero from behind a one-sided light).
        pub(crate) li: V3<R>,
        /// Unit direction from the receiver toward the point.
        pub(crate) wi: V3<R>,
        /// The point and its rounding-error bound.
        pub(crate) point: V3<R>,
        pub(crate) point_error: V3<R>,
        /// Its barycentrics.
        pub(crate) b: [R; 3],
        /// Density per solid angle at the receiver.
        pub(crate) pdf: R,
        /// Whether the sample carries light (a point at a distance, seen from its emitting side,
        /// of finite density).
        pub(crate) ok: R::Mask,
    }

    /// `TriangleLight::pdf_li` of a triangle of unit normal `normal` and area `area`.
    #[inline(always)]
    pub(crate) fn pdf_li<R: Real>(normal: V3<R>, area: R, wi: V3<R>, dist2: R) -> R {
        let zero = area.konst(0.0);
        let cos_light = normal.dot(wi).abs();
        R::select(cos_light.eq(zero), zero, dist2 / (cos_light * area))
    }

    /// A point uniformly over triangle `p` (unit normal `normal`, area `area`, radiance
    /// `emission` from the front face, or both when `two_sided`) seen from `receiver`.
    #[inline(always)]
    pub(crate) fn sample_li<R: Real>(
        p: [V3<R>; 3],
        normal: V3<R>,
        area: R,
        emission: V3<R>,
        two_sided: R::Mask,
        receiver: V3<R>,
        u: (R, R),
    ) -> TriangleSample<R> {
        let zero = area.konst(0.0);
        let (b0, b1) = sample_uniform_triangle(u.0, u.1);
        let b = [b0, b1, (area.konst(1.0) - b0) - b1];
        let point = p[0].scale(b[0]) + p[1].scale(b[1]) + p[2].scale(b[2]);
        let to_light = point - receiver;
        let dist2 = to_light.length_squared();
        let wi = to_light.div(dist2.sqrt());
        let cos_light = normal.dot(-wi);
        let li = V3::select(two_sided | cos_light.gt(zero), emission, V3::new(zero, zero, zero));
        let pdf = dist2 / (cos_light.abs() * area);
        let ok = dist2.gt(zero) & !(li.is_zero() | cos_light.eq(zero)) & pdf.is_finite();
        TriangleSample { li, wi, point, point_error: interpolation_error(p, b), b, pdf, ok }
    }
}
