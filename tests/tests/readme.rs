//! The README's commands work as written, run as a newcomer runs them from the repository root:
//! the shipped scene, a real asset lit by an HDR environment (by flag and by settings file), and
//! the farm on several machines in three commands, tokens included.

use std::{
    path::Path,
    process::Command,
    time::{Duration, Instant},
};

use tests::*;

fn readme() -> String {
    std::fs::read_to_string(repo().join("README.md")).unwrap()
}

/// The fenced blocks of `lang` under the heading `## title` (the whole README for "").
fn blocks(text: &str, title: &str, lang: &str) -> Vec<String> {
    let section = if title.is_empty() {
        text
    } else {
        let start =
            text.find(&format!("\n## {title}\n")).unwrap_or_else(|| panic!("no ## {title}"));
        let rest = &text[start + 1..];
        let end = rest[3..].find("\n## ").map_or(rest.len(), |e| e + 3);
        &rest[..end]
    };
    let fence = format!("```{lang}\n");
    section.split(&fence).skip(1).map(|b| b.split("```").next().unwrap().to_string()).collect()
}

/// The command lines of a block (comments and blank lines dropped).
fn commands(block: &str) -> Vec<String> {
    block
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| l.split(" #").next().unwrap().trim().to_string())
        .collect()
}

/// A README command line: `VAR=value ... cargo run --release -p BIN -- ARGS` as (env, bin,
/// args), or `cargo ARGS` as (env, "cargo", args).
struct Line {
    env: Vec<(String, String)>,
    bin: String,
    args: Vec<String>,
}

fn parse(line: &str) -> Line {
    let mut words = line.split_whitespace().map(str::to_string).peekable();
    let mut env = Vec::new();
    while let Some((k, v)) = words.peek().and_then(|w| w.split_once('=')) {
        env.push((k.to_string(), v.to_string()));
        words.next();
    }
    assert_eq!(words.next().as_deref(), Some("cargo"), "`{line}` is not a cargo command");
    let rest: Vec<String> = words.collect();
    match rest.iter().position(|w| w == "--") {
        Some(dash) if rest[0] == "run" => {
            let p = rest.iter().position(|w| w == "-p").expect("cargo run -p BIN");
            assert!(rest[..dash].contains(&"--release".to_string()), "`{line}`: not --release");
            Line { env, bin: rest[p + 1].clone(), args: rest[dash + 1..].to_vec() }
        }
        _ => Line { env, bin: "cargo".into(), args: rest },
    }
}

fn arg_after<'a>(args: &'a [String], flag: &str) -> &'a str {
    let i = args.iter().position(|a| a == flag).unwrap_or_else(|| panic!("no {flag} in {args:?}"));
    &args[i + 1]
}

