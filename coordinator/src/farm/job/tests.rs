//! A job's scheduling, merging and ending, without a farm around it.

use super::*;

/// Every test runs at one moment except where time matters.
const NOW: Moment = Moment::ZERO;

fn job(spp: u32, spt: u32, target: Option<f64>) -> Job {
    let settings = RenderSettings {
        width: 64,
        height: 32,
        tile_size: 32,
        spp,
        samples_per_task: spt,
        target_rel_error: target,
        ..Default::default()
    };
    Job::new("j".into(), 0, "s".into(), settings, 0, 0.0).unwrap()
}

fn fake_result(job: &Job, key: TaskKey, value: f32) -> TileAccum {
    let spec = job.spec(key);
    let mut acc = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                acc.add_sample(x, y, s, [value; 3]);
            }
        }
    }
    acc
}

#[test]
fn tasks_are_issued_progressively_and_complete_the_job() {
    let mut j = job(100, 32, None);
    let mut order = Vec::new();
    while let Some(key) = j.next_task() {
        j.lease(key, NOW);
        order.push(key);
    }
    assert_eq!(order.len(), 2 * 4);
    assert!(order.windows(2).all(|w| w[0].k <= w[1].k), "progressive order: {order:?}");
    for key in order {
        let r = fake_result(&j, key, 0.5);
        let n = r.pixels.iter().map(|p| p.n as u64).sum();
        j.merge(key, r, n, NOW);
    }
    assert_eq!(j.state, JobState::Done);
    assert_eq!(j.samples_done, 64 * 32 * 100);
    assert!(j.film(0).pixels.iter().all(|p| p.n == 100));
}

/// A bidirectional job's light tile has `bdpt.light_paths` samples per pixel sample, in as many
/// tasks as a camera tile (each of that many times the samples, so that the frame-sized sums
/// light tasks return do not multiply): every one is issued, the camera samples alone count as
/// pixel samples, the progress counts the light tile's work too, a restart restores both counts
/// as they were, and the frame's image adds the light tile's mean (over its own samples) to each
/// camera tile's.
#[test]
fn a_light_tile_takes_its_light_paths_in_longer_tasks() {
    let settings = RenderSettings {
        width: 64,
        height: 32,
        tile_size: 32,
        spp: 100,
        samples_per_task: 32,
        integrator: Integrator::Bdpt,
        bdpt: Some(common::settings::Bdpt { light_paths: 3 }),
        ..Default::default()
    };
    let mut j = Job::new("j".into(), 0, "s".into(), settings.clone(), 0, 0.0).unwrap();
    let light = j.light_tile().expect("a light tile");
    let mut keys = Vec::new();
    while let Some(key) = j.next_task() {
        j.lease(key, NOW);
        keys.push(key);
    }
    // 2 camera tiles and the light tile, 4 tasks each.
    assert_eq!(keys.len(), 3 * 4, "{keys:?}");
    let light_ranges: Vec<_> =
        keys.iter().filter(|k| k.tile as usize == light).map(|&k| j.spec(k).samples).collect();
    assert_eq!(
        light_ranges,
        [(0, 96), (96, 192), (192, 288), (288, 300)].map(|(start, end)| SampleRange { start, end })
    );
    assert!(keys
        .iter()
        .all(|&k| (k.tile as usize == light) == (j.spec(k).kind == TaskKind::Light)));
    let (camera, lights): (Vec<_>, Vec<_>) =
        keys.into_iter().partition(|k| k.tile as usize != light);
    for key in camera {
        let r = fake_result(&j, key, 0.5);
        let n = r.pixels.iter().map(|p| p.n as u64).sum();
        j.merge(key, r, n, NOW);
    }
    // The camera's pixel samples are a quarter of the work (one light sample a pixel sample
    // to each of 3 light paths).
    let progress = j.status(NOW).progress;
    assert!((progress - 0.25).abs() < 1e-12, "{progress}");
    let mut results = Vec::new();
    for key in lights {
        let r = fake_result(&j, key, 0.25);
        let n = r.pixels.iter().map(|p| p.n as u64).sum();
        results.push((key.k, r.clone()));
        j.merge(key, r, n, NOW);
    }
    assert_eq!(j.state, JobState::Done);
    assert_eq!(j.samples_done, 64 * 32 * 100, "camera samples only");
    assert_eq!(j.light_samples_done, 64 * 32 * 300);
    assert_eq!(j.status(NOW).progress, 1.0);
    let film = j.film(0);
    assert!(film.pixels.iter().all(|p| p.n == 100 && (p.mean()[0] - 0.75).abs() < 1e-12));
    // A restart: the light tile's samples restored count as its work, not as pixel samples.
    let mut again = Job::new("j".into(), 0, "s".into(), settings, 0, 0.0).unwrap();
    again.restore_tile(0, light as u32, 0, None, results).unwrap();
    assert_eq!((again.samples_done, again.light_samples_done), (0, 64 * 32 * 300));
}

