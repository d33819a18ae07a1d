//! The `livegesture` binary on a DiffSHEG bundle: `generate` on both backends writes a valid BEAT2 npz
//! covering the whole audio, bad sampler options are refused, and `parity` fails on a perturbed
//! denoiser weight, naming the graph.
//!
//! The bundle is the fixture's tiny DiffSHEG bundle (`livegesture_parity_tests::diffsheg_tiny_bundle`:
//! `$LIVEGESTURE_DIFFSHEG_TINY_BUNDLE`, set by `scripts/test.sh`, else exported once).

use crate::support::{run, text};

use std::path::{Path, PathBuf};
use std::process::Command;

use livegesture::output::read_beat2_npz;

fn bundle() -> PathBuf {
    livegesture_parity_tests::diffsheg_tiny_bundle()
}

/// A 16 kHz mono 16-bit WAV of `n` samples of the bundle's reference clip.
fn wav(dir: &Path, n: usize) -> PathBuf {
    let mut r = hound::WavReader::open(bundle().join("reference/clip.wav")).unwrap();
    let samples: Vec<i16> = r.samples::<i16>().take(n).map(|s| s.unwrap()).collect();
    assert_eq!(samples.len(), n);
    let p = dir.join(format!("speech-{n}.wav"));
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 16000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(&p, spec).unwrap();
    for s in samples {
        w.write_sample(s).unwrap();
    }
    w.finalize().unwrap();
    p
}

#[test]
fn generate_covers_the_whole_audio() {
    let tmp = tempfile::tempdir().unwrap();
    let b = bundle();
    // 2.3 s + 7 samples: not a whole number of frames, a shorter last window
    let n = 36807;
    let input = wav(tmp.path(), n);
    let want = (n * 30).div_ceil(16000);
    let mut outs = Vec::new();
    for backend in ["tract", "ort"] {
        let out = tmp.path().join(format!("{backend}.npz"));
        let o = run(&[
            "generate",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--bundle",
            b.to_str().unwrap(),
            "--backend",
            backend,
            "--seed",
            "3",
        ]);
        assert!(o.status.success(), "{backend}: {}", text(&o));
        let m = read_beat2_npz(&out).unwrap();
        m.validate().unwrap();
        assert_eq!(m.len(), want, "{backend}: frames = ceil(duration * 30)");
        assert!(m.poses.iter().all(|v| v.is_finite()));
        outs.push(m);
    }
    // both backends sample the same motion (the same noise; graphs within the docs/parity.md bounds):
    // frames within the rollout frame bound, 1e-4 scaled (measured on the tiny bundle: ~1e-5)
    let d = livegesture_parity_tests::diff2(&outs[0].poses, &outs[1].poses);
    eprintln!("generate: tract vs ort poses: {d}");
    if let Err(e) = d.ensure(1e-4, "generate: tract vs ort poses") {
        panic!("{e}");
    }
}

#[test]
fn bad_sampler_options_are_refused_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let b = bundle();
    let input = wav(tmp.path(), 16000);
    let out = tmp.path().join("never.npz");
    for (args, says) in [
        (vec!["--ddim-steps", "7"], "must divide 1000"),
        (vec!["--window", "500"], "window"),
        (vec!["--overlap", "24"], "overlap"),
        (vec!["--jumps", "0"], "jumps"),
        (vec!["--speaker", "99"], "speaker"),
        // the library names the option (`temperature`), the CLI spells it as its flag
        (
            vec!["--temperature", "0.5"],
            "error: --temperature only apply to LiveGesture bundles",
        ),
    ] {
        let mut a = vec![
            "generate",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--bundle",
            b.to_str().unwrap(),
        ];
        a.extend(args.iter().copied());
        let o = run(&a);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        assert!(text(&o).contains(says), "{args:?}: {}", text(&o));
        assert!(!out.exists(), "no output file after an error");
    }
}

#[test]
fn parity_fails_on_a_perturbed_denoiser_weight_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dst = tmp.path().join("broken");
    let py = std::env::var_os("LIVEGESTURE_PY")
        .filter(|v| !v.is_empty())
        .expect("LIVEGESTURE_PY (source scripts/env.sh): breaking a bundle needs onnx");
    let tool =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../parity-tests/tools/break_bundle.py");
    let o = Command::new(py)
        .arg(&tool)
        .arg(bundle())
        .arg(&dst)
        .args(["--graph", "denoiser", "--perturb-weight", "--delta", "0.01"])
        .output()
        .unwrap();
    assert!(o.status.success(), "break_bundle: {}", text(&o));
    let o = run(&[
        "parity",
        "--bundle",
        dst.to_str().unwrap(),
        "--backends",
        "ort,tract",
        "--checks",
        "graph",
    ]);
    let t = text(&o);
    assert!(
        !o.status.success(),
        "parity passed on a broken bundle:\n{t}"
    );
    let fails: Vec<&str> = t.lines().filter(|l| l.starts_with("FAIL ")).collect();
    assert!(!fails.is_empty(), "{t}");
    assert!(fails.iter().all(|l| l.contains("denoiser")), "{t}");
    assert!(fails.iter().any(|l| l.contains("tract vs torch")), "{t}");
    assert!(fails.iter().any(|l| l.contains("ort vs torch")), "{t}");
    // the untouched bundle passes the same check
    let o = run(&[
        "parity",
        "--bundle",
        bundle().to_str().unwrap(),
        "--backends",
        "tract",
        "--checks",
        "graph",
    ]);
    assert!(o.status.success(), "{}", text(&o));
}
