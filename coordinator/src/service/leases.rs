//! A lease's life after the grant, for the worker holding it (named by the `x-worker-id`
//! header): `POST /api/v1/leases/{lease}/heartbeat` renews it, `.../result` hands in the task's
//! partial sums (bincode) to be merged exactly once, `.../fail` reports that the task cannot be
//! rendered. Every refused result is counted in `/metrics` ([`crate::farm::Farm::result_refused`])
//! and logged with the worker, the lease and the reason (`refusals.rs`).

use axum::{
    body::Body,
    extract::{Path, State},
    http::HeaderMap,
    response::{IntoResponse, Response},
    routing::post,
    Json, Router,
};
use common::protocol::{decode_result, FailReport, WORKER_HEADER};
use serde_json::json;

use super::{blocking, content_type, discard_body, json_body, read_body, ApiResult, AppState};
use crate::farm::{ErrorKind, FarmError};

pub(super) fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/leases/{lease}/heartbeat", post(heartbeat))
        .route("/api/v1/leases/{lease}/result", post(submit_result))
        .route("/api/v1/leases/{lease}/fail", post(fail_task))
}

fn worker_id(headers: &HeaderMap) -> ApiResult<String> {
    headers
        .get(WORKER_HEADER)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
        .ok_or_else(|| FarmError::malformed(format!("missing the {WORKER_HEADER} header")))
}

async fn heartbeat(
    State(state): State<AppState>,
    Path(lease): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    read_body(body, 1 << 16, state.config.body_stall).await?;
    let worker = worker_id(&headers)?;
    let left = state.lock().heartbeat(&lease, &worker)?;
    Ok(Json(json!({ "lease_timeout_s": left })).into_response())
}

async fn submit_result(
    State(state): State<AppState>,
    Path(lease): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let answer = merge_result(state.clone(), lease, headers, body).await;
    if answer.is_err() {
        state.lock().result_refused();
    }
    answer
}

async fn merge_result(
    state: AppState,
    lease: String,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    // A live lease's result is read up to what its tile's sums can take; any other call is
    // refused, its body drained without being kept.
    let limit = worker_id(&headers).and_then(|w| Ok((state.lock().result_limit(&lease, &w)?, w)));
    let (limit, worker) = match limit {
        Ok(found) => found,
        Err(refusal) => {
            discard_body(body, state.config.max_upload_bytes, state.config.body_stall).await?;
            return Err(refusal);
        }
    };
    let bytes = read_body(body, limit, state.config.body_stall).await.map_err(|e| {
        if e.kind == ErrorKind::TooLarge {
            FarmError::new(
                e.kind,
                format!("result refused: over the {limit} bytes a result for this lease can take"),
            )
        } else {
            e
        }
    })?;
    match content_type(&headers).as_deref() {
        Some("application/octet-stream") => {}
        other => {
            return Err(FarmError::new(
                ErrorKind::UnsupportedMediaType,
                format!(
                    "a result is a bincode body with Content-Type application/octet-stream, got {}",
                    other.unwrap_or("none")
                ),
            ))
        }
    }
    let st = state.clone();
    blocking(move || {
        let result = decode_result(&bytes)
            .map_err(|e| FarmError::malformed(format!("result refused: {e}")))?;
        let size = bytes.len() as u64;
        // Nothing of the request's is kept while it waits for its commit.
        drop(bytes);
        let commit = st.lock().submit_queued(&lease, &worker, result, size)?;
        // Committed outside the farm lock, with the merges queued meanwhile.
        match commit {
            Some(commit) => commit.wait().map_err(|e| {
                tracing::error!("{e:#}");
                FarmError::from(e)
            }),
            None => Ok(()),
        }
    })
    .await?;
    state.work.notify_waiters();
    Ok(Json(json!({ "merged": true })).into_response())
}

async fn fail_task(
    State(state): State<AppState>,
    Path(lease): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let report: FailReport = json_body(&state, &headers, body).await?;
    let worker = worker_id(&headers)?;
    state.lock().fail(&lease, &worker, &report.error)?;
    state.work.notify_waiters();
    Ok(Json(json!({ "released": true })).into_response())
}
