//! The glTF 2.0 metallic-roughness BSDF (spec appendix B) with `KHR_materials_specular`,
//! `KHR_materials_ior`, `KHR_materials_transmission` and `KHR_materials_diffuse_transmission`:
//!
//! f = (1 - metallic) * [ (1 - s * max(F_d)) * base * ((1 - t) / pi + t * spec_t) + s * F_d * spec ]
//!     + metallic * F_m * spec
//!
//! where spec = D G2 / (4 |n.wo| |n.wi|) is GGX with height-correlated Smith masking
//! (alpha = roughness²), F_d the dielectric Schlick Fresnel with f0 = min(((ior-1)/(ior+1))² *
//! specular_color, 1), F_m the conductor Schlick Fresnel with f0 = base, s = specularFactor and
//! t = transmission. The surface is thin-walled (the transmission extension without a volume):
//! spec_t, for `wi` on the far side, is the specular lobe evaluated with `wi` mirrored through the
//! surface plane (half vector normalize(wo + mirror(wi)), as the extension defines it), so light
//! passes straight through, blurred by the roughness, and tinted by the base colour.
//! Diffuse transmission (factor dt, colour c_dt) splits the diffused light: (1 - dt) of it is the
//! Lambertian lobe above, dt of it a Lambertian lobe of colour c_dt on the far side (a thin
//! translucent sheet), weighted like the lobe above by 1 - s * max(F_d) at the mirrored half
//! vector.
//! Sampling picks the GGX lobe (visible normals, Heitz 2018), the mirrored GGX lobe, the cosine
//! lobe below or the cosine lobe above with probabilities from their estimated albedos.
//! The microfacet distribution is a type parameter: isotropic [`Ggx`] by default, or
//! [`AnisoGgx`](crate::render::sampling::AnisoGgx) for `KHR_materials_anisotropy` (see
//! `layered.rs`).

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};
use crate::render::{
    geometry::reflect,
    sampling::{cosine_hemisphere_pdf, sample_cosine_hemisphere, Ggx, Microfacet},
};

/// The glTF metallic-roughness BRDF at a point.
#[derive(Clone, Copy, Debug)]
pub struct MetalRough<M = Ggx> {
    /// Base colour (linear).
    pub base: Vec3,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// Microfacet distribution (alpha = roughness²).
    pub ggx: M,
    /// Dielectric reflectance at normal incidence, per channel.
    pub f0_dielectric: Vec3,
    /// `specularFactor`.
    pub specular: f32,
    /// `transmissionFactor` in [0, 1]: the share of the light entering the surface that passes
    /// through it instead of being diffused.
    pub transmission: f32,
    /// `diffuseTransmissionFactor` in [0, 1]: the share of the diffused light scattered to the
    /// far side (a Lambertian lobe there) instead of back.
    pub diffuse_transmission: f32,
    /// `diffuseTransmissionColor`: the colour of that lobe.
    pub diffuse_transmission_color: Vec3,
}

#[inline]
fn schlick_weight(cos: f32) -> f32 {
    let m = (1.0 - cos).clamp(0.0, 1.0);
    let m2 = m * m;
    m2 * m2 * m
}

#[inline]
fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

impl MetalRough {
    /// A BRDF from glTF parameters.
    pub fn new(
        base: Vec3,
        metallic: f32,
        roughness: f32,
        ior: f32,
        specular: f32,
        specular_color: Vec3,
    ) -> Self {
        let r = ((ior - 1.0) / (ior + 1.0)).powi(2);
        MetalRough {
            base: base.clamp(Vec3::ZERO, Vec3::ONE),
            metallic: metallic.clamp(0.0, 1.0),
            ggx: Ggx::new(roughness.clamp(0.0, 1.0).powi(2)),
            f0_dielectric: (specular_color * r).min(Vec3::ONE).max(Vec3::ZERO),
            specular: specular.clamp(0.0, 1.0),
            transmission: 0.0,
            diffuse_transmission: 0.0,
            diffuse_transmission_color: Vec3::ONE,
        }
    }
}

