//! Tests of the BSDFs: chi-square of `sample` against `pdf` for `Diffuse`, `MetalRough` (with and
//! without transmission), the layered BSDF (clear coat, sheen, anisotropy, thin film) and GGX
//! visible-normal
//! reflection (isotropic and anisotropic), the agreement of `sample` with `eval`/`pdf`, and
//! energy (albedo).

use glam::{Vec2, Vec3};

use super::chi2::{assert_fits, Rng, Spherical};
use crate::render::{
    bsdf::{
        anisotropic, Bsdf, Coat, Dielectric, Diffuse, Layered, Lobe, MetalRough, Sheen, ThinFilm,
    },
    geometry::reflect,
    sampling::{AnisoGgx, Ggx, Microfacet},
};

/// Perceptual roughness of the `MetalRough` chi-square cases (0.05 is alpha = 0.0025, a lobe a
/// few milliradians wide: the adaptive quadrature resolves it inside one cell).
const ROUGHNESS: [f32; 4] = [0.05, 0.3, 0.7, 1.0];

/// (metallic, specular) of the `MetalRough` chi-square cases. Metallic 1 ignores `specular`, and
/// (0, 0) is plain Lambert, tested once in `metal_rough_without_specular_matches_pdf`.
const METAL_SPECULAR: [(f32, f32); 4] = [(0.0, 1.0), (0.5, 0.0), (0.5, 1.0), (1.0, 1.0)];

/// cos(theta) of the outgoing directions of the `MetalRough` cases: normal, oblique, grazing.
const COS_WO: [f32; 3] = [1.0, 0.5, 0.05];

/// Base colour of the chi-square cases: coloured, so the lobe choice's luminance weights matter.
const BASE: Vec3 = Vec3::new(0.8, 0.5, 0.2);

/// GGX alphas of the visible-normal reflection cases.
const GGX_ALPHA: [f32; 3] = [0.05, 0.3, 1.0];

/// cos(theta) of the outgoing directions of the GGX cases.
const GGX_COS_WO: [f32; 2] = [0.8, 0.1];

/// cos(theta) of the outgoing directions of the `Diffuse` cases.
const DIFFUSE_COS_WO: [f32; 2] = [0.6, 0.05];

/// (transmission, roughness) of the transmitting `MetalRough` cases (metallic 0, specular 1):
/// fully and half transmitting, rough and near-specular.
const TRANSMISSION_CASES: [(f32, f32); 3] = [(1.0, 0.3), (0.5, 0.7), (1.0, 0.05)];

/// (perceptual roughness, eta) of the rough dielectric cases: from outside glass (1.5) and from
/// inside it (1 / 1.5, where total internal reflection takes part of the lobe), near-specular
/// to rough.
const DIELECTRIC_CASES: [(f32, f32); 6] =
    [(0.1, 1.5), (0.3, 1.5), (0.7, 1.5), (0.1, 1.0 / 1.5), (0.3, 1.0 / 1.5), (0.7, 1.0 / 1.5)];

/// cos(theta) of the outgoing directions of the dielectric cases.
const DIELECTRIC_COS_WO: [f32; 2] = [0.9, 0.3];

/// (diffuse transmission, thin transmission, roughness, specular) of the diffusely transmitting
/// `MetalRough` cases: a translucent glossy sheet, one that also passes light straight through,
/// and a pure translucent Lambertian sheet.
const DIFFUSE_TRANSMISSION_CASES: [(f32, f32, f32, f32); 3] =
    [(0.5, 0.0, 0.5, 1.0), (0.6, 0.4, 0.3, 1.0), (1.0, 0.0, 1.0, 0.0)];

/// (alpha_x, alpha_y) of the anisotropic GGX visible-normal cases.
const ANISO_ALPHA: [(f32, f32); 3] = [(0.05, 0.4), (0.6, 0.1), (1.0, 0.3)];

/// Number of `layered_cases`.
const N_LAYERED: usize = 10;

/// Chi-square tests in this file.
pub(super) const N_CHI2: usize = ROUGHNESS.len() * METAL_SPECULAR.len() * COS_WO.len()
    + N_LAYERED * COS_WO.len()
    + ANISO_ALPHA.len() * GGX_COS_WO.len()
    + TRANSMISSION_CASES.len() * COS_WO.len()
    + DIFFUSE_TRANSMISSION_CASES.len() * COS_WO.len()
    + DIELECTRIC_CASES.len() * DIELECTRIC_COS_WO.len()
    + 1
    + GGX_ALPHA.len() * GGX_COS_WO.len()
    + DIFFUSE_COS_WO.len();

