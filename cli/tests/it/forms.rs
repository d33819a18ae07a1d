//! Graph forms (docs/bundle.md#forms-and-precision): the tiny test bundle carries the canonical region eXperts and SVQ decoders
//! (one graph per region), the fused form (`experts_fused`, the four eXperts on a region axis;
//! `decoders_fused`, the four decoders side by side) and the attention form (the canonical eXperts
//! and decoders, the fusion as `fusion_attention` with the ONNX `Attention` op). The forms give
//! identical tokens and frames on both backends, alone and stepped together (`step_many`); a bundle whose
//! fused or attention graph has one perturbed weight fails parity, naming that graph; a bundle
//! exported before `decoders_fused` runs its fused form with the canonical decoders, one exported
//! before the attention form runs the canonical fusion; `--form` chooses the form.

use livegesture_parity_tests as common;

use std::path::Path;
use std::process::{Command, Output};

use livegesture::audio::read_wav_16k_mono;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{
    LiveGestureGraphs, LiveGestureModel, StreamOptions, TokenStep,
};
use livegesture::model::{GraphForm, MotionModel, StreamJob};
use livegesture_parity::{batch_bound, Check};

fn pipeline(bundle: &Bundle, kind: BackendKind, form: GraphForm) -> LiveGestureGraphs {
    if kind == BackendKind::Ort {
        common::require_ort();
    }
    let be = backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })
    .expect("backend");
    LiveGestureGraphs::with_form(bundle, be.as_ref(), form).expect("pipeline")
}

/// `seconds` of the reference clip (repeated).
fn audio(bundle: &Bundle, seconds: f64) -> Vec<f32> {
    let clip = read_wav_16k_mono(bundle.path("reference/clip.wav")).expect("reference clip");
    clip.iter()
        .cycle()
        .take((seconds * 16000.0) as usize)
        .copied()
        .collect()
}

fn run(p: &mut LiveGestureGraphs, opts: &StreamOptions, audio: &[f32]) -> Vec<TokenStep> {
    let mut s = p.new_stream(opts).expect("stream");
    let mut out = Vec::new();
    for c in audio.chunks(16000) {
        out.extend(p.push_steps(&mut s, c).expect("push"));
    }
    out
}

/// Identical tokens; frames within `bound` (scaled, `livegesture::compare`; 0: bit-identical), `b`
/// the reference side.
fn assert_same(a: &[TokenStep], b: &[TokenStep], bound: f64, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: step counts differ");
    for (x, y) in a.iter().zip(b) {
        assert_eq!(
            x.tokens, y.tokens,
            "{what}: tokens differ at step {}",
            x.token_index
        );
    }
    let fa: Vec<_> = a.iter().flat_map(|s| s.frames.clone()).collect();
    let fb: Vec<_> = b.iter().flat_map(|s| s.frames.clone()).collect();
    common::assert_frames_within(&fa, &fb, bound, what);
}

#[test]
fn the_tiny_bundle_carries_every_form() {
    let bundle = Bundle::load(common::tiny_bundle()).expect("bundle");
    let lg = bundle.livegesture().unwrap();
    let forms = lg.form_graphs();
    assert_eq!(forms["fused"].experts, vec!["experts_fused".to_string()]);
    assert_eq!(forms["fused"].decoders, vec!["decoders_fused".to_string()]);
    assert_eq!(forms["fused"].fusion, "fusion");
    assert_eq!(forms["canonical"].fusion, "fusion");
    assert_eq!(forms["attention"].fusion, "fusion_attention");
    assert_eq!(forms["attention"].experts, forms["canonical"].experts);
    assert_eq!(forms["attention"].decoders, forms["canonical"].decoders);
    assert_eq!(forms["canonical"].experts.len(), lg.regions.len());
    assert_eq!(
        forms["canonical"].decoders,
        lg.region_names()
            .iter()
            .map(|r| format!("decoder_{r}"))
            .collect::<Vec<_>>()
    );
    let be = backend::create(&BackendOptions::default()).unwrap();
    for (choice, name) in [
        (GraphForm::Canonical, "canonical"),
        (GraphForm::Fused, "fused"),
        (GraphForm::Attention, "attention"),
        (GraphForm::Auto, lg.default_form("tract")),
    ] {
        let p = LiveGestureGraphs::with_form(&bundle, be.as_ref(), choice).unwrap();
        assert_eq!(p.form(), name);
    }
}

