//! One test per edge, on a made-up timeline: the lease timeout is 30 s, the maximum lifetime
//! 100 s, a task's job fails at its 3rd failure or 5th expiry.

use common::{
    error::ErrorKind,
    film::{Rect, TileAccum},
    protocol::{JoinRequest, SampleRange, TaskKind},
};

use super::*;

fn at(seconds: u64) -> Moment {
    Moment::ZERO + Duration::from_secs(seconds)
}

fn key(k: u32) -> TaskKey {
    TaskKey { frame: 0, tile: 1, k }
}

fn spec(k: u32) -> TaskSpec {
    TaskSpec {
        frame: 0,
        rect: Rect { x0: 2, y0: 0, width: 2, height: 2 },
        samples: SampleRange { start: 4 * k, end: 4 * k + 4 },
        kind: TaskKind::Camera,
    }
}

/// Workers `a` and `b`, joined at 0.
fn machine() -> Leases {
    let rules = Rules {
        lease_timeout: Duration::from_secs(30),
        max_lease_lifetime: Duration::from_secs(100),
        max_task_failures: 3,
        max_task_expiries: 5,
    };
    let mut m = Leases::new(rules);
    for w in ["a", "b"] {
        let req = JoinRequest { name: w.into(), threads: 1, version: String::new() };
        m.workers_mut().join(w, req, at(0)).unwrap();
    }
    m
}

/// Leases task `k` of `job` to `worker` as `lease` at `now`.
fn grant(m: &mut Leases, lease: &str, job: &str, k: u32, worker: &str, now: Moment) {
    let offer = Offer { lease: lease.into(), job: job.into(), key: key(k), spec: spec(k) };
    let effects = m.step(Event::Lease { worker, offer: Some(offer) }, now).unwrap();
    let granted = Effect::Granted { lease: lease.into(), job: job.into(), key: key(k) };
    assert_eq!(effects, vec![granted]);
}

/// A result that answers task `k`.
fn result(k: u32) -> TaskResult {
    let spec = spec(k);
    let mut tile = TileAccum::new(spec.rect);
    for y in 0..spec.rect.height {
        for x in 0..spec.rect.width {
            for s in spec.samples.start..spec.samples.end {
                tile.add_sample(x, y, s, [0.5; 3]);
            }
        }
    }
    TaskResult { spec, tile, rays: 0, kernel: "path, scalar".into() }
}

fn refusal(answer: FarmResult<Vec<Effect>>) -> (ErrorKind, String) {
    let e = answer.expect_err("a refusal");
    (e.kind, e.message)
}

fn expired(job: &str, k: u32, worker: &str, count: u32) -> Effect {
    let why = Release::Expired { count };
    Effect::Released { job: job.into(), key: key(k), worker: worker.into(), why }
}

fn failed(job: &str, k: u32, worker: &str, count: u32, error: &str) -> Effect {
    let why = Release::Failed { count, error: error.into() };
    Effect::Released { job: job.into(), key: key(k), worker: worker.into(), why }
}

#[test]
fn a_lease_is_granted_until_the_lease_timeout_and_renewable_up_to_the_maximum_lifetime() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(10));
    let l = m.get("l").unwrap();
    assert_eq!((l.deadline, l.renewable_until), (at(40), at(110)));
    assert_eq!((l.worker.as_str(), l.spec), ("a", spec(0)));
    assert_eq!(m.worker_infos(at(10)).iter().map(|w| w.leases).collect::<Vec<_>>(), [1, 0]);
}

#[test]
fn a_lease_request_without_an_offer_grants_nothing_but_hears_the_worker() {
    let mut m = machine();
    assert_eq!(m.step(Event::Lease { worker: "a", offer: None }, at(80)).unwrap(), vec![]);
    assert!(m.is_empty());
    // Heard from at 80: still known at 80 + 89 s.
    m.step(Event::Tick, at(169)).unwrap();
    assert!(m.workers().knows("a") && !m.workers().knows("b"));
}

