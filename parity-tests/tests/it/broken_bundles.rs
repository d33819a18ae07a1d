//! Proof that the parity checks can fail: copies of the tiny bundle with one graph broken by
//! `tools/break_bundle.py` (ONNX surgery, manifest sha256 rewritten so the copy loads).

use livegesture_parity::{Check, Metric, Report};
use livegesture_parity_tests::{break_bundle, run_parity, tiny_bundle, Breakage};

const BROKEN: &str = "expert_hands";

/// Graph-level rows of `graph` with `comparison`.
fn graph_rows<'a>(
    report: &'a Report,
    graph: &str,
    comparison: &str,
) -> Vec<&'a livegesture_parity::Row> {
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

// ------------------------------------------------------------------ bounds scale with magnitude

/// `tools/break_bundle.py SRC DST --graph all --magnify M --ulps K`: every graph's data outputs
/// scaled to values near `M`, the reference a few float32 ulps away (see the tool's docs).
fn magnify(src: &std::path::Path, dst: &std::path::Path, target: f64, ulps: u32) {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tools")
        .join("break_bundle.py");
    let args: Vec<std::ffi::OsString> = vec![
        src.into(),
        dst.into(),
        "--graph".into(),
        "all".into(),
        format!("--magnify={target}").into(),
        format!("--ulps={ulps}").into(),
    ];
    let text = livegesture_parity_tests::run_python("tools/break_bundle.py", &script, &args);
    eprintln!("break_bundle: {}", text.trim());
}

/// docs/parity.md: every bound scales with the reference tensor's magnitude. Each graph of `src`
/// (every form it carries) with outputs near 40 and a reference 3 float32 ulps away passes its
/// graph rows, though the absolute error is above 1e-5 (the absolute bound of before would have
/// failed it); the same bundle with one weight of `broken` perturbed still fails, naming that graph,
/// against the reference on both backends, at the scale it was judged at.
fn magnitude_passes_and_a_perturbed_weight_fails(src: &std::path::Path, broken: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let big = tmp.path().join("magnified");
    magnify(src, &big, 40.0, 3);
    let report = run_parity(&big, &[Check::Graph]);
    let graphs: std::collections::BTreeSet<String> = livegesture::bundle::Bundle::load(&big)
        .unwrap()
        .graphs()
        .iter()
        .map(|g| g.name.clone())
        .collect();
    let failures: Vec<String> = report.failures().iter().map(|r| r.failure_line()).collect();
    assert!(
        failures.is_empty(),
        "values near 40 a few ulps apart must pass the scaled bounds:\n{}",
        failures.join("\n")
    );
    // every graph was compared near the magnified magnitude (the largest reference value is 40; a
    // row records the scale of its worst step, which is below that maximum: scale > 20, ten times
    // the unmagnified scales of 1-2.5), and in every graph
    // some row's absolute error is above its bound yet passes at its scale (issue 38 item 9: the
    // thresholds had been lowered to a scale > 4 and one such row in the whole report)
    for g in &graphs {
        let rows = report.rows_for(Check::Graph, g);
        assert!(
            rows.iter()
                .any(|r| r.comparison.starts_with("ort vs") && r.scale > 20.0),
            "{g}: no ort row judged at a scale above 20"
        );
        assert!(
            rows.iter().any(|r| r.comparison.starts_with("ort vs")
                && r.error > r.bound
                && r.pass),
            "{g}: no ort row with an absolute error above its bound: the test does not exercise the scale"
        );
    }

    let bad = tmp.path().join("magnified-perturbed");
    let change = break_bundle(&big, &bad, broken, &Breakage::PerturbWeight { delta: 0.05 });
    eprintln!("break_bundle: {change}");
    let report = run_parity(&bad, &[Check::Graph]);
    let failed: std::collections::BTreeSet<&str> =
        report.failures().iter().map(|r| r.what.as_str()).collect();
    assert_eq!(failed, [broken].into_iter().collect(), "graphs that failed");
    for backend in ["ort", "tract"] {
        let row = report
            .rows_for(Check::Graph, broken)
            .into_iter()
            .find(|r| r.comparison.starts_with(&format!("{backend} vs ")) && !r.pass)
            .unwrap_or_else(|| {
                panic!("{backend}: the perturbed weight in {broken} was not caught")
            });
        let line = row.failure_line();
        for part in [broken, row.output.as_str(), "step", "x scale"] {
            assert!(line.contains(part), "'{part}' not in: {line}");
        }
    }
}

