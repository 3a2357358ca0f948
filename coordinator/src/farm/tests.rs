//! The farm as a whole, on a temporary store: restarts, scratch stores, and time passing on a
//! manual clock.

use super::*;
use clock::ManualClock;
use common::{film::TileAccum, protocol::TaskResult, settings::RenderSettings};

/// An 8x8 frame in one tile, `spp` samples a pixel, 4 a task.
fn one_tile(spp: u32) -> RenderSettings {
    RenderSettings {
        width: 8,
        height: 8,
        tile_size: 8,
        spp,
        samples_per_task: 4,
        ..Default::default()
    }
}

/// A result with the counts `grant` asks for (values from `v`), as a worker would send.
pub(crate) fn result_for(grant: &LeaseGrant, v: f32) -> TaskResult {
    let spec = grant.task;
    let mut tile = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                tile.add_sample(x, y, s, [v + s as f32 * 0.01; 3]);
            }
        }
    }
    TaskResult { spec, tile, rays: 0, kernel: "path, scalar".into() }
}

/// A result accepted out of order survives a restart as pending: counted once, never
/// leased again, and added in task order once its predecessor arrives. The kernels that
/// rendered the frame survive with it, and the frame's EXR header names them all.
#[test]
fn pending_results_survive_a_restart_and_merge_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let settings = one_tile(8);
    let hash = "ab".repeat(32);
    let (id, first, second) = {
        let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
        farm.store.put_scene(&hash, "glb", b"scene").unwrap();
        let id = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
        let w = farm
            .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
            .unwrap()
            .id;
        let first = farm.lease(&w).unwrap().unwrap();
        let second = farm.lease(&w).unwrap().unwrap();
        assert_eq!((first.task.samples.start, second.task.samples.start), (0, 4));
        let avx2 = TaskResult { kernel: "path, AVX2 x8".into(), ..result_for(&second, 0.5) };
        farm.submit(&second.lease, &w, avx2, 0).unwrap();
        let status = farm.status(&id).unwrap();
        assert_eq!(status.samples_done, 64 * 4);
        assert_eq!(status.frame_progress[0].kernels, ["path, AVX2 x8"]);
        (id, first, second)
    };
    let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
    assert_eq!(farm.status(&id).unwrap().samples_done, 64 * 4, "the pending result was lost");
    assert_eq!(farm.status(&id).unwrap().frame_progress[0].kernels, ["path, AVX2 x8"]);
    let w =
        farm.join(JoinRequest { name: "w".into(), threads: 1, version: String::new() }).unwrap().id;
    let again = farm.lease(&w).unwrap().unwrap();
    assert_eq!(again.task, first.task, "only the unanswered task is leased again");
    assert!(farm.lease(&w).unwrap().is_none());
    farm.submit(&again.lease, &w, result_for(&again, 0.5), 0).unwrap();
    let status = farm.status(&id).unwrap();
    assert_eq!((status.state, status.samples_done), (JobState::Done, 64 * 8));
    let kernels = ["path, AVX2 x8", "path, scalar"];
    assert_eq!(status.frame_progress[0].kernels, kernels);
    assert_eq!(farm.frame_layout(&id, 0).unwrap().info.kernels, kernels);
    // The same bits as merging in order without any restart.
    let mut expected = TileAccum::new(first.task.rect);
    expected.merge(&result_for(&first, 0.5).tile);
    expected.merge(&result_for(&second, 0.5).tile);
    let (film, _) = farm.film(&id, 0).unwrap();
    assert_eq!(film.pixels, expected.pixels);
}

