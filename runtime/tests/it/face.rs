//! The face channel (docs/face.md) through the runtime, on the shipped bundles: every frame carries 52
//! ARKit weights in [0, 1] and 15 visemes summing to 1; causal (changing audio after a token changes no
//! earlier face); chunk-size invariant; the same through `step_many`; a bundle without a `face` section
//! gives frames without it and a section with wrong names is refused; the npz and glTF writers carry it.

use livegesture::audio::{read_wav_16k_mono, AudioSpan};
use livegesture::backend::{self, BackendOptions};
use livegesture::bundle::{repo_default_bundle, Bundle};
use livegesture::face::{ARKIT_NAMES, VISEME_NAMES};
use livegesture::model::{self, MotionModel, StreamJob, StreamOptions};
use livegesture::output::{gltf_from_frames, Frame, FrameSink, GltfContainer, NpzFrameWriter};

fn load(dir: &std::path::Path) -> (Bundle, Box<dyn MotionModel>) {
    let bundle = Bundle::load(dir).expect("bundle loads");
    let be = backend::create(&BackendOptions::default()).expect("tract");
    let m = model::load(&bundle, be.as_ref()).expect("model");
    (bundle, m)
}

fn clip(bundle: &Bundle, seconds: f32) -> Vec<f32> {
    let a = read_wav_16k_mono(bundle.path("reference/clip.wav")).expect("reference clip");
    a[..(seconds * 16000.0) as usize].to_vec()
}

fn run(m: &dyn MotionModel, a: &[f32], chunk: usize, seed: u64) -> Vec<Frame> {
    let mut s = m
        .new_stream(&StreamOptions {
            seed,
            ..Default::default()
        })
        .unwrap();
    let mut out = Vec::new();
    for c in a.chunks(chunk) {
        out.extend(s.push_audio(c).unwrap());
    }
    out.extend(s.finish(AudioSpan::at_16k(a.len() as u64)).unwrap());
    out
}

fn faces(frames: &[Frame]) -> Vec<f32> {
    frames
        .iter()
        .flat_map(|f| {
            let v = f.face.expect("every frame carries the face");
            v.arkit.into_iter().chain(v.visemes)
        })
        .collect()
}

#[test]
fn every_frame_carries_a_valid_causal_face_in_both_families() {
    for dir in [
        repo_default_bundle(),
        repo_default_bundle().with_file_name("diffsheg"),
    ] {
        let (bundle, m) = load(&dir);
        let a = clip(&bundle, 4.0);
        let frames = run(m.as_ref(), &a, 16000, 3);
        assert_eq!(frames.len(), 120, "{}", dir.display());
        for f in &frames {
            let v = f.face.expect("face");
            assert!(v.arkit.iter().all(|x| (0.0..=1.0).contains(x)));
            let s: f32 = v.visemes.iter().sum();
            assert!((s - 1.0).abs() < 1e-4, "frame {}: visemes sum {s}", f.index);
            f.check_finite().unwrap();
        }
        let jaw: Vec<f32> = frames.iter().map(|f| f.face.unwrap().arkit[17]).collect();
        let spread =
            jaw.iter().cloned().fold(0f32, f32::max) - jaw.iter().cloned().fold(1f32, f32::min);
        assert!(spread > 0.2, "jawOpen follows the speech (range {spread})");
        let blinks = frames
            .iter()
            .filter(|f| f.face.unwrap().arkit[0] > 0.9)
            .count();
        assert!(blinks > 0, "the seeded blinks show in 4 s");
        // chunk-size invariance: 1 ms chunks give the same face
        assert_eq!(faces(&run(m.as_ref(), &a, 16, 3)), faces(&frames));
        // causality: new audio after token 14 (frames 0..60) changes no earlier face, but later ones
        let mut b = a.clone();
        for x in &mut b[32000..] {
            *x = -*x * 0.5;
        }
        let fb = run(m.as_ref(), &b, 16000, 3);
        assert_eq!(faces(&fb[..60]), faces(&frames[..60]), "{}", dir.display());
        assert_ne!(faces(&fb[60..]), faces(&frames[60..]));
        // the seed moves the blinks only
        let other = run(m.as_ref(), &a, 16000, 4);
        let vis = |fr: &[Frame]| -> Vec<f32> {
            fr.iter().flat_map(|f| f.face.unwrap().visemes).collect()
        };
        assert_eq!(vis(&other), vis(&frames));
        // step_many gives each stream the face it gets alone
        let opts = StreamOptions {
            seed: 3,
            ..Default::default()
        };
        let mut s1 = m.new_stream(&opts).unwrap();
        let mut s2 = m.new_stream(&opts).unwrap();
        let half = &a[..a.len() / 2];
        let mut jobs = vec![
            StreamJob::push_and_finish(s1.as_mut(), &a, AudioSpan::at_16k(a.len() as u64)),
            StreamJob::push_and_finish(s2.as_mut(), half, AudioSpan::at_16k(half.len() as u64)),
        ];
        let r = m.step_many(&mut jobs);
        let r1 = r[0].as_ref().unwrap();
        let r2 = r[1].as_ref().unwrap();
        assert_eq!(faces(r1), faces(&frames));
        assert_eq!(faces(r2), faces(&run(m.as_ref(), half, 16000, 3)));
    }
}

