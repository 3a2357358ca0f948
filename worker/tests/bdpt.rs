//! Bidirectional path tracing (`"integrator": "bdpt"`) converges to what the path tracer and the
//! closed forms give: the Cornell box against the path tracer through a pinhole and a thin lens,
//! glossy plates (`veach-mis`) against the path tracer,
//! the mirror caustic against its closed form, the closed furnace against 1.

mod support;

use common::{film::Film, settings::RenderSettings};
use support::*;
use worker::render::scene::prepare_frame;

/// The camera tasks' film and the light task's film of frame 0 (the image is their sum).
fn render_bdpt(scene: &common::scene::Scene, settings: &RenderSettings) -> (Film, Film) {
    render_bdpt_with(scene, settings, None)
}

/// The Cornell box at `max_depth` 5: the sum of the camera tasks' and the light task's films
/// agrees with the path tracer per channel within 4 standard errors of the image mean (both
/// films' variances); light tracing carries a fair share of the image (so that the test would
/// see a wrong splat).
#[test]
fn bdpt_cornell_box_matches_the_path_tracer() {
    let scene = load("cornell-box.gltf");
    let base =
        RenderSettings { width: 32, height: 32, spp: 64, max_depth: 5, ..settings("cornell-box") };
    let t = std::time::Instant::now();
    let (camera, light) = render_bdpt(&scene, &base);
    let tb = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let path = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let tp = t.elapsed().as_secs_f64();
    let ours = bdpt_sum(&camera, &light);
    let (mut d, mut v) = ([0.0f64; 3], [0.0f64; 3]);
    let (mut lsum, mut csum) = (0.0, 0.0);
    for (o, p) in ours.iter().zip(&path.pixels) {
        let (pm, pv) = (p.mean(), p.variance_of_mean());
        for c in 0..3 {
            d[c] += o.0[c] - pm[c];
            v[c] += o.1[c] + pv[c];
        }
    }
    for (c, l) in camera.pixels.iter().zip(&light.pixels) {
        csum += c.mean()[0];
        lsum += l.mean()[0];
    }
    let z = [0, 1, 2].map(|c| d[c] / v[c].sqrt());
    let n = ours.len() as f64;
    println!(
        "cornell box 32x32, max_depth 5: bdpt 64 spp in {tb:.2} s, path tracer 256 spp in \
         {tp:.2} s; z per channel {z:.2?}; mean difference {:?}; of the red mean, camera \
         tasks {:.4} and light tracing {:.4}",
        d.map(|x| (x / n) as f32),
        csum / n,
        lsum / n
    );
    assert!(z.iter().all(|z| z.abs() < 4.0), "{z:?}");
    assert!(lsum > 0.1 * (lsum + csum), "light tracing carries {lsum} of {}", lsum + csum);
}

/// Relative MSE of per-pixel means against `expected` (channel 0: a grey scene).
fn rel_mse(means: impl Iterator<Item = f64>, expected: &[[f32; 3]]) -> f64 {
    let (mut sum, mut n) = (0.0, 0);
    for (m, e) in means.zip(expected) {
        let e = e[0] as f64;
        sum += ((m - e) / e).powi(2);
        n += 1;
    }
    sum / n as f64
}

/// The mirror caustic at `max_depth` 2 (the floor lit only by a small light through a mirror,
/// `worker::test_scenes::MirrorCaustic`): the image mean within 4 standard errors of the closed
/// form. Light tracing (t = 1) is the strategy that finds these paths well; the printed figures
/// compare its error and time with the path tracer's (the benchmark's business, not asserted).
#[test]
fn bdpt_mirror_caustic_matches_the_closed_form() {
    let res = 32;
    let (scene, expected, base) = bench_caustic(res, 64);
    let t = std::time::Instant::now();
    let (camera, light) = render_bdpt(&scene, &base);
    let tb = t.elapsed().as_secs_f64();
    let ours = bdpt_sum(&camera, &light);
    let (mut d, mut v) = (0.0, 0.0);
    for (o, e) in ours.iter().zip(&expected) {
        d += o.0[0] - e[0] as f64;
        v += o.1[0];
    }
    let z = d / v.sqrt();
    let rb = rel_mse(ours.iter().map(|o| o.0[0]), &expected);
    let t = std::time::Instant::now();
    let path = render(&scene, &RenderSettings { spp: 256, ..base.clone() });
    let tp = t.elapsed().as_secs_f64();
    let rp = rel_mse(path.pixels.iter().map(|p| p.mean()[0]), &expected);
    println!(
        "mirror caustic (light half side 0.125), {res}x{res}, max_depth 2: bdpt 64 spp in \
         {tb:.2} s, relative MSE {rb:.3e}, image z {z:.2}; path tracer 256 spp in {tp:.2} s, \
         relative MSE {rp:.3e}; path relMSE x seconds over bdpt's: {:.1}",
        rp * tp / (rb * tb)
    );
    assert!(z.abs() < 4.0, "{z}");
}