/// A scratch store writes nothing per result, yet the frames it evicts (each frame of a
/// multi-frame job as it finishes) read back with the same bits as a durable store's.
#[test]
fn a_scratch_store_keeps_evicted_frames_bit_for_bit() {
    let settings = RenderSettings {
        width: 16,
        frames: common::settings::Frames { start: 0, end: 1, fps: 24.0 },
        ..one_tile(8)
    };
    let hash = "ef".repeat(32);
    let films = [true, false].map(|durable| {
        let dir = tempfile::tempdir().unwrap();
        let mut config = FarmConfig::new(dir.path().into());
        config.durable = durable;
        let mut farm = Farm::open(config).unwrap();
        farm.store.put_scene(&hash, "glb", b"scene").unwrap();
        let id = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
        let w = farm
            .join(JoinRequest { name: "w".into(), threads: 1, version: String::new() })
            .unwrap()
            .id;
        let mut grants = Vec::new();
        while let Some(g) = farm.lease(&w).unwrap() {
            grants.push(g);
        }
        assert_eq!(grants.len(), 8, "2 frames x 2 tiles x 2 sample ranges");
        // Later sample ranges first, so that results wait as pending before they merge.
        for (i, g) in grants.iter().enumerate().rev() {
            farm.submit(&g.lease, &w, result_for(g, i as f32 * 0.1), 0).unwrap();
        }
        let job = &farm.jobs[&id];
        assert_eq!(job.state, JobState::Done);
        // Each frame of a multi-frame job leaves memory as it finishes, in both modes.
        assert!(job.frames.iter().all(|f| f.evicted), "durable {durable}");
        [0, 1].map(|f| farm.film(&id, f).unwrap().0)
    });
    assert_eq!(films[0], films[1]);
    assert!(films[1].iter().all(|f| f.pixels.iter().all(|p| p.n == 8)));
}

/// A farm on a manual clock, with a stored scene and one joined worker.
fn farm_on(clock: &ManualClock, config: FarmConfig) -> (Farm, String, String) {
    let mut farm = Farm::open_with_clock(config, Arc::new(clock.clone())).unwrap();
    let hash = "cd".repeat(32);
    farm.store.put_scene(&hash, "glb", b"scene").unwrap();
    let w =
        farm.join(JoinRequest { name: "w".into(), threads: 1, version: String::new() }).unwrap().id;
    (farm, hash, w)
}

/// A worker whose render hangs keeps heartbeating; at the lease's maximum lifetime the
/// heartbeats are refused, and at its last deadline the task goes back to the queue.
#[test]
fn a_hung_worker_loses_its_lease_at_the_maximum_lifetime() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = FarmConfig::new(dir.path().into());
    config.lease_timeout = Duration::from_millis(40);
    config.max_lease_lifetime = Duration::from_millis(100);
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, config);
    let settings = RenderSettings { width: 8, height: 8, spp: 4, ..Default::default() };
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let grant = farm.lease(&w).unwrap().unwrap();
    for _ in 0..4 {
        clock.advance(Duration::from_millis(20));
        farm.heartbeat(&grant.lease, &w).unwrap();
    }
    // At 100 ms, renewed last at 80 ms until 120 ms.
    clock.advance(Duration::from_millis(20));
    let refused = farm.heartbeat(&grant.lease, &w).unwrap_err();
    assert_eq!(refused.kind, ErrorKind::Conflict);
    assert!(refused.message.contains("maximum lifetime"), "{}", refused.message);
    clock.advance(Duration::from_millis(19));
    assert!(!farm.tick(), "the lease expired before its deadline");
    clock.advance(Duration::from_millis(1));
    assert!(farm.tick(), "the lease did not expire at its deadline");
    assert_eq!(farm.status(&id).unwrap().tasks_in_flight, 0);
    assert_eq!(farm.counters.tasks_expired, 1);
    let health = &farm.workers()[0];
    assert_eq!((health.leases_expired, health.tasks_failed), (1, 0), "the worker's health");
    assert!(farm.lease(&w).unwrap().is_some(), "the task is leased again");
}

/// A worker's failures count against it in the worker list, with what it said last (cut to
/// 300 characters); another worker's record stays clean.
#[test]
fn a_workers_failures_show_in_its_health() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    let other =
        farm.join(JoinRequest { name: "x".into(), threads: 1, version: String::new() }).unwrap().id;
    farm.create_job(&hash, one_tile(8), 0).unwrap();
    let first = farm.lease(&w).unwrap().unwrap();
    farm.fail(&first.lease, &w, "out of memory").unwrap();
    let second = farm.lease(&w).unwrap().unwrap();
    farm.fail(&second.lease, &w, &"é".repeat(400)).unwrap();
    let listed = farm.workers();
    let of = |id: &str| listed.iter().find(|i| i.id == id).unwrap().clone();
    let (mine, theirs) = (of(&w), of(&other));
    assert_eq!((mine.tasks_failed, mine.leases_expired), (2, 0));
    assert_eq!(mine.last_error.as_deref(), Some("é".repeat(300).as_str()));
    assert_eq!((theirs.tasks_failed, theirs.last_error), (0, None));
}

