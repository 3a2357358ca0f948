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
    // The Cornell box runs on the wavefront where the CPU has AVX2 or AVX-512.
    let kernel = get("renderfarm.kernels").unwrap();
    let expected = match worker::render::integrators::wavefront::lanes() {
        16 => "path, AVX-512 x16",
        8 => "path, AVX2 x8",
        _ => "path, scalar",
    };
    assert_eq!(kernel, expected);
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
    let hdr = repo().join("tests/assets/real/environments/studio_small_05_1k.hdr");
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

fn run_render(args: &[&str]) -> std::process::Output {
    coordinator()
        .arg("render")
        .args(args)
        .current_dir(repo())
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LOG")
        .output()
        .unwrap()
}

/// The Cornell box at 16x16 and 2 spp into `out`.
fn tiny_cornell(out: &std::path::Path) -> std::process::Output {
    let args = ["--spp", "2", "--width", "16", "--height", "16"];
    run_render(&[&["scenes/cornell-box.gltf", "-o", out.to_str().unwrap()], &args[..]].concat())
}

/// A file under the repository's `tests/assets/` (the Khronos samples and the environment map).
fn asset(path: &str) -> String {
    repo().join("tests/assets").join(path).to_string_lossy().into_owned()
}

const SKY: &str = "real/environments/studio_small_05_1k.hdr";
/// A real asset with textures and no lights of its own.
const BOXED: &str = "real/BoxTextured/glTF/BoxTextured.gltf";

/// The damaged helmet's own emissive parts light almost nothing of it: without an environment
/// the image is nearly black, and `render` says so once, naming `--env`; under the map it does
/// not, nor for the Cornell box.
#[test]
fn a_nearly_black_image_names_the_environment() {
    let helmet = asset("real/DamagedHelmet/glTF-Binary/DamagedHelmet.glb");
    let small = ["--width", "32", "--height", "32", "--spp", "4"];
    let dark = temp("helmet-dark.exr");
    let output =
        run_render(&[&[&helmet as &str, "-o", dark.to_str().unwrap()], &small[..]].concat());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert_eq!(stderr.matches("the image is nearly black").count(), 1, "{stderr}");
    assert!(stderr.contains("--env FILE.hdr"), "{stderr}");
    let (_, _, rgb) = coordinator::output::read_exr_rgb(&dark).unwrap();
    assert!(coordinator::output::nearly_black(&rgb).is_some());
    let sky = asset(SKY);
    let lit = temp("helmet-lit.exr");
    let args = [&helmet as &str, "--env", &sky, "-o", lit.to_str().unwrap()];
    let output = run_render(&[&args[..], &small[..]].concat());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success() && !stderr.contains("nearly black"), "{stderr}");
    let output = tiny_cornell(&temp("cb-bright.exr"));
    assert!(!String::from_utf8_lossy(&output.stderr).contains("nearly black"));
}

/// Extensions the file uses that the renderer ignores are named in one warning, with what is
/// rendered instead where it is known; the archived specular-glossiness one is read (converted
/// to metallic-roughness), so it is not named.
#[test]
fn ignored_extensions_are_named_in_one_warning() {
    let dir = temp("ignored-extensions");
    std::fs::create_dir_all(&dir).unwrap();
    let source = repo().join("tests/assets/real/Box/glTF");
    std::fs::copy(source.join("Box0.bin"), dir.join("Box0.bin")).unwrap();
    let mut gltf: serde_json::Value =
        serde_json::from_slice(&std::fs::read(source.join("Box.gltf")).unwrap()).unwrap();
    gltf["extensionsUsed"] = serde_json::json!([
        "KHR_materials_pbrSpecularGlossiness",
        "EXT_texture_avif",
        "EXT_made_up"
    ]);
    std::fs::write(dir.join("Box.gltf"), gltf.to_string()).unwrap();
    let scene = dir.join("Box.gltf");
    let out = dir.join("box.exr");
    let sky = asset(SKY);
    let args = [scene.to_str().unwrap(), "--env", &sky, "-o", out.to_str().unwrap()];
    let output =
        run_render(&[&args[..], &["--width", "16", "--height", "16", "--spp", "2"]].concat());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert_eq!(stderr.matches("extensionsUsed: the renderer ignores").count(), 1, "{stderr}");
    assert!(
        stderr.contains("EXT_texture_avif (the PNG or JPEG fallback")
            && stderr.contains("EXT_made_up")
            && !stderr.contains("KHR_materials_pbrSpecularGlossiness"),
        "{stderr}"
    );
}

