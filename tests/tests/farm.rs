//! The farm as users run it: `coordinator serve` and `worker --join` as real processes on
//! loopback sockets. The image of a job is bitwise the image of `coordinator render` with the
//! same settings, whatever happens to workers and to the coordinator; bad results are refused
//! without anything being merged.

use std::time::Duration;

use common::{
    film::{Rect, TileAccum},
    protocol::{encode_result, TaskResult, TaskSpec},
};
use serde_json::{json, Value};
use tests::*;

const TIMEOUT: Duration = Duration::from_secs(240);

fn settings(spp: u32, spt: u32) -> Value {
    json!({
        "width": 64, "height": 64, "spp": spp, "samples_per_task": spt, "tile_size": 32,
        "max_depth": 16, "seed": 7
    })
}

#[test]
fn three_workers_give_the_image_of_coordinator_render() {
    let dir = temp_dir("three");
    let s = settings(128, 32);
    let reference = render_reference(&dir, &s, 2);
    let cluster = Cluster::start(&dir, 3, &[]);
    let url = cluster.url.clone();
    let id = create_job(&url, &cluster.scene, &s, 0);
    let status = wait_done(&url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], 64 * 64 * 128);
    assert_eq!(status["progress"], 1.0);
    let image = fetch_exr(&url, &id, 0);
    assert_same_image(&reference, &image, "serve + 3 workers vs render");
    assert!(sample_counts(&image).iter().all(|&n| n == 128));
    let workers = get(&format!("{url}/api/v1/workers")).json();
    assert_eq!(workers["workers"].as_array().unwrap().len(), 3, "{workers:#}");
    assert_eq!(metric(&url, "renderfarm_tasks_merged_total"), 4.0 * 4.0);
    // Each result is committed in a transaction of its own or with others queued meanwhile.
    let commits = metric(&url, "renderfarm_commits_total");
    assert!((1.0..=16.0).contains(&commits), "{commits} transactions for 16 merges");
    assert!(metric(&url, "renderfarm_commit_seconds_total") > 0.0);
}

#[test]
fn a_worker_killed_mid_task_loses_nothing() {
    let dir = temp_dir("kill-worker");
    let s = settings(512, 128);
    let reference = render_reference(&dir, &s, 2);
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &["--lease-timeout", "1"]);
    let mut victim = start_worker(&url, 1, dir.join("victim.log"));
    let _survivor = start_worker(&url, 1, dir.join("survivor.log"));
    let scene = upload(&url, &cornell_zip());
    let id = create_job(&url, &scene, &s, 0);
    // Both workers hold leases from the first moment on; kill one while it renders.
    wait_for(&url, &id, TIMEOUT, |st| st["tasks_in_flight"].as_u64() == Some(2));
    victim.kill9();
    let status = wait_done(&url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], 64 * 64 * 512);
    let image = fetch_exr(&url, &id, 0);
    assert_same_image(&reference, &image, "after a worker was killed");
    assert!(sample_counts(&image).iter().all(|&n| n == 512));
    assert!(
        metric(&url, "renderfarm_tasks_expired_total") >= 1.0,
        "the victim's lease never expired"
    );
}

#[test]
fn a_coordinator_killed_mid_job_resumes_and_counts_every_sample_once() {
    let dir = temp_dir("kill-coordinator");
    let s = settings(512, 32);
    let reference = render_reference(&dir, &s, 2);
    let mut cluster = Cluster::start(&dir, 2, &["--lease-timeout", "2"]);
    let url = cluster.url.clone();
    let id = create_job(&url, &cluster.scene, &s, 0);
    let planned = 64 * 64 * 512;
    let before =
        wait_for(&url, &id, TIMEOUT, |st| st["samples_done"].as_u64().unwrap() >= planned / 4);
    assert_eq!(before["state"], "running");
    cluster.restart_coordinator(&["--lease-timeout", "2"]);
    let resumed = job_status(&url, &id);
    assert!(
        resumed["samples_done"].as_u64().unwrap() >= before["samples_done"].as_u64().unwrap(),
        "merged samples were lost: {resumed:#}"
    );
    let status = wait_done(&url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], planned);
    let image = fetch_exr(&url, &id, 0);
    assert_same_image(&reference, &image, "after the coordinator restarted");
    assert!(sample_counts(&image).iter().all(|&n| n == 512), "a sample was lost or counted twice");
}

/// A result a worker could have sent for `spec`: every sample of every pixel has value `v`.
fn result_for(spec: &TaskSpec, v: f32) -> TaskResult {
    let mut tile = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                tile.add_sample(x, y, s, [v; 3]);
            }
        }
    }
    TaskResult { spec: *spec, tile, rays: 0, kernel: "path, scalar".into() }
}

