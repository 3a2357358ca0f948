//! `coordinator`: command-line entry point (flags only; the work is in the library).

use std::{
    io::IsTerminal,
    net::{IpAddr, Ipv4Addr, SocketAddr},
    path::{Path, PathBuf},
    time::Duration,
};

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use common::{
    budget::SceneBudget,
    settings::{Environment, Integrator, RenderSettings},
};
use coordinator::{
    client::{healthcheck, submit, Remote},
    local::{render_file_within, Stage},
    output::{
        check_writable, describe_error, exr_output, is_black, nearly_black, nearly_black_warning,
    },
    service::{bind, serve_on, ServiceConfig},
};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Parser)]
#[command(version, about = "Distributed path-tracing render farm: coordinator")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// Render settings: a JSON file, and flags that override it.
#[derive(Args)]
struct SettingsArgs {
    /// Samples per pixel.
    #[arg(long)]
    spp: Option<u32>,
    /// Image width.
    #[arg(long)]
    width: Option<u32>,
    /// Image height.
    #[arg(long)]
    height: Option<u32>,
    /// Sampler seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Maximum path depth (bounces).
    #[arg(long)]
    max_depth: Option<u32>,
    /// Frames to render, `A..B` (inclusive) or `N`; a range writes OUT_####.exr per frame.
    #[arg(long, value_name = "A..B")]
    frames: Option<String>,
    /// Render settings JSON file; flags override it.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Light the scene with this equirectangular environment map (.hdr or .exr); the same as
    /// `"environment": {"map": FILE}` in the settings.
    #[arg(long, value_name = "FILE")]
    env: Option<PathBuf>,
    /// Multiplier of the environment map's radiance.
    #[arg(long, value_name = "X")]
    env_intensity: Option<f32>,
    /// Render the scene's `KHR_materials_variants` variant of this name; the same as
    /// `"variant": NAME` in the settings.
    #[arg(long, value_name = "NAME")]
    variant: Option<String>,
    /// The light-transport algorithm (`path`, `bdpt` or `sppm`); the same as `"integrator": NAME` in the
    /// settings.
    #[arg(long, value_name = "NAME")]
    integrator: Option<Integrator>,
    /// Stop issuing samples after this many seconds (the tasks in flight still merge); the same
    /// as `"time_limit_s"` in the settings.
    #[arg(long, value_name = "SECONDS")]
    time_limit: Option<f64>,
}

impl SettingsArgs {
    fn load(&self) -> Result<RenderSettings> {
        let mut s = match &self.settings {
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("reading {}", path.display()))?;
                // Parsed here, validated with the flags applied (`--integrator bdpt` with a
                // file's `"bdpt"` keys).
                let mut s: RenderSettings = serde_json::from_str(&text)
                    .map_err(|e| anyhow::anyhow!("settings: {e}"))
                    .with_context(|| format!("{}", path.display()))?;
                // A map named in a settings file is relative to that file.
                if let Some(Environment::Map { map, .. }) = &mut s.environment {
                    if Path::new(map.as_str()).is_relative() {
                        let dir = path.parent().unwrap_or(Path::new("."));
                        *map = dir.join(&*map).to_string_lossy().into_owned();
                    }
                }
                s
            }
            None => RenderSettings::default(),
        };
        s.spp = self.spp.unwrap_or(s.spp);
        s.width = self.width.unwrap_or(s.width);
        s.height = self.height.unwrap_or(s.height);
        s.seed = self.seed.unwrap_or(s.seed);
        s.max_depth = self.max_depth.unwrap_or(s.max_depth);
        if let Some(name) = &self.variant {
            s.variant = Some(name.clone());
        }
        if let Some(integrator) = self.integrator {
            s.integrator = integrator;
        }
        if let Some(seconds) = self.time_limit {
            s.time_limit_s = Some(seconds);
        }
        if let Some(file) = &self.env {
            let (intensity, rotation_deg, visible) = match &s.environment {
                Some(Environment::Map { intensity, rotation_deg, visible, .. }) => {
                    (*intensity, *rotation_deg, *visible)
                }
                _ => (1.0, 0.0, true),
            };
            let map = file.to_string_lossy().into_owned();
            s.environment = Some(Environment::Map { map, intensity, rotation_deg, visible });
        }
        if let Some(x) = self.env_intensity {
            match &mut s.environment {
                Some(Environment::Map { intensity, .. }) => *intensity = x,
                _ => anyhow::bail!(
                    "--env-intensity scales an environment map: give one with --env FILE (or \"environment\": {{\"map\": ...}} in the settings)"
                ),
            }
        }
        if let Some(range) = &self.frames {
            let parse = |v: &str| {
                v.trim()
                    .parse::<i64>()
                    .with_context(|| format!("--frames {range}: '{v}' is not a frame number"))
            };
            let (start, end) = match range.split_once("..") {
                Some((a, b)) => (parse(a)?, parse(b.trim_start_matches('='))?),
                None => (parse(range)?, parse(range)?),
            };
            anyhow::ensure!(start <= end, "--frames {range}: the range is empty");
            s.frames.start = start;
            s.frames.end = end;
        }
        s.validate().with_context(|| match &self.settings {
            Some(path) => format!("{} with the flags", path.display()),
            None => "the flags".into(),
        })?;
        Ok(s)
    }
}