#[test]
fn released_tasks_are_leased_again() {
    let mut j = job(64, 32, None);
    let a = j.next_task().unwrap();
    j.lease(a, NOW);
    j.give_back(a, NOW);
    assert_eq!(j.next_task(), Some(a));
    assert_eq!(j.in_flight, 0);
}

#[test]
fn adaptive_stops_converged_tiles_from_merged_data_only() {
    // A constant image has zero estimated error: every tile stops at the minimum.
    let mut j = job(256, 8, Some(0.01));
    let mut leased = Vec::new();
    while let Some(key) = j.next_task() {
        j.lease(key, NOW);
        leased.push(key);
    }
    // Without merged data only the first MIN_ADAPTIVE_SAMPLES are issued.
    assert_eq!(leased.len(), 2 * 2);
    for key in leased {
        let r = fake_result(&j, key, 0.25);
        let n = r.pixels.iter().map(|p| p.n as u64).sum();
        j.merge(key, r, n, NOW);
    }
    assert_eq!(j.state, JobState::Done);
    let status = j.status(NOW);
    assert_eq!(status.samples_saved, 64 * 32 * (256 - 16));
    assert_eq!(status.progress, 1.0);
}

#[test]
fn results_in_any_order_give_the_same_bits() {
    let run = |order: &[usize]| {
        let mut j = job(96, 32, None);
        let mut keys = Vec::new();
        while let Some(key) = j.next_task() {
            j.lease(key, NOW);
            keys.push(key);
        }
        for &i in order {
            let key = keys[i];
            // Values that differ per task so that the order of addition shows in the bits.
            let r = fake_result(&j, key, 0.1 + 0.37 * key.k as f32 + 0.011 * key.tile as f32);
            let n = r.pixels.iter().map(|p| p.n as u64).sum();
            j.merge(key, r, n, NOW);
        }
        assert_eq!(j.state, JobState::Done);
        assert!(j.frames[0].tiles.iter().all(|t| t.pending.is_empty()));
        j.film(0)
    };
    let forward = run(&[0, 1, 2, 3, 4, 5]);
    assert_eq!(forward, run(&[5, 4, 3, 2, 1, 0]));
    assert_eq!(forward, run(&[3, 0, 5, 1, 4, 2]));
}

#[test]
fn past_the_time_limit_the_last_lease_to_lapse_ends_the_job() {
    let mut j = job(64, 32, None);
    j.settings.time_limit_s = Some(1e-9);
    let key = j.next_task().unwrap();
    j.lease(key, NOW);
    assert!(j.check_time_limit(NOW + std::time::Duration::from_micros(1)));
    assert_eq!(j.state, JobState::Running, "a lease is still out");
    assert_eq!(j.next_task(), None, "nothing more is issued");
    j.give_back(key, NOW);
    assert_eq!(j.state, JobState::Done, "the job must not wait for a lease that lapsed");
}

