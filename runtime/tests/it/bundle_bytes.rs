//! A bundle given as bytes (`Bundle::from_files`, what the WebAssembly build loads; docs/wasm.md):
//! the same verification as a folder (sha256, size, graph I/O), graphs loaded from memory by tract
//! give the same frames as from files, and a page may leave out the reference vectors but never a
//! graph.

use std::collections::BTreeMap;

use livegesture::backend::tract::TractBackend;
use livegesture::bundle::{repo_default_bundle, Bundle, BundleError};
use livegesture::model::{self, StreamOptions};

/// Every file of the default bundle that its manifest lists, plus the manifest.
fn files() -> BTreeMap<String, Vec<u8>> {
    let dir = repo_default_bundle();
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    let mut files = BTreeMap::new();
    files.insert(
        "manifest.json".to_string(),
        std::fs::read(dir.join("manifest.json")).unwrap(),
    );
    for rel in manifest["files"].as_object().unwrap().keys() {
        files.insert(rel.clone(), std::fs::read(dir.join(rel)).unwrap());
    }
    files
}

#[test]
fn bytes_load_and_match_the_folder() {
    let b = Bundle::from_files("mem/default", files()).unwrap();
    assert!(b.is_in_memory());
    let d = Bundle::load(repo_default_bundle()).unwrap();
    assert_eq!(b.graphs().len(), d.graphs().len());
    // the same frames from graphs loaded from memory as from files
    let audio: Vec<f32> = (0..16000 * 2)
        .map(|i| (i as f32 * 0.013).sin() * 0.3)
        .collect();
    let opts = StreamOptions {
        seed: 3,
        ..Default::default()
    };
    let mut out = Vec::new();
    for bundle in [&b, &d] {
        let m = model::load(bundle, &TractBackend::new()).unwrap();
        let mut s = m.new_stream(&opts).unwrap();
        out.push(s.push_audio(&audio).unwrap());
    }
    assert!(!out[0].is_empty());
    assert_eq!(out[0], out[1]);
}

#[test]
fn a_changed_byte_is_refused_naming_the_file() {
    let mut f = files();
    let g = f.get_mut("fusion.onnx").unwrap();
    let n = g.len();
    g[n / 2] ^= 1;
    let e = Bundle::from_files("mem/default", f).unwrap_err();
    assert!(matches!(e, BundleError::HashMismatch { .. }), "{e}");
    assert!(e.to_string().contains("mem/default/fusion.onnx"), "{e}");
}

#[test]
fn missing_files_are_refused_unless_optional() {
    let mut f = files();
    f.remove("reference/rollout.npz");
    // complete: every listed file is required
    let e = Bundle::from_files("mem/default", f.clone()).unwrap_err();
    assert!(matches!(e, BundleError::MissingFile { .. }), "{e}");
    assert!(e.to_string().contains("reference/rollout.npz"), "{e}");
    // a page that only runs the model may leave out the references; reading one then fails
    let b = Bundle::from_some_files("mem/default", f.clone(), false).unwrap();
    let e = b.read("reference/rollout.npz").unwrap_err();
    assert!(e.to_string().contains("reference/rollout.npz"), "{e}");
    // ... but never a graph
    f.remove("expert_hands.onnx");
    let e = Bundle::from_some_files("mem/default", f, false).unwrap_err();
    assert!(e.to_string().contains("expert_hands.onnx"), "{e}");
    // and never the manifest
    let mut f = files();
    f.remove("manifest.json");
    let e = Bundle::from_files("mem/default", f).unwrap_err();
    assert!(matches!(e, BundleError::NoManifest { .. }), "{e}");
}