/// The outgoing direction with cos(theta) = `cos_theta`, at an azimuth off the grid's axes.
fn wo_at(cos_theta: f32) -> Vec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let (sin_phi, cos_phi) = 0.7f32.sin_cos();
    Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)
}

fn metal_rough(base: Vec3, metallic: f32, roughness: f32, specular: f32) -> Bsdf {
    Bsdf::MetalRough(MetalRough::new(base, metallic, roughness, 1.5, specular, Vec3::ONE))
}

/// Chi-square of `bsdf.sample` against `bsdf.pdf` over the upper hemisphere.
fn assert_bsdf_fits(name: &str, bsdf: &Bsdf, wo: Vec3) {
    assert_fits(
        name,
        Spherical::hemisphere(),
        |u| {
            let s = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z))?;
            assert!(s.pdf > 0.0 && s.pdf.is_finite(), "{name}: sample pdf {} at {:?}", s.pdf, s.wi);
            Some(s.wi)
        },
        |wi| bsdf.pdf(wo, wi),
    );
}

/// Chi-square of `bsdf.sample` against `bsdf.pdf` over the whole sphere (a transmitting BSDF:
/// `pdf` must integrate to 1 over both sides, less what no lobe can reach).
fn assert_bsdf_fits_sphere(name: &str, bsdf: &Bsdf, wo: Vec3) {
    assert_fits(
        name,
        Spherical::sphere(),
        |u| {
            let s = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z))?;
            assert!(s.pdf > 0.0 && s.pdf.is_finite(), "{name}: pdf {} at {:?}", s.pdf, s.wi);
            Some(s.wi)
        },
        |wi| bsdf.pdf(wo, wi),
    );
}

#[test]
fn diffuse_sampling_matches_pdf() {
    let bsdf = Bsdf::Diffuse(Diffuse { albedo: Vec3::new(0.2, 0.5, 0.9) });
    for cos_wo in DIFFUSE_COS_WO {
        assert_bsdf_fits(&format!("diffuse_coswo{cos_wo}"), &bsdf, wo_at(cos_wo));
    }
}

fn assert_metal_rough_fits(roughness: f32) {
    for (metallic, specular) in METAL_SPECULAR {
        let bsdf = metal_rough(BASE, metallic, roughness, specular);
        for cos_wo in COS_WO {
            let name = format!("metal_rough_r{roughness}_m{metallic}_s{specular}_coswo{cos_wo}");
            assert_bsdf_fits(&name, &bsdf, wo_at(cos_wo));
        }
    }
}

#[test]
fn metal_rough_roughness_005_matches_pdf() {
    assert_metal_rough_fits(ROUGHNESS[0]);
}

#[test]
fn metal_rough_roughness_03_matches_pdf() {
    assert_metal_rough_fits(ROUGHNESS[1]);
}

#[test]
fn metal_rough_roughness_07_matches_pdf() {
    assert_metal_rough_fits(ROUGHNESS[2]);
}

#[test]
fn metal_rough_roughness_1_matches_pdf() {
    assert_metal_rough_fits(ROUGHNESS[3]);
}

/// `metal_rough` with `KHR_materials_transmission`.
fn transmitting(base: Vec3, transmission: f32, roughness: f32) -> Bsdf {
    Bsdf::MetalRough(
        MetalRough::new(base, 0.0, roughness, 1.5, 1.0, Vec3::ONE).with_transmission(transmission),
    )
}

#[test]
fn transmitting_metal_rough_matches_pdf_over_the_sphere() {
    // Directions on both sides: the mirrored lobe below the surface, reflection and the cosine
    // lobe above, and `pdf` must integrate to 1 over the whole sphere.
    for (transmission, roughness) in TRANSMISSION_CASES {
        let bsdf = transmitting(BASE, transmission, roughness);
        for cos_wo in COS_WO {
            let wo = wo_at(cos_wo);
            let name = format!("transmitting_t{transmission}_r{roughness}_coswo{cos_wo}");
            assert_bsdf_fits_sphere(&name, &bsdf, wo);
        }
    }
}

