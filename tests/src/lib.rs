//! Support for the cross-process integration tests in `tests/`: builds and locates the real
//! `coordinator` and `worker` binaries, starts them as processes on loopback ports, and talks to
//! the service over real HTTP.

use std::{
    net::TcpListener,
    path::{Path, PathBuf},
    process::{Child, Command, Stdio},
    sync::OnceLock,
    time::{Duration, Instant},
};

use serde_json::{json, Value};

/// The repository root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The folder holding the release binaries, built once per test process.
pub fn bin_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let status = Command::new(cargo)
            .args(["build", "--release", "-p", "coordinator", "-p", "worker", "--bins"])
            .current_dir(repo())
            .status()
            .expect("running cargo build");
        assert!(status.success(), "building the binaries failed");
        let exe = std::env::current_exe().unwrap();
        // target/release/deps/farm-xxxx -> target/release
        exe.parent().and_then(Path::parent).unwrap().to_path_buf()
    })
}

/// A fresh temporary folder for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("renderfarm-it-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A loopback port free right now.
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A running process whose output goes to a log file; killed (SIGKILL) when dropped.
pub struct Proc {
    /// The process.
    pub child: Child,
    /// Its stderr and stdout.
    pub log: PathBuf,
}

impl Proc {
    fn spawn(mut cmd: Command, log: PathBuf) -> Proc {
        let file = std::fs::File::create(&log).unwrap();
        cmd.stdout(Stdio::from(file.try_clone().unwrap())).stderr(Stdio::from(file));
        cmd.env("RUST_LOG", "info");
        let child = cmd.spawn().expect("starting a process");
        Proc { child, log }
    }

    /// SIGKILL, at once.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then waits up to `timeout` for the exit; returns whether it exited cleanly.
    pub fn terminate(&mut self, timeout: Duration) -> bool {
        let _ = Command::new("kill").args(["-TERM", &self.child.id().to_string()]).status();
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if let Ok(Some(status)) = self.child.try_wait() {
                return status.success();
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        false
    }

    /// The log so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A process's peak resident memory so far, in MiB (`VmHWM`).
pub fn peak_mib(proc: &Proc) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{}/status", proc.child.id())).unwrap();
    let kb: f64 = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .expect("VmHWM in /proc/PID/status");
    kb / 1024.0
}

/// `coordinator serve` on `127.0.0.1:port` with its state in `data`.
pub fn start_coordinator(data: &Path, port: u16, extra: &[&str]) -> Proc {
    let mut cmd = Command::new(bin_dir().join("coordinator"));
    cmd.arg("serve").arg("--listen").arg(format!("127.0.0.1:{port}")).arg("--data").arg(data);
    cmd.args(extra);
    let n = std::fs::read_dir(data).map(|d| d.count()).unwrap_or(0);
    let p = Proc::spawn(cmd, data.with_extension(format!("coordinator-{n}.log")));
    let url = format!("http://127.0.0.1:{port}");
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        if ureq::get(&format!("{url}/healthz")).call().is_ok() {
            return p;
        }
        assert!(Instant::now() < end, "the coordinator did not come up:\n{}", p.log_text());
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// `worker --join url --threads threads`, logging to `log`.
pub fn start_worker(url: &str, threads: u32, log: PathBuf) -> Proc {
    start_worker_with(url, threads, log, &[])
}

/// [`start_worker`] with more arguments.
pub fn start_worker_with(url: &str, threads: u32, log: PathBuf, extra: &[&str]) -> Proc {
    let mut cmd = Command::new(bin_dir().join("worker"));
    cmd.args(["--join", url, "--threads", &threads.to_string(), "--wait", "1"]).args(extra);
    Proc::spawn(cmd, log)
}

/// An HTTP answer: status and body.
pub struct Answer {
    /// HTTP status.
    pub status: u16,
    /// Body bytes.
    pub body: Vec<u8>,
}

impl Answer {
    /// The body as JSON (Null when it is not JSON).
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body).unwrap_or(Value::Null)
    }

    /// The `error` field of a JSON error body.
    pub fn error(&self) -> String {
        self.json()["error"].as_str().unwrap_or_default().to_string()
    }
}

fn answer(r: Result<ureq::Response, ureq::Error>) -> Answer {
    let resp = match r {
        Ok(resp) => resp,
        Err(ureq::Error::Status(_, resp)) => resp,
        Err(e) => panic!("HTTP transport error: {e}"),
    };
    let status = resp.status();
    let mut body = Vec::new();
    std::io::Read::read_to_end(&mut resp.into_reader(), &mut body).unwrap();
    Answer { status, body }
}

