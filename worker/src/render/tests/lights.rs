//! Tests of the lights: chi-square of triangle-light sampling against its solid-angle pdf, the
//! spot cone's falloff and power weight, the mixture's choice probabilities, and the light
//! tree's: chi-square of its choices at several points, each point's probabilities summing to
//! one, and `pmf` giving what `choose` returned.

use std::f64::consts::PI;

use glam::{DVec2, Vec2, Vec3};

use super::chi2::{assert_fits, Spherical};
use super::chi2::{chi2_statistic, sidak_alpha, Chi2Test, Gnomonic, Rng};
use crate::render::light::{
    spot_falloff, ChooseLight, DirectionalLight, Environment, Light, LightChoice, LightSampler,
    MapEnvironment, PointLight, PowerMixture, ShadingContext, SpotLight, TriangleLight,
    CHOOSE_BATCH,
};
use common::envmap::EnvMap;

/// A triangle light seen from a receiver.
struct TriangleCase {
    /// Names the chi-square test.
    name: &'static str,
    /// Vertices (counter-clockwise seen from the emitting side).
    p: [Vec3; 3],
    /// The shading point.
    receiver: Vec3,
    /// Emits from both faces.
    two_sided: bool,
}

/// The triangle-light cases: a plain one, one that fills most of the hemisphere, a sliver, the
/// back of a two-sided light seen obliquely, and one seen almost edge-on from just above its plane.
const TRIANGLES: [TriangleCase; 5] = [
    TriangleCase {
        name: "small_distant",
        p: [Vec3::new(-1.0, -1.0, 3.0), Vec3::new(0.0, 1.0, 3.3), Vec3::new(1.0, -1.2, 2.8)],
        receiver: Vec3::new(0.2, 0.1, 0.0),
        two_sided: false,
    },
    TriangleCase {
        name: "large_close",
        p: [Vec3::new(-20.0, -20.0, 0.2), Vec3::new(0.0, 25.0, 0.2), Vec3::new(20.0, -20.0, 0.2)],
        receiver: Vec3::ZERO,
        two_sided: false,
    },
    TriangleCase {
        name: "thin",
        p: [Vec3::new(-1.0, 0.0, 2.0), Vec3::new(1.5, 0.3, 2.6), Vec3::new(1.5, 0.33, 2.6)],
        receiver: Vec3::ZERO,
        two_sided: true,
    },
    TriangleCase {
        name: "two_sided_back",
        p: [Vec3::new(0.0, 0.0, 1.0), Vec3::new(2.0, 0.0, 1.0), Vec3::new(0.0, 2.0, 1.0)],
        receiver: Vec3::new(-1.5, -0.5, 0.3),
        two_sided: true,
    },
    TriangleCase {
        name: "grazing",
        p: [Vec3::new(0.1, -1.0, 0.0), Vec3::new(1.6, 0.0, 0.0), Vec3::new(0.1, 1.0, 0.0)],
        receiver: Vec3::new(0.0, 0.0, 0.05),
        two_sided: false,
    },
];

/// Chi-square tests in this file.
pub(super) const N_CHI2: usize = TRIANGLES.len() + 1 + 2 + TREE_POINTS.len() + 2;

/// Distance along unit `dir` from `origin` to triangle `p` (Möller-Trumbore in f64), if it hits.
fn hit_distance(p: [Vec3; 3], origin: Vec3, dir: Vec3) -> Option<f64> {
    let [p0, p1, p2] = p.map(Vec3::as_dvec3);
    let (o, d) = (origin.as_dvec3(), dir.as_dvec3());
    let (e1, e2) = (p1 - p0, p2 - p0);
    let pvec = d.cross(e2);
    let det = e1.dot(pvec);
    if det == 0.0 {
        return None;
    }
    let tvec = o - p0;
    let b1 = tvec.dot(pvec) / det;
    let qvec = tvec.cross(e1);
    let b2 = d.dot(qvec) / det;
    let t = e2.dot(qvec) / det;
    (b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 && t > 0.0).then_some(t)
}

/// The gnomonic chart of the directions from `receiver` toward triangle `p`: the axis is the
/// normal of the triangle's plane, turned toward it, so the whole plane in front projects to the
/// chart, and the chart's rectangle is the projected triangle's bounding box plus 0.5%.
fn chart_around(p: [Vec3; 3], receiver: Vec3) -> Gnomonic {
    let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize();
    let axis = n * n.dot(p[0] - receiver).signum();
    let chart = Gnomonic::new(axis, p[1] - p[0], DVec2::ZERO, DVec2::ZERO);
    let corners = p.map(|v| chart.project((v - receiver).as_dvec3()));
    let min = corners.iter().copied().fold(DVec2::INFINITY, DVec2::min);
    let max = corners.iter().copied().fold(DVec2::NEG_INFINITY, DVec2::max);
    let pad = 0.005 * (max - min);
    Gnomonic::new(axis, p[1] - p[0], min - pad, max + pad)
}