/// Monte Carlo albedo of channel 0 over both sides, and the part of it that passes through.
fn albedo_both_sides(bsdf: &Bsdf, wo: Vec3, n: usize, rng: &mut Rng) -> [(f64, f64); 2] {
    let mut parts = [(0.0f64, 0.0f64); 2];
    for _ in 0..n {
        let u = rng.next_vec3();
        let Some(s) = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) else { continue };
        let x = (s.f.x * s.wi.z.abs() / s.pdf) as f64;
        for (k, part) in parts.iter_mut().enumerate() {
            if k == 0 || s.wi.z < 0.0 {
                part.0 += x;
                part.1 += x * x;
            }
        }
    }
    parts.map(|(sum, sum2)| {
        let mean = sum / n as f64;
        (mean, ((sum2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt())
    })
}

#[test]
fn thin_transmission_passes_what_the_surface_does_not_reflect() {
    // White, fully transmitting glass (ior 1.5, f0 = 0.04): nothing is diffused, so everything
    // either reflects or passes through. Near-specular at normal incidence: 4% reflects and 96%
    // passes. At every roughness and angle all of it, within the albedo tables' interpolation
    // error (4e-3, as `worker/tests/energy.rs`): the transmitted lobe passes all that the
    // specular layer does not reflect, its multiple scattering included (single scattering
    // alone lost up to 20% at roughness 1).
    let mut rng = Rng::from_name("thin_transmission_passes_what_the_surface_does_not_reflect");
    let n = 200_000;
    for roughness in ROUGHNESS {
        let bsdf = transmitting(Vec3::ONE, 1.0, roughness);
        for cos_wo in [1.0, 0.7, 0.3, 0.05] {
            let [(total, e_total), (through, e_through)] =
                albedo_both_sides(&bsdf, wo_at(cos_wo), n, &mut rng);
            println!(
                "transmitting r{roughness} coswo{cos_wo}: albedo {total:.5} +- {e_total:.5}, \
                 through {through:.5} +- {e_through:.5}"
            );
            assert!(
                (total - 1.0).abs() <= 3.0 * e_total + 4e-3,
                "r{roughness} cos {cos_wo}: {total}"
            );
            if roughness == 0.05 && cos_wo == 1.0 {
                assert!((total - 1.0).abs() < 5e-3, "near-specular albedo {total} +- {e_total}");
                assert!((through - 0.96).abs() < 5e-3, "near-specular through {through}");
            }
        }
    }
    // Half transmitting: the far side gets half of what full transmission passes.
    let full = transmitting(Vec3::ONE, 1.0, 0.3);
    let half = transmitting(Vec3::ONE, 0.5, 0.3);
    let wo = wo_at(0.7);
    let [_, (f, ef)] = albedo_both_sides(&full, wo, n, &mut rng);
    let [_, (h, eh)] = albedo_both_sides(&half, wo, n, &mut rng);
    assert!((h - 0.5 * f).abs() <= 3.0 * (eh * eh + 0.25 * ef * ef).sqrt(), "{h} vs half of {f}");
}

#[test]
fn metal_rough_without_specular_matches_pdf() {
    // Metallic 0 and specular 0 never pick the GGX lobe: sampling is the cosine lobe alone.
    let bsdf = metal_rough(BASE, 0.0, 0.3, 0.0);
    assert_bsdf_fits("metal_rough_r0.3_m0_s0_coswo0.5", &bsdf, wo_at(0.5));
}

/// Reflections off visible normals drawn from `ggx` for each `wo` of `GGX_COS_WO`, over the
/// whole sphere (those below the horizon count too, and `reflection_pdf` must integrate to 1).
fn assert_visible_normal_reflection_fits(name: &str, ggx: &impl Microfacet) {
    for cos_wo in GGX_COS_WO {
        let wo = wo_at(cos_wo);
        assert_fits(
            &format!("{name}_coswo{cos_wo}"),
            Spherical::sphere(),
            |u| {
                let h = ggx.sample_visible_normal(wo, Vec2::new(u.x, u.y));
                assert!(h.z > 0.0 && wo.dot(h) >= 0.0, "invisible normal {h:?} for {wo:?}");
                Some(reflect(wo, h))
            },
            |wi| {
                let h = wo + wi;
                if h.length_squared() < 1e-12 {
                    return 0.0;
                }
                ggx.reflection_pdf(wo, h.normalize())
            },
        );
    }
}

#[test]
fn ggx_visible_normal_reflection_matches_pdf() {
    for alpha in GGX_ALPHA {
        assert_visible_normal_reflection_fits(
            &format!("ggx_reflection_a{alpha}"),
            &Ggx::new(alpha),
        );
    }
}

/// Mean and standard error of `f(sample)` over `n` draws (failed draws count as 0).
fn mean_and_error(n: usize, rng: &mut Rng, mut f: impl FnMut(Vec3) -> f64) -> (f64, f64) {
    let (mut sum, mut sum2) = (0.0, 0.0);
    for _ in 0..n {
        let x = f(rng.next_vec3());
        sum += x;
        sum2 += x * x;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(0.0);
    (mean, (var / n as f64).sqrt())
}

/// Monte Carlo directional albedo of channel 0: the mean of f cos / pdf.
fn albedo(bsdf: &Bsdf, wo: Vec3, n: usize, rng: &mut Rng) -> (f64, f64) {
    mean_and_error(n, rng, |u| match bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) {
        Some(s) => (s.f.x * s.wi.z / s.pdf) as f64,
        None => 0.0,
    })
}

#[test]
fn metal_rough_conductor_gains_no_energy() {
    // A white conductor reflects at most what arrives (single scattering loses some at high
    // roughness), and a near-mirror at normal incidence reflects nearly all of it.
    let mut rng = Rng::from_name("metal_rough_conductor_gains_no_energy");
    let n = 200_000;
    for roughness in ROUGHNESS {
        let bsdf = metal_rough(Vec3::ONE, 1.0, roughness, 1.0);
        for cos_wo in [1.0, 0.7, 0.3, 0.05] {
            let (mean, error) = albedo(&bsdf, wo_at(cos_wo), n, &mut rng);
            println!("conductor albedo r{roughness} coswo{cos_wo}: {mean:.5} +- {error:.5}");
            assert!(
                mean <= 1.0 + 3.0 * error + 1e-6,
                "r{roughness} cos {cos_wo}: {mean} +- {error}"
            );
            if roughness == 0.05 && cos_wo == 1.0 {
                assert!((mean - 1.0).abs() < 5e-3, "near-mirror albedo {mean} +- {error}");
            }
        }
    }
    // Reported, not asserted: glTF's dielectric mixes Lambert and GGX by the Fresnel weight of
    // wo.h, which is not energy conserving at grazing angles by design.
    for roughness in ROUGHNESS {
        let bsdf = metal_rough(Vec3::ONE, 0.0, roughness, 1.0);
        for cos_wo in [1.0, 0.3, 0.05] {
            let (mean, error) = albedo(&bsdf, wo_at(cos_wo), n, &mut rng);
            println!("dielectric albedo r{roughness} coswo{cos_wo}: {mean:.5} +- {error:.5}");
        }
    }
}

#[test]
fn diffuse_albedo_equals_reflectance() {
    let albedo_rgb = Vec3::new(0.2, 0.5, 0.9);
    let bsdf = Bsdf::Diffuse(Diffuse { albedo: albedo_rgb });
    let mut rng = Rng::from_name("diffuse_albedo_equals_reflectance");
    for cos_wo in [1.0, 0.5, 0.05] {
        let wo = wo_at(cos_wo);
        for channel in 0..3 {
            let (mean, error) = mean_and_error(100_000, &mut rng, |u| {
                match bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) {
                    Some(s) => (s.f[channel] * s.wi.z / s.pdf) as f64,
                    None => 0.0,
                }
            });
            let expected = albedo_rgb[channel] as f64;
            // Each sample weighs exactly f cos / pdf = albedo up to rounding (and the odd draw at
            // the horizon that fails), so the tolerance is mostly float noise.
            assert!(
                (mean - expected).abs() <= 3.0 * error + 1e-5,
                "cos {cos_wo} channel {channel}: {mean} +- {error} vs {expected}"
            );
        }
    }
}