/// Past a job's time limit no task is leased; the job ends when its last lease lapses, and
/// its running time is the clock's.
#[test]
fn a_time_limit_stops_leasing_and_the_last_lease_out_ends_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    let settings = RenderSettings { time_limit_s: Some(1.0), ..one_tile(12) };
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let first = farm.lease(&w).unwrap().unwrap();
    clock.advance(Duration::from_millis(999));
    farm.tick();
    let second = farm.lease(&w).unwrap().expect("leased before the time limit");
    clock.advance(Duration::from_millis(1));
    farm.tick();
    assert!(farm.lease(&w).unwrap().is_none(), "leased past the time limit");
    farm.submit(&first.lease, &w, result_for(&first, 0.5), 0).unwrap();
    assert_eq!(farm.status(&id).unwrap().state, JobState::Running, "a lease is still out");
    // The second lease, granted at 0.999 s, lapses at 30.999 s.
    clock.advance(Duration::from_millis(29_999));
    assert!(farm.tick());
    let status = farm.status(&id).unwrap();
    assert_eq!((status.state, status.samples_done), (JobState::Done, 64 * 4));
    assert_eq!(status.elapsed_s, Duration::from_millis(30_999).as_secs_f64());
    assert!(farm.heartbeat(&second.lease, &w).is_err());
}

/// A farm in `dir` with a stored scene, one joined worker and one job of a single task
/// (8x8 pixels, 4 samples), that task leased: (farm, worker, job, grant).
fn one_leased_task(dir: &std::path::Path) -> (Farm, String, String, LeaseGrant) {
    let mut farm = Farm::open(FarmConfig::new(dir.into())).unwrap();
    let hash = "aa".repeat(32);
    farm.store.put_scene(&hash, "glb", b"scene").unwrap();
    let settings = one_tile(4);
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let w =
        farm.join(JoinRequest { name: "w".into(), threads: 1, version: String::new() }).unwrap().id;
    let grant = farm.lease(&w).unwrap().unwrap();
    (farm, w, id, grant)
}

/// Results no real samples could give (a negative or non-finite mean, negative squared
/// deviations, radiance past the renderer's largest sample) are refused as invalid, naming the
/// pixel and the value, and nothing is merged; the honest result is merged after them.
#[test]
fn physically_impossible_results_are_refused_and_nothing_is_merged() {
    let dir = tempfile::tempdir().unwrap();
    let (mut farm, w, id, grant) = one_leased_task(dir.path());
    let max = common::film::MAX_SAMPLE_VALUE as f64;
    type Forge = fn(&mut common::film::PixelSums, f64);
    let forgeries: [(&str, Forge, &str); 7] = [
        ("a mean of -100", |p, _| p.mean[0] = -100.0, "mean -100 is negative"),
        ("a NaN mean", |p, _| p.mean[1] = f64::NAN, "mean NaN is not finite"),
        ("an infinite mean", |p, _| p.mean[2] = f64::INFINITY, "mean inf is not finite"),
        ("negative squared deviations", |p, _| p.m2[1] = -1.0, "deviations -1 is negative"),
        ("a negative mean of odd samples", |p, _| p.mean_odd[0] = -0.5, "-0.5 is negative"),
        ("a mean past the largest sample", |p, max| p.mean[0] = 2.0 * max, "beyond the largest"),
        ("squared deviations no samples give", |p, max| p.m2[2] = 4.0 * max * max, "more than 4"),
    ];
    for (what, forge, needle) in forgeries {
        let mut forged = result_for(&grant, 0.5);
        // Pixel 11 of the tile: column 3, row 1.
        forge(&mut forged.tile.pixels[11], max);
        let refused = farm.submit(&grant.lease, &w, forged, 0).unwrap_err();
        assert_eq!(refused.kind, ErrorKind::Invalid, "{what}: {}", refused.message);
        assert!(
            refused.message.contains("pixel (3, 1)") && refused.message.contains(needle),
            "{what}: {}",
            refused.message
        );
        assert_eq!(farm.status(&id).unwrap().samples_done, 0, "{what} was merged");
    }
    // A sample count that does not match the lease is refused too.
    let mut short = result_for(&grant, 0.5);
    short.tile.pixels[0].n -= 1;
    assert_eq!(farm.submit(&grant.lease, &w, short, 0).unwrap_err().kind, ErrorKind::Invalid);
    // The lease is still live: the honest result is merged once.
    farm.submit(&grant.lease, &w, result_for(&grant, 0.5), 0).unwrap();
    let status = farm.status(&id).unwrap();
    assert_eq!((status.state, status.samples_done), (JobState::Done, 64 * 4));
}

