//! `/metrics` in the Prometheus text exposition format.

use std::fmt::Write;

use axum::{
    extract::State,
    http::{header, HeaderValue},
    response::{IntoResponse, Response},
};

use super::AppState;

pub(super) async fn metrics(State(state): State<AppState>) -> Response {
    let farm = state.lock();
    let c = farm.counters.clone();
    let (groups, group_seconds) = farm.commit_groups();
    let jobs = farm.job_counts();
    let workers = farm.workers();
    let leases = farm.leases_out();
    let uptime = farm.uptime();
    drop(farm);
    let mut out = String::new();
    let mut put = |name: &str, kind: &str, help: &str, samples: &[(String, f64)]| {
        let _ = writeln!(out, "# HELP {name} {help}");
        let _ = writeln!(out, "# TYPE {name} {kind}");
        for (labels, v) in samples {
            let _ = writeln!(out, "{name}{labels} {v}");
        }
    };
    let one = |v: f64| vec![(String::new(), v)];
    put(
        "renderfarm_jobs",
        "gauge",
        "Jobs by state.",
        &jobs.iter().map(|(s, n)| (format!("{{state=\"{s}\"}}"), *n as f64)).collect::<Vec<_>>(),
    );
    put("renderfarm_workers", "gauge", "Workers joined.", &one(workers.len() as f64));
    put(
        "renderfarm_worker_threads",
        "gauge",
        "Render threads over all workers.",
        &one(workers.iter().map(|w| w.threads as f64).sum()),
    );
    put("renderfarm_leases", "gauge", "Tasks leased now.", &one(leases as f64));
    put("renderfarm_tasks_leased_total", "counter", "Tasks leased.", &one(c.tasks_leased as f64));
    put("renderfarm_tasks_merged_total", "counter", "Results merged.", &one(c.tasks_merged as f64));
    put(
        "renderfarm_tasks_expired_total",
        "counter",
        "Leases that expired.",
        &one(c.tasks_expired as f64),
    );
    put(
        "renderfarm_tasks_failed_total",
        "counter",
        "Failures reported by workers.",
        &one(c.tasks_failed as f64),
    );
    put(
        "renderfarm_results_refused_total",
        "counter",
        "Results refused (stale, duplicate, forged or malformed).",
        &one(c.results_refused as f64),
    );
    let refused: Vec<(String, f64)> = {
        let r = state.refusals.lock().unwrap_or_else(|p| p.into_inner());
        r.by_status.iter().map(|(s, n)| (format!("{{status=\"{s}\"}}"), *n as f64)).collect()
    };
    put(
        "renderfarm_requests_refused_total",
        "counter",
        "Requests refused, by HTTP status: bad tokens, bodies and uploads over a budget, forged or stale results, a busy coordinator (unknown ids, 404, and ended jobs, 409, are not counted but on a result).",
        &refused,
    );
    put(
        "renderfarm_jobs_removed_total",
        "counter",
        "Jobs removed, by a user or past the retention time.",
        &one(c.jobs_removed as f64),
    );
    put(
        "renderfarm_samples_merged_total",
        "counter",
        "Pixel samples merged.",
        &one(c.samples_merged as f64),
    );
    put(
        "renderfarm_samples_per_second",
        "gauge",
        "Pixel samples merged per second since the coordinator started.",
        &one(c.samples_merged as f64 / uptime.max(1e-9)),
    );
    put("renderfarm_rays_total", "counter", "Rays traced by merged tasks.", &one(c.rays as f64));
    put(
        "renderfarm_result_bytes_total",
        "counter",
        "Bytes of results merged.",
        &one(c.bytes_merged as f64),
    );
    put(
        "renderfarm_merge_seconds_total",
        "counter",
        "Seconds spent merging results in memory.",
        &one(c.merge_seconds),
    );
    put(
        "renderfarm_commits_total",
        "counter",
        "Transactions that committed merged results (each takes every merge queued meanwhile).",
        &one(groups as f64),
    );
    put(
        "renderfarm_commit_seconds_total",
        "counter",
        "Seconds spent in those transactions.",
        &one(group_seconds),
    );
    put(
        "renderfarm_uptime_seconds",
        "gauge",
        "Seconds since the coordinator started.",
        &one(uptime),
    );
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        out,
    )
        .into_response()
}
