//! Per-op time profile of one bundle graph on tract (random data inputs, caches fed back).
//!   cargo run --release --example tract_profile -- models/default fusion 64
//!   cargo run --release --example tract_profile -- models/default fusion 64 nodes   # per node, with shapes
use std::collections::HashMap;
use std::time::Instant;

use livegesture::bundle::Bundle;
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
    let sym = typed.symbols.sym("batch");
    let model = typed.set_symbols(&HashMap::from([(sym, TDim::Val(batch))]))?;
    let plan = model.into_optimized()?.into_runnable()?;
    let mut state = plan.spawn()?;
    let n_data = spec.inputs.len();
    let n_out = spec.outputs.len();
    let mut inputs: TVec<TValue> = spec
        .all_inputs()
        .iter()
        .map(|(_, dt, shape)| {
            let s: Vec<usize> = livegesture::bundle::concrete_shape(shape, batch as usize);
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
                    (0..n).map(|i| (i * 37 % 200) as i64).collect(),
                )
                .unwrap()
                .into_tvalue(),
            }
        })
        .collect();
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
