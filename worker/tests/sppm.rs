//! Stochastic progressive photon mapping (`"integrator": "sppm"`) converges to what the closed
//! forms and the path tracer give: the mirror caustic within 1% of its closed form, the closed
//! furnace at 1, the Cornell box at the path tracer's image; and a pass is the same whatever the
//! threads and the tasks it is split into.

mod support;

use common::{film::Film, scene::Scene, settings::RenderSettings};
use support::*;
use worker::render::scene::{prepare, prepare_frame};

/// Renders the whole frame with photon mapping in tasks of `per_task` passes, each on `threads`
/// threads, as the farm splits it (the frame is one tile).
fn render_sppm(scene: &Scene, settings: &RenderSettings, per_task: u32, threads: usize) -> Film {
    render_sppm_with(scene, settings, per_task, threads, None)
}

/// The mirror caustic at `max_depth` 2 (a floor lit only through a mirror by a small light,
/// `worker::test_scenes::MirrorCaustic`): the image within 1% of the closed form (the radius's
/// bias included), its mean within 4 of its standard errors plus that 1%, and a closed form 3%
/// off rejected. Photons find these paths as the light does: the printed figures compare the
/// error and time with the path tracer's (the benchmark's business, not asserted).
#[test]
fn sppm_mirror_caustic_is_within_one_percent_of_the_closed_form() {
    let res = 32;
    let (scene, expected, base) = bench_caustic(res, 256);
    let t = std::time::Instant::now();
    let film = render_sppm(&scene, &base, 64, 2);
    let seconds = t.elapsed().as_secs_f64();
    assert_eq!(film.rejected, 0, "non-finite samples");
    let n = film.pixels.len() as f64;
    let mean = film.pixels.iter().map(|p| p.mean()[0]).sum::<f64>() / n;
    let se = (film.pixels.iter().map(|p| p.variance_of_mean()[0]).sum::<f64>()).sqrt() / n;
    let truth = expected.iter().map(|e| e[0] as f64).sum::<f64>() / n;
    let rel_mse = film
        .pixels
        .iter()
        .zip(&expected)
        .map(|(p, e)| ((p.mean()[0] - e[0] as f64) / e[0] as f64).powi(2))
        .sum::<f64>()
        / n;
    println!(
        "mirror caustic (light half side 0.125), {res}x{res}, max_depth 2: sppm {} passes in \
         {seconds:.2} s, image mean {mean:.5} against {truth:.5} (ratio {:.5}, standard error \
         {:.2e}), relative MSE {rel_mse:.3e}",
        base.spp,
        mean / truth,
        se / truth,
    );
    assert!((mean / truth - 1.0).abs() < 0.01 + 4.0 * se / truth, "ratio {}", mean / truth);
    for wrong in [0.97, 1.03] {
        assert!((mean / (truth * wrong) - 1.0).abs() > 0.01 + 4.0 * se / truth, "{wrong} passes");
    }
}

/// The closed furnace (every surface emits what it does not reflect, so that radiance is 1
/// everywhere, down to the longest paths): the image mean within 4 standard errors of 1 (a
/// sphere's inside has uniform irradiance, so the gather radius adds no bias).
#[test]
fn sppm_closed_furnace_is_one() {
    let scene = load("furnace-closed.gltf");
    let settings = RenderSettings { width: 16, height: 16, spp: 32, ..settings("furnace-closed") };
    let film = render_sppm(&scene, &settings, 16, 2);
    for (c, (mean, se)) in image_mean(&film).into_iter().enumerate() {
        println!("closed furnace, sppm, channel {c}: {mean:.5} (standard error {se:.1e})");
        assert!((mean - 1.0).abs() < 4.0 * se + 1e-3, "channel {c}: {mean} ({se})");
    }
}

