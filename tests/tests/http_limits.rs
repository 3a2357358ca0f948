//! Slow and greedy clients against `coordinator serve` (the real binary, loopback): headers sent
//! too slowly, a body that stops, more connections and more uploads at once than it takes. Each
//! is cut off or refused within its limit, and the service answers others meanwhile and after.

use std::{
    io::{Read, Write},
    net::TcpStream,
    time::{Duration, Instant},
};

use tests::*;

/// Reads until the server closes the connection (or 10 s pass); returns what it sent and when
/// it closed.
fn until_closed(mut s: TcpStream) -> (String, Duration) {
    let started = Instant::now();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    (String::from_utf8_lossy(&got).into_owned(), started.elapsed())
}

#[test]
fn slow_and_greedy_clients_are_cut_off_within_their_limits() {
    let dir = temp_dir("http-limits");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let addr = format!("127.0.0.1:{port}");
    let limits = [
        "--header-timeout",
        "1",
        "--body-timeout",
        "2",
        "--max-connections",
        "8",
        "--max-concurrent-uploads",
        "1",
    ];
    let coordinator = start_coordinator(&dir.join("data"), port, &limits);
    let scene = cornell_zip();

    // An upload whose body stops after 10 bytes holds the one upload slot: a second upload is
    // told the coordinator is busy; the stalled one is refused after the body timeout.
    let mut stalled = TcpStream::connect(&addr).unwrap();
    write!(
        stalled,
        "POST /api/v1/scenes HTTP/1.1\r\nHost: x\r\nContent-Type: application/zip\r\nContent-Length: {}\r\n\r\n",
        scene.len()
    )
    .unwrap();
    stalled.write_all(&scene[..10]).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let busy = post_bytes(&format!("{url}/api/v1/scenes"), "application/zip", &[], &scene);
    assert_eq!(busy.status, 503, "{}", busy.error());
    assert!(busy.error().contains("--max-concurrent-uploads"), "{}", busy.error());
    let (answer, took) = until_closed(stalled);
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    assert!(answer.contains("stalled") && answer.contains("--body-timeout"), "{answer}");
    assert!(took < Duration::from_secs(6), "the stalled body was held {took:?}");
    upload(&url, &scene);

    // Headers trickled: cut off after the header timeout, not held.
    let mut slow = TcpStream::connect(&addr).unwrap();
    slow.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n").unwrap();
    let (_, took) = until_closed(slow);
    assert!(took < Duration::from_secs(5), "trickled headers were held {took:?}");

    // Eight connections open and idle: a ninth is closed at once, and once the idle ones time
    // out the service answers again.
    let idle: Vec<TcpStream> = (0..8).map(|_| TcpStream::connect(&addr).unwrap()).collect();
    std::thread::sleep(Duration::from_millis(200));
    let (answer, took) = until_closed(TcpStream::connect(&addr).unwrap());
    assert!(answer.is_empty() && took < Duration::from_millis(900), "{answer:?} after {took:?}");
    // A client retrying in a loop is turned away each time, and logged once a second at most.
    for _ in 0..100 {
        let (answer, _) = until_closed(TcpStream::connect(&addr).unwrap());
        assert!(answer.is_empty());
    }
    let lines = coordinator.log_text().lines().filter(|l| l.contains("closed on arrival")).count();
    assert!((1..=3).contains(&lines), "{lines} lines for 101 connections turned away");
    drop(idle);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(get(&format!("{url}/healthz")).status, 200);
    let peak = peak_mib(&coordinator);
    eprintln!("coordinator peak resident memory: {peak:.0} MiB");
    assert!(peak < 100.0, "the coordinator peaked at {peak:.0} MiB");
}

/// Scene uploads being received share one budget of bytes held: one that holds 2 MiB of a
/// 3 MiB budget leaves room for no second 2 MiB upload (503, naming the flag), and once it is
/// refused (its body stalled) the budget is whole again.
#[test]
fn uploads_in_flight_share_one_byte_budget() {
    let dir = temp_dir("upload-bytes");
    let port = free_port();
    let url = format!("http://127.0.0.1:{port}");
    let addr = format!("127.0.0.1:{port}");
    let limits =
        ["--max-upload-mib", "2", "--max-uploads-in-flight-mib", "3", "--body-timeout", "2"];
    let coordinator = start_coordinator(&dir.join("data"), port, &limits);
    let big = vec![7u8; (2 << 20) - 64];
    let mut holding = TcpStream::connect(&addr).unwrap();
    write!(
        holding,
        "POST /api/v1/scenes HTTP/1.1\r\nHost: x\r\nContent-Type: application/zip\r\nContent-Length: {}\r\n\r\n",
        big.len() + 64
    )
    .unwrap();
    holding.write_all(&big).unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let busy = post_bytes(&format!("{url}/api/v1/scenes"), "application/zip", &[], &big);
    assert_eq!(busy.status, 503, "{}", busy.error());
    assert!(busy.error().contains("--max-uploads-in-flight-mib"), "{}", busy.error());
    let (answer, _) = until_closed(holding);
    assert!(answer.starts_with("HTTP/1.1 400") && answer.contains("stalled"), "{answer}");
    // The held bytes are given back: a scene is taken again.
    upload(&url, &cornell_zip());
    // An upload over the per-upload limit is too large, not busy.
    let over =
        post_bytes(&format!("{url}/api/v1/scenes"), "application/zip", &[], &vec![7; 3 << 20]);
    assert_eq!(over.status, 413, "{}", over.error());
    let peak = peak_mib(&coordinator);
    eprintln!("coordinator peak resident memory: {peak:.0} MiB");
    assert!(peak < 100.0, "the coordinator peaked at {peak:.0} MiB");
}
