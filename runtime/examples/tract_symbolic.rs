//! tract: one plan kept symbolic in the batch (sizes resolved at run time) against one plan per
//! batch size (`set_symbols`, what the backend builds on first use): build time, run time and
//! output difference per graph and size.
//!   cargo run --release --example tract_symbolic -- models/default 1,8,32,64 [runs]
use std::collections::HashMap;
use std::time::Instant;

use livegesture::bundle::Bundle;
use tract_onnx::prelude::*;

fn inputs(spec: &livegesture::bundle::GraphSpec, batch: usize) -> TVec<TValue> {
    spec.all_inputs()
        .iter()
        .map(|(_, dt, shape)| {
            let s: Vec<usize> = livegesture::bundle::concrete_shape(shape, batch);
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
                    (0..n).map(|i| (i % 5) as i64).collect(),
                )
                .unwrap()
                .into_tvalue(),
            }
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> TractResult<()> {
    let a: Vec<String> = std::env::args().collect();
    let bundle = Bundle::load(&a[1])?;
    let sizes: Vec<usize> = a[2].split(',').map(|s| s.parse().unwrap()).collect();
    let runs: usize = a.get(3).map_or(20, |s| s.parse().unwrap());
    let lg = bundle.livegesture()?;
    let mut names = vec!["audio_encoder".to_string()];
    let forms = lg.form_graphs();
    let f = &forms[lg.default_form("tract")];
    names.extend(f.experts.iter().cloned());
    names.push(f.fusion.clone());
    names.extend(f.decoders.iter().cloned());
    println!("| graph | batch | build concrete ms | build symbolic ms | run concrete ms | run symbolic ms | max abs diff |");
    println!("|---|---|---|---|---|---|---|");
    for name in &names {
        let spec = bundle.graph(name)?.clone();
        let typed = tract_onnx::onnx()
            .model_for_path(bundle.graph_path(&spec))?
            .into_typed()?
            .into_decluttered()?;
        let t = Instant::now();
        let sym_plan = typed.clone().into_optimized()?.into_runnable()?;
        let build_sym = t.elapsed().as_secs_f64() * 1e3;
        let mut sym_state = sym_plan.spawn()?;
        let sym = typed.symbols.sym("batch");
        for &b in &sizes {
            let t = Instant::now();
            let plan = typed
                .set_symbols(&HashMap::from([(sym.clone(), TDim::Val(b as i64))]))?
                .into_optimized()?
                .into_runnable()?;
            let build = t.elapsed().as_secs_f64() * 1e3;
            let mut state = plan.spawn()?;
            let inp = inputs(&spec, b);
            let (mut tc, mut ts) = (vec![], vec![]);
            let (mut oc, mut os) = (tvec![], tvec![]);
            for _ in 0..runs {
                let t = Instant::now();
                oc = state.run(inp.clone())?;
                tc.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                os = sym_state.run(inp.clone())?;
                ts.push(t.elapsed().as_secs_f64() * 1e3);
            }
            let mut diff = 0f32;
            for (x, y) in oc.iter().zip(&os) {
                if let (Ok(x), Ok(y)) = (
                    x.to_plain_array_view::<f32>(),
                    y.to_plain_array_view::<f32>(),
                ) {
                    for (p, q) in x.iter().zip(y.iter()) {
                        diff = diff.max((p - q).abs());
                    }
                }
            }
            println!(
                "| {name} | {b} | {build:.0} | {build_sym:.0} | {:.3} | {:.3} | {diff:.2e} |",
                median(tc),
                median(ts)
            );
        }
    }
    Ok(())
}
