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

use glam::{Vec2, Vec3};

use super::{BsdfSample, Lobe};
use crate::render::{
    geometry::reflect,
    sampling::{sample_cosine_hemisphere, Ggx, Microfacet},
};

/// The glTF metallic-roughness BRDF at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
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
        generic::lobe_weights(&self.lobes(), self.ggx.albedo_alpha(), wo.z)
    }

    /// The parameters the generic arithmetic reads (all but the microfacet distribution).
    #[inline]
    pub(crate) fn lobes(&self) -> generic::Lobes<f32> {
        generic::Lobes {
            base: self.base.into(),
            metallic: self.metallic,
            f0: self.f0_dielectric.into(),
            specular: self.specular,
            transmission: self.transmission,
            diffuse_transmission: self.diffuse_transmission,
            diffuse_transmission_color: self.diffuse_transmission_color.into(),
            seen: None,
        }
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
        let spec = self.metallic * generic::luminance(f_m.into()) + (1.0 - self.metallic) * f_d_max;
        let l = self.lobes();
        let (multiple, lost) = generic::multiple_weights(&l, self.ggx.albedo_alpha(), wo.z);
        generic::lobe_weights_given(&l, spec, f_d_max, multiple, lost)
    }

    /// The Schlick Fresnel terms at `cos` = |wo.h|: the dielectric's weighted by
    /// `specularFactor` (s F_d) and the metal's (F_m).
    #[inline]
    pub fn schlick_fresnel(&self, cos: f32) -> (Vec3, Vec3) {
        let (f_d, f_m) = generic::schlick_fresnel(&self.lobes(), cos);
        (f_d.into(), f_m.into())
    }

    /// f(wo, wi): reflection for `wi.z > 0`, transmission for `wi.z < 0`.
    #[inline]
    pub fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        self.eval_kept(
            wo,
            wi,
            |cos| self.schlick_fresnel(cos),
            |l, _| generic::Kept::by_albedo(l, self.ggx.albedo_alpha(), wo.z, wi.z.abs()),
        )
    }

    /// f(wo, wi) with the Fresnel terms (s F_d, F_m) of `fresnel` at |wo.h| in place of
    /// Schlick's (a thin film's): the dielectric's specular lobe weighted by s F_d, the light
    /// under it by 1 - max(s F_d) at the half vector, the metal's lobe by F_m, and the metal's
    /// multiple scattering from the albedo tables (`generic::Kept::by_fresnel`). `eval` weighs
    /// the light under the specular layer by the tables too (`generic::Kept::by_albedo`).
    #[inline]
    pub fn eval_with(&self, wo: Vec3, wi: Vec3, fresnel: impl Fn(f32) -> (Vec3, Vec3)) -> Vec3 {
        let alpha = self.ggx.albedo_alpha();
        self.eval_kept(wo, wi, fresnel, |l, f_d| {
            generic::Kept::by_fresnel(l, f_d.into(), alpha, wo.z, wi.z.abs())
        })
    }

    /// f(wo, wi) with the Fresnel terms of `fresnel` and what `kept` keeps of the light the
    /// microfacets do not reflect, given the lobes and s F_d at the half vector.
    #[inline]
    fn eval_kept(
        &self,
        wo: Vec3,
        wi: Vec3,
        fresnel: impl Fn(f32) -> (Vec3, Vec3),
        kept: impl Fn(&generic::Lobes<f32>, Vec3) -> generic::Kept<f32>,
    ) -> Vec3 {
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
            let spec_t = generic::specular(self.ggx.d(h), self.ggx.g2(wo, wm), wo.z, wm.z);
            let (f_d, _) = fresnel(wo.dot(h));
            let lobes = self.lobes();
            return generic::transmitted(&lobes, spec_t, kept(&lobes, f_d)).into();
        }
        let h = (wo + wi).normalize();
        let spec = generic::specular(self.ggx.d(h), self.ggx.g2(wo, wi), wo.z, wi.z);
        let (f_d, f_m) = fresnel(wo.dot(h));
        let lobes = self.lobes();
        generic::reflected(&lobes, f_d.into(), f_m.into(), spec, kept(&lobes, f_d)).into()
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
        let (_, p_trans, p_dtrans) = probabilities;
        if wi.z < 0.0 {
            if p_trans <= 0.0 && p_dtrans <= 0.0 {
                return 0.0;
            }
            let h = (wo + mirror(wi)).normalize();
            let through = p_trans * self.ggx.reflection_pdf(wo, h);
            if p_dtrans <= 0.0 {
                return through;
            }
            return generic::plus_far_cosine(through, p_dtrans, wi.z);
        }
        let h = (wo + wi).normalize();
        generic::reflection_pdf(probabilities, self.ggx.reflection_pdf(wo, h), wi.z)
    }

    /// Samples a lobe by `u_lobe`, then a direction from it.
    #[inline]
    pub fn sample(&self, wo: Vec3, u_lobe: f32, u: Vec2) -> Option<BsdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let probabilities = self.lobe_probabilities(wo);
        let (wi, lobe) = self.sample_direction(wo, u_lobe, u, probabilities)?;
        let pdf = self.pdf_given(wo, wi, probabilities);
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