#[test]
fn triangle_light_sampling_matches_pdf() {
    for case in &TRIANGLES {
        let name = format!("triangle_light_{}", case.name);
        let light =
            TriangleLight::new(case.p, Vec3::splat(2.0), case.two_sided).expect("a triangle");
        let receiver = case.receiver;
        // Samples on an edge may round to just outside the triangle, where the exact intersection
        // below gives 0: `sample` checks the sampler's own pdf instead.
        let outcome =
            Chi2Test::new(&name, chart_around(case.p, receiver)).without_sample_pdf_check().run(
                |u| {
                    let s = light.sample_li(receiver, Vec2::new(u.y, u.z))?;
                    let point = s.point.expect("an area light has a point");
                    let pdf = light.pdf_li(s.wi, (point - receiver).length_squared());
                    assert!(s.pdf > 0.0 && s.pdf.is_finite(), "{name}: pdf {} at {s:?}", s.pdf);
                    assert!((s.pdf - pdf).abs() <= 1e-4 * pdf, "{name}: pdf_li {pdf} for {s:?}");
                    assert!(s.li == light.emission, "{name}: li {:?}", s.li);
                    Some(s.wi)
                },
                |wi| {
                    let Some(t) = hit_distance(case.p, receiver, wi) else { return 0.0 };
                    if light.radiance(-wi) == Vec3::ZERO {
                        return 0.0;
                    }
                    light.pdf_li(wi, (t * t) as f32)
                },
            );
        outcome.assert_passed();
    }
}

/// Light leaving a triangle light (a light subpath's first direction): cosine-distributed about
/// the emitting face's normal, both faces half each for a two-sided light, with the density
/// `pdf_le` gives; the point is uniform over the triangle (its barycentrics sum to one).
#[test]
fn triangle_light_emission_sampling_matches_pdf() {
    let p = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.2, 0.1), Vec3::new(0.3, 1.0, -0.2)];
    for two_sided in [false, true] {
        let light = TriangleLight::new(p, Vec3::ONE, two_sided).expect("a triangle");
        let name =
            format!("triangle_light_le_{}", if two_sided { "two_sided" } else { "one_sided" });
        let domain =
            if two_sided { Spherical::sphere() } else { Spherical::cap(light.normal, PI / 2.0) };
        assert_fits(
            &name,
            domain,
            |u| {
                let (b, dir, pdf) = light.sample_le(Vec2::new(0.3, 0.6), Vec2::new(u.y, u.z))?;
                assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-6 && b.iter().all(|&x| x >= 0.0));
                let expect = light.pdf_le(light.normal.dot(dir));
                assert!((pdf - expect).abs() <= 1e-4 * expect, "{name}: {pdf} against {expect}");
                Some(dir)
            },
            |w| light.pdf_le(light.normal.dot(w)),
        );
    }
}

#[test]
fn one_sided_triangle_light_is_dark_from_behind() {
    let case = &TRIANGLES[0];
    let light = TriangleLight::new(case.p, Vec3::ONE, false).expect("a triangle");
    let behind = Vec3::new(0.0, 0.0, 6.0);
    let mut rng = Rng::from_name("one_sided_triangle_light_is_dark_from_behind");
    for _ in 0..10_000 {
        let u = Vec2::new(rng.next_f32(), rng.next_f32());
        assert!(light.sample_li(behind, u).is_none());
        assert!(light.sample_li(case.receiver, u).is_some());
    }
}

/// (inner, outer) cone angles in degrees: glTF's defaults, a narrow ring, a one-degree ramp,
/// a half-space, and a ramp narrower than the spec's 0.001 clamp on cos(inner) - cos(outer).
const SPOT_CONES: [(f32, f32); 5] =
    [(0.0, 45.0), (10.0, 20.0), (30.0, 31.0), (0.0, 90.0), (20.0, 20.02)];

fn spot(inner_degrees: f32, outer_degrees: f32) -> SpotLight {
    SpotLight {
        position: Vec3::ZERO,
        direction: Vec3::new(0.0, -1.0, 0.0),
        intensity: Vec3::ONE,
        cos_inner: inner_degrees.to_radians().cos(),
        cos_outer: outer_degrees.to_radians().cos(),
    }
}

#[test]
fn spot_cone_weight_matches_quadrature() {
    // The integral of the falloff over the sphere, 2 pi * integral of falloff(cos t) sin t dt,
    // by the midpoint rule in theta (the weight integrates in cos theta).
    let n = 400_000;
    for (inner, outer) in SPOT_CONES {
        let light = spot(inner, outer);
        let mut sum = 0.0f64;
        for i in 0..n {
            let theta = PI * (i as f64 + 0.5) / n as f64;
            let falloff = spot_falloff(theta.cos() as f32, light.cos_inner, light.cos_outer);
            sum += falloff as f64 * theta.sin();
        }
        let reference = 2.0 * PI * sum * PI / n as f64;
        let weight = light.cone_solid_angle_weight() as f64;
        let error = (weight - reference).abs() / reference;
        println!("spot cone ({inner}, {outer}) deg: weight {weight:.6}, quadrature {reference:.6}, relative error {error:.2e}");
        assert!(error < 1e-3, "cone ({inner}, {outer}): {weight} vs {reference}");
    }
}