fn copy_bundle(edit: impl Fn(&mut serde_json::Value)) -> tempfile::TempDir {
    let src = repo_default_bundle();
    let dir = tempfile::tempdir().unwrap();
    for e in walk(&src) {
        let rel = e.strip_prefix(&src).unwrap();
        let dst = dir.path().join(rel);
        std::fs::create_dir_all(dst.parent().unwrap()).unwrap();
        std::fs::copy(&e, &dst).unwrap();
    }
    let mp = dir.path().join("manifest.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mp).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(&mp, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    dir
}

fn walk(d: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(d).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

#[test]
fn a_bundle_without_a_face_gives_none_and_wrong_names_are_refused() {
    let dir = copy_bundle(|v| {
        v.as_object_mut().unwrap().remove("face");
    });
    let (bundle, m) = load(dir.path());
    let frames = run(m.as_ref(), &clip(&bundle, 1.0), 4000, 0);
    assert!(!frames.is_empty() && frames.iter().all(|f| f.face.is_none()));
    let line = frames[0].to_json_line().unwrap();
    assert!(
        !line.contains("arkit") && !line.contains("visemes"),
        "{line}"
    );

    let dir = copy_bundle(|v| v["face"]["visemes"][10] = "AA".into());
    let e = Bundle::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("face.visemes"), "{e}");
    let dir = copy_bundle(|v| v["face"]["graph"] = "faces".into());
    let e = Bundle::load(dir.path()).unwrap_err().to_string();
    assert!(e.contains("face.graph 'faces'"), "{e}");
}

#[test]
fn writers_carry_the_face() {
    let (bundle, m) = load(&repo_default_bundle());
    let frames = run(m.as_ref(), &clip(&bundle, 2.0), 16000, 1);
    // JSON lines round-trip
    let line = frames[5].to_json_line().unwrap();
    assert!(line.contains("\"arkit\":[") && line.contains("\"visemes\":["));
    assert_eq!(Frame::from_json_line(&line).unwrap(), frames[5]);
    // npz keys
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.npz");
    let mut w = NpzFrameWriter::new(&p);
    for f in &frames {
        w.write_frame(f).unwrap();
    }
    w.finish().unwrap();
    let mut z = ndarray_npy::NpzReader::new(std::fs::File::open(&p).unwrap()).unwrap();
    let names = z.names().unwrap();
    for k in [
        "arkit",
        "arkit_names",
        "visemes",
        "viseme_names",
        "poses",
        "betas",
    ] {
        assert!(names.iter().any(|n| n == k), "{k} in {names:?}");
    }
    let a: ndarray::Array2<f32> = z.by_name("arkit").unwrap();
    assert_eq!(a.dim(), (frames.len(), 52));
    assert_eq!(a.row(7).to_vec(), frames[7].face.unwrap().arkit.to_vec());
    // a stream mixing frames with and without the face is refused
    let mut w = NpzFrameWriter::new(dir.path().join("bad.npz"));
    let mut bare = frames[1].clone();
    bare.face = None;
    w.write_frame(&frames[0]).unwrap();
    w.write_frame(&bare).unwrap();
    let e = w.finish().unwrap_err().to_string();
    assert!(e.contains("1 of 2 frames carry the face"), "{e}");
    assert!(!dir.path().join("bad.npz").exists());
    // glTF: the face node with 52 named morph targets and a weights channel
    let glb = gltf_from_frames(&frames, GltfContainer::Gltf).unwrap();
    let doc: serde_json::Value = serde_json::from_slice(&glb).unwrap();
    let face_mesh = doc["meshes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == "face")
        .expect("face mesh");
    let tn: Vec<&str> = face_mesh["extras"]["targetNames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_str().unwrap())
        .collect();
    assert_eq!(tn, ARKIT_NAMES);
    assert_eq!(
        face_mesh["primitives"][0]["targets"]
            .as_array()
            .unwrap()
            .len(),
        52
    );
    let ch = doc["animations"][0]["channels"].as_array().unwrap();
    assert!(ch.iter().any(|c| c["target"]["path"] == "weights"));
    assert_eq!(VISEME_NAMES.len(), 15);
    // binary records: version 2 (1372 bytes) carries the face; read back equal
    let mut w = livegesture::output::BinaryFrameWriter::new(Vec::new());
    for f in &frames {
        w.write_frame(f).unwrap();
    }
    w.finish().unwrap();
    let bytes = w.into_inner();
    assert_eq!(bytes.len(), 16 + frames.len() * 1372);
    let r = livegesture::output::BinaryFrameReader::new(&bytes[..]).unwrap();
    assert_eq!(r.version(), 2);
    let back: Vec<Frame> = r.map(|f| f.unwrap()).collect();
    assert_eq!(back, frames);
}
