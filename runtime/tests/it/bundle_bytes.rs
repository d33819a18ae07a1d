//! A bundle given as bytes (`Bundle::from_files`, what the WebAssembly build loads; docs/wasm.md):
//! the same verification as a folder (sha256, size, graph I/O), graphs loaded from memory by tract
//! give the same frames as from files, and a page may leave out the reference vectors, and (loading
//! what tract runs) the graphs of the other forms, but never a graph the model runs.

use std::collections::BTreeMap;

use std::path::Path;

use livegesture::backend::tract::TractBackend;
use livegesture::backend::{Backend, GraphRunner};
use livegesture::bundle::{repo_default_bundle, Bundle, BundleError, GraphSpec};
use livegesture::model::{self, GraphForm, LoadOptions, StreamOptions};

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

/// The manifest and the files of `names` among `all`.
fn only(all: &BTreeMap<String, Vec<u8>>, names: &[String]) -> BTreeMap<String, Vec<u8>> {
    all.iter()
        .filter(|(k, _)| *k == "manifest.json" || names.contains(k))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect()
}

/// Two seconds of a sine (`step` radians a sample) through a stream of each bundle on tract with
/// `seed`: some frames, and the same from both.
fn assert_same_frames(a: &Bundle, b: &Bundle, seed: u64, step: f32) {
    assert_same_frames_with(
        a,
        b,
        seed,
        step,
        &TractBackend::new(),
        &LoadOptions::default(),
    );
}

/// [`assert_same_frames`], each bundle loaded on `backend` with `load`.
fn assert_same_frames_with(
    a: &Bundle,
    b: &Bundle,
    seed: u64,
    step: f32,
    backend: &dyn Backend,
    load: &LoadOptions,
) {
    let audio: Vec<f32> = (0..16000 * 2)
        .map(|i| (i as f32 * step).sin() * 0.3)
        .collect();
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let mut out = Vec::new();
    for bundle in [a, b] {
        let m = model::load_with(bundle, backend, load).unwrap();
        let mut s = m.new_stream(&opts).unwrap();
        out.push(s.push_audio(&audio).unwrap());
    }
    assert!(!out[0].is_empty());
    assert_eq!(out[0], out[1]);
}