/// GET `url`.
pub fn get(url: &str) -> Answer {
    answer(ureq::get(url).call())
}

/// POST raw bytes with a content type (and optional extra headers).
pub fn post_bytes(url: &str, content_type: &str, headers: &[(&str, &str)], body: &[u8]) -> Answer {
    let mut req = ureq::post(url).set("content-type", content_type);
    for (k, v) in headers {
        req = req.set(k, v);
    }
    answer(req.send_bytes(body))
}

/// POST JSON.
pub fn post_json(url: &str, body: &Value) -> Answer {
    post_bytes(url, "application/json", &[], body.to_string().as_bytes())
}

/// DELETE.
pub fn delete(url: &str) -> Answer {
    delete_with(url, &[])
}

/// DELETE with headers.
pub fn delete_with(url: &str, headers: &[(&str, &str)]) -> Answer {
    let mut req = ureq::delete(url);
    for (k, v) in headers {
        req = req.set(k, v);
    }
    answer(req.call())
}

/// The cornell box as a zip bundle (the .gltf and its .bin).
pub fn cornell_zip() -> Vec<u8> {
    let dir = repo().join("scenes");
    common::bundle::Bundle::pack(&[
        ("cornell-box.gltf".into(), std::fs::read(dir.join("cornell-box.gltf")).unwrap()),
        ("cornell-box.bin".into(), std::fs::read(dir.join("cornell-box.bin")).unwrap()),
    ])
    .unwrap()
}

/// Uploads scene bytes; returns its hash.
pub fn upload(url: &str, bytes: &[u8]) -> String {
    let a = post_bytes(&format!("{url}/api/v1/scenes"), "application/octet-stream", &[], &bytes);
    assert!(a.status == 201 || a.status == 200, "upload: {} {}", a.status, a.error());
    a.json()["scene"].as_str().unwrap().to_string()
}

/// Creates a job; returns its id.
pub fn create_job(url: &str, scene: &str, settings: &Value, priority: i32) -> String {
    let a = post_json(
        &format!("{url}/api/v1/jobs"),
        &json!({"scene": scene, "settings": settings, "priority": priority}),
    );
    assert_eq!(a.status, 201, "create job: {}", a.error());
    a.json()["id"].as_str().unwrap().to_string()
}

/// A job's status.
pub fn job_status(url: &str, id: &str) -> Value {
    let a = get(&format!("{url}/api/v1/jobs/{id}"));
    assert_eq!(a.status, 200, "job status: {}", a.error());
    a.json()
}

