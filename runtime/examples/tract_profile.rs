//! Per-op time profile of one bundle graph on tract (random data inputs, caches fed back).
//!   cargo run --release --example tract_profile -- models/default fusion 64
//!   cargo run --release --example tract_profile -- models/default fusion 64 nodes   # per node, with shapes
//!   DIM_frames=88 I64_BOUND=2 cargo run --release --example tract_profile -- models/diffsheg denoiser 2
//!   (DIM_<name>: a named dimension's size; I64_BOUND: integer inputs below it, here the speaker ids)
use std::collections::HashMap;
use std::time::Instant;

use livegesture::bundle::{concrete_shape, Bundle, Dim, GraphSpec};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::plan::eval;

fn main() -> TractResult<()> {
    let a: Vec<String> = std::env::args().collect();
    let bundle = Bundle::load(&a[1])?;
    let spec = bundle.graph(&a[2])?.clone();
    let batch: i64 = a[3].parse()?;
    let typed = tract_onnx::onnx()
        .model_for_path(bundle.graph_path(&spec))?
        .into_typed()?
        .into_decluttered()?;
    let mut subs = HashMap::from([(typed.symbols.sym("batch"), TDim::Val(batch))]);
    for (_, _, shape) in spec.all_inputs() {
        for d in shape {
            if let Dim::Named(n) = d {
                if named(n) > 0 {
                    subs.insert(typed.symbols.sym(n), TDim::Val(named(n) as i64));
                }
            }
        }
    }
    let model = typed.set_symbols(&subs)?;
    // as the backend plans it (its rewrites of the optimised graph included)
    let plan = livegesture::backend::tract::optimise(model)?;
    let mut state = plan.spawn()?;
    let n_data = spec.inputs.len();
    let n_out = spec.outputs.len();
    let mut inputs = data_inputs(&spec, batch as usize);
    let by_node = a.get(4).map(|s| s == "nodes").unwrap_or(false);
    let mut per_op: HashMap<String, (f64, usize)> = HashMap::new();
    let runs = 60;
    let t_all = Instant::now();
    for r in 0..runs + 10 {
        let mut local: Vec<(String, f64)> = vec![];
        let outs = state.run_plan_with_eval(inputs.clone(), |ctx, st, node, inp| {
            let t = Instant::now();
            let o = eval(ctx, st, node, inp);
            let key = if by_node {
                let ins: Vec<String> = node
                    .inputs
                    .iter()
                    .map(|o| {
                        format!(
                            "{:?}",
                            plan.model().outlet_fact(*o).map(|f| f.shape.to_tvec())
                        )
                    })
                    .collect();
                format!(
                    "{} {} {:?} <- {}",
                    node.op().name(),
                    node.name,
                    node.outputs[0].fact.shape.to_tvec(),
                    ins.join(", ")
                )
            } else {
                node.op().name().to_string()
            };
            local.push((key, t.elapsed().as_secs_f64() * 1e3));
            o
        })?;
        if r >= 10 {
            for (k, v) in local {
                let e = per_op.entry(k).or_default();
                e.0 += v;
                e.1 += 1;
            }
        }
        for (k, o) in outs.into_iter().skip(n_out).enumerate() {
            inputs[n_data + k] = o;
        }
    }
    let total = t_all.elapsed().as_secs_f64() * 1e3 / (runs + 10) as f64;
    let mut v: Vec<_> = per_op.into_iter().collect();
    v.sort_by(|x, y| y.1 .0.partial_cmp(&x.1 .0).unwrap());
    println!("{} batch {batch}: ~{total:.3} ms per run (profiled)", a[2]);
    for (k, (ms, n)) in v.iter().take(if by_node { 40 } else { 18 }) {
        println!(
            "  {k:<28} {:8.3} ms/run  ({} nodes)",
            ms / runs as f64,
            n / runs
        );
    }
    Ok(())
}

/// A named dimension's size: `DIM_<name>` (e.g. `DIM_frames=88`, DiffSHEG's window), else 0.
fn named(n: &str) -> usize {
    std::env::var(format!("DIM_{n}"))
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

/// Deterministic inputs of `batch` rows: floats in [-1, 1), integers below `I64_BOUND` (default 200;
/// 2 for DiffSHEG's speaker ids), named dimensions of the size [`named`] gives.
fn data_inputs(spec: &GraphSpec, batch: usize) -> TVec<TValue> {
    let i64_bound: usize = std::env::var("I64_BOUND")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    spec.all_inputs()
        .iter()
        .map(|(_, dt, shape)| {
            let s: Vec<usize> = shape
                .iter()
                .map(|d| match d {
                    Dim::Named(n) => named(n),
                    _ => concrete_shape(std::slice::from_ref(d), batch)[0],
                })
                .collect();
            let n: usize = s.iter().product();
            match dt {
                livegesture::backend::DType::F32 => tract_ndarray::ArrayD::from_shape_vec(
                    s,
                    (0..n)
                        .map(|i| ((i * 7919 % 1000) as f32) / 500.0 - 1.0)
                        .collect(),
                )
                .unwrap()
                .into_tvalue(),
                livegesture::backend::DType::I64 => tract_ndarray::ArrayD::from_shape_vec(
                    s,
                    (0..n).map(|i| (i * 37 % i64_bound) as i64).collect(),
                )
                .unwrap()
                .into_tvalue(),
            }
        })
        .collect()
}