/// The BSDF's arithmetic written once over `Real`: the pieces the scalar methods above combine
/// with their microfacet distribution (isotropic or anisotropic), and the whole BSDF with
/// isotropic GGX for a vector of paths (the wavefront), whose selects take the branches the
/// scalar methods take, so that each lane computes the scalar bits.
pub(crate) mod generic {
    use std::f32::consts::FRAC_1_PI;

    use crate::render::{
        bsdf::ggx_albedo,
        geometry::generic::reflect,
        lanes::{Real, V3},
        sampling::generic::{sample_cosine_hemisphere, Facets},
    };

    /// The BSDF's parameters but the microfacet distribution (`MetalRough`'s fields).
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Lobes<R: Real> {
        pub(crate) base: V3<R>,
        pub(crate) metallic: R,
        pub(crate) f0: V3<R>,
        pub(crate) specular: R,
        pub(crate) transmission: R,
        pub(crate) diffuse_transmission: R,
        pub(crate) diffuse_transmission_color: V3<R>,
        /// The albedos for the `wo` of a bounce, found once for all the bounce's calls (the
        /// wavefront), or `None` (found in each call).
        pub(crate) seen: Option<Seen<R>>,
    }

    /// `f32::clamp(x, 0, 1)`.
    #[inline(always)]
    fn clamp01<R: Real>(x: R) -> R {
        let (zero, one) = (x.konst(0.0), x.konst(1.0));
        let x = R::select(x.lt(zero), zero, x);
        R::select(x.gt(one), one, x)
    }

    /// Schlick's weight (1 - cos)^5, cos clamped to [0, 1].
    #[inline(always)]
    pub(crate) fn schlick_weight<R: Real>(cos: R) -> R {
        let m = clamp01(cos.konst(1.0) - cos);
        let m2 = m * m;
        m2 * m2 * m
    }

    /// Rec. 709 luminance.
    #[inline(always)]
    pub(crate) fn luminance<R: Real>(c: V3<R>) -> R {
        let k = |v: f32| c.x.konst(v);
        c.dot(V3::new(k(0.2126), k(0.7152), k(0.0722)))
    }

    /// `x + (1 - x) w`, per channel.
    #[inline(always)]
    fn toward_one<R: Real>(x: V3<R>, w: R) -> V3<R> {
        let one = w.konst(1.0);
        x + (V3::new(one, one, one) - x).scale(w)
    }

    /// The Schlick Fresnel terms at `cos`: s F_d and F_m (`MetalRough::schlick_fresnel`).
    #[inline(always)]
    pub(crate) fn schlick_fresnel<R: Real>(l: &Lobes<R>, cos: R) -> (V3<R>, V3<R>) {
        let w = schlick_weight(cos);
        (toward_one(l.f0, w).scale(l.specular), toward_one(l.base, w))
    }

