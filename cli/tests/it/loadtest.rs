//! `livegesture loadtest` against an in-process server (the tiny bundle, tract): a short, bounded
//! ramp completes its sessions and reports in the documented shape (table, JSON, SVG); a bound no
//! level can meet is reported as not held (and `--require` then fails); bad arguments and audio
//! are refused with a reason. A smoke test of the tool, not a measurement (docs/serve.md#load-test).

use std::path::Path;
use std::process::{Command, Output};

use livegesture_parity_tests as common;
use livegesture_serve::ServeConfig;

use crate::serve_common::start_tiny;

fn loadtest(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_livegesture"))
        .arg("loadtest")
        .args(args)
        .env_remove("LIVEGESTURE_REAL_SPEECH")
        .output()
        .expect("runs")
}

fn clip() -> String {
    common::tiny_bundle()
        .join("reference/clip.wav")
        .display()
        .to_string()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn a_short_ramp_completes_its_sessions_and_reports() {
    let server = start_tiny(ServeConfig::default());
    let url = format!("ws://{}", server.addr());
    let dir = tempfile::tempdir().unwrap();
    let (json, svg) = (dir.path().join("r.json"), dir.path().join("r.svg"));
    let pid = std::process::id().to_string();
    let out = loadtest(&[
        &url,
        "--audio",
        &clip(),
        "--levels",
        "1,2",
        "--hold",
        "1.5",
        "--pause",
        "0",
        "--p99-ms",
        "60000",
        "--server-pid",
        &pid,
        "--json",
        json.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
        "--require",
        "2",
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
    assert!(
        stdout.starts_with("| sessions | completed | failed | tokens | p50 ms | p99 ms |"),
        "{stdout}"
    );
    assert!(stdout.contains("\nheld: 2 real-time sessions"), "{stdout}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let levels = r["levels"].as_array().unwrap();
    assert_eq!(levels.len(), 2);
    for (l, n) in levels.iter().zip([1u64, 2]) {
        assert_eq!(l["sessions"], n);
        assert_eq!(l["completed"], n, "{l}");
        assert_eq!(l["failed"], 0);
        // 1.5 s of audio is 11 whole tokens per session, each measured
        assert_eq!(l["units"], 11 * n, "{l}");
        assert!(l["p99_ms"].as_f64().unwrap() >= l["p50_ms"].as_f64().unwrap());
        assert!(l["server_cpu_pct"].as_f64().unwrap() >= 0.0);
        // the server's steps, from its /metrics
        assert!(l["mean_batch"].as_f64().unwrap() >= 1.0, "{l}");
        assert!(l["step_pct"].as_f64().unwrap() > 0.0, "{l}");
        assert_eq!(l["held"], true);
    }
    assert_eq!(r["sessions_held"], 2);
    assert!(r["cores"].as_u64().unwrap() >= 1);
    let plot = std::fs::read_to_string(&svg).unwrap();
    assert!(plot.starts_with("<svg") && plot.trim_end().ends_with("</svg>"));
    assert_eq!(plot.matches("<polyline").count(), 3, "p50, p99, CPU");
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn a_bound_no_level_meets_is_not_held() {
    let server = start_tiny(ServeConfig::default());
    let url = format!("ws://{}", server.addr());
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("r.json");
    // no --server-pid: the server's CPU from its /metrics (process_cpu_seconds_total)
    let out = loadtest(&[
        &url,
        "--audio",
        &clip(),
        "--levels",
        "1,2",
        "--hold",
        "0.5",
        "--p99-ms",
        "0.001",
        "--require",
        "1",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = text(&out.stdout);
    // the first level is not held, so the ramp stops there
    assert_eq!(out.status.code(), Some(1), "{stdout}");
    assert!(
        stdout.contains("| 1 | 1 | 0 |") && stdout.contains("| no |"),
        "{stdout}"
    );
    assert!(!stdout.lines().any(|l| l.starts_with("| 2 |")), "{stdout}");
    assert!(stdout.contains("held: 0 real-time sessions"), "{stdout}");
    assert!(text(&out.stderr).contains("fewer than --require 1"));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let source = r["cpu_source"].as_str().unwrap();
    assert!(
        source.ends_with("/metrics (process_cpu_seconds_total)"),
        "{source}"
    );
    assert!(r["levels"][0]["server_cpu_pct"].as_f64().is_some(), "{r}");
    assert_eq!(r["cores"], serde_json::Value::Null);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn no_server_fails_every_session_with_its_reason() {
    // a port nothing listens on
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let out = loadtest(&[
        &format!("ws://127.0.0.1:{port}"),
        "--audio",
        &clip(),
        "--levels",
        "2",
        "--hold",
        "0.5",
        "--cores",
        "1",
    ]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stderr}");
    assert!(stdout.contains("| 2 | 0 | 2 |"), "{stdout}");
    assert!(stderr.contains("connect:"), "{stderr}");
}

#[test]
fn bad_arguments_and_audio_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let not_wav = dir.path().join("x.wav");
    std::fs::write(&not_wav, b"not a wav file").unwrap();
    let missing = Path::new("no/such/speech.wav");
    let c = clip();
    for (args, says) in [
        (vec!["--audio", &c, "--levels", "8,4"], "--levels"),
        (vec!["--audio", &c, "--levels", "0"], "--levels"),
        (vec!["--audio", &c, "--hold", "0"], "--hold"),
        (vec!["--audio", &c, "http://127.0.0.1:1"], "ws://"),
        (vec!["--audio", empty.to_str().unwrap()], "no .wav file"),
        (vec!["--audio", not_wav.to_str().unwrap()], "x.wav"),
        (vec!["--audio", missing.to_str().unwrap()], "speech.wav"),
    ] {
        let out = loadtest(&args);
        let err = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    // the default audio from the environment, checked
    let out = Command::new(env!("CARGO_BIN_EXE_livegesture"))
        .args(["loadtest", "--levels", "1"])
        .env("LIVEGESTURE_REAL_SPEECH", empty.join("nope"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("$LIVEGESTURE_REAL_SPEECH"));
}