impl<M: Microfacet> MetalRough<M> {
    /// The same BSDF with another microfacet distribution.
    pub fn with_microfacet<N: Microfacet>(self, ggx: N) -> MetalRough<N> {
        MetalRough {
            base: self.base,
            metallic: self.metallic,
            ggx,
            f0_dielectric: self.f0_dielectric,
            specular: self.specular,
            transmission: self.transmission,
            diffuse_transmission: self.diffuse_transmission,
            diffuse_transmission_color: self.diffuse_transmission_color,
        }
    }

    /// The same BSDF with `KHR_materials_diffuse_transmission`'s factor and colour (clamped to
    /// [0, 1]).
    pub fn with_diffuse_transmission(self, factor: f32, color: Vec3) -> Self {
        let factor = if factor > 0.0 { factor.min(1.0) } else { 0.0 };
        MetalRough {
            diffuse_transmission: factor,
            diffuse_transmission_color: color.clamp(Vec3::ZERO, Vec3::ONE),
            ..self
        }
    }

    /// The same BSDF with `KHR_materials_transmission`'s `transmission` (clamped to [0, 1]).
    pub fn with_transmission(self, transmission: f32) -> Self {
        let transmission = if transmission > 0.0 { transmission.min(1.0) } else { 0.0 };
        MetalRough { transmission, ..self }
    }

    /// Whether it has a Lambertian lobe (reflected or diffusely transmitted) that carries light.
    #[inline]
    pub fn has_diffuse(&self) -> bool {
        self.metallic < 1.0
            && self.transmission < 1.0
            && (self.base.max_element() > 0.0
                || self.diffuse_transmission_color.max_element() * self.diffuse_transmission > 0.0)
    }

    /// Whether light can pass through to the far side.
    #[inline]
    pub fn transmits(&self) -> bool {
        (self.transmission > 0.0 || self.diffuse_transmission > 0.0) && self.metallic < 1.0
    }

    /// Probabilities of sampling the GGX reflection lobe, the mirrored (transmission) lobe and
    /// the cosine lobe on the far side (diffuse transmission) for `wo`, from the lobes' albedos at
    /// normal-ish incidence; the cosine lobe on `wo`'s side takes the rest. Must be the same in
    /// `sample` and `pdf`.
    #[inline]
    fn lobe_probabilities(&self, wo: Vec3) -> (f32, f32, f32) {
        probabilities(self.lobe_weights(wo))
    }

    /// The estimated albedo of the whole BSDF for `wo` (what `lobe_probabilities` divides by).
    #[inline]
    pub fn albedo_estimate(&self, wo: Vec3) -> f32 {
        self.lobe_weights(wo).3
    }

    /// The estimated albedos of the GGX lobe, the mirrored lobe and the far side's cosine lobe
    /// for `wo`, and of all lobes together.
    #[inline]
    fn lobe_weights(&self, wo: Vec3) -> (f32, f32, f32, f32) {
        let w = schlick_weight(wo.z);
        let f_m = self.base + (Vec3::ONE - self.base) * w;
        let f_d = self.f0_dielectric + (Vec3::ONE - self.f0_dielectric) * w;
        let f_d_max = f_d.max_element();
        let spec = self.metallic * luminance(f_m) + (1.0 - self.metallic) * self.specular * f_d_max;
        self.lobe_weights_given(spec, self.specular * f_d_max)
    }

    /// `lobe_weights` with the Fresnel terms (s F_d, F_m) of `fresnel` (at `wo.z`) in place of
    /// Schlick's (`thin_film.rs`).
    #[inline]
    pub fn lobe_weights_with(
        &self,
        wo: Vec3,
        fresnel: impl Fn(f32) -> (Vec3, Vec3),
    ) -> (f32, f32, f32, f32) {
        let (f_d, f_m) = fresnel(wo.z);
        let f_d_max = f_d.max_element();
        let spec = self.metallic * luminance(f_m) + (1.0 - self.metallic) * f_d_max;
        self.lobe_weights_given(spec, f_d_max)
    }