#[test]
fn bsdf_sample_agrees_with_eval_and_pdf() {
    let mut bsdfs = vec![Bsdf::Diffuse(Diffuse { albedo: BASE })];
    for roughness in ROUGHNESS {
        for (metallic, specular) in METAL_SPECULAR.into_iter().chain([(0.0, 0.0)]) {
            bsdfs.push(metal_rough(BASE, metallic, roughness, specular));
        }
        bsdfs.push(transmitting(BASE, 1.0, roughness));
        bsdfs.push(transmitting(BASE, 0.4, roughness));
    }
    let mut rng = Rng::from_name("bsdf_sample_agrees_with_eval_and_pdf");
    for bsdf in &bsdfs {
        for cos_wo in [1.0, 0.7, 0.3, 0.05, 0.01] {
            let wo = wo_at(cos_wo);
            for _ in 0..20_000 {
                let u = rng.next_vec3();
                let Some(s) = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) else { continue };
                // Formatted only on failure: this loop runs millions of times.
                let case = || format!("{bsdf:?} wo {wo:?} u {u:?}: {s:?}");
                let side_ok = s.wi.z > 0.0 || (s.wi.z < 0.0 && bsdf.transmits());
                assert!((s.wi.length() - 1.0).abs() < 1e-5 && side_ok, "{}", case());
                assert!(s.pdf > 0.0 && s.pdf.is_finite(), "{}", case());
                assert!(s.f.is_finite() && s.f.min_element() >= 0.0, "{}", case());
                let (f, pdf) = (bsdf.eval(wo, s.wi), bsdf.pdf(wo, s.wi));
                assert!(
                    (s.f - f).abs().max_element() <= 1e-5 * f.max_element(),
                    "{}: eval {f}",
                    case()
                );
                assert!((s.pdf - pdf).abs() <= 1e-5 * pdf, "{}: pdf {pdf}", case());
            }
        }
    }
}

