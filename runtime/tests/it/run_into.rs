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