#[test]
fn forged_stale_and_malformed_results_are_refused_and_nothing_is_merged() {
    let dir = temp_dir("bad-results");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let coordinator = start_coordinator(&dir.join("data"), port, &[]);
    let scene = upload(&url, &cornell_zip());
    let single =
        json!({"width": 32, "height": 32, "spp": 32, "samples_per_task": 32, "tile_size": 32});
    let job = create_job(&url, &scene, &single, 0);
    let join = |name: &str| {
        let a = post_json(&format!("{url}/api/v1/workers"), &json!({"name": name, "threads": 1}));
        assert_eq!(a.status, 201, "{}", a.error());
        a.json()["id"].as_str().unwrap().to_string()
    };
    let (w1, w2) = (join("w1"), join("w2"));
    let lease_for = |worker: &str| {
        post_json(&format!("{url}/api/v1/workers/{worker}/lease?wait_s=5"), &json!({})).json()
    };
    let grant = lease_for(&w1);
    let lease = grant["lease"].as_str().unwrap().to_string();
    let spec: TaskSpec = serde_json::from_value(grant["task"].clone()).unwrap();
    // A second job's task takes the honest and the duplicate result below, so that the first
    // job is rendered by a real worker in the end.
    let scratch = create_job(&url, &scene, &single, 1);
    let scratch_grant = lease_for(&w1);
    assert_eq!(scratch_grant["job"].as_str(), Some(scratch.as_str()));
    let scratch_lease = scratch_grant["lease"].as_str().unwrap().to_string();
    // Another job runs on a real worker meanwhile, undisturbed by what follows.
    let _worker = start_worker(&url, 1, dir.join("worker.log"));
    let other = create_job(&url, &scene, &settings(64, 32), 0);

    let result_url = format!("{url}/api/v1/leases/{lease}/result");
    let send = |worker: &str, content_type: &str, body: &[u8]| {
        post_bytes(&result_url, content_type, &[("x-worker-id", worker)], body)
    };
    let good = encode_result(&result_for(&spec, 0.5));

    let a = send(&w1, "application/octet-stream", &good[..good.len() / 2]);
    assert_eq!(
        (a.status, a.error().contains("undecodable")),
        (400, true),
        "truncated: {}",
        a.error()
    );

    let mut small = spec;
    small.rect = Rect { width: 16, ..spec.rect };
    let mut wrong_tile = result_for(&small, 0.5);
    wrong_tile.spec = spec;
    let a = send(&w1, "application/octet-stream", &encode_result(&wrong_tile));
    assert_eq!((a.status, a.error().contains("tile")), (422, true), "wrong tile: {}", a.error());

    let mut impossible = result_for(&spec, 0.5);
    impossible.tile.pixels[5].m2[1] = -1.0;
    let a = send(&w1, "application/octet-stream", &encode_result(&impossible));
    assert_eq!(a.status, 422, "impossible values: {}", a.error());
    assert!(a.error().contains("pixel (5, 0)") && a.error().contains("negative"), "{}", a.error());

    let mut not_a_number = result_for(&spec, 0.5);
    not_a_number.tile.pixels[0].mean[0] = f64::NAN;
    let a = send(&w1, "application/octet-stream", &encode_result(&not_a_number));
    assert_eq!((a.status, a.error().contains("not finite")), (422, true), "NaN: {}", a.error());

    // Radiance is never negative: a mean of -100 (consistent counts, finite, within every
    // other bound) is refused, naming the pixel and the value.
    let mut negative = result_for(&spec, 0.5);
    negative.tile.pixels[32 * 3 + 7].mean[2] = -100.0;
    let a = send(&w1, "application/octet-stream", &encode_result(&negative));
    assert_eq!(a.status, 422, "a negative mean: {}", a.error());
    assert!(
        a.error().contains("pixel (7, 3)") && a.error().contains("mean -100 is negative"),
        "{}",
        a.error()
    );

    let mut blinding = result_for(&spec, 0.5);
    blinding.tile.pixels[1].mean[0] = 1e15;
    let a = send(&w1, "application/octet-stream", &encode_result(&blinding));
    assert_eq!((a.status, a.error().contains("beyond")), (422, true), "{}", a.error());

    let mut short = result_for(&spec, 0.5);
    short.tile.pixels[3].n -= 1;
    let a = send(&w1, "application/octet-stream", &encode_result(&short));
    assert_eq!((a.status, a.error().contains("samples")), (422, true), "{}", a.error());

    let a = send(&w2, "application/octet-stream", &good);
    assert_eq!((a.status, a.error().contains("another worker")), (403, true), "{}", a.error());

    let a = send(&w1, "application/json", &good);
    assert_eq!(a.status, 415, "{}", a.error());

    // A result is read no further than its tile's sums can take (a 32x32 tile: 84 KiB).
    let mut padded = good.clone();
    padded.resize(good.len() + (1 << 20), 0);
    let a = send(&w1, "application/octet-stream", &padded);
    assert_eq!(a.status, 413, "{}", a.error());
    assert!(a.error().contains("84224 bytes a result for this lease can take"), "{}", a.error());

    let a = post_bytes(&result_url, "application/octet-stream", &[], &good);
    assert_eq!((a.status, a.error().contains("x-worker-id")), (400, true), "{}", a.error());

    let a = post_bytes(
        &format!("{url}/api/v1/leases/0123456789abcdef/result"),
        "application/octet-stream",
        &[("x-worker-id", &w1)],
        &good,
    );
    assert_eq!(a.status, 409, "{}", a.error());
    // A call on a lease that is not the caller's is refused as such, its body unread and
    // unkept, however large.
    let a = post_bytes(
        &format!("{url}/api/v1/leases/0123456789abcdef/result"),
        "application/octet-stream",
        &[("x-worker-id", &w1)],
        &vec![0; 32 << 20],
    );
    assert_eq!(a.status, 409, "{}", a.error());

    assert_eq!(job_status(&url, &job)["samples_done"], 0, "a refused result was merged");

    let scratch_spec: TaskSpec = serde_json::from_value(scratch_grant["task"].clone()).unwrap();
    let honest = encode_result(&result_for(&scratch_spec, 0.5));
    let scratch_url = format!("{url}/api/v1/leases/{scratch_lease}/result");
    let a = post_bytes(&scratch_url, "application/octet-stream", &[("x-worker-id", &w1)], &honest);
    assert_eq!(a.status, 200, "the honest result: {}", a.error());
    let a = post_bytes(&scratch_url, "application/octet-stream", &[("x-worker-id", &w1)], &honest);
    assert_eq!((a.status, a.error().contains("not live")), (409, true), "duplicate: {}", a.error());
    let done = job_status(&url, &scratch);
    assert_eq!(done["samples_done"], 32 * 32 * 32, "{done:#}");
    assert_eq!(done["state"], "done");
    assert_eq!(metric(&url, "renderfarm_results_refused_total"), 14.0);
    // Each refusal is logged with the worker, the lease and the reason.
    let log = coordinator.log_text();
    let line = log.lines().find(|l| l.contains("mean -100 is negative")).expect("no log line");
    assert!(line.contains("WARN") && line.contains(&w1) && line.contains(&lease), "{line}");
    let refusals = log.lines().filter(|l| l.contains("result refused")).count();
    assert_eq!(refusals, 14, "{log}");

    // The forger leaves (it may remove only itself); its lease goes back, and a real worker
    // renders the job: its image is bit for bit `coordinator render`'s, nothing forged in it.
    let leave = format!("{url}/api/v1/workers/{w1}");
    let a = delete_with(&leave, &[]);
    assert_eq!((a.status, a.error().contains("x-worker-id")), (400, true), "{}", a.error());
    let a = delete_with(&leave, &[("x-worker-id", &w2)]);
    assert_eq!((a.status, a.error().contains("only itself")), (403, true), "{}", a.error());
    let a = delete_with(&leave, &[("x-worker-id", &w1)]);
    assert_eq!(a.status, 200, "{}", a.error());
    let status = wait_done(&url, &job, TIMEOUT);
    assert_eq!(status["samples_done"], 32 * 32 * 32);
    let reference = render_reference(&dir, &single, 1);
    assert_same_image(&reference, &fetch_exr(&url, &job, 0), "after forged results");
    wait_done(&url, &other, TIMEOUT);
}