/// More light-traced paths per pixel sample (`bdpt.light_paths` 4): the Cornell box still agrees
/// with the path tracer per channel within 4 standard errors of the image mean (the counts enter
/// every MIS weight, so the weights still sum to one: counted on one side only, the image would
/// be off where light tracing and the other strategies share the light). On the mirror caustic, whose light only light tracing finds well,
/// 8 paths per pixel sample lower the relative MSE at equal samples at least 4 times (8 times if
/// light tracing carried it all), the image within 4 standard errors of the closed form.
#[test]
fn bdpt_with_more_light_paths_matches_the_path_tracer_and_the_closed_form() {
    use common::settings::Bdpt;
    let scene = load("cornell-box.gltf");
    let base =
        RenderSettings { width: 32, height: 32, spp: 32, max_depth: 5, ..settings("cornell-box") };
    let four = RenderSettings { bdpt: Some(Bdpt { light_paths: 4 }), ..base.clone() };
    let (camera, light) = render_bdpt(&scene, &four);
    let path = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let ours = bdpt_sum(&camera, &light);
    let (mut d, mut v) = ([0.0f64; 3], [0.0f64; 3]);
    for (o, p) in ours.iter().zip(&path.pixels) {
        let (pm, pv) = (p.mean(), p.variance_of_mean());
        for c in 0..3 {
            d[c] += o.0[c] - pm[c];
            v[c] += o.1[c] + pv[c];
        }
    }
    let z = [0, 1, 2].map(|c| d[c] / v[c].sqrt());
    let lsum: f64 = light.pixels.iter().map(|p| p.mean()[0]).sum();
    let total: f64 = ours.iter().map(|o| o.0[0]).sum();
    println!(
        "cornell box 32x32, max_depth 5, 4 light paths per sample: z per channel {z:.2?}; light \
         tracing carries {:.3} of the red mean",
        lsum / total
    );
    assert!(z.iter().all(|z| z.abs() < 4.0), "{z:?}");

    let res = 32;
    let (scene, expected, base) = bench_caustic(res, 16);
    let error = |light_paths: u32| {
        let settings = RenderSettings { bdpt: Some(Bdpt { light_paths }), ..base.clone() };
        let (camera, light) = render_bdpt(&scene, &settings);
        let ours = bdpt_sum(&camera, &light);
        let (mut d, mut v) = (0.0, 0.0);
        for (o, e) in ours.iter().zip(&expected) {
            d += o.0[0] - e[0] as f64;
            v += o.1[0];
        }
        (rel_mse(ours.iter().map(|o| o.0[0]), &expected), d / v.sqrt())
    };
    let ((one, _), (eight, z)) = (error(1), error(8));
    println!(
        "mirror caustic {res}x{res}, 16 spp: relative MSE {one:.3e} with 1 light path per \
         sample, {eight:.3e} with 8 ({:.1} times lower), image z {z:.2}",
        one / eight
    );
    assert!(one > 4.0 * eight, "{one} against {eight}");
    assert!(z.abs() < 4.0, "{z}");
}

