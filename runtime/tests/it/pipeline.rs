//! The streaming pipeline against the bundle's reference rollout (torch), on both backends, and its
//! streaming properties (chunk-size invariance, batched stepping, guidance off).

use livegesture_parity_tests as common;

use livegesture::audio::read_wav_16k_mono;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{LiveGestureGraphs, StreamOptions, TokenStep};
use livegesture::output::Frame;
use livegesture_parity::ReferenceRollout;
use ndarray::Array2;

/// Rollout frames (docs/parity.md, scaled).
const FRAME_BOUND: f64 = 1e-4;

fn pipeline(kind: BackendKind) -> (Bundle, LiveGestureGraphs) {
    if kind == BackendKind::Ort {
        common::require_ort();
    }
    let bundle = Bundle::load(common::tiny_bundle()).expect("test bundle loads");
    let be = backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })
    .expect("backend");
    let p = LiveGestureGraphs::new(&bundle, be.as_ref()).expect("pipeline");
    (bundle, p)
}

fn rollout_audio(bundle: &Bundle, repeats: usize) -> Vec<f32> {
    let clip = read_wav_16k_mono(bundle.path("reference/clip.wav")).expect("reference clip");
    let mut a = Vec::with_capacity(clip.len() * repeats);
    for _ in 0..repeats {
        a.extend_from_slice(&clip);
    }
    a
}

fn frames_to(frames: &[Frame], f: impl Fn(&Frame) -> &[f32]) -> Array2<f32> {
    let d = frames.first().map(|fr| f(fr).len()).unwrap_or(0);
    Array2::from_shape_vec(
        (frames.len(), d),
        frames.iter().flat_map(|fr| f(fr).to_vec()).collect(),
    )
    .unwrap()
}

fn run_all(
    p: &mut LiveGestureGraphs,
    opts: &StreamOptions,
    audio: &[f32],
    chunk: usize,
) -> Vec<TokenStep> {
    let mut s = p.new_stream(opts).unwrap();
    let mut steps = Vec::new();
    for c in audio.chunks(chunk.max(1)) {
        steps.extend(p.push_steps(&mut s, c).unwrap());
    }
    steps
}

fn check_rollout(kind: BackendKind) {
    let (bundle, mut p) = pipeline(kind);
    let (ro, seed) = common::reference_rollout(&bundle);
    let audio = rollout_audio(&bundle, ro.clip_repeats);
    let opts = StreamOptions {
        seed,
        guidance: bundle.reference().and_then(|r| r.rollout_guidance),
        ..Default::default()
    };
    let steps = run_all(&mut p, &opts, &audio, 16000);
    assert_eq!(steps.len(), ro.tokens.len(), "{kind}: token count");
    for (t, s) in steps.iter().enumerate() {
        assert_eq!(s.tokens, ro.tokens[t], "{kind}: tokens differ at step {t}");
    }
    let frames: Vec<Frame> = steps.into_iter().flat_map(|s| s.frames).collect();
    assert_rollout_frames(&kind.to_string(), &frames, &ro);
}

/// The frames equal the reference rollout's within [`FRAME_BOUND`], every field.
fn assert_rollout_frames(what: &str, frames: &[Frame], ro: &ReferenceRollout) {
    for (name, got, want) in [
        ("poses", frames_to(frames, |f| &f.poses), &ro.poses),
        ("trans", frames_to(frames, |f| &f.trans), &ro.trans),
        (
            "expressions",
            frames_to(frames, |f| &f.expressions),
            &ro.expressions,
        ),
        (
            "foot_contact",
            frames_to(frames, |f| &f.foot_contact),
            &ro.foot_contact,
        ),
    ] {
        let d = common::diff2(&got, want);
        eprintln!("{what}: rollout {name}: {d}");
        if let Err(e) = d.ensure(FRAME_BOUND, format!("{what}: {name} vs the torch rollout")) {
            panic!("{e}");
        }
    }
}

/// The reference rollout's frames as [`Frame`]s.
fn frames_of(ro: &ReferenceRollout) -> Vec<Frame> {
    (0..ro.poses.nrows())
        .map(|t| {
            let mut f = Frame {
                index: t as u64,
                time_s: t as f64 / 30.0,
                poses: [0.0; 165],
                trans: [0.0; 3],
                expressions: [0.0; 100],
                foot_contact: [0.0; 4],
                face: None,
            };
            for (dst, src) in [
                (&mut f.poses[..], &ro.poses),
                (&mut f.trans[..], &ro.trans),
                (&mut f.expressions[..], &ro.expressions),
                (&mut f.foot_contact[..], &ro.foot_contact),
            ] {
                for (d, s) in dst.iter_mut().zip(src.row(t)) {
                    *d = *s;
                }
            }
            f
        })
        .collect()
}