/// Polls until `pred(status)` holds or `timeout` passes (then panics with the last status).
pub fn wait_for(url: &str, id: &str, timeout: Duration, pred: impl Fn(&Value) -> bool) -> Value {
    let end = Instant::now() + timeout;
    loop {
        if let Ok(resp) = ureq::get(&format!("{url}/api/v1/jobs/{id}")).call() {
            let status: Value = resp.into_json().unwrap();
            if pred(&status) {
                return status;
            }
            assert!(Instant::now() < end, "timed out; last status: {status:#}");
        } else {
            assert!(Instant::now() < end, "timed out waiting for the coordinator");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Waits until the job is done (panics if it fails or is cancelled).
pub fn wait_done(url: &str, id: &str, timeout: Duration) -> Value {
    let status = wait_for(url, id, timeout, |s| {
        matches!(s["state"].as_str(), Some("done" | "failed" | "cancelled"))
    });
    assert_eq!(status["state"], "done", "job ended as {status:#}");
    status
}

/// Fetches frame `n` of a job as EXR bytes.
pub fn fetch_exr(url: &str, id: &str, frame: i64) -> Vec<u8> {
    let a = get(&format!("{url}/api/v1/jobs/{id}/frames/{frame}.exr"));
    assert_eq!(a.status, 200, "fetch frame: {}", a.error());
    a.body
}

/// Every channel of an EXR (bytes), by name, as raw bits.
pub fn channels(bytes: &[u8]) -> Vec<(String, Vec<u32>)> {
    coordinator::output::read_channel_bits(bytes).unwrap()
}

/// The `samples` channel of an EXR.
pub fn sample_counts(bytes: &[u8]) -> Vec<u32> {
    channels(bytes).into_iter().find(|(n, _)| n == "samples").expect("a samples channel").1
}

/// Asserts two EXRs have bit-identical channels (headers may differ: render time).
pub fn assert_same_image(a: &[u8], b: &[u8], what: &str) {
    let (ca, cb) = (channels(a), channels(b));
    assert_eq!(ca.len(), cb.len(), "{what}: channel lists differ");
    for ((na, va), (nb, vb)) in ca.iter().zip(&cb) {
        assert_eq!(na, nb, "{what}: channel names differ");
        let diff = va.iter().zip(vb).filter(|(x, y)| x != y).count();
        assert_eq!(diff, 0, "{what}: channel {na} differs in {diff} of {} pixels", va.len());
    }
}

/// Renders the cornell box with `coordinator render` and `settings` (JSON written to a file);
/// returns the EXR bytes.
pub fn render_reference(dir: &Path, settings: &Value, workers: u32) -> Vec<u8> {
    let settings_path = dir.join("reference-settings.json");
    std::fs::write(&settings_path, settings.to_string()).unwrap();
    let out = dir.join("reference.exr");
    let output = Command::new(bin_dir().join("coordinator"))
        .args(["render", "scenes/cornell-box.gltf", "-o"])
        .arg(&out)
        .arg("--settings")
        .arg(&settings_path)
        .args(["--workers", &workers.to_string()])
        .current_dir(repo())
        .output()
        .unwrap();
    assert!(output.status.success(), "render failed: {}", String::from_utf8_lossy(&output.stderr));
    std::fs::read(out).unwrap()
}

/// A value from the coordinator's `/metrics` (0 when absent).
pub fn metric(url: &str, name: &str) -> f64 {
    let text = String::from_utf8(get(&format!("{url}/metrics")).body).unwrap();
    text.lines()
        .find(|l| l.split_whitespace().next() == Some(name))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

/// Relative MSE of image `a` against `reference` (the benchmarks' metric): mean of
/// (x - r)² / (r² + 0.01) over pixels and channels.
pub fn rel_mse(a: &[u8], reference: &[u8]) -> f64 {
    let rgb = |bytes: &[u8]| -> Vec<Vec<f64>> {
        let ch = channels(bytes);
        ["R", "G", "B"]
            .iter()
            .map(|name| {
                let bits = &ch.iter().find(|(n, _)| n == name).expect("an RGB image").1;
                bits.iter().map(|&b| f32::from_bits(b) as f64).collect()
            })
            .collect()
    };
    let (x, r) = (rgb(a), rgb(reference));
    assert_eq!(x[0].len(), r[0].len(), "an image at the reference's resolution");
    let mut sum = 0.0;
    for c in 0..3 {
        for (a, b) in x[c].iter().zip(&r[c]) {
            sum += (a - b) * (a - b) / (b * b + 0.01);
        }
    }
    sum / (3 * x[0].len()) as f64
}

/// A coordinator on a free loopback port with `workers` one-thread workers and the cornell box
/// uploaded: what most farm tests start from. Everything is killed when it is dropped.
pub struct Cluster {
    /// Base URL.
    pub url: String,
    /// Its port.
    pub port: u16,
    /// The coordinator's data folder.
    pub data: PathBuf,
    /// Hash of the uploaded cornell box.
    pub scene: String,
    /// The coordinator process.
    pub coordinator: Proc,
    /// The worker processes.
    pub workers: Vec<Proc>,
}

impl Cluster {
    /// Starts it in `dir` (`extra` goes to `coordinator serve`).
    pub fn start(dir: &Path, workers: usize, extra: &[&str]) -> Cluster {
        let port = free_port();
        let url = format!("http://127.0.0.1:{port}");
        let data = dir.join("data");
        let coordinator = start_coordinator(&data, port, extra);
        let workers =
            (0..workers).map(|i| start_worker(&url, 1, dir.join(format!("w{i}.log")))).collect();
        let scene = upload(&url, &cornell_zip());
        Cluster { url, port, data, scene, coordinator, workers }
    }

    /// Kills the coordinator with SIGKILL and starts it again on the same data folder and
    /// port (`extra` goes to `coordinator serve`); the workers find it again by themselves.
    pub fn restart_coordinator(&mut self, extra: &[&str]) {
        self.coordinator.kill9();
        std::thread::sleep(Duration::from_millis(500));
        self.coordinator = start_coordinator(&self.data, self.port, extra);
    }
}
