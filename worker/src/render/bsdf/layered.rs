//! The glTF BSDF with the layered extensions: `KHR_materials_anisotropy` in the base's specular
//! lobe, a `KHR_materials_sheen` layer over the base and a `KHR_materials_clearcoat` layer over
//! both, combined by the extensions' albedo scaling:
//!
//! f = c F_c(wo) spec_c + (1 - c F_c(wo)) [ f_sheen + (1 - max(sheenColor) E(n.wo)) f_base ]
//!
//! - f_base is [`MetalRough`] with anisotropic GGX: alpha_t = mix(alpha, 1, strength²) along
//!   the anisotropy direction (the local +x, which the integrator aligns with it) and alpha_b =
//!   alpha across it.
//! - The coat, of weight c = clearcoat, is the GGX specular lobe spec_c = D G2 / (4 |nc.wo|
//!   |nc.wi|) of alpha = clearcoatRoughness² around its own normal nc, weighted by the Schlick
//!   Fresnel of index 1.5, F_c(wo) = 0.04 + 0.96 (1 - |nc.wo|)^5 (the spec's `fresnel_coat`).
//!   The albedo scaling uses the cosine of `wo` to the coat normal only, as the spec does: a
//!   white coat reflects at most F_c(wo) of the light, so the layers never gain energy (the
//!   price is that f is not reciprocal).
//! - The sheen (`sheen.rs`) scales the base by one minus its white albedo E at the cosine of
//!   `wo` to the shading normal, times the largest channel of its colour (the spec's simplified
//!   scaling, again energy-conserving for every `wo`).
//!
//! - `KHR_materials_iridescence` replaces the Schlick Fresnel of the base's specular lobes by a
//!   thin film's (`thin_film.rs`), in its reflection, its albedo scaling and its lobe choice.
//!
//! Sampling picks the coat (GGX visible normals around nc), the sheen (uniform hemisphere) or
//! the base (its own lobe choice, with the lobe number rescaled) in proportion to c F_c(wo),
//! (1 - c F_c) max(sheenColor) E and (1 - c F_c) (1 - max(sheenColor) E) times the base's
//! albedo estimate.

use glam::{Vec2, Vec3};

use super::{metal_rough::probabilities, BsdfSample, Lobe, MetalRough, Sheen, ThinFilm};
use crate::render::{
    geometry::{reflect, Frame},
    sampling::{sample_uniform_hemisphere, uniform_hemisphere_pdf, AnisoGgx, Ggx},
};

/// Reflectance of the coat (index 1.5) at normal incidence: ((1.5 - 1) / (1.5 + 1))².
const COAT_F0: f32 = 0.04;

/// A clear coat at a point.
#[derive(Clone, Copy, Debug)]
pub struct Coat {
    /// `clearcoat` in (0, 1].
    pub weight: f32,
    /// The coat's microfacets (alpha = clearcoatRoughness²).
    pub ggx: Ggx,
    /// The coat's normal in the local shading frame (+z unless it has a normal map of its own
    /// or the base has one).
    pub normal: Vec3,
}

impl Coat {
    /// c F_c(wo): the share of the light the coat reflects, and takes from the layers below.
    #[inline]
    fn weight(&self, wo: Vec3) -> f32 {
        let m = (1.0 - wo.dot(self.normal).abs()).clamp(0.0, 1.0);
        let m2 = m * m;
        self.weight * (COAT_F0 + (1.0 - COAT_F0) * (m2 * m2 * m))
    }
}

/// The layered glTF BSDF.
#[derive(Clone, Copy, Debug)]
pub struct Layered {
    /// The metallic-roughness base, with its anisotropic (or isotropic) GGX.
    pub base: MetalRough<AnisoGgx>,
    /// The sheen over the base.
    pub sheen: Option<Sheen>,
    /// The coat over the sheen and the base.
    pub coat: Option<Coat>,
    /// The thin film on the base (`None`: the base's Schlick Fresnel).
    pub iridescence: Option<ThinFilm>,
}

impl Layered {
    /// Whether light can pass through to the far side (through the base).
    #[inline]
    pub fn transmits(&self) -> bool {
        self.base.transmits()
    }

    /// (c F_c(wo), the sheen's scaling of the base) for `wo`.
    #[inline]
    fn scalings(&self, wo: Vec3) -> (f32, f32) {
        let coat = self.coat.map_or(0.0, |c| c.weight(wo));
        let sheen = self.sheen.map_or(1.0, |s| s.scaling(wo.z));
        (coat, sheen)
    }

    /// The base's Fresnel terms (s F_d, F_m) at `cos` = |wo.h|, with the thin film.
    #[inline]
    fn film_fresnel(&self, film: &ThinFilm, cos: f32) -> (Vec3, Vec3) {
        let b = &self.base;
        let weighted_f0 = b.specular * b.f0_dielectric;
        film.mix_fresnel(b.schlick_fresnel(cos), weighted_f0, b.base, b.metallic, cos)
    }

    /// The base's estimated albedo for `wo` and its lobe probabilities, with the thin film
    /// (`None` without one: the base's own).
    #[inline]
    fn film_lobes(&self, wo: Vec3) -> Option<(f32, (f32, f32, f32))> {
        let film = self.iridescence.as_ref()?;
        let weights = self.base.lobe_weights_with(wo, |cos| self.film_fresnel(film, cos));
        Some((weights.3, probabilities(weights)))
    }