/// A running job removed is gone at once (its lease with it) and after a restart, with every
/// row it had; the other jobs and the scene stay.
#[test]
fn a_removed_job_is_gone_and_stays_gone_after_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let (mut farm, w, id, grant) = one_leased_task(dir.path());
    let settings = one_tile(8);
    let hash = "aa".repeat(32);
    let other = farm.create_job(&hash, settings, 0).unwrap().id;
    // The other job gets a merged task and a pending one; the removed one a merged task.
    let first = farm.lease(&w).unwrap().unwrap();
    let second = farm.lease(&w).unwrap().unwrap();
    assert_eq!((first.job.as_str(), second.job.as_str()), (other.as_str(), other.as_str()));
    farm.submit(&second.lease, &w, result_for(&second, 0.5), 0).unwrap();
    let rows = |farm: &Farm, job: &str| farm.store.rows_of(job);
    assert_eq!(rows(&farm, &other), 2, "the other job's row and its pending result");

    farm.remove_job(&id).unwrap();
    assert_eq!(farm.status(&id).unwrap_err().kind, ErrorKind::NotFound);
    assert_eq!(farm.remove_job(&id).unwrap_err().kind, ErrorKind::NotFound);
    assert_eq!(farm.leases_out(), 1, "the removed job's lease is gone, the other's stays");
    let late = farm.submit(&grant.lease, &w, result_for(&grant, 0.5), 0).unwrap_err();
    assert_eq!(late.kind, ErrorKind::Conflict, "{}", late.message);
    assert_eq!(rows(&farm, &id), 0);
    assert_eq!(farm.counters.jobs_removed, 1);
    drop(farm);

    let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
    assert_eq!(farm.status(&id).unwrap_err().kind, ErrorKind::NotFound, "it came back");
    assert_eq!(farm.status(&other).unwrap().samples_done, 64 * 4);
    assert!(farm.scene_file(&hash).is_ok(), "the scene left with the job");
    // A finished job is removed the same way, with its tiles.
    let w =
        farm.join(JoinRequest { name: "w".into(), threads: 1, version: String::new() }).unwrap().id;
    let again = farm.lease(&w).unwrap().unwrap();
    farm.submit(&again.lease, &w, result_for(&again, 0.5), 0).unwrap();
    assert_eq!(farm.status(&other).unwrap().state, JobState::Done);
    farm.remove_job(&other).unwrap();
    assert_eq!(rows(&farm, &other), 0);
    assert!(farm.list(&JobQuery::default()).jobs.is_empty());
}

