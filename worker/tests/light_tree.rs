//! The light tree through the whole renderer: a floor lit by many small emitters
//! (`worker::test_scenes::many_lights_gltf`) renders the same image with the tree as with the
//! power mixture, within the noise, and with less noise at equal samples; lamps merged into a
//! few meshes choose by the tree too; and the shipped scenes, with few emitters, keep the
//! mixture (so they render as before, the Cornell box on the wavefront).

mod support;

use common::{film::Film, settings::RenderSettings};
use support::*;
use worker::{
    render::{
        light::{LightChoice, TREE_MIN_EMITTERS},
        scene::{prepare, prepare_with_light_choice},
    },
    test_scenes::{many_lights_gltf, many_lights_gltf_in},
};

fn many_lights(n: usize) -> common::scene::Scene {
    let dir = std::env::temp_dir().join(format!("renderfarm-light-tree-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("many-{n}.gltf"));
    std::fs::write(&path, many_lights_gltf(n)).unwrap();
    common::gltf::load_path(&path).unwrap()
}

fn settings(res: u32, spp: u32) -> RenderSettings {
    RenderSettings { width: res, height: res, spp, max_depth: 8, ..Default::default() }
}

/// The mean over pixels and channels of the variance of the pixel mean, relative to the
/// squared value (+ 0.01, as the benchmarks' relative MSE): the film's expected relative MSE.
fn relative_variance(film: &Film) -> f64 {
    let mut sum = 0.0;
    for p in &film.pixels {
        let (mean, var) = (p.mean(), p.variance_of_mean());
        for c in 0..3 {
            sum += var[c] / (mean[c] * mean[c] + 0.01);
        }
    }
    sum / (film.pixels.len() * 3) as f64
}

#[test]
fn shipped_scenes_choose_as_measured() {
    // Flat lamps, a textured emitter and a sphere lit from inside keep the mixture; Veach's
    // spheres (its fill light carries most of the power) and `EmissiveStrengthTest`'s five
    // boxes enclose volumes and take the tree (`docs/perf/light-tree.md`).
    let choices = [
        (assets().join("real/DamagedHelmet/glTF-Binary/DamagedHelmet.glb"), false),
        (assets().join("real/EmissiveStrengthTest/glTF/EmissiveStrengthTest.gltf"), true),
        (scenes().join("cornell-box.gltf"), false),
        (scenes().join("cornell-glass.gltf"), false),
        (scenes().join("cornell-motion.gltf"), false),
        (scenes().join("veach-mis.gltf"), true),
        (scenes().join("furnace-closed.gltf"), false),
    ];
    // The materials scenes: glass, media and the extensions under flat lamps.
    let materials = std::fs::read_dir(scenes().join("materials"))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "gltf"))
        .map(|path| (path, false));
    for (path, tree) in choices.into_iter().chain(materials) {
        let scene = common::gltf::load_path(&path).unwrap();
        let prepared = prepare(&scene, &RenderSettings::default()).unwrap();
        assert_eq!(prepared.lights.uses_tree(), tree, "{}", path.display());
    }
    let cornell = prepare(&load("cornell-box.gltf"), &RenderSettings::default()).unwrap();
    assert!(cornell.wavefront().is_some(), "the Cornell box stays on the wavefront");
    // The kernel the worker's log names: the wavefront's lanes on this CPU.
    let kernel = worker::render::kernel(&cornell);
    match worker::render::integrators::wavefront::lanes() {
        16 => assert_eq!(kernel, "path, AVX-512 x16"),
        8 => assert_eq!(kernel, "path, AVX2 x8"),
        _ => assert_eq!(kernel, "path, scalar"),
    }
}

#[test]
fn many_emitters_choose_by_the_tree_on_the_wavefront() {
    let few = prepare(&many_lights(TREE_MIN_EMITTERS - 1), &settings(8, 1)).unwrap();
    assert!(!few.lights.uses_tree() && few.wavefront().is_some());
    let many = prepare(&many_lights(TREE_MIN_EMITTERS), &settings(8, 1)).unwrap();
    assert!(many.lights.uses_tree() && many.wavefront().is_some());
}

/// A thousand lamps merged into eight meshes (one power class each) are eight placements but a
/// thousand pieces: they choose by the tree, on the wavefront, as when each is its own node.
#[test]
fn lamps_merged_into_a_few_meshes_choose_by_the_tree() {
    let dir = std::env::temp_dir().join(format!("renderfarm-merged-lamps-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("merged.gltf");
    std::fs::write(&path, many_lights_gltf_in(1024, 0.15, 0.05, Some(8))).unwrap();
    let scene = common::gltf::load_path(&path).unwrap();
    assert_eq!(scene.instances.len(), 9, "the floor and eight lamp meshes");
    let prepared = prepare(&scene, &settings(8, 1)).unwrap();
    assert!(prepared.lights.uses_tree() && prepared.wavefront().is_some());
    // Fewer merged lamps than the threshold keep the mixture.
    std::fs::write(&path, many_lights_gltf_in(TREE_MIN_EMITTERS - 1, 0.15, 0.05, Some(2))).unwrap();
    let few = prepare(&common::gltf::load_path(&path).unwrap(), &settings(8, 1)).unwrap();
    assert!(!few.lights.uses_tree());
}

#[test]
fn many_lights_tree_agrees_with_the_mixture_with_less_noise() {
    let scene = many_lights(1024);
    let settings = settings(48, 32);
    let tree = prepare_with_light_choice(&scene, &settings, LightChoice::Tree).unwrap();
    let mixture = prepare_with_light_choice(&scene, &settings, LightChoice::Mixture).unwrap();
    assert!(tree.lights.uses_tree() && !mixture.lights.uses_tree());
    let (a, b) = (render_prepared(&tree, &settings), render_prepared(&mixture, &settings));
    // Block means of the two images differ by no more than their noise.
    let block = 8;
    let blocks = (settings.width / block) * (settings.height / block);
    let mut worst = 0.0f64;
    for by in 0..settings.height / block {
        for bx in 0..settings.width / block {
            let (mut d, mut v) = (0.0, 0.0);
            for y in by * block..(by + 1) * block {
                for x in bx * block..(bx + 1) * block {
                    let i = (y * settings.width + x) as usize;
                    let (pa, pb) = (&a.pixels[i], &b.pixels[i]);
                    for c in 0..3 {
                        d += pa.mean()[c] - pb.mean()[c];
                        v += pa.variance_of_mean()[c] + pb.variance_of_mean()[c];
                    }
                }
            }
            worst = worst.max((d / v.sqrt()).abs());
        }
    }
    let bound = sidak_z(0.01, blocks as usize);
    let (err_tree, err_mixture) = (relative_variance(&a), relative_variance(&b));
    println!(
        "1024 emitters, {} spp: worst block |z| = {worst:.2} (bound {bound:.2}); relative \
         variance of the mean: tree {err_tree:.4e}, mixture {err_mixture:.4e} ({:.1}x)",
        settings.spp,
        err_mixture / err_tree
    );
    assert!(worst <= bound, "worst block |z| = {worst}");
    assert!(err_tree * 3.0 < err_mixture, "tree {err_tree}, mixture {err_mixture}");
}
