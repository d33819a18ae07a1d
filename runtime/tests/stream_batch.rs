//! [`StreamBatch`]: streams stepped with their caches kept stacked between steps give exactly the
//! tokens and frames they give stepped alone, with streams joining and leaving (and one leaving,
//! stepping alone, and joining again) in the middle; mixed guidance, seeds and sampling settings; on
//! both backends. Plus the batch's bookkeeping and error cases.

use livegesture_parity_tests as common;

use livegesture::audio::read_wav_16k_mono;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{
    LiveGestureGraphs, Stream, StreamBatch, StreamId, StreamOptions, TokenStep,
};
use ndarray::Array2;

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

/// `n` samples of the reference clip (repeated), starting `offset` samples into it.
fn audio(bundle: &Bundle, offset: usize, n: usize) -> Vec<f32> {
    let clip = read_wav_16k_mono(bundle.path("reference/clip.wav")).expect("reference clip");
    clip.iter().cycle().skip(offset).take(n).copied().collect()
}

/// One stream of the scenario: its options, its audio, when it joins the batch and when it leaves.
struct Plan {
    opts: StreamOptions,
    audio: Vec<f32>,
    join: usize,
    leave: Option<usize>,
    /// After leaving: tokens stepped alone, then it joins the batch again until the end.
    alone_then_rejoin: Option<usize>,
}

fn opts(
    seed: u64,
    guidance: Option<f64>,
    temperature: Option<f64>,
    top_k: Option<usize>,
) -> StreamOptions {
    StreamOptions {
        seed,
        guidance,
        temperature,
        top_k,
        record_logits: seed.is_multiple_of(2),
        ..Default::default()
    }
}

/// Where a stream of the scenario is at a global step.
enum Place {
    Waiting,
    InBatch(StreamId),
    Alone(Box<Stream>),
    Done,
}

/// Token-sized audio chunk `t` of `a` (exactly one token's new samples: zero look-ahead).
fn token_chunk<'a>(p: &LiveGestureGraphs, a: &'a [f32], t: u64) -> &'a [f32] {
    let fe = p.frontend();
    let start = if t == 0 {
        0
    } else {
        fe.token_end(t - 1) as usize
    };
    &a[start..fe.token_end(t) as usize]
}

/// The comparison of two steps' values (`livegesture::compare`, `b` the reference side): the scaled
/// error, infinite when a value is NaN or Inf on either side or the lengths differ.
fn scaled(a: &[f32], b: &[f32]) -> f64 {
    let d = livegesture::compare::diff(a, b);
    if d.problem().is_some() {
        f64::INFINITY
    } else {
        d.scaled_error()
    }
}

/// The largest scaled difference between two token steps' frames (each field over the step's
/// frames one tensor) and logits.
fn step_diff(a: &TokenStep, b: &TokenStep) -> (f64, f64) {
    assert_eq!(a.frames.len(), b.frames.len());
    let mut f = 0f64;
    for (x, y) in a.frames.iter().zip(&b.frames) {
        assert_eq!(x.index, y.index);
    }
    let field = |s: &TokenStep, k: usize| -> Vec<f32> {
        s.frames
            .iter()
            .flat_map(|fr| match k {
                0 => fr.poses.to_vec(),
                1 => fr.trans.to_vec(),
                2 => fr.expressions.to_vec(),
                _ => fr.foot_contact.to_vec(),
            })
            .collect()
    };
    for k in 0..4 {
        f = f.max(scaled(&field(a, k), &field(b, k)));
    }
    let l = match (&a.logits, &b.logits) {
        (None, None) => 0.0,
        (Some(x), Some(y)) => {
            assert_eq!(x.uncond.is_some(), y.uncond.is_some());
            let u = match (&x.uncond, &y.uncond) {
                (Some(u), Some(v)) => scaled(u, v),
                _ => 0.0,
            };
            scaled(&x.cond, &y.cond).max(u)
        }
        _ => panic!("logits recorded for one step only"),
    };
    (f, l)
}

