//! A caustic with a closed form (`worker::test_scenes::MirrorCaustic`): a diffuse floor lit only
//! through a mirror by a small square light, whose radiance is albedo / pi x the light's
//! radiance x the projected solid angle of the light's mirror image. The path tracer, at
//! `max_depth` 2, agrees with it within its measured noise, and its relative error there is
//! printed (with the time it took) for the estimators that are to do better on such paths.
//! `CAUSTIC_FIGURES=1` adds the error at 2,048 samples per pixel for smaller lights.

mod support;

use common::{film::Film, settings::RenderSettings};
use glam::{Vec2, Vec3};
use support::*;
use worker::{
    render::{bsdf::MetalRough, scene::prepare},
    test_scenes::MirrorCaustic,
};

fn settings(res: u32, spp: u32) -> RenderSettings {
    RenderSettings { width: res, height: res, spp, max_depth: 2, seed: 7, ..Default::default() }
}

/// The film's relative root-mean-square error against `expected` over all pixels (channel 0:
/// the scene is grey).
fn relative_rmse(film: &Film, expected: &[[f32; 3]]) -> f64 {
    let sum: f64 = film
        .pixels
        .iter()
        .zip(expected)
        .map(|(p, e)| {
            let e = e[0] as f64;
            ((p.mean()[0] - e) / e).powi(2)
        })
        .sum();
    (sum / film.pixels.len() as f64).sqrt()
}

/// Renders `caustic` at `res` x `res` and `spp` with the path tracer; the film and the seconds
/// the render took.
fn render_timed(caustic: &MirrorCaustic, res: u32, spp: u32) -> (Film, f64) {
    let settings = settings(res, spp);
    let prepared = prepare(&load_caustic(caustic), &settings).unwrap();
    let start = std::time::Instant::now();
    let film = render_prepared(&prepared, &settings);
    (film, start.elapsed().as_secs_f64())
}