/// The Cornell box at `max_depth` 5 against the path tracer: the image mean per channel within 4
/// standard errors of both plus 1% (the gather radius's bias, which its corners show), and every
/// 8 x 8 block within the Sidak bound of the noise plus 2%.
#[test]
fn sppm_cornell_box_matches_the_path_tracer() {
    let scene = load("cornell-box.gltf");
    let base =
        RenderSettings { width: 32, height: 32, spp: 128, max_depth: 5, ..settings("cornell-box") };
    let t = std::time::Instant::now();
    let film = render_sppm(&scene, &base, 64, 2);
    let ts = t.elapsed().as_secs_f64();
    let path = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let ours = image_mean(&film);
    let theirs = image_mean(&path);
    println!("cornell box 32x32, max_depth 5: sppm 128 passes in {ts:.2} s");
    for c in 0..3 {
        let (m, se) = ours[c];
        let (pm, pse) = theirs[c];
        let z = (m - pm) / (se * se + pse * pse).sqrt();
        println!("channel {c}: sppm {m:.5} +- {se:.1e}, path {pm:.5} +- {pse:.1e}, z {z:.2}");
        assert!((m - pm).abs() < 4.0 * (se * se + pse * pse).sqrt() + 0.01 * pm, "channel {c}");
    }
    // Blocks of 8 x 8: within the Sidak bound of both films' standard errors plus 2% (the
    // radius's bias where the floor meets the boxes).
    let block = 8;
    let z_bound = sidak_z(0.01, ((base.width / block) * (base.height / block)) as usize);
    for by in 0..base.height / block {
        for bx in 0..base.width / block {
            let (mut a, mut b, mut var) = (0.0, 0.0, 0.0);
            for y in by * block..(by + 1) * block {
                for x in bx * block..(bx + 1) * block {
                    let (p, q) = (
                        &film.pixels[(y * base.width + x) as usize],
                        &path.pixels[(y * base.width + x) as usize],
                    );
                    a += p.mean().iter().sum::<f64>();
                    b += q.mean().iter().sum::<f64>();
                    var += p.variance_of_mean().iter().sum::<f64>()
                        + q.variance_of_mean().iter().sum::<f64>();
                }
            }
            let z = (a - b) / var.sqrt();
            assert!(
                (a - b).abs() < z_bound * var.sqrt() + 0.02 * b,
                "block ({bx}, {by}): sppm / path {}, z {z:.2} (bound {z_bound:.2})",
                a / b
            );
        }
    }
}

/// A pass is a function of (scene, settings, seed, pass) alone: on one thread or three the same
/// bits (tasks split as the farm splits them, whatever its workers), and the same means with the
/// passes split into other tasks (the film's running means merge to within rounding).
#[test]
fn sppm_is_the_same_on_any_threads_and_split() {
    let scene = load("cornell-box.gltf");
    let base =
        RenderSettings { width: 24, height: 20, spp: 6, max_depth: 5, ..settings("cornell-box") };
    let same = |x: &Film, y: &Film| x.pixels.iter().zip(&y.pixels).all(|(a, b)| a == b);
    let one = render_sppm(&scene, &base, 6, 1);
    assert!(same(&one, &render_sppm(&scene, &base, 6, 3)), "one task: 1 vs 3 threads");
    let split = render_sppm(&scene, &base, 2, 1);
    assert!(same(&split, &render_sppm(&scene, &base, 2, 3)), "three tasks: 1 vs 3 threads");
    for (a, b) in one.pixels.iter().zip(&split.pixels) {
        for c in 0..3 {
            assert!((a.mean[c] - b.mean[c]).abs() <= 1e-12 * a.mean[c].abs(), "{a:?} vs {b:?}");
        }
    }
    assert!(one.mean_rgb().iter().flatten().any(|&v| v > 0.0));
}