    /// The lobe weights from the specular lobes' weight `spec` and the share `reflected` of the
    /// light the dielectric's specular layer reflects (s max(F_d)).
    #[inline]
    fn lobe_weights_given(&self, spec: f32, reflected: f32) -> (f32, f32, f32, f32) {
        let entering = (1.0 - self.metallic) * (1.0 - reflected) * luminance(self.base);
        // Exact for no transmission: x * 1 is x and x * 0 is 0.
        let (diff, trans) = (entering * (1.0 - self.transmission), entering * self.transmission);
        let dtrans = (1.0 - self.metallic)
            * (1.0 - reflected)
            * (1.0 - self.transmission)
            * self.diffuse_transmission
            * luminance(self.diffuse_transmission_color);
        let diff = diff * (1.0 - self.diffuse_transmission);
        let total = spec + diff + trans + dtrans;
        (spec, trans, dtrans, total)
    }

    /// The Schlick Fresnel terms at `cos` = |wo.h|: the dielectric's weighted by
    /// `specularFactor` (s F_d) and the metal's (F_m).
    #[inline]
    pub fn schlick_fresnel(&self, cos: f32) -> (Vec3, Vec3) {
        let w = schlick_weight(cos);
        let f_d = self.f0_dielectric + (Vec3::ONE - self.f0_dielectric) * w;
        let f_m = self.base + (Vec3::ONE - self.base) * w;
        (self.specular * f_d, f_m)
    }