#[test]
fn bad_requests_get_a_json_error_naming_the_problem() {
    let dir = temp_dir("bad-requests");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator =
        start_coordinator(&dir.join("data"), port, &["--max-spp", "1024", "--max-upload-mib", "1"]);
    let scenes = format!("{url}/api/v1/scenes");
    let cases: Vec<(Answer, u16, &str)> = vec![
        (post_bytes(&scenes, "application/octet-stream", &[], b"GIF89a..."), 422, "not a scene"),
        (post_bytes(&scenes, "application/octet-stream", &[], b""), 422, "empty"),
        (post_bytes(&scenes, "text/plain", &[], b"{}"), 415, "text/plain"),
        (post_bytes(&scenes, "model/gltf-binary", &[], &cornell_zip()), 415, "zip"),
        (post_bytes(&scenes, "application/octet-stream", &[], &vec![b' '; 2 << 20]), 413, "limit"),
        (
            post_bytes(&scenes, "model/gltf+json", &[], br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"cornell-box.bin","byteLength":4}],"bufferViews":[{"buffer":0,"byteLength":4}],"accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC3"}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]}"#),
            422,
            "cornell-box.bin",
        ),
        (post_bytes(&scenes, "application/zip", &[], &cornell_zip()[..500]), 422, "zip"),
    ];
    for (a, status, needle) in cases {
        assert_eq!(a.status, status, "{}", a.error());
        assert!(a.error().contains(needle), "expected '{needle}' in '{}'", a.error());
    }
    let scene = upload(&url, &cornell_zip());
    assert_eq!(upload(&url, &cornell_zip()), scene, "the same bytes give the same hash");
    let jobs = format!("{url}/api/v1/jobs");
    let bad_jobs: Vec<(Value, u16, &str)> = vec![
        (json!({"scene": "ab".repeat(32), "settings": {}}), 404, "no scene"),
        (json!({"scene": scene, "settings": {"width": 0}}), 422, "width"),
        (json!({"scene": scene, "settings": {"width": 100000}}), 422, "width"),
        (json!({"scene": scene, "settings": {"spp": 5000}}), 422, "limit of 1024"),
        (json!({"scene": scene, "settings": {"sppp": 5}}), 422, "sppp"),
        (json!({"scene": scene, "settings": {"camera": "nope"}}), 422, "nope"),
        (json!({"scene": scene, "settings": {"environment": {"map": "sky.hdr"}}}), 422, "sky.hdr"),
        (
            json!({"scene": scene, "settings": {"spp": 1024, "samples_per_task": 1, "tile_size": 1}}),
            422,
            "tasks",
        ),
        (json!({"scene": scene, "priority": "high"}), 422, "priority"),
        (json!({"scene": scene, "name": 7}), 422, "name"),
        (json!({"scene": scene, "name": "x".repeat(201)}), 422, "over the limit of 200"),
        (json!({"scene": scene, "name": "two\nlines"}), 422, "control character"),
        (json!({"scene": scene, "name": "  "}), 422, "name: must not be empty"),
        (json!({"scene": scene, "name": "one\u{2028}two"}), 422, "U+2028"),
        (json!({"scene": scene, "name": "abc\u{202E}fdp.exe"}), 422, "U+202E"),
        (
            json!({"scene": scene, "settings": {"frames": {"start": 0, "end": 72057594037927935i64}}}),
            422,
            "frames",
        ),
    ];
    for (body, status, needle) in bad_jobs {
        let a = post_json(&jobs, &body);
        assert_eq!(a.status, status, "{body}: {}", a.error());
        assert!(a.error().contains(needle), "{body}: expected '{needle}' in '{}'", a.error());
    }
    let a = post_bytes(&jobs, "application/json", &[], b"{\"scene\": ");
    assert_eq!(a.status, 422, "{}", a.error());
    let a = post_bytes(&jobs, "text/plain", &[], b"{}");
    assert_eq!(a.status, 415, "{}", a.error());
    for (path, status) in [
        ("/api/v1/jobs/nope", 404),
        ("/api/v1/jobs/nope/frames/0.exr", 404),
        ("/api/v1/scenes/nope", 404),
        ("/api/v1/nothing", 404),
    ] {
        let a = get(&format!("{url}{path}"));
        assert_eq!(a.status, status, "{path}");
        assert!(!a.error().is_empty(), "{path}: no JSON error");
    }
    let a = delete(&format!("{url}/api/v1/jobs/nope"));
    assert_eq!((a.status, a.error().is_empty()), (404, false));
    let a = delete(&format!("{url}/api/v1/scenes"));
    assert_eq!((a.status, a.error().is_empty()), (405, false));
    let a = post_json(&format!("{url}/api/v1/workers/nope/lease"), &json!({}));
    assert_eq!((a.status, a.error().contains("join again")), (404, true));
    let a = post_json(&format!("{url}/api/v1/workers"), &json!({"name": "x", "threads": 0}));
    assert_eq!(a.status, 422);
    // The service is still healthy and serves its documents.
    assert_eq!(get(&format!("{url}/healthz")).status, 200);
    let api = get(&format!("{url}/api/v1/openapi.json")).json();
    assert_eq!(api["openapi"], "3.0.3");
    for path in ["/api/v1/jobs", "/api/v1/leases/{lease}/result", "/api/v1/workers/{id}/lease"] {
        assert!(api["paths"][path].is_object(), "{path} is not documented");
    }
    let page = String::from_utf8(get(&url).body).unwrap();
    assert!(page.contains("jobs-table"));
}