/// The rollout comparison fails when a NaN is on either side (the runtime's frames or the torch
/// reference), and passes on the clean pair.
#[test]
fn the_rollout_comparison_fails_on_nan_either_side() {
    let bundle = Bundle::load(common::tiny_bundle()).expect("test bundle loads");
    let (ro, _) = common::reference_rollout(&bundle);
    let frames = frames_of(&ro);
    assert_rollout_frames("clean", &frames, &ro);
    let at = frames.len() / 2;
    let bad = common::with_nan(&frames, at);
    common::assert_check_fails("rollout, NaN in the runtime's frames", "non-finite", || {
        assert_rollout_frames("probe", &bad, &ro)
    });
    let mut bad_ro = ro.clone();
    bad_ro.expressions[[at, 3]] = f32::NAN;
    common::assert_check_fails("rollout, NaN in the torch reference", "non-finite", || {
        assert_rollout_frames("probe", &frames, &bad_ro)
    });
}

#[test]
fn tract_reproduces_reference_rollout() {
    check_rollout(BackendKind::Tract);
}

#[test]
fn ort_reproduces_reference_rollout() {
    check_rollout(BackendKind::Ort);
}

#[test]
fn tract_and_ort_agree() {
    let (bundle, mut pt) = pipeline(BackendKind::Tract);
    let (_, mut po) = pipeline(BackendKind::Ort);
    let audio = rollout_audio(&bundle, 1);
    let opts = StreamOptions {
        seed: 7,
        record_logits: true,
        ..Default::default()
    };
    let a = run_all(&mut pt, &opts, &audio, 3200);
    let b = run_all(&mut po, &opts, &audio, 3200);
    assert_eq!(a.len(), b.len());
    let (mut lt, mut lo) = (Vec::new(), Vec::new());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(
            x.tokens, y.tokens,
            "tokens differ at step {}",
            x.token_index
        );
        let (lx, ly) = (x.logits.as_ref().unwrap(), y.logits.as_ref().unwrap());
        lt.extend_from_slice(&lx.cond);
        lo.extend_from_slice(&ly.cond);
        assert!(lx.uncond.is_some());
    }
    // tract vs ort: docs/parity.md's 1e-4 (scaled), with ort the reference side
    let d = livegesture::compare::assert_within(&lt, &lo, 1e-4, "logits, tract vs ort");
    eprintln!(
        "tract vs ort: {} steps, identical tokens, logits: {d}",
        a.len()
    );
}

#[test]
fn chunk_size_invariance() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let clip = rollout_audio(&bundle, 1);
    let audio = &clip[..clip.len().min(16000 * 2 + 1234)];
    let opts = StreamOptions {
        seed: 3,
        ..Default::default()
    };
    let whole = run_all(&mut p, &opts, audio, audio.len());
    assert_eq!(
        whole.len() as u64,
        bundle.frontend().n_tokens(audio.len() as u64)
    );
    for chunk in [1usize, 160, 3200, 16000] {
        let got = run_all(&mut p, &opts, audio, chunk);
        assert_eq!(got, whole, "chunk size {chunk} gives different output");
    }
}

#[test]
fn batched_steps_equal_single_streams() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let clip = rollout_audio(&bundle, 1);
    let audio = &clip[..16000];
    let opts: Vec<StreamOptions> = vec![
        StreamOptions {
            seed: 1,
            ..Default::default()
        },
        StreamOptions {
            seed: 2,
            guidance: Some(1.0),
            ..Default::default()
        },
        StreamOptions {
            seed: 3,
            guidance: Some(2.0),
            top_k: Some(0),
            ..Default::default()
        },
    ];
    let single: Vec<Vec<TokenStep>> = opts
        .iter()
        .map(|o| run_all(&mut p, o, audio, 4000))
        .collect();
    let mut streams: Vec<_> = opts.iter().map(|o| p.new_stream(o).unwrap()).collect();
    let mut batched: Vec<Vec<TokenStep>> = vec![Vec::new(); opts.len()];
    for c in audio.chunks(4000) {
        let mels: Vec<_> = streams
            .iter_mut()
            .map(|s| s.push_audio(c).unwrap())
            .collect();
        for k in 0..mels[0].len() {
            let m: Vec<_> = mels.iter().map(|v| v[k].clone()).collect();
            let mut refs: Vec<&mut _> = streams.iter_mut().collect();
            for (i, st) in p.step_batch(&mut refs, &m).unwrap().into_iter().enumerate() {
                batched[i].push(st);
            }
        }
    }
    for (i, (a, b)) in single.iter().zip(&batched).enumerate() {
        assert_batched_equal(&format!("stream {i}"), a, b);
    }
}