/// The photon-mapping film against the path tracer's by their means per channel over the
/// pixels where both are below `cap` (the lights seen straight on, whose edges' noise would hide
/// the rest, are left out): within 4 standard errors of both plus `bias` (relative); prints the
/// figures under `what`.
fn assert_means_agree(what: &str, ours: &Film, path: &Film, cap: f64, bias: f64) {
    let kept: Vec<usize> = (0..ours.pixels.len())
        .filter(|&i| {
            let below = |f: &Film| f.pixels[i].mean().iter().all(|&v| v < cap);
            below(ours) && below(path)
        })
        .collect();
    let n = kept.len() as f64;
    let stats = |f: &Film, c: usize| {
        let mean = kept.iter().map(|&i| f.pixels[i].mean()[c]).sum::<f64>() / n;
        let var = kept.iter().map(|&i| f.pixels[i].variance_of_mean()[c]).sum::<f64>() / (n * n);
        (mean, var.sqrt())
    };
    for c in 0..3 {
        let ((m, se), (pm, pse)) = (stats(ours, c), stats(path, c));
        let sigma = (se * se + pse * pse).sqrt();
        println!(
            "{what} ({} of {} pixels), channel {c}: sppm {m:.5} +- {se:.1e}, path {pm:.5} +- \
             {pse:.1e}, z {:.2}",
            kept.len(),
            ours.pixels.len(),
            (m - pm) / sigma
        );
        assert!((m - pm).abs() < 4.0 * sigma + bias * pm, "{what}, channel {c}: {m} vs {pm}");
    }
}

/// A glossy scene (`scenes/veach-mis`: four metal plates of GGX alpha 0.005 to 0.1 lit by four
/// lights of different sizes, followed to the floor they reflect) and
/// depth of field (the Cornell box through the thin lens of `cornell-dof`): image means within
/// the noise plus 1% of the path tracer's (on the plates, the lights seen straight on left out).
#[test]
fn sppm_glossy_plates_and_thin_lens_match_the_path_tracer() {
    let path = scenes().join("veach-mis.gltf");
    let scene = common::gltf::load_path(&path).unwrap();
    let base =
        RenderSettings { width: 48, height: 32, spp: 256, max_depth: 5, ..Default::default() };
    let film = render_sppm(&scene, &base, 128, 2);
    let reference = render(&scene, &RenderSettings { spp: 1024, seed: 3, ..base.clone() });
    assert_means_agree("veach-mis-s", &film, &reference, 2.0, 0.01);

    let scene = load("cornell-box.gltf");
    let dof = cornell_dof_settings();
    let base = RenderSettings { width: 32, height: 32, spp: 128, max_depth: 5, ..dof };
    let film = render_sppm(&scene, &base, 64, 2);
    let reference = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    assert_means_agree("cornell box, thin lens", &film, &reference, f64::INFINITY, 0.01);
}