#[test]
fn spot_falloff_is_one_inside_zero_outside_and_monotone() {
    for (inner, outer) in SPOT_CONES {
        let light = spot(inner, outer);
        let (ci, co) = (light.cos_inner, light.cos_outer);
        // The spec's reference code ramps over at least 0.001 in cos, so with a narrower ramp
        // the falloff reaches 1 slightly inside the inner cone.
        let full = co + (ci - co).max(0.001);
        let mut previous = 0.0f32;
        let n = 200_000;
        for i in 0..=n {
            let cos = -1.0 + 2.0 * i as f32 / n as f32;
            let f = spot_falloff(cos, ci, co);
            let case = format!("cone ({inner}, {outer}) at cos {cos}: {f}");
            assert!((0.0..=1.0).contains(&f), "{case}");
            assert!(f >= previous, "{case} after {previous}");
            if cos <= co {
                assert_eq!(f, 0.0, "{case}");
            }
            if cos >= full {
                assert_eq!(f, 1.0, "{case}");
            }
            if cos > co && cos < full {
                assert!(f > 0.0 && f < 1.0, "{case}");
            }
            previous = f;
        }
    }
}

#[test]
fn light_sampler_choose_matches_probability() {
    let triangle = |z: f32, size: f32, emission: f32, two_sided: bool| {
        let p = [Vec3::new(0.0, 0.0, z), Vec3::new(size, 0.0, z), Vec3::new(0.0, size, z)];
        Light::Triangle(
            TriangleLight::new(p, Vec3::splat(emission), two_sided).expect("a triangle"),
        )
    };
    let lights = vec![
        triangle(1.0, 1.0, 5.0, false),
        triangle(2.0, 0.3, 20.0, true),
        triangle(3.0, 2.0, 0.0, false),  // no power: never chosen
        triangle(4.0, 0.01, 1.0, false), // expects a few samples in 10^6: pooled
        Light::Point(PointLight { position: Vec3::ONE, intensity: Vec3::new(1.0, 2.0, 3.0) }),
        Light::Spot(SpotLight { intensity: Vec3::splat(10.0), ..spot(10.0, 30.0) }),
        Light::Directional(DirectionalLight { to_light: Vec3::Y, irradiance: Vec3::splat(0.1) }),
        Light::Environment(std::sync::Arc::new(Environment::Uniform(Vec3::splat(0.05)))),
    ];
    // The first two triangles are one emitter.
    let k = lights.len();
    let sampler = PowerMixture::new(&lights, &[0, 0, 1, 2, 3, 4, 5, 6], 5.0);
    let total: f64 = (0..k as u32).map(|i| sampler.probability(i) as f64).sum();
    assert!((total - 1.0).abs() < 1e-6, "probabilities sum to {total}");
    assert_eq!(sampler.probability(2), 0.0);

    let n = 1_000_000;
    let mut rng = Rng::from_name("light_sampler_choose_matches_probability");
    let mut observed = vec![0.0f64; k];
    for _ in 0..n {
        let (i, p) = sampler.choose(rng.next_f32()).expect("lights with power");
        assert_eq!(p, sampler.probability(i), "light {i}");
        observed[i as usize] += 1.0;
    }
    assert_eq!(observed[2], 0.0, "a light without power was chosen");
    let expected: Vec<f64> =
        (0..k as u32).map(|i| sampler.probability(i) as f64 * n as f64).collect();
    let stat = chi2_statistic(&observed, &expected, n).expect("a valid table");
    println!(
        "light_sampler: chi2 = {:.2}, dof = {}, p = {:.4}; observed {observed:?}, expected {expected:?}",
        stat.chi2, stat.dof, stat.p_value
    );
    assert!(stat.p_value > sidak_alpha(), "{stat:?}: observed {observed:?}, expected {expected:?}");
    // The edges of [0, 1) pick the first and the last light with power.
    assert_eq!(sampler.choose(0.0).map(|c| c.0), Some(0));
    assert_eq!(sampler.choose(1.0 - f32::EPSILON / 2.0).map(|c| c.0), Some(k as u32 - 1));
}

