//! Reduced-precision bundles (docs/bundle.md#forms-and-precision): `export/quantize.py --precision f16` derives a float16-weight
//! bundle from the tiny export (weights stored as float16 + Cast, float32 arithmetic; its graph
//! reference vectors are the f32 bundle's torch ones, each graph with the bound quantize measured and
//! stated; its rollout is onnxruntime's on the reduced graphs). That bundle passes every parity check
//! on both backends, tract vs ort within 1e-4 included, both forms; the same bundle with one float16
//! weight perturbed fails against the f32 torch vectors, naming that graph.

use std::ffi::OsStr;
use std::path::Path;

use livegesture::bundle::Bundle;
use livegesture_parity::{Check, Report};
use livegesture_parity_tests::{
    break_bundle, repo_root, rollout_tokens_row, run_parity, run_python, tiny_bundle, Breakage,
};

const BROKEN: &str = "expert_hands";

fn quantize(src: &Path, dst: &Path, precision: &str) {
    let args: [&OsStr; 6] = [
        "--bundle".as_ref(),
        src.as_os_str(),
        "--precision".as_ref(),
        precision.as_ref(),
        "--out".as_ref(),
        dst.as_os_str(),
    ];
    let script = repo_root().join("export").join("quantize.py");
    run_python("export/quantize.py", &script, &args);
}

fn graph_comparisons(report: &Report, comparison: &str) -> std::collections::BTreeSet<String> {
    report
        .rows
        .iter()
        .filter(|r| r.check == Check::Graph && r.comparison == comparison)
        .map(|r| r.what.clone())
        .collect()
}

#[test]
fn f16_bundle_passes_parity_and_a_perturbed_one_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let f16 = tmp.path().join("tiny-f16");
    quantize(&tiny_bundle(), &f16, "f16");
    let bundle = Bundle::load(&f16).expect("the f16 bundle loads and its files match the manifest");
    assert_eq!(bundle.precision(), "float16");
    assert!(bundle.is_reduced_precision());
    let names: std::collections::BTreeSet<String> =
        bundle.graphs().iter().map(|g| g.name.clone()).collect();
    assert!(
        names.contains("experts_fused"),
        "the tiny export carries the fused form: {names:?}"
    );

    let report = run_parity(&f16, &[]);
    let failures: Vec<String> = report.failures().iter().map(|r| r.failure_line()).collect();
    assert!(
        failures.is_empty(),
        "the f16 bundle fails parity:\n{}",
        failures.join("\n")
    );
    assert!(report.passed());
    // every graph (both forms) compared on both backends against the f32 torch reference vectors with
    // the stated bound, and tract against ort
    for comparison in ["ort vs f32 torch", "tract vs f32 torch", "tract vs ort"] {
        assert_eq!(
            graph_comparisons(&report, comparison),
            names,
            "{comparison}: graphs compared"
        );
    }
    for comparison in ["ort vs reference", "tract vs reference", "tract vs ort"] {
        let tokens = rollout_tokens_row(&report, comparison);
        assert!(
            tokens.compared >= 1000,
            "{comparison}: {} steps",
            tokens.compared
        );
    }

    for g in bundle.graphs() {
        let stated = bundle.manifest().checks[&g.name]["reduced_vs_f32_torch_bound"]
            .as_f64()
            .unwrap_or_else(|| panic!("{}: no stated bound", g.name));
        let row = report
            .rows_for(Check::Graph, &g.name)
            .into_iter()
            .find(|r| r.comparison == "ort vs f32 torch")
            .expect("an ort vs f32 torch row");
        assert_eq!(row.bound, stated, "{}: the stated bound is applied", g.name);
        assert!(stated < 0.01, "{}: float16 bound {stated}", g.name);
    }

    // one float16 weight perturbed: that graph fails against the f32 torch vectors, on both backends
    let broken = tmp.path().join("tiny-f16-perturbed");
    let change = break_bundle(
        &f16,
        &broken,
        BROKEN,
        &Breakage::PerturbWeight { delta: 0.1 },
    );
    assert!(
        change["initializer"]
            .as_str()
            .is_some_and(|s| s.ends_with("_float16")),
        "break_bundle perturbed a float16 weight: {change}"
    );
    let report = run_parity(&broken, &[Check::Graph]);
    let failed: std::collections::BTreeSet<&str> =
        report.failures().iter().map(|r| r.what.as_str()).collect();
    assert_eq!(failed, [BROKEN].into_iter().collect(), "graphs that failed");
    for comparison in ["ort vs f32 torch", "tract vs f32 torch"] {
        assert!(
            report
                .rows_for(Check::Graph, BROKEN)
                .iter()
                .any(|r| r.comparison == comparison && !r.pass),
            "{comparison}: the perturbed weight was not caught"
        );
    }
    assert!(!report.passed());
}