    /// The lobes' estimated albedos for `wo_z` (`MetalRough::lobe_weights`), the metal's
    /// multiple scattering (sampled with the cosine lobe) from the albedo tables at roughness
    /// `alpha`.
    #[inline(always)]
    pub(crate) fn lobe_weights<R: Real>(l: &Lobes<R>, alpha: R, wo_z: R) -> (R, R, R, R) {
        let one = wo_z.konst(1.0);
        let w = schlick_weight(wo_z);
        let f_m = toward_one(l.base, w);
        let f_d_max = toward_one(l.f0, w).max_element();
        let spec = l.metallic * luminance(f_m) + (one - l.metallic) * l.specular * f_d_max;
        let (multiple, lost) = multiple_weights(l, alpha, wo_z);
        lobe_weights_given(l, spec, l.specular * f_d_max, multiple, lost)
    }

    /// The lobe weights from the specular lobes' weight `spec`, the share `reflected` of the
    /// light the dielectric's specular layer reflects (s max(F_d)), the albedo `multiple` of
    /// the metal's multiple scattering (sampled with the cosine lobe), and the share `lost`
    /// (1 - E(mu_o)) of thin-walled transmission's multiple scattering (sampled with the far
    /// side's cosine lobe).
    #[inline(always)]
    pub(crate) fn lobe_weights_given<R: Real>(
        l: &Lobes<R>,
        spec: R,
        reflected: R,
        multiple: R,
        lost: R,
    ) -> (R, R, R, R) {
        let one = spec.konst(1.0);
        let entering = (one - l.metallic) * (one - reflected) * luminance(l.base);
        // Exact for no transmission: x * 1 is x and x * 0 is 0.
        let (diff, trans) = (entering * (one - l.transmission), entering * l.transmission);
        let dtrans = (one - l.metallic)
            * (one - reflected)
            * (one - l.transmission)
            * l.diffuse_transmission
            * luminance(l.diffuse_transmission_color)
            + trans * lost;
        let diff = diff * (one - l.diffuse_transmission);
        // Exact without a metal: x + 0 is x.
        let total = spec + diff + trans + dtrans + multiple;
        (spec, trans, dtrans, total)
    }

    /// `super::probabilities`.
    #[inline(always)]
    pub(crate) fn probabilities<R: Real>((spec, trans, dtrans, total): (R, R, R, R)) -> (R, R, R) {
        let zero = total.konst(0.0);
        let none = total.le(zero);
        (
            R::select(none, zero, spec / total),
            R::select(none, zero, trans / total),
            R::select(none, zero, dtrans / total),
        )
    }

    /// What the BSDF keeps of the light that one scattering off the microfacets does not
    /// reflect, for one pair of directions.
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Kept<R: Real> {
        /// The weight of the light under the dielectric's specular layer (the diffuse and
        /// diffusely transmitted lobes).
        pub(crate) under: R,
        /// The metal's multiple-scattering lobe (before the weight `metallic`).
        pub(crate) multiple: V3<R>,
        /// The weight of thin-walled transmission (the light that enters below the specular
        /// layer, before `transmission` and the base colour).
        pub(crate) through: R,
        /// White multiple scattering, (1 - E(mu_o)) (1 - E(mu_i)) / (pi (1 - E_avg)), which
        /// thin-walled transmission adds to its microfacet lobe.
        pub(crate) lost: R,
    }

