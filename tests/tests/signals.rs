//! `worker --join` stops as a user expects: an idle worker, waiting in its long poll for work,
//! leaves the farm and exits within a second of SIGTERM or Ctrl-C (SIGINT), instead of at the
//! end of its poll (20 s by default).

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
