//! Jobs: `POST /api/v1/jobs` creates one on a stored scene, `GET /api/v1/jobs` lists them a page
//! at a time (`?state=&order=&after=&limit=`), `GET /api/v1/jobs/{id}` shows one,
//! `POST /api/v1/jobs/{id}/cancel` cancels one (and so does `DELETE /api/v1/jobs/{id}`, as it
//! always did), and `DELETE /api/v1/jobs/{id}?purge=true` removes one entirely. A frame's
//! image, `GET /api/v1/jobs/{id}/frames/{n}.exr|png`, and its tiles' progress and error,
//! `GET /api/v1/jobs/{id}/frames/{n}/tiles`, are served by `frames.rs`.

use std::sync::Mutex;

use axum::{
    body::Body,
    extract::{rejection::QueryRejection, Path, Query, State},
    http::{HeaderMap, StatusCode},
    response::{IntoResponse, Response},
    routing::{get, post},
    Json, Router,
};
use common::{scene::Scene, settings::RenderSettings};
use serde::Deserialize;
use serde_json::json;

use super::{blocking, json_body, lock_farm, ApiResult, AppState};
use crate::farm::{
    job::{JobState, JobStatus},
    validate_job_scene, ErrorKind, Farm, FarmError, JobQuery, ListOrder, MAX_LIST_LIMIT,
};

pub(super) fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/jobs", post(create_job).get(list_jobs))
        .route("/api/v1/jobs/{id}", get(job_status).delete(delete_job))
        .route("/api/v1/jobs/{id}/cancel", post(cancel_job))
        .route("/api/v1/jobs/{id}/frames/{file}", get(super::frames::frame_image))
        .route("/api/v1/jobs/{id}/frames/{n}/tiles", get(super::frames::frame_tiles))
}