/// With a retention time, the tick removes finished jobs that long after they ended (by the
/// farm's clock, also across a restart), and never a job that still runs.
#[test]
fn finished_jobs_are_removed_after_the_retention_time() {
    let dir = tempfile::tempdir().unwrap();
    let hour = Duration::from_secs(3600);
    let mut config = FarmConfig::new(dir.path().into());
    config.retain_finished = Some(hour);
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, config.clone());
    let settings = RenderSettings { width: 8, height: 8, spp: 4, ..Default::default() };
    let done = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
    let grant = farm.lease(&w).unwrap().unwrap();
    clock.advance(Duration::from_secs(10));
    farm.submit(&grant.lease, &w, result_for(&grant, 0.5), 0).unwrap();
    let status = farm.status(&done).unwrap();
    assert_eq!((status.state, status.finished_unix), (JobState::Done, Some(10.0)));
    let running = farm.create_job(&hash, settings.clone(), 0).unwrap().id;
    assert!(farm.lease(&w).unwrap().is_some());
    clock.advance(Duration::from_secs(30 * 60));
    let cancelled = farm.create_job(&hash, settings, 0).unwrap().id;
    farm.cancel(&cancelled).unwrap();
    assert_eq!(farm.status(&cancelled).unwrap().finished_unix, Some(1810.0));
    drop(farm);

    // The end time survives a restart.
    let mut farm = Farm::open_with_clock(config, Arc::new(clock.clone())).unwrap();
    clock.advance(hour - Duration::from_secs(30 * 60 + 1));
    farm.tick();
    assert!(farm.status(&done).is_ok(), "removed before its time");
    clock.advance(Duration::from_secs(1));
    farm.tick();
    assert_eq!(farm.status(&done).unwrap_err().kind, ErrorKind::NotFound);
    assert!(farm.status(&cancelled).is_ok());
    assert_eq!(farm.status(&running).unwrap().finished_unix, None);
    clock.advance(Duration::from_secs(30 * 60));
    farm.tick();
    assert_eq!(farm.status(&cancelled).unwrap_err().kind, ErrorKind::NotFound);
    clock.advance(100 * hour);
    farm.tick();
    assert!(farm.status(&running).is_ok(), "a job that runs is never removed");
    assert_eq!(farm.counters.jobs_removed, 2);
}

/// Without a retention time nothing is removed, however old.
#[test]
fn without_a_retention_time_finished_jobs_stay() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, _) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    let settings = RenderSettings { width: 8, height: 8, spp: 4, ..Default::default() };
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    farm.cancel(&id).unwrap();
    clock.advance(Duration::from_secs(10 * 365 * 24 * 3600));
    farm.tick();
    assert!(farm.status(&id).is_ok());
}

/// Lists come a page at a time in either order, filtered by state, as summaries without the
/// per-frame lists; a page's cursor leads to the next one, and the last has none.
#[test]
fn jobs_are_listed_a_page_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, _) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    let settings = RenderSettings {
        width: 8,
        height: 8,
        spp: 4,
        frames: common::settings::Frames { start: 3, end: 12, fps: 24.0 },
        ..Default::default()
    };
    let ids: Vec<String> =
        (0..5).map(|_| farm.create_job(&hash, settings.clone(), 0).unwrap().id).collect();
    farm.cancel(&ids[1]).unwrap();
    farm.cancel(&ids[3]).unwrap();
    let listed = |page: &JobPage| page.jobs.iter().map(|j| j.id.clone()).collect::<Vec<_>>();

    let all = farm.list(&JobQuery::default());
    assert_eq!((listed(&all), all.next), (ids.clone(), None));
    let summary = &all.jobs[0];
    assert_eq!(
        (summary.frame_count, summary.first_frame, summary.state),
        (10, 3, JobState::Queued)
    );
    let json = serde_json::to_value(summary).unwrap();
    assert!(json.get("frame_progress").is_none() && json.get("settings").is_none(), "{json}");

    let mut query = JobQuery { limit: 2, ..Default::default() };
    let mut pages = Vec::new();
    loop {
        let page = farm.list(&query);
        pages.push(listed(&page));
        let Some(next) = page.next else { break };
        query.after = Some(next);
    }
    assert_eq!(pages, [&ids[0..2], &ids[2..4], &ids[4..5]]);

    let newest = JobQuery { order: ListOrder::Newest, limit: 3, ..Default::default() };
    let page = farm.list(&newest);
    assert_eq!(listed(&page), [ids[4].clone(), ids[3].clone(), ids[2].clone()]);
    let rest = farm.list(&JobQuery { after: page.next, ..newest });
    assert_eq!((listed(&rest), rest.next), (vec![ids[1].clone(), ids[0].clone()], None));

    let cancelled = JobQuery { states: Some(vec![JobState::Cancelled]), ..Default::default() };
    assert_eq!(listed(&farm.list(&cancelled)), [ids[1].clone(), ids[3].clone()]);
    // A removed job leaves no hole a cursor could fall into.
    farm.remove_job(&ids[2]).unwrap();
    let page = farm.list(&JobQuery {
        limit: 2,
        after: Some(farm.jobs[&ids[1]].seq),
        ..Default::default()
    });
    assert_eq!(listed(&page), [ids[3].clone(), ids[4].clone()]);
}