#[test]
fn workers_join_and_leave_mid_job_and_priorities_are_honoured() {
    let dir = temp_dir("join-leave");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &[]);
    let scene = upload(&url, &cornell_zip());
    let low = create_job(&url, &scene, &settings(256, 32), 0);
    let high = create_job(&url, &scene, &settings(256, 32), 5);
    let mut first = start_worker(&url, 1, dir.join("first.log"));
    wait_for(&url, &high, TIMEOUT, |s| s["samples_done"].as_u64().unwrap() > 0);
    assert_eq!(job_status(&url, &low)["samples_done"], 0, "the low-priority job ran first");
    let _second = start_worker(&url, 1, dir.join("second.log"));
    wait_for(&url, &high, TIMEOUT, |s| s["progress"].as_f64().unwrap() > 0.5);
    assert!(
        first.terminate(Duration::from_secs(60)),
        "SIGTERM: the worker did not leave cleanly:\n{}",
        first.log_text()
    );
    assert!(first.log_text().contains("left the farm"));
    let names: Vec<Value> =
        get(&format!("{url}/api/v1/workers")).json()["workers"].as_array().unwrap().clone();
    assert_eq!(names.len(), 1, "the worker that left is still listed: {names:?}");
    wait_done(&url, &high, TIMEOUT);
    let low_then = job_status(&url, &low);
    assert_ne!(low_then["state"], "done", "the low-priority job finished first");
    wait_done(&url, &low, TIMEOUT);
    assert_eq!(
        metric(&url, "renderfarm_tasks_expired_total"),
        0.0,
        "a clean leave let a lease expire"
    );
}

#[test]
fn heartbeats_keep_long_tasks_alive_and_time_limits_stop_jobs() {
    let dir = temp_dir("heartbeat");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &["--lease-timeout", "0.5"]);
    let _worker = start_worker(&url, 1, dir.join("worker.log"));
    let scene = upload(&url, &cornell_zip());
    // One task of about two seconds, four times the lease timeout.
    let long =
        json!({"width": 32, "height": 32, "spp": 2048, "samples_per_task": 2048, "tile_size": 32});
    let id = create_job(&url, &scene, &long, 0);
    let status = wait_done(&url, &id, TIMEOUT);
    assert_eq!(status["samples_done"], 32 * 32 * 2048);
    assert_eq!(
        metric(&url, "renderfarm_tasks_expired_total"),
        0.0,
        "a heartbeat-renewed lease expired"
    );
    // A time limit ends a job that asks for far more samples than it can take in that time.
    let limited = json!({"width": 64, "height": 64, "spp": 65536, "samples_per_task": 16, "time_limit_s": 1.0});
    let id = create_job(&url, &scene, &limited, 0);
    let status = wait_done(&url, &id, TIMEOUT);
    let done = status["samples_done"].as_u64().unwrap();
    assert!(done > 0 && done < status["samples_planned"].as_u64().unwrap(), "{status:#}");
    assert!(status["elapsed_s"].as_f64().unwrap() < 30.0, "{status:#}");
    let image = fetch_exr(&url, &id, 0);
    assert!(sample_counts(&image).iter().all(|&n| n > 0 && n % 16 == 0), "whole tasks only");
}