/// tract under another name that runs the forms of the backend `forms_of` names, as ONNX Runtime Web
/// runs ort's.
struct FormsOf(TractBackend, &'static str);

impl Backend for FormsOf {
    fn name(&self) -> &str {
        "tract-under-another-name"
    }
    fn forms_of(&self) -> &str {
        self.1
    }
    fn load(&self, spec: &GraphSpec, path: &Path) -> anyhow::Result<Box<dyn GraphRunner>> {
        self.0.load(spec, path)
    }
    fn load_bytes(
        &self,
        spec: &GraphSpec,
        path: &Path,
        bytes: &[u8],
    ) -> anyhow::Result<Box<dyn GraphRunner>> {
        self.0.load_bytes(spec, path, bytes)
    }
}

#[test]
fn bytes_load_and_match_the_folder() {
    let b = Bundle::from_files("mem/default", files()).unwrap();
    assert!(b.is_in_memory());
    let d = Bundle::load(repo_default_bundle()).unwrap();
    assert_eq!(b.graphs().len(), d.graphs().len());
    // the same frames from graphs loaded from memory as from files
    assert_same_frames(&b, &d, 3, 0.013);
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

#[test]
fn a_page_may_load_only_the_graphs_tract_runs() {
    let all = files();
    let d = Bundle::load(repo_default_bundle()).unwrap();
    let run = d.manifest().graph_files_run_by("tract", None);
    let graph_bytes = |names: &mut dyn Iterator<Item = &String>| -> usize {
        names.map(|f| all[f.as_str()].len()).sum()
    };
    let every: Vec<String> = d.graphs().iter().map(|g| g.file.clone()).collect();
    let (run_bytes, every_bytes) = (graph_bytes(&mut run.iter()), graph_bytes(&mut every.iter()));
    // the default bundle carries every form; tract runs one of them (and the face graph)
    assert!(run.contains(&"audio_encoder.onnx".to_string()), "{run:?}");
    assert!(run.contains(&"face.onnx".to_string()), "{run:?}");
    assert!(
        run_bytes * 2 < every_bytes,
        "{run_bytes} of {every_bytes} graph bytes: {run:?}"
    );
    let some = only(&all, &run);
    // the same frames as the folder with every file
    let b = Bundle::from_files_run_by("mem/default", some.clone(), "tract", None).unwrap();
    assert_same_frames(&b, &d, 5, 0.011);
    // asking for every graph, the same files are refused, naming one that is missing
    let e = Bundle::from_some_files("mem/default", some.clone(), false).unwrap_err();
    assert!(matches!(e, BundleError::MissingFile { .. }), "{e}");
    // a graph tract runs may not be left out
    for gone in ["decoders_fused.onnx", "face.onnx"] {
        assert!(run.contains(&gone.to_string()), "{run:?}");
        let mut f = some.clone();
        f.remove(gone);
        let e = Bundle::from_files_run_by("mem/default", f, "tract", None).unwrap_err();
        assert!(matches!(e, BundleError::MissingFile { .. }), "{e}");
        assert!(e.to_string().contains(gone), "{e}");
    }
    // a graph given but not run is still checked
    let mut f = some.clone();
    let mut bad = all["experts_fused_ring.onnx"].clone();
    let n = bad.len();
    bad[n / 2] ^= 1;
    f.insert("experts_fused_ring.onnx".into(), bad);
    let e = Bundle::from_files_run_by("mem/default", f, "tract", None).unwrap_err();
    assert!(matches!(e, BundleError::HashMismatch { .. }), "{e}");
    // loaded with only ONNX Runtime's graphs, tract's model names a graph it lacks
    let ort_run = d.manifest().graph_files_run_by("ort", None);
    assert_ne!(ort_run, run);
    let b = Bundle::from_files_run_by("mem/default", only(&all, &ort_run), "ort", None).unwrap();
    let e = model::load(&b, &TractBackend::new()).err().unwrap();
    let msg = format!("{e:#}");
    assert!(msg.contains(".onnx"), "{msg}");
}

#[test]
fn a_backend_runs_the_forms_it_names_and_a_page_loads_only_their_graphs() {
    let all = files();
    let d = Bundle::load(repo_default_bundle()).unwrap();
    let m = d.manifest();
    let has = |files: &[String], f: &str| files.iter().any(|x| x == f);
    // ONNX Runtime Web runs ort's form (`Backend::forms_of`): its graphs, not the canonical ones
    let ort_run = m.graph_files_run_by("ort", None);
    for f in ["experts_fused_ring.onnx", "fusion_ring.onnx", "face.onnx"] {
        assert!(has(&ort_run, f), "{f} not in {ort_run:?}");
    }
    assert!(!has(&ort_run, "expert_upper.onnx"), "{ort_run:?}");
    let b = Bundle::from_files_run_by("mem/default", only(&all, &ort_run), "ort", None).unwrap();
    // a backend that runs ort's forms loads from those files alone, the same frames as from the folder
    let as_ort = FormsOf(TractBackend::new(), "ort");
    assert_same_frames_with(&b, &d, 5, 0.011, &as_ort, &LoadOptions::default());
    // under its own name (no form in the manifest) it would run the canonical graphs, not given here
    let own = FormsOf(TractBackend::new(), "tract-under-another-name");
    let e = model::load(&b, &own).err().unwrap();
    assert!(format!("{e:#}").contains(".onnx"), "{e:#}");
    // a named form: its graphs and its own decoders; `auto` is the backend's own
    let canonical = m.graph_files_run_by("tract", Some("canonical"));
    for f in [
        "audio_encoder.onnx",
        "fusion.onnx",
        "expert_upper.onnx",
        "decoder_face.onnx",
        "face.onnx",
    ] {
        assert!(has(&canonical, f), "{f} not in {canonical:?}");
    }
    assert!(!has(&canonical, "decoders_fused.onnx"), "{canonical:?}");
    assert_eq!(
        m.graph_files_run_by("tract", Some("auto")),
        m.graph_files_run_by("tract", None)
    );
    let b = Bundle::from_files_run_by(
        "mem/default",
        only(&all, &canonical),
        "tract",
        Some("canonical"),
    )
    .unwrap();
    let opts = LoadOptions {
        form: GraphForm::Canonical,
    };
    assert_same_frames_with(&b, &d, 5, 0.011, &TractBackend::new(), &opts);
}
