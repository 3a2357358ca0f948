//! `coordinator submit` and `coordinator healthcheck`: a user's client of a running farm over its
//! REST API. Submit bundles a scene (with the files it uses and the environment map), uploads it,
//! creates a job, follows its progress, and downloads every frame as EXR and PNG.

use std::{
    path::Path,
    time::{Duration, Instant},
};

use anyhow::{bail, Context, Result};
use common::settings::RenderSettings;
use serde_json::{json, Value};

use crate::{
    local::{bundle_scene, http_error, numbered, Progress, Stage},
    output::{self, is_black, read_exr_rgb},
};

/// Where the farm is and how to talk to it.
#[derive(Clone, Debug)]
pub struct Remote {
    /// Base URL (`http://host:port`).
    pub url: String,
    /// Bearer token of the user API, when the coordinator has one.
    pub api_token: Option<String>,
}

impl Remote {
    fn agent(&self) -> ureq::Agent {
        ureq::AgentBuilder::new()
            .timeout_connect(Duration::from_secs(10))
            .timeout_read(Duration::from_secs(600))
            .build()
    }

    fn with_auth(&self, req: ureq::Request) -> ureq::Request {
        match &self.api_token {
            Some(t) => req.set("authorization", &format!("Bearer {t}")),
            None => req,
        }
    }

    /// Uploads a scene bundle and creates a job on it (named `name`, where given); returns
    /// (scene hash, job id).
    pub fn create_job(
        &self,
        bundle: &[u8],
        settings: &RenderSettings,
        priority: i32,
        name: Option<&str>,
    ) -> Result<(String, String)> {
        let agent = self.agent();
        let base = self.url.trim_end_matches('/');
        let scene: Value = self
            .with_auth(agent.post(&format!("{base}/api/v1/scenes")))
            .set("content-type", "application/octet-stream")
            .send_bytes(bundle)
            .map_err(|e| http_error("uploading the scene", e))?
            .into_json()?;
        let hash = scene["scene"].as_str().context("upload answer without a hash")?.to_string();
        let mut body = json!({"scene": hash, "settings": settings, "priority": priority});
        // Only where given: a coordinator from before job names refuses the key.
        if let Some(name) = name {
            body["name"] = json!(name);
        }
        let job: Value = self
            .with_auth(agent.post(&format!("{base}/api/v1/jobs")))
            .send_json(body)
            .map_err(|e| http_error("creating the job", e))?
            .into_json()?;
        let id = job["id"].as_str().context("job answer without an id")?.to_string();
        Ok((hash, id))
    }

    fn get(&self, agent: &ureq::Agent, path: &str) -> Result<ureq::Response> {
        let url = format!("{}{path}", self.url.trim_end_matches('/'));
        self.with_auth(agent.get(&url)).call().map_err(|e| http_error(&format!("GET {path}"), e))
    }
}

/// A finished job, as `submit` saw it.
pub struct Submitted {
    /// The final job status (`GET /api/v1/jobs/{id}`).
    pub status: Value,
    /// Files written (EXR then PNG per frame).
    pub outputs: Vec<std::path::PathBuf>,
    /// The last frame is black.
    pub black: bool,
    /// The last frame's mean luminance, where it is nearly black (`output::nearly_black`).
    pub nearly_black: Option<f64>,
}

/// Submits `scene_path` with `settings` to the farm (a job named `name`, where given), waits for
/// the job, and writes its frames to `out` (`OUT_####.exr` for frame ranges) with PNG previews.
pub fn submit(
    remote: &Remote,
    scene_path: &Path,
    settings: &RenderSettings,
    priority: i32,
    name: Option<&str>,
    out: &Path,
    progress: Progress<'_>,
) -> Result<Submitted> {
    settings.validate()?;
    if let Some(name) = name {
        crate::farm::validate_job_name(name).map_err(|e| anyhow::anyhow!("--{}", e.message))?;
    }
    progress(Stage::Loading);
    let bundle = bundle_scene(scene_path, settings, &Default::default())?;
    let (hash, id) = remote.create_job(&bundle.bytes, &bundle.settings, priority, name)?;
    let agent = remote.agent();
    tracing::info!(job = %id, scene = %hash, "job submitted");
    let mut unreachable_since: Option<Instant> = None;
    let status = loop {
        match remote.get(&agent, &format!("/api/v1/jobs/{id}")) {
            Ok(resp) => {
                unreachable_since = None;
                let status: Value = resp.into_json()?;
                let done = status["samples_done"].as_u64().unwrap_or(0);
                let total = status["samples_planned"].as_u64().unwrap_or(0)
                    - status["samples_saved"].as_u64().unwrap_or(0);
                progress(match (status["state"].as_str(), done) {
                    (Some("queued"), _) => Stage::Queued,
                    (_, 0) => Stage::Preparing,
                    _ => Stage::Rendering { done, total },
                });
                if matches!(status["state"].as_str(), Some("done" | "failed" | "cancelled")) {
                    break status;
                }
            }
            // The coordinator may be restarting: keep asking for a while.
            Err(e) => {
                let since = *unreachable_since.get_or_insert_with(Instant::now);
                if since.elapsed() > Duration::from_secs(300) {
                    return Err(e.context("the coordinator stopped answering"));
                }
            }
        }
        std::thread::sleep(Duration::from_millis(250));
    };
    if status["state"] != "done" {
        bail!(
            "job {id} ended {}: {}",
            status["state"].as_str().unwrap_or("?"),
            status["error"].as_str().unwrap_or("")
        );
    }
    let frames: Vec<i64> = status["frames"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_i64).collect())
        .unwrap_or_default();
    let mut outputs = Vec::new();
    for &frame in &frames {
        let exr_path = if frames.len() > 1 { numbered(out, frame) } else { out.to_path_buf() };
        for (ext, path) in [("exr", exr_path.clone()), ("png", exr_path.with_extension("png"))] {
            let resp = remote.get(&agent, &format!("/api/v1/jobs/{id}/frames/{frame}.{ext}"))?;
            let mut bytes = Vec::new();
            std::io::Read::read_to_end(&mut resp.into_reader(), &mut bytes)?;
            std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
            outputs.push(path);
        }
    }
    let (black, nearly_black) = match outputs.iter().rev().nth(1) {
        Some(last_exr) => {
            let rgb = read_exr_rgb(last_exr)?.2;
            (is_black(&rgb), output::nearly_black(&rgb))
        }
        None => (false, None),
    };
    Ok(Submitted { status, outputs, black, nearly_black })
}

/// Exits non-zero unless `url` answers `/healthz` (the container image's health check).
pub fn healthcheck(url: &str) -> Result<()> {
    let agent = ureq::AgentBuilder::new().timeout(Duration::from_secs(5)).build();
    let url = format!("{}/healthz", url.trim_end_matches('/'));
    agent.get(&url).call().map_err(|e| http_error(&url, e))?;
    Ok(())
}