/// What loading one scene may cost, checked before the work it bounds.
#[derive(Args, Clone, Copy, Debug)]
struct BudgetArgs {
    /// Most bytes a scene's .zip may unpack to, in MiB (checked while unpacking).
    #[arg(long, default_value_t = SceneBudget::default().inflated_bytes >> 20)]
    max_scene_mib: u64,
    /// Most decoded texels of a scene's images, in millions (counted from their headers,
    /// before decoding; 4 bytes each).
    #[arg(long, default_value_t = SceneBudget::default().texels as f64 / 1e6)]
    max_megatexels: f64,
    /// Most triangles of a scene after instancing, in millions.
    #[arg(long, default_value_t = SceneBudget::default().triangles as f64 / 1e6)]
    max_megatriangles: f64,
}

impl BudgetArgs {
    fn budget(self) -> Result<SceneBudget> {
        for (flag, value) in [
            ("--max-megatexels", self.max_megatexels),
            ("--max-megatriangles", self.max_megatriangles),
        ] {
            anyhow::ensure!(
                value.is_finite() && value > 0.0,
                "{flag} must be a positive number of millions"
            );
        }
        Ok(SceneBudget {
            inflated_bytes: self.max_scene_mib.saturating_mul(1 << 20),
            texels: (self.max_megatexels * 1e6) as u64,
            triangles: (self.max_megatriangles * 1e6) as u64,
            ..SceneBudget::default()
        })
    }
}

