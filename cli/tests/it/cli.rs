//! The `livegesture` binary end to end: generate (both backends), stream, info, bad input, bad bundles.

use livegesture_parity_tests as common;

use crate::support::{livegesture, run};

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};

use livegesture::audio::AudioSpan;
use livegesture::frontend::FrontendConfig;
use livegesture::output::{read_beat2_npz, BinaryFrameReader, Frame};

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The first `seconds` of the bundle's reference clip as a 16 kHz mono 16-bit WAV.
fn short_wav(dir: &Path, seconds: f64) -> (PathBuf, Vec<i16>) {
    let mut r = hound::WavReader::open(common::tiny_bundle().join("reference/clip.wav")).unwrap();
    let n = (seconds * 16000.0) as usize;
    let samples: Vec<i16> = r.samples::<i16>().take(n).map(|s| s.unwrap()).collect();
    let p = dir.join("short.wav");
    write_wav(&p, &samples);
    (p, samples)
}

fn write_wav(p: &Path, samples: &[i16]) {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: 16000,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(p, spec).unwrap();
    for &s in samples {
        w.write_sample(s).unwrap();
    }
    w.finalize().unwrap();
}

/// A WAV file with an arbitrary header (for unsupported encodings) and raw data bytes.
fn raw_wav(p: &Path, format_tag: u16, channels: u16, rate: u32, bits: u16, data: &[u8]) {
    let block = channels * bits.div_ceil(8);
    let mut v = Vec::new();
    v.extend_from_slice(b"RIFF");
    v.extend_from_slice(&(36 + data.len() as u32).to_le_bytes());
    v.extend_from_slice(b"WAVEfmt ");
    v.extend_from_slice(&16u32.to_le_bytes());
    v.extend_from_slice(&format_tag.to_le_bytes());
    v.extend_from_slice(&channels.to_le_bytes());
    v.extend_from_slice(&rate.to_le_bytes());
    v.extend_from_slice(&(rate * block as u32).to_le_bytes());
    v.extend_from_slice(&block.to_le_bytes());
    v.extend_from_slice(&bits.to_le_bytes());
    v.extend_from_slice(b"data");
    v.extend_from_slice(&(data.len() as u32).to_le_bytes());
    v.extend_from_slice(data);
    std::fs::write(p, v).unwrap();
}

fn bundle_arg() -> String {
    common::tiny_bundle().display().to_string()
}

fn frontend() -> FrontendConfig {
    livegesture::bundle::Bundle::load(common::tiny_bundle())
        .unwrap()
        .frontend()
        .clone()
}

/// Keys, dtypes and shapes of an uncompressed .npz (read from the npy headers).
fn npz_entries(p: &Path) -> Vec<(String, String, String)> {
    let mut z = zip::ZipArchive::new(std::fs::File::open(p).unwrap()).unwrap();
    let mut out = Vec::new();
    for i in 0..z.len() {
        let mut f = z.by_index(i).unwrap();
        let name = f.name().trim_end_matches(".npy").to_string();
        let mut head = vec![0u8; 10];
        f.read_exact(&mut head).unwrap();
        assert_eq!(&head[..6], b"\x93NUMPY");
        let hl = u16::from_le_bytes([head[8], head[9]]) as usize;
        let mut h = vec![0u8; hl];
        f.read_exact(&mut h).unwrap();
        let h = String::from_utf8(h).unwrap();
        let descr = h
            .split("'descr': '")
            .nth(1)
            .unwrap()
            .split('\'')
            .next()
            .unwrap()
            .to_string();
        let shape = h
            .split("'shape': ")
            .nth(1)
            .unwrap()
            .split(')')
            .next()
            .unwrap()
            .to_string()
            + ")";
        out.push((name, descr, shape));
    }
    out.sort();
    out
}

fn generate(wav: &Path, out: &Path, extra: &[&str]) -> Output {
    let b = bundle_arg();
    let mut args = vec![
        "generate",
        wav.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--bundle",
        &b,
    ];
    args.extend_from_slice(extra);
    run(&args)
}

/// Runs `livegesture stream ARGS --bundle <test bundle>` with `pcm` written to its stdin in pieces of
/// `piece` bytes (from a thread: the child's stdout must be drained meanwhile or both block).
fn stream_stdin(args: &[&str], pcm: Vec<u8>, piece: usize) -> Output {
    let mut child = livegesture()
        .arg("stream")
        .args(args)
        .args(["--bundle", &bundle_arg()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        use std::io::Write;
        for c in pcm.chunks(piece.max(1)) {
            stdin.write_all(c).unwrap();
        }
    });
    let o = child.wait_with_output().unwrap();
    writer.join().unwrap();
    o
}