/// The rows of `table` in the database under `dir`, read on a connection of the test's own.
fn rows_in(dir: &std::path::Path, table: &str) -> i64 {
    let db = rusqlite::Connection::open(dir.join("farm.sqlite")).unwrap();
    db.query_row(&format!("SELECT COUNT(*) FROM {table}"), [], |r| r.get(0)).unwrap()
}

/// The film of `results` merged as the farm merges them, whatever their arrival: each tile's
/// results in task order (sample ranges), the first taken as it is.
fn merged_in_task_order(width: u32, height: u32, results: &[TaskResult]) -> common::film::Film {
    let mut tiles: BTreeMap<(u32, u32), Vec<&TaskResult>> = BTreeMap::new();
    for r in results {
        tiles.entry((r.spec.rect.y0, r.spec.rect.x0)).or_default().push(r);
    }
    let mut film = common::film::Film::new(width, height);
    for mut rs in tiles.into_values() {
        rs.sort_by_key(|r| r.spec.samples.start);
        let mut sums = rs[0].tile.clone();
        for r in &rs[1..] {
            sums.merge(&r.tile);
        }
        film.merge_tile(&sums);
    }
    film
}

/// Group commit: merges queue their writes under the farm lock and commit outside it, all that
/// is queued in one transaction, in the order they were merged. Nothing is in the database
/// until a commit is waited for; waiting for the last commits the others with it; a use of the
/// database commits what is queued first; and the database reopens to the film of the results
/// merged in task order, bit for bit.
#[test]
fn merges_commit_in_groups_in_the_order_they_were_made() {
    let dir = tempfile::tempdir().unwrap();
    let settings = RenderSettings { width: 16, height: 16, spp: 12, ..one_tile(12) };
    let (mut farm, hash, w) = farm_on(&ManualClock::new(), FarmConfig::new(dir.path().into()));
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let grants: Vec<_> = std::iter::from_fn(|| farm.lease(&w).unwrap()).collect();
    assert_eq!(grants.len(), 12, "4 tiles x 3 sample ranges");
    // Ranges out of order in one group: the third waits as pending, the first is the tile's
    // sums, the second absorbs the third (two new sums of the tile in the group, the last
    // written).
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by_key(|&i| (grants[i].task.samples.start != 8, grants[i].task.samples.start, i));
    let results: Vec<TaskResult> =
        order.iter().map(|&i| result_for(&grants[i], 0.1 + i as f32 * 0.07)).collect();
    let mut commits = Vec::new();
    for (&i, r) in order.iter().zip(&results) {
        let commit = farm.submit_queued(&grants[i].lease, &w, r.clone(), 0).unwrap();
        commits.push(commit.expect("a durable store commits each merge"));
    }
    assert_eq!(farm.status(&id).unwrap().state, JobState::Done);
    assert_eq!((rows_in(dir.path(), "tiles"), rows_in(dir.path(), "pending")), (0, 0));
    // The last merge's commit takes the eleven before it along.
    commits.pop().unwrap().wait().unwrap();
    assert_eq!((rows_in(dir.path(), "tiles"), rows_in(dir.path(), "pending")), (4, 0));
    assert_eq!(farm.commit_groups().0, 1);
    for commit in commits {
        commit.wait().unwrap();
    }
    let expected = merged_in_task_order(16, 16, &results);
    assert_eq!(farm.film(&id, 0).unwrap().0, expected);

    // A merge queued and never waited for is committed before the database is next used.
    let id2 = farm.create_job(&hash, RenderSettings { spp: 4, ..one_tile(4) }, 0).unwrap().id;
    let g = farm.lease(&w).unwrap().unwrap();
    let unwaited = farm.submit_queued(&g.lease, &w, result_for(&g, 0.25), 0).unwrap();
    assert_eq!(rows_in(dir.path(), "tiles"), 4);
    farm.store.scene_format(&hash).unwrap();
    assert_eq!(rows_in(dir.path(), "tiles"), 5, "committed before the database was read");
    unwaited.unwrap().wait().unwrap();
    farm.remove_job(&id2).unwrap();
    assert_eq!(rows_in(dir.path(), "tiles"), 4);
    drop(farm);

    let farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
    assert_eq!(farm.status(&id).unwrap().state, JobState::Done);
    assert_eq!(farm.film(&id, 0).unwrap().0, expected);
}