fn forms_agree(kind: BackendKind) {
    let bundle = Bundle::load(common::tiny_bundle()).expect("bundle");
    let audio = audio(&bundle, 20.0);
    let mut canonical = pipeline(&bundle, kind, GraphForm::Canonical);
    let mut fused = pipeline(&bundle, kind, GraphForm::Fused);
    let mut attention = pipeline(&bundle, kind, GraphForm::Attention);
    for opts in [
        StreamOptions {
            seed: 7,
            ..Default::default()
        },
        StreamOptions {
            seed: 8,
            guidance: Some(1.0),
            ..Default::default()
        },
    ] {
        let a = run(&mut canonical, &opts, &audio);
        let b = run(&mut fused, &opts, &audio);
        assert!(a.len() >= 140, "{} steps", a.len());
        // one stream: the same tokens through the same decoders at the same batch size: bit-identical
        assert_same(
            &b,
            &a,
            0.0,
            &format!("{kind} fused vs canonical, seed {}", opts.seed),
        );
        // the attention form's fusion rounds differently (~1e-7 on the logits) but samples the same
        // tokens, which the same decoders turn into the same frames
        let c = run(&mut attention, &opts, &audio);
        assert_same(
            &c,
            &a,
            0.0,
            &format!("{kind} attention vs canonical, seed {}", opts.seed),
        );
    }
    // several streams stepped together in the fused form (the model's step_many, caches stacked in
    // its cohort) = each alone in the canonical form
    let fused = LiveGestureModel::from(fused);
    let opts: Vec<StreamOptions> = (0..3)
        .map(|i| StreamOptions {
            seed: 20 + i,
            guidance: (i == 1).then_some(1.0),
            ..Default::default()
        })
        .collect();
    let mut together: Vec<_> = opts.iter().map(|o| fused.new_stream(o).unwrap()).collect();
    let mut alone: Vec<_> = opts
        .iter()
        .map(|o| canonical.new_stream(o).unwrap())
        .collect();
    let (mut got, mut want) = (vec![Vec::new(); 3], vec![Vec::new(); 3]);
    for c in audio[..16000 * 6].chunks(3200) {
        let mut jobs: Vec<StreamJob<'_>> = together
            .iter_mut()
            .map(|s| StreamJob::push(s.as_mut(), c))
            .collect();
        for (i, r) in fused.step_many_steps(&mut jobs).into_iter().enumerate() {
            got[i].extend(r.unwrap());
            want[i].extend(canonical.push_steps(&mut alone[i], c).unwrap());
        }
    }
    for (i, (g, w)) in got.iter().zip(&want).enumerate() {
        assert!(g.len() >= 40, "stream {i}: {} steps", g.len());
        // decoders at batch 3 vs 1: the batch check's bound (tract plans per batch size)
        assert_same(
            g,
            w,
            batch_bound(kind),
            &format!("{kind} fused step_many vs canonical alone, stream {i}"),
        );
    }
}

/// The forms' comparison fails when a NaN is on either side (bound 0 included), and passes on the
/// clean pair.
#[test]
fn the_form_comparison_fails_on_nan_either_side() {
    let bundle = Bundle::load(common::tiny_bundle()).expect("bundle");
    let audio = audio(&bundle, 1.0);
    let mut p = pipeline(&bundle, BackendKind::Tract, GraphForm::Canonical);
    let opts = StreamOptions {
        seed: 7,
        ..Default::default()
    };
    let a = run(&mut p, &opts, &audio);
    assert!(a.len() >= 3);
    assert_same(&a, &a, 0.0, "clean");
    let mut bad = a.clone();
    bad[2].frames[1].expressions[5] = f32::NAN;
    for bound in [0.0, 1e-4] {
        common::assert_check_fails("forms, NaN in got", "non-finite", || {
            assert_same(&bad, &a, bound, "probe")
        });
        common::assert_check_fails("forms, NaN in the reference", "non-finite", || {
            assert_same(&a, &bad, bound, "probe")
        });
    }
}