#[test]
fn generate_writes_a_beat2_npz_with_both_backends() {
    common::require_ort();
    let tmp = tempfile::tempdir().unwrap();
    let (wav, samples) = short_wav(tmp.path(), 2.3);
    // docs/output.md: the frames cover the whole audio, ceil(duration x 30)
    let n_frames = AudioSpan::at_16k(samples.len() as u64).frames(30) as usize;
    assert!(n_frames > 4 * frontend().n_tokens(samples.len() as u64) as usize);
    let mut motions = Vec::new();
    for backend in ["tract", "ort"] {
        let out = tmp.path().join(format!("{backend}.npz"));
        let o = generate(&wav, &out, &["--backend", backend, "--seed", "11"]);
        assert!(o.status.success(), "{backend}: {}", stderr(&o));
        assert!(o.stdout.is_empty());
        let entries = npz_entries(&out);
        let want: Vec<(String, String, String)> = [
            ("betas", "<f4", "(300,)".to_string()),
            ("expressions", "<f4", format!("({n_frames}, 100)")),
            ("gender", "<U7", "()".to_string()),
            ("mocap_frame_rate", "<i8", "()".to_string()),
            ("model", "<U9", "()".to_string()),
            ("poses", "<f4", format!("({n_frames}, 165)")),
            ("trans", "<f4", format!("({n_frames}, 3)")),
        ]
        .into_iter()
        .map(|(a, b, c)| (a.to_string(), b.to_string(), c))
        .collect();
        assert_eq!(entries, want, "{backend}: npz layout");
        motions.push(read_beat2_npz(&out).unwrap());
    }
    assert_backends_agree(&motions[0].poses, &motions[1].poses);
    // no temporary files left beside the outputs
    let names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
}

/// generate's poses on tract and on ort agree within 1e-4 (docs/parity.md's rollout frame bound,
/// scaled; ort the reference side).
fn assert_backends_agree(tract: &ndarray::Array2<f32>, ort: &ndarray::Array2<f32>) {
    let d = common::diff2(tract, ort);
    eprintln!(
        "generate: tract vs ort poses over {} frames: {d}",
        tract.nrows()
    );
    if let Err(e) = d.ensure(1e-4, "generate: tract vs ort poses") {
        panic!("{e}");
    }
}

/// The tract-vs-ort comparison of generate's output fails when a NaN is on either side.
#[test]
fn the_backend_comparison_fails_on_nan_either_side() {
    let a = ndarray::Array2::from_shape_fn((6, 165), |(t, j)| ((t * 165 + j) as f32 * 0.01).sin());
    assert_backends_agree(&a, &a);
    let mut bad = a.clone();
    bad[[3, 40]] = f32::NAN;
    common::assert_check_fails("generate, NaN on tract", "non-finite", || {
        assert_backends_agree(&bad, &a)
    });
    common::assert_check_fails("generate, NaN on ort", "non-finite", || {
        assert_backends_agree(&a, &bad)
    });
}

