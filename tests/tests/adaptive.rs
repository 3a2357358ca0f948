//! Adaptive sampling on the cornell box, scored against the independent reference image: a job
//! with `target_rel_error` reaches that error with fewer samples than uniform sampling needs, and
//! where it stops is decided from completed data only, so the image (sample counts included) is
//! bitwise the same on one process with two workers and on a cluster of three.

use std::time::Duration;

use serde_json::{json, Value};
use tests::*;

/// Relative MSE against the cornell box's independent reference.
fn rel_mse_to_reference(image: &[u8]) -> f64 {
    let reference = std::fs::read(repo().join("scenes/ref/cornell-box.exr")).unwrap();
    rel_mse(image, &reference)
}

fn settings(spp: u32, target: Option<f64>) -> Value {
    json!({
        "width": 256, "height": 256, "spp": spp, "samples_per_task": 8, "tile_size": 32,
        "max_depth": 128, "seed": 0, "target_rel_error": target
    })
}

#[test]
fn adaptive_sampling_reaches_the_target_with_fewer_samples_than_uniform() {
    let dir = temp_dir("adaptive-target");
    let target = 0.04;
    let adaptive = render_reference(&dir, &settings(1024, Some(target)), 2);
    let counts = sample_counts(&adaptive);
    let total: u64 = counts.iter().map(|&n| n as u64).sum();
    let pixels = counts.len() as u64;
    let err = rel_mse_to_reference(&adaptive);
    eprintln!(
        "adaptive: {total} samples ({:.1} spp on average), relMSE {err:.4e}",
        total as f64 / pixels as f64
    );
    assert!(
        err <= target * target * 1.05,
        "adaptive missed its target: relMSE {err:.4e} > {:.4e}",
        target * target
    );
    assert!(counts.iter().any(|&n| n != counts[0]), "adaptive sampling did not adapt");
    assert!(counts.iter().all(|&n| n >= 16), "a tile stopped before its pilot");
    // Uniform sampling with at least as many samples does not reach the target.
    let uniform_spp = total.div_ceil(pixels) as u32;
    let uniform = render_reference(&dir, &settings(uniform_spp, None), 2);
    let uniform_err = rel_mse_to_reference(&uniform);
    eprintln!("uniform: {uniform_spp} spp, relMSE {uniform_err:.4e}");
    assert!(
        uniform_err > target * target,
        "uniform at {uniform_spp} spp reaches {uniform_err:.4e}: adaptivity saved nothing"
    );
    assert!(err < uniform_err);
}

#[test]
fn adaptive_stopping_is_deterministic_across_processes_and_worker_counts() {
    let dir = temp_dir("adaptive-determinism");
    let s = settings(512, Some(0.06));
    let local = render_reference(&dir, &s, 2);
    let cluster = Cluster::start(&dir, 3, &[]);
    let url = &cluster.url;
    let id = create_job(url, &cluster.scene, &s, 0);
    let status = wait_done(url, &id, Duration::from_secs(240));
    let image = fetch_exr(url, &id, 0);
    assert_same_image(&local, &image, "adaptive job: render vs serve + 3 workers");
    let saved = status["samples_saved"].as_u64().unwrap();
    let done = status["samples_done"].as_u64().unwrap();
    assert_eq!(done + saved, status["samples_planned"].as_u64().unwrap(), "{status:#}");
    assert!(saved > 0, "{status:#}");
    assert!(status["est_rel_error"].as_f64().unwrap() <= 0.06, "{status:#}");
    assert_eq!(status["progress"], 1.0);
}
