//! The parity checks that need no files and no onnxruntime (`livegesture::portable_parity`, what the
//! WebAssembly binding's `Model.parity()` runs in a browser), natively on tract: they pass on both
//! shipped bundles, read from a folder or from files in memory alike, and fail on a perturbed weight
//! naming the graph.

use std::collections::BTreeMap;
use std::path::Path;

use livegesture::backend::tract::TractBackend;
use livegesture::bundle::Bundle;
use livegesture::portable_parity::{self, Report};
use livegesture_parity_tests::{break_bundle, default_bundle, repo_root, tiny_bundle, Breakage};

/// Every file of the bundle folder `dir` (recursively), keyed by its path relative to `dir`.
fn files_of(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p
                    .strip_prefix(root)
                    .unwrap()
                    .to_string_lossy()
                    .replace('\\', "/");
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

fn run(bundle: &Bundle) -> Report {
    portable_parity::run(bundle, &TractBackend::new(), "tract")
}

fn passes_from_folder_and_memory(dir: &Path) {
    let from_dir = run(&Bundle::load(dir).unwrap());
    assert!(from_dir.ok(), "{}: {:#?}", dir.display(), from_dir.lines);
    assert!(
        from_dir.passed >= 3,
        "{}: {:?}",
        dir.display(),
        from_dir.lines
    );
    assert!(
        from_dir.lines.iter().any(|l| l.contains("rollout")),
        "the rollout ran: {:?}",
        from_dir.lines
    );
    let in_memory = Bundle::from_files(dir, files_of(dir)).unwrap();
    assert!(in_memory.is_in_memory());
    let from_memory = run(&in_memory);
    assert_eq!(from_dir.lines, from_memory.lines, "folder vs memory");
}

#[test]
fn passes_on_the_shipped_livegesture_bundle() {
    passes_from_folder_and_memory(&default_bundle());
}

#[test]
fn passes_on_the_shipped_diffsheg_bundle() {
    passes_from_folder_and_memory(&repo_root().join("models").join("diffsheg"));
}

#[test]
fn fails_on_a_perturbed_weight_naming_the_graph() {
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("perturbed");
    let graph = "expert_hands";
    break_bundle(
        &tiny_bundle(),
        &dst,
        graph,
        &Breakage::PerturbWeight { delta: 0.01 },
    );
    let report = run(&Bundle::load(&dst).unwrap());
    assert!(
        !report.ok(),
        "a perturbed weight passed: {:#?}",
        report.lines
    );
    let failed: Vec<&String> = report
        .lines
        .iter()
        .filter(|l| l.starts_with("FAIL"))
        .collect();
    assert!(
        failed
            .iter()
            .any(|l| l.contains(&format!("graph {graph} "))),
        "no FAIL line names {graph}: {failed:#?}"
    );
    // the other graphs still pass
    assert!(
        failed
            .iter()
            .filter(|l| l.starts_with("FAIL graph"))
            .all(|l| l.contains(&format!("graph {graph} "))),
        "{failed:#?}"
    );
}

#[test]
fn a_reference_file_left_out_is_a_failure_not_a_pass() {
    let dir = default_bundle();
    let mut files = files_of(&dir);
    let rollout = Bundle::load(&dir).unwrap().reference_rollout();
    assert!(files.remove(&rollout).is_some(), "{rollout}");
    let b = Bundle::from_some_files(&dir, files, false).unwrap();
    let report = run(&b);
    assert!(!report.ok());
    assert!(
        report
            .lines
            .iter()
            .any(|l| l.starts_with("FAIL rollout") && l.contains(&rollout)),
        "{:#?}",
        report.lines
    );
}