#[test]
fn a_task_leased_ahead_is_renewed_while_it_waits() {
    let dir = temp_dir("prefetch");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &["--lease-timeout", "0.5"]);
    // Every task after the first is leased while the one before renders, and waits for it
    // (about a second, twice the lease timeout) on heartbeats alone.
    let _worker = start_worker_with(&url, 1, dir.join("worker.log"), &["--prefetch-below", "3600"]);
    let scene = upload(&url, &cornell_zip());
    let s =
        json!({"width": 64, "height": 32, "spp": 2048, "samples_per_task": 1024, "tile_size": 32});
    let id = create_job(&url, &scene, &s, 0);
    let most_held = std::cell::Cell::new(0);
    let status = wait_for(&url, &id, TIMEOUT, |status| {
        for w in get(&format!("{url}/api/v1/workers")).json()["workers"].as_array().unwrap() {
            most_held.set(most_held.get().max(w["leases"].as_u64().unwrap()));
        }
        matches!(status["state"].as_str(), Some("done" | "failed" | "cancelled"))
    });
    assert_eq!(status["state"], "done", "{status:#}");
    assert_eq!(status["samples_done"], 64 * 32 * 2048);
    // One rendering and one leased ahead, plus up to two finished ones whose results are still
    // on their way (one being sent, one queued behind it).
    let most = most_held.get();
    assert!((2..=4).contains(&most), "the worker held {most} leases at once");
    assert_eq!(metric(&url, "renderfarm_tasks_expired_total"), 0.0, "a waiting lease expired");
    assert_eq!(metric(&url, "renderfarm_tasks_merged_total"), 4.0);
}

#[test]
fn a_task_that_keeps_failing_fails_its_job_with_the_reason() {
    let dir = temp_dir("failing");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &[]);
    let scene = upload(&url, &cornell_zip());
    let s = json!({"width": 32, "height": 32, "spp": 64, "samples_per_task": 32});
    let id = create_job(&url, &scene, &s, 0);
    let a = post_json(&format!("{url}/api/v1/workers"), &json!({"name": "flaky", "threads": 1}));
    let worker = a.json()["id"].as_str().unwrap().to_string();
    for attempt in 1..=3 {
        let grant =
            post_json(&format!("{url}/api/v1/workers/{worker}/lease?wait_s=5"), &json!({})).json();
        assert_eq!(
            grant["task"]["samples"]["start"], 0,
            "attempt {attempt}: the failed task is retried first"
        );
        let lease = grant["lease"].as_str().unwrap();
        let a = post_bytes(
            &format!("{url}/api/v1/leases/{lease}/fail"),
            "application/json",
            &[("x-worker-id", &worker)],
            json!({"error": "out of memory building the BVH"}).to_string().as_bytes(),
        );
        assert_eq!(a.status, 200, "{}", a.error());
    }
    let status = job_status(&url, &id);
    assert_eq!(status["state"], "failed", "{status:#}");
    let error = status["error"].as_str().unwrap();
    assert!(
        error.contains("failed 3 times") && error.contains("out of memory building the BVH"),
        "{error}"
    );
    // Its other task is not handed out any more.
    let a = post_json(&format!("{url}/api/v1/workers/{worker}/lease?wait_s=0"), &json!({}));
    assert_eq!(a.status, 204);
    // The worker's health says so.
    let listed = get(&format!("{url}/api/v1/workers")).json();
    let flaky = &listed["workers"][0];
    assert_eq!(
        (flaky["tasks_failed"].as_u64(), flaky["leases_expired"].as_u64()),
        (Some(3), Some(0))
    );
    assert_eq!(flaky["last_error"], "out of memory building the BVH", "{listed:#}");
}