#[test]
fn light_choice_mixes_power_with_a_uniform_choice_of_emitter() {
    let quad = |x: f32, size: f32, emission: f32| {
        let [a, b, c, d] = [[0.0, 0.0], [size, 0.0], [size, size], [0.0, size]]
            .map(|[u, v]| Vec3::new(x + u, v, 0.0));
        [[a, b, c], [a, c, d]]
            .map(|p| Light::Triangle(TriangleLight::new(p, Vec3::splat(emission), false).unwrap()))
    };
    // A bright emitter (two triangles, 98% of the power), a dim one (two triangles), a dark one
    // (never chosen) and a point light.
    let [b0, b1] = quad(0.0, 1.0, 1000.0);
    let [d0, d1] = quad(5.0, 0.5, 80.0);
    let [z0, z1] = quad(9.0, 1.0, 0.0);
    let point = Light::Point(PointLight { position: Vec3::ONE, intensity: Vec3::splat(0.5) });
    let lights = vec![b0, b1, d0, z0, d1, z1, point];
    let powers: Vec<f64> = lights.iter().map(|l| l.power(5.0) as f64).collect();
    let sampler = PowerMixture::new(&lights, &[7, 7, 3, 9, 3, 9, 1], 5.0);
    let total: f64 = powers.iter().sum();
    let emitter = |i: &[usize]| i.iter().map(|&i| powers[i]).sum::<f64>();
    let (bright, dim) = (emitter(&[0, 1]), emitter(&[2, 4]));
    let share =
        |i: usize, of_emitter: f64| 0.5 * powers[i] / total + 0.5 * powers[i] / of_emitter / 3.0;
    let expected = [
        share(0, bright),
        share(1, bright),
        share(2, dim),
        0.0,
        share(4, dim),
        0.0,
        share(6, powers[6]),
    ];
    for (i, &want) in expected.iter().enumerate() {
        let got = sampler.probability(i as u32) as f64;
        assert!((got - want).abs() <= 1e-6 * want.max(1e-3), "light {i}: {got} against {want}");
    }
    // By power alone each dim triangle would get 1% and the point light 0.2%; each lit
    // emitter now gets at least a sixth of the choice.
    assert!(expected[2] > 0.08 && expected[6] > 0.16);
}

/// A 64x32 map with a smooth gradient, a bright 3x3-texel "sun" and a black band, so that the
/// sampled density varies over two orders of magnitude (a much smaller, brighter sun defeats the
/// harness's quadrature of the expected counts, not the sampler).
fn test_map() -> EnvMap {
    let (w, h) = (64u32, 32u32);
    let texels = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if (40..43).contains(&x) && (9..12).contains(&y) {
                Vec3::new(60.0, 50.0, 40.0)
            } else if (20..24).contains(&y) {
                Vec3::ZERO
            } else {
                Vec3::new(0.2 + x as f32 / 64.0, 0.5, 1.0 - y as f32 / 40.0)
            }
        })
        .collect();
    EnvMap { width: w, height: h, texels }
}

#[test]
fn environment_map_sampling_matches_pdf() {
    for (name, rotation) in [("env_map", 0.0f32), ("env_map_rotated", 70.0)] {
        let env = MapEnvironment::new(&test_map(), 2.0, rotation);
        assert_fits(
            name,
            Spherical::sphere(),
            |u| env.sample(Vec2::new(u.x, u.y)).map(|(d, _, _)| d),
            |d| env.pdf(d),
        );
    }
}

#[test]
fn environment_map_sample_returns_the_radiance_and_density_of_its_direction() {
    let env = MapEnvironment::new(&test_map(), 2.0, 33.0);
    let mut rng = Rng::from_name("env_map_consistency");
    for _ in 0..10_000 {
        let u = Vec2::new(rng.next_f32(), rng.next_f32());
        let Some((d, radiance, pdf)) = env.sample(u) else { continue };
        assert!((d.length() - 1.0).abs() < 1e-4);
        assert_eq!(radiance, env.radiance(d), "direction {d}");
        assert!((pdf / env.pdf(d) - 1.0).abs() < 1e-3, "pdf {pdf} vs {}", env.pdf(d));
    }
    // The black band is never sampled and has zero density.
    let dark = EnvMap::uv_to_direction(0.3, 22.5 / 32.0);
    let rotated = {
        let (s, c) = 33f32.to_radians().sin_cos();
        Vec3::new(c * dark.x + s * dark.z, dark.y, -s * dark.x + c * dark.z)
    };
    assert_eq!(env.pdf(rotated), 0.0);
    assert_eq!(env.radiance(rotated), Vec3::ZERO);
}

/// Lights spread through a 10-unit box: small triangles facing every way (some two-sided, some
/// dark), point and spot lights, a directional light and the environment. Enough that the tree
/// is a few levels deep, few enough that each expects many samples in 10^6.
fn many_lights() -> Vec<Light> {
    let mut rng = Rng::from_name("many_lights");
    let mut lights = Vec::new();
    for k in 0..150 {
        let centre = (rng.next_vec3() - 0.5) * 10.0;
        let [a, b] = [rng.next_vec3() - 0.5, rng.next_vec3() - 0.5];
        let emission = if k % 37 == 5 { 0.0 } else { 0.5 + 4.0 * rng.next_f32() };
        if let Some(l) =
            TriangleLight::new([centre, centre + a, centre + b], Vec3::splat(emission), k % 3 == 0)
        {
            lights.push(Light::Triangle(l));
        }
    }
    for _ in 0..4 {
        let position = (rng.next_vec3() - 0.5) * 10.0;
        lights.push(Light::Point(PointLight { position, intensity: Vec3::splat(2.0) }));
    }
    lights.push(Light::Spot(SpotLight {
        position: Vec3::new(0.0, 4.0, 0.0),
        intensity: Vec3::splat(30.0),
        ..spot(20.0, 35.0)
    }));
    lights.push(Light::Directional(DirectionalLight {
        to_light: Vec3::Y,
        irradiance: Vec3::splat(0.1),
    }));
    lights.push(Light::Environment(std::sync::Arc::new(Environment::Uniform(Vec3::splat(0.05)))));
    lights
}

