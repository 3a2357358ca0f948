//! The `coordinator` binary as a user runs it: `render` writes the EXR and PNG, the image does not
//! depend on the number of workers, and bad input fails with a message instead of a panic.

use std::{path::PathBuf, process::Command};

fn coordinator() -> Command {
    Command::new(env!("CARGO_BIN_EXE_coordinator"))
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("renderfarm-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Every channel of an EXR, by name, as raw bits.
fn channels(path: &PathBuf) -> Vec<(String, Vec<u32>)> {
    coordinator::output::read_channel_bits(&std::fs::read(path).unwrap()).unwrap()
}

fn render(workers: &str, out: &PathBuf) {
    render_with("--workers", workers, out)
}

fn render_with(flag: &str, workers: &str, out: &PathBuf) {
    let status = coordinator()
        .args(["render", "scenes/cornell-box.gltf", "-o"])
        .arg(out)
        .args(["--width", "64", "--height", "48", "--spp", "24", flag, workers])
        .current_dir(repo())
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn image_is_identical_with_one_or_two_workers() {
    let (one, two) = (temp("one.exr"), temp("two.exr"));
    render("1", &one);
    render("2", &two);
    let (a, b) = (channels(&one), channels(&two));
    let names: Vec<&str> = a.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["B", "G", "R", "samples", "variance.B", "variance.G", "variance.R"]);
    assert_eq!(a, b, "channels differ between 1 and 2 workers");
    // `--threads` (what the peers harness passes) is `--workers`.
    let threads = temp("threads.exr");
    render_with("--threads", "2", &threads);
    assert_eq!(channels(&threads), b, "--threads 2 differs from --workers 2");
    let samples = &a.iter().find(|(n, _)| n == "samples").unwrap().1;
    assert!(samples.iter().all(|&s| s == 24), "every pixel gets exactly spp samples");
    assert!(one.with_extension("png").exists());
    // Two parts: the image with the header attributes, then the variance.
    let attributes =
        coordinator::output::read_text_attributes(&std::fs::read(&one).unwrap()).unwrap();
    let get = |name: &str| {
        attributes.iter().find(|(part, n, _)| part == "rgba" && n == name).map(|a| a.2.clone())
    };
    assert_eq!(get("renderfarm.samples").as_deref(), Some(&*(64 * 48 * 24).to_string()));
    assert_eq!(get("renderfarm.frame").as_deref(), Some("0"));
    assert_eq!(get("renderfarm.rejected_samples").as_deref(), Some("0"));
    assert_eq!(get("renderfarm.scene_sha256").map(|h| h.len()), Some(64));
    let settings: serde_json::Value =
        serde_json::from_str(&get("renderfarm.settings").unwrap()).unwrap();
    assert_eq!(settings["spp"], 24);
    assert!(get("renderfarm.est_rel_mse").unwrap().parse::<f64>().unwrap() > 0.0);
}

#[test]
fn bad_input_fails_with_a_message() {
    let out = temp("bad.exr");
    for (args, needle) in [
        (vec!["render", "does-not-exist.gltf"], "does-not-exist.gltf"),
        (vec!["render", "scenes/cornell-box.gltf", "--spp", "0"], "spp"),
        (vec!["render", "scenes/cornell-box.settings.json"], "cornell-box.settings.json"),
    ] {
        let output =
            coordinator().args(&args).arg("-o").arg(&out).current_dir(repo()).output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{args:?} succeeded");
        assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
        assert!(stderr.contains(needle), "{args:?}: message does not name {needle}: {stderr}");
    }
}

#[test]
fn environment_map_is_found_beside_the_settings_file() {
    let dir = std::env::temp_dir().join(format!("renderfarm-cli-env-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let hdr = repo().join("../shared/scenes/real/environments/studio_small_05_1k.hdr");
    std::fs::copy(&hdr, dir.join("sky.hdr")).unwrap();
    let settings = dir.join("settings.json");
    std::fs::write(
        &settings,
        r#"{"width": 24, "height": 16, "spp": 4, "environment": {"map": "sky.hdr", "intensity": 2.0}}"#,
    )
    .unwrap();
    let out = dir.join("env.exr");
    let render = || {
        coordinator()
            .args(["render", "scenes/cornell-box.gltf", "--settings"])
            .arg(&settings)
            .arg("-o")
            .arg(&out)
            .current_dir(repo())
            .output()
            .unwrap()
    };
    let output = render();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(out.exists());

    std::fs::remove_file(dir.join("sky.hdr")).unwrap();
    let output = render();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("sky.hdr") && !stderr.contains("panicked"), "{stderr}");
}

/// A render whose log reader goes away (`coordinator render ... 2>&1 | head -1`) still finishes
/// and writes its image: a log line that cannot be written is dropped, not a panic that used to
/// leave the local workers' lease renewers waiting forever.
#[test]
fn a_closed_log_pipe_does_not_stop_the_render() {
    use std::io::{BufRead, BufReader};
    let out = temp("closed-log.exr");
    let mut child = coordinator()
        .args(["render", "scenes/cornell-box.gltf", "-o"])
        .arg(&out)
        .args(["--width", "64", "--height", "64", "--spp", "16", "--workers", "2"])
        .current_dir(repo())
        .env("RUST_LOG", "trace")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Read the first log line, then hang up, as `head -1` does.
    let mut first = String::new();
    BufReader::new(child.stderr.take().unwrap()).read_line(&mut first).unwrap();
    assert!(!first.is_empty(), "the trace log says something");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if std::time::Instant::now() > deadline {
            child.kill().unwrap();
            panic!("the render hung after its log pipe closed");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    assert!(status.success(), "{status}");
    assert!(out.exists());
}