#[test]
fn fused_and_canonical_forms_agree_on_tract() {
    forms_agree(BackendKind::Tract);
}

#[test]
fn fused_and_canonical_forms_agree_on_ort() {
    forms_agree(BackendKind::Ort);
}

#[test]
fn parity_fails_on_a_perturbed_fused_weight_naming_the_fused_graph() {
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken");
    common::break_bundle(
        &common::tiny_bundle(),
        &broken,
        "experts_fused",
        &common::Breakage::PerturbWeight { delta: 0.05 },
    );
    let report = common::run_parity(&broken, &[Check::Graph]);
    let failed: Vec<_> = report.rows.iter().filter(|r| !r.pass).collect();
    assert!(
        !failed.is_empty(),
        "parity passed on a perturbed fused graph"
    );
    assert!(
        failed
            .iter()
            .all(|r| r.what == "experts_fused" && r.comparison.contains("vs torch")),
        "only the fused graph vs torch fails: {failed:#?}"
    );
    // the forms disagree on the rollout too, on a backend that runs the fused form
    let report = common::run_parity(&broken, &[Check::Rollout]);
    let row = report
        .rows
        .iter()
        .find(|r| r.what == "rollout (fused form)" && r.output == "tokens")
        .expect("the rollout compares the fused form with the canonical one");
    assert!(
        !row.pass,
        "the forms agree with a perturbed fused graph: {row:?}"
    );
}

#[test]
fn parity_fails_on_a_perturbed_fused_decoder_weight_naming_the_fused_decoders() {
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken");
    common::break_bundle(
        &common::tiny_bundle(),
        &broken,
        "decoders_fused",
        &common::Breakage::PerturbWeight { delta: 0.05 },
    );
    let report = common::run_parity(&broken, &[Check::Graph]);
    let failed: Vec<_> = report.rows.iter().filter(|r| !r.pass).collect();
    assert!(
        !failed.is_empty(),
        "parity passed on a perturbed fused decoder graph"
    );
    assert!(
        failed
            .iter()
            .all(|r| r.what == "decoders_fused" && r.comparison.contains("vs torch")),
        "only the fused decoders vs torch fail: {failed:#?}"
    );
    assert!(
        failed.iter().any(|r| r.output.contains("motion")),
        "the perturbed decoders' motion is named: {failed:#?}"
    );
    // on the rollout the forms sample the same tokens (the decoders do not feed back) but their
    // frames differ, on a backend that runs the fused form
    let report = common::run_parity(&broken, &[Check::Rollout]);
    let rows: Vec<_> = report
        .rows
        .iter()
        .filter(|r| r.what == "rollout (fused form)")
        .collect();
    let tokens = rows
        .iter()
        .find(|r| r.output == "tokens")
        .expect("the rollout compares the fused form with the canonical one");
    assert!(tokens.pass, "{tokens:?}");
    assert!(
        rows.iter().any(|r| !r.pass && r.output != "tokens"),
        "the forms' frames agree with a perturbed fused decoder graph: {rows:#?}"
    );
}

#[test]
fn parity_fails_on_a_perturbed_attention_fusion_weight_naming_the_graph() {
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken");
    common::break_bundle(
        &common::tiny_bundle(),
        &broken,
        "fusion_attention",
        &common::Breakage::PerturbWeight { delta: 0.05 },
    );
    let report = common::run_parity(&broken, &[Check::Graph]);
    let failed: Vec<_> = report.rows.iter().filter(|r| !r.pass).collect();
    assert!(
        !failed.is_empty(),
        "parity passed on a perturbed fusion_attention graph"
    );
    assert!(
        failed
            .iter()
            .all(|r| r.what == "fusion_attention" && r.comparison.contains("vs torch")),
        "only fusion_attention vs torch fails: {failed:#?}"
    );
    // the forms disagree on the rollout too, on the backend made to run the attention form
    let opts = livegesture_parity::ParityOptions {
        backends: vec![BackendKind::Tract],
        checks: vec![Check::Rollout],
        form: GraphForm::Attention,
        ..Default::default()
    };
    let report = livegesture_parity::run(&broken, &opts, &mut |m: &str| eprintln!("parity: {m}"))
        .expect("parity runs");
    let row = report
        .rows
        .iter()
        .find(|r| r.what == "rollout (attention form)" && r.output == "tokens")
        .expect("the rollout compares the attention form with the canonical one");
    assert!(
        !row.pass,
        "the forms agree with a perturbed fusion_attention: {row:?}"
    );
}