#[test]
fn tokens_guard_the_worker_protocol_and_the_user_api() {
    let dir = temp_dir("tokens");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let coordinator = start_coordinator(
        &dir.join("data"),
        port,
        &["--token", "join-secret", "--api-token", "api-secret"],
    );
    let worker = |token: Option<&str>| {
        let mut cmd = std::process::Command::new(bin_dir().join("worker"));
        cmd.args(["--join", &url, "--wait", "1"]).env_remove("RENDERFARM_TOKEN");
        if let Some(t) = token {
            cmd.env("RENDERFARM_TOKEN", t);
        }
        cmd.output().unwrap()
    };
    let wrong = worker(Some("guess"));
    assert!(!wrong.status.success());
    assert!(String::from_utf8_lossy(&wrong.stderr).contains("join token refused"), "{wrong:?}");
    let missing = worker(None);
    assert!(!missing.status.success());
    assert!(String::from_utf8_lossy(&missing.stderr).contains("needs a join token"), "{missing:?}");
    let jobs = format!("{url}/api/v1/jobs");
    assert_eq!(get(&jobs).status, 401);
    let a = post_bytes(&jobs, "application/json", &[("authorization", "Bearer nope")], b"{}");
    assert_eq!((a.status, a.error().contains("API token")), (401, true), "{}", a.error());
    let a = post_json(&format!("{url}/api/v1/workers"), &json!({"name": "x", "threads": 1}));
    assert_eq!(a.status, 401, "a worker joined without the token");
    assert_eq!(get(&format!("{url}/healthz")).status, 200, "health stays open");
    // With the right tokens everything works: a worker joins and a job is rendered.
    let mut good = std::process::Command::new(bin_dir().join("worker"));
    good.args(["--join", &url, "--token", "join-secret", "--wait", "1"]);
    let log = std::fs::File::create(dir.join("worker.log")).unwrap();
    let mut child = good.stderr(log).spawn().unwrap();
    let api = [("authorization", "Bearer api-secret")];
    let a = post_bytes(&format!("{url}/api/v1/scenes"), "application/zip", &api, &cornell_zip());
    assert_eq!(a.status, 201, "{}", a.error());
    let scene = a.json()["scene"].as_str().unwrap().to_string();
    let body = json!({"scene": scene, "settings": {"width": 32, "height": 32, "spp": 8}});
    let a = post_bytes(&jobs, "application/json", &api, body.to_string().as_bytes());
    assert_eq!(a.status, 201, "{}", a.error());
    let id = a.json()["id"].as_str().unwrap().to_string();
    let end = std::time::Instant::now() + TIMEOUT;
    loop {
        let resp = ureq::get(&format!("{jobs}/{id}"))
            .set("authorization", "Bearer api-secret")
            .call()
            .unwrap();
        let status: Value = resp.into_json().unwrap();
        if status["state"] == "done" {
            break;
        }
        assert!(std::time::Instant::now() < end, "{status:#}");
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = child.kill();
    let _ = child.wait();

    // A worker removes only itself (join token, its id in x-worker-id); an operator with the
    // API token removes any worker.
    let join_auth = ("authorization", "Bearer join-secret");
    let join = |name: &str| {
        let body = json!({"name": name, "threads": 1}).to_string();
        let a = post_bytes(
            &format!("{url}/api/v1/workers"),
            "application/json",
            &[join_auth],
            body.as_bytes(),
        );
        assert_eq!(a.status, 201, "{}", a.error());
        a.json()["id"].as_str().unwrap().to_string()
    };
    let (a_id, b_id) = (join("a"), join("b"));
    let (a_url, b_url) =
        (format!("{url}/api/v1/workers/{a_id}"), format!("{url}/api/v1/workers/{b_id}"));
    let a = delete_with(&a_url, &[join_auth, ("x-worker-id", &b_id)]);
    assert_eq!((a.status, a.error().contains("only itself")), (403, true), "{}", a.error());
    let a = delete_with(&a_url, &[join_auth]);
    assert_eq!((a.status, a.error().contains("x-worker-id")), (400, true), "{}", a.error());
    let a = delete_with(&b_url, &[("x-worker-id", &b_id)]);
    assert_eq!(a.status, 401, "{}", a.error());
    let a = delete_with(&a_url, &[api[0]]);
    assert_eq!(a.status, 200, "the operator: {}", a.error());
    let a = delete_with(&b_url, &[join_auth, ("x-worker-id", &b_id)]);
    assert_eq!(a.status, 200, "the worker itself: {}", a.error());
    let listed = ureq::get(&format!("{url}/api/v1/workers"))
        .set("authorization", "Bearer api-secret")
        .call()
        .unwrap()
        .into_json::<Value>()
        .unwrap();
    let ids: Vec<&str> =
        listed["workers"].as_array().unwrap().iter().filter_map(|w| w["id"].as_str()).collect();
    assert!(!ids.contains(&a_id.as_str()) && !ids.contains(&b_id.as_str()), "{listed:#}");

    // A client guessing tokens in a loop: every try is counted by status on /metrics, and the
    // log holds at most 20 lines of refusals in 10 s, each naming the request and the reason.
    let before = metric(&url, "renderfarm_requests_refused_total{status=\"401\"}");
    for i in 0..100 {
        let a = ureq::get(&format!("{url}/api/v1/jobs"))
            .set("authorization", &format!("Bearer guess-{i}"))
            .call();
        assert!(matches!(a, Err(ureq::Error::Status(401, _))));
    }
    let after = metric(&url, "renderfarm_requests_refused_total{status=\"401\"}");
    assert_eq!(after - before, 100.0);
    let log = coordinator.log_text();
    let lines: Vec<&str> =
        log.lines().filter(|l| l.contains("WARN") && l.contains("refused")).collect();
    assert!(
        lines.iter().any(|l| l.contains("GET") && l.contains("/api/v1/jobs") && l.contains("401")),
        "{log}"
    );
    assert!(lines.len() <= 20, "{} lines of refusals in a few seconds:\n{log}", lines.len());
}

#[test]
fn without_a_token_the_coordinator_serves_loopback_only_and_says_so() {
    let dir = temp_dir("no-token");
    let port = free_port();
    let mut cmd = std::process::Command::new(bin_dir().join("coordinator"));
    cmd.args(["serve", "--listen", &format!("0.0.0.0:{port}"), "--data"]).arg(dir.join("data"));
    cmd.env_remove("RENDERFARM_TOKEN").env_remove("RENDERFARM_API_TOKEN");
    let log = dir.join("coordinator.log");
    cmd.stderr(std::fs::File::create(&log).unwrap());
    let mut child = cmd.spawn().unwrap();
    let url = format!("http://127.0.0.1:{port}/healthz");
    let end = std::time::Instant::now() + Duration::from_secs(20);
    while ureq::get(&url).call().is_err() {
        assert!(std::time::Instant::now() < end, "{}", std::fs::read_to_string(&log).unwrap());
        std::thread::sleep(Duration::from_millis(50));
    }
    let text = std::fs::read_to_string(&log).unwrap();
    // Another interface of this machine, if it has one, must not answer.
    let other = std::process::Command::new("hostname").arg("-I").output().ok().and_then(|o| {
        String::from_utf8_lossy(&o.stdout)
            .split_whitespace()
            .find(|a| !a.starts_with("127.") && !a.contains(':'))
            .map(str::to_string)
    });
    let reached_elsewhere =
        other.map(|ip| ureq::get(&format!("http://{ip}:{port}/healthz")).call().is_ok());
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        text.contains(&format!("listening on 127.0.0.1:{port} only, not 0.0.0.0:{port}")),
        "{text}"
    );
    assert_ne!(reached_elsewhere, Some(true), "answered on a non-loopback address");
}

