//! Times an ONNX file on tract with random f32 inputs of the given shapes (profiling aid).
//!   cargo run --release --example onnx_time -- model.onnx 64x4x1x64 64x4x32x64
//! With ONNX_TIME_DUMP=file, also writes the first output as raw little-endian f32 (to check a form against
//! another backend fed the same inputs: element i of every input is ((i * 7919) % 1000) / 1000 - 0.5).
use std::time::Instant;
use tract_onnx::prelude::*;

fn main() -> TractResult<()> {
    let a: Vec<String> = std::env::args().collect();
    let shapes: Vec<Vec<usize>> = a[2..]
        .iter()
        .map(|s| s.split('x').map(|d| d.parse().unwrap()).collect())
        .collect();
    let mut model = tract_onnx::onnx().model_for_path(&a[1])?;
    for (i, s) in shapes.iter().enumerate() {
        model.set_input_fact(i, f32::fact(s).into())?;
    }
    let plan = model.into_optimized()?.into_runnable()?;
    let inputs: TVec<TValue> = shapes
        .iter()
        .map(|s| {
            let n: usize = s.iter().product();
            let v: Vec<f32> = (0..n)
                .map(|i| ((i * 7919 % 1000) as f32) / 1000.0 - 0.5)
                .collect();
            tract_ndarray::ArrayD::from_shape_vec(s.clone(), v)
                .unwrap()
                .into_tvalue()
        })
        .collect();
    if let Ok(path) = std::env::var("ONNX_TIME_DUMP") {
        let out = plan.run(inputs.clone())?;
        let v = out[0].to_plain_array_view::<f32>()?;
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(&path, bytes)?;
    }
    let mut ts = vec![];
    for _ in 0..300 {
        let t = Instant::now();
        let _ = plan.run(inputs.clone())?;
        ts.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ts.drain(..50);
    ts.sort_by(|x, y| x.partial_cmp(y).unwrap());
    println!("{}: median {:.3} ms", a[1], ts[ts.len() / 2]);
    Ok(())
}