#[test]
fn stream_and_generate_give_the_same_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let (wav, samples) = short_wav(tmp.path(), 2.0);
    let out = tmp.path().join("g.npz");
    let o = generate(&wav, &out, &["--seed", "5", "--guidance", "1.5"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = read_beat2_npz(&out).unwrap();
    let pcm: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
    let stream = |fmt: &str| -> Vec<u8> {
        let args = [
            "--rate",
            "16000",
            "--format",
            "s16le",
            "--output",
            fmt,
            "--seed",
            "5",
            "--guidance",
            "1.5",
        ];
        let o = stream_stdin(&args, pcm.clone(), 777);
        assert!(o.status.success(), "stream --output {fmt}: {}", stderr(&o));
        o.stdout
    };
    let jsonl = stream("jsonl");
    let frames: Vec<Frame> = String::from_utf8(jsonl)
        .unwrap()
        .lines()
        .map(|l| Frame::from_json_line(l).unwrap())
        .collect();
    assert_eq!(frames.len(), m.len());
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.index, i as u64);
        // JSON numbers go through decimal text: compare within the text round trip
        assert!((f.time_s - i as f64 / 30.0).abs() < 1e-12);
        let close = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-6 * (1.0 + y.abs()))
        };
        assert!(
            close(&f.poses, m.poses.row(i).as_slice().unwrap()),
            "frame {i} poses"
        );
        assert!(
            close(&f.trans, m.trans.row(i).as_slice().unwrap()),
            "frame {i} trans"
        );
        assert!(
            close(&f.expressions, m.expressions.row(i).as_slice().unwrap()),
            "frame {i} expressions"
        );
    }
    // binary records are exact
    let binary = stream("binary");
    let bframes: Vec<Frame> = BinaryFrameReader::new(&binary[..])
        .unwrap()
        .map(|f| f.unwrap())
        .collect();
    assert_eq!(bframes.len(), m.len());
    for (i, f) in bframes.iter().enumerate() {
        assert_eq!(f.index, i as u64);
        assert_eq!(f.time_s, i as f64 / 30.0);
        assert_eq!(
            &f.poses[..],
            m.poses.row(i).as_slice().unwrap(),
            "frame {i} poses"
        );
        assert_eq!(
            &f.trans[..],
            m.trans.row(i).as_slice().unwrap(),
            "frame {i} trans"
        );
        assert_eq!(
            &f.expressions[..],
            m.expressions.row(i).as_slice().unwrap(),
            "frame {i} expressions"
        );
    }
}

