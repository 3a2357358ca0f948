//! `KHR_lights_punctual` lights: point (radiant intensity), spot (intensity with the spec's
//! smooth cone falloff) and directional (irradiance). All are delta lights.

use glam::Vec3;

use super::LightSample;

/// A point light.
#[derive(Clone, Copy, Debug)]
pub struct PointLight {
    /// Position.
    pub position: Vec3,
    /// Radiant intensity (W/sr, RGB).
    pub intensity: Vec3,
}

impl PointLight {
    /// The only direction to the light, with inverse-square falloff.
    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<LightSample> {
        let d = self.position - p;
        let dist2 = d.length_squared();
        if !(dist2 > 0.0) {
            return None;
        }
        Some(LightSample {
            li: self.intensity / dist2,
            wi: d / dist2.sqrt(),
            point: Some(self.position),
            normal: Vec3::ZERO,
            point_error: Vec3::ZERO,
            barycentrics: [0.0; 3],
            pdf: 1.0,
            is_delta: true,
        })
    }
}

/// The spot falloff of KHR_lights_punctual at `cos_angle` from the axis: a smoothstep-like
/// square of a linear ramp between the outer and inner cone.
#[inline]
pub fn spot_falloff(cos_angle: f32, cos_inner: f32, cos_outer: f32) -> f32 {
    let scale = 1.0 / (cos_inner - cos_outer).max(0.001);
    let offset = -cos_outer * scale;
    let a = (cos_angle * scale + offset).clamp(0.0, 1.0);
    a * a
}

/// A spot light.
#[derive(Clone, Copy, Debug)]
pub struct SpotLight {
    /// Position.
    pub position: Vec3,
    /// Unit axis the light points along.
    pub direction: Vec3,
    /// Radiant intensity on the axis.
    pub intensity: Vec3,
    /// cos(innerConeAngle).
    pub cos_inner: f32,
    /// cos(outerConeAngle).
    pub cos_outer: f32,
}

impl SpotLight {
    /// Toward the light, attenuated by the cone: a point light seen through the falloff.
    #[inline]
    pub fn sample_li(&self, p: Vec3) -> Option<LightSample> {
        let point = PointLight { position: self.position, intensity: self.intensity };
        let mut ls = point.sample_li(p)?;
        let falloff = spot_falloff(self.direction.dot(-ls.wi), self.cos_inner, self.cos_outer);
        if falloff <= 0.0 {
            return None;
        }
        ls.li *= falloff;
        Some(ls)
    }

    /// The integral of the falloff over the sphere of directions (emitted power / intensity).
    pub fn cone_solid_angle_weight(&self) -> f32 {
        // Midpoint rule in cos(theta) over the cone: exact enough for choosing lights.
        let n = 256;
        let mut sum = 0.0;
        for i in 0..n {
            let c = self.cos_outer + (1.0 - self.cos_outer) * (i as f32 + 0.5) / n as f32;
            sum += spot_falloff(c, self.cos_inner, self.cos_outer);
        }
        2.0 * std::f32::consts::PI * sum * (1.0 - self.cos_outer) / n as f32
    }
}

/// A directional light (the sun).
#[derive(Clone, Copy, Debug)]
pub struct DirectionalLight {
    /// Unit direction toward the light (opposite to where it shines).
    pub to_light: Vec3,
    /// Irradiance on a surface facing the light.
    pub irradiance: Vec3,
}

impl DirectionalLight {
    /// The only direction, at infinity.
    #[inline]
    pub fn sample_li(&self) -> Option<LightSample> {
        Some(LightSample {
            li: self.irradiance,
            wi: self.to_light,
            point: None,
            normal: Vec3::ZERO,
            point_error: Vec3::ZERO,
            barycentrics: [0.0; 3],
            pdf: 1.0,
            is_delta: true,
        })
    }
}