/// Shading points for the tree: the middle of the lights, a corner, far outside, and on a
/// surface facing away from most of them; the last one without a normal (as in a medium).
const TREE_POINTS: [(Vec3, Vec3); 5] = [
    (Vec3::new(0.1, 0.2, -0.3), Vec3::Y),
    (Vec3::new(4.5, -4.5, 4.5), Vec3::new(0.0, 0.0, 1.0)),
    (Vec3::new(30.0, 2.0, -10.0), Vec3::new(-1.0, 0.0, 0.0)),
    (Vec3::new(-2.0, -4.9, 1.0), Vec3::new(0.0, -1.0, 0.0)),
    (Vec3::new(1.0, 1.0, 1.0), Vec3::ZERO),
];

fn tree_sampler() -> LightSampler {
    let lights = many_lights();
    let emitters: Vec<u32> = (0..lights.len() as u32).collect();
    LightSampler::with_choice(lights, &emitters, 8.0, LightChoice::Tree)
}

#[test]
fn light_tree_probabilities_sum_to_one_and_match_choose() {
    let sampler = tree_sampler();
    let k = sampler.lights.len() as u32;
    for (p, n) in TREE_POINTS {
        let ctx = ShadingContext { p, n: n.normalize_or_zero() };
        let pmfs: Vec<f64> = (0..k).map(|i| sampler.pmf(&ctx, i) as f64).collect();
        let total: f64 = pmfs.iter().sum();
        assert!((total - 1.0).abs() < 1e-5, "at {p}: probabilities sum to {total}");
        // Dark lights are never chosen; the environment and the directional light share a fixed
        // two thirds (pbrt-v4: each light at infinity as much as the whole tree).
        for (i, light) in sampler.lights.iter().enumerate() {
            if light.power(8.0) == 0.0 {
                assert_eq!(pmfs[i], 0.0);
            }
            if matches!(light, Light::Environment(_) | Light::Directional(_)) {
                assert_eq!(pmfs[i], (1.0f32 / 3.0) as f64);
            }
        }
        let mut rng = Rng::from_name("light_tree_probabilities_sum_to_one_and_match_choose");
        for _ in 0..20_000 {
            let u = rng.next_f32();
            let (i, pmf, remapped) = sampler.choose(&ctx, u).expect("a light reaches the point");
            assert_eq!(pmf, sampler.pmf(&ctx, i), "light {i} at {p}, u = {u}");
            assert!(pmf > 0.0 && (0.0..1.0).contains(&remapped));
        }
    }
}

/// The batched choice and probability (`choose_batch`, `pmf_batch`, which the wavefront calls for
/// all its lanes at once) give `choose`'s and `pmf`'s bits, in batches of every size with
/// receivers of every kind side by side (walks that end at different depths, lights at infinity).
#[test]
fn light_tree_batches_give_the_single_choices_bit_for_bit() {
    let sampler = tree_sampler();
    let k = sampler.lights.len() as u32;
    let mut rng = Rng::from_name("light_tree_batches_give_the_single_choices_bit_for_bit");
    let mut walked = 0;
    for round in 0..2_000 {
        let n = 1 + round % CHOOSE_BATCH;
        let ctx: Vec<ShadingContext> = (0..n)
            .map(|_| {
                let (p, normal) = TREE_POINTS[(rng.next_u64() % TREE_POINTS.len() as u64) as usize];
                let jitter = rng.next_vec3() - 0.5;
                ShadingContext { p: p + jitter * 0.2, n: normal.normalize_or_zero() }
            })
            .collect();
        let u: Vec<f32> = (0..n).map(|_| rng.next_f32()).collect();
        let mut chosen = vec![None; n];
        sampler.choose_batch(&ctx, &u, &mut chosen);
        let light: Vec<u32> = (0..n).map(|_| (rng.next_u64() % k as u64) as u32).collect();
        let mut pmf = vec![0.0; n];
        sampler.pmf_batch(&ctx, &light, &mut pmf);
        for i in 0..n {
            let single = sampler.choose(&ctx[i], u[i]);
            assert_eq!(
                chosen[i].map(|(l, p, r)| (l, p.to_bits(), r.to_bits())),
                single.map(|(l, p, r)| (l, p.to_bits(), r.to_bits())),
                "round {round}, receiver {i} of {n}"
            );
            assert_eq!(pmf[i].to_bits(), sampler.pmf(&ctx[i], light[i]).to_bits());
            walked += usize::from(pmf[i] > 0.0 && !sampler.lights[light[i] as usize].is_infinite());
        }
    }
    assert!(walked > 1_000, "the batches walk the tree ({walked} probabilities)");
}