/// Light tracing pools every pixel's light subpaths, which start from one frame-wide
/// low-discrepancy sequence (`light_film`). Under a light much smaller than a pixel's footprint
/// on the floor (the mirror caustic with a light of half side 0.002, an eighth of a pixel of
/// 32x32), where a light path lands depends on its direction alone, the sequence's first and
/// best stratified pair, so the image's relative MSE falls much faster than one over the light
/// paths: at least 25 times for 16 times the samples (8 light paths per pixel sample, 4 and 64
/// samples; 33.6-44.4 over five seeds). Light subpaths from each pixel sample's own numbers,
/// independent from pixel to pixel, fall as independent paths do, 15.4-16.9 times over the same
/// seeds, their error at 64 samples 3.7-3.9 times higher. The even and odd sample indices' light
/// subpaths start from two independent sequences, so the image's squared errors sum to what the
/// halves' differences predict (within 0.8-1.2 times at 64 samples: 0.97-1.07 over the seeds;
/// one sequence for both halves, which gives the two halves the same light subpaths, 1.29-1.44).
#[test]
fn light_tracing_error_falls_faster_than_one_over_the_paths() {
    use common::settings::Bdpt;
    let (half, res) = (0.002, 32);
    let (scene, expected, base) = caustic_with_light(half, res, 1);
    let error = |spp: u32| {
        let settings = RenderSettings { spp, bdpt: Some(Bdpt { light_paths: 8 }), ..base.clone() };
        let (camera, light) = render_bdpt(&scene, &settings);
        let ours = bdpt_sum(&camera, &light);
        // The squared errors over the variance the halves' differences give (`Film`'s estimate).
        let (mut squared, mut predicted) = (0.0, 0.0);
        for ((c, l), e) in camera.pixels.iter().zip(&light.pixels).zip(&expected) {
            let sum = c.plus_independent(l);
            squared += (sum.mean()[0] - e[0] as f64).powi(2);
            predicted += sum.half_difference_variance().expect("both halves")[0];
        }
        (rel_mse(ours.iter().map(|o| o.0[0]), &expected), squared / predicted)
    };
    let ((few, _), (many, calibration)) = (error(4), error(64));
    println!(
        "mirror caustic, light half side {half}, {res}x{res}, 8 light paths per sample: relative \
         MSE {few:.3e} at 4 spp, {many:.3e} at 64 ({:.1} times lower); squared error over the \
         halves' prediction at 64 spp {calibration:.2}",
        few / many
    );
    assert!(few > 25.0 * many, "{few} against {many}: {:.2} times", few / many);
    assert!((0.8..1.2).contains(&calibration), "squared error / half differences {calibration}");
}

/// A glossy scene (`scenes/veach-mis`: four metal plates of GGX alpha 0.005 to
/// 0.1 lit by four lights of different sizes), where every strategy is in play (light samples
/// and BSDF hits on the plates, light tracing of their reflections): the means of the image's
/// four quadrants per channel within 4 standard errors of the path tracer's (the lights seen
/// straight on left out). Blocks of 8x8 are no fair test here: the sharpest plate's connections
/// leave heavy tails, and a block's estimated variance misses them at 64 spp (worst blocks of
/// 0.5 to 1.1 of the Sidak bound over seeds, on either side). The same scene with the plates made
/// rough (roughness 0.7) is told apart.
#[test]
fn bdpt_glossy_plates_match_the_path_tracer() {
    let path = scenes().join("veach-mis.gltf");
    let scene = common::gltf::load_path(&path).unwrap();
    let base =
        RenderSettings { width: 48, height: 32, spp: 64, max_depth: 5, ..Default::default() };
    let (camera, light) = render_bdpt(&scene, &base);
    let ours = bdpt_sum(&camera, &light);
    let reference =
        pixel_stats(&render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() }));
    let worst = worst_quadrant(&ours, &reference, base.width, base.height);
    println!("veach-mis-s 48x32: worst quadrant |z| {worst:.2}");
    assert!(worst < 4.0, "{worst}");
    let mut rough = scene.clone();
    for m in &mut rough.materials {
        if m.metallic > 0.5 {
            m.roughness = m.roughness.max(0.7);
        }
    }
    let rough = pixel_stats(&render(&rough, &RenderSettings { spp: 256, seed: 3, ..base.clone() }));
    let worst = worst_quadrant(&ours, &rough, base.width, base.height);
    println!("  against rough plates: worst quadrant |z| {worst:.2}");
    assert!(worst > 4.0, "rough plates pass: {worst}");
}

/// The largest |z| over the image's four quadrants and three channels of the difference of the
/// two images' means there, over the pixels where both are below 2 (lights seen straight on,
/// whose edges' noise would hide the rest, are left out).
fn worst_quadrant(
    ours: &[([f64; 3], [f64; 3])],
    reference: &[([f64; 3], [f64; 3])],
    width: u32,
    height: u32,
) -> f64 {
    let mut worst = 0.0f64;
    for q in 0..4u32 {
        let (mut d, mut v, mut n) = ([0.0f64; 3], [0.0f64; 3], 0.0);
        for (i, (o, r)) in ours.iter().zip(reference).enumerate() {
            let (x, y) = (i as u32 % width, i as u32 / width);
            let quadrant = (x >= width / 2) as u32 + 2 * (y >= height / 2) as u32;
            if quadrant != q || o.0.iter().chain(&r.0).any(|&m| m >= 2.0) {
                continue;
            }
            n += 1.0;
            for c in 0..3 {
                d[c] += o.0[c] - r.0[c];
                v[c] += o.1[c] + r.1[c];
            }
        }
        assert!(n > 0.0);
        for c in 0..3 {
            worst = worst.max((d[c] / v[c].sqrt()).abs());
        }
    }
    worst
}