/// A batched step (`b`) agrees with the stream stepped alone (`a`): frames and logits within the
/// backend's bounds (bit-identical on ort; tract's kernels round differently for different batch
/// sizes, by ~1e-6 here, with step_batch alike, so there the bound of step_batch's test applies).
/// Returns the frame and logit errors.
fn assert_step_agrees(kind: BackendKind, what: &str, a: &TokenStep, b: &TokenStep) -> (f64, f64) {
    let (df, dl) = step_diff(a, b);
    let (bf, bl) = match kind {
        BackendKind::Ort => (0.0, 0.0),
        BackendKind::Tract => (1e-5, 1e-4),
    };
    assert!(
        df.is_finite() && dl.is_finite(),
        "{kind}: {what}: a non-finite value (NaN or Inf) or a length mismatch in the frames or logits"
    );
    assert!(
        df <= bf && dl <= bl,
        "{kind}: {what}: frames differ from stepping alone by {df:e} (scaled), logits by {dl:e} \
         (bounds {bf:e}, {bl:e})"
    );
    (df, dl)
}

/// The batch-vs-alone comparison fails when a NaN is on either side, in a frame or in the logits.
#[test]
fn the_batch_comparison_fails_on_nan_either_side() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let mut s = p.new_stream(&opts(12, None, None, None)).unwrap();
    let steps = p.push_steps(&mut s, &audio(&bundle, 0, 8000)).unwrap();
    let a = steps[1].clone();
    assert!(a.logits.is_some(), "the stream records its logits");
    for kind in [BackendKind::Ort, BackendKind::Tract] {
        assert_step_agrees(kind, "clean", &a, &a);
        let mut bad_frame = a.clone();
        bad_frame.frames[2].trans[1] = f32::NAN;
        let mut bad_logit = a.clone();
        bad_logit.logits.as_mut().unwrap().cond[3] = f32::NAN;
        for (what, bad) in [("frame", &bad_frame), ("logits", &bad_logit)] {
            common::assert_check_fails(
                &format!("{kind} batch, NaN in the batched {what}"),
                "non-finite",
                || {
                    assert_step_agrees(kind, "probe", &a, bad);
                },
            );
            common::assert_check_fails(
                &format!("{kind} batch, NaN in the alone {what}"),
                "non-finite",
                || {
                    assert_step_agrees(kind, "probe", bad, &a);
                },
            );
        }
    }
}