#[test]
fn an_unknown_worker_is_told_to_join_again() {
    let mut m = machine();
    let offer = Offer { lease: "l".into(), job: "j".into(), key: key(0), spec: spec(0) };
    let (kind, message) =
        refusal(m.step(Event::Lease { worker: "nobody", offer: Some(offer) }, at(0)));
    assert_eq!(kind, ErrorKind::NotFound);
    assert!(message.contains("join again"), "{message}");
    assert!(m.is_empty(), "a refused lease was granted");
    let (kind, _) = refusal(m.step(Event::Heartbeat { lease: "l", worker: "nobody" }, at(0)));
    assert_eq!(kind, ErrorKind::NotFound);
}

#[test]
fn a_heartbeat_moves_the_deadline() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    let renewed = m.step(Event::Heartbeat { lease: "l", worker: "a" }, at(20)).unwrap();
    assert_eq!(renewed, vec![Effect::Renewed { lease: "l".into(), deadline: at(50) }]);
    assert_eq!(m.step(Event::Tick, at(30)).unwrap(), vec![], "expired at the old deadline");
    assert_eq!(m.step(Event::Tick, at(50)).unwrap(), vec![expired("j", 0, "a", 1)]);
}

#[test]
fn a_heartbeat_at_the_maximum_lifetime_is_refused_and_the_lease_then_expires() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    for t in [25, 50, 75, 99] {
        m.step(Event::Heartbeat { lease: "l", worker: "a" }, at(t)).unwrap();
    }
    let (kind, message) = refusal(m.step(Event::Heartbeat { lease: "l", worker: "a" }, at(100)));
    assert_eq!(kind, ErrorKind::Conflict);
    assert!(message.contains("maximum lifetime of 100 s"), "{message}");
    assert_eq!(m.get("l").unwrap().deadline, at(129), "the refusal renewed the lease");
    assert_eq!(m.step(Event::Tick, at(128)).unwrap(), vec![]);
    assert_eq!(m.step(Event::Tick, at(129)).unwrap(), vec![expired("j", 0, "a", 1)]);
}

#[test]
fn a_lease_expires_at_exactly_its_deadline() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    let just_before = at(30) - Duration::from_nanos(1);
    assert_eq!(m.step(Event::Tick, just_before).unwrap(), vec![]);
    assert_eq!(m.step(Event::Tick, at(30)).unwrap(), vec![expired("j", 0, "a", 1)]);
    assert!(m.get("l").is_none());
    let (kind, message) = refusal(m.step(Event::Heartbeat { lease: "l", worker: "a" }, at(30)));
    assert_eq!(kind, ErrorKind::Conflict);
    assert!(message.contains("not live"), "{message}");
}

/// Lets task 0 of job `j` expire four times on worker `a` (keeping `b` alive); returns the time.
fn expire_four_times(m: &mut Leases) -> u64 {
    let mut t = 0;
    for n in 1..=4 {
        grant(m, &format!("l{n}"), "j", 0, "a", at(t));
        m.step(Event::Seen { worker: "b" }, at(t)).unwrap();
        t += 30;
        assert_eq!(m.step(Event::Tick, at(t)).unwrap(), vec![expired("j", 0, "a", n)]);
    }
    t
}

const FIFTH_EXPIRY: &str =
    "task frame 0 tile (2, 0) samples 0..4: its lease expired 5 times (workers died or hung on it)";

#[test]
fn the_fifth_expiry_of_a_task_fails_its_job_and_drops_its_leases() {
    let mut m = machine();
    let t = expire_four_times(&mut m);
    grant(&mut m, "l5", "j", 0, "a", at(t));
    grant(&mut m, "sibling", "j", 1, "b", at(t + 10));
    grant(&mut m, "other-job", "k", 0, "b", at(t + 10));
    let failed = Effect::JobFailed { job: "j".into(), reason: FIFTH_EXPIRY.into() };
    assert_eq!(m.step(Event::Tick, at(t + 30)).unwrap(), vec![expired("j", 0, "a", 5), failed]);
    assert!(m.get("sibling").is_none(), "the failed job kept a lease");
    assert!(m.get("other-job").is_some(), "another job lost its lease");
}