#[test]
fn livegesture_every_form_scaled_bound_passes_near_40_and_catches_a_perturbed_weight() {
    // the tiny export carries every form: canonical, fused (experts_fused, decoders_fused) and
    // attention (fusion_attention); the perturbed one is the fused eXperts
    let names: Vec<String> = livegesture::bundle::Bundle::load(tiny_bundle())
        .unwrap()
        .graphs()
        .iter()
        .map(|g| g.name.clone())
        .collect();
    for form_graph in ["experts_fused", "decoders_fused", "fusion_attention"] {
        assert!(
            names.iter().any(|n| n == form_graph),
            "{form_graph} missing"
        );
    }
    magnitude_passes_and_a_perturbed_weight_fails(&tiny_bundle(), "experts_fused");
}

#[test]
fn livegesture_canonical_graph_scaled_bound_catches_a_perturbed_weight() {
    magnitude_passes_and_a_perturbed_weight_fails(&tiny_bundle(), BROKEN);
}

#[test]
fn diffsheg_scaled_bound_passes_near_40_and_catches_a_perturbed_weight() {
    magnitude_passes_and_a_perturbed_weight_fails(
        &livegesture_parity_tests::diffsheg_tiny_bundle(),
        "denoiser",
    );
}

#[test]
fn f16_scaled_bound_passes_near_40_and_catches_a_perturbed_weight() {
    // a reduced-precision bundle is checked against the f32 bundle's torch references with the bound
    // export/quantize.py measured and stated: derive it from the magnified f32 bundle, so its graphs,
    // references and stated bounds are all at values near 40
    let tmp = tempfile::tempdir().unwrap();
    let big = tmp.path().join("tiny-magnified");
    magnify(&tiny_bundle(), &big, 40.0, 3);
    let f16 = tmp.path().join("tiny-magnified-f16");
    let script = livegesture_parity_tests::repo_root()
        .join("export")
        .join("quantize.py");
    let args: Vec<std::ffi::OsString> = vec![
        "--bundle".into(),
        big.into(),
        "--precision".into(),
        "f16".into(),
        "--out".into(),
        f16.clone().into(),
    ];
    livegesture_parity_tests::run_python("export/quantize.py", &script, &args);
    let report = run_parity(&f16, &[Check::Graph]);
    let failures: Vec<String> = report.failures().iter().map(|r| r.failure_line()).collect();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(
        report
            .rows
            .iter()
            .any(|r| r.comparison.starts_with("ort vs") && r.scale > 30.0),
        "no row judged at a scale above 30"
    );
    // the bound is stated once, from the scaled error (issue 38 item 4): the same perturbation the
    // f32 tests catch (0.01-0.05) is caught in the f16 bundle too; with the bound stated from the
    // absolute error and scaled again it took 0.5
    let bad = tmp.path().join("f16-perturbed");
    break_bundle(&f16, &bad, BROKEN, &Breakage::PerturbWeight { delta: 0.02 });
    let report = run_parity(&bad, &[Check::Graph]);
    let failed: std::collections::BTreeSet<&str> =
        report.failures().iter().map(|r| r.what.as_str()).collect();
    assert_eq!(failed, [BROKEN].into_iter().collect(), "graphs that failed");
    for r in report.failures() {
        let line = r.failure_line();
        assert!(line.contains(BROKEN) && line.contains("x scale"), "{line}");
    }
}
