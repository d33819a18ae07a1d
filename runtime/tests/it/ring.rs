//! Ring caches (docs/bundle.md#ring-caches) in the runtime, on the tiny bundle exported with the
//! ring forms (each backend runs its ring form by default): streams that join and leave cohorts at
//! other phases (their rows rotated as they are copied in), step alone in between, are reset or
//! dropped keep the frames each gets alone, on both backends; and a ring graph chained as `livegesture
//! parity` chains it matches the torch reference with its entries written at the phase, and fails
//! when they are written one slot off.

use livegesture_parity_tests as common;

use livegesture::backend::{self, Backend, BackendKind, BackendOptions, Tensor};
use livegesture::bundle::{Bundle, GraphSpec};
use livegesture::compare;
use livegesture::model::livegesture::{LiveGestureGraphs, StreamOptions};
use livegesture::model::{self};
use livegesture::output::Frame;
use livegesture_parity::ReferenceVectors;
use ndarray::Array2;

fn backend_of(kind: BackendKind) -> Box<dyn Backend> {
    if kind == BackendKind::Ort {
        common::require_ort();
    }
    backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })
    .expect("backend")
}

#[test]
fn ring_streams_changing_company_keep_their_frames_on_both_backends() {
    let bundle = Bundle::load(common::ring_bundle()).expect("ring test bundle loads");
    for kind in [BackendKind::Tract, BackendKind::Ort] {
        let be = backend_of(kind);
        let g = LiveGestureGraphs::new(&bundle, be.as_ref()).expect("graphs");
        assert!(
            g.ring_caches(),
            "{kind:?}: the bundle's form '{}' runs on ring caches",
            g.form()
        );
        let m = model::load(&bundle, be.as_ref()).expect("model");
        super::step_many::check_changing_company(&bundle, m.as_ref());
    }
}

/// Mel blocks of one token each, pseudo-random (a fixed LCG per `seed`) in the log-mel range.
fn mels(bundle: &Bundle, seed: u64, n: usize) -> Vec<Array2<f32>> {
    let f = bundle.frontend();
    let shape = (f.mel_frames_per_token as usize, f.n_mels);
    let mut x = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..n)
        .map(|_| {
            Array2::from_shape_fn(shape, |_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                -8.0 + 6.0 * ((x >> 40) as f32 / (1u64 << 24) as f32)
            })
        })
        .collect()
}

/// Streams that have stepped 3, 1 and 0 tokens alone (their caches at three phases) are stepped
/// together in one `step_batch` (their rows rotated to the first one's phase): each keeps the frames
/// it gets alone, on both backends.
#[test]
fn ring_streams_at_other_phases_stepped_in_one_batch_keep_their_frames() {
    let bundle = Bundle::load(common::ring_bundle()).expect("ring test bundle loads");
    let (lead, n) = ([3usize, 1, 0], 12);
    let blocks: Vec<Vec<Array2<f32>>> = (0..3).map(|i| mels(&bundle, i as u64 + 1, n)).collect();
    let opts = |i: usize| StreamOptions {
        seed: 10 + i as u64,
        ..Default::default()
    };
    for kind in [BackendKind::Tract, BackendKind::Ort] {
        let be = backend_of(kind);
        let g = LiveGestureGraphs::new(&bundle, be.as_ref()).expect("graphs");
        assert!(g.ring_caches(), "{kind:?}: runs on ring caches");
        let alone: Vec<Vec<Frame>> = (0..3)
            .map(|i| {
                let mut s = g.new_stream(&opts(i)).unwrap();
                blocks[i]
                    .iter()
                    .flat_map(|m| g.step(&mut s, m).unwrap().frames)
                    .collect()
            })
            .collect();
        let mut streams: Vec<_> = (0..3).map(|i| g.new_stream(&opts(i)).unwrap()).collect();
        let mut got: Vec<Vec<Frame>> = vec![Vec::new(); 3];
        for i in 0..3 {
            for m in &blocks[i][..lead[i]] {
                got[i].extend(g.step(&mut streams[i], m).unwrap().frames);
            }
        }
        // then together, each from its own next block, until the first runs out
        for k in 0..n - lead[0] {
            let ms: Vec<Array2<f32>> = (0..3).map(|i| blocks[i][lead[i] + k].clone()).collect();
            let mut refs: Vec<_> = streams.iter_mut().collect();
            for (i, st) in g
                .step_batch(&mut refs, &ms)
                .unwrap()
                .into_iter()
                .enumerate()
            {
                got[i].extend(st.frames);
            }
        }
        for i in 0..3 {
            let want = &alone[i][..got[i].len()];
            let (_, d) = common::frames_diff(&got[i], want);
            assert!(
                d.within(1e-4),
                "{kind:?} stream {i}: together vs alone: {d}"
            );
        }
        // the comparison can fail: another stream's frames
        let (_, d) = common::frames_diff(&got[1], &alone[0][..got[1].len()]);
        assert!(
            !d.within(1e-4),
            "{kind:?}: two streams' frames compared equal"
        );
    }
}

