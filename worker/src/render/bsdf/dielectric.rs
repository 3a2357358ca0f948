//! A smooth dielectric interface: the boundary of a refractive volume (`KHR_materials_volume`
//! with `KHR_materials_transmission`), glass or water with a polished surface.
//!
//! Both lobes are delta distributions: mirror reflection with the exact (unpolarised) Fresnel
//! reflectance F, and refraction by Snell's law with 1 - F (total internal reflection past the
//! critical angle). `sample` picks reflection with probability F, so a sample's weight
//! f |cos| / pdf is 1 for reflection and tint / eta² for refraction: radiance is scaled by
//! 1 / eta² crossing into a denser medium (pbrt's radiance mode; the path tracer's Russian
//! roulette undoes the scale with the eta it is told). `eval` and `pdf` are 0: no light sample
//! can hit a delta lobe.

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};

/// A smooth dielectric boundary seen from one side.
#[derive(Clone, Copy, Debug)]
pub struct Dielectric {
    /// Index of refraction of the far side over that of `wo`'s side (the local frame's +z side).
    pub eta: f32,
    /// What refraction lets through, per channel (the base colour times the transmission).
    pub tint: Vec3,
}

/// Fresnel reflectance of an unpolarised wave at a smooth dielectric boundary, for the cosine
/// `cos_i` (> 0) of the incident angle and the relative index `eta` (far side over near side);
/// 1 past the critical angle.
#[inline]
pub fn fresnel_dielectric(cos_i: f32, eta: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (r_parl * r_parl + r_perp * r_perp)
}

/// `wo` (z > 0) refracted through the plane z = 0 into a medium `eta` times as dense: the
/// transmitted direction (z < 0), or `None` past the critical angle.
#[inline]
pub fn refract(wo: Vec3, eta: f32) -> Option<Vec3> {
    let cos_i = wo.z;
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some(Vec3::new(-wo.x / eta, -wo.y / eta, -cos_t))
}

impl Dielectric {
    /// f(wo, wi): 0, the lobes are delta distributions.
    #[inline]
    pub fn eval(&self, _wo: Vec3, _wi: Vec3) -> Vec3 {
        Vec3::ZERO
    }

    /// Density of `wi`: 0 (see `eval`).
    #[inline]
    pub fn pdf(&self, _wo: Vec3, _wi: Vec3) -> f32 {
        0.0
    }

    /// Reflection with probability F (chosen by `u_lobe`), else refraction.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, _u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let f = fresnel_dielectric(wo.z, self.eta);
        if u_lobe < f {
            let wi = Vec3::new(-wo.x, -wo.y, wo.z);
            return Some(BsdfSample {
                f: Vec3::splat(f / wi.z),
                wi,
                pdf: f,
                lobe: Lobe::SpecularReflection,
                eta: 1.0,
            });
        }
        let wi = refract(wo, self.eta)?;
        let t = 1.0 - f;
        Some(BsdfSample {
            f: self.tint * (t / (self.eta * self.eta * -wi.z)),
            wi,
            pdf: t,
            lobe: Lobe::SpecularTransmission,
            eta: self.eta,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At normal incidence F = ((eta - 1) / (eta + 1))²; past the critical angle F = 1; light
    /// is conserved (F + T = 1) and Snell's law holds (sin_t = sin_i / eta); entering and leaving
    /// are reciprocal (the same F both ways along one ray).
    #[test]
    fn fresnel_and_snell_are_exact() {
        let eta = 1.5f32;
        assert!((fresnel_dielectric(1.0, eta) - 0.04).abs() < 1e-6);
        assert!((fresnel_dielectric(1.0, 1.0 / eta) - 0.04).abs() < 1e-6);
        let critical = (1.0 / eta).asin();
        assert_eq!(fresnel_dielectric((critical + 0.01).cos(), 1.0 / eta), 1.0);
        assert!(refract(
            Vec3::new((critical + 0.01).sin(), 0.0, (critical + 0.01).cos()),
            1.0 / eta
        )
        .is_none());
        for deg in [0.0f32, 10.0, 30.0, 60.0, 85.0] {
            let theta = deg.to_radians();
            let wo = Vec3::new(theta.sin(), 0.0, theta.cos());
            let wi = refract(wo, eta).unwrap();
            assert!((wi.length() - 1.0).abs() < 1e-6);
            let sin_t = (wi.x * wi.x + wi.y * wi.y).sqrt();
            assert!((sin_t - theta.sin() / eta).abs() < 1e-6, "{deg} degrees");
            // Back out along the reversed ray: the same reflectance, and the original angle. Seen
            // from inside (the frame turned over, z -> -z), the reversed ray is (-x, -y, -z) of
            // wi with its z turned over: (-wi.x, -wi.y, -wi.z).
            let back = fresnel_dielectric(-wi.z, 1.0 / eta);
            assert!((back - fresnel_dielectric(wo.z, eta)).abs() < 1e-5, "{deg} degrees");
            let out = refract(Vec3::new(-wi.x, -wi.y, -wi.z), 1.0 / eta).unwrap();
            // It leaves along the original ray reversed.
            assert!((out + wo).abs().max_element() < 1e-5, "{deg}: {out}");
        }
    }

    /// Sampling picks reflection with probability F, and each sample's weight is exactly what
    /// the lobe passes: 1 for reflection, tint / eta² for refraction, so a clear boundary
    /// crossed both ways returns the weight 1.
    #[test]
    fn samples_are_weighted_by_what_they_pass() {
        let into = Dielectric { eta: 1.5, tint: Vec3::new(1.0, 0.5, 0.25) };
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let f = fresnel_dielectric(0.8, 1.5);
        let mut reflected = 0;
        let n = 100_000;
        for i in 0..n {
            let u = (i as f32 + 0.5) / n as f32;
            let s = into.sample(wo, u, Vec2::ZERO).unwrap();
            let weight = s.f * s.wi.z.abs() / s.pdf;
            if s.lobe == Lobe::SpecularReflection {
                reflected += 1;
                assert!((weight - Vec3::ONE).abs().max_element() < 1e-6);
                assert_eq!(s.wi, Vec3::new(-0.6, 0.0, 0.8));
            } else {
                assert_eq!(s.lobe, Lobe::SpecularTransmission);
                let expected = into.tint / 2.25;
                assert!((weight - expected).abs().max_element() < 1e-6, "{weight}");
                assert_eq!(s.eta, 1.5);
            }
        }
        assert!((reflected as f32 / n as f32 - f).abs() < 1e-4);
        let out = Dielectric { eta: 1.0 / 1.5, tint: Vec3::ONE };
        let s = out.sample(Vec3::new(0.0, 0.0, 1.0), 0.99, Vec2::ZERO).unwrap();
        let through = s.f * s.wi.z.abs() / s.pdf;
        assert!((through - Vec3::splat(2.25)).abs().max_element() < 1e-5, "{through}");
    }
}
