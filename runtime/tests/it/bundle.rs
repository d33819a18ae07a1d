//! Bundle loading: verification of files, hashes, schema version and graph I/O; state from the manifest.

use livegesture_parity_tests as common;

use livegesture::backend::DType;
use livegesture::bundle::{concrete_shape, Bundle, BundleError, Dim};

fn load_err(dir: &std::path::Path) -> String {
    match Bundle::load(dir) {
        Ok(_) => panic!(
            "bundle {} loaded but should have been refused",
            dir.display()
        ),
        Err(e) => e.to_string(),
    }
}

fn edit_manifest(dir: &std::path::Path, f: impl FnOnce(&mut serde_json::Value)) {
    let p = dir.join("manifest.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

#[test]
fn test_bundle_loads_and_describes_itself() {
    let b = Bundle::load(common::tiny_bundle()).expect("test bundle loads");
    assert_eq!(b.family(), livegesture::bundle::Family::LiveGesture);
    let lg = b.livegesture().unwrap();
    assert_eq!(lg.region_names(), ["upper", "hands", "lower", "face"]);
    // 10 canonical graphs, the fused eXperts, the fused decoders and the attention form's fusion
    // (docs/bundle.md#forms-and-precision); no face graph (the tiny config's 16 mel bands, docs/face.md)
    assert_eq!(b.graphs().len(), 13);
    assert!(b.graph("experts_fused").is_ok());
    assert!(b.graph("decoders_fused").is_ok());
    assert!(b.graph("fusion_attention").is_ok());
    assert!(lg.vocab.bos_token >= lg.vocab.codebook_size as i64);
    assert!(lg.sampling.temperature > 0.0);
    // initial state comes from the manifest's cache shapes
    for g in b.graphs() {
        assert!(!g.caches.is_empty(), "graph {} has caches", g.name);
        for c in &g.caches {
            let z = c.zeros(3);
            assert_eq!(z.shape, concrete_shape(&c.shape, 3));
            assert_eq!(c.shape[0], Dim::Batch);
            assert_eq!(z.dtype(), c.dtype);
            assert!(c.dtype == DType::F32 || c.dtype == DType::I64);
        }
    }
}

#[test]
fn a_form_naming_a_missing_graph_or_an_unknown_form_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| {
        v["forms"]["fused"]["experts"] = serde_json::json!(["experts_missing"]);
    });
    let e = load_err(&dir);
    assert!(
        e.contains("forms.fused.experts") && e.contains("experts_missing"),
        "{e}"
    );
    edit_manifest(&dir, |v| {
        v["forms"]["fused"]["experts"] = serde_json::json!(["experts_fused"]);
        v["forms"]["fused"]["decoders"] = serde_json::json!(["decoders_missing"]);
    });
    let e = load_err(&dir);
    assert!(
        e.contains("forms.fused.decoders") && e.contains("decoders_missing"),
        "{e}"
    );
    edit_manifest(&dir, |v| {
        v["forms"]["fused"]["decoders"] = serde_json::json!(["decoders_fused", "decoder_upper"]);
    });
    let e = load_err(&dir);
    assert!(e.contains("forms.fused.decoders lists 2 graphs"), "{e}");
    edit_manifest(&dir, |v| {
        v["forms"]["fused"]["decoders"] = serde_json::json!(["decoders_fused"]);
        v["forms"]["attention"]["fusion"] = serde_json::json!("fusion_missing");
    });
    let e = load_err(&dir);
    assert!(
        e.contains("forms.attention.fusion") && e.contains("fusion_missing"),
        "{e}"
    );
    edit_manifest(&dir, |v| {
        v["forms"]["attention"]["fusion"] = serde_json::json!("fusion_attention");
        v["backend_forms"]["tract"] = serde_json::json!("sideways");
    });
    let e = load_err(&dir);
    assert!(
        e.contains("backend_forms.tract") && e.contains("sideways"),
        "{e}"
    );
}

#[test]
fn one_changed_byte_in_a_graph_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    let p = dir.join("fusion.onnx");
    let mut bytes = std::fs::read(&p).unwrap();
    let i = bytes.len() / 2;
    bytes[i] ^= 0x01;
    std::fs::write(&p, bytes).unwrap();
    let e = load_err(&dir);
    assert!(
        e.contains("fusion.onnx") && e.contains("sha256") && e.contains("expects"),
        "{e}"
    );
}

#[test]
fn a_missing_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    std::fs::remove_file(dir.join("decoder_hands.onnx")).unwrap();
    let e = load_err(&dir);
    assert!(
        e.contains("decoder_hands.onnx") && e.contains("missing"),
        "{e}"
    );
}

#[test]
fn a_missing_form_fusion_file_is_refused_naming_it() {
    // the attention form's fusion graph (docs/bundle.md#forms-and-precision) is checked like every graph file
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    std::fs::remove_file(dir.join("fusion_attention.onnx")).unwrap();
    let e = load_err(&dir);
    assert!(
        e.contains("fusion_attention.onnx") && e.contains("missing"),
        "{e}"
    );
}

#[test]
fn a_missing_reference_file_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    std::fs::remove_file(dir.join("reference/clip.wav")).unwrap();
    let e = load_err(&dir);
    assert!(e.contains("clip.wav"), "{e}");
}

#[test]
fn schema_version_2_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| v["schema_version"] = 2.into());
    let e = load_err(&dir);
    assert!(
        e.contains("manifest.json")
            && e.contains("schema_version 2")
            && e.contains("reads schema_version 1"),
        "{e}"
    );
}

#[test]
fn no_manifest_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let e = load_err(tmp.path());
    assert!(e.contains("manifest.json not found"), "{e}");
    assert!(matches!(
        Bundle::load(tmp.path()),
        Err(BundleError::NoManifest { .. })
    ));
}

#[test]
fn graph_io_is_checked_against_the_onnx_file() {
    // a renamed input
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| {
        let g = v["graphs"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .find(|g| g["name"] == "expert_face")
            .unwrap();
        g["inputs"][0]["name"] = "previous_token".into();
    });
    let e = load_err(&dir);
    assert!(
        e.contains("expert_face.onnx") && e.contains("previous_token"),
        "{e}"
    );

    // a wrong dtype
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| {
        let g = v["graphs"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .find(|g| g["name"] == "decoder_lower")
            .unwrap();
        g["inputs"][0]["dtype"] = "float32".into();
    });
    let e = load_err(&dir);
    assert!(
        e.contains("decoder_lower.onnx") && e.contains("int64"),
        "{e}"
    );

    // a wrong rank of a cache
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| {
        let g = v["graphs"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .find(|g| g["name"] == "audio_encoder")
            .unwrap();
        g["caches"][0]["shape"]
            .as_array_mut()
            .unwrap()
            .push(1.into());
    });
    let e = load_err(&dir);
    assert!(
        e.contains("audio_encoder.onnx") && e.contains("rank"),
        "{e}"
    );
}

#[test]
fn an_unlisted_graph_is_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    edit_manifest(&dir, |v| {
        v["files"].as_object_mut().unwrap().remove("fusion.onnx");
    });
    let e = load_err(&dir);
    assert!(e.contains("fusion.onnx") && e.contains("not listed"), "{e}");
}