#[test]
fn light_tree_choices_match_their_probabilities() {
    let sampler = tree_sampler();
    let k = sampler.lights.len();
    let n = 1_000_000;
    for (p, normal) in TREE_POINTS {
        let ctx = ShadingContext { p, n: normal.normalize_or_zero() };
        let mut rng = Rng::from_name(&format!("light_tree_chi2 {p}"));
        let mut observed = vec![0.0f64; k];
        for _ in 0..n {
            let (i, _, _) = sampler.choose(&ctx, rng.next_f32()).expect("a light");
            observed[i as usize] += 1.0;
        }
        let expected: Vec<f64> =
            (0..k as u32).map(|i| sampler.pmf(&ctx, i) as f64 * n as f64).collect();
        let stat = chi2_statistic(&observed, &expected, n).expect("a valid table");
        println!(
            "light tree at {p}: chi2 = {:.2}, dof = {}, p = {:.4}",
            stat.chi2, stat.dof, stat.p_value
        );
        assert!(stat.p_value > sidak_alpha(), "at {p}: {stat:?}");
    }
}

#[test]
fn light_tree_spreads_each_lights_numbers_over_the_unit_interval() {
    let sampler = tree_sampler();
    let ctx = ShadingContext { p: Vec3::new(0.5, -1.0, 2.0), n: Vec3::Z };
    let n = 200_000;
    let mut per_light: Vec<Vec<f32>> = vec![Vec::new(); sampler.lights.len()];
    for k in 0..n {
        let u = (k as f32 + 0.5) / n as f32;
        let (i, _, remapped) = sampler.choose(&ctx, u).expect("a light");
        per_light[i as usize].push(remapped);
    }
    for (i, values) in per_light.iter().enumerate().filter(|(_, v)| v.len() >= 8) {
        // Evenly spread: the k-th value sits in the k-th of len equal cells.
        for (k, r) in values.iter().enumerate() {
            let cell = (r * values.len() as f32) as usize;
            assert!(cell.abs_diff(k) <= 1, "light {i}: value {k} = {r} out of its stratum");
        }
    }
}

#[test]
fn light_tree_favours_near_lights_that_face_the_point() {
    // Two equal quads at y = 1 facing down, at x = -5 and x = +5, and a third at x = +5 facing
    // up, away from the floor.
    let quad = |x: f32, down: bool| {
        let [a, b, c, d] =
            [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]].map(|[u, v]| Vec3::new(x + u, 1.0, v));
        let p = if down { [[a, b, c], [a, c, d]] } else { [[a, c, b], [a, d, c]] };
        p.map(|p| Light::Triangle(TriangleLight::new(p, Vec3::ONE, false).unwrap()))
    };
    let lights: Vec<Light> =
        [quad(-5.0, true), quad(5.0, true), quad(5.0, false)].into_iter().flatten().collect();
    assert!(lights[0..4].iter().all(|l| matches!(l, Light::Triangle(t) if t.normal.y < 0.0)));
    let sampler = LightSampler::with_choice(lights, &[0, 0, 1, 1, 2, 2], 8.0, LightChoice::Tree);
    // A point on the floor under the right-hand quads.
    let ctx = ShadingContext { p: Vec3::new(5.5, 0.0, 0.5), n: Vec3::Y };
    let near: f32 = (2..4).map(|i| sampler.pmf(&ctx, i)).sum();
    let far: f32 = (0..2).map(|i| sampler.pmf(&ctx, i)).sum();
    let away: f32 = (4..6).map(|i| sampler.pmf(&ctx, i)).sum();
    assert!(near > 0.9, "near {near}, far {far}, facing away {away}");
    assert_eq!(away, 0.0, "a light facing away cannot reach the point");
}