#[test]
fn stream_resamples_and_mixes_any_input() {
    // 48 kHz stereo f32: runs and emits about the right number of frames
    let (_, samples) = short_wav(tempfile::tempdir().unwrap().path(), 1.5);
    let mut pcm = Vec::new();
    for &s in &samples {
        let x = s as f32 / 32768.0;
        for _ in 0..3 {
            for _ in 0..2 {
                pcm.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    let args = ["--rate", "48000", "--channels", "2", "--format", "f32le"];
    let o = stream_stdin(&args, pcm, usize::MAX);
    assert!(o.status.success(), "{}", stderr(&o));
    let lines = String::from_utf8(o.stdout).unwrap().lines().count();
    // docs/output.md, from the input's own count and rate: ceil(n * 30 / 48000) frames
    let n_in = 3 * samples.len() as u64;
    assert_eq!(lines as u64, (n_in * 30).div_ceil(48000));
}

#[test]
fn info_describes_the_bundle() {
    let o = run(&["info", "--bundle", &bundle_arg()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = String::from_utf8(o.stdout).unwrap();
    for needle in [
        "config 'tiny'",
        "upper",
        "fusion",
        "state",
        "guidance",
        "provenance",
        "random weights",
    ] {
        assert!(s.contains(needle), "info output lacks '{needle}':\n{s}");
    }
    let o = run(&["info", "--json", "--bundle", &bundle_arg()]);
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["state_bytes_per_stream"]["guided"].as_u64().unwrap() > 0);
}

fn assert_bad_input(what: &str, wav: &Path, out: &Path) {
    let o = generate(wav, out, &[]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{what}: exit code, stderr: {err}");
    assert!(
        err.contains(&*wav.file_name().unwrap().to_string_lossy()),
        "{what}: error does not name the file: {err}"
    );
    assert!(!out.exists(), "{what}: an output file was left");
    let leftovers: Vec<_> = std::fs::read_dir(out.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("out.npz"))
        .collect();
    assert!(leftovers.is_empty(), "{what}: left {leftovers:?}");
    eprintln!("{what}: {}", err.trim());
}

#[test]
fn bad_input_is_refused_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let out = d.join("out.npz");

    let p = d.join("empty.wav");
    std::fs::write(&p, b"").unwrap();
    assert_bad_input("empty file", &p, &out);

    let p = d.join("text.wav");
    std::fs::write(&p, b"this is not a wav file at all, just some text\n").unwrap();
    assert_bad_input("non-WAV", &p, &out);

    let (good, _) = short_wav(d, 1.0);
    let bytes = std::fs::read(&good).unwrap();
    let p = d.join("truncated.wav");
    std::fs::write(&p, &bytes[..bytes.len() / 2 + 1]).unwrap();
    assert_bad_input("truncated", &p, &out);

    let p = d.join("header_only.wav");
    std::fs::write(&p, &bytes[..30]).unwrap();
    assert_bad_input("truncated header", &p, &out);

    let p = d.join("f64.wav");
    raw_wav(&p, 3, 1, 16000, 64, &[0u8; 8 * 4000]);
    assert_bad_input("64-bit float", &p, &out);

    let p = d.join("adpcm.wav");
    raw_wav(&p, 2, 1, 16000, 4, &[0u8; 4000]);
    assert_bad_input("ADPCM", &p, &out);

    let p = d.join("nan.wav");
    let mut data = Vec::new();
    for i in 0..8000 {
        let x: f32 = if i == 5000 { f32::NAN } else { 0.1 };
        data.extend_from_slice(&x.to_le_bytes());
    }
    raw_wav(&p, 3, 1, 16000, 32, &data);
    assert_bad_input("NaN sample", &p, &out);

    let p = d.join("inf.wav");
    let mut data = Vec::new();
    for i in 0..8000 {
        let x: f32 = if i == 10 { f32::INFINITY } else { 0.1 };
        data.extend_from_slice(&x.to_le_bytes());
    }
    raw_wav(&p, 3, 1, 16000, 32, &data);
    assert_bad_input("infinite sample", &p, &out);

    let p = d.join("zero_length.wav");
    write_wav(&p, &[]);
    assert_bad_input("zero-length audio", &p, &out);

    let o = generate(&d.join("does_not_exist.wav"), &out, &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("does_not_exist.wav"));
}

#[test]
fn usage_errors_exit_2() {
    assert_eq!(run(&["generate"]).status.code(), Some(2));
    assert_eq!(run(&["frobnicate"]).status.code(), Some(2));
    let tmp = tempfile::tempdir().unwrap();
    let (wav, _) = short_wav(tmp.path(), 1.0);
    let out = tmp.path().join("o.npz");
    for extra in [
        &["--temperature", "0"][..],
        &["--backend", "nope"],
        &["--ep", "cuda"],
    ] {
        let o = generate(&wav, &out, extra);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", stderr(&o));
        assert!(!out.exists());
    }
    let o = generate(&wav, &tmp.path().join("no/such/dir/o.npz"), &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(run(&["--help"]).status.success());
}

#[test]
fn a_corrupted_bundle_is_refused_by_the_cli() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::copy_bundle(tmp.path());
    let p = dir.join("expert_lower.onnx");
    let mut bytes = std::fs::read(&p).unwrap();
    bytes[100] = bytes[100].wrapping_add(1);
    std::fs::write(&p, bytes).unwrap();
    let (wav, _) = short_wav(tmp.path(), 1.0);
    let out = tmp.path().join("o.npz");
    let o = livegesture()
        .args([
            "generate",
            wav.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--bundle",
            dir.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("expert_lower.onnx") && stderr(&o).contains("sha256"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
    // the same bundle through the environment variable, with info
    let o = livegesture()
        .args(["info"])
        .env("LIVEGESTURE_BUNDLE", &dir)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("expert_lower.onnx"));
}

/// docs/output.md through the CLI: audio shorter than one token, and a length one sample past a token
/// boundary, give ceil(duration x 30) frames from `generate` and `stream`, and the same frames.
#[test]
fn generate_and_stream_cover_the_whole_audio() {
    let tmp = tempfile::tempdir().unwrap();
    let f = frontend();
    for n in [1000u64, f.token_end(2) + 1] {
        let samples: Vec<i16> = (0..n).map(|i| ((i * 37) % 2000) as i16 - 1000).collect();
        let wav = tmp.path().join(format!("a{n}.wav"));
        write_wav(&wav, &samples);
        let want = (n * 30).div_ceil(16000);
        let out = tmp.path().join(format!("a{n}.npz"));
        let o = generate(&wav, &out, &["--seed", "3"]);
        assert!(o.status.success(), "{n} samples: {}", stderr(&o));
        let m = read_beat2_npz(&out).unwrap();
        assert_eq!(m.len() as u64, want, "{n} samples: generate frames");
        let pcm: Vec<u8> = samples.iter().flat_map(|s| s.to_le_bytes()).collect();
        let o = stream_stdin(&["--output", "binary", "--seed", "3"], pcm, 4096);
        assert!(o.status.success(), "{n} samples: {}", stderr(&o));
        let frames: Vec<Frame> = BinaryFrameReader::new(&o.stdout[..])
            .unwrap()
            .map(|f| f.unwrap())
            .collect();
        assert_eq!(frames.len() as u64, want, "{n} samples: stream frames");
        for (i, fr) in frames.iter().enumerate() {
            assert_eq!(
                &fr.poses[..],
                m.poses.row(i).as_slice().unwrap(),
                "frame {i}"
            );
        }
    }
}
