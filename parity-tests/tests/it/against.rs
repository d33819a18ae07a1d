//! Export against export (`livegesture parity --against`, `livegesture_parity::against`): a
//! re-export of the same weights passes; an export of other weights (the tiny config with another
//! `--random-seed`) fails, naming the graphs and outputs that moved and the rollout's first differing
//! step.

use std::ffi::OsString;
use std::path::{Path, PathBuf};

use livegesture_parity::{self as parity, AgainstOptions, Check, Metric, ParityOptions, Report};
use livegesture_parity_tests::{diffsheg_tiny_bundle, repo_root, run_python, tiny_bundle};

/// Exports `args` into `dir` with `export/export.py`.
fn export(dir: &Path, args: &[&str]) -> PathBuf {
    let mut a: Vec<OsString> = args.iter().map(OsString::from).collect();
    a.push("--out".into());
    a.push(dir.into());
    run_python(
        "export/export.py (re-exports for --against)",
        &repo_root().join("export").join("export.py"),
        &a,
    );
    dir.to_path_buf()
}

/// The exporter's arguments for a short reference clip and rollout (as scripts/variants.sh): for the
/// NEW side of `against`, whose reference rollout is not compared.
const SHORT_REFERENCE: &[&str] = &["--reference-seconds", "6", "--rollout-tokens", "40"];

fn against(new: &Path, old: &Path) -> Report {
    livegesture_parity_tests::require_ort();
    let mut log = |m: &str| eprintln!("against: {m}");
    let r = parity::against(
        new,
        old,
        &ParityOptions::default(),
        &AgainstOptions::default(),
        &mut log,
    )
    .unwrap_or_else(|e| panic!("--against could not run: {e:#}"));
    eprintln!("{}\n{}", r.table(false), r.summary());
    r
}

#[test]
fn a_reexport_of_the_same_weights_passes_and_other_weights_fail_naming_what_moved() {
    let tmp = tempfile::tempdir().unwrap();
    let old = tiny_bundle();
    // `against` runs both bundles on the OLD bundle's reference inputs and rollout (audio, seed): the
    // new bundles' own reference rollouts are never read, so they are exported short (SHORT_REFERENCE:
    // 40 tokens instead of 1125, three torch rollouts each, about 60 s of CPU per export). The graphs
    // are the same files whatever the reference's length. The two exports side by side (one thread of
    // torch each).
    let (same, other) = std::thread::scope(|s| {
        let other = s.spawn(|| {
            export(
                &tmp.path().join("seed1"),
                &[&["--config", "tiny", "--random-seed", "1"], SHORT_REFERENCE].concat(),
            )
        });
        let same = export(
            &tmp.path().join("same"),
            &[livegesture_parity_tests::EXPORT_ARGS, SHORT_REFERENCE].concat(),
        );
        (same, other.join().expect("the seed-1 export panicked"))
    });
    let report = against(&same, &old);
    assert!(report.passed(), "a re-export moved: {}", report.summary());
    let graphs = livegesture::bundle::Bundle::load(&old)
        .unwrap()
        .graphs()
        .len();
    let compared: std::collections::BTreeSet<&str> = report
        .rows
        .iter()
        .filter(|r| r.check == Check::Graph)
        .map(|r| r.what.as_str())
        .collect();
    assert_eq!(compared.len(), graphs, "every graph compared: {compared:?}");
    let tokens = report
        .rows
        .iter()
        .find(|r| r.check == Check::Rollout && r.output == "tokens")
        .expect("a rollout token row");
    assert!(tokens.compared >= 1000 && tokens.error == 0.0);

    let report = against(&other, &old);
    assert!(!report.passed());
    let failed: std::collections::BTreeSet<&str> = report
        .failures()
        .iter()
        .filter(|r| r.check == Check::Graph)
        .map(|r| r.what.as_str())
        .collect();
    assert_eq!(failed.len(), graphs, "every graph moved: {failed:?}");
    for r in report.failures() {
        let line = r.failure_line();
        assert!(
            line.contains(&r.what) && line.contains(&r.output) && line.contains("new vs old"),
            "{line}"
        );
    }
    let tokens = report
        .rows
        .iter()
        .find(|r| r.check == Check::Rollout && r.output == "tokens")
        .expect("a rollout token row");
    assert_eq!(tokens.metric, Metric::DifferingSteps);
    assert!(!tokens.pass && tokens.step.is_some(), "{tokens:?}");
    assert!(
        report
            .divergences
            .iter()
            .any(|d| d.first == "new" && d.second == "old"),
        "the first differing step is reported"
    );

    // the bounds are the user's: with a token agreement of 0 and huge bounds the same pair passes
    let loose = AgainstOptions {
        graph_bound: 1e9,
        frames_bound: 1e9,
        token_agreement: 0.0,
    };
    let mut log = |_: &str| {};
    let r = parity::against(&other, &old, &ParityOptions::default(), &loose, &mut log).unwrap();
    assert!(r.passed(), "{}", r.summary());
}

#[test]
fn diffsheg_against_itself_passes_and_other_weights_fail() {
    let tmp = tempfile::tempdir().unwrap();
    let old = diffsheg_tiny_bundle();
    let report = against(&old, &old);
    assert!(report.passed(), "{}", report.summary());
    assert!(report
        .rows
        .iter()
        .any(|r| r.check == Check::Rollout && r.output == "poses"));
    let other = export(
        &tmp.path().join("seed1"),
        &[
            "--family",
            "diffsheg",
            "--config",
            "tiny",
            "--random-seed",
            "1",
        ],
    );
    let report = against(&other, &old);
    let failed: std::collections::BTreeSet<&str> =
        report.failures().iter().map(|r| r.what.as_str()).collect();
    assert!(
        failed.contains("denoiser") && failed.contains("rollout"),
        "{failed:?}"
    );
}
