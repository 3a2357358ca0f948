//! Workers: `POST /api/v1/workers` joins, `DELETE /api/v1/workers/{id}` leaves (a worker removes
//! only itself, naming itself in the `x-worker-id` header; an operator with the API token removes
//! any worker),
//! `GET /api/v1/workers` lists them, and `POST /api/v1/workers/{id}/lease?wait_s=S` asks for a
//! task, waiting up to S seconds (at most the service's `max_lease_wait`) for one: `200` with a
//! lease grant, or `204` when no work came.

use std::{sync::atomic::Ordering, time::Duration};

use axum::{
    body::Body,
    extract::{Path, State},
    http::{HeaderMap, StatusCode},
    response::{IntoResponse, Response},
    routing::{delete, get, post},
    Json, Router,
};
use common::protocol::{JoinRequest, WORKER_HEADER};
use serde_json::json;

use super::{auth::Operator, json_body, read_body, ApiResult, AppState};
use crate::farm::FarmError;

pub(super) fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/workers", get(list_workers).post(join))
        .route("/api/v1/workers/{id}", delete(leave))
        .route("/api/v1/workers/{id}/lease", post(lease))
}

async fn list_workers(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(json!({ "workers": state.lock().workers() }))
}

async fn join(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let req: JoinRequest = json_body(&state, &headers, body).await?;
    let resp = state.lock().join(req)?;
    Ok((StatusCode::CREATED, Json(resp)).into_response())
}

async fn leave(
    State(state): State<AppState>,
    Path(id): Path<String>,
    operator: Option<axum::Extension<Operator>>,
    headers: HeaderMap,
) -> ApiResult<Response> {
    if operator.is_some() {
        tracing::info!(worker = %id, "worker removed with the API token");
    } else {
        let caller = headers.get(WORKER_HEADER).and_then(|v| v.to_str().ok());
        match caller {
            Some(caller) if caller == id => {}
            Some(caller) => {
                return Err(FarmError::forbidden(format!(
                    "worker {caller} may not remove worker {id}: a worker removes only itself (an operator removes any worker with the API token)"
                )))
            }
            None => {
                return Err(FarmError::malformed(format!(
                    "missing the {WORKER_HEADER} header: a worker leaving names itself in it (a worker too old to send it must be updated); an operator removes any worker with the API token"
                )))
            }
        }
    }
    state.lock().leave(&id)?;
    state.work.notify_waiters();
    Ok(Json(json!({ "left": id })).into_response())
}

async fn lease(
    State(state): State<AppState>,
    Path(worker): Path<String>,
    uri: axum::http::Uri,
    body: Body,
) -> ApiResult<Response> {
    // Any body is read (and ignored): one left unread makes the server drop the connection,
    // which a client that keeps connections alive sees as a failure of its next request.
    read_body(body, 1 << 16, state.config.body_stall).await?;
    let mut wait_s = 0.0;
    for pair in uri.query().unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        match pair.split_once('=') {
            Some(("wait_s", v)) => {
                wait_s = v.parse::<f64>().ok().filter(|w| w.is_finite()).ok_or_else(|| {
                    FarmError::malformed(format!("wait_s: '{v}' is not a number of seconds"))
                })?;
            }
            _ => {
                return Err(FarmError::malformed(format!(
                    "unknown query parameter '{pair}' (only wait_s)"
                )))
            }
        }
    }
    let max = state.config.max_lease_wait.as_secs_f64();
    let wait = Duration::from_secs_f64(wait_s.clamp(0.0, max));
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        let notified = state.work.notified();
        tokio::pin!(notified);
        notified.as_mut().enable();
        if state.draining.load(Ordering::Relaxed) {
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
        if let Some(grant) = state.lock().lease(&worker)? {
            return Ok(Json(grant).into_response());
        }
        if tokio::time::timeout_at(deadline, notified).await.is_err() {
            state.lock().seen(&worker);
            return Ok(StatusCode::NO_CONTENT.into_response());
        }
    }
}