/// Removes graph `name` from a copied bundle and its manifest `m`: its graph file and reference vectors
/// (and their `files` entries), its `graphs`, `reference.graphs` and `checks` entries.
fn remove_graph(bundle: &Path, m: &mut serde_json::Value, name: &str) {
    let graph = m["graphs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|g| g["name"] == name)
        .cloned()
        .unwrap_or_else(|| panic!("the tiny bundle has {name}"));
    m["graphs"]
        .as_array_mut()
        .unwrap()
        .retain(|g| g["name"] != name);
    for key in ["file", "reference"] {
        let rel = graph[key].as_str().unwrap();
        std::fs::remove_file(bundle.join(rel)).unwrap();
        m["files"].as_object_mut().unwrap().remove(rel);
    }
    m["reference"]["graphs"]
        .as_object_mut()
        .unwrap()
        .remove(name);
    m["checks"].as_object_mut().unwrap().remove(name);
}

/// A copy of the tiny bundle as exported before the attention form: no `forms.attention`, no
/// `fusion_attention` (graph, reference vectors, manifest entries), no `fusion` key in any form.
fn bundle_without_attention_form(dir: &Path) -> std::path::PathBuf {
    let bundle = common::copy_bundle(dir);
    let path = bundle.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    remove_graph(&bundle, &mut m, "fusion_attention");
    m["checks"]
        .as_object_mut()
        .unwrap()
        .remove("forms_attention");
    let forms = m["forms"].as_object_mut().unwrap();
    forms.remove("attention");
    for f in forms.values_mut() {
        assert!(f.as_object_mut().unwrap().remove("fusion").is_none());
    }
    for b in ["ort", "tract"] {
        if m["backend_forms"][b] == "attention" {
            m["backend_forms"][b] = serde_json::json!("canonical");
        }
    }
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    bundle
}

#[test]
fn a_bundle_without_the_attention_form_runs_the_canonical_fusion() {
    let dir = tempfile::tempdir().unwrap();
    let old = bundle_without_attention_form(dir.path());
    let b = Bundle::load(&old).expect("a bundle without fusion_attention loads");
    let forms = b.livegesture().unwrap().form_graphs();
    assert!(!forms.contains_key("attention"));
    for f in forms.values() {
        assert_eq!(f.fusion, "fusion");
    }
    let full = Bundle::load(common::tiny_bundle()).unwrap();
    let audio = audio(&full, 6.0);
    let opts = StreamOptions {
        seed: 5,
        ..Default::default()
    };
    for kind in [BackendKind::Ort, BackendKind::Tract] {
        let mut p = pipeline(&b, kind, GraphForm::Auto);
        let got = run(&mut p, &opts, &audio);
        let want = run(
            &mut pipeline(&full, kind, GraphForm::Canonical),
            &opts,
            &audio,
        );
        assert_same(
            &got,
            &want,
            0.0,
            &format!("{kind}: without the attention form"),
        );
        let be = backend::create(&BackendOptions {
            kind,
            ..Default::default()
        })
        .unwrap();
        let e = LiveGestureGraphs::with_form(&b, be.as_ref(), GraphForm::Attention)
            .expect_err("the attention form is refused");
        let e = format!("{e:#}");
        assert!(e.contains("no 'attention' form"), "{e}");
    }
}

/// A copy of the tiny bundle as exported before the fused decoders: its fused form lists the fused
/// eXperts only, and `decoders_fused` (graph, reference vectors, manifest entries) is gone.
fn bundle_without_fused_decoders(dir: &Path) -> std::path::PathBuf {
    let bundle = common::copy_bundle(dir);
    let path = bundle.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    remove_graph(&bundle, &mut m, "decoders_fused");
    for form in ["canonical", "fused"] {
        m["forms"][form].as_object_mut().unwrap().remove("decoders");
    }
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    bundle
}

#[test]
fn a_bundle_without_fused_decoders_runs_its_fused_form_with_the_canonical_decoders() {
    let dir = tempfile::tempdir().unwrap();
    let old = bundle_without_fused_decoders(dir.path());
    let b = Bundle::load(&old).expect("a bundle without decoders_fused loads");
    let lg = b.livegesture().unwrap();
    let forms = lg.form_graphs();
    assert_eq!(forms["fused"].experts, vec!["experts_fused".to_string()]);
    assert_eq!(forms["fused"].decoders, forms["canonical"].decoders);
    let full = Bundle::load(common::tiny_bundle()).unwrap();
    let audio = audio(&full, 8.0);
    let opts = StreamOptions {
        seed: 3,
        ..Default::default()
    };
    for kind in [BackendKind::Ort, BackendKind::Tract] {
        let mut p = pipeline(&b, kind, GraphForm::Fused);
        assert_eq!(p.form(), "fused");
        let got = run(&mut p, &opts, &audio);
        let want = run(&mut pipeline(&full, kind, GraphForm::Fused), &opts, &audio);
        // the canonical decoders and decoders_fused are bit-identical on both backends at one stream
        assert_same(&got, &want, 0.0, &format!("{kind}: without decoders_fused"));
    }
    // the parity suite passes on it, the fused form's rollout against the canonical one included
    let report = common::run_parity(&old, &[Check::Graph, Check::Rollout]);
    assert!(report.passed(), "{}", report.table(true));
    assert!(report
        .rows
        .iter()
        .any(|r| r.what == "rollout (fused form)" && r.output == "tokens"));
}

/// tract's `auto` runs the bundle's fused decoders (`decoders_fused`) with its attention form, a
/// named form its own decoders, and a bundle without `decoders_fused` the per-region ones; ort's
/// `auto` (the fused form) runs the fused decoders anyway. One stream's tokens and frames are those
/// of the attention form with its own decoders, bit for bit.
#[test]
fn tract_auto_runs_the_fused_decoders_when_the_bundle_has_them() {
    let full = Bundle::load(common::tiny_bundle()).unwrap();
    let lg = full.livegesture().unwrap();
    assert_eq!(lg.default_form("tract"), "attention");
    let per_region: Vec<String> = lg
        .region_names()
        .iter()
        .map(|r| format!("decoder_{r}"))
        .collect();
    assert_eq!(lg.default_decoders("tract"), vec!["decoders_fused"]);
    assert_eq!(lg.default_decoders("ort"), vec!["decoders_fused"]);
    let mut auto = pipeline(&full, BackendKind::Tract, GraphForm::Auto);
    assert_eq!(auto.form(), "attention");
    assert_eq!(auto.decoder_graphs(), vec!["decoders_fused"]);
    let mut named = pipeline(&full, BackendKind::Tract, GraphForm::Attention);
    assert_eq!(named.decoder_graphs(), per_region);
    let audio = audio(&full, 8.0);
    for opts in [
        StreamOptions {
            seed: 4,
            ..Default::default()
        },
        StreamOptions {
            seed: 5,
            guidance: Some(1.0),
            ..Default::default()
        },
    ] {
        let got = run(&mut auto, &opts, &audio);
        let want = run(&mut named, &opts, &audio);
        assert!(got.len() >= 50, "{} steps", got.len());
        assert_same(
            &got,
            &want,
            0.0,
            &format!(
                "tract auto (decoders_fused) vs attention, seed {}",
                opts.seed
            ),
        );
    }
    // a bundle exported before decoders_fused: tract's auto runs the per-region decoders
    let dir = tempfile::tempdir().unwrap();
    let old = Bundle::load(bundle_without_fused_decoders(dir.path())).unwrap();
    assert_eq!(
        old.livegesture().unwrap().default_decoders("tract"),
        per_region
    );
    let p = pipeline(&old, BackendKind::Tract, GraphForm::Auto);
    assert_eq!(p.decoder_graphs(), per_region);
}

/// Runs `livegesture generate` on `bundle`'s reference clip into `out` with `args` (and
/// `LIVEGESTURE_FORM` set to `form_env`, else unset).
fn generate(bundle: &Path, args: &[&str], form_env: Option<&str>, out: &Path) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_livegesture"));
    c.env_remove("LIVEGESTURE_FORM");
    if let Some(f) = form_env {
        c.env("LIVEGESTURE_FORM", f);
    }
    c.arg("generate")
        .args(args)
        .arg("--bundle")
        .arg(bundle)
        .arg(bundle.join("reference/clip.wav"))
        .arg("-o")
        .arg(out)
        .output()
        .unwrap()
}