/// Batched steps equal the single stream's: identical tokens, frames within 1e-5 (scaled).
fn assert_batched_equal(what: &str, a: &[TokenStep], b: &[TokenStep]) {
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x.tokens, y.tokens, "{what} step {}", x.token_index);
    }
    let fa: Vec<Frame> = a.iter().flat_map(|s| s.frames.clone()).collect();
    let fb: Vec<Frame> = b.iter().flat_map(|s| s.frames.clone()).collect();
    common::assert_frames_within(&fb, &fa, 1e-5, &format!("{what}: batched vs single"));
}

fn nan_in_step(steps: &[TokenStep], t: usize) -> Vec<TokenStep> {
    let mut v = steps.to_vec();
    v[t].frames[1].poses[7] = f32::NAN;
    v
}

/// The batched-vs-single comparison fails when a NaN is on either side.
#[test]
fn the_batch_comparison_fails_on_nan_either_side() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let clip = rollout_audio(&bundle, 1);
    let opts = StreamOptions {
        seed: 1,
        ..Default::default()
    };
    let a = run_all(&mut p, &opts, &clip[..8000], 8000);
    assert!(a.len() >= 3);
    assert_batched_equal("clean", &a, &a);
    let bad = nan_in_step(&a, 2);
    common::assert_check_fails("batch, NaN in the batched side", "non-finite", || {
        assert_batched_equal("probe", &a, &bad)
    });
    common::assert_check_fails("batch, NaN in the single stream", "non-finite", || {
        assert_batched_equal("probe", &bad, &a)
    });
}

/// Output up to the token that completes before `cut` is the same for `audio` and `changed` (which
/// differ from `cut` on), and later output differs (the later audio is used).
fn check_look_ahead(
    p: &mut LiveGestureGraphs,
    bundle: &Bundle,
    audio: &[f32],
    changed: &[f32],
    cut: usize,
) {
    let opts = StreamOptions {
        seed: 5,
        ..Default::default()
    };
    let a = run_all(p, &opts, audio, 1000);
    let b = run_all(p, &opts, changed, 1000);
    let done = bundle.frontend().n_tokens(cut as u64) as usize;
    assert!(done > 0);
    assert_eq!(a.len(), b.len());
    assert!(a.len() > done + 2, "too little audio after the change");
    assert_eq!(
        a[..done],
        b[..done],
        "output before the change depends on later audio"
    );
    assert!(
        a[done..]
            .iter()
            .zip(&b[done..])
            .any(|(x, y)| x.frames != y.frames),
        "output after the change does not depend on the changed audio"
    );
}

#[test]
fn zero_look_ahead() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let clip = rollout_audio(&bundle, 1);
    let audio: Vec<f32> = clip[..24000].to_vec();
    let mut changed = audio.clone();
    let cut = 12000;
    for x in &mut changed[cut..] {
        *x = -*x * 0.5;
    }
    check_look_ahead(&mut p, &bundle, &audio, &changed, cut);
    // the check fails on a broken input: audio changed before the cut (a look-ahead), and no change.
    // The early change is a loud tone over the last 0.4 s (3 tokens) before the cut: a milder one (the
    // same halving over 0.25 s) left every token of the seed-3 tiny bundle's random weights unchanged
    let mut early = audio.clone();
    for (i, x) in early[cut - 6400..].iter_mut().enumerate() {
        *x = (i as f32 * 0.173).sin() * 0.5;
    }
    common::assert_check_fails("change before the cut", "depends on later audio", || {
        check_look_ahead(&mut p, &bundle, &audio, &early, cut)
    });
    common::assert_check_fails("no change", "does not depend", || {
        check_look_ahead(&mut p, &bundle, &audio, &audio, cut)
    });
}