fn rough_dielectric(roughness: f32, eta: f32) -> Bsdf {
    Bsdf::Dielectric(Dielectric { eta, tint: BASE, ggx: Some(Ggx::new(roughness * roughness)) })
}

#[test]
fn rough_dielectric_matches_pdf_over_the_sphere() {
    // Reflection above the surface and refraction below it: `pdf` (the visible-normal density
    // times each lobe's Jacobian and choice) must integrate to 1 less what falls on no valid
    // microfacet, and match where `sample` puts its directions.
    for (roughness, eta) in DIELECTRIC_CASES {
        let bsdf = rough_dielectric(roughness, eta);
        for cos_wo in DIELECTRIC_COS_WO {
            let wo = wo_at(cos_wo);
            let name = format!("rough_dielectric_r{roughness}_eta{eta:.3}_coswo{cos_wo}");
            assert_fits(
                &name,
                Spherical::sphere(),
                |u| {
                    let s = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z))?;
                    assert!(
                        s.pdf > 0.0 && s.pdf.is_finite(),
                        "{name}: pdf {} at {:?}",
                        s.pdf,
                        s.wi
                    );
                    let refracted = s.wi.z < 0.0;
                    assert_eq!(refracted, s.lobe == Lobe::GlossyTransmission, "{name}");
                    assert_eq!(s.eta, if refracted { eta } else { 1.0 }, "{name}");
                    Some(s.wi)
                },
                |wi| bsdf.pdf(wo, wi),
            );
        }
    }
}

/// A rough dielectric makes no light: what it reflects plus what it refracts (with the 1 / eta²
/// of radiance undone) is at most what arrives, and close to it at low roughness.
#[test]
fn rough_dielectric_gains_no_energy() {
    let mut rng = Rng::from_name("rough_dielectric_gains_no_energy");
    let n = 200_000;
    for (roughness, eta) in DIELECTRIC_CASES {
        let white = Bsdf::Dielectric(Dielectric {
            eta,
            tint: Vec3::ONE,
            ggx: Some(Ggx::new(roughness * roughness)),
        });
        for cos_wo in DIELECTRIC_COS_WO {
            let wo = wo_at(cos_wo);
            let (mean, err) =
                mean_and_error(n, &mut rng, |u| match white.sample(wo, u.x, Vec2::new(u.y, u.z)) {
                    Some(s) => (s.f.x * s.wi.z.abs() / s.pdf * s.eta * s.eta) as f64,
                    None => 0.0,
                });
            assert!(mean <= 1.0 + 4.0 * err, "r{roughness} eta{eta} cos{cos_wo}: {mean} +- {err}");
            if roughness <= 0.1 {
                assert!(mean > 0.97, "r{roughness} eta{eta} cos{cos_wo}: {mean} +- {err}");
            }
        }
    }
}

fn translucent(dt: f32, transmission: f32, roughness: f32, specular: f32) -> Bsdf {
    Bsdf::MetalRough(
        MetalRough::new(BASE, 0.0, roughness, 1.5, specular, Vec3::ONE)
            .with_transmission(transmission)
            .with_diffuse_transmission(dt, Vec3::new(0.3, 0.9, 0.6)),
    )
}

#[test]
fn diffuse_transmission_matches_pdf_over_the_sphere() {
    for (dt, t, roughness, specular) in DIFFUSE_TRANSMISSION_CASES {
        let bsdf = translucent(dt, t, roughness, specular);
        assert!(bsdf.transmits());
        for cos_wo in COS_WO {
            let wo = wo_at(cos_wo);
            let name = format!("diffuse_transmission_dt{dt}_t{t}_r{roughness}_coswo{cos_wo}");
            assert_bsdf_fits_sphere(&name, &bsdf, wo);
        }
    }
}