/// `Light::sample_le` for every kind of light: the light's flux estimated from its samples
/// (the mean of `LeSample::beta`) matches its power in closed form (`Light::power`: emission x
/// area x pi per face, 4 pi x intensity, the spot's cone weight, irradiance or 4 pi x radiance
/// over the disk of the scene's radius), within 5 standard errors of the estimate; every sample
/// reports the densities `pdf_le` gives for its direction, and a light at infinity starts outside
/// the scene on a ray through it.
#[test]
fn light_emission_samples_carry_the_lights_power() {
    let lum = |c: Vec3| c.dot(Vec3::new(0.2126, 0.7152, 0.0722)) as f64;
    let sphere = (Vec3::new(0.5, -1.0, 2.0), 3.0f32);
    let p = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.2, 0.1), Vec3::new(0.3, 1.0, -0.2)];
    let map = Environment::Map(MapEnvironment::new(&test_map(), 2.0, 33.0));
    let lights = [
        (
            "one-sided triangle",
            Light::Triangle(TriangleLight::new(p, Vec3::splat(2.0), false).unwrap()),
        ),
        (
            "two-sided triangle",
            Light::Triangle(TriangleLight::new(p, Vec3::splat(2.0), true).unwrap()),
        ),
        (
            "point",
            Light::Point(PointLight { position: Vec3::ONE, intensity: Vec3::new(1.0, 2.0, 3.0) }),
        ),
        ("spot", Light::Spot(SpotLight { intensity: Vec3::splat(10.0), ..spot(10.0, 30.0) })),
        (
            "directional",
            Light::Directional(DirectionalLight {
                to_light: Vec3::new(0.6, 0.8, 0.0),
                irradiance: Vec3::splat(0.7),
            }),
        ),
        (
            "uniform environment",
            Light::Environment(std::sync::Arc::new(Environment::Uniform(Vec3::splat(0.05)))),
        ),
        ("map environment", Light::Environment(std::sync::Arc::new(map))),
    ];
    let n = 200_000;
    for (name, light) in &lights {
        let mut rng = Rng::from_name(name);
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let u_main = Vec2::new(rng.next_f32(), rng.next_f32());
            let u_other = Vec2::new(rng.next_f32(), rng.next_f32());
            let Some(ls) = light.sample_le(u_main, u_other, sphere) else { continue };
            let pdf = light.pdf_le(ls.dir, sphere.1);
            let close = |a: f32, b: f32| (a - b).abs() <= 1e-3 * b.abs().max(1e-6);
            assert!(
                close(pdf.pos, ls.pdf_pos) && close(pdf.dir, ls.pdf_dir),
                "{name}: {ls:?} against {pdf:?}"
            );
            assert!((ls.dir.length() - 1.0).abs() < 1e-5, "{name}: direction {}", ls.dir);
            if light.is_infinite() {
                let to_centre = sphere.0 - ls.p;
                let along = to_centre.dot(ls.dir);
                let miss = (to_centre - along * ls.dir).length();
                assert!(
                    along >= sphere.1 * 0.999 && miss <= sphere.1 * 1.001,
                    "{name}: starts at {}",
                    ls.p
                );
            }
            let b = lum(ls.beta(light, 1.0));
            sum += b;
            sum2 += b * b;
        }
        let mean = sum / n as f64;
        let std_err = ((sum2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt();
        let power = light.power(sphere.1) as f64;
        // The spot's weight and the map's mean are quadratures, good to about 1e-3.
        let tolerance = 5.0 * std_err + 2e-3 * power;
        assert!(
            (mean - power).abs() <= tolerance,
            "{name}: flux {mean} against power {power} (tolerance {tolerance})"
        );
    }
}

/// The automatic choice counts emitters two ways: placements, and the pieces of a placement
/// that share no corner. Lamps merged into one mesh count one each (so many of them choose by
/// the tree), a lamp of many triangles counts once, and pieces give way where lights at
/// infinity carry more power than the rest.
#[test]
fn the_automatic_choice_counts_lamps_merged_into_one_mesh() {
    use super::super::light::TREE_MIN_EMITTERS;
    // Quad k at x = 2k, its two triangles sharing two corners, facing down.
    let quad = |k: usize| {
        let x = 2.0 * k as f32;
        let [a, b, c, d] =
            [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]].map(|[u, v]| Vec3::new(x + u, 1.0, v));
        [[a, b, c], [a, c, d]]
            .map(|p| Light::Triangle(TriangleLight::new(p, Vec3::ONE, false).unwrap()))
    };
    let quads = |n: usize| -> Vec<Light> { (0..n).flat_map(quad).collect() };
    let auto = |lights: Vec<Light>, emitters: &[u32]| {
        LightSampler::with_choice(lights, emitters, 8.0, LightChoice::Auto).uses_tree()
    };
    let n = TREE_MIN_EMITTERS;
    // In one placement: n - 1 lamps keep the mixture, n choose by the tree.
    assert!(!auto(quads(n - 1), &vec![0; 2 * (n - 1)]));
    assert!(auto(quads(n), &vec![0; 2 * n]));
    // Each lamp its own placement: the same.
    let own = |n: usize| (0..2 * n as u32).map(|i| i / 2).collect::<Vec<_>>();
    assert!(!auto(quads(n - 1), &own(n - 1)));
    assert!(auto(quads(n), &own(n)));
    // A fan of 4n triangles around one corner (a disc lamp): one piece.
    let fan: Vec<Light> = (0..4 * n)
        .map(|k| {
            let angle = |k: usize| k as f32 * std::f32::consts::TAU / (4 * n) as f32;
            let rim = |k: usize| Vec3::new(angle(k).cos(), 1.0, angle(k).sin());
            let p = [Vec3::Y, rim(k), rim(k + 1)];
            Light::Triangle(TriangleLight::new(p, Vec3::ONE, false).unwrap())
        })
        .collect();
    assert!(fan.iter().all(|l| matches!(l, Light::Triangle(t) if t.normal.y < 0.0)));
    assert!(!auto(fan, &vec![0; 4 * n]));
    // Under a sky that outshines them, merged lamps keep the mixture; placements still count.
    let sky = |mut lights: Vec<Light>, radiance: f32| {
        lights.push(Light::Environment(std::sync::Arc::new(Environment::Uniform(Vec3::splat(
            radiance,
        )))));
        lights
    };
    let merged = |n: usize| {
        let mut e = vec![0; 2 * n];
        e.push(1);
        e
    };
    let placed = |n: usize| {
        let mut e = own(n);
        e.push(n as u32);
        e
    };
    // The quads' power: n pi (unit area, radiance 1, one side); the sky's: 4 pi² r² L, r = 8.
    // A sky of half their power, then of twice it.
    let dim = 0.5 * n as f32 / (4.0 * std::f32::consts::PI * 64.0);
    assert!(auto(sky(quads(n), dim), &merged(n)));
    assert!(!auto(sky(quads(n), 4.0 * dim), &merged(n)));
    assert!(auto(sky(quads(n), 4.0 * dim), &placed(n)));
}

