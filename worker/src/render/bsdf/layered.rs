//! The glTF BSDF with the layered extensions: `KHR_materials_anisotropy` in the base's specular
//! lobe, a `KHR_materials_sheen` layer over the base and a `KHR_materials_clearcoat` layer over
//! both, combined by the extensions' albedo scaling:
//!
//! f = c F_c(wo) spec_c + (1 - c F_c(wo) E_c(nc.wo)) [ f_sheen + (1 - max(sheenColor) E(n.wo)) f_base ]
//!
//! - f_base is [`MetalRough`] with anisotropic GGX: alpha_t = mix(alpha, 1, strength²) along
//!   the anisotropy direction (the local +x, which the integrator aligns with it) and alpha_b =
//!   alpha across it.
//! - The coat, of weight c = clearcoat, is the GGX specular lobe spec_c = D G2 / (4 |nc.wo|
//!   |nc.wi|) of alpha = clearcoatRoughness² around its own normal nc, weighted by the Schlick
//!   Fresnel of index 1.5, F_c(wo) = 0.04 + 0.96 (1 - |nc.wo|)^5 (the spec's `fresnel_coat`).
//!   The coat reflects c F_c(wo) E_c of the light, E_c its lobe's white single-scattering
//!   albedo at the cosine of `wo` to the coat normal (`ggx_albedo`), and the layers below take
//!   the rest: what the spec's scaling by 1 - c F_c(wo) leaves out of the coat's lobe
//!   (c F_c (1 - E_c)) is no longer lost. With `wo` only, as the spec does, so that the layers
//!   never gain energy (the price is that f is not reciprocal).
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
use crate::render::sampling::{sample_uniform_hemisphere, uniform_hemisphere_pdf, AnisoGgx, Ggx};

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
        generic::coat_weight(&self.lanes(), wo.into())
    }

    /// The coat as the generic arithmetic reads it.
    #[inline]
    pub(crate) fn lanes(&self) -> generic::CoatLanes<f32> {
        generic::CoatLanes {
            weight: self.weight,
            alpha: self.ggx.alpha,
            normal: self.normal.into(),
        }
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
        let albedo = match self.film_lobes(wo) {
            Some((albedo, _)) => albedo,
            None => self.base.albedo_estimate(wo),
        };
        generic::lobe_probabilities(coat, sheen_scaling, albedo)
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
        let coat = self.coat.map(|c| {
            let c = c.lanes();
            let taken = generic::coat_taken(&c, wo.into(), coat_weight);
            (coat_weight, generic::coat_specular(&c, wo.into(), wi.into()), taken)
        });
        generic::layers_f(under.into(), coat).into()
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
        let pdf = generic::base_share(p_coat, p_sheen) * base_pdf;
        if wi.z <= 0.0 {
            return pdf;
        }
        let pdf = if self.sheen.is_some() { pdf + p_sheen * uniform_hemisphere_pdf() } else { pdf };
        match &self.coat {
            Some(c) => generic::plus_coat_pdf(pdf, p_coat, &c.lanes(), wo.into(), wi.into()),
            None => pdf,
        }
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
            let (wi, ok) = generic::sample_coat(&c.lanes(), wo.into(), u.x, u.y);
            if !ok {
                return None;
            }
            (wi.into(), Lobe::Glossy)
        } else if u_lobe < p_coat + p_sheen {
            (sample_uniform_hemisphere(u), Lobe::Glossy)
        } else {
            let u_base = generic::base_number(u_lobe, p_coat, p_sheen);
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

/// `base` with anisotropic GGX of `strength` in [0, 1] (`KHR_materials_anisotropy`): alpha_t =
/// mix(alpha, 1, strength²) along the local +x, alpha_b = alpha along +y. Strength 0 keeps the
/// base's alpha both ways.
pub fn anisotropic(base: MetalRough, strength: f32) -> MetalRough<AnisoGgx> {
    let alpha = base.ggx.alpha;
    let s2 = strength.clamp(0.0, 1.0) * strength.clamp(0.0, 1.0);
    base.with_microfacet(AnisoGgx::new(alpha + (1.0 - alpha) * s2, alpha))
}

/// The coat's arithmetic and the layers' combination, written once over `Real`: for one path
/// (`f32`, through [`Layered`]) and for a vector of them (the wavefront, for the lanes whose
/// layers are a coat over an anisotropic or isotropic base).
pub(crate) mod generic {
    use crate::render::{
        bsdf::sheen::generic as sheen,
        geometry::generic::{frame_from_z, reflect},
        lanes::{Real, V3},
        sampling::{
            generic::{sample_uniform_hemisphere, Facets, Iso},
            uniform_hemisphere_pdf,
        },
    };

    use super::super::metal_rough::generic::{
        self as metal_rough, lobe_weights, schlick_weight, Lobes,
    };
    use super::COAT_F0;

    /// A clear coat, for every lane: `clearcoat`, its GGX alpha, and its normal in the shading
    /// frame.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct CoatLanes<R: Real> {
        pub(crate) weight: R,
        pub(crate) alpha: R,
        pub(crate) normal: V3<R>,
    }

    /// The largest f32 below 1: a rescaled lobe number must stay in [0, 1).
    const ONE_BELOW: f32 = 1.0 - f32::EPSILON / 2.0;

    /// `Coat::weight`: c F_c(wo), F_c the Schlick Fresnel of index 1.5 at |nc.wo|.
    #[inline(always)]
    pub(crate) fn coat_weight<R: Real>(c: &CoatLanes<R>, wo: V3<R>) -> R {
        let k = |v: f32| c.weight.konst(v);
        c.weight * (k(COAT_F0) + k(1.0 - COAT_F0) * schlick_weight(wo.dot(c.normal).abs()))
    }

    /// c F_c(wo) E_c(nc.wo): the share of the light the coat's lobe reflects (the coat's
    /// `weight` times its white single-scattering albedo), which the layers below give up.
    #[inline(always)]
    pub(crate) fn coat_taken<R: Real>(c: &CoatLanes<R>, wo: V3<R>, weight: R) -> R {
        let [e] = R::map_lanes([wo.dot(c.normal).abs(), c.alpha], coat_albedo);
        weight * e
    }

    /// E_c for one lane, from (|nc.wo|, alpha). Not inlined: a vector of paths calls it lane by
    /// lane (`Real::map_lanes`).
    #[inline(never)]
    fn coat_albedo([mu, alpha]: [f32; 2]) -> [f32; 1] {
        [crate::render::bsdf::ggx_albedo::albedos(mu, alpha).0]
    }

    /// `v` in the coat's frame (`Frame::from_z(normal).to_local`), and the frame's tangents.
    #[inline(always)]
    fn coat_frame<R: Real>(c: &CoatLanes<R>, v: V3<R>) -> (V3<R>, V3<R>, V3<R>) {
        let (x, y) = frame_from_z(c.normal);
        (V3::new(v.dot(x), v.dot(y), v.dot(c.normal)), x, y)
    }

    /// spec_c(wo, wi): the coat's GGX lobe, 0 unless both directions are above the coat and
    /// `wi` above the surface.
    #[inline(always)]
    pub(crate) fn coat_specular<R: Real>(c: &CoatLanes<R>, wo: V3<R>, wi: V3<R>) -> R {
        let zero = c.weight.konst(0.0);
        let (wo_c, _, _) = coat_frame(c, wo);
        let (wi_c, _, _) = coat_frame(c, wi);
        let h = (wo_c + wi_c).normalize();
        let m = Iso(c.alpha);
        let spec = m.d(h) * m.g2(wo_c, wi_c) / (c.weight.konst(4.0) * wo_c.z * wi_c.z);
        R::select(wi.z.le(zero) | wo_c.z.le(zero) | wi_c.z.le(zero), zero, spec)
    }

    /// `pdf` plus `p_coat` times the density of the coat's visible-normal reflection producing
    /// `wi` (nothing where the coat cannot produce it).
    #[inline(always)]
    pub(crate) fn plus_coat_pdf<R: Real>(
        pdf: R,
        p_coat: R,
        c: &CoatLanes<R>,
        wo: V3<R>,
        wi: V3<R>,
    ) -> R {
        let zero = c.weight.konst(0.0);
        let (wo_c, _, _) = coat_frame(c, wo);
        let (wi_c, _, _) = coat_frame(c, wi);
        let coat = Iso(c.alpha).reflection_pdf(wo_c, (wo_c + wi_c).normalize());
        let coat = R::select(wo_c.z.le(zero) | wi_c.z.le(zero), zero, coat);
        pdf + p_coat * coat
    }

    /// A direction reflected by the coat (in the shading frame), and whether it is one: both
    /// `wo` and it above the coat.
    #[inline(always)]
    pub(crate) fn sample_coat<R: Real>(
        c: &CoatLanes<R>,
        wo: V3<R>,
        ux: R,
        uy: R,
    ) -> (V3<R>, R::Mask) {
        let zero = c.weight.konst(0.0);
        let (wo_c, x, y) = coat_frame(c, wo);
        let wi_c = reflect(wo_c, Iso(c.alpha).visible_normal(wo_c, ux, uy));
        let wi = x.scale(wi_c.x) + y.scale(wi_c.y) + c.normal.scale(wi_c.z);
        (wi, wo_c.z.gt(zero) & wi_c.z.gt(zero))
    }

    /// The probabilities of sampling the coat and the sheen, from the coat's weight c F_c(wo),
    /// the sheen's scaling of the base and the base's estimated albedo; the base takes the rest.
    #[inline(always)]
    pub(crate) fn lobe_probabilities<R: Real>(coat: R, sheen_scaling: R, albedo: R) -> (R, R) {
        let (zero, one) = (coat.konst(0.0), coat.konst(1.0));
        let under = one - coat;
        let sheen = under * (one - sheen_scaling);
        let base = under * sheen_scaling * albedo;
        let total = coat + sheen + base;
        let none = total.le(zero) | !total.eq(total);
        (R::select(none, zero, coat / total), R::select(none, zero, sheen / total))
    }

    /// The base's share of the lobe choice.
    #[inline(always)]
    pub(crate) fn base_share<R: Real>(p_coat: R, p_sheen: R) -> R {
        (p_coat.konst(1.0) - p_coat - p_sheen).max0()
    }

    /// The lobe number `u_lobe`, past the coat's and the sheen's shares, rescaled to the base's.
    #[inline(always)]
    pub(crate) fn base_number<R: Real>(u_lobe: R, p_coat: R, p_sheen: R) -> R {
        let (zero, below) = (u_lobe.konst(0.0), u_lobe.konst(ONE_BELOW));
        let p_base = u_lobe.konst(1.0) - p_coat - p_sheen;
        let u = (u_lobe - p_coat - p_sheen) / p_base;
        // `f32::clamp`, which keeps a NaN.
        let u = R::select(u.lt(zero), zero, u);
        R::select(u.gt(below), below, u)
    }

    /// f from what lies under the coat (`under`: the sheen and the scaled base) and the coat's
    /// weight, lobe value and the share it takes from below ([`coat_taken`]), if it has one.
    #[inline(always)]
    pub(crate) fn layers_f<R: Real>(under: V3<R>, coat: Option<(R, R, R)>) -> V3<R> {
        match coat {
            Some((weight, spec, taken)) => {
                let coat = weight * spec;
                under.scale(weight.konst(1.0) - taken) + V3::new(coat, coat, coat)
            }
            // Without a coat its weight is 0: under x (1 - 0).
            None => under.scale(under.x.konst(1.0)),
        }
    }

    /// A sheen, for every lane: its colour and roughness (`Sheen`'s fields).
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct SheenLanes<R: Real> {
        pub(crate) color: V3<R>,
        pub(crate) alpha: R,
    }

    /// The layered BSDF of the lanes without a thin film: a coat (where `has_coat`) over a sheen
    /// (where `has_sheen`) over the base `base` with microfacets `facets`, as the wavefront
    /// holds it. `Layered`'s arithmetic, lane for lane.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Coated<'a, R: Real, M> {
        pub(crate) base: &'a Lobes<R>,
        pub(crate) facets: M,
        pub(crate) coat: &'a CoatLanes<R>,
        pub(crate) has_coat: R::Mask,
        pub(crate) sheen: &'a SheenLanes<R>,
        pub(crate) has_sheen: R::Mask,
        /// Whether any lane has a coat (when none does, its arithmetic is not done).
        pub(crate) coats: bool,
        /// Whether any lane has a sheen (when none does, its arithmetic is not done).
        pub(crate) sheens: bool,
        /// Whether any lane's base may transmit (`metal_rough::eval`'s `transmits`).
        pub(crate) transmits: bool,
    }

    impl<R: Real, M: Facets<R>> Coated<'_, R, M> {
        /// `Layered::scalings`: c F_c(wo) (0 without a coat) and the sheen's scaling of the
        /// base (1 without a sheen).
        #[inline(always)]
        fn scalings(&self, wo: V3<R>) -> (R, R) {
            let (zero, one) = (wo.z.konst(0.0), wo.z.konst(1.0));
            let weight = if self.coats {
                R::select(self.has_coat, coat_weight(self.coat, wo), zero)
            } else {
                zero
            };
            if !self.sheens {
                return (weight, one);
            }
            let s = self.sheen;
            let scaling = sheen::scaling(s.color.max_element(), s.alpha, wo.z);
            (weight, R::select(self.has_sheen, scaling, one))
        }

        /// The probabilities of the coat and the sheen for `wo` (`Layered::lobe_probabilities`).
        #[inline(always)]
        fn choice(&self, wo: V3<R>) -> (R, R) {
            let (weight, scaling) = self.scalings(wo);
            lobe_probabilities(
                weight,
                scaling,
                lobe_weights(self.base, self.facets.albedo_alpha(), wo.z).3,
            )
        }

        /// `Layered::eval`.
        #[inline(always)]
        pub(crate) fn eval(&self, wo: V3<R>, wi: V3<R>) -> V3<R> {
            let zero = wo.z.konst(0.0);
            let (weight, scaling) = self.scalings(wo);
            let base = metal_rough::eval(self.base, self.facets, wo, wi, self.transmits);
            let under = base.scale(scaling);
            let under = if self.sheens {
                let sheen = self.sheen.color.scale(sheen::brdf(self.sheen.alpha, wo, wi));
                V3::select(self.has_sheen, under + sheen, under)
            } else {
                under
            };
            let without = layers_f(under, None);
            let f = if self.coats {
                let taken = coat_taken(self.coat, wo, weight);
                let with = layers_f(under, Some((weight, coat_specular(self.coat, wo, wi), taken)));
                V3::select(self.has_coat, with, without)
            } else {
                without
            };
            V3::select(wo.z.le(zero) | wi.z.eq(zero), V3::new(zero, zero, zero), f)
        }

        /// `Layered::pdf` with the choice for `wo` found.
        #[inline(always)]
        fn pdf_given(&self, wo: V3<R>, wi: V3<R>, (p_coat, p_sheen): (R, R)) -> R {
            let zero = wo.z.konst(0.0);
            let base_pdf = metal_rough::pdf(self.base, self.facets, wo, wi, self.transmits);
            let pdf = base_share(p_coat, p_sheen) * base_pdf;
            let above = wi.z.gt(zero);
            let hemisphere = wo.z.konst(uniform_hemisphere_pdf());
            let pdf = R::select(self.has_sheen & above, pdf + p_sheen * hemisphere, pdf);
            let pdf = if self.coats {
                let with = plus_coat_pdf(pdf, p_coat, self.coat, wo, wi);
                R::select(self.has_coat & above, with, pdf)
            } else {
                pdf
            };
            R::select(wo.z.le(zero) | wi.z.eq(zero), zero, pdf)
        }

        /// `Layered::pdf`.
        #[inline(always)]
        pub(crate) fn pdf(&self, wo: V3<R>, wi: V3<R>) -> R {
            self.pdf_given(wo, wi, self.choice(wo))
        }

        /// `Layered::sample`: the direction, f, its density, whether it went to the far side,
        /// and whether there is a sample.
        #[inline(always)]
        pub(crate) fn sample(
            &self,
            wo: V3<R>,
            u_lobe: R,
            (ux, uy): (R, R),
        ) -> (V3<R>, V3<R>, R, R::Mask, R::Mask) {
            let zero = wo.z.konst(0.0);
            let choice = self.choice(wo);
            let (p_coat, p_sheen) = choice;
            // Without a coat p_coat is 0, and no lane takes the coat's direction.
            let (coat_wi, coat_ok) =
                if self.coats { sample_coat(self.coat, wo, ux, uy) } else { (wo, zero.lt(zero)) };
            let sheen_wi = if self.sheens { sample_uniform_hemisphere(ux, uy) } else { wo };
            let u_base = base_number(u_lobe, p_coat, p_sheen);
            let (base_wi, _, _, base_far, base_ok) =
                metal_rough::sample(self.base, self.facets, wo, u_base, (ux, uy), self.transmits);
            let coat = u_lobe.lt(p_coat);
            let sheen = !coat & u_lobe.lt(p_coat + p_sheen);
            let base = !coat & !sheen;
            let wi = V3::select(coat, coat_wi, V3::select(sheen, sheen_wi, base_wi));
            let far = base & base_far;
            let ok = (coat & coat_ok & self.has_coat) | (sheen & self.has_sheen) | (base & base_ok);
            let ok = ok & wo.z.gt(zero) & !wi.z.eq(zero) & !(wi.z.lt(zero) & !far);
            let pdf = self.pdf_given(wo, wi, choice);
            let f = self.eval(wo, wi);
            (wi, f, pdf, far, ok & pdf.gt(zero))
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::{Vec2, Vec3};

    use super::{
        anisotropic,
        generic::{CoatLanes, Coated, SheenLanes},
        Coat, Layered,
    };
    use crate::render::{
        bsdf::{MetalRough, Sheen},
        sampling::{generic::Aniso, Ggx},
    };

    /// A reproducible stream of numbers in [0, 1).
    fn numbers(seed: u32) -> impl FnMut() -> f32 {
        let mut state = seed.wrapping_mul(0x9e37_79b9) | 1;
        move || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state >> 8) as f32 / (1u32 << 24) as f32
        }
    }

    fn direction(u: &mut impl FnMut() -> f32, upper: bool) -> Vec3 {
        let z = if upper { u() } else { 2.0 * u() - 1.0 };
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f32::consts::TAU * u();
        Vec3::new(r * phi.cos(), r * phi.sin(), z)
    }

    /// The generic layers over an anisotropic base (`Coated`, which the wavefront runs on
    /// vectors) give `Layered`'s values, densities and samples bit for bit, with and without a
    /// coat and a sheen, transmitting or not, at grazing angles and with the coat's normal
    /// tilted.
    #[test]
    fn the_generic_coat_is_the_layered_bsdf_bit_for_bit() {
        let mut u = numbers(7);
        for case in 0..400 {
            let base = MetalRough::new(
                Vec3::new(u(), u(), u()),
                if case % 3 == 0 { 1.0 } else { u() },
                u(),
                1.0 + u(),
                u(),
                Vec3::new(u(), u(), u()),
            );
            let base = match case % 4 {
                0 => base.with_transmission(u()),
                1 => base.with_diffuse_transmission(u(), Vec3::new(u(), u(), u())),
                _ => base,
            };
            let base = anisotropic(base, if case % 5 == 0 { 0.0 } else { u() });
            let coat = (case % 6 != 0).then(|| Coat {
                weight: u(),
                ggx: Ggx::new(u() * u()),
                normal: (Vec3::Z + direction(&mut u, true) * 0.4 * u()).normalize(),
            });
            let sheen = (case % 4 != 1).then(|| Sheen::new(Vec3::new(u(), u(), u()), u()));
            let layered = Layered { base, sheen, coat, iridescence: None };
            let lanes = coat
                .map_or(CoatLanes { weight: 0.0, alpha: 1.0, normal: Vec3::Z.into() }, |c| {
                    c.lanes()
                });
            let sheen_lanes =
                sheen.map_or(SheenLanes { color: Vec3::ZERO.into(), alpha: 1.0 }, |s| SheenLanes {
                    color: s.color.into(),
                    alpha: s.alpha,
                });
            let generic = Coated {
                base: &base.lobes(),
                facets: Aniso(base.ggx.alpha_x, base.ggx.alpha_y),
                coat: &lanes,
                has_coat: coat.is_some(),
                sheen: &sheen_lanes,
                has_sheen: sheen.is_some(),
                coats: coat.is_some(),
                sheens: sheen.is_some(),
                transmits: true,
            };
            for _ in 0..20 {
                let wo = direction(&mut u, case % 7 != 0);
                let wi = direction(&mut u, false);
                let f: Vec3 = generic.eval(wo.into(), wi.into()).into();
                assert_eq!(
                    f.to_array().map(f32::to_bits),
                    layered.eval(wo, wi).to_array().map(f32::to_bits),
                    "{case}: f({wo}, {wi})"
                );
                let pdf = generic.pdf(wo.into(), wi.into());
                assert_eq!(pdf.to_bits(), layered.pdf(wo, wi).to_bits(), "{case}: pdf({wo}, {wi})");
                let (u_lobe, u2) = (u(), Vec2::new(u(), u()));
                let (wi, f, pdf, far, ok) = generic.sample(wo.into(), u_lobe, (u2.x, u2.y));
                match layered.sample(wo, u_lobe, u2) {
                    Some(bs) => {
                        assert!(ok, "{case}: a sample for {wo}");
                        assert_eq!(Vec3::from(wi), bs.wi, "{case}");
                        assert_eq!(Vec3::from(f), bs.f, "{case}");
                        assert_eq!(pdf.to_bits(), bs.pdf.to_bits(), "{case}");
                        assert_eq!(far, bs.wi.z < 0.0, "{case}");
                    }
                    None => assert!(!ok, "{case}: no sample for {wo}"),
                }
            }
        }
    }
}
