//! How a worker reaches its coordinator: the farm protocol's calls as a trait ([`Link`]), over
//! HTTP for `worker --join` ([`HttpLink`]); `coordinator render` links its local workers to its
//! farm in-process instead (the coordinator's `service::LocalLink`), with the same leases,
//! checks and merging but no sockets or encoding.

use std::{
    sync::{
        atomic::{AtomicBool, Ordering},
        mpsc::RecvTimeoutError,
        Arc,
    },
    time::Duration,
};

/// How often a waiting lease request looks at the stop flag ([`HttpLink::stop_waiting_on`]).
pub const STOP_POLL: Duration = Duration::from_millis(50);

use common::{
    error::ErrorKind,
    protocol::{
        encode_result, FailReport, JoinRequest, JoinResponse, LeaseGrant, TaskResult, WORKER_HEADER,
    },
};

/// Why a call failed.
#[derive(Clone, Debug)]
pub enum CallError {
    /// The coordinator refused the call: the kind of refusal and its message.
    Refused(ErrorKind, String),
    /// No answer (connection refused, reset, timed out).
    Transport(String),
}

impl std::fmt::Display for CallError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CallError::Refused(kind, msg) => write!(f, "{kind}: {msg}"),
            CallError::Transport(msg) => write!(f, "coordinator unreachable: {msg}"),
        }
    }
}

/// The worker's side of the farm protocol (`PRODUCT.md`, "Interfaces"): one method per call.
pub trait Link: Sync {
    /// Where the coordinator is, for messages.
    fn describe(&self) -> String;
    /// Joins the farm.
    fn join(&self, req: &JoinRequest) -> Result<JoinResponse, CallError>;
    /// Asks for a task, waiting up to `wait_s` seconds for one; `None`: no work.
    fn lease(&self, worker: &str, wait_s: f64) -> Result<Option<LeaseGrant>, CallError>;
    /// The scene bundle with this hash.
    fn scene(&self, hash: &str) -> Result<Vec<u8>, CallError>;
    /// Renews a lease.
    fn heartbeat(&self, worker: &str, lease: &str) -> Result<(), CallError>;
    /// Hands in a lease's result. The link takes it: an in-process one keeps its sums without a
    /// copy, a network one sends it (and sends again what the network lost).
    fn submit(&self, worker: &str, lease: &str, result: TaskResult) -> Result<(), CallError>;
    /// Reports that a lease's task cannot be rendered.
    fn fail(&self, worker: &str, lease: &str, report: &FailReport) -> Result<(), CallError>;
    /// Leaves the farm.
    fn leave(&self, worker: &str) -> Result<(), CallError>;
    /// Whether one thread should lease, render and hand in each task in turn rather than pass
    /// tasks and results between a leasing, a rendering and a sending thread: true for a link
    /// whose calls are cheaper than a thread's wake-up (an in-process one); a network link keeps
    /// the three, so that leasing ahead and uploading overlap rendering.
    fn hands_in_inline(&self) -> bool {
        false
    }
}

/// The farm protocol over HTTP (`/api/v1/...`), results as bincode.
pub struct HttpLink {
    agent: ureq::Agent,
    base: String,
    auth: Option<String>,
    /// Raised when the worker is told to stop: a lease request waiting for work gives up.
    stop: Option<Arc<AtomicBool>>,
}

impl HttpLink {
    /// A link to the coordinator at `url`, sending `token` as a bearer token. Lease requests may
    /// wait up to `wait_s` seconds for work.
    pub fn new(url: &str, token: Option<&str>, wait_s: f64) -> Self {
        // Leases, results and heartbeats go out on three threads at once: keep a connection for
        // each instead of reconnecting.
        let agent = ureq::AgentBuilder::new()
            .max_idle_connections_per_host(4)
            .timeout_connect(Duration::from_secs(5))
            .timeout_read(Duration::from_secs_f64(wait_s + 60.0))
            .timeout_write(Duration::from_secs(60))
            .build();
        HttpLink {
            agent,
            base: url.trim_end_matches('/').to_string(),
            auth: token.map(|t| format!("Bearer {t}")),
            stop: None,
        }
    }

    /// Lease requests stop waiting for work, and answer "no work", as soon as `stop` is raised
    /// (within [`STOP_POLL`]): an idle worker told to stop leaves at once instead of at the end
    /// of its long poll. The abandoned request ends on its own; a task it is granted meanwhile
    /// goes back when the worker leaves (a grant after that is refused: the worker is gone).
    pub fn stop_waiting_on(mut self, stop: Arc<AtomicBool>) -> Self {
        self.stop = Some(stop);
        self
    }

    fn url(&self, path: &str) -> String {
        format!("{}/api/v1{path}", self.base)
    }

