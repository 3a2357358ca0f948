//! Emissive triangles as area lights, sampled uniformly over their area and converted to solid
//! angle at the receiver.

use glam::{Vec2, Vec3};

use super::LightSample;
use crate::render::{
    geometry::{interpolation_error, Frame},
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
        let (b0, b1) = sample_uniform_triangle(u);
        let b = [b0, b1, 1.0 - b0 - b1];
        let point = self.p[0] * b[0] + self.p[1] * b[1] + self.p[2] * b[2];
        let to_light = point - receiver;
        let dist2 = to_light.length_squared();
        if !(dist2 > 0.0) {
            return None;
        }
        let wi = to_light / dist2.sqrt();
        let cos_light = self.normal.dot(-wi);
        let li = self.radiance(-wi);
        if li == Vec3::ZERO || cos_light == 0.0 {
            return None;
        }
        let pdf = dist2 / (cos_light.abs() * self.area);
        if !pdf.is_finite() {
            return None;
        }
        Some(LightSample {
            li,
            wi,
            point: Some(point),
            normal: self.normal,
            point_error: interpolation_error(self.p, b),
            barycentrics: b,
            pdf,
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
        let cos_light = self.normal.dot(wi).abs();
        if cos_light == 0.0 {
            return 0.0;
        }
        dist2 / (cos_light * self.area)
    }
}
