//! The integrators beyond the path tracer on the farm: bidirectional path tracing
//! (`"integrator": "bdpt"`: camera tasks over tiles and light tasks over the whole frame) and
//! photon mapping (`"integrator": "sppm"`: one tile, the frame, whose tasks are ranges of
//! passes). The image is bitwise the same whatever the number of workers, in one process or as
//! `worker --join` processes, after a worker is killed mid-job and after the coordinator is
//! killed mid-job and restarted. What an integrator does not take yet is refused naming the
//! setting before any work is leased.

use std::time::Duration;

use serde_json::{json, Value};
use tests::*;

const TIMEOUT: Duration = Duration::from_secs(240);

fn settings(integrator: &str, spp: u32, spt: u32) -> Value {
    let mut s = json!({
        "width": 48, "height": 48, "spp": spp, "samples_per_task": spt, "tile_size": 16,
        "max_depth": 6, "seed": 11, "integrator": integrator
    });
    if integrator == "bdpt" {
        // Two light-traced paths per pixel sample: the light tile's tasks have twice the samples.
        s["bdpt"] = json!({"light_paths": 2});
    }
    s
}

/// `integrator`'s image of the Cornell box on 1 and 3 threads of one process (`render
/// --workers`: one local worker of that many threads, the job's 4 whole-frame tasks being fewer
/// than twice them), on serve + 3
/// worker processes (which merge `tasks` tasks), after one of two workers is kill -9'd while
/// both hold leases (a longer job, so that both do) and after the coordinator is kill -9'd and
/// restarted: the same bits.
fn same_image_on_any_workers_and_after_a_kill(integrator: &str, tasks: f64) {
    let dir = temp_dir(&format!("{integrator}-farm"));
    let s = settings(integrator, 64, 16);
    let one = render_reference(&dir, &s, 1);
    let three = render_reference(&dir, &s, 3);
    assert_same_image(&one, &three, "coordinator render --workers 1 vs 3 (threads)");
    assert!(sample_counts(&one).iter().all(|&n| n == 64));

    // Three worker processes.
    let cluster = Cluster::start(&temp_dir(&format!("{integrator}-cluster")), 3, &[]);
    let id = create_job(&cluster.url, &cluster.scene, &s, 0);
    let status = wait_done(&cluster.url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], 48 * 48 * 64, "camera samples only: {status:#}");
    assert_same_image(&one, &fetch_exr(&cluster.url, &id, 0), "serve + 3 workers vs render");
    assert_eq!(metric(&cluster.url, "renderfarm_tasks_merged_total"), tasks);
    drop(cluster);

    let s = settings(integrator, 512, 128);
    let one = render_reference(&dir, &s, 2);
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let kill_dir = temp_dir(&format!("{integrator}-kill"));
    let _coordinator = start_coordinator(&kill_dir.join("data"), port, &["--lease-timeout", "1"]);
    let mut victim = start_worker(&url, 1, kill_dir.join("victim.log"));
    let _survivor = start_worker(&url, 1, kill_dir.join("survivor.log"));
    let scene = upload(&url, &cornell_zip());
    let id = create_job(&url, &scene, &s, 0);
    wait_for(&url, &id, TIMEOUT, |st| st["tasks_in_flight"].as_u64() == Some(2));
    victim.kill9();
    wait_done(&url, &id, TIMEOUT);
    assert_same_image(&one, &fetch_exr(&url, &id, 0), "after a worker was killed");

    // The coordinator kill -9'd a quarter of the way through and restarted on its data folder:
    // the merged tasks (light tasks among them) come back from its database, none is merged
    // twice, and the job ends with the same bits.
    let restart_dir = temp_dir(&format!("{integrator}-restart"));
    let mut cluster = Cluster::start(&restart_dir, 2, &["--lease-timeout", "2"]);
    let url = cluster.url.clone();
    let id = create_job(&url, &cluster.scene, &s, 0);
    let progress = |st: &Value| st["progress"].as_f64().unwrap_or(0.0);
    let before = wait_for(&url, &id, TIMEOUT, |st| progress(st) >= 0.25);
    assert_eq!(before["state"], "running", "{before:#}");
    cluster.restart_coordinator(&["--lease-timeout", "2"]);
    let resumed = job_status(&url, &id);
    assert!(progress(&resumed) >= progress(&before), "merged work was lost: {resumed:#}");
    let status = wait_done(&url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], 48 * 48 * 512, "{status:#}");
    assert_eq!(progress(&status), 1.0, "{status:#}");
    assert_same_image(&one, &fetch_exr(&url, &id, 0), "after the coordinator restarted");
}