#[derive(Subcommand)]
enum Command {
    /// Render a glTF scene on this machine and write OUT.exr (+ OUT.png).
    Render {
        /// The scene: .gltf (with the files it names beside it), .glb, or a .zip of a folder.
        scene: PathBuf,
        /// Output image: OUT.exr (an OUT.png preview is written beside it; -o OUT.png writes
        /// both too).
        #[arg(short, long)]
        output: PathBuf,
        #[command(flatten)]
        settings: SettingsArgs,
        /// Render threads (default: one per core): local workers of one thread each, or one
        /// local worker of them all where a `sppm` or `bdpt` job has fewer whole-frame tasks
        /// (photon passes, light tracing) than twice the threads. `--threads` is the same (the
        /// peers benchmark harness passes it).
        #[arg(long, visible_alias = "threads")]
        workers: Option<usize>,
        #[command(flatten)]
        budget: BudgetArgs,
    },
    /// Run the farm service: REST API, worker protocol, metrics and dashboard.
    Serve {
        /// Address to listen on. Without a join token only loopback addresses are served.
        #[arg(long, default_value = "127.0.0.1:8080")]
        listen: String,
        /// Folder for the database and the uploaded scenes (created if missing).
        #[arg(long, default_value = "farm-data")]
        data: PathBuf,
        /// Shared token workers must present to join.
        #[arg(long, env = "RENDERFARM_TOKEN", hide_env_values = true)]
        token: Option<String>,
        /// Bearer token users must present to the REST API.
        #[arg(long, env = "RENDERFARM_API_TOKEN", hide_env_values = true)]
        api_token: Option<String>,
        /// Seconds before an unrenewed lease is given to another worker.
        #[arg(long, default_value_t = 30.0)]
        lease_timeout: f64,
        /// Largest spp a job may ask for.
        #[arg(long, default_value_t = 65536)]
        max_spp: u32,
        /// Hours a task may stay leased to one worker, heartbeats or not (a hung render).
        #[arg(long, default_value_t = 6.0)]
        max_lease_hours: f64,
        /// Times a task may be reported failed by workers before its job fails with the reason.
        #[arg(long, default_value_t = 3)]
        max_task_failures: u32,
        /// Times a task's lease may expire (its worker gone silent) before its job fails.
        #[arg(long, default_value_t = 5)]
        max_task_expiries: u32,
        /// Largest scene upload in MiB (a result is read no further than its tile's sums can take).
        #[arg(long, default_value_t = 1024)]
        max_upload_mib: usize,
        /// Most MiB of scene uploads held at once, over all uploads being received and checked;
        /// past it an upload is refused as busy (503). At least --max-upload-mib.
        #[arg(long, default_value_t = 2048)]
        max_uploads_in_flight_mib: usize,
        #[command(flatten)]
        budget: BudgetArgs,
        /// Seconds a client has to send a request's headers.
        #[arg(long, default_value_t = 10.0)]
        header_timeout: f64,
        /// Seconds a request body may send nothing before it is refused.
        #[arg(long, default_value_t = 30.0)]
        body_timeout: f64,
        /// Connections open at once; more are closed as they arrive. As many may wait to be
        /// accepted (up to the kernel's net.core.somaxconn), for workers that connect all at once.
        #[arg(long, default_value_t = 4096)]
        max_connections: usize,
        /// Scene uploads received at once; more are refused as busy (503).
        #[arg(long, default_value_t = 4)]
        max_concurrent_uploads: usize,
        /// Remove finished jobs (done, failed, cancelled), with their images, this many hours
        /// after they ended (default: keep them until removed with
        /// `DELETE /api/v1/jobs/{id}?purge=true`).
        #[arg(long)]
        retain_finished_hours: Option<f64>,
    },
    /// Submit a scene to a running farm, wait, and write OUT.exr (+ OUT.png).
    Submit {
        /// The scene: .gltf (with the files it names beside it), .glb, or a .zip of a folder.
        scene: PathBuf,
        /// Output image: OUT.exr (an OUT.png preview is written beside it; -o OUT.png writes
        /// both too).
        #[arg(short, long)]
        output: PathBuf,
        /// The coordinator.
        #[arg(long, env = "RENDERFARM_URL", default_value = "http://127.0.0.1:8080")]
        url: String,
        /// Bearer token of the coordinator's REST API.
        #[arg(long, env = "RENDERFARM_API_TOKEN", hide_env_values = true)]
        api_token: Option<String>,
        /// Job priority (higher runs first).
        #[arg(long, default_value_t = 0)]
        priority: i32,
        /// A name for the job, shown in the dashboard and the job's status instead of its id
        /// (up to 200 characters, one line).
        #[arg(long)]
        name: Option<String>,
        #[command(flatten)]
        settings: SettingsArgs,
    },
    /// Exit 0 when the coordinator at URL answers /healthz (for container health checks).
    Healthcheck {
        /// The coordinator.
        #[arg(long, default_value = "http://127.0.0.1:8080")]
        url: String,
    },
}

/// An empty token (an unset variable in a compose file) means no token.
fn token(t: Option<String>) -> Option<String> {
    t.filter(|t| !t.trim().is_empty())
}

/// A progress display on a terminal (nothing when stderr is a file or a pipe): the stage
/// (loading, queued, preparing the scene) until samples come in, then a bar of samples.
fn progress_bar() -> Option<ProgressBar> {
    std::io::stderr().is_terminal().then(|| {
        let bar = ProgressBar::new(0);
        bar.enable_steady_tick(Duration::from_millis(200));
        show_stage(&bar, Stage::Loading);
        bar
    })
}

fn show_stage(bar: &ProgressBar, stage: Stage) {
    let waiting = |what: &str| {
        bar.set_style(
            ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"),
        );
        bar.set_message(what.to_string());
    };
    match stage {
        Stage::Loading => waiting("loading the scene"),
        Stage::Queued => waiting("queued: waiting for a worker"),
        Stage::Preparing => waiting("preparing scene (loading, BVH)"),
        Stage::Rendering { done, total } => {
            if bar.message() != "rendering" {
                bar.set_style(
                    ProgressStyle::with_template(
                        "{msg} {bar:40} {percent}% of samples {elapsed} eta {eta}",
                    )
                    .expect("valid template"),
                );
                bar.set_message("rendering");
            }
            bar.set_length(total);
            bar.set_position(done);
        }
    }
}

