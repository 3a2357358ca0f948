//! Glass and subsurface scattering against an independent renderer.
//!
//! The scenes of `scenes/materials/` (a smooth and a rough absorbing glass sphere, and a sphere of
//! a scattering medium behind a smooth ior-1.5 and behind an index-matched boundary, on a
//! checkered floor under an area light and a sky colour) rendered at 48x48 by Mitsuba 3's
//! volumetric path tracer at tens of thousands of samples per pixel are
//! `scenes/materials/ref/<scene>-48.exr`; each `.ref.json` beside them records how
//! (the peers' `make_ref.py` or `scenes/materials/mitsuba_peer.py --ref`, whose loaders
//! map the glTF volume to Mitsuba's `dielectric` or `roughdielectric` and a `homogeneous` medium)
//! and the reference's own noise. The scattering media's references are rendered without Russian
//! roulette, which biases Mitsuba's `volpathmis` (`docs/perf/materials.md`). Our render at a modest sample count must agree with it over the whole image and per
//! 16x16 block, within the noise the film measures plus the reference's (see
//! `docs/perf/materials.md` for the full-size comparison).

mod support;

use std::path::{Path, PathBuf};

use common::settings::RenderSettings;
use support::*;

fn materials() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/materials")
}

/// Renders `scenes/materials/<name>.gltf` at 48x48 with `spp` samples and checks it against its
/// reference.
fn matches_reference(name: &str, spp: u32) {
    let dir = materials();
    let scene = common::gltf::load_path(&dir.join(format!("{name}.gltf"))).unwrap();
    let text = std::fs::read_to_string(dir.join(format!("{name}.settings.json"))).unwrap();
    let settings =
        RenderSettings { width: 48, height: 48, spp, ..RenderSettings::from_json(&text).unwrap() };
    let film = render(&scene, &settings);
    assert_eq!(film.rejected, 0, "{name}: non-finite samples");
    let (w, h, reference) = read_rgb(&dir.join(format!("ref/{name}-48.exr")));
    assert_eq!((w, h), (48, 48));
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join(format!("ref/{name}-48.ref.json"))).unwrap(),
    )
    .unwrap();
    let ref_rmse = meta["noise_rmse_est"].as_f64().unwrap();
    let cmp = compare(&film, &reference, ref_rmse * ref_rmse, 16);
    let z_block = sidak_z(0.01, cmp.blocks);
    let mean = |img: &mut dyn Iterator<Item = [f64; 3]>| {
        let (mut s, mut n) = (0.0, 0.0);
        for p in img {
            s += p[0] + p[1] + p[2];
            n += 3.0;
        }
        s / n
    };
    let ours = mean(&mut film.pixels.iter().map(|p| p.mean()));
    let theirs = mean(&mut reference.iter().map(|p| p.map(f64::from)));
    eprintln!(
        "{name}: {cmp:?} (block limit {z_block:.2}); image mean {ours:.5} vs reference {theirs:.5}"
    );
    assert!(cmp.z_image.abs() < 4.0, "{name}: image-level bias, z = {:.2}", cmp.z_image);
    assert!(cmp.z_block_max < z_block, "{name}: a block is off by {:.2} sigma", cmp.z_block_max);
}

/// The outline of the smooth-shaded sphere comes out darker than Mitsuba's (paths between the
/// shading and the geometric surface end): z of the whole image about -2.7 at this count.
#[test]
fn smooth_glass_matches_mitsuba() {
    matches_reference("glass-smooth", 1024);
}

#[test]
fn rough_glass_matches_mitsuba() {
    matches_reference("glass-rough", 512);
}

#[test]
fn subsurface_scattering_matches_mitsuba() {
    matches_reference("subsurface", 256);
}

#[test]
fn index_matched_subsurface_scattering_matches_mitsuba() {
    matches_reference("subsurface-matched", 256);
}

/// Bidirectional path tracing and photon mapping through refractive volumes against the same
/// Mitsuba 3 references (smooth and rough absorbing glass on a floor, 48x48): every 8 x 8 block
/// within the Sidak bound of both images' noise (photon mapping: plus 4%, its radius's bias).
#[test]
fn bdpt_and_sppm_glass_match_mitsuba() {
    bdpt_and_sppm_match_mitsuba(&["glass-smooth", "glass-rough"], 256, 8);
}

/// Subsurface scattering (a scattering sphere behind an ior-1.5 and an index-matched boundary)
/// in bidirectional path tracing and photon mapping against the same references, at 512
/// samples, by 16 x 16 blocks as the path tracer's test compares them (the reference's noise is
/// given for the whole image). Bidirectional path tracing's light inside the index-matched
/// sphere comes in rare heavy samples, whose spread the two halves' estimate of the error
/// understates: over six seeds the worst block reached 0.44-0.83 of the bound, and 1.12 with one
/// seed whose block 1% bright stayed at 4,096 samples against our path tracer's 8,192 (z 4.1),
/// where another seed's is within z 2.2 and the whole image within 0.1%.
#[test]
fn bdpt_and_sppm_subsurface_scattering_match_mitsuba() {
    bdpt_and_sppm_match_mitsuba(&["subsurface", "subsurface-matched"], 512, 16);
}

/// Renders each of `names` with both integrators at 48x48 and `spp` samples (passes) and checks
/// every `block` x `block` block against its Mitsuba 3 reference.
fn bdpt_and_sppm_match_mitsuba(names: &[&str], spp: u32, block: u32) {
    let dir = materials();
    for &name in names {
        let scene = common::gltf::load_path(&dir.join(format!("{name}.gltf"))).unwrap();
        let text = std::fs::read_to_string(dir.join(format!("{name}.settings.json"))).unwrap();
        let settings = RenderSettings {
            width: 48,
            height: 48,
            spp,
            ..RenderSettings::from_json(&text).unwrap()
        };
        let (_, _, reference) = read_rgb(&dir.join(format!("ref/{name}-48.exr")));
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(format!("ref/{name}-48.ref.json"))).unwrap(),
        )
        .unwrap();
        let var = meta["noise_rmse_est"].as_f64().unwrap().powi(2);
        let reference: Vec<_> = reference.iter().map(|p| (p.map(f64::from), [var; 3])).collect();
        let (camera, light) = render_bdpt_with(&scene, &settings, None);
        let (score, at) = worst_block(&bdpt_sum(&camera, &light), &reference, 48, block, 0.0);
        eprintln!("{name}, bdpt: worst block {score:.2} ({at})");
        assert!(score < 1.0, "{name}, bdpt: {at}");
        let film = render_sppm_with(&scene, &settings, 128, 2, None);
        let (score, at) = worst_block(&pixel_stats(&film), &reference, 48, block, 0.04);
        eprintln!("{name}, sppm: worst block {score:.2} ({at})");
        assert!(score < 1.0, "{name}, sppm: {at}");
    }
}
