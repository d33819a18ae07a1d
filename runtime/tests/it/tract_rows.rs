//! The tract backend's elementwise ops on a row broadcast over leading axes
//! (`backend::tract::rows`): bit-identical to tract's own broadcasting, in either operand order, and
//! applied where tract would broadcast generically.

use livegesture::backend::tract::{optimise, rows};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::ops::math::{add, mul, sub};

/// `x op y` for sources of shapes `a` and `b` (`y` a constant when `b_const`).
fn model(op: &str, a: &[usize], b: &[usize], b_const: bool) -> TypedModel {
    let mut m = TypedModel::default();
    let x = m.add_source("x", f32::fact(a)).unwrap();
    let y = if b_const {
        m.add_const("y", tensor_of(b, 0.37)).unwrap()
    } else {
        m.add_source("y", f32::fact(b)).unwrap()
    };
    let op = match op {
        "add" => add(),
        "sub" => sub(),
        _ => mul(),
    };
    let z = m.wire_node("op", op, &[x, y]).unwrap();
    m.select_output_outlets(&z).unwrap();
    m
}

fn tensor_of(shape: &[usize], phase: f32) -> Tensor {
    let n: usize = shape.iter().product();
    tract_ndarray::ArrayD::from_shape_vec(
        shape.to_vec(),
        (0..n)
            .map(|i| (i as f32 * 0.731 + phase).sin() * 3.0)
            .collect(),
    )
    .unwrap()
    .into_tensor()
}

fn run(plan: &Arc<TypedSimplePlan>, a: &[usize], b: Option<&[usize]>) -> Vec<f32> {
    let mut inputs = tvec![tensor_of(a, 0.1).into_tvalue()];
    if let Some(b) = b {
        inputs.push(tensor_of(b, 0.37).into_tvalue());
    }
    first_output(plan, inputs)
}

/// The first output of `plan` run on `inputs`, as f32 values (also `tract_softmax`'s).
pub(crate) fn first_output(plan: &Arc<TypedSimplePlan>, inputs: TVec<TValue>) -> Vec<f32> {
    let out = plan.run(inputs).unwrap();
    out[0]
        .to_plain_array_view::<f32>()
        .unwrap()
        .iter()
        .copied()
        .collect()
}

#[test]
fn row_broadcasts_equal_tracts_broadcasting_bit_for_bit() {
    let cases: [(&[usize], &[usize]); 5] = [
        (&[2, 9, 24], &[2, 1, 24]), // AdaIN: a row per stream
        (&[2, 9, 21], &[1, 1, 21]), // LayerNorm's weight, a length no kernel vector divides
        (&[2, 1, 24], &[2, 9, 24]), // the broadcast operand first
        (&[3, 4, 5, 16], &[3, 1, 5, 16]),
        (&[4, 12], &[1, 12]),
    ];
    for op in ["add", "sub", "mul"] {
        for (a, b) in cases {
            for b_const in [false, true] {
                let what = format!("{op} {a:?} {b:?} const {b_const}");
                let feed = (!b_const).then_some(b);
                let generic = model(op, a, b, b_const)
                    .into_optimized()
                    .unwrap()
                    .into_runnable()
                    .unwrap();
                let want = run(&generic, a, feed);
                // the rewrite applies (tract left these to its generic broadcasting)
                let mut optimised = model(op, a, b, b_const).into_optimized().unwrap();
                let n = rows::row_broadcasts(&mut optimised).unwrap();
                assert_eq!(n, 1, "{what}: {optimised}");
                let got = run(&optimise(model(op, a, b, b_const)).unwrap(), a, feed);
                assert_eq!(got.len(), want.len(), "{what}");
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(g.to_bits(), w.to_bits(), "{what}: element {i}: {g} vs {w}");
                }
            }
        }
    }
}

#[test]
fn shapes_tract_handles_itself_are_left_alone() {
    // the same shape (tract's unicast kernel) and a scalar per row (its by-scalar kernel)
    for (a, b) in [
        (&[2usize, 9, 32][..], &[2usize, 9, 32][..]),
        (&[2, 9, 32], &[2, 9, 1]),
    ] {
        let mut optimised = model("mul", a, b, false).into_optimized().unwrap();
        assert_eq!(
            rows::row_broadcasts(&mut optimised).unwrap(),
            0,
            "{a:?} {b:?}"
        );
    }
}