    fn post(&self, path: &str) -> ureq::Request {
        self.authorize(self.agent.post(&self.url(path)))
    }

    fn post_lease(&self, worker: &str, lease: &str, what: &str) -> ureq::Request {
        self.post(&format!("/leases/{lease}/{what}")).set(WORKER_HEADER, worker)
    }

    fn authorize(&self, req: ureq::Request) -> ureq::Request {
        match &self.auth {
            Some(value) => req.set("authorization", value),
            None => req,
        }
    }
}

/// An HTTP error as the refusal it carries. A status of no kind (a proxy's) stays in the
/// message.
fn call_error(e: ureq::Error) -> CallError {
    match e {
        ureq::Error::Status(code, resp) => {
            let text = resp.into_string().unwrap_or_default();
            let msg = serde_json::from_str::<serde_json::Value>(&text)
                .ok()
                .and_then(|v| v.get("error").and_then(|e| e.as_str()).map(str::to_string))
                .unwrap_or(text);
            let kind = ErrorKind::from_http_status(code);
            let msg = if kind.http_status() == code { msg } else { format!("HTTP {code}: {msg}") };
            CallError::Refused(kind, msg)
        }
        ureq::Error::Transport(t) => CallError::Transport(t.to_string()),
    }
}

impl Link for HttpLink {
    fn describe(&self) -> String {
        self.base.clone()
    }

    fn join(&self, req: &JoinRequest) -> Result<JoinResponse, CallError> {
        let resp = self.post("/workers").send_json(req).map_err(call_error)?;
        resp.into_json().map_err(|e| CallError::Transport(e.to_string()))
    }

    fn lease(&self, worker: &str, wait_s: f64) -> Result<Option<LeaseGrant>, CallError> {
        let request = self.post(&format!("/workers/{worker}/lease?wait_s={wait_s}"));
        let call = move || -> Result<Option<LeaseGrant>, CallError> {
            let resp = request.call().map_err(call_error)?;
            if resp.status() == 204 {
                return Ok(None);
            }
            resp.into_json().map(Some).map_err(|e| CallError::Transport(e.to_string()))
        };
        let Some(stop) = &self.stop else { return call() };
        // The long poll runs on its own thread, so that this one can stop waiting for it.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("lease-poll".into())
            .spawn(move || {
                let _ = tx.send(call());
            })
            .map_err(|e| CallError::Transport(format!("starting the lease request: {e}")))?;
        loop {
            match rx.recv_timeout(STOP_POLL) {
                Ok(answer) => return answer,
                Err(RecvTimeoutError::Timeout) if stop.load(Ordering::Relaxed) => return Ok(None),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(CallError::Transport("the lease request was lost".into()))
                }
            }
        }
    }

    fn scene(&self, hash: &str) -> Result<Vec<u8>, CallError> {
        let resp = self
            .authorize(self.agent.get(&self.url(&format!("/scenes/{hash}"))))
            .call()
            .map_err(call_error)?;
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut resp.into_reader(), &mut bytes)
            .map_err(|e| CallError::Transport(e.to_string()))?;
        Ok(bytes)
    }

    fn heartbeat(&self, worker: &str, lease: &str) -> Result<(), CallError> {
        self.post_lease(worker, lease, "heartbeat").call().map(|_| ()).map_err(call_error)
    }

    /// Sends the result; what the network loses (no answer) is sent again, from the same bytes,
    /// up to five times with a growing pause.
    fn submit(&self, worker: &str, lease: &str, result: TaskResult) -> Result<(), CallError> {
        let bytes = encode_result(&result);
        drop(result);
        let mut attempt = 0;
        loop {
            let sent = self
                .post_lease(worker, lease, "result")
                .set("content-type", "application/octet-stream")
                .send_bytes(&bytes)
                .map(|_| ())
                .map_err(call_error);
            match sent {
                Err(CallError::Transport(e)) if attempt < 5 => {
                    attempt += 1;
                    tracing::warn!(lease = %lease, "sending the result: {e}; retrying");
                    std::thread::sleep(Duration::from_millis(200 << attempt));
                }
                answer => return answer,
            }
        }
    }

    fn fail(&self, worker: &str, lease: &str, report: &FailReport) -> Result<(), CallError> {
        self.post_lease(worker, lease, "fail").send_json(report).map(|_| ()).map_err(call_error)
    }

    fn leave(&self, worker: &str) -> Result<(), CallError> {
        self.authorize(self.agent.delete(&self.url(&format!("/workers/{worker}"))))
            .set(WORKER_HEADER, worker)
            .call()
            .map(|_| ())
            .map_err(call_error)
    }
}