/// Runs the scenario: every stream stepped alone over its whole life (`alone`); the streams in one
/// StreamBatch joining and leaving between steps (`batched`); and twins of the batched streams,
/// separately owned Streams stepped with `step_batch` in exactly the batch's composition and order
/// at every step (`twins`).
// long: one scenario's three runs (alone, batched, twins) and their comparisons, step by step, as the doc above lists them
fn check_scenario(kind: BackendKind) {
    let (bundle, mut p) = pipeline(kind);
    let steps = 24usize;
    let n_samples = p.frontend().token_end(steps as u64) as usize + 1;
    let a = |i: usize| audio(&bundle, 3217 * i, n_samples);
    // guidance None = the bundle's default (guided); 1.0 = unguided (one row in every graph)
    #[rustfmt::skip]
    let plans = vec![
        Plan { opts: opts(11, None, None, None), audio: a(0), join: 0, leave: None, alone_then_rejoin: None },
        Plan { opts: opts(12, Some(1.0), None, None), audio: a(1), join: 0, leave: Some(5), alone_then_rejoin: Some(4) },
        Plan { opts: opts(13, Some(2.0), None, Some(0)), audio: a(2), join: 0, leave: Some(9), alone_then_rejoin: None },
        Plan { opts: opts(14, Some(1.0), Some(0.8), None), audio: a(3), join: 3, leave: None, alone_then_rejoin: None },
        Plan { opts: opts(15, None, Some(1.3), Some(3)), audio: a(4), join: 6, leave: Some(15), alone_then_rejoin: None },
        Plan { opts: opts(16, Some(1.0), None, None), audio: a(5), join: 9, leave: Some(20), alone_then_rejoin: None },
        Plan { opts: opts(17, Some(3.0), None, None), audio: a(6), join: 10, leave: Some(12), alone_then_rejoin: None },
        Plan { opts: opts(18, None, None, None), audio: a(7), join: 10, leave: None, alone_then_rejoin: None },
        Plan { opts: opts(19, Some(1.0), None, None), audio: a(8), join: 16, leave: None, alone_then_rejoin: None },
    ];

    // each stream stepped alone over its whole life
    let life = |pl: &Plan| -> usize {
        let in_batch = pl.leave.unwrap_or(steps) - pl.join;
        match (pl.leave, pl.alone_then_rejoin) {
            (Some(l), Some(k)) => in_batch + k + (steps - (l + k)),
            _ => in_batch,
        }
    };
    let alone: Vec<Vec<TokenStep>> = plans
        .iter()
        .map(|pl| {
            let mut s = p.new_stream(&pl.opts).unwrap();
            let n = life(pl) as u64;
            let out = p
                .push_steps(&mut s, &pl.audio[..p.frontend().token_end(n - 1) as usize])
                .unwrap();
            assert_eq!(out.len() as u64, n);
            out
        })
        .collect();

    let mut batch = p.new_batch();
    let mut places: Vec<Place> = plans.iter().map(|_| Place::Waiting).collect();
    let mut twins: Vec<Option<Stream>> = plans.iter().map(|_| None).collect();
    let mut got: Vec<Vec<TokenStep>> = plans.iter().map(|_| Vec::new()).collect();
    let mut got_twins: Vec<Vec<TokenStep>> = plans.iter().map(|_| Vec::new()).collect();
    let (mut largest, mut reordered) = (0, false);
    for g in 0..steps {
        for (i, pl) in plans.iter().enumerate() {
            let place = std::mem::replace(&mut places[i], Place::Done);
            places[i] = match place {
                Place::Waiting if pl.join == g => {
                    twins[i] = Some(p.new_stream(&pl.opts).unwrap());
                    Place::InBatch(batch.add(p.new_stream(&pl.opts).unwrap()).unwrap())
                }
                Place::InBatch(id) if pl.leave == Some(g) => {
                    let before = batch.ids();
                    let s = batch.remove(id).unwrap();
                    assert!(!batch.contains(id));
                    let kept: Vec<StreamId> = before.iter().copied().filter(|&x| x != id).collect();
                    reordered |= batch.ids() != kept;
                    assert_eq!(s.tokens_done(), got[i].len() as u64);
                    match pl.alone_then_rejoin {
                        Some(_) => Place::Alone(Box::new(s)),
                        None => Place::Done,
                    }
                }
                Place::Alone(s) if pl.leave.unwrap() + pl.alone_then_rejoin.unwrap() == g => {
                    Place::InBatch(batch.add(*s).unwrap())
                }
                other => other,
            };
        }
        // streams outside the batch step alone (and so do their twins)
        for (i, pl) in plans.iter().enumerate() {
            if let Place::Alone(s) = &mut places[i] {
                let t = s.tokens_done();
                let mels = s.push_audio(token_chunk(&p, &pl.audio, t)).unwrap();
                assert_eq!(mels.len(), 1);
                got[i].push(p.step(s, &mels[0]).unwrap());
                let twin = twins[i].as_mut().unwrap();
                got_twins[i].push(p.step(twin, &mels[0]).unwrap());
            }
        }
        // everyone in the batch gets its token's audio and steps together, in batch order
        let ids = batch.ids();
        let order: Vec<usize> = ids
            .iter()
            .map(|id| {
                places
                    .iter()
                    .position(|pl| matches!(pl, Place::InBatch(x) if x == id))
                    .unwrap()
            })
            .collect();
        let mut mels: Vec<Array2<f32>> = Vec::with_capacity(ids.len());
        for (id, &i) in ids.iter().zip(&order) {
            let t = batch.tokens_done(*id).unwrap();
            let mut m = batch
                .push_audio(*id, token_chunk(&p, &plans[i].audio, t))
                .unwrap();
            assert_eq!(m.len(), 1, "one mel block per token of audio");
            mels.push(m.pop().unwrap());
        }
        largest = largest.max(ids.len());
        let out = p.step_stream_batch(&mut batch, &mels).unwrap();
        assert_eq!(out.len(), ids.len());
        for (&i, st) in order.iter().zip(out) {
            got[i].push(st);
        }
        // the twins: the same streams, the same order, separately owned, stacked and split per step
        let mut tw: Vec<Option<Stream>> = order.iter().map(|&i| twins[i].take()).collect();
        let mut refs: Vec<&mut Stream> = tw.iter_mut().map(|t| t.as_mut().unwrap()).collect();
        let out = p.step_batch(&mut refs, &mels).unwrap();
        for ((&i, st), t) in order.iter().zip(out).zip(tw) {
            got_twins[i].push(st);
            twins[i] = t;
        }
    }
    assert!(
        largest >= 5,
        "the scenario keeps several streams in the batch"
    );
    assert!(
        reordered,
        "the scenario moves a stream into a leaving stream's place"
    );

    let (mut worst_frame, mut worst_logit) = (0f64, 0f64);
    for (i, ((want, have), twin)) in alone.iter().zip(&got).zip(&got_twins).enumerate() {
        assert_eq!(have.len(), want.len(), "{kind}: stream {i}: token count");
        assert_eq!(
            twin.len(),
            want.len(),
            "{kind}: stream {i}: twin token count"
        );
        for ((a, b), c) in want.iter().zip(have).zip(twin) {
            let t = a.token_index;
            assert_eq!(b.token_index, t, "{kind}: stream {i}: token index");
            // tokens: exactly those of the stream stepped alone
            assert_eq!(
                b.tokens, a.tokens,
                "{kind}: stream {i}: tokens differ at token {t}"
            );
            // everything bit for bit equal to the same batch stacked and split per step
            let (df, dl) = step_diff(b, c);
            assert!(
                b == c,
                "{kind}: stream {i} token {t}: StreamBatch differs from step_batch with the same streams \
                 (frames by {df:e}, logits by {dl:e})"
            );
            // frames and logits: bit-identical to stepping alone on ort; tract's kernels round
            // differently for different batch sizes (by ~1e-6 here, with step_batch alike), so there
            // the bound of step_batch's test applies
            let (df, dl) = assert_step_agrees(kind, &format!("stream {i} token {t}"), a, b);
            worst_frame = worst_frame.max(df);
            worst_logit = worst_logit.max(dl);
        }
    }
    eprintln!(
        "{kind}: {} streams, up to {largest} at once: tokens identical to stepping alone, frames within \
         {worst_frame:.2e}, logits within {worst_logit:.2e}; bit-identical to step_batch",
        plans.len()
    );
}