/// A white Lambertian sheet (no specular layer) with diffuse transmission dt reflects 1 - dt of
/// the light and passes dt to the far side, Lambertian there, at every angle.
#[test]
fn diffuse_transmission_splits_the_diffused_light() {
    let mut rng = Rng::from_name("diffuse_transmission_splits_the_diffused_light");
    for dt in [0.3f32, 1.0] {
        let sheet = Bsdf::MetalRough(
            MetalRough::new(Vec3::ONE, 0.0, 1.0, 1.5, 0.0, Vec3::ONE)
                .with_diffuse_transmission(dt, Vec3::ONE),
        );
        for cos_wo in [1.0, 0.5, 0.05] {
            let [(total, e_total), (through, e_through)] =
                albedo_both_sides(&sheet, wo_at(cos_wo), 100_000, &mut rng);
            assert!(
                (total - 1.0).abs() < 1e-4,
                "dt {dt} cos {cos_wo}: albedo {total} +- {e_total}"
            );
            assert!(
                (through - dt as f64).abs() < 4.0 * e_through + 1e-4,
                "dt {dt} cos {cos_wo}: through {through} +- {e_through}"
            );
        }
    }
}

/// A layered BSDF over `base` with anisotropy `strength`, an optional sheen (colour, roughness)
/// and an optional coat (weight, roughness, normal).
fn layered(
    base: MetalRough,
    strength: f32,
    sheen: Option<(Vec3, f32)>,
    coat: Option<(f32, f32, Vec3)>,
) -> Bsdf {
    Bsdf::Layered(Layered {
        base: anisotropic(base, strength),
        sheen: sheen.map(|(color, roughness)| Sheen::new(color, roughness)),
        coat: coat.map(|(weight, roughness, normal)| Coat {
            weight,
            ggx: Ggx::new(roughness * roughness),
            normal: normal.normalize(),
        }),
        iridescence: None,
    })
}

/// `bsdf` (layered) with a thin film of `weight`, index `ior` and `thickness` nanometres.
fn with_film(bsdf: Bsdf, weight: f32, ior: f32, thickness: f32) -> Bsdf {
    let Bsdf::Layered(mut l) = bsdf else { unreachable!("a layered BSDF") };
    l.iridescence = Some(ThinFilm { weight, ior, thickness });
    Bsdf::Layered(l)
}

/// The layered chi-square cases: coats (one with a normal of its own), sheens, anisotropy, all
/// three over a transmitting base, and thin films (whose Fresnel sets the base's lobe choice).
fn layered_cases() -> [(&'static str, Bsdf); N_LAYERED] {
    let dielectric = |roughness| MetalRough::new(BASE, 0.0, roughness, 1.5, 1.0, Vec3::ONE);
    let metal = |roughness| MetalRough::new(BASE, 1.0, roughness, 1.5, 1.0, Vec3::ONE);
    let lambert = MetalRough::new(BASE, 0.0, 1.0, 1.5, 0.0, Vec3::ONE);
    let tilted = Vec3::new(0.3, -0.2, 0.93);
    [
        ("coat_c1_r0.1", layered(dielectric(0.6), 0.0, None, Some((1.0, 0.1, Vec3::Z)))),
        ("coat_c0.7_r0.4_tilted", layered(metal(0.3), 0.0, None, Some((0.7, 0.4, tilted)))),
        ("sheen_r0.5", layered(lambert, 0.0, Some((Vec3::new(0.9, 0.6, 0.3), 0.5)), None)),
        (
            "sheen_r0.1_coat_c0.5_r0.2",
            layered(dielectric(0.5), 0.0, Some((Vec3::ONE, 0.1)), Some((0.5, 0.2, Vec3::Z))),
        ),
        ("aniso_s0.8_metal_r0.4", layered(metal(0.4), 0.8, None, None)),
        ("aniso_s0.5_dielectric_r0.1", layered(dielectric(0.1), 0.5, None, None)),
        (
            "aniso_s1_sheen_coat_transmitting",
            layered(
                dielectric(0.2).with_transmission(0.5).with_diffuse_transmission(0.3, Vec3::ONE),
                1.0,
                Some((Vec3::new(0.2, 0.8, 0.5), 0.7)),
                Some((0.8, 0.3, tilted)),
            ),
        ),
        (
            "film_w1_d400_dielectric_r0.3",
            with_film(layered(dielectric(0.3), 0.0, None, None), 1.0, 1.8, 400.0),
        ),
        (
            "film_w0.6_d250_metal_r0.2_coat",
            with_film(layered(metal(0.2), 0.0, None, Some((0.5, 0.3, Vec3::Z))), 0.6, 1.3, 250.0),
        ),
        (
            "film_w1_d700_half_metal_transmitting_aniso",
            with_film(
                layered(
                    MetalRough::new(BASE, 0.5, 0.4, 1.5, 0.7, Vec3::ONE).with_transmission(0.5),
                    0.6,
                    None,
                    None,
                ),
                1.0,
                2.0,
                700.0,
            ),
        ),
    ]
}

#[test]
fn layered_sampling_matches_pdf_over_the_sphere() {
    for (name, bsdf) in layered_cases() {
        for cos_wo in COS_WO {
            assert_bsdf_fits_sphere(&format!("layered_{name}_coswo{cos_wo}"), &bsdf, wo_at(cos_wo));
        }
    }
}

#[test]
fn layered_sample_agrees_with_eval_and_pdf() {
    let mut rng = Rng::from_name("layered_sample_agrees_with_eval_and_pdf");
    for (name, bsdf) in layered_cases() {
        for cos_wo in [1.0, 0.7, 0.3, 0.05, 0.01] {
            let wo = wo_at(cos_wo);
            for _ in 0..20_000 {
                let u = rng.next_vec3();
                let Some(s) = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) else { continue };
                let case = || format!("{name} wo {wo:?} u {u:?}: {s:?}");
                let side_ok = s.wi.z > 0.0 || (s.wi.z < 0.0 && bsdf.transmits());
                assert!((s.wi.length() - 1.0).abs() < 1e-5 && side_ok, "{}", case());
                assert!(s.pdf > 0.0 && s.pdf.is_finite(), "{}", case());
                assert!(s.f.is_finite() && s.f.min_element() >= 0.0, "{}", case());
                let (f, pdf) = (bsdf.eval(wo, s.wi), bsdf.pdf(wo, s.wi));
                assert_eq!((s.f, s.pdf), (f, pdf), "{}", case());
            }
        }
    }
}