/// `POST /jobs` after the body is parsed: checks the settings against the farm and the stored
/// scene, and creates the job. Slow (it may load the scene): call it off the async threads.
/// `loaded`: the scene (and whether the environment map) the caller loaded from the stored
/// bundle, as `validate_job_scene` takes it.
pub(super) fn create_checked_job(
    farm: &Mutex<Farm>,
    scene: &str,
    settings: RenderSettings,
    priority: i32,
    name: Option<String>,
    loaded: Option<(&Scene, bool)>,
) -> ApiResult<JobStatus> {
    if let Some(name) = &name {
        crate::farm::validate_job_name(name)?;
    }
    lock_farm(farm).check_settings(&settings)?;
    let path = lock_farm(farm).scene_file(scene).map_err(|e| match e.kind {
        ErrorKind::NotFound => {
            FarmError::not_found(format!("{}: upload it to /api/v1/scenes first", e.message))
        }
        _ => e,
    })?;
    let bytes = std::fs::read(path).map_err(|e| FarmError::internal(format!("scene: {e}")))?;
    let budget = lock_farm(farm).config().scene_budget;
    validate_job_scene(&bytes, &settings, &budget, loaded)?;
    lock_farm(farm).create_named_job(scene, settings, priority, name)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CreateJob {
    scene: String,
    #[serde(default)]
    settings: serde_json::Value,
    #[serde(default)]
    priority: i32,
    /// A name for people to know the job by.
    #[serde(default)]
    name: Option<String>,
}

async fn create_job(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let req: CreateJob = json_body(&state, &headers, body).await?;
    let settings_value = if req.settings.is_null() { json!({}) } else { req.settings };
    let settings: RenderSettings =
        serde_path_to_error::deserialize(settings_value).map_err(|e| {
            let path = e.path().to_string();
            let at = if path == "." { String::new() } else { format!(".{path}") };
            FarmError::invalid(format!("settings{at}: {}", e.into_inner()))
        })?;
    let farm = state.farm.clone();
    let status = blocking(move || {
        create_checked_job(&farm, &req.scene, settings, req.priority, req.name, None)
    })
    .await?;
    state.work.notify_waiters();
    Ok((StatusCode::CREATED, Json(status)).into_response())
}

/// A query string's pairs, decoded; an undecodable one is a 400 with a JSON body like every
/// other refusal.
pub(super) type QueryPairs = Result<Query<Vec<(String, String)>>, QueryRejection>;

pub(super) fn query_pairs(query: QueryPairs) -> ApiResult<Vec<(String, String)>> {
    query.map(|Query(pairs)| pairs).map_err(|e| FarmError::malformed(format!("query: {e}")))
}

/// Reads `GET /jobs`' query: `state` (one or more states, comma-separated), `order` (`oldest`,
/// the default, or `newest`), `after` (the `next` cursor of the previous page) and `limit`
/// (1 to [`MAX_LIST_LIMIT`], default [`crate::farm::DEFAULT_LIST_LIMIT`]).
fn job_query(pairs: Vec<(String, String)>) -> ApiResult<JobQuery> {
    let mut query = JobQuery::default();
    for (key, value) in pairs {
        match key.as_str() {
            "state" => {
                let states = value.split(',').map(|s| {
                    JobState::parse(s.trim()).ok_or_else(|| {
                        FarmError::malformed(format!(
                            "state: '{s}' is not one of queued, running, done, failed, cancelled"
                        ))
                    })
                });
                query
                    .states
                    .get_or_insert_with(Vec::new)
                    .extend(states.collect::<Result<Vec<_>, _>>()?);
            }
            "order" => {
                query.order = match value.as_str() {
                    "oldest" => ListOrder::Oldest,
                    "newest" => ListOrder::Newest,
                    _ => {
                        return Err(FarmError::malformed(format!(
                            "order: '{value}' is neither oldest nor newest"
                        )))
                    }
                }
            }
            "after" => {
                query.after = Some(value.parse().map_err(|_| {
                    FarmError::malformed(format!(
                        "after: '{value}' is not a cursor (use the next field of a page)"
                    ))
                })?);
            }
            "limit" => {
                let limit = value.parse().ok().filter(|n| (1..=MAX_LIST_LIMIT).contains(n));
                query.limit = limit.ok_or_else(|| {
                    FarmError::malformed(format!(
                        "limit: '{value}' is not a number from 1 to {MAX_LIST_LIMIT}"
                    ))
                })?;
            }
            _ => {
                return Err(FarmError::malformed(format!(
                    "unknown query parameter '{key}' (state, order, after, limit)"
                )))
            }
        }
    }
    Ok(query)
}

async fn list_jobs(State(state): State<AppState>, query: QueryPairs) -> ApiResult<Response> {
    let query = job_query(query_pairs(query)?)?;
    let page = state.lock().list(&query);
    let next = page.next.map(|seq| seq.to_string());
    Ok(Json(json!({ "jobs": page.jobs, "next": next })).into_response())
}

async fn job_status(State(state): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    Ok(Json(state.lock().status(&id)?).into_response())
}

async fn cancel_job(State(state): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    let status = state.lock().cancel(&id)?;
    Ok(Json(status).into_response())
}

/// `DELETE /jobs/{id}` cancels, as it always has (a client written for that must not lose a
/// job's images); `?purge=true` removes the job entirely, cancelling it first if it runs.
async fn delete_job(
    State(state): State<AppState>,
    Path(id): Path<String>,
    query: QueryPairs,
) -> ApiResult<Response> {
    let mut purge = false;
    for (key, value) in query_pairs(query)? {
        match (key.as_str(), value.as_str()) {
            ("purge", "true") => purge = true,
            ("purge", "false") => purge = false,
            ("purge", _) => {
                return Err(FarmError::malformed(format!(
                    "purge: '{value}' is neither true nor false"
                )))
            }
            _ => {
                return Err(FarmError::malformed(format!(
                    "unknown query parameter '{key}' (only purge)"
                )))
            }
        }
    }
    if !purge {
        return cancel_job(State(state), Path(id)).await;
    }
    state.lock().remove_job(&id)?;
    Ok(Json(json!({ "removed": id })).into_response())
}