/// Runs a README line with `cargo` as written (it builds what it runs).
fn cargo_run(line: &str, dir: &Path) -> std::process::Output {
    let l = parse(line);
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut words: Vec<String> = line.split_whitespace().map(str::to_string).collect();
    words.drain(..l.env.len() + 1);
    let output = Command::new(cargo)
        .args(&words)
        .envs(l.env.iter().map(|(k, v)| (k, v)))
        .env("CARGO_TARGET_DIR", repo().join("target"))
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "`{line}` failed:\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

#[test]
fn readme_render_command_works_as_written() {
    let root = repo();
    let first = &blocks(&readme(), "", "sh")[0];
    let lines = commands(first);
    assert!(lines.contains(&"cargo test --workspace --release".to_string()), "{lines:?}");
    let command = lines.iter().find(|l| l.starts_with("cargo run")).expect("a `cargo run` line");
    let out = root.join(arg_after(&parse(command).args, "-o"));
    let _ = std::fs::remove_file(&out);
    cargo_run(command, &root);
    assert!(out.exists(), "`{command}` wrote no {}", out.display());
    assert!(out.with_extension("png").exists());
    let _ = std::fs::remove_file(&out);
    let _ = std::fs::remove_file(out.with_extension("png"));
}

/// The real asset and the map the README names (in `tests/assets/`), rendered by the `--env`
/// command and by the settings file, as written, from the repository's folder: the same image.
#[test]
fn readme_real_asset_commands_work_as_written_and_agree() {
    let dir = repo();
    /// Removes the files this test put in the repository's folder, however it ends.
    struct Cleanup(Vec<std::path::PathBuf>);
    impl Drop for Cleanup {
        fn drop(&mut self) {
            for path in &self.0 {
                let _ = std::fs::remove_file(path);
            }
        }
    }
    let mut cleanup = Cleanup(Vec::new());
    let text = readme();
    let sh = blocks(&text, "Render a real asset", "sh");
    let json = blocks(&text, "Render a real asset", "json");
    assert_eq!(json.len(), 1, "one settings file in the section");
    let lines: Vec<String> = sh.iter().flat_map(|b| commands(b)).collect();
    let by_flag = lines.iter().find(|l| l.contains("--env ")).expect("a command with --env FILE");
    let by_file = lines.iter().find(|l| l.contains("--settings")).expect("a --settings command");
    let settings_name = arg_after(&parse(by_file).args, "--settings").to_string();
    std::fs::write(dir.join(&settings_name), &json[0]).unwrap();
    cleanup.0.push(dir.join(&settings_name));
    for line in [by_flag, by_file] {
        let out = dir.join(arg_after(&parse(line).args, "-o"));
        cleanup.0.extend([out.with_extension("png"), out]);
    }

    let out = cargo_run(by_flag, &dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("nothing lights"), "{stderr}");
    let image = dir.join(arg_after(&parse(by_flag).args, "-o"));
    let flag_exr = std::fs::read(&image).unwrap();
    assert!(image.with_extension("png").exists());
    let (_, _, rgb) = coordinator::output::read_exr_rgb(&image).unwrap();
    assert!(!coordinator::output::is_black(&rgb), "the lit helmet is black");

    std::fs::remove_file(&image).unwrap();
    cargo_run(by_file, &dir);
    let file_exr = std::fs::read(dir.join(arg_after(&parse(by_file).args, "-o"))).unwrap();
    assert_same_image(&flag_exr, &file_exr, "the --env command and the settings file");
}

/// The farm's three commands, exactly as written but for the host name and port: the
/// coordinator with the token on all interfaces, a worker with the same token, and `submit`.
#[test]
fn readme_farm_commands_work_as_written() {
    let dir = temp_dir("readme-farm");
    let lines = commands(&blocks(&readme(), "The farm", "sh")[0]);
    assert_eq!(lines.len(), 3, "three commands: {lines:?}");
    let (serve, join, submit) = (parse(&lines[0]), parse(&lines[1]), parse(&lines[2]));
    assert_eq!((serve.bin.as_str(), serve.args[0].as_str()), ("coordinator", "serve"));
    assert_eq!((join.bin.as_str(), submit.bin.as_str()), ("worker", "coordinator"));
    assert_eq!(submit.args[0], "submit");
    let token = |l: &Line| l.env.iter().find(|(k, _)| k == "RENDERFARM_TOKEN").map(|e| e.1.clone());
    assert!(token(&serve).is_some(), "the coordinator starts without a join token");
    assert_eq!(token(&join), token(&serve), "the worker's token is not the coordinator's");
    let listen = arg_after(&serve.args, "--listen");
    assert!(listen.starts_with("0.0.0.0:"), "--listen {listen} serves no other machine");
    let url = arg_after(&join.args, "--join").to_string();
    assert_eq!(arg_after(&submit.args, "--url"), url, "submit goes elsewhere than the worker");

    // Other machines become this one: the host is loopback, the port a free one.
    let port = free_port();
    let host = url.trim_start_matches("http://").to_string();
    let local = |args: &[String]| -> Vec<String> {
        args.iter()
            .map(|a| {
                a.replace(&host, &format!("127.0.0.1:{port}"))
                    .replace(listen, &format!("0.0.0.0:{port}"))
            })
            .collect()
    };
    let spawn = |l: &Line, log: &str| {
        let file = std::fs::File::create(dir.join(log)).unwrap();
        Command::new(bin_dir().join(&l.bin))
            .args(local(&l.args))
            .envs(l.env.iter().map(|(k, v)| (k, v)))
            .current_dir(&dir)
            .stdout(file.try_clone().unwrap())
            .stderr(file)
            .spawn()
            .unwrap()
    };
    // `--data farm-data` is relative: the coordinator keeps its state in the test's folder.
    struct Killed(std::process::Child);
    impl Drop for Killed {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let _coordinator = Killed(spawn(&serve, "serve.log"));
    let up = Instant::now() + Duration::from_secs(20);
    while ureq::get(&format!("http://127.0.0.1:{port}/healthz")).call().is_err() {
        assert!(Instant::now() < up, "the coordinator did not come up");
        std::thread::sleep(Duration::from_millis(50));
    }
    let serve_log = std::fs::read_to_string(dir.join("serve.log")).unwrap();
    assert!(!serve_log.contains("no join token"), "{serve_log}");
    let _worker = Killed(spawn(&join, "worker.log"));
    // `submit` runs from the repository root, where the README's scene paths are.
    let out = dir.join(arg_after(&submit.args, "-o"));
    let mut args = local(&submit.args);
    let o = args.iter().position(|a| a == "-o").unwrap();
    args[o + 1] = out.to_string_lossy().into_owned();
    let output = Command::new(bin_dir().join("coordinator"))
        .args(&args)
        .current_dir(repo())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "submit failed: {stderr}");
    assert!(stderr.contains("estimated relative error"), "{stderr}");
    assert_eq!(sample_counts(&std::fs::read(&out).unwrap()).len(), 256 * 256);
    assert!(out.with_extension("png").exists());
    let worker_log = std::fs::read_to_string(dir.join("worker.log")).unwrap();
    assert!(worker_log.contains("joined"), "{worker_log}");
}