#[test]
fn anisotropic_ggx_visible_normal_reflection_matches_pdf() {
    for (ax, ay) in ANISO_ALPHA {
        let ggx = AnisoGgx::new(ax, ay);
        assert_visible_normal_reflection_fits(&format!("aniso_ggx_reflection_a{ax}_{ay}"), &ggx);
    }
}

/// A white sheen or coat over a white Lambertian base (no specular layer, albedo exactly 1)
/// takes from the base what it reflects: the albedo stays at most 1 at every angle, and with a
/// sheen alone (whose albedo scaling is its tabulated albedo) it is 1 within the table's error.
#[test]
fn layers_over_white_lambert_gain_no_energy() {
    let mut rng = Rng::from_name("layers_over_white_lambert_gain_no_energy");
    let white = MetalRough::new(Vec3::ONE, 0.0, 1.0, 1.5, 0.0, Vec3::ONE);
    let n = 200_000;
    for roughness in [0.0f32, 0.1, 0.3, 0.6, 1.0] {
        let sheen = layered(white, 0.0, Some((Vec3::ONE, roughness)), None);
        let coat = layered(white, 0.0, None, Some((1.0, roughness, Vec3::Z)));
        let both =
            layered(white, 0.0, Some((Vec3::ONE, roughness)), Some((1.0, roughness, Vec3::Z)));
        for cos_wo in [1.0, 0.7, 0.3, 0.1, 0.02] {
            let wo = wo_at(cos_wo);
            for (name, bsdf) in [("sheen", &sheen), ("coat", &coat), ("sheen and coat", &both)] {
                let (mean, error) = albedo(bsdf, wo, n, &mut rng);
                println!("{name} r{roughness} coswo{cos_wo}: albedo {mean:.5} +- {error:.5}");
                // The table's bilinear error (under 2e-3, `sheen.rs`) on top of the noise.
                assert!(
                    mean <= 1.0 + 4.0 * error + 2e-3,
                    "{name} r{roughness} cos {cos_wo}: {mean} +- {error}"
                );
                if name == "sheen" {
                    assert!(
                        (mean - 1.0).abs() <= 4.0 * error + 5e-3,
                        "{name} r{roughness} cos {cos_wo}: {mean} +- {error}"
                    );
                }
            }
        }
    }
}

/// The sheen's tabulated albedo matches a Monte Carlo estimate of the lobe itself (sampled
/// through the layered BSDF with a black base, so only the sheen reflects).
#[test]
fn sheen_albedo_table_matches_the_lobe() {
    let mut rng = Rng::from_name("sheen_albedo_table_matches_the_lobe");
    let black = MetalRough::new(Vec3::ZERO, 0.0, 1.0, 1.5, 0.0, Vec3::ONE);
    for roughness in [0.1f32, 0.4, 0.9] {
        let bsdf = layered(black, 0.0, Some((Vec3::ONE, roughness)), None);
        for cos_wo in [0.9f32, 0.5, 0.15] {
            let (mean, error) = albedo(&bsdf, wo_at(cos_wo), 200_000, &mut rng);
            let table = crate::render::bsdf::sheen_albedo(cos_wo, roughness) as f64;
            assert!(
                (mean - table).abs() <= 4.0 * error + 0.01 * table + 1e-3,
                "r{roughness} cos {cos_wo}: {mean} +- {error} vs table {table}"
            );
        }
    }
}

