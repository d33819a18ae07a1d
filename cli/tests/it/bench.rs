//! `livegesture bench` end to end on the tiny bundles (a smoke run, not a measurement): every part
//! of the LiveGesture report, the batched steps through `step_many` with churn included, and the
//! DiffSHEG report with the family's options given as `generate` takes them. A batched step that
//! does not give every stream its token's frames fails the run (the bench checks it).

use livegesture_parity_tests as common;

use crate::support::{run, text};

fn bench(bundle: &std::path::Path, extra: &[&str]) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("bench.json");
    let mut args = vec![
        "bench",
        "--bundle",
        bundle.to_str().unwrap(),
        "--backend",
        "tract",
        "--threads",
        "1",
        "--warmup",
        "1",
        "--steps",
        "3",
        "--latency-trials",
        "1",
        "--quiet",
        "--json",
        json.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = run(&args);
    assert!(o.status.success(), "{}", text(&o));
    serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap()
}

#[test]
fn bench_runs_batched_steps_through_step_many() {
    let r = bench(
        &common::tiny_bundle(),
        &[
            "--streams",
            "1,3",
            "--batch-warmup",
            "2",
            "--batch-steps",
            "4",
            "--batch-min-steps",
            "4",
            "--batch-seconds",
            "30",
        ],
    );
    let batched = r["batched"].as_array().expect("batched");
    assert_eq!(batched.len(), 2);
    for (b, n) in batched.iter().zip([1, 3]) {
        assert_eq!(b["streams"], n);
        assert_eq!(b["timed_steps"], 4, "{b}");
        assert_eq!(b["churn"], n > 1);
        let rt = b["realtime_streams_with_frontend"].as_f64().unwrap();
        assert!(rt.is_finite() && rt > 0.0, "{b}");
    }
    assert!(r["single"]["chain_ms"]["median"].as_f64().unwrap() > 0.0);
}

#[test]
fn bench_takes_the_diffsheg_options_as_generate_does() {
    let r = bench(
        &common::diffsheg_tiny_bundle(),
        &[
            "--ddim-steps",
            "5",
            "--jumps",
            "1",
            "--windows",
            "1",
            "--table-steps",
            "",
        ],
    );
    assert_eq!(r["ddim_steps"], 5);
    assert_eq!(r["jumps"], 1);
    // a LiveGesture option on a DiffSHEG bundle is refused, naming it
    let o = run(&[
        "bench",
        "--bundle",
        common::diffsheg_tiny_bundle().to_str().unwrap(),
        "--backend",
        "tract",
        "--top-k",
        "3",
        "--streams",
        "",
        "--quiet",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("--top-k"), "{}", text(&o));
}
