//! Refused requests, logged and counted: a forged or stale result, a wrong token, an upload over
//! a budget, a malformed body, a busy coordinator. Each is counted by status on `/metrics`
//! (`renderfarm_requests_refused_total`) and logged at warn with what was asked, who asked (the
//! `x-worker-id` header, when sent) and the reason, at most [`LINES`] lines in a window of
//! [`WINDOW`]: a client refused in a loop cannot flood the log. The lines held back are
//! counted, and their number is logged when the next window opens.
//!
//! Routine answers are not refusals here: an unknown id (404), a method a route does not take
//! (405), a job that ended (409), except on a result, where every refusal is logged.

use std::{
    collections::BTreeMap,
    time::{Duration, Instant},
};

use axum::{
    extract::{Request, State},
    middleware::Next,
    response::Response,
};
use common::protocol::WORKER_HEADER;

use super::AppState;
use crate::farm::FarmError;

/// The window of the log's rate limit.
pub(super) const WINDOW: Duration = Duration::from_secs(10);
/// Lines logged at most in a window.
pub(super) const LINES: u32 = 20;

/// The log's rate limit and the counts by status.
#[derive(Debug)]
pub(super) struct Refusals {
    window_start: Option<Instant>,
    logged: u32,
    held_back: u64,
    /// Refused requests by HTTP status, since the start.
    pub by_status: BTreeMap<u16, u64>,
}

impl Refusals {
    pub(super) fn new() -> Self {
        Refusals { window_start: None, logged: 0, held_back: 0, by_status: BTreeMap::new() }
    }

    /// Counts a refusal at `now`; whether to log it. Opening a window logs how many lines the
    /// last one held back.
    pub(super) fn admit(&mut self, status: u16, now: Instant) -> bool {
        *self.by_status.entry(status).or_default() += 1;
        let open = self.window_start.is_some_and(|start| now.duration_since(start) < WINDOW);
        if !open {
            if self.held_back > 0 {
                tracing::warn!(
                    "{} more refused requests in the last window were not logged (all are counted on /metrics)",
                    self.held_back
                );
            }
            self.window_start = Some(now);
            self.logged = 0;
            self.held_back = 0;
        }
        if self.logged < LINES {
            self.logged += 1;
            true
        } else {
            self.held_back += 1;
            false
        }
    }
}

/// Middleware: logs and counts the refusals among the answers.
pub(super) async fn log(State(state): State<AppState>, req: Request, next: Next) -> Response {
    let method = req.method().clone();
    let path = req.uri().path().to_string();
    let worker = req.headers().get(WORKER_HEADER).and_then(|v| v.to_str().ok()).map(str::to_string);
    let response = next.run(req).await;
    let Some(refusal) = response.extensions().get::<FarmError>() else {
        return response;
    };
    let status = response.status().as_u16();
    let lease = path
        .strip_prefix("/api/v1/leases/")
        .and_then(|rest| rest.strip_suffix("/result"))
        .map(str::to_string);
    if lease.is_none() && matches!(status, 404 | 405 | 409) {
        return response;
    }
    let admitted = lock(&state).admit(status, Instant::now());
    if admitted {
        let worker = worker.as_deref().unwrap_or("(not named)");
        let kind = refusal.kind;
        match lease {
            Some(lease) => {
                let reason =
                    refusal.message.strip_prefix("result refused: ").unwrap_or(&refusal.message);
                tracing::warn!(worker, lease, %kind, status, "result refused: {reason}");
            }
            None => {
                tracing::warn!(worker, %method, path, %kind, status, "refused: {}", refusal.message)
            }
        }
    }
    response
}

fn lock(state: &AppState) -> std::sync::MutexGuard<'_, Refusals> {
    state.refusals.lock().unwrap_or_else(|p| p.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At most `LINES` lines a window, every refusal counted; a new window logs again.
    #[test]
    fn the_log_is_rate_limited_and_the_counts_are_whole() {
        let mut r = Refusals::new();
        let t0 = Instant::now();
        let admitted = (0..100).filter(|i| r.admit(401, t0 + Duration::from_millis(*i))).count();
        assert_eq!(admitted, LINES as usize);
        assert_eq!(r.held_back, 100 - LINES as u64);
        assert!(r.admit(422, t0 + WINDOW + Duration::from_millis(1)), "a new window logs");
        assert_eq!(r.held_back, 0);
        assert_eq!(r.by_status, BTreeMap::from([(401, 100), (422, 1)]));
    }
}
