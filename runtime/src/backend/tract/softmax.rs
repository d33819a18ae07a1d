//! Softmax over an inner axis, computed on the last one.
//!
//! tract 0.23 computes a softmax over the last axis of a contiguous tensor row by row with its
//! vectorised kernels, but a softmax over any other axis element by element through `ndarray` views
//! (libm `exp`, one collapsed view per row): DiffSHEG's linear attention normalises its keys over
//! the window's frames (axis 1 of `[rows, frames, heads, dim]`), and those four softmaxes took 1.7 ms
//! each of the denoiser's 12 ms on tract against 0.05 ms for the same softmax over the last axis
//! (BENCHMARKS.md, "Issue 42 in one sitting", "tract's softmax over the frames").
//!
//! Moving the axis last, taking the softmax there and moving it back computes the same function; the
//! two moves are copies of the tensor. The rewrite is applied to the optimised model, so tract's own
//! axis-change pass does not fold the moves back into the softmax.

use tract_onnx::prelude::*;
use tract_onnx::tract_core::ops::change_axes::AxisOp;
use tract_onnx::tract_core::ops::nn::Softmax;

/// Set to `generic` to keep tract's softmax over inner axes (for A/B measurements).
pub const SWITCH: &str = "LIVEGESTURE_TRACT_SOFTMAX";

/// Replaces every f32 softmax over one axis that is not the last by move, softmax over the last axis,
/// move back. Returns how many were replaced.
pub fn on_last_axis(model: &mut TypedModel) -> TractResult<usize> {
    let ids: Vec<usize> = model
        .nodes()
        .iter()
        .filter(|n| n.op_as::<Softmax>().is_some())
        .map(|n| n.id)
        .collect();
    let mut replaced = 0;
    for id in ids {
        let node = model.node(id).clone();
        let Some(sm) = node.op_as::<Softmax>() else {
            continue;
        };
        let fact = model.outlet_fact(node.inputs[0])?.clone();
        let rank = fact.rank();
        if sm.axes.len() != 1
            || sm.axes[0] + 1 == rank
            || fact.datum_type != f32::datum_type()
            || sm.quant_output_dt.is_some()
        {
            continue;
        }
        let axis = sm.axes[0];
        let mut patch = TypedModelPatch::default();
        let x = patch.tap_model(model, node.inputs[0])?;
        let last = patch.wire_node(
            format!("{}.axis_last", node.name),
            AxisOp::Move(axis, rank - 1),
            &[x],
        )?;
        let soft = patch.wire_node(
            format!("{}.on_last", node.name),
            Softmax {
                axes: tvec![rank - 1],
                ..sm.clone()
            },
            &last,
        )?;
        let back = patch.wire_node(
            format!("{}.axis_back", node.name),
            AxisOp::Move(rank - 1, axis),
            &soft,
        )?;
        patch.shunt_outside(model, OutletId::new(id, 0), back[0])?;
        patch.obliterate(id)?;
        patch.apply(model)?;
        replaced += 1;
    }
    if replaced > 0 {
        model.compact()?;
    }
    Ok(replaced)
}