    impl<R: Real> Kept<R> {
        /// What a thin film's Fresnel (`thin_film.rs`) keeps: under the specular layer, the glTF
        /// specification's sketch, 1 - max(s F_d) at the half vector; and the metal's multiple
        /// scattering as `by_albedo`'s, its colour F_ms from the base's Schlick mean (a film
        /// over a white metal reflects all, as the metal does, so F_ms is 1 there too).
        #[inline(always)]
        pub(crate) fn by_fresnel(l: &Lobes<R>, f_d: V3<R>, alpha: R, mu_o: R, mu_i: R) -> Self {
            let under = f_d.x.konst(1.0) - f_d.max_element();
            Kept { under, through: under, ..Kept::by_albedo(l, alpha, mu_o, mu_i) }
        }

        /// Energy kept by the albedo tables (`ggx_albedo`) at roughness `alpha`, for `wo` and `wi`
        /// at cosines `mu_o` and `mu_i` (> 0):
        /// - under the dielectric's specular layer of albedo L(mu) = s (f0 E(mu) + (1 - f0) W(mu))
        ///   (f0 its largest channel), the weight (1 - L(mu_o)) (1 - L(mu_i)) / (1 - L_avg):
        ///   reciprocal, and over the hemisphere exactly what the layer does not reflect,
        ///   1 - L(mu_o) (Kelemen and Szirmay-Kalos 2001, the albedo scaling of glTF's layering
        ///   extensions made symmetric);
        /// - the metal's multiple scattering, Kulla and Conty's (2017) lobe
        ///   F_ms (1 - E(mu_o)) (1 - E(mu_i)) / (pi (1 - E_avg)), with
        ///   F_ms = F_avg² E_avg / (1 - F_avg (1 - E_avg)) and Schlick's F_avg = f0 + (1 - f0) / 21:
        ///   a white metal (f0 = 1) then reflects E(mu_o) + 1 - E(mu_o) = 1 at every roughness.
        ///
        /// Without a specular layer (s = 0) `under` is 1 exactly.
        #[inline(always)]
        pub(crate) fn by_albedo(l: &Lobes<R>, alpha: R, mu_o: R, mu_i: R) -> Self {
            let o = l.seen.unwrap_or_else(|| Seen::new(l, alpha, mu_o));
            let one = mu_i.konst(1.0);
            let [e_i, w_i] = R::map_lanes([mu_i, o.alpha], albedos);
            let under = o.under * (one - layer(l, e_i, w_i)).max0();
            let lost = o.lost * (one - e_i).max0();
            Kept { under, multiple: o.colour.scale(lost), through: o.through, lost }
        }
    }

    /// The lobe choice's weights for multiple scattering at `wo_z`: the metal's
    /// (`Seen::multiple`) and the share 1 - E(mu_o) of thin-walled transmission's.
    #[inline(always)]
    pub(crate) fn multiple_weights<R: Real>(l: &Lobes<R>, alpha: R, wo_z: R) -> (R, R) {
        let o = l.seen.unwrap_or_else(|| Seen::new(l, alpha, wo_z));
        (o.multiple, o.lost_share)
    }

    /// The albedo tables read for the `wo` of a bounce, at the roughness `alpha` of the tables
    /// (`Facets::albedo_alpha`): E(mu_o), W(mu_o), E_avg, W_avg, and the albedo of the metal's
    /// multiple scattering for `wo` (what the lobe choice gives the cosine lobe for it).
    #[derive(Clone, Copy, Debug)]
    pub(crate) struct Seen<R: Real> {
        alpha: R,
        /// (1 - L(mu_o)) / (1 - L_avg), the layer's albedo scaling but for `wi`.
        under: R,
        /// (1 - E(mu_o)) / (pi (1 - E_avg)), the multiple scattering's but for `wi` and F_ms.
        lost: R,
        /// F_ms.
        colour: V3<R>,
        /// metallic luminance(F_ms) (1 - E(mu_o)): the lobe choice's weight for it.
        multiple: R,
        /// 1 - L(mu_o): what enters below the specular layer, the weight of thin-walled
        /// transmission.
        through: R,
        /// 1 - E(mu_o).
        lost_share: R,
    }

