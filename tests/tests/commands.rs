//! The farm's commands as a user runs them against a running coordinator: `worker --join` stops
//! as a user expects (an idle worker, waiting in its long poll for work, leaves the farm and exits
//! within a second of SIGTERM or Ctrl-C, instead of at the end of its 20 s poll), and `submit`
//! warns about a scene nothing lights, takes `--env`, a `.zip` and `-o OUT.png` as `render` does.

use std::{
    process::Command,
    time::{Duration, Instant},
};

use tests::*;

#[test]
fn an_idle_worker_leaves_at_once_on_sigterm_and_sigint() {
    let dir = temp_dir("signals");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let _coordinator = start_coordinator(&dir.join("data"), port, &[]);
    for signal in ["-TERM", "-INT"] {
        // The default long poll (no `--wait`): the worker asks for work and waits 20 s for it.
        let mut cmd = Command::new(bin_dir().join("worker"));
        cmd.args(["--join", &url, "--threads", "1", "--name", &signal[1..].to_lowercase()]);
        let log = dir.join(format!("worker{signal}.log"));
        let file = std::fs::File::create(&log).unwrap();
        let mut worker = cmd
            .stdout(file.try_clone().unwrap())
            .stderr(file)
            .env("RUST_LOG", "info")
            .spawn()
            .unwrap();
        let joined = Instant::now() + Duration::from_secs(20);
        while get(&format!("{url}/api/v1/workers")).json()["workers"].as_array().unwrap().is_empty()
        {
            assert!(Instant::now() < joined, "the worker did not join");
            std::thread::sleep(Duration::from_millis(20));
        }
        // Well inside its first long poll.
        std::thread::sleep(Duration::from_millis(500));
        let sent = Instant::now();
        Command::new("kill").args([signal, &worker.id().to_string()]).status().unwrap();
        let status = loop {
            if let Some(status) = worker.try_wait().unwrap() {
                break status;
            }
            if sent.elapsed() > Duration::from_secs(15) {
                let _ = worker.kill();
                panic!("{signal}: the idle worker was still running 15 s later");
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        let took = sent.elapsed();
        let text = std::fs::read_to_string(&log).unwrap();
        assert!(status.success(), "{signal}: {status}\n{text}");
        assert!(took < Duration::from_secs(1), "{signal}: exited after {took:?}, not within 1 s");
        assert!(text.contains("left the farm"), "{signal}: it did not leave:\n{text}");
        let workers = get(&format!("{url}/api/v1/workers")).json();
        assert_eq!(workers["workers"], serde_json::json!([]), "{signal}: still listed");
    }
}

fn submit(url: &str, args: &[&str]) -> std::process::Output {
    Command::new(bin_dir().join("coordinator"))
        .args(["submit", "--url", url, "--width", "16", "--height", "16", "--spp", "2"])
        .args(args)
        .current_dir(repo())
        .env_remove("RUST_LOG")
        .output()
        .unwrap()
}

#[test]
fn submit_warns_about_an_unlit_scene_and_takes_env_and_zip() {
    let dir = temp_dir("submit");
    let cluster = Cluster::start(&dir, 1, &[]);
    let real = repo().join("tests/assets/real");
    let boxed = real.join("BoxTextured/glTF/BoxTextured.gltf");
    let sky = real.join("environments/studio_small_05_1k.hdr");

    let dark = dir.join("dark.png");
    let output = submit(&cluster.url, &[boxed.to_str().unwrap(), "-o", dark.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(stderr.contains("nothing lights this scene") && stderr.contains("--env"), "{stderr}");
    assert!(stderr.contains("the image is black") && !stderr.contains("relMSE 0"), "{stderr}");
    assert!(dark.exists() && dark.with_extension("exr").exists(), "-o OUT.png writes both");

    // The textured box's folder zipped, lit by --env: no warning, an error estimate, a lit image.
    let mut files = Vec::new();
    for entry in std::fs::read_dir(boxed.parent().unwrap()).unwrap() {
        let path = entry.unwrap().path();
        files.push((
            path.file_name().unwrap().to_string_lossy().into_owned(),
            std::fs::read(&path).unwrap(),
        ));
    }
    let zip = dir.join("box-textured.zip");
    std::fs::write(&zip, common::bundle::Bundle::pack(&files).unwrap()).unwrap();
    let lit = dir.join("lit.exr");
    let output = submit(
        &cluster.url,
        &[
            zip.to_str().unwrap(),
            "--env",
            sky.to_str().unwrap(),
            "-o",
            lit.to_str().unwrap(),
            "--name",
            "box, lit",
        ],
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(!stderr.contains("nothing lights"), "{stderr}");
    assert!(stderr.contains("estimated relative error"), "{stderr}");
    let (_, _, rgb) = coordinator::output::read_exr_rgb(&lit).unwrap();
    assert!(!coordinator::output::is_black(&rgb));
    // `--name` names the job; a name that is not one line of text is refused before the upload.
    let listed = get(&format!("{}/api/v1/jobs?order=newest&limit=1", cluster.url)).json();
    assert_eq!(listed["jobs"][0]["name"], "box, lit", "{listed}");
    let output = submit(&cluster.url, &[zip.to_str().unwrap(), "-o", "x.exr", "--name", "a\tb"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("--name"), "{stderr}");
    let listed = get(&format!("{}/api/v1/jobs", cluster.url)).json();
    assert_eq!(listed["jobs"].as_array().map(Vec::len), Some(2), "nothing was submitted");
}

/// `render --integrator NAME` and `--time-limit SECONDS` reach the job's settings, which the
/// EXR header carries, with a settings file's keys for that integrator; an integrator the renderer does not have is refused naming the setting
/// and the ones it has, before anything renders.
#[test]
fn render_takes_the_integrator_and_a_time_limit() {
    let dir = temp_dir("integrator-flags");
    let scene = repo().join("scenes/cornell-box.gltf");
    let run = |out: &std::path::Path, extra: &[&str]| {
        Command::new(bin_dir().join("coordinator"))
            .arg("render")
            .arg(&scene)
            .arg("-o")
            .arg(out)
            .args(["--spp", "1", "--width", "8", "--height", "8", "--workers", "1"])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = dir.join("path.exr");
    let output = run(&out, &["--integrator", "path", "--time-limit", "30"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let header = String::from_utf8_lossy(&std::fs::read(&out).unwrap()).into_owned();
    assert!(header.contains(r#""integrator":"path""#), "the header names the integrator");
    assert!(header.contains(r#""time_limit_s":30.0"#), "the header carries the time limit");

    let out = dir.join("bdpt.exr");
    let output = run(&out, &["--integrator", "bdpt"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let header = String::from_utf8_lossy(&std::fs::read(&out).unwrap()).into_owned();
    assert!(header.contains(r#""integrator":"bdpt""#), "the header names the integrator");

    // A settings file's `bdpt` keys take the flag's integrator (flags and file are validated
    // together); without it they are refused, naming the key.
    let file = dir.join("light-paths.json");
    std::fs::write(&file, r#"{"bdpt": {"light_paths": 4}}"#).unwrap();
    let out = dir.join("bdpt-4.exr");
    let output = run(&out, &["--integrator", "bdpt", "--settings", file.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let header = String::from_utf8_lossy(&std::fs::read(&out).unwrap()).into_owned();
    assert!(header.contains(r#""bdpt":{"light_paths":4}"#), "the header carries the setting");
    let out = dir.join("path-4.exr");
    let output = run(&out, &["--settings", file.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("`bdpt`"), "{stderr}");
    assert!(!out.exists(), "no image for refused settings");

    let out = dir.join("sppm.exr");
    let output = run(&out, &["--integrator", "sppm"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let header = String::from_utf8_lossy(&std::fs::read(&out).unwrap()).into_owned();
    assert!(header.contains(r#""integrator":"sppm""#), "the header names the integrator");

    let out = dir.join("mlt.exr");
    let output = run(&out, &["--integrator", "mlt"]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "an unknown integrator rendered");
    assert!(
        stderr.contains("integrator")
            && stderr.contains("mlt")
            && stderr.contains("path, bdpt, sppm"),
        "{stderr}"
    );
    assert!(!out.exists(), "no image for a refused integrator");
}