/// `livegesture info` on `bundle` with `args` before the subcommand and `LIVEGESTURE_FORM` as given.
fn info(bundle: &Path, args: &[&str], form_env: Option<&str>) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_livegesture"));
    c.env_remove("LIVEGESTURE_FORM");
    if let Some(f) = form_env {
        c.env("LIVEGESTURE_FORM", f);
    }
    c.args(args)
        .args(["info", "--bundle"])
        .arg(bundle)
        .output()
        .unwrap()
}

fn assert_ok(o: &Output) {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn cli_form_flag_chooses_the_form_and_rejects_unknown_ones() {
    let bundle = common::tiny_bundle();
    let out = info(&bundle, &[], None);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("experts_fused"), "{text}");
    // an unknown form is a usage error, from the flag or from the variable (read by the CLI only)
    for (args, env) in [
        (&["--form", "sideways"][..], None),
        (&[][..], Some("sideways")),
    ] {
        let out = info(&bundle, args, env);
        assert_eq!(out.status.code(), Some(2));
        assert!(String::from_utf8_lossy(&out.stderr).contains("unknown form 'sideways'"));
    }
    // every form, and the form from the flag or the variable, write the same motion
    let dir = tempfile::tempdir().unwrap();
    let runs: [(&[&str], Option<&str>); 4] = [
        (&["--form", "canonical", "--backend", "tract"], None),
        (&["--form", "fused", "--backend", "tract"], None),
        (&["--backend", "tract"], Some("fused")),
        (&["--form", "attention", "--backend", "tract"], None),
    ];
    let mut npz = Vec::new();
    for (i, (args, env)) in runs.iter().enumerate() {
        let o = dir.path().join(format!("{i}.npz"));
        assert_ok(&generate(&bundle, args, *env, &o));
        npz.push(std::fs::read(&o).unwrap());
    }
    assert!(
        npz[0] == npz[1] && npz[1] == npz[2] && npz[2] == npz[3],
        "generate wrote different motion with --form canonical, --form fused, LIVEGESTURE_FORM=fused and --form attention"
    );
}