#[test]
fn bdpt_images_are_the_same_on_one_or_three_workers_and_after_a_kill() {
    // 9 tiles and the light tile, 4 tasks each (the light tasks of 2 light paths per pixel
    // sample); the kill job's light tasks are 48 x 48 x 256 light paths.
    same_image_on_any_workers_and_after_a_kill("bdpt", 40.0);
}

#[test]
fn sppm_images_are_the_same_on_one_or_three_workers_and_after_a_kill() {
    // One tile, the frame: 4 tasks of 16 passes; the kill job's tasks are 128 passes.
    same_image_on_any_workers_and_after_a_kill("sppm", 4.0);
}

/// Photon mapping under adaptive sampling (`target_rel_error`): its frame, one tile, stops once
/// its own estimate reaches the target, decided from merged passes only: the same bits on
/// `coordinator render --workers 2` and on serve + 3 worker processes, fewer passes than
/// planned, the estimate within the target.
#[test]
fn adaptive_photon_mapping_stops_at_its_target_with_the_same_bits_anywhere() {
    let dir = temp_dir("sppm-adaptive");
    let mut s = settings("sppm", 1024, 16);
    s["target_rel_error"] = json!(0.025);
    let local = render_reference(&dir, &s, 2);
    let cluster = Cluster::start(&dir, 3, &[]);
    let id = create_job(&cluster.url, &cluster.scene, &s, 0);
    let status = wait_done(&cluster.url, &id, TIMEOUT);
    assert_same_image(&local, &fetch_exr(&cluster.url, &id, 0), "render vs serve + 3 workers");
    let saved = status["samples_saved"].as_u64().unwrap();
    let done = status["samples_done"].as_u64().unwrap();
    println!("{} passes of 1024, estimated error {}", done / (48 * 48), status["est_rel_error"]);
    assert_eq!(done + saved, status["samples_planned"].as_u64().unwrap(), "{status:#}");
    assert!(saved > 0 && done >= 48 * 48 * 16, "{status:#}");
    assert!(status["est_rel_error"].as_f64().unwrap() <= 0.025, "{status:#}");
    assert_eq!(status["progress"], 1.0);
}

/// Bidirectional path tracing under adaptive sampling (`target_rel_error`): each camera tile
/// and the light tile stop on their own counts, decided from the pilot's image and each tile's
/// merged tasks only: the same bits on `coordinator render --workers 2` and on serve + 2 worker
/// processes whose coordinator is kill -9'd once a tile has stopped and restarted (the pilot
/// image comes back from its database); fewer samples than planned; the estimate within the
/// target and within 2x of the real error, against the path tracer's image at 4,096 spp.
#[test]
fn adaptive_bdpt_stops_its_tiles_with_the_same_bits_anywhere_and_a_calibrated_estimate() {
    let dir = temp_dir("bdpt-adaptive");
    let target = 0.02;
    let mut s = settings("bdpt", 1024, 16);
    s["target_rel_error"] = json!(target);
    let local = render_reference(&dir, &s, 2);
    let counts = sample_counts(&local);
    assert!(counts.iter().any(|&n| n != counts[0]), "adaptive sampling did not adapt");
    assert!(counts.iter().all(|&n| (16..1024).contains(&n)), "a tile ran to its end");

    let mut cluster = Cluster::start(&dir, 2, &["--lease-timeout", "2"]);
    let url = cluster.url.clone();
    let id = create_job(&url, &cluster.scene, &s, 0);
    let before = wait_for(&url, &id, TIMEOUT, |st| st["samples_saved"].as_u64() > Some(0));
    assert_eq!(before["state"], "running", "{before:#}");
    cluster.restart_coordinator(&["--lease-timeout", "2"]);
    let status = wait_done(&url, &id, TIMEOUT);
    assert_same_image(&local, &fetch_exr(&url, &id, 0), "serve + restart vs render");
    let saved = status["samples_saved"].as_u64().unwrap();
    let done = status["samples_done"].as_u64().unwrap();
    assert_eq!(done + saved, status["samples_planned"].as_u64().unwrap(), "{status:#}");
    assert_eq!(status["progress"], 1.0, "{status:#}");
    let estimate = status["est_rel_error"].as_f64().unwrap();
    assert!(estimate <= target, "{status:#}");

    let mut r = settings("path", 4096, 256);
    r["seed"] = json!(3);
    let real = rel_mse(&local, &render_reference(&dir, &r, 2));
    let ratio = real / (estimate * estimate);
    println!(
        "{:.1} spp on average; estimated relative error {estimate:.4}, real {:.4} \
         (squared ratio {ratio:.2})",
        done as f64 / (48.0 * 48.0),
        real.sqrt()
    );
    assert!(
        (0.5..2.0).contains(&ratio),
        "real relative MSE {real:.3e}, estimated {:.3e}",
        estimate * estimate
    );
}