/// A photon-mapping job under adaptive sampling: its frame is one tile whose passes' variance
/// grows (as the gather radius shrinks), so it stops at the first task after which its own
/// estimate is within the target (the pilot's variance per sample would stop it early, above
/// it), and no sooner.
#[test]
fn an_adaptive_photon_mapping_frame_stops_when_its_own_estimate_reaches_the_target() {
    let target = 0.017;
    let settings = RenderSettings {
        width: 16,
        height: 16,
        spp: 4096,
        samples_per_task: 16,
        integrator: Integrator::Sppm,
        target_rel_error: Some(target),
        ..Default::default()
    };
    let mut j = Job::new("j".into(), 0, "s".into(), settings, 0, 0.0).unwrap();
    assert_eq!(j.frames[0].tiles.len(), 1, "a photon-mapping frame is one tile");
    // Pass s: 1 plus a uniform number in [-a_s, a_s], a_s growing with the pass (the scale from
    // the pilot, 16 passes, stops this one 1.24 times above the target, 10 tasks sooner).
    let noisy = |j: &Job, key: TaskKey| {
        let spec = j.spec(key);
        let mut acc = TileAccum::new(spec.rect);
        for y in 0..spec.rect.height {
            for x in 0..spec.rect.width {
                for s in spec.samples.start..spec.samples.end {
                    let mut h = (x as u64) << 40 ^ (y as u64) << 20 ^ s as u64;
                    h = (h ^ (h >> 31)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
                    h = (h ^ (h >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                    let u = (h >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0;
                    // Variance growing as the pass's number to the 1/3 (1 / r² for alpha 2/3).
                    let a = 0.4 * (1.0 + s as f32 / 16.0).powf(1.0 / 6.0);
                    acc.add_sample(x, y, s, [1.0 + a * u; 3]);
                }
            }
        }
        acc
    };
    let mut estimates = Vec::new();
    while let Some(key) = j.next_task() {
        j.lease(key, NOW);
        let r = noisy(&j, key);
        let n = r.pixels.iter().map(|p| p.n as u64).sum();
        j.merge(key, r, n, NOW);
        estimates.push(j.frames[0].tiles[0].rel_mse);
    }
    assert_eq!(j.state, JobState::Done);
    let last = *estimates.last().unwrap();
    let before = estimates[estimates.len() - 2];
    println!("{} tasks; the estimate {before:.3e} then {last:.3e}", estimates.len());
    assert!(last <= target * target, "stopped above the target: {last}");
    assert!(before > target * target, "went on past the target: {before}");
    assert!(j.status(NOW).samples_saved > 0);
}

/// Task `key`'s result in a bidirectional frame of two camera tiles: tile 0's camera part is
/// bright and smooth, tile 1's dim and noisy (where light tracing carries its pixels), and the
/// light tile's part noisy over the whole frame: 0.5 on average, 0.5 / p with probability p
/// and else 0, of variance `bdpt.light_paths` / 12 (so that a pixel sample's light samples are as
/// noisy together whatever their number).
fn noisy_bdpt(j: &Job, key: TaskKey) -> TileAccum {
    let spec = j.spec(key);
    let light = j.light_tile() == Some(key.tile as usize);
    let p = 1.0 / (1.0 + j.settings.light_paths() as f32 / 3.0);
    let (base, spread) = match key.tile {
        _ if light => (0.5, 0.0),
        0 => (1.0, 0.3),
        _ => (0.1, 0.6),
    };
    let mut acc = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                let mut h =
                    (x as u64) << 40 ^ (y as u64) << 20 ^ s as u64 ^ (key.tile as u64) << 60;
                h = (h ^ (h >> 31)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
                h = (h ^ (h >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                let u = (h >> 40) as f32 / (1u64 << 24) as f32;
                let v = match light {
                    true if u < p => base / p,
                    true => 0.0,
                    false => base + spread * (2.0 * u - 1.0),
                };
                acc.add_sample(x, y, s, [v; 3]);
            }
        }
    }
    acc
}

/// Leases every task it may and merges those results in reverse order (`reverse`), or leases
/// and merges one at a time, until the job is done or `stop_after` results are in (the tasks
/// leased and not merged then stay out).
fn drive(j: &mut Job, reverse: bool, stop_after: usize, result: fn(&Job, TaskKey) -> TileAccum) {
    let mut merged = 0;
    while j.state != JobState::Done && merged < stop_after {
        let mut keys = Vec::new();
        while let Some(key) = j.next_task() {
            j.lease(key, NOW);
            keys.push(key);
            if !reverse {
                break;
            }
        }
        if reverse {
            keys.reverse();
        }
        for key in keys {
            if merged == stop_after {
                break;
            }
            let r = result(j, key);
            let n = r.pixels.iter().map(|p| p.n as u64).sum();
            j.merge(key, r, n, NOW);
            merged += 1;
        }
    }
}

/// A bidirectional job under adaptive sampling: each camera tile and the light tile stop on
/// their own counts, decided from the pilot's image and each tile's own merged tasks, so that
/// results merged in any order (a pilot of 4 tasks a tile, merged in reverse, waits in pending
/// results), and a restart from what the database keeps, give the same bits; the image's
/// estimated error is then within the target.
#[test]
fn an_adaptive_bidirectional_frame_stops_each_tile_on_its_part_of_the_error() {
    let target = 0.02;
    let settings = RenderSettings {
        width: 64,
        height: 32,
        tile_size: 32,
        spp: 1024,
        samples_per_task: 4,
        integrator: Integrator::Bdpt,
        target_rel_error: Some(target),
        ..Default::default()
    };
    let new_job = || Job::new("j".into(), 0, "s".into(), settings.clone(), 0, 0.0).unwrap();
    let mut ahead = new_job();
    drive(&mut ahead, true, usize::MAX, noisy_bdpt);
    let mut in_order = new_job();
    drive(&mut in_order, false, usize::MAX, noisy_bdpt);
    assert_eq!(ahead.state, JobState::Done);
    let prefixes = |j: &Job| j.frames[0].tiles.iter().map(|t| t.prefix).collect::<Vec<_>>();
    assert_eq!(prefixes(&ahead), prefixes(&in_order));
    assert_eq!(ahead.film(0), in_order.film(0), "merge order changed the image");
    let p = prefixes(&ahead);
    println!("tasks per tile (camera 0, camera 1, light): {p:?}");
    assert!(p.iter().all(|&k| (4..256).contains(&k)), "every tile stops on its own: {p:?}");
    assert!(p[1] > p[0], "the noisier camera part takes more samples: {p:?}");
    // The image's estimate (each camera tile plus the light tile) is within the target.
    let e = ErrorEstimate::of_pixels(&ahead.film(0).pixels).rel_mse;
    println!("estimated relative RMSE {:.4} for a target of {target}", e.sqrt());
    assert!(e <= target * target * 1.1, "{} > {target}", e.sqrt());
    let status = ahead.status(NOW);
    assert_eq!(status.samples_done + status.samples_saved, status.samples_planned);
    assert_eq!(status.progress, 1.0);
    // The status's estimate adds the tiles' shares: the image's, but for the pilot's means.
    let shares = status.est_rel_error.unwrap().powi(2);
    assert!((shares / e - 1.0).abs() < 0.1, "status {shares:.3e}, image {e:.3e}");
    // Without adaptive sampling the shares are measured against the image's current means.
    let mut uniform = Job::new(
        "u".into(),
        0,
        "s".into(),
        RenderSettings { target_rel_error: None, spp: 64, ..settings.clone() },
        0,
        0.0,
    )
    .unwrap();
    let light = uniform.light_tile().unwrap() as u32;
    let mut keys = Vec::new();
    while let Some(key) = uniform.next_task() {
        uniform.lease(key, NOW);
        keys.push(key);
    }
    // No estimate while a camera tile has none: a light task says nothing of their parts.
    for key in keys.iter().filter(|k| k.tile == light || k.k > 0) {
        uniform.merge(*key, noisy_bdpt(&uniform, *key), 0, NOW);
    }
    assert_eq!(uniform.status(NOW).est_rel_error, None);
    for key in keys.iter().filter(|k| k.tile != light && k.k == 0) {
        uniform.merge(*key, noisy_bdpt(&uniform, *key), 0, NOW);
    }
    let image = ErrorEstimate::of_pixels(&uniform.film(0).pixels).rel_mse;
    let shares = uniform.status(NOW).est_rel_error.unwrap().powi(2);
    assert!((shares / image - 1.0).abs() < 1e-3, "status {shares:.3e}, image {image:.3e}");

    // A restart, from what the database keeps (prefix sums, pending results, the scale and the
    // pilot image), goes on to the same bits: within the pilot, with results pending, and past
    // it.
    let restarted = |before: &Job| {
        let mut again = new_job();
        for (i, t) in before.frames[0].tiles.iter().enumerate() {
            let pending = t.pending.iter().map(|(&k, a)| (k, a.clone())).collect();
            let sums = (t.prefix > 0).then(|| t.sums.clone());
            again.restore_tile(0, i as u32, t.prefix, sums, pending).unwrap();
        }
        let pilot = before.pilot(0).map(|p| vec![(0, p.to_vec())]).unwrap_or_default();
        again.restore_adaptive(&before.scales(), pilot).unwrap();
        again
    };
    for (reverse, merged) in [(true, 5), (false, 3 * 4 + 5)] {
        let mut before = new_job();
        drive(&mut before, reverse, merged, noisy_bdpt);
        let pending = before.frames[0].tiles.iter().any(|t| !t.pending.is_empty());
        assert_eq!((pending, before.frames[0].pilot.is_some()), (reverse, !reverse));
        let mut again = restarted(&before);
        drive(&mut again, false, usize::MAX, noisy_bdpt);
        assert_eq!(prefixes(&again), p);
        assert_eq!(again.film(0), ahead.film(0), "a restart changed the image");
    }
    let mut before = new_job();
    drive(&mut before, false, 3 * 4 + 5, noisy_bdpt);
    // Without its pilot image a restored frame is refused rather than decided otherwise.
    let mut lost = new_job();
    assert!(lost.restore_adaptive(&before.scales(), vec![]).unwrap_err().contains("pilot"));
}

/// A light sample index of `bdpt.light_paths` light subpaths costs that many camera samples:
/// with as noisy a pixel sample, the light tile stops sooner and the camera tiles later.
#[test]
fn an_adaptive_bidirectional_frame_weighs_the_light_tiles_cost() {
    let counts = |light_paths: u32| {
        let settings = RenderSettings {
            width: 64,
            height: 32,
            tile_size: 32,
            spp: 1024,
            samples_per_task: 16,
            integrator: Integrator::Bdpt,
            bdpt: Some(common::settings::Bdpt { light_paths }),
            target_rel_error: Some(0.02),
            ..Default::default()
        };
        let mut j = Job::new("j".into(), 0, "s".into(), settings, 0, 0.0).unwrap();
        drive(&mut j, true, usize::MAX, noisy_bdpt);
        j.frames[0].tiles.iter().map(|t| t.prefix).collect::<Vec<_>>()
    };
    let (one, four) = (counts(1), counts(4));
    println!("tasks per tile (camera 0, camera 1, light): {one:?} at 1 light path, {four:?} at 4");
    assert!(four[2] < one[2] && four[0] >= one[0] && four[1] > one[1], "{one:?} {four:?}");
}