/// A radius larger than the scene (every photon lands near every visible point): each chunk of
/// photons sums per visible point instead of listing its contributions, and the image is still
/// finite and the same bits on one thread or three; a radius too small for f32 makes no NaN.
#[test]
fn sppm_with_a_radius_larger_than_the_scene_stays_bounded_and_the_same() {
    let scene = load("cornell-box.gltf");
    let base = RenderSettings {
        width: 8,
        height: 8,
        spp: 2,
        max_depth: 3,
        sppm: Some(common::settings::Sppm { radius: Some(100.0), ..Default::default() }),
        ..settings("cornell-box")
    };
    let one = render_sppm(&scene, &base, 2, 1);
    let three = render_sppm(&scene, &base, 2, 3);
    assert_eq!(one.rejected, 0);
    assert!(one.pixels.iter().zip(&three.pixels).all(|(a, b)| a == b), "1 vs 3 threads");
    assert!(one.mean_rgb().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
    // And one too small to have an area in f32: no photon is gathered, and no NaN made.
    let tiny = RenderSettings {
        sppm: Some(common::settings::Sppm { radius: Some(1e-60), ..Default::default() }),
        ..base
    };
    let film = render_sppm(&scene, &tiny, 2, 2);
    assert_eq!(film.rejected, 0, "non-finite samples");
}

/// Many lights (64 small emitters over a floor): the light samples of the camera paths choose by
/// the light tree, as the path tracer's do, and photons leave the lights by the power mixture;
/// the image means agree with the path tracer's within the noise plus 1%.
#[test]
fn sppm_with_the_light_tree_matches_the_path_tracer() {
    let scene = load_many_lights(64, "sppm");
    let base =
        RenderSettings { width: 32, height: 32, spp: 128, max_depth: 4, ..Default::default() };
    let prepared = prepare(
        &scene,
        &RenderSettings { integrator: common::settings::Integrator::Sppm, ..base.clone() },
    )
    .unwrap();
    assert!(prepared.lights.uses_tree() && prepared.emission.is_some());
    let film = render_sppm(&scene, &base, 64, 2);
    let reference = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    assert_means_agree("64 lights", &film, &reference, f64::INFINITY, 0.01);
}

/// Motion blur: each pass is one instant of the shutter. The Cornell box whose blocks move,
/// seen from a still camera and from one that slides too: every 8 x 8 block within the Sidak
/// bound of the noise plus 4% of the path tracer's (the radius's bias, which at 32 x 32 pixels
/// darkens the blocks at the box's corners 2-3% after 256 passes, moving or not), and the image
/// of the shutter's first instant (the scene frozen, 30-40% off in some block) told apart. With
/// the light moving too (photons leave it where it is at each pass's instant), every 16 x 16
/// block within the noise plus 4%.
#[test]
fn sppm_motion_blur_matches_the_path_tracer() {
    for moving_camera in [false, true] {
        let (scene, motion) = cornell_motion(moving_camera);
        let base = RenderSettings { width: 32, height: 32, spp: 256, max_depth: 5, ..motion };
        let film = render_sppm(&scene, &base, 128, 2);
        let path = render_frame0(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
        let ours = pixel_stats(&film);
        let (score, at) = worst_block(&ours, &pixel_stats(&path), base.width, 8, 0.04);
        println!("motion blur, moving camera {moving_camera}: worst block {score:.2} ({at})");
        assert!(score < 1.0, "moving camera {moving_camera}: {at}");
        let frozen = RenderSettings {
            shutter: common::settings::Shutter { open: 0.0, close: 0.0 },
            ..base.clone()
        };
        let frozen = render_frame0(&scene, &RenderSettings { spp: 512, seed: 3, ..frozen });
        let (score, at) = worst_block(&ours, &pixel_stats(&frozen), base.width, 8, 0.04);
        println!("  against the frozen scene: worst block {score:.2} ({at})");
        assert!(score > 1.0, "moving camera {moving_camera}: the frozen image passes ({at})");
    }
    // A pass's instant is a function of (seed, pass): the same bits on one thread or three.
    let (scene, motion) = cornell_motion(true);
    let small = RenderSettings { width: 16, height: 16, spp: 4, max_depth: 5, ..motion };
    let one = render_sppm(&scene, &small, 2, 1);
    let three = render_sppm(&scene, &small, 2, 3);
    assert!(one.pixels.iter().zip(&three.pixels).all(|(a, b)| a == b), "1 vs 3 threads");
    // The light slides too (its node takes the short block's): no light sample reaches an
    // emitter that moves, so camera paths count its hits in full (the visible points' BSDF
    // samples find its direct light), and photons leave it where it is at each pass's instant.
    let (scene, motion) = cornell_motion(false);
    let scene = with_moving_light(&scene);
    let base = RenderSettings { width: 32, height: 32, spp: 256, max_depth: 5, ..motion };
    assert_moving_light_matches_the_path_tracer("the light moving", &scene, &base);
    // And a point light that stays put besides it: photons leave either kind by its share of
    // the power, each carrying its flux over its whole choice's probability.
    let mut scene = scene;
    scene.lights.push(common::scene::PunctualLight {
        name: "still".into(),
        kind: common::scene::PunctualKind::Point,
        intensity: glam::Vec3::new(0.02, 0.03, 0.05),
        position: glam::DVec3::new(0.4, 0.4, 0.2),
        direction: glam::DVec3::NEG_Z,
        range: None,
        node: None,
    });
    let prepared = prepare_frame(
        &scene,
        &RenderSettings { integrator: common::settings::Integrator::Sppm, ..base.clone() },
        None,
        0,
    )
    .unwrap();
    let share = prepared.moving_emitters.as_ref().expect("the moving light").share;
    println!("  the moving light's share of the photons beside a still one: {share:.2}");
    assert!(share > 0.1 && share < 0.9, "{share}");
    assert_moving_light_matches_the_path_tracer("and a still light", &scene, &base);
}

/// An emitter that moves within the shutter inside an absorbing volume
/// (`cornell_moving_light_in_water`): its photons start in the volume it lies inside at the
/// shutter's opening and lose light on their way out (all its light reaches the room through
/// the water's surface, so photons carry it all). Every 16 x 16 block within the noise plus 4%
/// of the path tracer's image.
#[test]
fn sppm_moving_light_inside_a_volume_matches_the_path_tracer() {
    let (scene, motion) = cornell_moving_light_in_water();
    let base = RenderSettings { width: 32, height: 32, spp: 256, max_depth: 5, ..motion };
    assert_moving_light_matches_the_path_tracer("the light moving in water", &scene, &base);
}

/// A scene whose light moves within the shutter: `base`'s passes against the path tracer's
/// 512 samples, every 16 x 16 block within the noise plus 4% (a light found only by the visible
/// points' BSDF samples and photons leaves heavier tails than 8 x 8 blocks allow).
fn assert_moving_light_matches_the_path_tracer(what: &str, scene: &Scene, base: &RenderSettings) {
    let film = render_sppm(scene, base, 128, 2);
    let path = render_frame0(scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&pixel_stats(&film), &pixel_stats(&path), base.width, 16, 0.04);
    println!(
        "{what}: worst block {score:.2} ({at}); means {:?} vs {:?}",
        image_mean(&film),
        image_mean(&path)
    );
    assert!(score < 1.0, "{what}: {at}");
}

/// Lights at infinity. The furnace (a convex sphere of albedo 0.8 in a uniform environment of
/// radiance 1, all its light direct, so no radius bias): every 4 x 4 block within the noise of
/// its exact image. The Cornell box lit through its open front by a sun (a directional light)
/// and an environment map besides its ceiling light, whose photons enter through the disk
/// across the scene: every 8 x 8 block within the noise plus 4% of the path tracer's image, the
/// image's means within the noise plus 1%.
#[test]
fn sppm_lights_at_infinity_match_the_closed_form_and_the_path_tracer() {
    let scene = load("furnace.gltf");
    let furnace = RenderSettings { width: 32, height: 32, spp: 32, ..settings("furnace") };
    let film = render_sppm(&scene, &furnace, 32, 2);
    let exact: Vec<_> =
        furnace_expected(32).iter().map(|e| (e.map(|v| v as f64), [0.0; 3])).collect();
    let (score, at) = worst_block(&pixel_stats(&film), &exact, 32, 4, 0.0);
    println!("furnace: worst block {score:.2} ({at})");
    assert!(score < 1.0, "furnace: {at}");

    let (scene, outdoors, map) = cornell_sun_and_sky();
    let base = RenderSettings { spp: 256, ..outdoors };
    let film = render_sppm_with(&scene, &base, 128, 2, Some(&map));
    let settings = RenderSettings { spp: 512, seed: 3, ..base.clone() };
    let prepared =
        worker::render::scene::prepare_with_environment(&scene, &settings, Some(&map)).unwrap();
    let path = render_prepared(&prepared, &settings);
    let (score, at) = worst_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!("sun and sky: worst block {score:.2} ({at})");
    assert_means_agree("sun and sky", &film, &path, f64::INFINITY, 0.01);
    assert!(score < 1.0, "sun and sky: {at}");
}

/// Dispersion (`KHR_materials_dispersion`): a pass's camera paths and photons bend light by one
/// wavelength, and a path through a dispersive vertex on either half takes that light's colour
/// once. A dispersive glass box in the white furnace stays white (each channel's mean within 4
/// standard errors of 1); the Cornell box's sphere made dispersive (`cornell_dispersive_glass`),
/// whose caustic photons carry: each channel's every 8 x 8 block within the noise plus 4% of the
/// path tracer's image.
#[test]
fn sppm_dispersive_glass_matches_the_furnace_and_the_path_tracer() {
    let mut material = dielectric_material(1.5, 1.0, None);
    material["extensions"]["KHR_materials_dispersion"] = serde_json::json!({"dispersion": 2.0});
    let path = furnace_box("sppm-dispersive-furnace", material);
    let scene = common::gltf::load_path(&path).unwrap();
    let furnace = RenderSettings { max_depth: 64, ..white_furnace(16, 256) };
    // A pass's pixels share its wavelength: the noise from 32 batches of 8 passes.
    assert_white(
        "dispersive furnace",
        batch_mean_image(&render_sppm_batches(&scene, &furnace, 8, 2)),
        0.0,
    );

    let scene = cornell_dispersive_glass();
    let base =
        RenderSettings { width: 32, height: 32, spp: 256, max_depth: 8, ..settings("cornell-box") };
    let film = render_sppm(&scene, &base, 128, 2);
    let path = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let (score, at) = worst_channel_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!("dispersive cornell glass: worst block {score:.2} ({at})");
    assert!(score < 1.0, "dispersive cornell glass: {at}");
}

/// Dispersion seen through glass: a dispersive slab tilted over an emitting half-plane, seen from
/// above by an orthographic camera, moves the edge by each channel's colour-weighted Snell
/// offset, as in the path tracer's test (`tests/glass.rs`).
#[test]
fn sppm_splits_an_edge_seen_through_dispersive_glass_by_colour() {
    let (path, settings) = dispersive_slab_edge("sppm-dispersive-snell", 128);
    let scene = common::gltf::load_path(&path).unwrap();
    // 16 batches of 4 passes: a pass's pixels share its wavelength.
    let batches = render_sppm_batches(&scene, &settings, 4, 2);
    assert_edge_split_by_colour_in_batches(&batches, 128);
}

/// The prism's rainbow (`worker::test_scenes::PrismRainbow`): sunlight through a dispersive
/// glass prism onto a white floor, which only photons find (the light is a direction and the
/// prism's faces are smooth), each wavelength bent by its own index and each in its colour.
/// Every column's mean over the rows, per channel, within the noise of the closed form (from 32
/// batches of passes: a pass's pixels share its wavelength and photons) plus 2% of the
/// brightest: the gather radius blurs the bands' edges and reaches past the floor's end, where
/// the first column's blue (0.0025) comes out at 0.0001 (z -22 without the allowance).
#[test]
fn sppm_prism_rainbow_matches_the_closed_form() {
    let scene = common::gltf::load_path(&prism::scene("sppm")).unwrap();
    let width = 32;
    let settings = RenderSettings {
        width,
        height: width,
        spp: 256,
        max_depth: 3,
        sppm: Some(common::settings::Sppm { photons_per_pass: Some(8192), ..Default::default() }),
        ..Default::default()
    };
    let t = std::time::Instant::now();
    // 32 batches of 8 passes, whose spread gives the columns' noise (a pass's pixels share its
    // wavelength and photons).
    let batches = render_sppm_batches(&scene, &settings, 8, 2);
    println!("rendered in {:.2} s", t.elapsed().as_secs_f64());
    prism::assert_matches_closed_form(&prism::batch_columns(&batches, width), width, 0.02);
}

/// Scattering media: camera paths and photons draw free flights by the pass's hero channel, a
/// camera path follows a scattering by its phase function, and photons are gathered where they
/// land, weighed with the visible point by the channels' densities of the whole path. Media of
/// albedo 1 in the white furnace stay white (`scattering_furnaces`, each channel's mean within
/// four standard errors, from 32 batches of passes, plus 1.5% of 1: where the box's diffusely
/// transmitting faces gather photons, a gather near an edge takes in the next face's, 0.7% dark
/// here; with a sixteenth of the photons, 0.9% at 256 passes and 0.5% at 1,024, as the radius
/// shrinks), and the Cornell box in a fog (`cornell_in_fog`) agrees with the
/// path tracer in every channel's 8 x 8 blocks within the noise plus 4%.
#[test]
fn sppm_scattering_media_stay_white_in_the_furnace_and_match_the_path_tracer() {
    for (what, path) in scattering_furnaces("sppm-scatter") {
        let scene = common::gltf::load_path(&path).unwrap();
        let furnace = RenderSettings {
            max_depth: 1024,
            sppm: Some(common::settings::Sppm {
                photons_per_pass: Some(4096),
                ..Default::default()
            }),
            ..white_furnace(16, 256)
        };
        // A pass's pixels share its hero channel and photons: the noise from 32 batches.
        let batches = render_sppm_batches(&scene, &furnace, 8, 2);
        assert_white(what, batch_mean_image(&batches), 0.015);
    }

    assert_fog_matches_the_path_tracer("fog", &cornell_in_fog());
}

/// A Cornell box in a fog at 32 x 32 (`max_depth` 8): 256 passes against the path tracer's
/// 1,024 samples, every channel's 8 x 8 blocks within the noise plus 4%.
fn assert_fog_matches_the_path_tracer(what: &str, scene: &Scene) {
    let base =
        RenderSettings { width: 32, height: 32, spp: 256, max_depth: 8, ..settings("cornell-box") };
    let film = render_sppm(scene, &base, 128, 2);
    let path = render(scene, &RenderSettings { spp: 1024, seed: 3, ..base.clone() });
    let (score, at) = worst_channel_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!(
        "{what}: worst block {score:.2} ({at}); means {:?} vs {:?}",
        image_mean(&film),
        image_mean(&path)
    );
    assert!(score < 1.0, "{what}: {at}");
}

/// The camera inside a scattering medium (`cornell_in_a_fog_bank`: fog around the whole Cornell
/// box): camera paths start in the fog and photons leave a light inside it. Every channel's
/// 8 x 8 blocks within the noise plus 4% of the path tracer's image.
#[test]
fn sppm_with_the_camera_in_a_fog_bank_matches_the_path_tracer() {
    assert_fog_matches_the_path_tracer("fog bank", &cornell_in_a_fog_bank());
}

/// Refractive volumes. A clear glass box in the white furnace: every pixel within 1e-5 of 1
/// (camera paths follow the smooth boundary; nothing there gathers photons). The Cornell box's tinted
/// glass sphere (`scenes/cornell-glass`), whose caustic on the floor is photons' work, and the
/// Cornell box partly under an absorbing medium (`cornell_under_water`) and the one whose light
/// is inside such a medium (`cornell_light_in_water`: photons start in it): every 8 x 8 block
/// within the noise plus 4% of the path tracer's image (the glass's means within the noise plus
/// 1%).
#[test]
fn sppm_glass_matches_the_furnace_and_the_path_tracer() {
    let path = furnace_box("sppm-furnace", dielectric_material(1.5, 1.0, None));
    let scene = common::gltf::load_path(&path).unwrap();
    let furnace = RenderSettings { max_depth: 64, ..white_furnace(16, 64) };
    let film = render_sppm(&scene, &furnace, 64, 2);
    let worst = worst_from_white(&film);
    println!("glass furnace: worst pixel {worst:.1e} from 1");
    assert!(worst < 1e-5, "a pixel is {worst} away from 1");

    let scene = repo_scene("cornell-glass.gltf");
    let base =
        RenderSettings { width: 32, height: 32, spp: 256, max_depth: 8, ..settings("cornell-box") };
    let film = render_sppm(&scene, &base, 128, 2);
    let path = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!("cornell glass: worst block {score:.2} ({at})");
    assert_means_agree("cornell glass", &film, &path, f64::INFINITY, 0.01);
    assert!(score < 1.0, "cornell glass: {at}");

    // Visible points inside an absorbing medium, which photons reach through it.
    let scene = cornell_under_water();
    let film = render_sppm(&scene, &base, 128, 2);
    let path = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!("under water: worst block {score:.2} ({at})");
    assert!(score < 1.0, "under water: {at}");

    // Photons that leave a light inside the medium, and lose light to it on their way out.
    let scene = cornell_light_in_water();
    let film = render_sppm(&scene, &base, 128, 2);
    let path = render(&scene, &RenderSettings { spp: 512, seed: 3, ..base.clone() });
    let (score, at) = worst_block(&pixel_stats(&film), &pixel_stats(&path), 32, 8, 0.04);
    println!("light in water: worst block {score:.2} ({at})");
    assert!(score < 1.0, "light in water: {at}");
}