#[test]
fn a_job_failed_by_an_expiry_loses_its_other_overdue_leases_in_the_same_tick() {
    let mut m = machine();
    let t = expire_four_times(&mut m);
    grant(&mut m, "l5", "j", 0, "a", at(t));
    grant(&mut m, "sibling", "j", 1, "b", at(t + 1));
    grant(&mut m, "other-job", "k", 0, "b", at(t + 1));
    // All three are overdue; the first fails job j, whose sibling lease is then gone.
    let failed = Effect::JobFailed { job: "j".into(), reason: FIFTH_EXPIRY.into() };
    assert_eq!(
        m.step(Event::Tick, at(t + 40)).unwrap(),
        vec![expired("j", 0, "a", 5), failed, expired("k", 0, "b", 1)]
    );
    assert!(m.is_empty());
}

#[test]
fn the_third_failure_of_a_task_fails_its_job_with_the_last_error() {
    let mut m = machine();
    for n in 1..=2 {
        grant(&mut m, "l", "j", 0, "a", at(n));
        let fail = Event::Fail { lease: "l", worker: "a", error: "out of memory" };
        assert_eq!(
            m.step(fail, at(n)).unwrap(),
            vec![failed("j", 0, "a", n as u32, "out of memory")]
        );
    }
    // Expiries are counted apart from failures.
    grant(&mut m, "l", "j", 0, "b", at(10));
    assert_eq!(m.step(Event::Tick, at(40)).unwrap(), vec![expired("j", 0, "b", 1)]);
    grant(&mut m, "l", "j", 0, "b", at(40));
    let fail = Event::Fail { lease: "l", worker: "b", error: "the BVH is too deep" };
    let reason =
        "task frame 0 tile (2, 0) samples 0..4 failed 3 times; last error: the BVH is too deep";
    assert_eq!(
        m.step(fail, at(41)).unwrap(),
        vec![
            failed("j", 0, "b", 3, "the BVH is too deep"),
            Effect::JobFailed { job: "j".into(), reason: reason.into() }
        ]
    );
    assert!(m.is_empty());
}

#[test]
fn a_result_ends_its_lease_once() {
    let mut m = machine();
    grant(&mut m, "l", "j", 2, "a", at(0));
    let r = result(2);
    let answer = Event::Result { lease: "l", worker: "a", result: &r };
    assert_eq!(
        m.step(answer, at(5)).unwrap(),
        vec![Effect::Answered { job: "j".into(), key: key(2) }]
    );
    let again = Event::Result { lease: "l", worker: "a", result: &r };
    let (kind, message) = refusal(m.step(again, at(6)));
    assert_eq!(kind, ErrorKind::Conflict);
    assert!(message.contains("not live"), "{message}");
}

#[test]
fn results_for_expired_reassigned_or_unknown_leases_are_refused() {
    let mut m = machine();
    grant(&mut m, "old", "j", 0, "a", at(0));
    m.step(Event::Tick, at(30)).unwrap();
    grant(&mut m, "new", "j", 0, "b", at(31));
    let r = result(0);
    for lease in ["old", "never-granted"] {
        let late = Event::Result { lease, worker: "a", result: &r };
        let (kind, message) = refusal(m.step(late, at(32)));
        assert_eq!(kind, ErrorKind::Conflict, "{lease}");
        assert!(message.contains(&format!("lease {lease} is not live")), "{message}");
    }
    assert_eq!(m.get("new").unwrap().worker, "b", "the reassigned lease was touched");
}

#[test]
fn another_workers_lease_is_refused_and_left_alone() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    let r = result(0);
    for event in [
        Event::Heartbeat { lease: "l", worker: "b" },
        Event::Result { lease: "l", worker: "b", result: &r },
        Event::Fail { lease: "l", worker: "b", error: "not mine" },
    ] {
        let (kind, message) = refusal(m.step(event, at(10)));
        assert_eq!(kind, ErrorKind::Forbidden);
        assert!(message.contains("another worker"), "{message}");
    }
    assert_eq!(m.get("l").unwrap().deadline, at(30));
}

