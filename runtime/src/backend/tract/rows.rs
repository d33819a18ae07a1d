//! Elementwise `Add`, `Sub` and `Mul` of a tensor and a row broadcast over its leading axes.
//!
//! tract 0.23 has fast kernels for an elementwise op whose second operand is a scalar per row or
//! the same shape (after leading ones, and a row length that is a multiple of its vector size);
//! anything else goes through `ndarray`'s generic broadcasting at about 4 ns an element. DiffSHEG's
//! denoiser is full of the other case: AdaIN's scale and shift `[rows, 1, C]` against `[rows, 88, C]`,
//! and LayerNorm's weight and bias `[1, 1, 553]` (553 is no multiple of 16): 1.5 of its 5.6 ms per
//! call on tract (BENCHMARKS.md, "Issue 42 in one sitting", "tract's broadcasting of a row").
//!
//! [`RowBroadcast`] computes the same elementwise function row by row: both operands share the last
//! axis, the smaller one is read at the row its leading indices map to, and each row is one
//! vectorisable loop. Every element is the same single IEEE operation as before, so the results are
//! bit-identical.

use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;
use tract_onnx::tract_core::ops::binary::TypedBinOp;
use tract_onnx::tract_core::ops::math::{Add, Mul, Sub};
use tract_onnx::tract_core::{as_op, op_as_typed_op, op_out_of_plan};

/// Set to `generic` to keep tract's broadcasting (for A/B measurements).
pub const SWITCH: &str = "LIVEGESTURE_TRACT_ROWS";

/// The elementwise operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    Add,
    Sub,
    Mul,
}

/// `a op b` for f32 tensors of one rank whose last axes are equal and one of which has the output's
/// shape (the other broadcast over some leading axes).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct RowBroadcast {
    pub kind: Kind,
}

impl Op for RowBroadcast {
    fn name(&self) -> StaticName {
        format!("RowBroadcast{:?}", self.kind).into()
    }
    op_as_typed_op!();
}

/// The offset of each output row's row in a tensor of `shape` broadcast to `out` (row-major, the
/// last axis excluded).
fn row_offsets(shape: &[usize], out: &[usize]) -> Vec<usize> {
    let rank = out.len();
    let rows: usize = out[..rank - 1].iter().product();
    let c = out[rank - 1];
    // strides of `shape` in rows of c, 0 where broadcast
    let mut strides = vec![0usize; rank - 1];
    let mut s = 1;
    for k in (0..rank - 1).rev() {
        strides[k] = if shape[k] == 1 && out[k] != 1 { 0 } else { s };
        s *= shape[k];
    }
    let mut idx = vec![0usize; rank - 1];
    let mut offsets = Vec::with_capacity(rows);
    for _ in 0..rows {
        offsets.push(idx.iter().zip(&strides).map(|(i, s)| i * s).sum::<usize>() * c);
        for k in (0..rank - 1).rev() {
            idx[k] += 1;
            if idx[k] < out[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    offsets
}

impl EvalOp for RowBroadcast {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let (a, b) = args_2!(inputs);
        let out: TVec<usize> =
            tract_onnx::tract_core::broadcast::multi_broadcast(&[a.shape(), b.shape()])?;
        let rank = out.len();
        ensure!(rank >= 1 && a.rank() == rank && b.rank() == rank);
        let c = out[rank - 1];
        ensure!(a.shape()[rank - 1] == c && b.shape()[rank - 1] == c);
        let a_rows = row_offsets(a.shape(), &out);
        let b_rows = row_offsets(b.shape(), &out);
        let av = a.to_plain_array_view::<f32>()?;
        let bv = b.to_plain_array_view::<f32>()?;
        let (Some(x), Some(y)) = (av.as_slice(), bv.as_slice()) else {
            bail!("RowBroadcast: inputs are not contiguous");
        };
        let mut result = vec![0f32; out.iter().product()];
        for ((o, &ao), &bo) in result.chunks_exact_mut(c.max(1)).zip(&a_rows).zip(&b_rows) {
            let (x, y) = (&x[ao..ao + c], &y[bo..bo + c]);
            match self.kind {
                Kind::Add => o
                    .iter_mut()
                    .zip(x.iter().zip(y))
                    .for_each(|(o, (p, q))| *o = p + q),
                Kind::Sub => o
                    .iter_mut()
                    .zip(x.iter().zip(y))
                    .for_each(|(o, (p, q))| *o = p - q),
                Kind::Mul => o
                    .iter_mut()
                    .zip(x.iter().zip(y))
                    .for_each(|(o, (p, q))| *o = p * q),
            }
        }
        let t = tract_ndarray::ArrayD::from_shape_vec(out.to_vec(), result)?;
        Ok(tvec!(t.into_tvalue()))
    }
}

impl TypedOp for RowBroadcast {
    as_op!();

    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        let shape = tract_onnx::tract_core::broadcast::multi_broadcast(&[
            inputs[0].shape.to_tvec(),
            inputs[1].shape.to_tvec(),
        ])?;
        Ok(tvec!(f32::fact(shape)))
    }
}

/// Replaces every generic f32 `Add`, `Sub` or `Mul` left in the optimised `model` whose operands
/// have concrete shapes of one rank, the same last axis (at least 8 long), and one of them the
/// output's shape, by [`RowBroadcast`]. Returns how many were replaced.
pub fn row_broadcasts(model: &mut TypedModel) -> TractResult<usize> {
    let mut replaced = 0;
    let ids: Vec<usize> = model
        .nodes()
        .iter()
        .filter(|n| n.op_as::<TypedBinOp>().is_some())
        .map(|n| n.id)
        .collect();
    for id in ids {
        let node = model.node(id).clone();
        let op = node.op_as::<TypedBinOp>().expect("filtered above");
        let kind = if op.0.is::<Add>() {
            Kind::Add
        } else if op.0.is::<Sub>() {
            Kind::Sub
        } else if op.0.is::<Mul>() {
            Kind::Mul
        } else {
            continue;
        };
        if op.1.is_some() || node.inputs.len() != 2 {
            continue;
        }
        let facts: Vec<TypedFact> = model.node_input_facts(id)?.into_iter().cloned().collect();
        let (Some(a), Some(b)) = (facts[0].shape.as_concrete(), facts[1].shape.as_concrete())
        else {
            continue;
        };
        let (a, b) = (a.to_vec(), b.to_vec());
        if facts.iter().any(|f| f.datum_type != f32::datum_type()) || a.len() != b.len() || a == b {
            continue;
        }
        let Ok(out) = tract_onnx::tract_core::broadcast::multi_broadcast(&[&a[..], &b[..]]) else {
            continue;
        };
        let rank = a.len();
        if rank == 0
            || a[rank - 1] != b[rank - 1]
            || a[rank - 1] < 8
            || (out[..] != a[..] && out[..] != b[..])
        {
            continue;
        }
        let patch =
            TypedModelPatch::replace_single_op(model, &node, &node.inputs, RowBroadcast { kind })?;
        patch.apply(model)?;
        replaced += 1;
    }
    if replaced > 0 {
        model.compact()?;
    }
    Ok(replaced)
}
