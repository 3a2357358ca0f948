//! `coordinator serve`: the farm over HTTP (axum). The REST API of PRODUCT.md for users and the
//! worker protocol, both under `/api/v1` and described by `/api/v1/openapi.json`; `/healthz`,
//! `/metrics` (Prometheus text) and a dashboard at `/`.
//!
//! Every error is a 4xx/5xx with a JSON body `{"error": "..."}` naming the problem: the farm's
//! refusals ([`FarmError`]) get their status here, from their kind, and nowhere else. The farm
//! state sits behind one mutex; slow work (validating an upload, decoding a result, encoding an
//! image) runs outside it on blocking threads, and a merge holds it only for the in-memory
//! addition and the database commit.

mod auth;
mod local_link;
mod metrics;

pub use local_link::LocalLink;

use std::{
    net::SocketAddr,
    sync::{
        atomic::{AtomicBool, Ordering},
        Arc, Mutex, MutexGuard,
    },
    time::Duration,
};

use anyhow::{Context, Result};
use axum::{
    body::Body,
    extract::{Path, State},
    http::{header, HeaderMap, HeaderValue, StatusCode},
    response::{Html, IntoResponse, Response},
    routing::{get, post},
    Json, Router,
};
use common::{
    bundle::Format,
    protocol::{decode_result, FailReport, JoinRequest, WORKER_HEADER},
    settings::RenderSettings,
};
use serde::Deserialize;
use serde_json::json;
use tokio::sync::Notify;

use crate::{
    farm::{validate_job_scene, validate_upload, ErrorKind, Farm, FarmConfig, FarmError},
    output::{exr_bytes, png_bytes, FrameInfo},
};

/// The service's settings.
#[derive(Clone, Debug)]
pub struct ServiceConfig {
    /// The farm's settings.
    pub farm: FarmConfig,
    /// Largest accepted upload (scenes and results).
    pub max_upload_bytes: usize,
    /// How long a lease request may wait for work.
    pub max_lease_wait: Duration,
    /// Workers must present this bearer token (when set).
    pub join_token: Option<String>,
    /// Users must present this bearer token to the user API (when set).
    pub api_token: Option<String>,
}

impl ServiceConfig {
    /// Defaults for a data folder.
    pub fn new(data_dir: std::path::PathBuf) -> Self {
        ServiceConfig {
            farm: FarmConfig::new(data_dir),
            max_upload_bytes: 1 << 30,
            max_lease_wait: Duration::from_secs(30),
            join_token: None,
            api_token: None,
        }
    }
}

#[derive(Clone)]
struct AppState {
    farm: Arc<Mutex<Farm>>,
    work: Arc<Notify>,
    config: Arc<ServiceConfig>,
    /// Set when the embedding process is about to stop: lease requests answer at once.
    draining: Arc<AtomicBool>,
}

impl AppState {
    fn lock(&self) -> MutexGuard<'_, Farm> {
        lock_farm(&self.farm)
    }
}

fn lock_farm(farm: &Mutex<Farm>) -> MutexGuard<'_, Farm> {
    farm.lock().unwrap_or_else(|p| p.into_inner())
}

/// `POST /scenes` after the body is read: checks the upload and stores it. Slow (it loads the
/// scene): call it off the async threads.
fn store_upload(
    farm: &Mutex<Farm>,
    bytes: &[u8],
    declared: Option<Format>,
) -> ApiResult<crate::farm::SceneInfo> {
    let mut info = validate_upload(bytes, declared)?;
    lock_farm(farm).put_scene(bytes, &mut info)?;
    Ok(info)
}

/// `POST /jobs` after the body is parsed: checks the settings against the farm and the stored
/// scene, and creates the job. Slow (it may load the scene): call it off the async threads.
fn create_checked_job(
    farm: &Mutex<Farm>,
    scene: &str,
    settings: RenderSettings,
    priority: i32,
) -> ApiResult<crate::farm::job::JobStatus> {
    lock_farm(farm).check_settings(&settings)?;
    let path = lock_farm(farm).scene_file(scene).map_err(|e| match e.kind {
        ErrorKind::NotFound => {
            FarmError::not_found(format!("{}: upload it to /api/v1/scenes first", e.message))
        }
        _ => e,
    })?;
    let bytes = std::fs::read(path).map_err(|e| FarmError::internal(format!("scene: {e}")))?;
    validate_job_scene(&bytes, &settings)?;
    lock_farm(farm).create_job(scene, settings, priority)
}

/// The HTTP status of each kind of refusal (the table is `common::error`'s, which the worker's
/// HTTP link reads back).
fn status_of(kind: ErrorKind) -> StatusCode {
    StatusCode::from_u16(kind.http_status()).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR)
}