#[test]
fn tract_stream_batch_equals_streams_stepped_alone() {
    check_scenario(BackendKind::Tract);
}

#[test]
fn ort_stream_batch_equals_streams_stepped_alone() {
    check_scenario(BackendKind::Ort);
}

/// `step_batch` (stack and split every step) and a StreamBatch give identical steps for the same
/// streams; the StreamBatch keeps its order until a stream leaves.
#[test]
fn stream_batch_equals_step_batch() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let a = audio(&bundle, 0, 16000 * 2);
    let opts: Vec<StreamOptions> = (0..4)
        .map(|i| StreamOptions {
            seed: 100 + i,
            guidance: if i % 2 == 0 { None } else { Some(1.0) },
            ..Default::default()
        })
        .collect();
    let mut streams: Vec<Stream> = opts.iter().map(|o| p.new_stream(o).unwrap()).collect();
    let mut batch = p.new_batch();
    let ids: Vec<StreamId> = opts
        .iter()
        .map(|o| batch.add(p.new_stream(o).unwrap()).unwrap())
        .collect();
    assert_eq!(batch.ids(), ids);
    assert_eq!(batch.branch_rows(), 6);
    let mut fe = p.new_stream(&opts[0]).unwrap();
    let mels = fe.push_audio(&a).unwrap();
    for (t, mel) in mels.iter().take(10).enumerate() {
        let block = vec![mel.clone(); 4];
        let mut refs: Vec<&mut Stream> = streams.iter_mut().collect();
        let x = p.step_batch(&mut refs, &block).unwrap();
        let y = p.step_stream_batch(&mut batch, &block).unwrap();
        assert!(x == y, "step {t}: StreamBatch and step_batch differ");
    }
}