/// The worst scaled error of `spec`'s outputs against its torch reference vectors over the
/// reference's chained steps, the entries of every ring cache written at the step's phase plus
/// `skew` (0: where `livegesture parity` writes them).
fn chain_error(be: &dyn Backend, bundle: &Bundle, spec: &GraphSpec, skew: u64) -> f64 {
    let refv = ReferenceVectors::load(&bundle.path(&format!("reference/{}.npz", spec.name)))
        .expect("reference vectors");
    let runner = be
        .load(spec, &bundle.graph_path(spec))
        .expect("graph loads");
    let n = refv.scalar("n_steps").expect("n_steps") as usize;
    let key = |s: usize, kind: &str, name: &str| format!("step{s}.{kind}.{name}");
    let batch = refv
        .get(&key(0, "input", &spec.inputs[0].name))
        .expect("input")
        .batch();
    let mut caches: Vec<Tensor> = spec.caches.iter().map(|c| c.zeros(batch)).collect();
    let at = spec
        .input_index("phase")
        .expect("a ring graph has a phase input");
    let mut worst = 0f64;
    for s in 0..n {
        let mut inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&key(s, "input", &i.name)).expect("input").clone())
            .collect();
        let phase = inputs[at].as_i64("phase").expect("int64")[0] as u64;
        inputs.extend(caches.iter().cloned());
        let out = runner.run(&inputs).expect("run");
        for (k, o) in spec.outputs.iter().enumerate() {
            let want = refv.get(&key(s, "output", &o.name)).expect("output");
            worst = worst.max(compare::diff_tensors(&out[k], want).scaled_error());
        }
        for (k, c) in spec.caches.iter().enumerate() {
            let o = out[spec.outputs.len() + k].clone();
            c.store_output(&mut caches[k], o, phase + skew)
                .expect("write");
        }
    }
    worst
}

#[test]
fn ring_entries_written_one_slot_off_fail_the_graph_check() {
    let bundle = Bundle::load(common::ring_bundle()).expect("ring test bundle loads");
    for (kind, graph) in [
        (BackendKind::Ort, "experts_fused_ring"),
        (BackendKind::Ort, "fusion_ring"),
        (BackendKind::Tract, "expert_upper_ring"),
        (BackendKind::Tract, "fusion_attention_ring"),
    ] {
        let be = backend_of(kind);
        let spec = bundle.graph(graph).expect("ring graph").clone();
        assert!(spec.is_ring(), "{graph}: the manifest marks ring caches");
        let right = chain_error(be.as_ref(), &bundle, &spec, 0);
        let wrong = chain_error(be.as_ref(), &bundle, &spec, 1);
        // docs/parity.md: ort 1e-5, tract 1e-4 against torch (scaled)
        assert!(right <= 1e-4, "{kind:?} {graph}: {right:.3e} at the phase");
        assert!(
            wrong > 1e-2,
            "{kind:?} {graph}: written one slot off went unnoticed ({wrong:.3e})"
        );
    }
}