/// A group whose transaction fails fails every merge in it, each waiter told why, and stops the
/// database there: later merges fail with the same error rather than commit behind a gap. A
/// restarted coordinator resumes from what was committed, leases the rest again, and finishes
/// with the film of the results merged in task order.
#[test]
fn a_failed_group_commit_stops_the_database_until_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let settings = RenderSettings { width: 16, height: 16, ..one_tile(8) };
    let (mut farm, hash, w) = farm_on(&ManualClock::new(), FarmConfig::new(dir.path().into()));
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let grants: Vec<_> = std::iter::from_fn(|| farm.lease(&w).unwrap()).collect();
    assert_eq!(grants.len(), 8);
    // Two merges commit; then the disk fails under the next group of two.
    for g in &grants[..2] {
        farm.submit(&g.lease, &w, result_for(g, 0.5), 0).unwrap();
    }
    let db = rusqlite::Connection::open(dir.path().join("farm.sqlite")).unwrap();
    db.execute_batch(
        "CREATE TRIGGER full BEFORE INSERT ON tiles BEGIN SELECT RAISE(ABORT, 'disk full'); END;
         CREATE TRIGGER full_pending BEFORE INSERT ON pending BEGIN SELECT RAISE(ABORT, 'disk full'); END;",
    )
    .unwrap();
    let failing: Vec<_> = grants[2..4]
        .iter()
        .map(|g| farm.submit_queued(&g.lease, &w, result_for(g, 0.5), 0).unwrap().unwrap())
        .collect();
    for commit in failing {
        let e = commit.wait().unwrap_err();
        assert!(format!("{e:#}").contains("disk full"), "{e:#}");
    }
    // The disk is fine again, but nothing more is committed: the next merge fails with the
    // first error, and so does any use of the database.
    db.execute_batch("DROP TRIGGER full; DROP TRIGGER full_pending").unwrap();
    let e = farm.submit(&grants[4].lease, &w, result_for(&grants[4], 0.5), 0).unwrap_err();
    assert!(e.message.contains("disk full") && e.message.contains("restart"), "{}", e.message);
    assert!(farm.store.scene_format(&hash).is_err());
    assert_eq!(rows_in(dir.path(), "tiles") + rows_in(dir.path(), "pending"), 2);
    drop(farm);

    // The restart resumes from the two committed merges.
    let mut farm = Farm::open(FarmConfig::new(dir.path().into())).unwrap();
    assert_eq!(farm.status(&id).unwrap().samples_done, 2 * 64 * 4);
    let w =
        farm.join(JoinRequest { name: "w".into(), threads: 1, version: String::new() }).unwrap().id;
    let mut results: Vec<TaskResult> = grants[..2].iter().map(|g| result_for(g, 0.5)).collect();
    while let Some(g) = farm.lease(&w).unwrap() {
        let r = result_for(&g, 0.5);
        farm.submit(&g.lease, &w, r.clone(), 0).unwrap();
        results.push(r);
    }
    assert_eq!(results.len(), 8, "the six tasks not committed are leased again");
    assert_eq!(farm.status(&id).unwrap().state, JobState::Done);
    assert_eq!(farm.film(&id, 0).unwrap().0, merged_in_task_order(16, 16, &results));
}

/// What waits for a commit is bounded: the merge that fills the queue commits it, so that a
/// farm outrunning its disk holds at most `MAX_QUEUED` copies of tile sums queued. Sixteen new
/// sums of each tile in one group: the last of each is what is stored.
#[test]
fn a_full_queue_commits_before_the_farm_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let settings = RenderSettings { width: 16, height: 16, spp: 64, ..one_tile(64) };
    let (mut farm, hash, w) = farm_on(&ManualClock::new(), FarmConfig::new(dir.path().into()));
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let grants: Vec<_> = std::iter::from_fn(|| farm.lease(&w).unwrap()).collect();
    assert_eq!(grants.len(), store::MAX_QUEUED);
    let mut commits = Vec::new();
    let mut results = Vec::new();
    for (i, g) in grants.iter().enumerate() {
        assert_eq!(rows_in(dir.path(), "tiles"), 0, "committed before the queue was full ({i})");
        let r = result_for(g, 0.5 + (i % 5) as f32 * 0.1);
        commits.push(farm.submit_queued(&g.lease, &w, r.clone(), 0).unwrap().unwrap());
        results.push(r);
    }
    assert_eq!(rows_in(dir.path(), "tiles"), 4, "4 tiles");
    assert_eq!(farm.commit_groups().0, 1);
    for commit in commits {
        commit.wait().unwrap();
    }
    let stored = farm.store.tiles(&id).unwrap();
    assert!(stored.iter().all(|t| t.prefix == 16 && t.pending.is_empty()), "16 tasks a tile");
    assert_eq!(farm.film(&id, 0).unwrap().0, merged_in_task_order(16, 16, &results));
}

