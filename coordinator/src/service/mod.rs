//! `coordinator serve`: the farm over HTTP (axum). The REST API of PRODUCT.md for users and the
//! worker protocol, both under `/api/v1` and described by `/api/v1/openapi.json`; `/healthz`,
//! `/metrics` (Prometheus text) and a dashboard at `/`.
//!
//! Every error is a 4xx/5xx with a JSON body `{"error": "..."}` naming the problem: the farm's
//! refusals ([`FarmError`]) get their status here, from their kind, and nowhere else. The farm
//! state sits behind one mutex; slow work (validating an upload, decoding a result, encoding an
//! image) runs outside it on blocking threads, and a merge holds it only for the in-memory
//! addition and the database commit.
//!
//! # Routes, by the file that handles them
//! - here: `GET /`, `GET /healthz`, `GET /api/v1/openapi.json`; `metrics.rs`: `GET /metrics`.
//! - `scenes.rs`: `POST /api/v1/scenes`, `GET /api/v1/scenes/{hash}`.
//! - `jobs.rs`: `POST|GET /api/v1/jobs`, `GET|DELETE /api/v1/jobs/{id}`,
//!   `POST /api/v1/jobs/{id}/cancel`; `frames.rs`: `GET /api/v1/jobs/{id}/frames/{n}.exr|png`.
//! - `workers.rs`: `GET|POST /api/v1/workers`, `DELETE /api/v1/workers/{id}`,
//!   `POST /api/v1/workers/{id}/lease`.
//! - `leases.rs`: `POST /api/v1/leases/{lease}/heartbeat|result|fail`.
//!
//! `auth.rs` checks tokens before any of them; `local_link.rs` is the worker protocol without
//! HTTP, for the local workers of `coordinator render`.

mod auth;
mod frames;
mod jobs;
mod leases;
mod listen;
mod local_link;
mod metrics;
mod refusals;
mod scenes;
mod workers;

pub use listen::{bind, ConnectionLimits};
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
    http::{header, HeaderMap, HeaderValue, StatusCode},
    response::{Html, IntoResponse, Response},
    routing::get,
    Json, Router,
};
use common::settings::RenderSettings;
use serde_json::json;
use tokio::sync::Notify;

use crate::farm::{ErrorKind, Farm, FarmConfig, FarmError};

/// The service's settings.
#[derive(Clone, Debug)]
pub struct ServiceConfig {
    /// The farm's settings.
    pub farm: FarmConfig,
    /// Largest accepted scene upload.
    pub max_upload_bytes: usize,
    /// Most bytes of scene uploads held at once, over all uploads being received and checked;
    /// past it an upload is refused as busy (503).
    pub max_upload_bytes_in_flight: usize,
    /// How long a lease request may wait for work.
    pub max_lease_wait: Duration,
    /// Workers must present this bearer token (when set).
    pub join_token: Option<String>,
    /// Users must present this bearer token to the user API (when set).
    pub api_token: Option<String>,
    /// Connection limits: header read time, connections open at once.
    pub connections: listen::ConnectionLimits,
    /// A request body that sends nothing for this long is refused.
    pub body_stall: Duration,
    /// Scene uploads received at once; more are refused as busy (503).
    pub max_concurrent_uploads: usize,
}

impl ServiceConfig {
    /// Defaults for a data folder.
    pub fn new(data_dir: std::path::PathBuf) -> Self {
        ServiceConfig {
            farm: FarmConfig::new(data_dir),
            max_upload_bytes: 1 << 30,
            max_upload_bytes_in_flight: 2 << 30,
            max_lease_wait: Duration::from_secs(30),
            join_token: None,
            api_token: None,
            connections: listen::ConnectionLimits {
                header_timeout: Duration::from_secs(10),
                max_connections: 4096,
            },
            body_stall: Duration::from_secs(30),
            max_concurrent_uploads: 4,
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
    /// One permit per scene upload being received.
    uploads: Arc<tokio::sync::Semaphore>,
    /// One permit per KiB of scene uploads held.
    upload_kib: Arc<tokio::sync::Semaphore>,
    /// Refused requests: counts, and the log's rate limit.
    refusals: Arc<Mutex<refusals::Refusals>>,
}

impl AppState {
    fn lock(&self) -> MutexGuard<'_, Farm> {
        lock_farm(&self.farm)
    }
}

fn lock_farm(farm: &Mutex<Farm>) -> MutexGuard<'_, Farm> {
    farm.lock().unwrap_or_else(|p| p.into_inner())
}

/// The HTTP status of each kind of refusal (the table is `common::error`'s, which the worker's
/// HTTP link reads back).
fn status_of(kind: ErrorKind) -> StatusCode {
    StatusCode::from_u16(kind.http_status()).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR)
}