#[test]
fn a_result_that_does_not_answer_its_task_is_refused_and_the_lease_stays() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    let wrong = result(1);
    let (kind, message) =
        refusal(m.step(Event::Result { lease: "l", worker: "a", result: &wrong }, at(1)));
    assert_eq!(kind, ErrorKind::Invalid);
    assert!(message.starts_with("result refused: "), "{message}");
    assert!(m.get("l").is_some());
}

#[test]
fn a_worker_that_leaves_gives_its_leases_back_uncounted() {
    let mut m = machine();
    grant(&mut m, "l1", "j", 0, "a", at(0));
    grant(&mut m, "l2", "j", 1, "a", at(1));
    grant(&mut m, "l3", "j", 2, "b", at(2));
    let given_back = |k: u32| Effect::Released {
        job: "j".into(),
        key: key(k),
        worker: "a".into(),
        why: Release::GivenBack,
    };
    assert_eq!(
        m.step(Event::Leave { worker: "a" }, at(5)).unwrap(),
        vec![given_back(0), given_back(1)]
    );
    assert_eq!(m.len(), 1);
    let (kind, message) = refusal(m.step(Event::Leave { worker: "a" }, at(6)));
    assert_eq!((kind, message.as_str()), (ErrorKind::NotFound, "unknown worker a"));
    // Nothing was counted: the task's next expiry is its first.
    grant(&mut m, "l4", "j", 0, "b", at(10));
    let effects = m.step(Event::Tick, at(40)).unwrap();
    assert_eq!(effects, vec![expired("j", 2, "b", 1), expired("j", 0, "b", 1)]);
}

#[test]
fn a_grant_given_back_is_not_counted() {
    let mut m = machine();
    grant(&mut m, "l", "j", 0, "a", at(0));
    let effects = m.step(Event::GiveBack { lease: "l" }, at(0)).unwrap();
    let why = Release::GivenBack;
    assert_eq!(
        effects,
        vec![Effect::Released { job: "j".into(), key: key(0), worker: "a".into(), why }]
    );
    assert!(m.is_empty());
    assert_eq!(m.step(Event::GiveBack { lease: "l" }, at(0)).unwrap(), vec![]);
}

#[test]
fn cancelling_a_job_drops_its_leases_only() {
    let mut m = machine();
    grant(&mut m, "l1", "j", 0, "a", at(0));
    grant(&mut m, "l2", "j", 1, "b", at(0));
    grant(&mut m, "l3", "k", 0, "b", at(0));
    assert_eq!(m.step(Event::Cancel { job: "j" }, at(1)).unwrap(), vec![]);
    assert!(m.get("l1").is_none() && m.get("l2").is_none());
    let r = result(0);
    let (kind, _) = refusal(m.step(Event::Result { lease: "l1", worker: "a", result: &r }, at(2)));
    assert_eq!(kind, ErrorKind::Conflict);
    assert_eq!(m.step(Event::Tick, at(30)).unwrap(), vec![expired("k", 0, "b", 1)]);
}

#[test]
fn silent_workers_are_forgotten_after_three_lease_timeouts() {
    let mut m = machine();
    m.step(Event::Seen { worker: "a" }, at(10)).unwrap();
    let silent_b = at(90) - Duration::from_nanos(1);
    m.step(Event::Tick, silent_b).unwrap();
    assert!(m.workers().knows("b"));
    m.step(Event::Tick, at(90)).unwrap();
    assert!(!m.workers().knows("b") && m.workers().knows("a"));
    m.step(Event::Tick, at(100)).unwrap();
    assert!(!m.workers().knows("a"));
    let (kind, _) = refusal(m.step(Event::Lease { worker: "a", offer: None }, at(100)));
    assert_eq!(kind, ErrorKind::NotFound);
}

#[test]
fn a_refused_request_still_counts_as_hearing_from_the_worker() {
    let mut m = machine();
    let stale = Event::Heartbeat { lease: "gone", worker: "a" };
    assert_eq!(refusal(m.step(stale, at(60))).0, ErrorKind::Conflict);
    m.step(Event::Tick, at(90)).unwrap();
    assert!(m.workers().knows("a") && !m.workers().knows("b"));
}