#[test]
fn stream_batch_bookkeeping_and_errors() {
    let (bundle, mut p) = pipeline(BackendKind::Tract);
    let guided = StreamOptions {
        seed: 1,
        ..Default::default()
    };
    let unguided = StreamOptions {
        seed: 2,
        guidance: Some(1.0),
        ..Default::default()
    };
    let mut batch: StreamBatch = p.new_batch();
    assert!(batch.is_empty());
    assert!(p.step_stream_batch(&mut batch, &[]).unwrap().is_empty());
    let a = batch.add(p.new_stream(&guided).unwrap()).unwrap();
    let b = batch.add(p.new_stream(&unguided).unwrap()).unwrap();
    let c = batch.add(p.new_stream(&guided).unwrap()).unwrap();
    let d = batch.add(p.new_stream(&unguided).unwrap()).unwrap();
    assert_eq!(batch.ids(), vec![a, b, c, d]);
    assert_eq!(batch.branch_rows(), 6);
    assert_eq!(batch.options(b).unwrap(), &unguided);

    // the last stream has the same rows as b: it takes b's place
    let sb = batch.remove(b).unwrap();
    assert_eq!(sb.options(), &unguided);
    assert_eq!(batch.ids(), vec![a, d, c]);
    // the last (guided) differs from d (unguided): the later streams shift down
    batch.remove(d).unwrap();
    assert_eq!(batch.ids(), vec![a, c]);
    assert!(batch.remove(d).is_err(), "removing twice");
    assert!(batch.tokens_done(d).is_err());
    let e = batch.add(sb).unwrap();
    assert_ne!(e, b, "ids are never reused");
    assert_eq!(batch.ids(), vec![a, c, e]);
    assert_eq!(batch.branch_rows(), 5);

    // a wrong number of mel blocks or a wrong mel shape is refused without harming the batch
    let clip = audio(&bundle, 0, 16000);
    let mut fe = p.new_stream(&guided).unwrap();
    let mel = fe.push_audio(&clip).unwrap().remove(0);
    assert!(p
        .step_stream_batch(&mut batch, std::slice::from_ref(&mel))
        .is_err());
    let bad = Array2::<f32>::zeros((mel.nrows() + 1, mel.ncols()));
    assert!(p
        .step_stream_batch(&mut batch, &[mel.clone(), mel.clone(), bad])
        .is_err());
    assert!(!batch.is_poisoned());
    let out = p
        .step_stream_batch(&mut batch, &[mel.clone(), mel.clone(), mel.clone()])
        .unwrap();
    assert_eq!(out.len(), 3);
    assert_eq!(batch.tokens_done(a).unwrap(), 1);
    assert_eq!(batch.tokens_done(e).unwrap(), 1);
}

fn data_ptrs(ts: &[livegesture::backend::Tensor]) -> Vec<usize> {
    use livegesture::backend::TensorData;
    ts.iter()
        .map(|t| match &t.data {
            TensorData::F32(v) => v.as_ptr() as usize,
            TensorData::I64(v) => v.as_ptr() as usize,
        })
        .collect()
}

/// `run_into` (what a StreamBatch uses, last step's input caches as output buffers) gives what
/// `run` gives, overwrites every element of stale buffers, and on ort writes in place (the buffers
/// are kept).
fn check_run_into(kind: BackendKind) {
    use livegesture::backend::{Tensor, TensorData};
    use livegesture::bundle::concrete_shape;
    if kind == BackendKind::Ort {
        common::require_ort();
    }
    let bundle = Bundle::load(common::tiny_bundle()).unwrap();
    let be = backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })
    .unwrap();
    for name in ["expert_upper", "fusion", "decoder_face"] {
        let spec = bundle.graph(name).unwrap().clone();
        let mut g = be.load(&spec, &bundle.graph_path(&spec)).unwrap();
        let batch = 3;
        let mut inputs: Vec<Tensor> = spec
            .all_inputs()
            .iter()
            .map(|(_, dt, shape)| Tensor::zeros(*dt, concrete_shape(shape, batch)))
            .collect();
        // two chained steps so the caches are not all zeros
        let n_data = spec.inputs.len();
        let first = g.run(&inputs).unwrap();
        for (i, c) in first[spec.outputs.len()..].iter().enumerate() {
            inputs[n_data + i] = c.clone();
        }
        let want = g.run(&inputs).unwrap();
        // stale buffers: NaN / sentinel everywhere, one of them too small
        let mut outs: Vec<Tensor> = want.clone();
        for t in outs.iter_mut() {
            match &mut t.data {
                TensorData::F32(v) => v.iter_mut().for_each(|x| *x = f32::NAN),
                TensorData::I64(v) => v.iter_mut().for_each(|x| *x = -7),
            }
        }
        outs[0] = Tensor::zeros(outs[0].dtype(), vec![1]);
        g.run_into(&inputs, &mut outs).unwrap();
        assert!(outs == want, "{kind}: {name}: run_into differs from run");
        let ptrs = data_ptrs(&outs);
        g.run_into(&inputs, &mut outs).unwrap();
        assert!(
            outs == want,
            "{kind}: {name}: second run_into differs from run"
        );
        if kind == BackendKind::Ort {
            assert_eq!(
                data_ptrs(&outs),
                ptrs,
                "{name}: ort run_into reallocated its outputs"
            );
        }
    }
}

#[test]
fn ort_run_into_writes_in_place() {
    check_run_into(BackendKind::Ort);
}

#[test]
fn tract_run_into_equals_run() {
    check_run_into(BackendKind::Tract);
}
