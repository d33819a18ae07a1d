//! The streaming pipeline against the bundle's reference rollout (torch), on both backends, and its
//! streaming properties (chunk-size invariance, batched stepping, guidance off).

use livegesture_parity_tests as common;

use livegesture::audio::read_wav_16k_mono;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{LiveGestureGraphs, StreamOptions, TokenStep};
use livegesture::output::Frame;
use ndarray::Array2;

const FRAME_BOUND: f32 = 1e-4;

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
    for (name, got, want) in [
        ("poses", frames_to(&frames, |f| &f.poses), &ro.poses),
        ("trans", frames_to(&frames, |f| &f.trans), &ro.trans),
        (
            "expressions",
            frames_to(&frames, |f| &f.expressions),
            &ro.expressions,
        ),
        (
            "foot_contact",
            frames_to(&frames, |f| &f.foot_contact),
            &ro.foot_contact,
        ),
    ] {
        let e = common::max_abs(&got, want);
        eprintln!(
            "{kind}: rollout {name} max abs error {e:.3e} over {} frames",
            frames.len()
        );
        assert!(
            e <= FRAME_BOUND,
            "{kind}: {name} differs from the torch rollout by {e} > {FRAME_BOUND}"
        );
    }
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
    let mut max_logit = 0f32;
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(
            x.tokens, y.tokens,
            "tokens differ at step {}",
            x.token_index
        );
        let (lx, ly) = (x.logits.as_ref().unwrap(), y.logits.as_ref().unwrap());
        for (u, v) in lx.cond.iter().zip(&ly.cond) {
            max_logit = max_logit.max((u - v).abs());
        }
        assert!(lx.uncond.is_some());
    }
    eprintln!(
        "tract vs ort: {} steps, identical tokens, max abs logit difference {max_logit:.3e}",
        a.len()
    );
    assert!(max_logit <= 1e-4);
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
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert_eq!(x.tokens, y.tokens, "stream {i} step {}", x.token_index);
            for (fa, fb) in x.frames.iter().zip(&y.frames) {
                let e = fa
                    .poses
                    .iter()
                    .zip(&fb.poses)
                    .map(|(u, v)| (u - v).abs())
                    .fold(0f32, f32::max);
                assert!(
                    e <= 1e-5,
                    "stream {i} frame {}: batched differs by {e}",
                    fa.index
                );
            }
        }
    }
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
    let opts = StreamOptions {
        seed: 5,
        ..Default::default()
    };
    let a = run_all(&mut p, &opts, &audio, 1000);
    let b = run_all(&mut p, &opts, &changed, 1000);
    let done = bundle.frontend().n_tokens(cut as u64) as usize;
    assert!(done > 0);
    assert_eq!(
        a[..done],
        b[..done],
        "output before the change depends on later audio"
    );
}