impl IntoResponse for FarmError {
    fn into_response(self) -> Response {
        let mut response =
            (status_of(self.kind), Json(json!({ "error": self.message.clone() }))).into_response();
        // For the refusals log (`refusals.rs`), which runs outside every handler.
        response.extensions_mut().insert(self);
        response
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
async fn read_body(body: Body, limit: usize, stall: Duration) -> ApiResult<axum::body::Bytes> {
    read_body_reserving(body, limit, stall, &mut |_| Ok(())).await
}

/// [`read_body`], asking `reserve` for each chunk's bytes before keeping them: a refusal stops
/// the keeping (what was kept is dropped), and is the answer once the rest of the body is
/// drained, so that a client still sending hears it.
async fn read_body_reserving(
    body: Body,
    limit: usize,
    stall: Duration,
    reserve: &mut (dyn FnMut(usize) -> ApiResult<()> + Send),
) -> ApiResult<axum::body::Bytes> {
    use http_body_util::BodyExt;
    // Past the limit the rest is still read (and dropped), up to a cap, so that a client that is
    // still sending hears the 413 instead of a broken connection.
    let drain_cap = limit.saturating_mul(4).max(64 << 20);
    let mut body = body;
    let mut kept: Vec<u8> = Vec::new();
    let mut total = 0usize;
    let mut refused = None;
    loop {
        // A client that stops sending does not hold its connection and buffer for ever.
        let Ok(frame) = tokio::time::timeout(stall, body.frame()).await else {
            return Err(FarmError::malformed(format!(
                "the body stalled: nothing arrived for {} s after {total} bytes (--body-timeout)",
                stall.as_secs_f64()
            )));
        };
        let Some(frame) = frame else { break };
        let frame = frame.map_err(|e| {
            let source =
                std::error::Error::source(&e).map(|s| format!(": {s}")).unwrap_or_default();
            FarmError::malformed(format!("the body was cut short or unreadable: {e}{source}"))
        })?;
        if let Ok(data) = frame.into_data() {
            total = total.saturating_add(data.len());
            if total <= limit && refused.is_none() {
                match reserve(data.len()) {
                    Ok(()) => kept.extend_from_slice(&data),
                    Err(e) => {
                        refused = Some(e);
                        kept = Vec::new();
                    }
                }
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
    match refused {
        Some(e) => Err(e),
        None => Ok(kept.into()),
    }
}

/// A file's bytes from where it stands, 256 KiB at a time, for a streamed response body (the
/// stream ends after an error).
fn file_chunks(
    file: tokio::fs::File,
) -> impl futures_util::Stream<Item = std::io::Result<axum::body::Bytes>> + Send + 'static {
    use tokio::io::AsyncReadExt;
    futures_util::stream::unfold(Some(file), |file| async move {
        let mut file = file?;
        let mut buf = vec![0; 256 << 10];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok(axum::body::Bytes::from(buf)), Some(file)))
            }
            Err(e) => Some((Err(e), None)),
        }
    })
}

/// Reads a body to its end without keeping it (up to `cap` bytes; past that the rest is left
/// unread and the connection closes after the answer), so that a refusal decided before
/// reading reaches a client that is still sending.
async fn discard_body(body: Body, cap: usize, stall: Duration) -> ApiResult<()> {
    use http_body_util::BodyExt;
    let mut body = body;
    let mut total = 0usize;
    while total <= cap {
        let Ok(frame) = tokio::time::timeout(stall, body.frame()).await else {
            return Err(FarmError::malformed(format!(
                "the body stalled: nothing arrived for {} s after {total} bytes (--body-timeout)",
                stall.as_secs_f64()
            )));
        };
        match frame {
            Some(Ok(frame)) => total += frame.data_ref().map_or(0, |d| d.len()),
            Some(Err(_)) | None => break,
        }
    }
    Ok(())
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
    state: &AppState,
    headers: &HeaderMap,
    body: Body,
) -> ApiResult<T> {
    let bytes = read_body(body, 1 << 20, state.config.body_stall).await?;
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

/// The router of the whole service: each resource's routes, merged.
fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(dashboard))
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics::metrics))
        .route("/api/v1/openapi.json", get(openapi))
        .merge(scenes::routes())
        .merge(jobs::routes())
        .merge(workers::routes())
        .merge(leases::routes())
        .fallback(|uri: axum::http::Uri| async move {
            FarmError::not_found(format!("no such endpoint: {uri} (see /api/v1/openapi.json)"))
        })
        // After the merges: it applies to the routes added so far.
        .method_not_allowed_fallback(
            |method: axum::http::Method, uri: axum::http::Uri| async move {
                FarmError::new(
                    ErrorKind::MethodNotAllowed,
                    format!("{method} is not allowed on {uri}"),
                )
            },
        )
        .layer(axum::middleware::from_fn_with_state(state.clone(), auth::check))
        // Outermost: it sees the refusals of the token check too.
        .layer(axum::middleware::from_fn_with_state(state.clone(), refusals::log))
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
        let info = scenes::store_upload(&self.farm, bundle, None)?;
        let status =
            jobs::create_checked_job(&self.farm, &info.scene, settings, priority, None, None)?;
        self.work.notify_waiters();
        Ok((info.scene, status.id))
    }

    /// [`Running::create_job`] of a bundle whose scene (and the settings' environment map,
    /// where `env_loaded`) the caller loaded from it within the farm's scene budget: the
    /// checks that need them read these rather than decode them again.
    pub fn create_loaded_job(
        &self,
        bundle: &[u8],
        scene: &common::scene::Scene,
        env_loaded: bool,
        settings: RenderSettings,
        priority: i32,
    ) -> Result<(String, String), FarmError> {
        let info = scenes::store_loaded(&self.farm, bundle, scene)?;
        let loaded = Some((scene, env_loaded));
        let status =
            jobs::create_checked_job(&self.farm, &info.scene, settings, priority, None, loaded)?;
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
    let uploads = Arc::new(tokio::sync::Semaphore::new(config.max_concurrent_uploads.max(1)));
    let kib =
        (config.max_upload_bytes_in_flight >> 10).clamp(1, tokio::sync::Semaphore::MAX_PERMITS);
    let upload_kib = Arc::new(tokio::sync::Semaphore::new(kib));
    let refusals = Arc::new(Mutex::new(refusals::Refusals::new()));
    let state =
        AppState { farm, work, config: Arc::new(config), draining, uploads, upload_kib, refusals };
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
    let (draining, work) = (state.draining.clone(), state.work.clone());
    let shutdown = async move {
        shutdown.await;
        draining.store(true, Ordering::Relaxed);
        work.notify_waiters();
    };
    listen::serve(listener, app, state.config.connections, shutdown).await;
    ticker.abort();
    Ok(())
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