    /// f(wo, wi): reflection for `wi.z > 0`, transmission for `wi.z < 0`.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        self.eval_with(wo, wi, |cos| self.schlick_fresnel(cos))
    }

    /// f(wo, wi) with the Fresnel terms (s F_d, F_m) of `fresnel` at |wo.h| in place of
    /// Schlick's: the dielectric's specular lobe weighted by s F_d, the light under it by
    /// 1 - max(s F_d), the metal's lobe by F_m. With [`Self::schlick_fresnel`] this is `eval`,
    /// operation for operation (s max(F_d) is max(s F_d) exactly: rounding is monotonic).
    #[inline]
    pub fn eval_with(&self, wo: Vec3, wi: Vec3, fresnel: impl Fn(f32) -> (Vec3, Vec3)) -> Vec3 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return Vec3::ZERO;
        }
        if wi.z < 0.0 {
            if !self.transmits() {
                return Vec3::ZERO;
            }
            // Thin-walled: the specular lobe seen through the surface.
            let wm = mirror(wi);
            let h = (wo + wm).normalize();
            let spec_t = self.ggx.d(h) * self.ggx.g2(wo, wm) / (4.0 * wo.z * wm.z);
            let (f_d, _) = fresnel(wo.dot(h));
            let entering = 1.0 - f_d.max_element();
            let through = (1.0 - self.metallic) * entering * self.transmission * self.base * spec_t;
            if self.diffuse_transmission <= 0.0 {
                return through;
            }
            // The diffused light's share that leaves on the far side, Lambertian there.
            let diffused = (1.0 - self.metallic) * entering * (1.0 - self.transmission);
            return through
                + diffused
                    * self.diffuse_transmission
                    * self.diffuse_transmission_color
                    * FRAC_1_PI;
        }
        let h = (wo + wi).normalize();
        let spec = self.ggx.d(h) * self.ggx.g2(wo, wi) / (4.0 * wo.z * wi.z);
        let (f_d, f_m) = fresnel(wo.dot(h));
        let diffuse = (1.0 - f_d.max_element())
            * self.base
            * FRAC_1_PI
            * (1.0 - self.transmission)
            * (1.0 - self.diffuse_transmission);
        let dielectric = diffuse + f_d * spec;
        (1.0 - self.metallic) * dielectric + self.metallic * f_m * spec
    }

    /// Density of `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        self.pdf_given(wo, wi, self.lobe_probabilities(wo))
    }

    /// Density of `wi` when the lobes are chosen with `probabilities` (of the GGX lobe, the
    /// mirrored lobe and the far side's cosine lobe, as [`probabilities`] makes them).
    #[inline]
    pub fn pdf_given(&self, wo: Vec3, wi: Vec3, probabilities: (f32, f32, f32)) -> f32 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        let (p_spec, p_trans, p_dtrans) = probabilities;
        if wi.z < 0.0 {
            if p_trans <= 0.0 && p_dtrans <= 0.0 {
                return 0.0;
            }
            let h = (wo + mirror(wi)).normalize();
            let through = p_trans * self.ggx.reflection_pdf(wo, h);
            if p_dtrans <= 0.0 {
                return through;
            }
            return through + p_dtrans * cosine_hemisphere_pdf(-wi.z);
        }
        let h = (wo + wi).normalize();
        // max: with full transmission the probabilities can sum to one ulp over 1.
        p_spec * self.ggx.reflection_pdf(wo, h)
            + (1.0 - p_spec - p_trans - p_dtrans).max(0.0) * cosine_hemisphere_pdf(wi.z)
    }

    /// Samples a lobe by `u_lobe`, then a direction from it.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let (wi, lobe) = self.sample_direction(wo, u_lobe, u, self.lobe_probabilities(wo))?;
        let pdf = self.pdf(wo, wi);
        if !(pdf > 0.0) {
            return None;
        }
        Some(BsdfSample { f: self.eval(wo, wi), wi, pdf, lobe, eta: 1.0 })
    }

    /// A direction and its lobe for `wo.z > 0`, the lobe chosen by `u_lobe` with `probabilities`
    /// (as for [`Self::pdf_given`]); `None` where the direction falls on the wrong side.
    #[inline]
    pub fn sample_direction(
        &self,
        wo: Vec3,
        u_lobe: f32,
        u: Vec2,
        probabilities: (f32, f32, f32),
    ) -> Option<(Vec3, Lobe)> {
        let (p_spec, p_trans, p_dtrans) = probabilities;
        let (wi, lobe) = if u_lobe < p_spec {
            let h = self.ggx.sample_visible_normal(wo, u);
            (reflect(wo, h), Lobe::Glossy)
        } else if u_lobe < p_spec + p_trans {
            let h = self.ggx.sample_visible_normal(wo, u);
            let wm = reflect(wo, h);
            if wm.z <= 0.0 {
                return None;
            }
            (mirror(wm), Lobe::Transmission)
        } else if u_lobe < p_spec + p_trans + p_dtrans {
            (mirror(sample_cosine_hemisphere(u)), Lobe::Transmission)
        } else {
            (sample_cosine_hemisphere(u), Lobe::Diffuse)
        };
        if wi.z == 0.0 || (wi.z < 0.0 && lobe != Lobe::Transmission) {
            return None;
        }
        Some((wi, lobe))
    }
}

/// Probabilities of sampling the GGX lobe, the mirrored lobe and the far side's cosine lobe from
/// the lobe weights (`lobe_weights`, `lobe_weights_with`); the cosine lobe on `wo`'s side takes
/// the rest.
#[inline]
pub(super) fn probabilities((spec, trans, dtrans, total): (f32, f32, f32, f32)) -> (f32, f32, f32) {
    if total <= 0.0 {
        return (0.0, 0.0, 0.0);
    }
    (spec / total, trans / total, dtrans / total)
}

/// `w` mirrored through the surface plane (z = 0).
#[inline]
fn mirror(w: Vec3) -> Vec3 {
    Vec3::new(w.x, w.y, -w.z)
}