/// The automatic choice takes the tree where emitters that enclose a volume and face out carry
/// most of the finite power (half of such an emitter faces away from any point outside it), and
/// the mixture for the same box turned inside out (every face toward the points that see it),
/// emitting from both faces, textured, outshone by a flat panel, or under a brighter sky.
#[test]
fn the_automatic_choice_takes_the_tree_for_closed_emitters() {
    // A unit box of twelve triangles (two per face) at x0, wound so the normals point out.
    let cube = |x0: f32, inward: bool, two_sided: bool, textured: bool| -> Vec<Light> {
        let corner =
            |i: usize| Vec3::new(x0 + (i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32);
        // Faces -x, +x, -y, +y, -z, +z, each a loop of corners.
        let faces =
            [[0, 2, 6, 4], [1, 5, 7, 3], [0, 4, 5, 1], [2, 3, 7, 6], [0, 1, 3, 2], [4, 6, 7, 5]];
        faces
            .iter()
            .flat_map(|&[a, b, c, d]| [[a, b, c], [a, c, d]])
            .map(|t| {
                let mut p = t.map(corner);
                // Wound counter-clockwise seen from outside (or from inside, turned inward).
                let normal = (p[1] - p[0]).cross(p[2] - p[0]);
                let out = normal.dot(p[0] + p[1] + p[2] - 3.0 * Vec3::new(x0 + 0.5, 0.5, 0.5));
                if (out < 0.0) != inward {
                    p.swap(1, 2);
                }
                let mut l = TriangleLight::new(p, Vec3::ONE, two_sided).unwrap();
                l.textured = textured;
                Light::Triangle(l)
            })
            .collect()
    };
    let centre = Vec3::new(0.5, 0.5, 0.5);
    for l in cube(0.0, false, false, false) {
        let Light::Triangle(t) = l else { unreachable!() };
        let mid = (t.p[0] + t.p[1] + t.p[2]) / 3.0;
        assert!(t.normal.dot(mid - centre) > 0.0, "the box's normals point out");
    }
    let auto = |lights: Vec<Light>| {
        let emitters = vec![0; lights.len()];
        LightSampler::with_choice(lights, &emitters, 8.0, LightChoice::Auto).uses_tree()
    };
    assert!(auto(cube(0.0, false, false, false)));
    assert!(!auto(cube(0.0, true, false, false)), "turned inside out");
    assert!(!auto(cube(0.0, false, true, false)), "emitting from both faces");
    assert!(!auto(cube(0.0, false, false, true)), "textured");
    // The box without its top and bottom (a tube, open at both ends) still encloses; the box
    // without its +z face (vector area a fifth of its area) does too; one face alone does not.
    let without = |faces: &[usize]| -> Vec<Light> {
        cube(0.0, false, false, false)
            .into_iter()
            .enumerate()
            .filter(|(k, _)| !faces.contains(&(k / 2)))
            .map(|(_, l)| l)
            .collect()
    };
    assert!(auto(without(&[2, 3])));
    assert!(auto(without(&[5])));
    assert!(!auto(without(&[0, 1, 2, 3, 4])));
    // One face and the same face turned over, sharing its corners: no vector area, and no
    // volume to speak of either, so not closed (a flat lamp lit on both sides).
    let sheets: Vec<Light> = without(&[0, 1, 2, 3, 4])
        .into_iter()
        .flat_map(|l| {
            let Light::Triangle(t) = l else { unreachable!() };
            let turned = [t.p[0], t.p[2], t.p[1]];
            [l, Light::Triangle(TriangleLight::new(turned, Vec3::ONE, false).unwrap())]
        })
        .collect();
    assert!(!auto(sheets));
    // Beside a flat panel: the tree while the box carries at least half the finite power.
    let panel = |emission: f32| {
        let p = [Vec3::new(3.0, 2.0, 0.0), Vec3::new(3.0, 2.0, 1.0), Vec3::new(4.0, 2.0, 1.0)];
        Light::Triangle(TriangleLight::new(p, Vec3::splat(emission), false).unwrap())
    };
    // The box's power: 6 pi (area 6, radiance 1, one side); the panel's: 0.5 pi emission.
    let with_panel = |emission: f32| {
        let mut lights = cube(0.0, false, false, false);
        lights.push(panel(emission));
        lights
    };
    assert!(auto(with_panel(11.0)));
    assert!(!auto(with_panel(13.0)));
    // Under a sky of more power than the box, the mixture.
    let sky = |radiance: f32| {
        let mut lights = cube(0.0, false, false, false);
        lights.push(Light::Environment(std::sync::Arc::new(Environment::Uniform(Vec3::splat(
            radiance,
        )))));
        lights
    };
    // The sky's power: 4 pi² r² L with r = 8; half and twice the box's.
    let even = 6.0 / (4.0 * std::f32::consts::PI * 64.0);
    assert!(auto(sky(0.5 * even)));
    assert!(!auto(sky(2.0 * even)));
}
