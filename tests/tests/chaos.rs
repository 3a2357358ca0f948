//! Chaos: three jobs run at once on `coordinator serve` with three `worker --join` processes
//! (real processes, loopback) while a seeded schedule kills workers (`kill -9`, or SIGTERM) and
//! the coordinator (`kill -9`, restarted on the same data folder) dozens of times. Every job
//! still finishes with the image of `coordinator render`, bit for bit, every sample counted
//! once.
//!
//! The schedule is a function of the seed: which event comes next, whom it hits, and the pause
//! before the coordinator comes back. Events fire at seeded fractions of the work done (not at
//! moments), so a fast machine sees as many of them as a slow one. The seed is printed;
//! `RENDERFARM_CHAOS_SEED=N cargo test --release -p tests --test chaos -- --nocapture` replays
//! a schedule.

use std::time::{Duration, Instant};

use serde_json::{json, Value};
use tests::*;

const TIMEOUT: Duration = Duration::from_secs(300);

/// How many events a run has.
const EVENTS: usize = 36;

/// SplitMix64: the schedule's random numbers.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n`.
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// One thing done to the farm.
#[derive(Clone, Copy, Debug)]
enum Event {
    /// `kill -9` worker `i` and start another in its place.
    KillWorker(usize),
    /// SIGTERM worker `i` (it finishes its task and leaves) and start another in its place.
    StopWorker(usize),
    /// `kill -9` the coordinator and start it again on its data after this many milliseconds.
    KillCoordinator(u64),
}

/// The schedule of a seed: each event with the fraction of all samples done that fires it.
fn schedule(seed: u64, workers: usize) -> Vec<(f64, Event)> {
    let mut rng = Rng(seed);
    let mut events: Vec<(f64, Event)> = (0..EVENTS)
        .map(|_| {
            // Events fire while 2%..92% of the work is done, so the last ones hit running jobs.
            let at = 0.02 + 0.9 * rng.below(1 << 20) as f64 / (1 << 20) as f64;
            let who = rng.below(workers as u64) as usize;
            let event = match rng.below(10) {
                0..=6 => Event::KillWorker(who),
                7 => Event::StopWorker(who),
                _ => Event::KillCoordinator(rng.below(400)),
            };
            (at, event)
        })
        .collect();
    events.sort_by(|a, b| a.0.total_cmp(&b.0));
    events
}

fn job_settings() -> Vec<(Value, i32)> {
    vec![
        (
            json!({"width": 64, "height": 64, "spp": 1024, "samples_per_task": 64,
                   "tile_size": 32, "max_depth": 16, "seed": 1}),
            0,
        ),
        (
            json!({"width": 48, "height": 48, "spp": 1024, "samples_per_task": 128,
                   "tile_size": 16, "max_depth": 8, "seed": 2}),
            0,
        ),
        (
            json!({"width": 64, "height": 32, "spp": 2048, "samples_per_task": 256,
                   "tile_size": 32, "max_depth": 16, "seed": 3}),
            1,
        ),
    ]
}

/// Samples of a job when it is done.
fn planned(settings: &Value) -> u64 {
    ["width", "height", "spp"].iter().map(|k| settings[k].as_u64().unwrap()).product()
}

/// Samples done by each job (`None` while the coordinator does not answer).
fn samples_done(url: &str, ids: &[String]) -> Option<Vec<u64>> {
    ids.iter()
        .map(|id| {
            let resp = ureq::get(&format!("{url}/api/v1/jobs/{id}")).call().ok()?;
            let status: Value = resp.into_json().ok()?;
            status["samples_done"].as_u64()
        })
        .collect()
}

#[test]
fn seeded_kills_of_workers_and_the_coordinator_change_no_image() {
    let seed: u64 = std::env::var("RENDERFARM_CHAOS_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20261205);
    eprintln!("chaos seed {seed} (RENDERFARM_CHAOS_SEED={seed} replays this schedule)");
    let dir = temp_dir("chaos");
    let jobs = job_settings();
    let references: Vec<Vec<u8>> = jobs.iter().map(|(s, _)| render_reference(&dir, s, 2)).collect();

    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let data = dir.join("data");
    // Kills expire leases over and over: no task may fail its job for that.
    let args = ["--lease-timeout", "1", "--max-task-expiries", "1000"];
    let mut coordinator = start_coordinator(&data, port, &args);
    let mut started = 0;
    let worker = |started: &mut usize| {
        *started += 1;
        start_worker(&url, 1, dir.join(format!("worker-{started}.log")))
    };
    let mut workers: Vec<Proc> = (0..3).map(|_| worker(&mut started)).collect();
    let scene = upload(&url, &cornell_zip());
    let ids: Vec<String> =
        jobs.iter().map(|(s, priority)| create_job(&url, &scene, s, *priority)).collect();
    let total: u64 = jobs.iter().map(|(s, _)| planned(s)).sum();

    let start = Instant::now();
    let mut log = Vec::new();
    for (at, event) in schedule(seed, workers.len()) {
        // Wait for the work to reach the event's fraction.
        loop {
            assert!(start.elapsed() < TIMEOUT, "seed {seed}: stuck before {event:?}: {log:#?}");
            if let Some(done) = samples_done(&url, &ids) {
                if done.iter().sum::<u64>() as f64 >= at * total as f64 {
                    break;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        match event {
            Event::KillWorker(i) => {
                workers[i].kill9();
                workers[i] = worker(&mut started);
            }
            Event::StopWorker(i) => {
                workers[i].terminate(Duration::from_secs(30));
                workers[i] = worker(&mut started);
            }
            Event::KillCoordinator(pause_ms) => {
                coordinator.kill9();
                std::thread::sleep(Duration::from_millis(pause_ms));
                coordinator = start_coordinator(&data, port, &args);
            }
        }
        log.push(format!(
            "{:6.2} s at {:4.1}%: {event:?}",
            start.elapsed().as_secs_f64(),
            at * 100.0
        ));
    }
    let states: Vec<Value> = ids.iter().map(|id| job_status(&url, id)).collect();
    let running = states.iter().filter(|s| s["state"] != "done").count();
    eprintln!(
        "{} events, {running} of 3 jobs still running after the last:\n{}",
        log.len(),
        log.join("\n")
    );
    assert!(running > 0, "seed {seed}: the jobs ended before the last event");

    for (((settings, _), id), reference) in jobs.iter().zip(&ids).zip(&references) {
        let status = wait_done(&url, id, TIMEOUT);
        assert_eq!(status["samples_done"].as_u64(), Some(planned(settings)), "seed {seed}");
        let image = fetch_exr(&url, id, 0);
        assert_same_image(reference, &image, &format!("seed {seed}: job {id} after the chaos"));
        let spp = settings["spp"].as_u64().unwrap() as u32;
        assert!(sample_counts(&image).iter().all(|&n| n == spp), "seed {seed}: a sample lost");
    }
    assert!(!coordinator.log_text().contains("panicked"), "{}", coordinator.log_text());
    eprintln!(
        "chaos seed {seed}: every image bit for bit in {:.1} s",
        start.elapsed().as_secs_f64()
    );
}