impl IntoResponse for FarmError {
    fn into_response(self) -> Response {
        (status_of(self.kind), Json(json!({ "error": self.message }))).into_response()
    }
}

type ApiResult<T> = Result<T, FarmError>;

/// Runs blocking work off the async threads.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> ApiResult<T> + Send + 'static,
) -> ApiResult<T> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| FarmError::internal(format!("internal error: {e}")))?
}

/// Reads a whole body, with clear errors for oversize and truncated ones.
async fn read_body(body: Body, limit: usize) -> ApiResult<axum::body::Bytes> {
    use http_body_util::BodyExt;
    // Past the limit the rest is still read (and dropped), up to a cap, so that a client that is
    // still sending hears the 413 instead of a broken connection.
    let drain_cap = limit.saturating_mul(4).max(64 << 20);
    let mut body = body;
    let mut kept: Vec<u8> = Vec::new();
    let mut total = 0usize;
    while let Some(frame) = body.frame().await {
        let frame = frame.map_err(|e| {
            let source =
                std::error::Error::source(&e).map(|s| format!(": {s}")).unwrap_or_default();
            FarmError::malformed(format!("the body was cut short or unreadable: {e}{source}"))
        })?;
        if let Ok(data) = frame.into_data() {
            total = total.saturating_add(data.len());
            if total <= limit {
                kept.extend_from_slice(&data);
            } else if total > drain_cap {
                break;
            }
        }
    }
    if total > limit {
        return Err(FarmError::new(
            ErrorKind::TooLarge,
            format!("the body is larger than the limit of {limit} bytes"),
        ));
    }
    Ok(kept.into())
}

fn content_type(headers: &HeaderMap) -> Option<String> {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .map(|v| v.split(';').next().unwrap_or("").trim().to_ascii_lowercase())
}

/// Reads a JSON body into `T`.
/// The body is read before any header is judged, so that a client still sending it hears the
/// answer instead of a broken connection.
async fn json_body<T: serde::de::DeserializeOwned>(
    headers: &HeaderMap,
    body: Body,
) -> ApiResult<T> {
    let bytes = read_body(body, 1 << 20).await?;
    match content_type(headers).as_deref() {
        Some("application/json") => {}
        other => {
            return Err(FarmError::new(
                ErrorKind::UnsupportedMediaType,
                format!("expected Content-Type application/json, got {}", other.unwrap_or("none")),
            ))
        }
    }
    let de = &mut serde_json::Deserializer::from_slice(&bytes);
    serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        let at = if path == "." { String::new() } else { format!("{path}: ") };
        FarmError::invalid(format!("request body: {at}{}", e.into_inner()))
    })
}

/// The router of the whole service.
fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(dashboard))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics::metrics))
        .route("/api/v1/openapi.json", get(openapi))
        .route("/api/v1/scenes", post(upload_scene))
        .route("/api/v1/scenes/{hash}", get(download_scene))
        .route("/api/v1/jobs", post(create_job).get(list_jobs))
        .route("/api/v1/jobs/{id}", get(job_status).delete(cancel_job))
        .route("/api/v1/jobs/{id}/frames/{file}", get(frame_image))
        .route("/api/v1/workers", get(list_workers).post(join))
        .route("/api/v1/workers/{id}", axum::routing::delete(leave))
        .route("/api/v1/workers/{id}/lease", post(lease))
        .route("/api/v1/leases/{lease}/heartbeat", post(heartbeat))
        .route("/api/v1/leases/{lease}/result", post(submit_result))
        .route("/api/v1/leases/{lease}/fail", post(fail_task))
        .fallback(|uri: axum::http::Uri| async move {
            FarmError::not_found(format!("no such endpoint: {uri} (see /api/v1/openapi.json)"))
        })
        .method_not_allowed_fallback(
            |method: axum::http::Method, uri: axum::http::Uri| async move {
                FarmError::new(
                    ErrorKind::MethodNotAllowed,
                    format!("{method} is not allowed on {uri}"),
                )
            },
        )
        .layer(axum::middleware::from_fn_with_state(state.clone(), auth::check))
        .with_state(state)
}

/// A running service: its address and a handle to stop it.
pub struct Running {
    /// The address it listens on.
    pub addr: SocketAddr,
    farm: Arc<Mutex<Farm>>,
    draining: Arc<AtomicBool>,
    work: Arc<Notify>,
    max_lease_wait: Duration,
    handins: Arc<local_link::Handins>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<Result<()>>>,
}

impl Running {
    /// The base URL (`http://addr`).
    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// The farm state, for an embedding process that wants to read it directly.
    pub fn farm(&self) -> Arc<Mutex<Farm>> {
        self.farm.clone()
    }

