//! Proof that the parity checks can fail: copies of the tiny bundle with one graph broken by
//! `tools/break_bundle.py` (ONNX surgery, manifest sha256 rewritten so the copy loads).

use livegesture::parity::{Check, Metric, Report};
use livegesture_parity_tests::{break_bundle, run_parity, tiny_bundle, Breakage};

const BROKEN: &str = "expert_hands";

/// Graph-level rows of `graph` with `comparison`.
fn graph_rows<'a>(
    report: &'a Report,
    graph: &str,
    comparison: &str,
) -> Vec<&'a livegesture::parity::Row> {
    report
        .rows_for(Check::Graph, graph)
        .into_iter()
        .filter(|r| r.comparison == comparison)
        .collect()
}

/// Every graph other than `broken` passes all its graph-level rows.
fn others_pass(report: &Report, broken: &str) {
    for r in report
        .rows
        .iter()
        .filter(|r| r.check == Check::Graph && r.what != broken)
    {
        assert!(
            r.pass,
            "graph '{}' should pass: {}",
            r.what,
            r.failure_line()
        );
    }
}

#[test]
fn perturbed_weight_fails_exactly_that_graph() {
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("perturbed");
    let change = break_bundle(
        &tiny_bundle(),
        &dst,
        BROKEN,
        &Breakage::PerturbWeight { delta: 0.01 },
    );
    eprintln!("break_bundle: {change}");
    let report = run_parity(&dst, &[Check::Graph]);

    // exactly that graph fails, against torch on both backends ...
    let failed: std::collections::BTreeSet<&str> =
        report.failures().iter().map(|r| r.what.as_str()).collect();
    assert_eq!(failed, [BROKEN].into_iter().collect(), "graphs that failed");
    for comparison in ["ort vs torch", "tract vs torch"] {
        let rows = graph_rows(&report, BROKEN, comparison);
        let bad: Vec<_> = rows.iter().filter(|r| !r.pass).collect();
        assert!(
            !bad.is_empty(),
            "{comparison}: the perturbed weight was not caught"
        );
        for r in bad {
            // a failure names the graph, the output, the step and the error
            assert_eq!(r.what, BROKEN);
            assert!(!r.output.is_empty() && r.output != "(all)");
            assert!(r.step.is_some(), "no step in {}", r.failure_line());
            assert!(r.error > r.bound && r.error.is_finite());
            let line = r.failure_line();
            assert!(
                line.contains(BROKEN) && line.contains(&r.output) && line.contains("step"),
                "{line}"
            );
        }
    }
    // ... while both backends run the same perturbed graph alike
    let cross = graph_rows(&report, BROKEN, "tract vs ort");
    assert!(!cross.is_empty());
    assert!(
        cross.iter().all(|r| r.pass),
        "tract vs ort must still agree on the perturbed graph"
    );
    others_pass(&report, BROKEN);
}

#[test]
fn frozen_cache_update_is_caught() {
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("frozen");
    let cache = "layer0.xattn.k";
    let change = break_bundle(
        &tiny_bundle(),
        &dst,
        BROKEN,
        &Breakage::FreezeCache { name: cache.into() },
    );
    eprintln!("break_bundle: {change}");
    // ort runs the fused eXperts by default (docs/bundle.md#forms-and-precision): there the broken canonical graph shows in the
    // rollout of the canonical form against the fused one
    let report = run_parity(&dst, &[Check::Rollout]);
    let forms = report
        .rows
        .iter()
        .find(|r| r.what == "rollout (fused form)" && r.output == "tokens")
        .expect("the rollout compares the forms on ort");
    assert!(!forms.pass, "ort: the forms agree: {forms:?}");
    // from here on both backends run the canonical form, so both rollouts step the broken graph
    let manifest = dst.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    m["backend_forms"] = serde_json::json!({"ort": "canonical", "tract": "canonical"});
    std::fs::write(&manifest, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let report = run_parity(&dst, &[Check::Graph, Check::Rollout]);

    // the graph check names the graph and the broken cache output
    let output = format!("new_cache.{cache}");
    for comparison in ["ort vs torch", "tract vs torch"] {
        let row = graph_rows(&report, BROKEN, comparison)
            .into_iter()
            .find(|r| r.output == output)
            .unwrap_or_else(|| panic!("no {comparison} row for {output}"));
        assert!(
            !row.pass,
            "{comparison}: the frozen cache was not caught: {row:?}"
        );
        assert_eq!(
            row.step,
            Some(9),
            "the final caches are compared after the last step"
        );
    }
    others_pass(&report, BROKEN);

    // and the rollout diverges from torch, reported with step, region, tokens and margins
    for backend in ["ort", "tract"] {
        let tokens = report
            .rows
            .iter()
            .find(|r| {
                r.check == Check::Rollout
                    && r.comparison == format!("{backend} vs torch")
                    && r.output == "tokens"
            })
            .expect("rollout token row");
        assert_eq!(tokens.metric, Metric::DifferingSteps);
        assert!(!tokens.pass, "{backend}: the rollout did not diverge");
        let d = report
            .divergences
            .iter()
            .find(|d| d.first == backend && d.second == "torch")
            .expect("a divergence report");
        assert_eq!(Some(d.step), tokens.step);
        assert!(["upper", "hands", "lower", "face"].contains(&d.region.as_str()));
        assert_ne!(d.first_token, d.second_token);
        assert_eq!(d.margins.len(), 2, "margins from both backends' logits");
        let text = d.to_string();
        assert!(
            text.contains(&format!("step {}", d.step))
                && text.contains(&d.region)
                && text.contains("verdict"),
            "{text}"
        );
    }
    // ort and tract run the same broken graph alike: identical tokens
    let cross = report
        .rows
        .iter()
        .find(|r| {
            r.check == Check::Rollout && r.comparison == "tract vs ort" && r.output == "tokens"
        })
        .expect("tract vs ort rollout row");
    assert!(cross.pass, "{}", cross.failure_line());
}