/// The material `MirrorCaustic` gives its mirror (metallic 1, roughness 0, base colour 1)
/// reflects all the light, around the mirror direction: its sampled weight f cos / pdf averages
/// 1 within 1e-5, and GGX's tails at alpha 1e-3 take the share they should away from the mirror
/// direction (4 alpha² / theta² beyond theta radians: 0.16% beyond 0.05, 1e-4 beyond 0.2).
#[test]
fn caustic_mirror_reflects_all_the_light() {
    let mirror = MetalRough::new(Vec3::ONE, 1.0, 0.0, 1.5, 1.0, Vec3::ONE);
    let n = 400;
    for degrees in [5.0f32, 30.0, 60.0] {
        let theta = degrees.to_radians();
        let wo = Vec3::new(theta.sin(), 0.0, theta.cos());
        let reflected = Vec3::new(-wo.x, 0.0, wo.z);
        let (mut sum, mut beyond_005, mut beyond_02) = (0.0f64, 0usize, 0usize);
        for i in 0..n {
            for j in 0..n {
                let u = Vec2::new((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                let s = mirror.sample(wo, 0.5, u).expect("a mirror sample");
                sum += (s.f.x * s.wi.z / s.pdf) as f64;
                let angle = s.wi.dot(reflected).min(1.0).acos();
                beyond_005 += (angle > 0.05) as usize;
                beyond_02 += (angle > 0.2) as usize;
            }
        }
        let total = (n * n) as f64;
        let mean = sum / total;
        let (share_005, share_02) = (beyond_005 as f64 / total, beyond_02 as f64 / total);
        assert!((mean - 1.0).abs() < 1e-5, "{degrees} degrees: reflects {mean}");
        assert!(share_005 < 3e-3 && share_02 < 3e-4, "{degrees} degrees: {share_005}, {share_02}");
    }
}

/// The pixels' squared errors against `expected` over the variance of the mean their even and
/// odd halves estimate, summed over the image (channel 0: the scene is grey): 1 in expectation
/// whatever the sampler (the per-sample variance overstates the error of the stratified samples
/// the renderer draws).
fn error_over_half_differences(film: &Film, expected: &[[f32; 3]]) -> f64 {
    let (mut error, mut variance) = (0.0, 0.0);
    for (p, e) in film.pixels.iter().zip(expected) {
        error += (p.mean()[0] - e[0] as f64).powi(2);
        variance += p.half_difference_variance().expect("both halves")[0];
    }
    error / variance
}

/// The path tracer at `max_depth` 2 against the closed form over the whole image (the floor
/// where it sees the whole mirrored light): the image mean within 4 standard errors and every
/// 8 x 8 block within the Sidak bound (the per-sample variance, an upper bound for stratified
/// samples), and the pixels' squared errors summing to what the films' half differences
/// predict; and the same film rejects the closed form scaled by 0.98 or 1.02 (a light or a
/// mirror 2% off) by the image mean (per pixel such an error is within the noise at this
/// sample count).
#[test]
fn path_tracer_matches_the_mirror_caustic() {
    let caustic = MirrorCaustic { light_half_side: 0.5, radiance: 30.0 };
    let (res, spp) = (64, 512);
    let (film, seconds) = render_timed(&caustic, res, spp);
    assert_eq!(film.rejected, 0, "non-finite samples");
    let expected = caustic_expected(&caustic, res);
    let cmp = compare(&film, &expected, 0.0, 8);
    let z_block = sidak_z(0.01, cmp.blocks);
    let ratio = error_over_half_differences(&film, &expected);
    let scaled = |factor: f32| {
        let e: Vec<[f32; 3]> = expected.iter().map(|p| p.map(|v| v * factor)).collect();
        (compare(&film, &e, 0.0, 8).z_image, error_over_half_differences(&film, &e))
    };
    let (low, high) = (scaled(0.98), scaled(1.02));
    println!(
        "mirror caustic, light half side {}, {res}x{res} at {spp} spp, max_depth 2: path tracer \
         relative RMSE {:.2}% in {seconds:.2} s; image z {:.2}, worst 8x8 block |z| {:.2} \
         (bound {z_block:.2}), squared error / half differences {ratio:.3}; against the closed \
         form x 0.98: z {:.1}, ratio {:.2}; x 1.02: z {:.1}, ratio {:.2}",
        caustic.light_half_side,
        100.0 * relative_rmse(&film, &expected),
        cmp.z_image,
        cmp.z_block_max,
        low.0,
        low.1,
        high.0,
        high.1,
    );
    assert!(cmp.z_image.abs() < 4.0, "image mean off by {:.2} sigma", cmp.z_image);
    assert!(cmp.z_block_max < z_block, "a block is off by {:.2} sigma", cmp.z_block_max);
    // A ratio of two sums of 4,096 one-degree squares: standard deviation about 0.03.
    assert!((ratio - 1.0).abs() < 0.15, "squared error / half differences {ratio}");
    assert!(low.0 > 4.0 && high.0 < -4.0, "a 2% error would pass: z {} and {}", low.0, high.0);
}

/// With `CAUSTIC_FIGURES=1`: the path tracer's relative error in the caustic at 2,048 samples
/// per pixel (64 x 64) for lights of half side 0.5, 0.25 and 0.125, and the time each took.
#[test]
fn path_tracer_caustic_figures() {
    if std::env::var_os("CAUSTIC_FIGURES").is_none() {
        return;
    }
    for light_half_side in [0.5, 0.25, 0.125] {
        // The light's power falls with its area: keep the floor near 1.
        let radiance = 7.5 / (light_half_side * light_half_side);
        let caustic = MirrorCaustic { light_half_side, radiance };
        let (res, spp) = (64, 2048);
        let (film, seconds) = render_timed(&caustic, res, spp);
        let expected = caustic_expected(&caustic, res);
        println!(
            "light half side {light_half_side}: {res}x{res} at {spp} spp, path tracer relative \
             RMSE {:.2}% in {seconds:.2} s (2 threads), image z {:.2}, squared error / half \
             differences {:.3}",
            100.0 * relative_rmse(&film, &expected),
            compare(&film, &expected, 0.0, 8).z_image,
            error_over_half_differences(&film, &expected),
        );
    }
}