/// A thin film over a white conductor neither gains nor loses energy: a lossless film over a
/// perfect mirror reflects all it receives, and the metal's multiple scattering gives back what
/// single scattering off the microfacets loses. Every channel's albedo is 1 within 4 standard
/// errors plus the albedo tables' interpolation error (4e-3, as `worker/tests/energy.rs`), for
/// any film, roughness and angle. Without the multiple scattering, roughness 1 loses up to half.
#[test]
fn thin_films_over_a_white_conductor_keep_all_energy() {
    let mut rng = Rng::from_name("thin_films_over_a_white_conductor_gain_no_energy");
    let n = 100_000;
    {
        for roughness in [0.05f32, 0.4, 1.0] {
            let white = MetalRough::new(Vec3::ONE, 1.0, roughness, 1.5, 1.0, Vec3::ONE);
            for (ior, thickness) in [(1.3f32, 400.0f32), (1.8, 250.0), (2.3, 900.0), (1.1, 100.0)] {
                let bsdf = with_film(layered(white, 0.0, None, None), 1.0, ior, thickness);
                for cos_wo in [1.0, 0.7, 0.3, 0.05] {
                    let wo = wo_at(cos_wo);
                    let (mut sum, mut sum_sq) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
                    for _ in 0..n {
                        let u = rng.next_vec3();
                        let Some(s) = bsdf.sample(wo, u.x, Vec2::new(u.y, u.z)) else { continue };
                        let x = (s.f * s.wi.z / s.pdf).as_dvec3();
                        (sum, sum_sq) = (sum + x, sum_sq + x * x);
                    }
                    let mean = sum / n as f64;
                    let error = ((sum_sq / n as f64 - mean * mean).max(glam::DVec3::ZERO)
                        / n as f64)
                        .powf(0.5);
                    let case = format!("r{roughness} ior {ior} d {thickness}");
                    println!("{case} coswo{cos_wo}: albedo {mean:.4} +- {error:.4}");
                    for k in 0..3 {
                        assert!(
                            (mean[k] - 1.0).abs() <= 4.0 * error[k] + 4e-3,
                            "{case} cos {cos_wo}: channel {k} {mean} +- {error}"
                        );
                    }
                }
            }
        }
    }
}

/// A white anisotropic conductor reflects at most what arrives, at any strength.
#[test]
fn anisotropic_conductor_gains_no_energy() {
    let mut rng = Rng::from_name("anisotropic_conductor_gains_no_energy");
    for roughness in [0.1f32, 0.5] {
        for strength in [0.5f32, 1.0] {
            let metal = MetalRough::new(Vec3::ONE, 1.0, roughness, 1.5, 1.0, Vec3::ONE);
            let bsdf = layered(metal, strength, None, None);
            for cos_wo in [1.0, 0.5, 0.1] {
                let (mean, error) = albedo(&bsdf, wo_at(cos_wo), 200_000, &mut rng);
                assert!(
                    mean <= 1.0 + 4.0 * error + 1e-6,
                    "r{roughness} s{strength} cos {cos_wo}: {mean} +- {error}"
                );
            }
        }
    }
}

/// With strength 0 anisotropic GGX is the isotropic lobe: the same f and pdf within rounding.
#[test]
fn zero_anisotropy_is_the_isotropic_brdf() {
    let mut rng = Rng::from_name("zero_anisotropy_is_the_isotropic_brdf");
    for roughness in [0.2f32, 0.7] {
        let base = MetalRough::new(BASE, 0.5, roughness, 1.5, 1.0, Vec3::ONE);
        let (iso, aniso) = (Bsdf::MetalRough(base), layered(base, 0.0, None, None));
        let wo = wo_at(0.6);
        for _ in 0..1000 {
            let u = rng.next_vec3();
            let Some(s) = iso.sample(wo, u.x, Vec2::new(u.y, u.z)) else { continue };
            let (f, pdf) = (aniso.eval(wo, s.wi), aniso.pdf(wo, s.wi));
            assert!((f - s.f).abs().max_element() <= 1e-4 * s.f.max_element(), "{f} vs {}", s.f);
            assert!((pdf - s.pdf).abs() <= 1e-4 * s.pdf, "{pdf} vs {}", s.pdf);
        }
    }
}
