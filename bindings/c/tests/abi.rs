//! The C entry points, called as C calls them: a chunked push loop gives the frames of the whole-file
//! path (`lg_stream_generate_wav`, which is `livegesture generate`'s) bit for bit, for both families;
//! bad input returns a status and a message, never a crash.

use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr;

use livegesture_c::*;
use livegesture_parity_tests::{diffsheg_tiny_bundle, tiny_bundle};

fn last_error() -> String {
    unsafe { CStr::from_ptr(lg_last_error()) }
        .to_str()
        .unwrap()
        .to_string()
}

fn c(s: &str) -> CString {
    CString::new(s).unwrap()
}

fn ok(st: LgStatus) {
    assert_eq!(st, LgStatus::Ok, "{}", last_error());
}

/// Deterministic speech-like noise, 16-bit.
fn audio(n: usize) -> Vec<i16> {
    let mut x = 0x2545_f491_u32;
    (0..n)
        .map(|i| {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let env = ((i as f32 / 900.0).sin() * 0.5 + 0.5) * 9000.0;
            ((x as f32 / u32::MAX as f32 - 0.5) * 2.0 * env) as i16
        })
        .collect()
}

fn write_wav(path: &Path, pcm: &[i16], rate: u32) {
    let spec = hound::WavSpec {
        channels: 1,
        sample_rate: rate,
        bits_per_sample: 16,
        sample_format: hound::SampleFormat::Int,
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for &s in pcm {
        w.write_sample(s).unwrap();
    }
    w.finalize().unwrap();
}

struct Frames {
    poses: Vec<f32>,
    trans: Vec<f32>,
    expressions: Vec<f32>,
    index: Vec<u64>,
}

/// Reads every waiting frame, in batches of 5.
fn read_all(s: *mut LgStream, into: &mut Frames) {
    loop {
        let mut p = vec![0f32; 5 * LG_POSE_DIM];
        let mut t = vec![0f32; 5 * LG_TRANS_DIM];
        let mut e = vec![0f32; 5 * LG_EXPR_DIM];
        let mut i = vec![0u64; 5];
        let mut n = 0;
        ok(unsafe {
            lg_stream_read(
                s,
                5,
                p.as_mut_ptr(),
                t.as_mut_ptr(),
                e.as_mut_ptr(),
                i.as_mut_ptr(),
                &mut n,
            )
        });
        if n == 0 {
            return;
        }
        into.poses.extend_from_slice(&p[..n * LG_POSE_DIM]);
        into.trans.extend_from_slice(&t[..n * LG_TRANS_DIM]);
        into.expressions.extend_from_slice(&e[..n * LG_EXPR_DIM]);
        into.index.extend_from_slice(&i[..n]);
    }
}

fn empty() -> Frames {
    Frames {
        poses: vec![],
        trans: vec![],
        expressions: vec![],
        index: vec![],
    }
}

fn load(bundle: &Path) -> *mut LgModel {
    let mut m = ptr::null_mut();
    ok(unsafe {
        lg_model_load(
            c(bundle.to_str().unwrap()).as_ptr(),
            c("tract").as_ptr(),
            &mut m,
        )
    });
    assert!(!m.is_null());
    m
}

fn check_push_equals_generate(bundle: PathBuf, ddim_steps: i64) {
    let dir = tempfile_dir();
    let rate = 22050;
    let pcm = audio((rate as f64 * 1.3) as usize);
    let wav = dir.join("a.wav");
    write_wav(&wav, &pcm, rate);
    let model = load(&bundle);
    let mut opts = lg_stream_options_default();
    opts.seed = 5;
    opts.ddim_steps = ddim_steps;
    let mut s = ptr::null_mut();
    ok(unsafe { lg_stream_new(model, &opts, &mut s) });

    let mut whole = empty();
    let mut ready = 0;
    ok(unsafe { lg_stream_generate_wav(s, c(wav.to_str().unwrap()).as_ptr(), &mut ready) });
    assert_eq!(ready, (pcm.len() * 30).div_ceil(rate as usize));
    read_all(s, &mut whole);
    assert_eq!(whole.index, (0..ready as u64).collect::<Vec<_>>());

    // the same audio pushed in chunks: 16-bit and float, then the frames match exactly
    for as_float in [false, true] {
        ok(unsafe { lg_stream_reset(s) });
        let mut pushed = empty();
        for chunk in pcm.chunks(1733) {
            let st = if as_float {
                let f: Vec<f32> = chunk.iter().map(|&x| f32::from(x) / 32768.0).collect();
                unsafe { lg_stream_push(s, f.as_ptr(), f.len(), rate, &mut ready) }
            } else {
                unsafe { lg_stream_push_i16(s, chunk.as_ptr(), chunk.len(), rate, &mut ready) }
            };
            ok(st);
            read_all(s, &mut pushed);
        }
        ok(unsafe { lg_stream_finish(s, &mut ready) });
        read_all(s, &mut pushed);
        assert_eq!(pushed.index, whole.index);
        assert!(pushed.poses == whole.poses, "poses differ");
        assert!(pushed.trans == whole.trans, "trans differ");
        assert!(
            pushed.expressions == whole.expressions,
            "expressions differ"
        );
    }
    // another seed differs (the comparison can fail)
    opts.seed = 6;
    let mut s2 = ptr::null_mut();
    ok(unsafe { lg_stream_new(model, &opts, &mut s2) });
    let mut other = empty();
    ok(unsafe { lg_stream_generate_wav(s2, c(wav.to_str().unwrap()).as_ptr(), &mut ready) });
    read_all(s2, &mut other);
    assert!(other.poses != whole.poses);
    unsafe {
        lg_stream_free(s);
        lg_stream_free(s2);
        lg_model_free(model);
    }
}

fn tempfile_dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!(
        "livegesture-c-abi-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn push_loop_equals_generate_livegesture() {
    check_push_equals_generate(tiny_bundle(), -1);
}

#[test]
fn push_loop_equals_generate_diffsheg() {
    check_push_equals_generate(diffsheg_tiny_bundle(), 5);
}

#[test]
fn bad_input_returns_errors_with_messages() {
    let dir = tempfile_dir();
    let mut m = ptr::null_mut();
    // not a bundle
    let st = unsafe { lg_model_load(c(dir.to_str().unwrap()).as_ptr(), ptr::null(), &mut m) };
    assert_eq!(st, LgStatus::NotFound);
    assert!(m.is_null());
    assert!(
        last_error().contains("manifest.json not found"),
        "{}",
        last_error()
    );
    // unknown backend
    let b = tiny_bundle();
    let st = unsafe { lg_model_load(c(b.to_str().unwrap()).as_ptr(), c("cuda").as_ptr(), &mut m) };
    assert_eq!(st, LgStatus::Input);
    assert!(last_error().contains("unknown backend 'cuda'"));
    // NULL out pointer
    let st = unsafe { lg_model_load(ptr::null(), ptr::null(), ptr::null_mut()) };
    assert_eq!(st, LgStatus::Input);
    assert_eq!(last_error(), "out is NULL");

    let model = load(&b);
    let mut s = ptr::null_mut();
    // an option of the other family
    let mut opts = lg_stream_options_default();
    opts.ddim_steps = 5;
    assert_eq!(
        unsafe { lg_stream_new(model, &opts, &mut s) },
        LgStatus::Input
    );
    // the option named as the field of LgStreamOptions, not as a CLI flag
    assert!(
        last_error().contains("ddim_steps only apply to DiffSHEG") && !last_error().contains("--"),
        "{}",
        last_error()
    );
    opts.ddim_steps = -1;
    opts.guidance = f64::INFINITY;
    assert_eq!(
        unsafe { lg_stream_new(model, &opts, &mut s) },
        LgStatus::Input
    );
    assert!(last_error().contains("guidance must be a finite number"));
    ok(unsafe { lg_stream_new(model, ptr::null(), &mut s) });

    // missing and non-WAV files
    let mut ready = 0;
    let missing = dir.join("missing.wav");
    let st =
        unsafe { lg_stream_generate_wav(s, c(missing.to_str().unwrap()).as_ptr(), &mut ready) };
    assert_eq!(st, LgStatus::NotFound);
    assert!(
        last_error().contains("no such file; expected a WAV file"),
        "{}",
        last_error()
    );
    let text = dir.join("text.wav");
    std::fs::write(&text, "not audio at all").unwrap();
    let st = unsafe { lg_stream_generate_wav(s, c(text.to_str().unwrap()).as_ptr(), &mut ready) };
    assert_eq!(st, LgStatus::Input);
    assert!(last_error().contains("not a WAV file"), "{}", last_error());

    // NaN samples: refused, the stream goes on
    let mut x = vec![0.1f32; 3000];
    x[77] = f32::NAN;
    let st = unsafe { lg_stream_push(s, x.as_ptr(), x.len(), 16000, &mut ready) };
    assert_eq!(st, LgStatus::Input);
    assert!(
        last_error().contains("sample 77 is NaN"),
        "{}",
        last_error()
    );
    x[77] = 0.1;
    ok(unsafe { lg_stream_push(s, x.as_ptr(), x.len(), 16000, &mut ready) });
    // another rate in the same stream
    let st = unsafe { lg_stream_push(s, x.as_ptr(), x.len(), 44100, &mut ready) };
    assert_eq!(st, LgStatus::Input);
    assert!(last_error().contains("differs from the 16000 Hz"));
    // NULL samples with a count, NULL stream
    let st = unsafe { lg_stream_push(s, ptr::null(), 10, 16000, &mut ready) };
    assert_eq!(st, LgStatus::Input);
    assert_eq!(last_error(), "samples is NULL");
    let st = unsafe { lg_stream_push(ptr::null_mut(), x.as_ptr(), 1, 16000, &mut ready) };
    assert_eq!(st, LgStatus::Input);
    assert_eq!(last_error(), "stream is NULL");
    assert_eq!(unsafe { lg_stream_frames_ready(ptr::null()) }, 0);
    // finish twice
    ok(unsafe { lg_stream_finish(s, &mut ready) });
    assert_eq!(ready, (3000usize * 30).div_ceil(16000));
    assert_eq!(unsafe { lg_stream_finish(s, &mut ready) }, LgStatus::Input);
    assert!(last_error().contains("already finished"));
    unsafe {
        lg_stream_free(s);
        lg_model_free(model);
        lg_stream_free(ptr::null_mut());
        lg_model_free(ptr::null_mut());
    }
}

/// Every waiting frame's face, in batches of 5 (`lg_stream_read_face`), and their indices.
fn read_faces(s: *mut LgStream) -> (Vec<LgFace>, Vec<u64>) {
    let (mut faces, mut index) = (vec![], vec![]);
    loop {
        let zero = LgFace {
            arkit: [0.0; LG_ARKIT_DIM],
            visemes: [0.0; LG_VISEME_DIM],
        };
        let mut f = vec![zero; 5];
        let mut i = vec![0u64; 5];
        let mut n = 0;
        ok(unsafe {
            lg_stream_read_face(
                s,
                5,
                ptr::null_mut(),
                ptr::null_mut(),
                ptr::null_mut(),
                i.as_mut_ptr(),
                f.as_mut_ptr(),
                &mut n,
            )
        });
        if n == 0 {
            return (faces, index);
        }
        faces.extend_from_slice(&f[..n]);
        index.extend_from_slice(&i[..n]);
    }
}

#[test]
fn the_face_channel_equals_generate_and_a_bundle_without_says_so() {
    // names
    let name = |p: *const std::ffi::c_char| unsafe { CStr::from_ptr(p) }.to_str().unwrap();
    assert_eq!(name(lg_arkit_name(17)), "jawOpen");
    assert_eq!(name(lg_arkit_name(51)), "tongueOut");
    assert!(lg_arkit_name(52).is_null() && lg_viseme_name(15).is_null());
    assert_eq!(name(lg_viseme_name(0)), "sil");
    assert_eq!(name(lg_viseme_name(10)), "aa");
    assert_eq!(unsafe { lg_model_has_face(ptr::null()) }, 0);

    // models/default carries the face: a push loop's face equals the library's generate (the CLI's)
    let dir = tempfile_dir();
    let rate = 16000;
    let pcm = audio((rate as f64 * 1.3) as usize);
    let wav = dir.join("face.wav");
    write_wav(&wav, &pcm, rate);
    let bundle = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default");
    let model = load(&bundle);
    assert_eq!(unsafe { lg_model_has_face(model) }, 1);
    let mut opts = lg_stream_options_default();
    opts.seed = 9;
    let mut s = ptr::null_mut();
    ok(unsafe { lg_stream_new(model, &opts, &mut s) });
    let mut ready = 0;
    for chunk in pcm.chunks(2011) {
        ok(unsafe { lg_stream_push_i16(s, chunk.as_ptr(), chunk.len(), rate, &mut ready) });
    }
    ok(unsafe { lg_stream_finish(s, &mut ready) });
    let (faces, index) = read_faces(s);
    assert_eq!(faces.len(), (pcm.len() * 30).div_ceil(rate as usize));
    assert_eq!(index, (0..faces.len() as u64).collect::<Vec<_>>());
    let lib_model = livegesture::generate::open_model(
        Some(&bundle),
        &livegesture::backend::BackendOptions {
            kind: livegesture::backend::BackendKind::Tract,
            execution_provider: "cpu".into(),
            intra_threads: 1,
            ort_library: None,
        },
        livegesture::model::GraphForm::Auto,
    )
    .unwrap();
    let whole = livegesture::generate::generate_wav(
        lib_model.as_ref(),
        &livegesture::model::StreamOptions {
            seed: 9,
            ..Default::default()
        },
        &wav,
    )
    .unwrap();
    for (f, w) in faces.iter().zip(&whole.frames) {
        let v = w.face.expect("the library's frame has a face");
        assert!(
            f.arkit == v.arkit && f.visemes == v.visemes,
            "frame {}",
            w.index
        );
        assert!(f.arkit.iter().all(|x| (0.0..=1.0).contains(x)));
        assert!((f.visemes.iter().sum::<f32>() - 1.0).abs() < 1e-5);
    }
    // the comparison can fail: another seed blinks elsewhere, so some frame's face differs
    opts.seed = 10;
    let mut s2 = ptr::null_mut();
    ok(unsafe { lg_stream_new(model, &opts, &mut s2) });
    ok(unsafe { lg_stream_generate_wav(s2, c(wav.to_str().unwrap()).as_ptr(), &mut ready) });
    let (other, _) = read_faces(s2);
    assert!(other != faces);

    // a bundle without a face graph: has_face 0, and a face buffer is refused without moving frames
    let tiny = load(&tiny_bundle());
    assert_eq!(unsafe { lg_model_has_face(tiny) }, 0);
    let mut t = ptr::null_mut();
    ok(unsafe { lg_stream_new(tiny, ptr::null(), &mut t) });
    ok(unsafe { lg_stream_generate_wav(t, c(wav.to_str().unwrap()).as_ptr(), &mut ready) });
    let mut one = [LgFace {
        arkit: [0.0; LG_ARKIT_DIM],
        visemes: [0.0; LG_VISEME_DIM],
    }];
    let mut n = 7;
    let st = unsafe {
        lg_stream_read_face(
            t,
            1,
            ptr::null_mut(),
            ptr::null_mut(),
            ptr::null_mut(),
            ptr::null_mut(),
            one.as_mut_ptr(),
            &mut n,
        )
    };
    assert_eq!(st, LgStatus::Input);
    assert!(last_error().contains("no face channel"), "{}", last_error());
    assert_eq!(n, 0);
    assert_eq!(unsafe { lg_stream_frames_ready(t) }, ready);
    unsafe {
        lg_stream_free(s);
        lg_stream_free(s2);
        lg_stream_free(t);
        lg_model_free(model);
        lg_model_free(tiny);
    }
}
