//! Scene bundles: `POST /api/v1/scenes` checks and stores an upload (content-addressed, so the
//! same bytes give the same hash), `GET /api/v1/scenes/{hash}` serves it back (to workers).

use std::sync::Mutex;

use axum::{
    body::Body,
    extract::{Path, State},
    http::{header, HeaderMap, HeaderValue, StatusCode},
    response::{IntoResponse, Response},
    routing::{get, post},
    Json, Router,
};
use common::bundle::Format;

use super::{
    blocking, content_type, file_chunks, lock_farm, read_body_reserving, ApiResult, AppState,
};
use common::scene::Scene;

use crate::farm::{validate_upload, validate_upload_loaded, ErrorKind, Farm, FarmError, SceneInfo};

pub(super) fn routes() -> Router<AppState> {
    Router::new()
        .route("/api/v1/scenes", post(upload_scene))
        .route("/api/v1/scenes/{hash}", get(download_scene))
}

/// `POST /scenes` after the body is read: checks the upload and stores it. Slow (it loads the
/// scene): call it off the async threads.
pub(super) fn store_upload(
    farm: &Mutex<Farm>,
    bytes: &[u8],
    declared: Option<Format>,
) -> ApiResult<SceneInfo> {
    let budget = lock_farm(farm).config().scene_budget;
    let mut info = validate_upload(bytes, declared, &budget)?;
    lock_farm(farm).put_scene(bytes, &mut info)?;
    Ok(info)
}

/// [`store_upload`] of a bundle whose scene the caller loaded from these bytes within the
/// farm's scene budget (the embedded render): the scene is not loaded again.
pub(super) fn store_loaded(
    farm: &Mutex<Farm>,
    bytes: &[u8],
    scene: &Scene,
) -> ApiResult<SceneInfo> {
    let budget = lock_farm(farm).config().scene_budget;
    let mut info = validate_upload_loaded(bytes, &budget, scene)?;
    lock_farm(farm).put_scene(bytes, &mut info)?;
    Ok(info)
}

async fn upload_scene(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    // Each upload being received holds up to its size in memory: a few at once, and the others
    // told to come back, rather than many buffered together.
    let Ok(_receiving) = state.uploads.clone().try_acquire_owned() else {
        return Err(FarmError::new(
            ErrorKind::Busy,
            format!(
                "{} scene uploads are being received, the most this coordinator takes at once (--max-concurrent-uploads); try again shortly",
                state.config.max_concurrent_uploads
            ),
        ));
    };
    // Every upload's bytes held count against one budget (a KiB a permit), taken as they
    // arrive and given back when the upload is stored or refused.
    let mut held: Option<tokio::sync::OwnedSemaphorePermit> = None;
    let budget = state.upload_kib.clone();
    let in_flight_mib = state.config.max_upload_bytes_in_flight >> 20;
    let mut reserve = |bytes: usize| -> ApiResult<()> {
        let kib = u32::try_from(bytes.div_ceil(1024)).unwrap_or(u32::MAX);
        let permit = budget.clone().try_acquire_many_owned(kib).map_err(|_| {
            FarmError::new(
                ErrorKind::Busy,
                format!(
                    "scene uploads being received hold {in_flight_mib} MiB, the most this coordinator holds at once (--max-uploads-in-flight-mib); try again shortly"
                ),
            )
        })?;
        match &mut held {
            Some(h) => h.merge(permit),
            None => held = Some(permit),
        }
        Ok(())
    };
    let bytes = read_body_reserving(
        body,
        state.config.max_upload_bytes,
        state.config.body_stall,
        &mut reserve,
    )
    .await?;
    let declared = match content_type(&headers).as_deref() {
        Some("model/gltf-binary") => Some(Format::Glb),
        Some("model/gltf+json") => Some(Format::Gltf),
        Some("application/zip") | Some("application/x-zip-compressed") => Some(Format::Zip),
        Some("application/octet-stream") | None => None,
        Some(other) => {
            return Err(FarmError::new(
                ErrorKind::UnsupportedMediaType,
                format!("Content-Type {other} is not a scene: use model/gltf-binary, model/gltf+json, application/zip or application/octet-stream"),
            ))
        }
    };
    let farm = state.farm.clone();
    let info = blocking(move || store_upload(&farm, &bytes, declared)).await?;
    let status = if info.created { StatusCode::CREATED } else { StatusCode::OK };
    Ok((status, Json(info)).into_response())
}

async fn download_scene(
    State(state): State<AppState>,
    Path(hash): Path<String>,
) -> ApiResult<Response> {
    // Streamed from its file: workers fetching a large scene at once hold none of it.
    let path = blocking(move || state.lock().scene_file(&hash)).await?;
    let file = tokio::fs::File::open(&path)
        .await
        .map_err(|e| FarmError::internal(format!("scene {}: {e}", path.display())))?;
    let len = file
        .metadata()
        .await
        .map_err(|e| FarmError::internal(format!("scene {}: {e}", path.display())))?
        .len();
    Ok((
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("application/octet-stream")),
            (header::CONTENT_LENGTH, HeaderValue::from(len)),
        ],
        Body::from_stream(file_chunks(file)),
    )
        .into_response())
}