/// A light inside an absorbing volume (`cornell_light_in_water`): light subpaths start in the
/// medium the light lies in, lose light to it and leave it at its boundary. Every 16 x 16 block
/// within the noise of the path tracer's image (with the light taken to be in air, the light
/// traced share of the room is too bright and the test fails).
#[test]
fn bdpt_light_inside_an_absorbing_volume_matches_the_path_tracer() {
    let scene = cornell_light_in_water();
    let base =
        RenderSettings { width: 32, height: 32, spp: 128, max_depth: 8, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 1024, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&bdpt_sum(&camera, &light), &pixel_stats(&path), 32, 16, 0.0);
    println!("light in water: worst block {score:.2} ({at})");
    assert!(score < 1.0, "light in water: {at}");
}

/// Image means per channel of the two films' sum, with their standard errors.
fn mean_and_se(camera: &Film, light: &Film) -> [(f64, f64); 3] {
    let ours = bdpt_sum(camera, light);
    let n = ours.len() as f64;
    [0, 1, 2].map(|c| {
        let mean = ours.iter().map(|o| o.0[c]).sum::<f64>() / n;
        let var = ours.iter().map(|o| o.1[c]).sum::<f64>() / (n * n);
        (mean, var.sqrt())
    })
}

/// The closed furnace (every surface emits what it does not reflect, so that radiance is 1
/// everywhere), its long paths included: the image mean within 4 standard errors of 1.
#[test]
fn bdpt_closed_furnace_is_one() {
    let scene = load("furnace-closed.gltf");
    let settings = RenderSettings { width: 16, height: 16, spp: 16, ..settings("furnace-closed") };
    let (camera, light) = render_bdpt(&scene, &settings);
    for (c, (mean, se)) in mean_and_se(&camera, &light).into_iter().enumerate() {
        println!("closed furnace, bdpt, channel {c}: {mean:.5} (standard error {se:.1e})");
        assert!((mean - 1.0).abs() < 4.0 * se + 1e-4, "channel {c}: {mean} ({se})");
    }
}

/// Depth of field: the Cornell box through the thin lens of `scenes/cornell-dof.settings.json`
/// agrees with the path tracer's image (light tracing connects to points on the lens).
#[test]
fn bdpt_thin_lens_matches_the_path_tracer() {
    let scene = load("cornell-box.gltf");
    let dof = cornell_dof_settings();
    let base = RenderSettings { width: 32, height: 32, spp: 64, max_depth: 5, ..dof };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let ours = mean_and_se(&camera, &light);
    let n = path.pixels.len() as f64;
    for c in 0..3 {
        let pm = path.pixels.iter().map(|p| p.mean()[c]).sum::<f64>() / n;
        let pv = path.pixels.iter().map(|p| p.variance_of_mean()[c]).sum::<f64>() / (n * n);
        let z = (ours[c].0 - pm) / (ours[c].1 * ours[c].1 + pv).sqrt();
        println!("thin lens, channel {c}: bdpt {:.5}, path {pm:.5}, z {z:.2}", ours[c].0);
        assert!(z.abs() < 4.0, "channel {c}: z {z}");
    }
    let light_share = light.pixels.iter().map(|p| p.mean()[0]).sum::<f64>() / n / ours[0].0;
    assert!(light_share > 0.05, "light tracing carries {light_share} of the image");
}