#[test]
fn jobs_are_listed_by_pages_cancelled_and_removed_for_good() {
    let dir = temp_dir("job-list");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let data = dir.join("data");
    let mut coordinator = start_coordinator(&data, port, &[]);
    let scene = upload(&url, &cornell_zip());
    // No worker: every job stays queued until it is cancelled.
    let animation =
        json!({"width": 16, "height": 16, "spp": 4, "frames": {"start": 5, "end": 104}});
    let jobs = format!("{url}/api/v1/jobs");
    // The second job has a name (any text on one line): its status and the list show it, and
    // it survives a restart (below).
    let name = "lobby, take 3 · ünïcode";
    let create = |k: usize| {
        if k != 1 {
            return create_job(&url, &scene, &animation, 0);
        }
        let a = post_json(&jobs, &json!({"scene": scene, "settings": animation, "name": name}));
        assert_eq!((a.status, a.json()["name"].as_str()), (201, Some(name)), "{}", a.error());
        a.json()["id"].as_str().unwrap().to_string()
    };
    let ids: Vec<String> = (0..3).map(create).collect();
    assert_eq!(job_status(&url, &ids[1])["name"], name);
    assert_eq!(job_status(&url, &ids[0])["name"], Value::Null, "a job without a name");
    let listed = |query: &str| {
        let a = get(&format!("{jobs}{query}"));
        assert_eq!(a.status, 200, "{query}: {}", a.error());
        let page = a.json();
        let ids: Vec<String> = page["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j["id"].as_str().unwrap().to_string())
            .collect();
        (ids, page)
    };
    let (all, page) = listed("");
    assert_eq!((all, page["next"].clone()), (ids.clone(), Value::Null));
    // A list item is compact: no per-frame lists, the frame count instead.
    let item = &page["jobs"][0];
    assert_eq!((item["frame_count"].as_u64(), item["first_frame"].as_i64()), (Some(100), Some(5)));
    assert!(item.get("frame_progress").is_none() && item.get("frames").is_none(), "{item:#}");
    assert_eq!(item["scene"], scene.as_str());
    assert_eq!((&page["jobs"][0]["name"], &page["jobs"][1]["name"]), (&Value::Null, &json!(name)));

    let (first, page) = listed("?limit=2");
    assert_eq!(first, ids[..2]);
    let next = page["next"].as_str().expect("a cursor to the next page").to_string();
    let (rest, page) = listed(&format!("?limit=2&after={next}"));
    assert_eq!((rest, page["next"].clone()), (ids[2..].to_vec(), Value::Null));
    let (newest, _) = listed("?order=newest&limit=1");
    assert_eq!(newest, ids[2..]);
    for (query, needle) in [
        ("?limit=0", "limit"),
        ("?limit=1001", "limit"),
        ("?state=sleeping", "sleeping"),
        ("?order=random", "order"),
        ("?after=x", "after"),
        ("?colour=red", "colour"),
    ] {
        let a = get(&format!("{jobs}{query}"));
        assert_eq!((a.status, a.error().contains(needle)), (400, true), "{query}: {}", a.error());
    }

    // Cancel: POST .../cancel, or DELETE as before.
    let a = post_json(&format!("{jobs}/{}/cancel", ids[0]), &json!({}));
    assert_eq!((a.status, a.json()["state"].as_str()), (200, Some("cancelled")), "{}", a.error());
    let a = delete(&format!("{jobs}/{}", ids[1]));
    assert_eq!((a.status, a.json()["state"].as_str()), (200, Some("cancelled")), "{}", a.error());
    let a = delete(&format!("{jobs}/{}", ids[1]));
    assert_eq!(a.status, 409, "{}", a.error());
    let (cancelled, _) = listed("?state=cancelled");
    assert_eq!(cancelled, ids[..2]);
    let (active, _) = listed("?state=queued,running");
    assert_eq!(active, ids[2..]);

    // Purge: a finished job and a queued one, both gone for good.
    let a = delete(&format!("{jobs}/{}?purge=yes", ids[0]));
    assert_eq!(a.status, 400, "{}", a.error());
    for id in [&ids[0], &ids[2]] {
        let a = delete(&format!("{jobs}/{id}?purge=true"));
        assert_eq!((a.status, a.json()["removed"].as_str()), (200, Some(id.as_str())));
        assert_eq!(get(&format!("{jobs}/{id}")).status, 404);
        assert_eq!(get(&format!("{jobs}/{id}/frames/5.exr")).status, 404);
    }
    let a = delete(&format!("{jobs}/{}?purge=true", ids[0]));
    assert_eq!(a.status, 404, "{}", a.error());
    coordinator.kill9();
    let _coordinator = start_coordinator(&data, port, &[]);
    let (left, _) = listed("");
    assert_eq!(left, ids[1..2], "a removed job came back after a restart");
    assert_eq!(job_status(&url, &ids[1])["name"], name, "the name is kept");
    // The scene stays for other jobs.
    create_job(&url, &scene, &animation, 0);
}

#[test]
fn finished_jobs_are_removed_after_the_retention_time() {
    let dir = temp_dir("retention");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator =
        start_coordinator(&dir.join("data"), port, &["--retain-finished-hours", "0"]);
    let scene = upload(&url, &cornell_zip());
    let kept = create_job(&url, &scene, &settings(8, 8), 0);
    let gone = create_job(&url, &scene, &settings(8, 8), 0);
    let a = post_json(&format!("{url}/api/v1/jobs/{gone}/cancel"), &json!({}));
    assert_eq!(a.status, 200, "{}", a.error());
    // A retention of zero hours: the next tick removes it.
    let end = std::time::Instant::now() + TIMEOUT;
    while get(&format!("{url}/api/v1/jobs/{gone}")).status != 404 {
        assert!(std::time::Instant::now() < end, "the finished job was never removed");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(job_status(&url, &kept)["state"], "queued", "a job that waits was removed");
    assert_eq!(metric(&url, "renderfarm_jobs_removed_total"), 1.0);
}

/// What the dashboard's frame view reads: each tile's samples and estimated error, the job's
/// error against time, and previews at an exposure and through a tone map (bad ones refused,
/// naming what is allowed).
#[test]
fn a_frame_shows_its_tiles_its_error_history_and_tone_mapped_previews() {
    let farm = Cluster::start(&temp_dir("frame-view"), 1, &[]);
    let (url, scene) = (&farm.url, &farm.scene);
    let s = json!({"width": 32, "height": 24, "tile_size": 16, "spp": 16, "samples_per_task": 4,
                   "frames": {"start": 0, "end": 1, "fps": 24}});
    let id = create_job(&url, &scene, &s, 0);
    let status = wait_done(&url, &id, Duration::from_secs(120));

    let tiles = get(&format!("{url}/api/v1/jobs/{id}/frames/1/tiles"));
    assert_eq!(tiles.status, 200, "{}", tiles.error());
    let map = tiles.json();
    assert_eq!((map["frame"].as_i64(), map["width"].as_u64()), (Some(1), Some(32)));
    let tiles = map["tiles"].as_array().unwrap();
    // 2 x 2 tiles, the lower ones 8 rows high.
    let rects: Vec<[u64; 4]> = tiles
        .iter()
        .map(|t| ["x", "y", "width", "height"].map(|k| t[k].as_u64().unwrap()))
        .collect();
    assert_eq!(rects, [[0, 0, 16, 16], [16, 0, 16, 16], [0, 16, 16, 8], [16, 16, 16, 8]]);
    for t in tiles {
        assert_eq!((t["samples"].as_u64(), t["tasks_done"].as_u64()), (Some(16), Some(4)), "{t}");
        assert_eq!((t["tasks"].as_u64(), t["complete"].as_bool()), (Some(4), Some(true)), "{t}");
        let err = t["est_rel_error"].as_f64().expect("an error estimate");
        assert!(err > 0.0 && err < 1.0, "{t}");
    }
    for bad in ["2", "x"] {
        assert_eq!(get(&format!("{url}/api/v1/jobs/{id}/frames/{bad}/tiles")).status, 404);
    }

    let history = status["history"].as_array().unwrap();
    assert!(history.len() >= 2, "{history:?}");
    let last = history.last().unwrap();
    assert_eq!(last["samples_done"], status["samples_done"]);
    assert_eq!(last["est_rel_error"], status["est_rel_error"]);
    let times: Vec<f64> = history.iter().map(|p| p["elapsed_s"].as_f64().unwrap()).collect();
    assert!(times.windows(2).all(|w| w[0] < w[1]), "{times:?}");

    let png = |q: &str| get(&format!("{url}/api/v1/jobs/{id}/frames/0.png{q}"));
    let plain = png("");
    assert_eq!(plain.status, 200);
    assert_eq!(png("?exposure=0&tonemap=clamp&v=7").body, plain.body);
    for other in
        ["?exposure=1.5", "?tonemap=reinhard", "?tonemap=aces", "?exposure=-2&tonemap=aces"]
    {
        let a = png(other);
        assert_eq!(a.status, 200, "{other}: {}", a.error());
        assert_ne!(a.body, plain.body, "{other} changed nothing");
    }
    let bad = png("?tonemap=filmic");
    assert_eq!(bad.status, 400);
    assert!(bad.error().contains("clamp, reinhard, aces"), "{}", bad.error());
    let bad = png("?exposure=99");
    assert_eq!(bad.status, 400);
    assert!(bad.error().contains("exposure"), "{}", bad.error());
}