#[test]
fn asking_for_a_form_the_bundle_lacks_is_bad_input_and_writes_nothing() {
    // a bundle exported with the canonical form only (no `forms` / `backend_forms` in its manifest)
    let dir = tempfile::tempdir().unwrap();
    let bundle = common::copy_bundle(dir.path());
    let path = bundle.join("manifest.json");
    let mut m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let obj = m.as_object_mut().unwrap();
    assert!(
        obj.remove("forms").is_some(),
        "the tiny bundle lists no forms"
    );
    obj.remove("backend_forms");
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    let o = dir.path().join("out.npz");
    let out = generate(&bundle, &["--form", "fused"], None, &o);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("manifest.json") && err.contains("no 'fused' form"),
        "{err}"
    );
    assert!(!o.exists(), "a refused run left {}", o.display());
    // the canonical form still runs from that bundle
    assert_ok(&generate(&bundle, &["--backend", "tract"], None, &o));
}

#[test]
fn form_is_refused_for_diffsheg_bundles() {
    // a DiffSHEG bundle has one form: asking for one is bad input, and nothing is written
    let ds = common::diffsheg_tiny_bundle();
    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().join("ds.npz");
    let out = generate(&ds, &["--form", "canonical"], None, &o);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--form canonical") && err.contains("diffsheg"),
        "{err}"
    );
    assert!(!o.exists());
}