#[test]
fn what_bdpt_and_sppm_do_not_take_is_refused_naming_the_setting() {
    let dir = temp_dir("integrator-refusals");
    let cluster = Cluster::start(&dir, 0, &[]);
    let url = &cluster.url;
    let job = |settings: Value| {
        post_json(
            &format!("{url}/api/v1/jobs"),
            &json!({"scene": cluster.scene, "settings": settings}),
        )
    };
    let unknown = job(json!({"integrator": "sppm-typo"}));
    assert!(
        unknown.error().contains("integrator") && unknown.error().contains("bdpt, sppm"),
        "{}",
        unknown.error()
    );
    // Photon mapping: parameters that cannot converge.
    for (sppm, key) in [
        (json!({"radius": 0}), "sppm.radius"),
        (json!({"radius": -0.5}), "sppm.radius"),
        (json!({"photons_per_pass": 0}), "sppm.photons_per_pass"),
        (json!({"alpha": 1.0}), "sppm.alpha"),
    ] {
        let bad = job(json!({"integrator": "sppm", "sppm": sppm}));
        assert_eq!(bad.status, 422, "{}", bad.error());
        assert!(bad.error().contains(key), "{key}: {}", bad.error());
    }
    // Bidirectional path tracing: no light-traced paths, or its keys on another integrator.
    for (settings, key) in [
        (json!({"integrator": "bdpt", "bdpt": {"light_paths": 0}}), "bdpt.light_paths"),
        (json!({"integrator": "path", "bdpt": {"light_paths": 4}}), "`bdpt`"),
    ] {
        let bad = job(settings);
        assert_eq!(bad.status, 422, "{}", bad.error());
        assert!(bad.error().contains(key), "{key}: {}", bad.error());
    }
    let jobs = get(&format!("{url}/api/v1/jobs")).json();
    assert_eq!(jobs["jobs"].as_array().map(Vec::len), Some(0), "{jobs:#}");
    // Scattering media (a subsurface sphere), once refused, are taken.
    let dir_scenes = repo().join("scenes/materials");
    let skin = common::bundle::Bundle::pack(&[
        ("subsurface.gltf".into(), std::fs::read(dir_scenes.join("subsurface.gltf")).unwrap()),
        ("materials.bin".into(), std::fs::read(dir_scenes.join("materials.bin")).unwrap()),
    ])
    .unwrap();
    let skin = upload(url, &skin);
    for integrator in ["bdpt", "sppm"] {
        let medium = post_json(
            &format!("{url}/api/v1/jobs"),
            &json!({"scene": skin, "settings": {"integrator": integrator}}),
        );
        assert!((200..300).contains(&medium.status), "{integrator}: {}", medium.error());
    }
}