/// The EXR to write for `-o OUT`, its files checked for writability before any work.
fn outputs(out: &Path, settings: &RenderSettings) -> Result<PathBuf> {
    let exr = exr_output(out)?;
    let first = if settings.frames.end > settings.frames.start {
        coordinator::local::numbered(&exr, settings.frames.start)
    } else {
        exr.clone()
    };
    check_writable(&[first.clone(), first.with_extension("png")])?;
    Ok(exr)
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    // `render` reports only problems (the farm's chatter is for the service's log).
    let default_filter = match cli.command {
        Command::Serve { .. } => "coordinator=info,worker=info,common=info",
        _ => "warn",
    };
    let filter = || {
        tracing_subscriber::EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| default_filter.into())
    };
    // A log that can no longer be written (stderr piped into `head`, a closed terminal) is
    // dropped; the default would print a complaint to that same stderr, which panics.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    match cli.command {
        // A service's log is read later and needs its times.
        Command::Serve { .. } => tracing_subscriber::fmt()
            .with_env_filter(filter())
            .with_writer(std::io::stderr)
            .log_internal_errors(false)
            .with_ansi(ansi)
            .init(),
        // A command's warnings are read now, each once (`coordinator::log`).
        _ => tracing_subscriber::fmt()
            .with_env_filter(filter())
            .with_writer(coordinator::log::OnceWarnings::default())
            .log_internal_errors(false)
            .with_ansi(ansi)
            .without_time()
            .with_target(false)
            .init(),
    }
    match cli.command {
        Command::Serve {
            listen,
            data,
            token: join,
            api_token,
            lease_timeout,
            max_spp,
            max_lease_hours,
            max_task_failures,
            max_task_expiries,
            max_upload_mib,
            max_uploads_in_flight_mib,
            budget,
            header_timeout,
            body_timeout,
            max_connections,
            max_concurrent_uploads,
            retain_finished_hours,
        } => {
            for (flag, value) in
                [("--header-timeout", header_timeout), ("--body-timeout", body_timeout)]
            {
                anyhow::ensure!(
                    value.is_finite() && value > 0.0,
                    "{flag} must be a positive number of seconds"
                );
            }
            anyhow::ensure!(max_connections > 0, "--max-connections must be at least 1");
            anyhow::ensure!(
                max_concurrent_uploads > 0,
                "--max-concurrent-uploads must be at least 1"
            );
            let scene_budget = budget.budget()?;
            anyhow::ensure!(
                lease_timeout.is_finite() && lease_timeout > 0.0,
                "--lease-timeout must be a positive number of seconds"
            );
            anyhow::ensure!(
                max_lease_hours.is_finite() && max_lease_hours > 0.0,
                "--max-lease-hours must be a positive number"
            );
            let retain_finished = retain_finished_hours
                .map(|h| {
                    Duration::try_from_secs_f64(h * 3600.0).map_err(|_| {
                        anyhow::anyhow!(
                            "--retain-finished-hours {h}: must be a number of hours, 0 or more"
                        )
                    })
                })
                .transpose()?;
            let mut addr: SocketAddr = listen.parse().with_context(|| {
                format!("--listen {listen}: expected an address like 0.0.0.0:8080")
            })?;
            let mut config = ServiceConfig::new(data);
            config.join_token = token(join);
            config.api_token = token(api_token);
            if config.join_token.is_none() && !addr.ip().is_loopback() {
                let requested = addr;
                addr.set_ip(IpAddr::V4(Ipv4Addr::LOCALHOST));
                tracing::warn!(
                    "no join token (--token or RENDERFARM_TOKEN): listening on {addr} only, not {requested}, so that no other machine can join or submit; set a token to serve a network"
                );
            } else if config.api_token.is_none() && !addr.ip().is_loopback() {
                tracing::warn!(
                    "no API token (--api-token or RENDERFARM_API_TOKEN): anyone who can reach {addr} can submit and cancel jobs"
                );
            }
            config.farm.lease_timeout = Duration::from_secs_f64(lease_timeout);
            config.farm.max_spp = max_spp;
            config.farm.max_lease_lifetime = Duration::from_secs_f64(max_lease_hours * 3600.0);
            anyhow::ensure!(
                max_task_failures > 0 && max_task_expiries > 0,
                "--max-task-failures and --max-task-expiries must be at least 1"
            );
            config.farm.max_task_failures = max_task_failures;
            config.farm.max_task_expiries = max_task_expiries;
            anyhow::ensure!(
                max_uploads_in_flight_mib >= max_upload_mib,
                "--max-uploads-in-flight-mib {max_uploads_in_flight_mib} is below --max-upload-mib {max_upload_mib}: the largest upload could never be taken"
            );
            config.max_upload_bytes = max_upload_mib << 20;
            config.max_upload_bytes_in_flight = max_uploads_in_flight_mib << 20;
            config.connections.header_timeout = Duration::from_secs_f64(header_timeout);
            config.connections.max_connections = max_connections;
            config.body_stall = Duration::from_secs_f64(body_timeout);
            config.max_concurrent_uploads = max_concurrent_uploads;
            config.farm.scene_budget = scene_budget;
            config.farm.retain_finished = retain_finished;
            if let Some(h) = retain_finished_hours {
                tracing::info!("finished jobs are removed {h} hours after they end");
            }
            let backlog = u32::try_from(max_connections).unwrap_or(u32::MAX);
            let runtime = tokio::runtime::Runtime::new()?;
            runtime.block_on(async {
                // Room for every connection to wait to be accepted: workers join all at once.
                let listener =
                    bind(addr, backlog).with_context(|| format!("listening on {addr}"))?;
                tracing::info!("coordinator listening on http://{}", listener.local_addr()?);
                serve_on(listener, config, shutdown_signal()).await
            })
        }
        Command::Healthcheck { url } => healthcheck(&url),
        Command::Submit { scene, output, url, api_token, priority, name, settings } => {
            let settings = settings.load()?;
            let output = outputs(&output, &settings)?;
            let remote = Remote { url, api_token: token(api_token) };
            let bar = progress_bar();
            let progress = |stage: Stage| {
                if let Some(bar) = &bar {
                    show_stage(bar, stage);
                }
            };
            let done =
                submit(&remote, &scene, &settings, priority, name.as_deref(), &output, &progress)?;
            if let Some(bar) = bar {
                bar.finish_and_clear();
            }
            if let (Some(mean), true) = (done.nearly_black, unlit_by_environment(&settings)) {
                tracing::warn!("{}", nearly_black_warning(mean));
            }
            let status = &done.status;
            let rel_mse = status["est_rel_error"].as_f64().map(|e| e * e);
            summary(format_args!(
                "job {} done: {} samples in {:.2} s; {}; wrote {}",
                status["id"].as_str().unwrap_or("?"),
                status["samples_done"],
                status["elapsed_s"].as_f64().unwrap_or(0.0),
                describe_error(rel_mse, done.black),
                list(&done.outputs)
            ));
            Ok(())
        }
        Command::Render { scene, output, settings, workers, budget } => {
            let budget = budget.budget()?;
            let s = settings.load()?;
            let output = outputs(&output, &s)?;
            let workers = workers.unwrap_or_else(|| {
                std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
            });
            let bar = progress_bar();
            let progress = |stage: Stage| {
                if let Some(bar) = &bar {
                    show_stage(bar, stage);
                }
            };
            let report = render_file_within(&scene, &s, workers, budget, &output, &progress)?;
            if let Some(bar) = bar {
                bar.finish_and_clear();
            }
            if report.rejected > 0 {
                tracing::warn!(
                    rejected = report.rejected,
                    "samples were NaN, infinite or absurdly large and were counted as zero; reproduce one with `worker debug-sample`"
                );
            }
            if let (Some(mean), true) = (nearly_black(&report.mean_rgb), unlit_by_environment(&s)) {
                tracing::warn!("{}", nearly_black_warning(mean));
            }
            summary(format_args!(
                "rendered {} samples in {:.2} s ({:.2} Msamples/s, {:.2} Mrays/s); load {:.3} s; kernel {}; {}; wrote {}",
                report.samples,
                report.render_seconds,
                report.samples as f64 / report.render_seconds / 1e6,
                report.rays as f64 / report.render_seconds / 1e6,
                report.load_seconds,
                report.kernels.join(" + "),
                describe_error(Some(report.est_rel_mse), is_black(&report.mean_rgb)),
                list(&report.outputs)
            ));
            Ok(())
        }
    }
}

/// Whether the settings give no environment that lights the scene (none, or a black one).
fn unlit_by_environment(settings: &RenderSettings) -> bool {
    settings.environment.as_ref().is_none_or(|e| e.is_black())
}

fn list(paths: &[PathBuf]) -> String {
    paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
}

/// The closing summary on stderr. Unlike `eprintln!`, a stderr nobody reads any more (piped into
/// `head`) is no reason to fail a render whose files are written.
fn summary(line: std::fmt::Arguments<'_>) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// Completes on SIGTERM or Ctrl-C.
async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
    tracing::info!("shutting down");
}
