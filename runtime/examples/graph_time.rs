//! Times one graph of a bundle in a tight loop (pseudo-random data inputs, caches fed back), for profiling a
//! backend; `THRASH_MB=n` reads n MiB of other memory between runs, as the other graphs of a step do.
//!   cargo run --release --example graph_time -- models/default expert_upper 2 ort
//! `SYMBOLIC=1`: tract runs the plan with the batch left symbolic (what `serve` runs for more than
//! two rows and no prepared plan of its row count) instead of a plan optimised for this batch.
//! `PREPARED=1`: as `serve` prepares it (tract: the plan of the next row count of
//! [`livegesture::backend::tract::TRACT_ROW_BUCKETS`], the run padded to it).
//! Prints the median wall time and the median CPU time of the calling thread per run (one intra-op
//! thread: all of the run), which a shared core's preemptions do not inflate.
use std::time::Instant;

use livegesture::backend::{self, BackendKind, BackendOptions, Tensor};
use livegesture::bundle::{concrete_shape, Bundle};

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let bundle = Bundle::load(&a[1])?;
    let spec = bundle.graph(&a[2])?.clone();
    let batch: usize = a[3].parse()?;
    let kind = if a[4] == "ort" {
        BackendKind::Ort
    } else {
        BackendKind::Tract
    };
    let be = backend::create(&BackendOptions {
        kind,
        ..Default::default()
    })?;
    let g = be.load(&spec, &bundle.graph_path(&spec))?;
    if std::env::var_os("SYMBOLIC").is_some() {
        g.prepare_batches(&[])?;
    } else if std::env::var_os("PREPARED").is_some() {
        g.prepare_batches(&[batch])?;
    }
    let mut inputs: Vec<Tensor> = spec
        .all_inputs()
        .iter()
        .map(|(_, dt, shape)| Tensor::zeros(*dt, concrete_shape(shape, batch)))
        .collect();
    // pseudo-random data inputs (caches start at zero and are fed back)
    let mut seed = 0x9e3779b97f4a7c15u64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let n_data = spec.inputs.len();
    let n_out = spec.outputs.len();
    let mut outs = Vec::new();
    let mut ts = Vec::new();
    let mut cpu = Vec::new();
    // THRASH_MB=n: read n MiB of other memory between runs (what the other graphs of a step do to the caches)
    let thrash_mb: usize = std::env::var("THRASH_MB")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    let junk = vec![1.0f32; thrash_mb * 262144];
    let mut sink = 0.0f32;
    for _ in 0..400 {
        sink += junk.iter().step_by(16).sum::<f32>();
        for t in inputs[..n_data].iter_mut() {
            match &mut t.data {
                livegesture::backend::TensorData::F32(v) => {
                    v.iter_mut().for_each(|x| *x = (rnd() * 4.0 - 2.0) as f32)
                }
                livegesture::backend::TensorData::I64(v) => {
                    v.iter_mut().for_each(|x| *x = (rnd() * 200.0) as i64)
                }
            }
        }
        let c = thread_cpu_ms();
        let t = Instant::now();
        g.run_into(&inputs, &mut outs)?;
        ts.push(t.elapsed().as_secs_f64() * 1e3);
        cpu.push(thread_cpu_ms() - c);
        for (k, c) in outs[n_out..].iter_mut().enumerate() {
            std::mem::swap(&mut inputs[n_data + k], c);
        }
    }
    std::hint::black_box(sink);
    ts.drain(..100);
    cpu.drain(..100);
    ts.sort_by(|x, y| x.partial_cmp(y).unwrap());
    cpu.sort_by(|x, y| x.partial_cmp(y).unwrap());
    println!(
        "{} {} batch {batch}: median {:.3} ms (thread CPU median {:.3} ms)",
        a[4],
        a[2],
        ts[ts.len() / 2],
        cpu[cpu.len() / 2]
    );
    Ok(())
}

/// CPU time of the calling thread in ms (CLOCK_THREAD_CPUTIME_ID).
fn thread_cpu_ms() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid out-pointer for clock_gettime.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
}
