//! The parity checks fail on a deliberately broken input, naming what failed (issue: checks that
//! cannot pass a broken result). Each test changes ONE thing a check compares against in a copy of
//! the tiny bundle (`tools/edit_reference.py`): a NaN on the reference side of a graph row and of
//! the rollout rows, a perturbed or NaN log-mel reference, an expected figure missing from the
//! manifest. The untouched bundle passes the same checks (the bundle tests).

use std::path::Path;

use livegesture::backend::BackendKind;
use livegesture_parity::{Check, Report};
use livegesture_parity_tests::{edit_reference, run_parity_on, tiny_bundle};

fn broken(dir: &Path, args: &[&str]) -> std::path::PathBuf {
    let dst = dir.join("broken");
    edit_reference(&tiny_bundle(), &dst, args);
    dst
}

/// The failing rows as `check what (comparison) output`.
fn failed(report: &Report) -> Vec<String> {
    report
        .failures()
        .iter()
        .map(|r| format!("{} {} ({}) {}", r.check, r.what, r.comparison, r.output))
        .collect()
}

#[test]
fn the_logmel_check_fails_on_a_perturbed_or_nan_reference() {
    let tmp = tempfile::tempdir().unwrap();
    // 1e-3 on one value of the Python frontend's log-mel: ten times the bound
    let dir = broken(
        tmp.path(),
        &[
            "--array",
            "reference/logmel.npy",
            "--index",
            "1000",
            "--add",
            "1e-3",
        ],
    );
    let report = run_parity_on(&dir, &[BackendKind::Tract], &[Check::Logmel]);
    assert_eq!(
        failed(&report),
        ["logmel clip.wav (rust vs python) log-mel"],
        "{}",
        report.summary()
    );
    let line = report.failures()[0].failure_line();
    assert!(line.contains("log-mel"), "{line}");
    // NaN in the Python frontend's log-mel (the reference side)
    let tmp = tempfile::tempdir().unwrap();
    let dir = broken(
        tmp.path(),
        &[
            "--array",
            "reference/logmel.npy",
            "--index",
            "1000",
            "--set",
            "nan",
        ],
    );
    let report = run_parity_on(&dir, &[BackendKind::Tract], &[Check::Logmel]);
    assert_eq!(
        failed(&report),
        ["logmel clip.wav (rust vs python) log-mel"],
        "a NaN in the Python log-mel passed:\n{}",
        report.summary()
    );
}

#[test]
fn a_nan_in_the_torch_rollout_fails_the_rollout_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = broken(
        tmp.path(),
        &[
            "--array",
            "reference/rollout.npz:poses",
            "--index",
            "4000",
            "--set",
            "nan",
        ],
    );
    let report = run_parity_on(&dir, &[BackendKind::Tract], &[Check::Rollout]);
    assert_eq!(
        failed(&report),
        ["rollout rollout (tract vs torch) poses"],
        "a NaN in the torch rollout's poses:\n{}",
        report.summary()
    );
}

#[test]
fn a_nan_in_a_graph_reference_fails_its_row() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = broken(
        tmp.path(),
        &[
            "--array",
            "reference/fusion.npz:step3.output.logits",
            "--index",
            "5",
            "--set",
            "nan",
        ],
    );
    let report = run_parity_on(&dir, &[BackendKind::Tract], &[Check::Graph]);
    assert_eq!(
        failed(&report),
        ["graph fusion (tract vs torch) logits"],
        "a NaN in the torch reference of the fusion logits:\n{}",
        report.summary()
    );
}

#[test]
fn a_missing_torch_step_vs_offline_figure_fails_naming_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = broken(
        tmp.path(),
        &["--drop-check", "fusion.torch_step_vs_offline_max_abs"],
    );
    let report = run_parity_on(&dir, &[BackendKind::Tract], &[Check::Graph]);
    let f = report.failures();
    assert_eq!(f.len(), 1, "{}", report.summary());
    assert_eq!(f[0].what, "fusion");
    assert_eq!(f[0].comparison, "torch step vs offline");
    let line = f[0].failure_line();
    assert!(
        line.contains("torch_step_vs_offline_max_abs"),
        "the failure names the key it looked for: {line}"
    );
}