    impl<R: Real> Seen<R> {
        #[inline(always)]
        pub(crate) fn new(l: &Lobes<R>, alpha: R, mu_o: R) -> Self {
            let [e_o, w_o, e_avg, w_avg] = R::map_lanes([mu_o, alpha], seen);
            let (one, floor) = (e_avg.konst(1.0), e_avg.konst(1e-4));
            let through = (one - layer(l, e_o, w_o)).max0();
            let under = through / (one - layer(l, e_avg, w_avg)).glam_max(floor);
            let lost = (one - e_o).max0()
                / ((one - e_avg).glam_max(floor) * one.konst(std::f32::consts::PI));
            let f_avg = l.base + (V3::new(one, one, one) - l.base).scale(one.konst(1.0 / 21.0));
            let colour = multiple_colour(f_avg, e_avg);
            let multiple = l.metallic * luminance(colour) * (one - e_o).max0();
            let lost_share = (one - e_o).max0();
            Seen { alpha, under, lost, colour, multiple, through, lost_share }
        }
    }

    /// The tables at (mu_o, alpha): [E(mu_o), W(mu_o), E_avg, W_avg]. Not inlined: a vector of
    /// paths calls it lane by lane (`Real::map_lanes`), and its lookups would crowd the vector
    /// kernel's code.
    #[inline(never)]
    fn seen([mu_o, alpha]: [f32; 2]) -> [f32; 4] {
        let (e_o, w_o) = ggx_albedo::albedos(mu_o, alpha);
        let (e_avg, w_avg) = ggx_albedo::mean_albedos(alpha);
        [e_o, w_o, e_avg, w_avg]
    }

    /// The dielectric specular layer's albedo L(mu) = s (f0 E(mu) + (1 - f0) W(mu)), f0 its
    /// largest channel, from the tables' E and W.
    #[inline(always)]
    fn layer<R: Real>(l: &Lobes<R>, e: R, w: R) -> R {
        let f0 = l.f0.max_element();
        l.specular * (f0 * e + (e.konst(1.0) - f0) * w)
    }

    /// (E(mu_i), W(mu_i)) at `alpha`, for one lane. Not inlined, as [`seen`].
    #[inline(never)]
    fn albedos([mu_i, alpha]: [f32; 2]) -> [f32; 2] {
        let (e, w) = ggx_albedo::albedos(mu_i, alpha);
        [e, w]
    }

    /// Kulla and Conty's F_ms, the colour of the metal's multiple scattering, from Schlick's mean
    /// Fresnel `f_avg` and the mean white albedo `e_avg`.
    #[inline(always)]
    fn multiple_colour<R: Real>(f_avg: V3<R>, e_avg: R) -> V3<R> {
        let one = e_avg.konst(1.0);
        let f = |c: R| c * c * e_avg / (one - c * (one - e_avg));
        V3::new(f(f_avg.x), f(f_avg.y), f(f_avg.z))
    }

    /// The microfacet lobe's value D G2 / (4 wo.z wi.z).
    #[inline(always)]
    pub(crate) fn specular<R: Real>(d: R, g2: R, wo_z: R, wi_z: R) -> R {
        d * g2 / (d.konst(4.0) * wo_z * wi_z)
    }

    /// f for `wi` above: the dielectric's diffuse and specular lobes and the metal's, from the
    /// Fresnel terms at the half vector, the microfacet lobe's value `spec` and what is `kept`.
    #[inline(always)]
    pub(crate) fn reflected<R: Real>(
        l: &Lobes<R>,
        f_d: V3<R>,
        f_m: V3<R>,
        spec: R,
        kept: Kept<R>,
    ) -> V3<R> {
        let one = spec.konst(1.0);
        let diffuse = l
            .base
            .scale(kept.under)
            .scale(spec.konst(FRAC_1_PI))
            .scale(one - l.transmission)
            .scale(one - l.diffuse_transmission);
        let dielectric = diffuse + f_d.scale(spec);
        // Exact without a metal: the added terms are 0.
        dielectric.scale(one - l.metallic)
            + f_m.scale(l.metallic).scale(spec)
            + kept.multiple.scale(l.metallic)
    }