    /// A link for workers in this process: the farm protocol without HTTP.
    pub fn local_link(&self) -> LocalLink {
        LocalLink {
            farm: self.farm.clone(),
            work: self.work.clone(),
            draining: self.draining.clone(),
            max_lease_wait: self.max_lease_wait,
            handins: self.handins.clone(),
        }
    }

    /// Stores `bundle` and creates a job on it, with the checks and refusals of `POST /scenes`
    /// and `POST /jobs` but no HTTP (the embedded render). Returns the scene hash and the job id.
    pub fn create_job(
        &self,
        bundle: &[u8],
        settings: RenderSettings,
        priority: i32,
    ) -> Result<(String, String), FarmError> {
        let info = store_upload(&self.farm, bundle, None)?;
        let status = create_checked_job(&self.farm, &info.scene, settings, priority)?;
        self.work.notify_waiters();
        Ok((info.scene, status.id))
    }

    /// Waits until the local workers have handed in more than `seen` results, failures or
    /// departures, or `timeout` passed; returns how many they have handed in.
    pub fn wait_for_handins(&self, seen: u64, timeout: Duration) -> u64 {
        self.handins.wait_past(seen, timeout)
    }

    /// From now on lease requests answer "no work" at once instead of waiting, so that local
    /// workers told to stop are not held by a long poll.
    pub fn drain(&self) {
        self.draining.store(true, Ordering::Relaxed);
        self.work.notify_waiters();
        // Local workers napping between lease polls see it at once.
        self.handins.wake_all();
    }