/// Motion blur: the Cornell box whose blocks move within the shutter, seen from a still camera
/// and from one that slides too. Every 8 x 8 block of the two films' sum agrees with the path
/// tracer's within the noise (a Sidak bound over the blocks, no allowance for bias), and the
/// path tracer's image of the shutter's first instant (the scene frozen) is told apart from it.
#[test]
fn bdpt_motion_blur_matches_the_path_tracer() {
    for moving_camera in [false, true] {
        let (scene, motion) = cornell_motion(moving_camera);
        let base = RenderSettings { width: 32, height: 32, spp: 64, max_depth: 5, ..motion };
        let (camera, light) = render_bdpt(&scene, &base);
        let ours: Vec<_> = bdpt_sum(&camera, &light);
        let path = render_frame0(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
        let (score, at) = worst_block(&ours, &pixel_stats(&path), base.width, 8, 0.0);
        println!("motion blur, moving camera {moving_camera}: worst block {score:.2} ({at})");
        assert!(score < 1.0, "moving camera {moving_camera}: {at}");
        let frozen = RenderSettings {
            spp: 256,
            seed: 3,
            shutter: common::settings::Shutter { open: 0.0, close: 0.0 },
            ..base.clone()
        };
        let frozen = render_frame0(&scene, &frozen);
        let (score, at) = worst_block(&ours, &pixel_stats(&frozen), base.width, 8, 0.0);
        println!("  against the frozen scene: worst block {score:.2} ({at})");
        assert!(score > 1.0, "moving camera {moving_camera}: the frozen image passes ({at})");
    }
    // The light slides too: no light subpath or light sample starts on an emitter that moves,
    // so the camera subpath's hits count it in full, as the path tracer's do (it is the only
    // light: the image is not black).
    let (scene, motion) = cornell_motion(false);
    let scene = with_moving_light(&scene);
    let base = RenderSettings { width: 32, height: 32, spp: 64, max_depth: 5, ..motion };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render_frame0(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    // Blocks of 16 x 16: a light found only by the camera subpaths leaves heavy tails.
    let (score, at) =
        worst_block(&bdpt_sum(&camera, &light), &pixel_stats(&path), base.width, 16, 0.0);
    println!("motion blur, the light moving: worst block {score:.2} ({at})");
    assert!(score < 1.0, "the light moving: {at}");
    assert!(camera.mean_rgb().iter().flatten().any(|&v| v > 0.0), "the light moving: black");
}

/// Many lights (64 small emitters over a floor, `worker::test_scenes::many_lights_gltf`): light
/// samples choose by the light tree from the shaded point and light subpaths leave by the
/// point-blind mixture, the MIS weights carrying the quotient of the two; the image agrees with
/// the path tracer's, every 8 x 8 block within the noise (no allowance for bias).
#[test]
fn bdpt_with_the_light_tree_matches_the_path_tracer() {
    let scene = load_many_lights(64, "bdpt");
    let base =
        RenderSettings { width: 32, height: 32, spp: 64, max_depth: 4, ..Default::default() };
    let bdpt = RenderSettings { integrator: common::settings::Integrator::Bdpt, ..base.clone() };
    let prepared = prepare_frame(&scene, &bdpt, None, 0).unwrap();
    assert!(prepared.lights.uses_tree() && prepared.emission.is_some());
    let (camera, light) = render_bdpt(&scene, &base);
    let reference = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let ours = bdpt_sum(&camera, &light);
    let (score, at) = worst_block(&ours, &pixel_stats(&reference), base.width, 8, 0.0);
    let (mean, theirs) = (mean_and_se(&camera, &light), image_mean(&reference));
    println!("64 lights: worst block {score:.2} ({at}); red mean bdpt {mean:?} path {theirs:?}");
    assert!(score < 1.0, "{at}");
}

/// Lights at infinity. The furnace (a convex sphere of albedo 0.8 in a uniform environment of
/// radiance 1): every 4 x 4 block within the noise of its exact image, light tracing (light
/// subpaths entering through the disk across the scene) carrying a share of it. The Cornell box
/// lit through its open front by a sun (a directional light) and an environment map besides its
/// ceiling light: every 8 x 8 block within the noise of the path tracer's image.
#[test]
fn bdpt_lights_at_infinity_match_the_closed_form_and_the_path_tracer() {
    let scene = load("furnace.gltf");
    let furnace = RenderSettings { width: 32, height: 32, spp: 32, ..settings("furnace") };
    let (camera, light) = render_bdpt(&scene, &furnace);
    let exact: Vec<_> =
        furnace_expected(32).iter().map(|e| (e.map(|v| v as f64), [0.0; 3])).collect();
    let (score, at) = worst_block(&bdpt_sum(&camera, &light), &exact, 32, 4, 0.0);
    let n = light.pixels.len() as f64;
    let light_share = light.pixels.iter().map(|p| p.mean()[0]).sum::<f64>()
        / n
        / mean_and_se(&camera, &light)[0].0;
    println!("furnace: worst block {score:.2} ({at}); light tracing carries {light_share:.3}");
    assert!(score < 1.0, "furnace: {at}");
    assert!(light_share > 0.02, "light tracing carries {light_share}");

    let (scene, outdoors, map) = cornell_sun_and_sky();
    let base = RenderSettings { spp: 64, ..outdoors };
    let (camera, light) = render_bdpt_with(&scene, &base, Some(&map));
    let settings = RenderSettings { spp: 256, seed: 3, ..base.clone() };
    let prepared =
        worker::render::scene::prepare_with_environment(&scene, &settings, Some(&map)).unwrap();
    let path = render_prepared(&prepared, &settings);
    let (score, at) = worst_block(&bdpt_sum(&camera, &light), &pixel_stats(&path), 32, 8, 0.0);
    let (ours, theirs) = (mean_and_se(&camera, &light), image_mean(&path));
    println!("sun and sky: worst block {score:.2} ({at}); means {ours:?} vs {theirs:?}");
    assert!(score < 1.0, "sun and sky: {at}");
}

/// Refractive volumes. A clear glass box in the white furnace (a smooth boundary neither makes
/// nor loses light, and the 1 / eta² of radiance entering the glass comes back leaving it): every
/// pixel within 1e-5 of 1, as the path tracer's (only camera subpaths find these paths: every
/// vertex is on a smooth boundary). The Cornell box's tinted glass sphere (`scenes/cornell-glass`:
/// refraction, total internal reflection, absorption, and a caustic on the floor that light
/// tracing finds, whose flux, unlike radiance, is not scaled by 1 / eta² entering the glass):
/// every 8 x 8 block within the noise of the path tracer's image.
#[test]
fn bdpt_glass_matches_the_furnace_and_the_path_tracer() {
    let path = furnace_box("bdpt-furnace", dielectric_material(1.5, 1.0, None));
    // Seen through a perspective camera (2 atan(1 / 3): the box's view), as light tracing needs.
    with_perspective_camera(&path, 2.0 * (1.0f64 / 3.0).atan());
    let scene = common::gltf::load_path(&path).unwrap();
    let furnace = RenderSettings { max_depth: 64, ..white_furnace(16, 64) };
    let (camera, light) = render_bdpt(&scene, &furnace);
    let worst = bdpt_sum(&camera, &light)
        .iter()
        .flat_map(|p| p.0)
        .map(|v| (v - 1.0).abs())
        .fold(0.0, f64::max);
    println!("glass furnace: worst pixel {worst:.1e} from 1");
    assert!(worst < 1e-5, "a pixel is {worst} away from 1");

    let scene = repo_scene("cornell-glass.gltf");
    let base =
        RenderSettings { width: 32, height: 32, spp: 64, max_depth: 8, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&bdpt_sum(&camera, &light), &pixel_stats(&path), 32, 8, 0.0);
    let (ours, theirs) = (mean_and_se(&camera, &light), image_mean(&path));
    println!("cornell glass: worst block {score:.2} ({at}); means {ours:?} vs {theirs:?}");
    assert!(score < 1.0, "cornell glass: {at}");
}

/// Dispersion (`KHR_materials_dispersion`): a sample's two subpaths bend light by one
/// wavelength, and a path through a dispersive vertex on either takes that light's colour once.
/// A dispersive glass box in the white furnace stays white (each channel's mean within 4
/// standard errors of 1); the Cornell box's sphere made dispersive (`cornell_dispersive_glass`),
/// whose caustic light tracing carries: each channel's every 8 x 8 block within the noise of the
/// path tracer's image.
#[test]
fn bdpt_dispersive_glass_matches_the_furnace_and_the_path_tracer() {
    let mut material = dielectric_material(1.5, 1.0, None);
    material["extensions"]["KHR_materials_dispersion"] = serde_json::json!({"dispersion": 2.0});
    let path = furnace_box("bdpt-dispersive-furnace", material);
    with_perspective_camera(&path, 2.0 * (1.0f64 / 3.0).atan());
    let scene = common::gltf::load_path(&path).unwrap();
    let furnace = RenderSettings { max_depth: 64, ..white_furnace(16, 256) };
    let (camera, light) = render_bdpt(&scene, &furnace);
    let means = mean_and_se(&camera, &light);
    println!("dispersive furnace: {means:?}");
    for (c, (mean, se)) in means.into_iter().enumerate() {
        assert!((mean - 1.0).abs() < 4.0 * se + 1e-5, "channel {c}: {mean} ({se})");
    }

    let scene = cornell_dispersive_glass();
    let base =
        RenderSettings { width: 32, height: 32, spp: 64, max_depth: 8, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 256, seed: 3, ..base.clone() });
    let ours = bdpt_sum(&camera, &light);
    let (score, at) = worst_channel_block(&ours, &pixel_stats(&path), 32, 8, 0.0);
    let (mine, theirs) = (mean_and_se(&camera, &light), image_mean(&path));
    println!(
        "dispersive cornell glass: worst block {score:.2} ({at}); means {mine:?} vs {theirs:?}"
    );
    assert!(score < 1.0, "dispersive cornell glass: {at}");
}

/// Dispersion seen through glass: a dispersive slab tilted over an emitting half-plane, seen from
/// above by an orthographic camera (camera subpaths alone: light tracing cannot reach it), moves
/// the edge by each channel's colour-weighted Snell offset, as in the path tracer's test
/// (`tests/glass.rs`).
#[test]
fn bdpt_splits_an_edge_seen_through_dispersive_glass_by_colour() {
    let (path, settings) = dispersive_slab_edge("bdpt-dispersive-snell", 128);
    let scene = common::gltf::load_path(&path).unwrap();
    let (camera, light) = render_bdpt(&scene, &settings);
    assert_edge_split_by_colour(&bdpt_sum(&camera, &light), 128);
}

/// The prism's rainbow (`worker::test_scenes::PrismRainbow`): sunlight through a dispersive
/// glass prism onto a white floor, which only light tracing finds (the light is a direction and
/// the prism's faces are smooth), each wavelength bent by its own index and each in its colour.
/// Every column's mean over the rows, per channel, within the noise of the closed form (Sidak
/// bound at 1% over the 96 of them, plus 0.2% of the brightest).
#[test]
fn bdpt_prism_rainbow_matches_the_closed_form() {
    let scene = common::gltf::load_path(&prism::scene("bdpt")).unwrap();
    let width = 32;
    let settings = RenderSettings {
        width,
        height: width,
        spp: 256,
        max_depth: 3,
        bdpt: Some(common::settings::Bdpt { light_paths: 4 }),
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let (camera, light) = render_bdpt(&scene, &settings);
    println!("rendered in {:.2} s", t.elapsed().as_secs_f64());
    prism::assert_matches_closed_form(
        &prism::columns(&bdpt_sum(&camera, &light), width),
        width,
        0.002,
    );
}

/// Scattering media: subpaths draw free flights by the sample's hero channel, and connections
/// weigh their light by the channels' densities of the whole path. Media of albedo 1 in the white
/// furnace stay white (`scattering_furnaces`: a per-channel extinction, a diffusely transmitting
/// boundary, glass over a white floor; each channel's mean within four standard errors of 1),
/// and the Cornell box's floor and block in a fog of different extinctions per channel
/// (`cornell_in_fog`), met by connections through it, agree with the path tracer in every
/// channel's 16 x 16 blocks.
#[test]
fn bdpt_scattering_media_stay_white_in_the_furnace_and_match_the_path_tracer() {
    for (what, path) in scattering_furnaces("bdpt-scatter") {
        with_perspective_camera(&path, 2.0 * (1.0f64 / 3.0).atan());
        let scene = common::gltf::load_path(&path).unwrap();
        let furnace = RenderSettings { max_depth: 1024, ..white_furnace(16, 256) };
        let (camera, light) = render_bdpt(&scene, &furnace);
        assert_white(what, mean_and_se(&camera, &light), 0.0);
    }

    assert_fog_matches_the_path_tracer("fog", &cornell_in_fog());
}

/// A Cornell box in a fog at 32 x 32 (`max_depth` 8): BDPT's 256 samples against the path
/// tracer's 1,024, every channel's 16 x 16 blocks within the noise.
fn assert_fog_matches_the_path_tracer(what: &str, scene: &common::scene::Scene) {
    let base =
        RenderSettings { width: 32, height: 32, spp: 256, max_depth: 8, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(scene, &base);
    let path = render(scene, &RenderSettings { spp: 1024, seed: 3, ..base.clone() });
    let ours = bdpt_sum(&camera, &light);
    let (score, at) = worst_channel_block(&ours, &pixel_stats(&path), 32, 16, 0.0);
    let (mine, theirs) = (mean_and_se(&camera, &light), image_mean(&path));
    println!("{what}: worst block {score:.2} ({at}); means {mine:?} vs {theirs:?}");
    assert!(score < 1.0, "{what}: {at}");
}

/// The camera inside a scattering medium (`cornell_in_a_fog_bank`: fog around the whole Cornell
/// box): camera subpaths start in the fog, light subpaths leave a light inside it, and light
/// tracing connects to the camera through it. Every channel's 16 x 16 blocks within the noise of
/// the path tracer's image.
#[test]
fn bdpt_with_the_camera_in_a_fog_bank_matches_the_path_tracer() {
    assert_fog_matches_the_path_tracer("fog bank", &cornell_in_a_fog_bank());
}

/// `bdpt.light_paths` above 1 with an orthographic camera, which light tracing cannot reach, is
/// refused naming the key and the camera; one light path per sample renders.
#[test]
fn more_light_paths_with_an_orthographic_camera_are_refused() {
    let path = furnace_box("bdpt-orthographic", dielectric_material(1.5, 1.0, None));
    let scene = common::gltf::load_path(&path).unwrap();
    let base =
        RenderSettings { integrator: common::settings::Integrator::Bdpt, ..white_furnace(8, 4) };
    let four =
        RenderSettings { bdpt: Some(common::settings::Bdpt { light_paths: 4 }), ..base.clone() };
    let e = prepare_frame(&scene, &four, None, 0).err().expect("refused").to_string();
    assert!(e.contains("bdpt.light_paths") && e.contains("orthographic"), "{e}");
    assert!(prepare_frame(&scene, &base, None, 0).is_ok());
}

/// Diffuse surfaces inside an absorbing volume (`cornell_under_water`: the floor, the short block
/// and the red wall under tinted water, lit only through its surface, a caustic for both
/// renderers): subpaths inside it lose light to it, and connections between their vertices
/// carry its transmittance. Every 16 x 16 block within the noise of the path tracer's image.
#[test]
fn bdpt_inside_an_absorbing_volume_matches_the_path_tracer() {
    let scene = cornell_under_water();
    let base =
        RenderSettings { width: 32, height: 32, spp: 256, max_depth: 8, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 1024, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&bdpt_sum(&camera, &light), &pixel_stats(&path), 32, 16, 0.0);
    println!("under water: worst block {score:.2} ({at})");
    assert!(score < 1.0, "under water: {at}");
}

/// A light task's sample indices are spread over a worker's threads, one film per index, added
/// in index order: the same bits on one thread and on three (a wave of three films, then the
/// rest), with depth of field and the shutter open so that every shared number is drawn.
#[test]
fn a_light_task_gives_the_same_bits_on_any_number_of_threads() {
    use common::{
        film::Rect,
        protocol::{SampleRange, TaskKind, TaskSpec},
    };
    let (scene, motion) = cornell_motion(true);
    let settings = RenderSettings {
        width: 24,
        height: 24,
        spp: 7,
        max_depth: 5,
        integrator: common::settings::Integrator::Bdpt,
        lens: cornell_dof_settings().lens,
        ..motion
    };
    let prepared = prepare_frame(&scene, &settings, None, 0).expect("prepare");
    let rect = Rect { x0: 0, y0: 0, width: 24, height: 24 };
    let task = TaskSpec {
        frame: 0,
        rect,
        samples: SampleRange { start: 2, end: 9 },
        kind: TaskKind::Light,
    };
    let one = worker::render::render_task_threads(&prepared, 5, &task, 1);
    let three = worker::render::render_task_threads(&prepared, 5, &task, 3);
    assert!(one.tile.pixels.iter().any(|p| p.mean()[0] > 0.0), "light tracing reaches the camera");
    assert_eq!(one.rays, three.rays);
    assert!(one.tile.pixels.iter().zip(&three.tile.pixels).all(|(a, b)| a == b), "1 vs 3 threads");
}

/// Each pixel converges, not only each block: the Cornell box at 16x16 with 512 samples against
/// the path tracer's 2,048, every pixel and channel's difference over its standard error
/// (z), whose mean square is about 1 where each pixel's estimate is unbiased (below 1 here: a
/// low-discrepancy estimate's spread overstates its error). Light subpaths whose numbers stay in
/// a few strata for one pixel (as a frame-wide sequence indexed by sample and pixel gives) leave
/// each pixel's connections a bias of its own, which block means average out and this does not.
#[test]
fn bdpt_converges_pixel_by_pixel() {
    let scene = load("cornell-box.gltf");
    let base =
        RenderSettings { width: 16, height: 16, spp: 512, max_depth: 5, ..settings("cornell-box") };
    let (camera, light) = render_bdpt(&scene, &base);
    let path = render(&scene, &RenderSettings { spp: 2048, seed: 3, ..base.clone() });
    let ours = bdpt_sum(&camera, &light);
    let (mut sum, mut worst, mut n) = (0.0f64, 0.0f64, 0.0f64);
    for (o, p) in ours.iter().zip(&path.pixels) {
        let (pm, pv) = (p.mean(), p.variance_of_mean());
        for c in 0..3 {
            let var = o.1[c] + pv[c];
            if var > 0.0 {
                let z2 = (o.0[c] - pm[c]).powi(2) / var;
                sum += z2;
                worst = worst.max(z2);
                n += 1.0;
            }
        }
    }
    let mean = sum / n;
    println!("per pixel: mean z² {mean:.3} over {n} values, worst z {:.2}", worst.sqrt());
    assert!(mean < 1.5, "mean z² {mean}");
}