    /// f for `wi` below: thin-walled transmission, the mirrored microfacet lobe's value `spec_t`
    /// plus white multiple scattering, weighted by what `kept` lets through (1 - L(mu_o), the
    /// albedo scaling of glTF's layering extensions, so that a white surface passes all that its
    /// specular layer does not reflect); and diffuse transmission, weighted by `Kept::under`
    /// (for `wi` mirrored).
    #[inline(always)]
    pub(crate) fn transmitted<R: Real>(l: &Lobes<R>, spec_t: R, kept: Kept<R>) -> V3<R> {
        let (zero, one) = (spec_t.konst(0.0), spec_t.konst(1.0));
        let weight = (one - l.metallic) * kept.through * l.transmission;
        let through = l.base.scale(weight * (spec_t + kept.lost));
        // The diffused light's share that leaves on the far side, Lambertian there.
        let diffused = (one - l.metallic) * kept.under * (one - l.transmission);
        let far = through
            + l.diffuse_transmission_color
                .scale(diffused * l.diffuse_transmission)
                .scale(spec_t.konst(FRAC_1_PI));
        V3::select(l.diffuse_transmission.le(zero), through, far)
    }

    /// The density above: the microfacet lobe's share times its density `ggx_pdf`, and the
    /// cosine lobe's.
    #[inline(always)]
    pub(crate) fn reflection_pdf<R: Real>(
        (p_spec, p_trans, p_dtrans): (R, R, R),
        ggx_pdf: R,
        wi_z: R,
    ) -> R {
        let rest = (wi_z.konst(1.0) - p_spec - p_trans - p_dtrans).max0();
        p_spec * ggx_pdf + rest * cosine_pdf(wi_z)
    }

    /// `through` plus the far side's cosine lobe's share of the density at `wi_z` (< 0).
    #[inline(always)]
    pub(crate) fn plus_far_cosine<R: Real>(through: R, p_dtrans: R, wi_z: R) -> R {
        through + p_dtrans * cosine_pdf(-wi_z)
    }

    /// `sampling::cosine_hemisphere_pdf`.
    #[inline(always)]
    fn cosine_pdf<R: Real>(cos: R) -> R {
        cos.max0() * cos.konst(FRAC_1_PI)
    }

    /// `w` mirrored through the surface plane.
    #[inline(always)]
    fn mirror<R: Real>(w: V3<R>) -> V3<R> {
        V3::new(w.x, w.y, -w.z)
    }

    /// `MetalRough::eval` with the microfacets `m`, for every lane; `transmits` says whether
    /// any lane may transmit (when none does, the far side's branch is not computed: it is zero
    /// in every lane).
    #[inline(always)]
    pub(crate) fn eval<R: Real>(
        l: &Lobes<R>,
        m: impl Facets<R>,
        wo: V3<R>,
        wi: V3<R>,
        transmits: bool,
    ) -> V3<R> {
        let zero = wo.z.konst(0.0);
        let z3 = V3::new(zero, zero, zero);
        let h = (wo + wi).normalize();
        let spec = specular(m.d(h), m.g2(wo, wi), wo.z, wi.z);
        let (f_d, f_m) = schlick_fresnel(l, wo.dot(h));
        let kept = Kept::by_albedo(l, m.albedo_alpha(), wo.z, wi.z.abs());
        let above = reflected(l, f_d, f_m, spec, kept);
        let below = if transmits {
            let wm = mirror(wi);
            let h = (wo + wm).normalize();
            let spec_t = specular(m.d(h), m.g2(wo, wm), wo.z, wm.z);
            V3::select(lane_transmits(l), transmitted(l, spec_t, kept), z3)
        } else {
            z3
        };
        let f = V3::select(wi.z.lt(zero), below, above);
        V3::select(wo.z.le(zero) | wi.z.eq(zero), z3, f)
    }

