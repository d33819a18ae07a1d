//! `GraphRunner::run_into`: the last step's input caches as the output buffers of the next (the
//! stacked caches of a `step_many` cohort) give what `run` gives, on both backends.

use livegesture_parity_tests as common;

use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;

fn data_ptrs(ts: &[livegesture::backend::Tensor]) -> Vec<usize> {
    use livegesture::backend::TensorData;
    ts.iter()
        .map(|t| match &t.data {
            TensorData::F32(v) => v.as_ptr() as usize,
            TensorData::I64(v) => v.as_ptr() as usize,
        })
        .collect()
}

/// `run_into` (what a cohort of `step_many` uses, last step's input caches as output buffers) gives what
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
        let g = be.load(&spec, &bundle.graph_path(&spec)).unwrap();
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

/// `GraphRunner::run_held` (what a `step_many` cohort runs): chained steps with the caches held by
/// the backend give bit for bit what `run` gives with the caches fed back as plain tensors (same
/// graph, same batch); on tract the new caches stay tract's own (`held.native`, no plain copy) until
/// `settle`, which gives exactly the plain caches; tract refuses another graph's held caches.
fn check_run_held(kind: BackendKind) {
    use livegesture::backend::{HeldCaches, Tensor, TensorData};
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
    let mut last: Option<(String, HeldCaches)> = None;
    for name in ["expert_upper", "fusion", "decoder_face"] {
        let spec = bundle.graph(name).unwrap().clone();
        let g = be.load(&spec, &bundle.graph_path(&spec)).unwrap();
        let batch = 3;
        let n_data = spec.inputs.len();
        let n_out = spec.outputs.len();
        let all: Vec<Tensor> = spec
            .all_inputs()
            .iter()
            .map(|(_, dt, shape)| Tensor::zeros(*dt, concrete_shape(shape, batch)))
            .collect();
        // float data inputs away from zero, so the caches change from step to step
        let mut data: Vec<Tensor> = all[..n_data].to_vec();
        for t in data.iter_mut() {
            if let TensorData::F32(v) = &mut t.data {
                v.iter_mut()
                    .enumerate()
                    .for_each(|(i, x)| *x = (i as f32 * 0.37).sin() * 0.5);
            }
        }
        let mut plain: Vec<Tensor> = all[n_data..].to_vec();
        let mut held = HeldCaches::plain(plain.clone(), Vec::new());
        for step in 0..4 {
            let mut inputs = data.clone();
            inputs.extend(plain.clone());
            let want = g.run(&inputs).unwrap();
            let got = g.run_held(data.clone(), &mut held).unwrap();
            assert!(
                got[..] == want[..n_out],
                "{kind}: {name}: run_held's data outputs differ from run's at step {step}"
            );
            plain = want[n_out..].to_vec();
            if kind == BackendKind::Tract {
                assert!(
                    held.native.is_some() && held.plain.is_empty(),
                    "{name}: tract did not keep the new caches as its own at step {step}"
                );
            } else {
                assert!(
                    held.plain == plain,
                    "{name}: ort's new caches at step {step}"
                );
            }
        }
        held.settle().unwrap();
        assert!(held.native.is_none());
        assert!(
            held.plain == plain,
            "{kind}: {name}: the settled caches differ from run's"
        );
        if kind == BackendKind::Tract {
            // held again, then handed to another graph: refused, naming both
            g.run_held(data.clone(), &mut held).unwrap();
            if let Some((other, mut h)) = last.take() {
                let e = g
                    .run_held(data.clone(), &mut h)
                    .expect_err("another graph's held caches are refused");
                let e = format!("{e:#}");
                assert!(e.contains(name) && e.contains(&other), "{e}");
            }
            last = Some((name.to_string(), held));
        }
    }
}

#[test]
fn ort_run_held_equals_run() {
    check_run_held(BackendKind::Ort);
}

#[test]
fn tract_run_held_keeps_its_caches_and_equals_run() {
    check_run_held(BackendKind::Tract);
}