    /// Stops the service and waits for it.
    pub fn stop(mut self) -> Result<()> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Result<()> {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        match self.thread.take() {
            Some(t) => t.join().map_err(|_| anyhow::anyhow!("service thread panicked"))?,
            None => Ok(()),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.shutdown();
    }
}

/// Starts the service on its own thread and runtime (used by `coordinator render`).
pub fn spawn(listen: &str, config: ServiceConfig) -> Result<Running> {
    let farm = Arc::new(Mutex::new(Farm::open(config.farm.clone())?));
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let listener = runtime
        .block_on(tokio::net::TcpListener::bind(listen))
        .with_context(|| format!("listening on {listen}"))?;
    let addr = listener.local_addr()?;
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let shared = farm.clone();
    let draining = Arc::new(AtomicBool::new(false));
    let work = Arc::new(Notify::new());
    let (d, w) = (draining.clone(), work.clone());
    let max_lease_wait = config.max_lease_wait;
    let thread = std::thread::Builder::new().name("coordinator".into()).spawn(move || {
        runtime.block_on(serve_farm(listener, shared, config, Some((d, w)), async {
            let _ = rx.await;
        }))
    })?;
    Ok(Running {
        addr,
        farm,
        draining,
        work,
        max_lease_wait,
        handins: Arc::default(),
        stop: Some(tx),
        thread: Some(thread),
    })
}

/// Opens the farm under `config` and serves it on `listener` until `shutdown` completes.
pub async fn serve_on(
    listener: tokio::net::TcpListener,
    config: ServiceConfig,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<()> {
    let farm_config = config.farm.clone();
    let farm = tokio::task::spawn_blocking(move || Farm::open(farm_config))
        .await
        .context("opening the farm")??;
    tracing::info!(data = %config.farm.data_dir.display(), "farm state opened");
    serve_farm(listener, Arc::new(Mutex::new(farm)), config, None, shutdown).await
}

async fn serve_farm(
    listener: tokio::net::TcpListener,
    farm: Arc<Mutex<Farm>>,
    config: ServiceConfig,
    embedded: Option<(Arc<AtomicBool>, Arc<Notify>)>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> Result<()> {
    let (draining, work) = embedded.unwrap_or_default();
    let state = AppState { farm, work, config: Arc::new(config), draining };
    let ticker = {
        let state = state.clone();
        tokio::spawn(async move {
            let mut interval = tokio::time::interval(Duration::from_millis(250));
            loop {
                interval.tick().await;
                let st = state.clone();
                let freed =
                    tokio::task::spawn_blocking(move || st.lock().tick()).await.unwrap_or(false);
                if freed {
                    state.work.notify_waiters();
                }
            }
        })
    };
    let app = router(state.clone());
    // On shutdown, long polls answer "no work" at once instead of holding the server open.
    let shutdown = async move {
        shutdown.await;
        state.draining.store(true, Ordering::Relaxed);
        state.work.notify_waiters();
    };
    let result = axum::serve(listener, app).with_graceful_shutdown(shutdown).await;
    ticker.abort();
    result.context("serving HTTP")
}

async fn dashboard() -> Html<&'static str> {
    Html(include_str!("dashboard.html"))
}

async fn healthz() -> Json<serde_json::Value> {
    Json(json!({ "status": "ok" }))
}

async fn openapi() -> Response {
    (
        [(header::CONTENT_TYPE, HeaderValue::from_static("application/json"))],
        include_str!("openapi.json"),
    )
        .into_response()
}

async fn upload_scene(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let bytes = read_body(body, state.config.max_upload_bytes).await?;
    let declared = match content_type(&headers).as_deref() {
        Some("model/gltf-binary") => Some(Format::Glb),
        Some("model/gltf+json") => Some(Format::Gltf),
        Some("application/zip") | Some("application/x-zip-compressed") => Some(Format::Zip),
        Some("application/octet-stream") | None => None,
        Some(other) => {
            return Err(FarmError::new(ErrorKind::UnsupportedMediaType, format!("Content-Type {other} is not a scene: use model/gltf-binary, model/gltf+json, application/zip or application/octet-stream"),
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
    let bytes = blocking(move || {
        let path = state.lock().scene_file(&hash)?;
        std::fs::read(path).map_err(|e| FarmError::internal(format!("scene {hash}: {e}")))
    })
    .await?;
    Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("application/octet-stream"))], bytes)
        .into_response())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CreateJob {
    scene: String,
    #[serde(default)]
    settings: serde_json::Value,
    #[serde(default)]
    priority: i32,
}

async fn create_job(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let req: CreateJob = json_body(&headers, body).await?;
    let settings_value = if req.settings.is_null() { json!({}) } else { req.settings };
    let settings: RenderSettings =
        serde_path_to_error::deserialize(settings_value).map_err(|e| {
            let path = e.path().to_string();
            let at = if path == "." { String::new() } else { format!(".{path}") };
            FarmError::invalid(format!("settings{at}: {}", e.into_inner()))
        })?;
    let farm = state.farm.clone();
    let status =
        blocking(move || create_checked_job(&farm, &req.scene, settings, req.priority)).await?;
    state.work.notify_waiters();
    Ok((StatusCode::CREATED, Json(status)).into_response())
}

async fn list_jobs(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(json!({ "jobs": state.lock().list() }))
}

async fn job_status(State(state): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    Ok(Json(state.lock().status(&id)?).into_response())
}

async fn cancel_job(State(state): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
    let status = state.lock().cancel(&id)?;
    Ok(Json(status).into_response())
}

async fn frame_image(
    State(state): State<AppState>,
    Path((id, file)): Path<(String, String)>,
) -> ApiResult<Response> {
    let (number, ext) = file
        .rsplit_once('.')
        .and_then(|(n, e)| Some((n.parse::<i64>().ok()?, e.to_ascii_lowercase())))
        .ok_or_else(|| {
            FarmError::not_found(format!(
                "'{file}' is not a frame file: use {{n}}.exr or {{n}}.png"
            ))
        })?;
    if ext != "exr" && ext != "png" {
        return Err(FarmError::not_found(format!("'{file}': frames are served as .exr or .png")));
    }
    let st = state.clone();
    blocking(move || {
        let (image, status) = st.lock().image(&id, number)?;
        if ext == "exr" {
            let info = FrameInfo {
                settings_json: serde_json::to_string(&status.settings).unwrap_or_default(),
                scene_hash: status.scene.clone(),
                render_seconds: status.elapsed_s,
                frame: number,
            };
            let bytes = exr_bytes(image, &info)?;
            Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/x-exr"))], bytes)
                .into_response())
        } else {
            let bytes = png_bytes(&image, 0.0)?;
            Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], bytes)
                .into_response())
        }
    })
    .await
}

async fn list_workers(State(state): State<AppState>) -> Json<serde_json::Value> {
    Json(json!({ "workers": state.lock().workers() }))
}

async fn join(
    State(state): State<AppState>,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let req: JoinRequest = json_body(&headers, body).await?;
    let resp = state.lock().join(req)?;
    Ok((StatusCode::CREATED, Json(resp)).into_response())
}

async fn leave(State(state): State<AppState>, Path(id): Path<String>) -> ApiResult<Response> {
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
    read_body(body, 1 << 16).await?;
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
    read_body(body, 1 << 16).await?;
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
        state.lock().counters.results_refused += 1;
    }
    answer
}

async fn merge_result(
    state: AppState,
    lease: String,
    headers: HeaderMap,
    body: Body,
) -> ApiResult<Response> {
    let bytes = read_body(body, state.config.max_upload_bytes).await?;
    let worker = worker_id(&headers)?;
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
        st.lock().submit(&lease, &worker, result, bytes.len() as u64)
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
    let report: FailReport = json_body(&headers, body).await?;
    let worker = worker_id(&headers)?;
    state.lock().fail(&lease, &worker, &report.error)?;
    state.work.notify_waiters();
    Ok(Json(json!({ "released": true })).into_response())
}