/// A job's error history: a point at its first merge, then one per step of running time (one
/// second at first), one at the merge that finishes it; once full, every other point goes and
/// the step doubles, so that it spans the whole run evenly within `HISTORY_POINTS`. The error
/// falls as samples are merged.
#[test]
fn the_error_history_spans_the_run_evenly() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    // 8 tiles x 100 tasks, leased tile by tile as the progressive choice gives them.
    let settings = RenderSettings {
        width: 32,
        height: 16,
        tile_size: 8,
        spp: 400,
        samples_per_task: 4,
        ..Default::default()
    };
    let id = farm.create_job(&hash, settings, 0).unwrap().id;
    let mut merges = 0;
    while let Some(g) = farm.lease(&w).unwrap() {
        clock.advance(Duration::from_millis(700));
        let v = 0.5 + 0.3 * ((merges * 7919) % 13) as f32 / 13.0;
        farm.submit(&g.lease, &w, result_for(&g, v), 0).unwrap();
        merges += 1;
        if merges == 3 {
            // The first merge, then the first one a second or more later.
            let h = farm.status(&id).unwrap().history;
            assert_eq!(h.len(), 2, "{h:?}");
            assert_eq!((h[0].elapsed_s, h[1].elapsed_s), (0.7, 2.1));
            assert_eq!(h[0].samples_done, 8 * 8 * 4);
        }
    }
    assert_eq!(merges, 800);
    let status = farm.status(&id).unwrap();
    assert_eq!(status.state, JobState::Done);
    let h = &status.history;
    assert!(h.len() < job::HISTORY_POINTS && h.len() > job::HISTORY_POINTS / 4, "{}", h.len());
    let last = h.last().unwrap();
    assert_eq!((last.elapsed_s, last.samples_done), (status.elapsed_s, status.samples_done));
    assert_eq!(h[0].elapsed_s, 0.7);
    // 560 s of running time, a merge each 0.7 s: thinned once, to steps of 2 s, so that no gap
    // is longer than two merges' time past the last step before the thinning (2.8 s).
    let steps: Vec<f64> = h.windows(2).map(|p| p[1].elapsed_s - p[0].elapsed_s).collect();
    assert!(steps.iter().all(|&s| s > 0.0 && s < 2.8 + 1e-9), "{steps:?}");
    let errors: Vec<f64> = h.iter().filter_map(|p| p.est_rel_error).collect();
    assert!(errors.len() > h.len() / 2, "{h:?}");
    assert!(errors.last().unwrap() < &(errors[0] * 0.5), "{errors:?}");
}

/// A job that ends without a merge noting it (here cancelled, a while after its last merge)
/// shows a last point at its end.
#[test]
fn the_error_history_ends_where_a_cancelled_job_ends() {
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new();
    let (mut farm, hash, w) = farm_on(&clock, FarmConfig::new(dir.path().into()));
    let id = farm.create_job(&hash, one_tile(64), 0).unwrap().id;
    let g = farm.lease(&w).unwrap().unwrap();
    clock.advance(Duration::from_millis(500));
    farm.submit(&g.lease, &w, result_for(&g, 0.5), 0).unwrap();
    clock.advance(Duration::from_secs(3));
    farm.cancel(&id).unwrap();
    let status = farm.status(&id).unwrap();
    let h = &status.history;
    assert_eq!(h.len(), 2, "{h:?}");
    assert_eq!((h[0].elapsed_s, h[1].elapsed_s), (0.5, status.elapsed_s));
    assert!(status.elapsed_s >= 3.5, "{}", status.elapsed_s);
    assert_eq!(h[1].samples_done, status.samples_done);
}