    /// Probabilities of sampling the coat and the sheen for `wo`; the base takes the rest.
    #[inline]
    fn lobe_probabilities(&self, wo: Vec3) -> (f32, f32) {
        let (coat, sheen_scaling) = self.scalings(wo);
        let under = 1.0 - coat;
        let sheen = under * (1.0 - sheen_scaling);
        let albedo = match self.film_lobes(wo) {
            Some((albedo, _)) => albedo,
            None => self.base.albedo_estimate(wo),
        };
        let base = under * sheen_scaling * albedo;
        let total = coat + sheen + base;
        if total.is_nan() || total <= 0.0 {
            return (0.0, 0.0);
        }
        (coat / total, sheen / total)
    }

    /// f(wo, wi): reflection for `wi.z > 0`, the base's transmission for `wi.z < 0`.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return Vec3::ZERO;
        }
        let (coat_weight, sheen_scaling) = self.scalings(wo);
        let base = match &self.iridescence {
            Some(film) => self.base.eval_with(wo, wi, |cos| self.film_fresnel(film, cos)),
            None => self.base.eval(wo, wi),
        };
        let mut under = base * sheen_scaling;
        if let Some(s) = &self.sheen {
            under += s.eval(wo, wi);
        }
        let mut f = under * (1.0 - coat_weight);
        if let Some(c) = &self.coat {
            f += Vec3::splat(coat_weight * coat_specular(c, wo, wi));
        }
        f
    }

    /// Density of `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z <= 0.0 || wi.z == 0.0 {
            return 0.0;
        }
        let (p_coat, p_sheen) = self.lobe_probabilities(wo);
        let base_pdf = match self.film_lobes(wo) {
            Some((_, probabilities)) => self.base.pdf_given(wo, wi, probabilities),
            None => self.base.pdf(wo, wi),
        };
        let mut pdf = (1.0 - p_coat - p_sheen).max(0.0) * base_pdf;
        if wi.z > 0.0 {
            if self.sheen.is_some() {
                pdf += p_sheen * uniform_hemisphere_pdf();
            }
            if let Some(c) = &self.coat {
                pdf += p_coat * coat_pdf(c, wo, wi);
            }
        }
        pdf
    }

    /// Samples a layer by `u_lobe`, then a direction from it.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let (p_coat, p_sheen) = self.lobe_probabilities(wo);
        let (wi, lobe) = if u_lobe < p_coat {
            let c = self.coat.as_ref()?;
            let frame = Frame::from_z(c.normal);
            let wo_c = frame.to_local(wo);
            if wo_c.z <= 0.0 {
                return None;
            }
            let h = c.ggx.sample_visible_normal(wo_c, u);
            let wi_c = reflect(wo_c, h);
            if wi_c.z <= 0.0 {
                return None;
            }
            (frame.to_world(wi_c), Lobe::Glossy)
        } else if u_lobe < p_coat + p_sheen {
            (sample_uniform_hemisphere(u), Lobe::Glossy)
        } else {
            let p_base = 1.0 - p_coat - p_sheen;
            let u_base = ((u_lobe - p_coat - p_sheen) / p_base).clamp(0.0, ONE_BELOW);
            match self.film_lobes(wo) {
                Some((_, probabilities)) => {
                    self.base.sample_direction(wo, u_base, u, probabilities)?
                }
                None => {
                    let s = self.base.sample(wo, u_base, u)?;
                    (s.wi, s.lobe)
                }
            }
        };
        if wi.z == 0.0 || (wi.z < 0.0 && lobe != Lobe::Transmission) {
            return None;
        }
        let pdf = self.pdf(wo, wi);
        if pdf.is_nan() || pdf <= 0.0 {
            return None;
        }
        Some(BsdfSample { f: self.eval(wo, wi), wi, pdf, lobe, eta: 1.0 })
    }
}

/// The largest f32 below 1: a rescaled lobe number must stay in [0, 1).
const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

/// spec_c(wo, wi) of the coat, in its own frame (0 unless both directions are above the coat
/// and `wi` above the surface).
#[inline]
fn coat_specular(c: &Coat, wo: Vec3, wi: Vec3) -> f32 {
    if wi.z <= 0.0 {
        return 0.0;
    }
    let frame = Frame::from_z(c.normal);
    let (wo_c, wi_c) = (frame.to_local(wo), frame.to_local(wi));
    if wo_c.z <= 0.0 || wi_c.z <= 0.0 {
        return 0.0;
    }
    let h = (wo_c + wi_c).normalize();
    c.ggx.d(h) * c.ggx.g2(wo_c, wi_c) / (4.0 * wo_c.z * wi_c.z)
}

/// Density of the coat's visible-normal reflection producing `wi` (0 where `coat_specular` is).
#[inline]
fn coat_pdf(c: &Coat, wo: Vec3, wi: Vec3) -> f32 {
    let frame = Frame::from_z(c.normal);
    let (wo_c, wi_c) = (frame.to_local(wo), frame.to_local(wi));
    if wo_c.z <= 0.0 || wi_c.z <= 0.0 {
        return 0.0;
    }
    c.ggx.reflection_pdf(wo_c, (wo_c + wi_c).normalize())
}

/// `base` with anisotropic GGX of `strength` in [0, 1] (`KHR_materials_anisotropy`): alpha_t =
/// mix(alpha, 1, strength²) along the local +x, alpha_b = alpha along +y. Strength 0 keeps the
/// base's alpha both ways.
pub fn anisotropic(base: MetalRough, strength: f32) -> MetalRough<AnisoGgx> {
    let alpha = base.ggx.alpha;
    let s2 = strength.clamp(0.0, 1.0) * strength.clamp(0.0, 1.0);
    base.with_microfacet(AnisoGgx::new(alpha + (1.0 - alpha) * s2, alpha))
}
