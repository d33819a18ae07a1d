//! The tract backend's softmax over an inner axis (`backend::tract::softmax`): the rewritten plan
//! computes the softmax over the axis the graph names, as a plain softmax over that axis does, and the
//! rewrite is applied wherever the axis is not the last.

use livegesture::backend::tract::{optimise, softmax};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::ops::nn::{Softmax, SoftmaxKind};

const SHAPE: [usize; 4] = [2, 11, 3, 8];

/// A model of one softmax over `axis` of a `SHAPE` input.
fn model(axis: usize) -> TypedModel {
    let mut m = TypedModel::default();
    let x = m.add_source("x", f32::fact(SHAPE)).unwrap();
    let y = m
        .wire_node(
            "softmax",
            Softmax {
                axes: tvec![axis],
                quant_output_dt: None,
                kind: SoftmaxKind::Softmax,
            },
            &[x],
        )
        .unwrap();
    m.select_output_outlets(&y).unwrap();
    m
}

fn input() -> Vec<f32> {
    let n: usize = SHAPE.iter().product();
    (0..n)
        .map(|i| ((i * 7919 % 1013) as f32 / 1013.0 - 0.5) * 6.0)
        .collect()
}

/// The softmax of `x` (shape `SHAPE`, row-major) over `axis`, in f64.
fn reference(x: &[f32], axis: usize) -> Vec<f32> {
    let stride: usize = SHAPE[axis + 1..].iter().product();
    let len = SHAPE[axis];
    let mut out = vec![0f32; x.len()];
    for start in 0..x.len() {
        // the first element of each softmax: index `axis` is 0
        if !(start / stride).is_multiple_of(len) {
            continue;
        }
        let idx: Vec<usize> = (0..len).map(|k| start + k * stride).collect();
        let max = idx.iter().map(|&i| x[i] as f64).fold(f64::MIN, f64::max);
        let sum: f64 = idx.iter().map(|&i| (x[i] as f64 - max).exp()).sum();
        for &i in &idx {
            out[i] = ((x[i] as f64 - max).exp() / sum) as f32;
        }
    }
    out
}

fn run(plan: &Arc<TypedSimplePlan>, x: &[f32]) -> Vec<f32> {
    let t = tract_ndarray::ArrayD::from_shape_vec(SHAPE.to_vec(), x.to_vec()).unwrap();
    super::tract_rows::first_output(plan, tvec![t.into_tvalue()])
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn softmax_over_an_inner_axis_is_rewritten_and_equals_the_softmax_over_that_axis() {
    let x = input();
    for axis in 0..SHAPE.len() {
        let want = reference(&x, axis);
        // the rewrite applies to every axis but the last
        let mut optimised = model(axis).into_optimized().unwrap();
        let n = softmax::on_last_axis(&mut optimised).unwrap();
        assert_eq!(n, usize::from(axis + 1 < SHAPE.len()), "axis {axis}");
        // what the backend runs (optimise: tract's optimisation, then the rewrite)
        let got = run(&optimise(model(axis)).unwrap(), &x);
        let d = max_diff(&got, &want);
        assert!(d < 1e-6, "axis {axis}: {d} from the softmax over that axis");
        // and what tract computes without the rewrite
        let generic = run(
            &model(axis)
                .into_optimized()
                .unwrap()
                .into_runnable()
                .unwrap(),
            &x,
        );
        assert!(max_diff(&got, &generic) < 1e-6, "axis {axis}");
        // the comparison can tell the axes apart: the softmax over another axis is far off
        let other = reference(&x, (axis + 1) % SHAPE.len());
        assert!(max_diff(&got, &other) > 0.05, "axis {axis}");
    }
}