    /// `MetalRough::transmits`, per lane.
    #[inline(always)]
    pub(crate) fn lane_transmits<R: Real>(l: &Lobes<R>) -> R::Mask {
        let (zero, one) = (l.metallic.konst(0.0), l.metallic.konst(1.0));
        (l.transmission.gt(zero) | l.diffuse_transmission.gt(zero)) & l.metallic.lt(one)
    }

    /// `MetalRough::pdf` with the microfacets `m`, for every lane (`transmits` as for
    /// [`eval`]).
    #[inline(always)]
    pub(crate) fn pdf<R: Real>(
        l: &Lobes<R>,
        m: impl Facets<R>,
        wo: V3<R>,
        wi: V3<R>,
        transmits: bool,
    ) -> R {
        pdf_given(m, wo, wi, probabilities(lobe_weights(l, m.albedo_alpha(), wo.z)), transmits)
    }

    /// [`pdf`] with the lobe probabilities for `wo` already found.
    #[inline(always)]
    fn pdf_given<R: Real>(
        m: impl Facets<R>,
        wo: V3<R>,
        wi: V3<R>,
        probabilities: (R, R, R),
        transmits: bool,
    ) -> R {
        let zero = wo.z.konst(0.0);
        let (_, p_trans, p_dtrans) = probabilities;
        let h = (wo + wi).normalize();
        let above = reflection_pdf(probabilities, m.reflection_pdf(wo, h), wi.z);
        let below = if transmits {
            let h = (wo + mirror(wi)).normalize();
            let through = p_trans * m.reflection_pdf(wo, h);
            let with_far = plus_far_cosine(through, p_dtrans, wi.z);
            let below = R::select(p_dtrans.le(zero), through, with_far);
            R::select(p_trans.le(zero) & p_dtrans.le(zero), zero, below)
        } else {
            zero
        };
        let p = R::select(wi.z.lt(zero), below, above);
        R::select(wo.z.le(zero) | wi.z.eq(zero), zero, p)
    }

    /// `MetalRough::sample` with the microfacets `m`, for every lane: the direction, f, its
    /// density, whether it went to the far side, and whether there is a sample (`transmits` as
    /// for [`eval`]).
    #[inline(always)]
    pub(crate) fn sample<R: Real>(
        l: &Lobes<R>,
        m: impl Facets<R>,
        wo: V3<R>,
        u_lobe: R,
        (ux, uy): (R, R),
        transmits: bool,
    ) -> (V3<R>, V3<R>, R, R::Mask, R::Mask) {
        let zero = wo.z.konst(0.0);
        let chances = probabilities(lobe_weights(l, m.albedo_alpha(), wo.z));
        let (p_spec, p_trans, p_dtrans) = chances;
        let glossy = reflect(wo, m.visible_normal(wo, ux, uy));
        let diffuse = sample_cosine_hemisphere(ux, uy);
        let spec_lobe = u_lobe.lt(p_spec);
        let trans_lobe = !spec_lobe & u_lobe.lt(p_spec + p_trans);
        let dtrans_lobe = !spec_lobe & !trans_lobe & u_lobe.lt(p_spec + p_trans + p_dtrans);
        let far = trans_lobe | dtrans_lobe;
        let wi = V3::select(
            spec_lobe,
            glossy,
            V3::select(
                trans_lobe,
                mirror(glossy),
                V3::select(dtrans_lobe, mirror(diffuse), diffuse),
            ),
        );
        let ok = wo.z.gt(zero)
            & !(trans_lobe & glossy.z.le(zero))
            & !wi.z.eq(zero)
            & !(wi.z.lt(zero) & !far);
        let pdf = pdf_given(m, wo, wi, chances, transmits);
        let f = eval(l, m, wo, wi, transmits);
        (wi, f, pdf, far, ok & pdf.gt(zero))
    }
}
