//! The parity suite passes on the shipped bundle and on a freshly exported tiny bundle, both
//! backends, every check (docs/parity.md).

use livegesture_parity::{Check, Metric, Report};
use livegesture_parity_tests::{default_bundle, rollout_tokens_row, run_parity, tiny_bundle};

/// Every check ran and produced rows for every graph and both backends, and all passed.
fn assert_complete_and_passing(report: &Report, graphs: usize) {
    for check in Check::ALL {
        assert!(
            report.rows.iter().any(|r| r.check == check),
            "no rows for the {check} check"
        );
    }
    for comparison in ["ort vs torch", "tract vs torch", "tract vs ort"] {
        let covered: std::collections::BTreeSet<&str> = report
            .rows
            .iter()
            .filter(|r| r.check == Check::Graph && r.comparison == comparison)
            .map(|r| r.what.as_str())
            .collect();
        assert_eq!(
            covered.len(),
            graphs,
            "{comparison}: graphs compared {covered:?}"
        );
    }
    for comparison in ["ort vs torch", "tract vs torch", "tract vs ort"] {
        let tokens = rollout_tokens_row(report, comparison);
        assert_eq!(tokens.metric, Metric::DifferingSteps);
        assert!(
            tokens.compared >= 1000,
            "{comparison}: rollout of only {} steps",
            tokens.compared
        );
    }
    let failures: Vec<String> = report.failures().iter().map(|r| r.failure_line()).collect();
    assert!(
        failures.is_empty(),
        "parity failures:\n{}",
        failures.join("\n")
    );
    assert!(report.passed());
}

#[test]
fn default_bundle_passes_every_check() {
    let dir = default_bundle();
    let report = run_parity(&dir, &[]);
    let graphs = livegesture::bundle::Bundle::load(&dir)
        .unwrap()
        .graphs()
        .len();
    assert_complete_and_passing(&report, graphs);
}

#[test]
fn fresh_tiny_bundle_passes_every_check() {
    let dir = tiny_bundle();
    let report = run_parity(&dir, &[]);
    let graphs = livegesture::bundle::Bundle::load(&dir)
        .unwrap()
        .graphs()
        .len();
    assert_complete_and_passing(&report, graphs);
}