/// A real asset has no lights of its own: without an environment it renders black, and the
/// command says so (and names the fix) instead of reporting a converged image.
#[test]
fn an_unlit_scene_is_reported_and_an_environment_lights_it() {
    let out = temp("box-textured.exr");
    let small = ["--width", "24", "--height", "24", "--spp", "4"];
    let output =
        run_render(&[&[&asset(BOXED) as &str, "-o", out.to_str().unwrap()], &small[..]].concat());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(
        stderr.contains("nothing lights this scene") && stderr.contains("--env FILE.hdr"),
        "{stderr}"
    );
    assert!(stderr.contains("the image is black"), "{stderr}");
    assert!(!stderr.contains("relMSE 0"), "{stderr}");
    let (_, _, rgb) = coordinator::output::read_exr_rgb(&out).unwrap();
    assert!(coordinator::output::is_black(&rgb), "the warning said black; the image is not");

    let sky = asset(SKY);
    let lit = temp("box-textured-lit.exr");
    let output = run_render(
        &[&[&asset(BOXED) as &str, "--env", &sky, "-o", lit.to_str().unwrap()], &small[..]]
            .concat(),
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    assert!(!stderr.contains("nothing lights"), "{stderr}");
    assert!(stderr.contains("estimated relative error"), "{stderr}");
    let (_, _, rgb) = coordinator::output::read_exr_rgb(&lit).unwrap();
    assert!(!coordinator::output::is_black(&rgb));

    // A scene with an emitter of its own (the Cornell box) gets no warning.
    let output = tiny_cornell(&temp("cb.exr"));
    assert!(output.status.success());
    assert!(!String::from_utf8_lossy(&output.stderr).contains("nothing lights"));
}

/// `--env FILE --env-intensity X` is the settings file's `environment` map, bit for bit, and a
/// `.zip` of the scene's folder renders what the `.gltf` beside its files renders.
#[test]
fn env_flag_and_zip_bundles_render_what_the_settings_and_the_folder_do() {
    let dir = temp("envzip");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(asset(SKY), dir.join("sky.hdr")).unwrap();
    std::fs::write(
        dir.join("settings.json"),
        r#"{"width": 24, "height": 16, "spp": 4, "environment": {"map": "sky.hdr", "intensity": 2.0}}"#,
    )
    .unwrap();
    let by_settings = dir.join("settings.exr");
    let output = run_render(&[
        &asset(BOXED),
        "--settings",
        dir.join("settings.json").to_str().unwrap(),
        "-o",
        by_settings.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let by_flag = dir.join("flag.exr");
    let sky = dir.join("sky.hdr");
    let small = ["--width", "24", "--height", "16", "--spp", "4"];
    let output = run_render(
        &[
            &[&asset(BOXED) as &str, "--env", sky.to_str().unwrap(), "--env-intensity", "2"],
            &small[..],
            &["-o", by_flag.to_str().unwrap()],
        ]
        .concat(),
    );
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(channels(&by_flag), channels(&by_settings), "--env differs from the settings' map");

    // The textured box's folder as a zip (as the REST API takes it), with the map added by --env.
    let folder = repo().join("tests/assets/real/BoxTextured/glTF");
    let mut files = Vec::new();
    for entry in std::fs::read_dir(&folder).unwrap() {
        let path = entry.unwrap().path();
        let name = format!("BoxTextured/{}", path.file_name().unwrap().to_string_lossy());
        files.push((name, std::fs::read(&path).unwrap()));
    }
    let zip = dir.join("box-textured.zip");
    std::fs::write(&zip, common::bundle::Bundle::pack(&files).unwrap()).unwrap();
    let by_zip = dir.join("zip.exr");
    let output = run_render(
        &[
            &[zip.to_str().unwrap(), "--env", sky.to_str().unwrap(), "--env-intensity", "2"],
            &small[..],
            &["-o", by_zip.to_str().unwrap()],
        ]
        .concat(),
    );
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(channels(&by_zip), channels(&by_flag), "the zip renders another image");

    // --env-intensity alone has nothing to scale.
    let output =
        run_render(&[&asset(BOXED), "--env-intensity", "2", "-o", by_flag.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("--env FILE"), "{stderr}");
}

/// `-o out.png` writes the EXR and its preview (never one in place of the other); an output
/// that cannot be written is refused before anything renders; an unknown extension is refused.
#[test]
fn output_paths_are_checked_before_rendering() {
    let png = temp("preview-named.png");
    let _ = std::fs::remove_file(png.with_extension("exr"));
    let output = tiny_cornell(&png);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert_eq!(&std::fs::read(&png).unwrap()[..8], b"\x89PNG\r\n\x1a\n", "the .png is a PNG");
    assert_eq!(channels(&png.with_extension("exr")).len(), 7, "the EXR is beside it");

    let folder = temp("a-folder.exr");
    std::fs::create_dir_all(&folder).unwrap();
    let missing = repo().join("no-such-folder/out.exr");
    for (out, needle) in [
        (missing.to_str().unwrap(), "no-such-folder"),
        (folder.to_str().unwrap(), "is a folder"),
        ("out.jpg", "OUT.exr"),
    ] {
        // 16k x 16k at 64k spp would take hours: a refusal must come before the work.
        let started = std::time::Instant::now();
        let output = run_render(&[
            "scenes/cornell-box.gltf",
            "-o",
            out,
            "--spp",
            "65536",
            "--width",
            "16384",
            "--height",
            "16384",
        ]);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{out}: {stderr}");
        assert!(stderr.contains(needle), "{out}: {stderr}");
        assert!(
            started.elapsed() < std::time::Duration::from_secs(30),
            "{out}: refused only after rendering"
        );
    }
    assert!(!repo().join("no-such-folder").exists());
}

/// A wrong `environment` object is refused in plain words, naming what is missing.
#[test]
fn settings_errors_are_plain_words() {
    let settings = temp("bad-env.json");
    std::fs::write(&settings, r#"{"environment": {"intensity": 3}}"#).unwrap();
    let output = run_render(&[
        "scenes/cornell-box.gltf",
        "--settings",
        settings.to_str().unwrap(),
        "-o",
        temp("x.exr").to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("needs `color`") && stderr.contains("`map`"), "{stderr}");
    assert!(!stderr.contains("variant") && !stderr.contains("untagged"), "{stderr}");
}

/// On a terminal, the progress display names the stage before samples come in: the scene is
/// loaded and prepared (textures decoded, BVH built) before the first sample.
#[test]
fn progress_shows_the_preparing_stage_on_a_terminal() {
    let out = temp("progress.exr");
    let command = format!(
        "{} render {} -o {} --spp 4 --width 32 --height 32 --workers 1",
        env!("CARGO_BIN_EXE_coordinator"),
        asset("real/DamagedHelmet/glTF-Binary/DamagedHelmet.glb"),
        out.display()
    );
    // `script` runs it on a pseudo-terminal and copies what it drew to our stdout.
    let output = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .current_dir(repo())
        .output()
        .expect("`script` (util-linux) runs a command on a pseudo-terminal");
    let drawn = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{drawn}");
    assert!(drawn.contains("preparing scene"), "no preparing stage drawn: {drawn}");
    assert!(drawn.contains("rendered"), "{drawn}");
}

/// `render` takes the scene budgets `serve` takes: a scene over one is refused before it is
/// rendered, with the figure and the flag; within it the render goes on.
#[test]
fn render_takes_the_scene_budgets() {
    let out = temp("render-budgets.exr");
    let tiny = ["--spp", "1", "--width", "8", "--height", "8"];
    let cornell = ["scenes/cornell-box.gltf", "-o", out.to_str().unwrap()];
    let over = run_render(&[&cornell[..], &tiny, &["--max-megatriangles", "0.00001"]].concat());
    let stderr = String::from_utf8_lossy(&over.stderr);
    assert!(!over.status.success(), "{stderr}");
    assert!(
        stderr.contains("triangles after instancing")
            && stderr.contains("budget of 10")
            && stderr.contains("--max-megatriangles"),
        "{stderr}"
    );
    assert!(!out.exists(), "nothing is written for a refused scene");
    let within = run_render(&[&cornell[..], &tiny, &["--max-megatriangles", "0.001"]].concat());
    assert!(within.status.success(), "{}", String::from_utf8_lossy(&within.stderr));
    let bad = run_render(&[&cornell[..], &tiny, &["--max-megatexels", "0"]].concat());
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success() && stderr.contains("--max-megatexels"), "{stderr}");
}

/// A thin lens on an orthographic camera is refused before anything renders, naming the camera
/// and the fix, rather than dropped (the same settings on the perspective camera render).
#[test]
fn a_lens_on_an_orthographic_camera_is_refused() {
    let cameras = asset("real/Cameras/glTF/Cameras.gltf");
    let settings = |camera: &str| {
        let path = temp(&format!("lens-{}.json", camera.replace(' ', "-")));
        let json = format!(
            r#"{{"width": 16, "height": 16, "spp": 2, "camera": "{camera}",
                "lens": {{"aperture_radius": 0.05, "focus_distance": 3.0}},
                "environment": {{"color": [1, 1, 1]}}}}"#
        );
        std::fs::write(&path, json).unwrap();
        path
    };
    let out = temp("lens-ortho.exr");
    let _ = std::fs::remove_file(&out);
    let ortho = settings("camera 1");
    let output =
        run_render(&[&cameras, "--settings", ortho.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{stderr}");
    assert!(
        stderr.contains("orthographic camera 'camera 1' has no lens") && stderr.contains("`lens`"),
        "{stderr}"
    );
    assert!(!out.exists(), "an image was written");
    let persp = settings("camera 0");
    let output =
        run_render(&[&cameras, "--settings", persp.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
}

/// Each loader warning is printed once, though `render` loads the scene twice (to bundle it, and
/// as the farm checks the upload).
#[test]
fn each_loader_warning_is_printed_once() {
    let out = temp("modes.exr");
    let scene = asset("real/MeshPrimitiveModes/glTF/MeshPrimitiveModes.gltf");
    let small = ["--width", "8", "--height", "8", "--spp", "1", "--env-intensity", "1"];
    let sky = asset(SKY);
    let output = run_render(
        &[&[&scene as &str, "--env", &sky, "-o", out.to_str().unwrap()], &small[..]].concat(),
    );
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stderr}");
    for mode in ["Points", "Lines", "LineLoop", "LineStrip"] {
        let line = format!("mode {mode} has no triangles; skipped");
        assert_eq!(stderr.matches(&line).count(), 1, "{mode}: {stderr}");
    }
}
