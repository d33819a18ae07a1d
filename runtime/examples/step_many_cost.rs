//! Where the time of one serve tick goes, for N LiveGesture streams stepped together: the graphs
//! with the caches stacked before and split after every graph (`step_batch`, the separately owned
//! streams), and the whole `MotionModel::step_many` the server calls (frontend, steps, frames, the
//! caches kept stacked in the model's cohort). Interleaved rounds, medians.
//!
//!   cargo run --release --example step_many_cost -- models/default ort 8,16,32 [rounds]
use std::time::Instant;

use livegesture::audio::read_wav_16k_mono;
use livegesture::backend::{self, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::model::livegesture::{LiveGestureGraphs, LiveGestureModel, StreamOptions};
use livegesture::model::{MotionModel, MotionStream, StreamJob};

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let bundle = Bundle::load(&a[1])?;
    let kind = match a[2].as_str() {
        "ort" => BackendKind::Ort,
        _ => BackendKind::Tract,
    };
    let ns: Vec<usize> = a[3].split(',').map(|s| s.parse().unwrap()).collect();
    let rounds: usize = a.get(4).map_or(30, |s| s.parse().unwrap());
    let be = backend::create(&BackendOptions {
        kind,
        execution_provider: "cpu".into(),
        intra_threads: 1,
        ort_library: None,
    })?;
    let audio = read_wav_16k_mono(bundle.dir().join("reference/clip.wav"))?;
    let tok = bundle.frontend().token_end(0) as usize;
    let graphs = LiveGestureGraphs::new(&bundle, be.as_ref())?;
    // mel blocks of the clip, one per token
    let mut s0 = graphs.new_stream(&StreamOptions::default())?;
    let mels = s0.push_audio(&audio)?;
    let model = LiveGestureModel::from(LiveGestureGraphs::new(&bundle, be.as_ref())?);
    println!(
        "| N | stack+split ms | step_many ms (frontend, frames) | per stream: split / step_many |"
    );
    println!("|---|---|---|---|");
    for &n in &ns {
        let opts = |i: usize| StreamOptions {
            seed: i as u64,
            ..Default::default()
        };
        let mut sep: Vec<_> = (0..n)
            .map(|i| graphs.new_stream(&opts(i)))
            .collect::<anyhow::Result<_>>()?;
        let mut streams: Vec<Box<dyn MotionStream>> = (0..n)
            .map(|i| model.new_stream(&opts(i)))
            .collect::<anyhow::Result<_>>()?;
        let (mut tb, mut tc) = (vec![], vec![]);
        for (pos, r) in (0..rounds + 3).enumerate() {
            let block: Vec<_> = (0..n)
                .map(|i| mels[(pos + i * 7) % mels.len()].clone())
                .collect();
            let mut refs: Vec<_> = sep.iter_mut().collect();
            let t = Instant::now();
            std::hint::black_box(graphs.step_batch(&mut refs, &block)?);
            let b_ms = t.elapsed().as_secs_f64() * 1e3;
            // one token of audio per stream, as the scheduler hands it over
            let chunks: Vec<&[f32]> = (0..n)
                .map(|i| {
                    let s = (pos * tok + i * 7919) % (audio.len() - tok);
                    &audio[s..s + tok]
                })
                .collect();
            let mut jobs: Vec<StreamJob> = streams
                .iter_mut()
                .zip(&chunks)
                .map(|(s, c)| StreamJob {
                    stream: s.as_mut(),
                    audio: c,
                    end: None,
                })
                .collect();
            let t = Instant::now();
            let out = model.step_many(&mut jobs);
            let c_ms = t.elapsed().as_secs_f64() * 1e3;
            for o in out {
                std::hint::black_box(o?);
            }
            if r >= 3 {
                tb.push(b_ms);
                tc.push(c_ms);
            }
        }
        let (b_, c_) = (median(&mut tb), median(&mut tc));
        let nf = n as f64;
        println!(
            "| {n} | {b_:.2} | {c_:.2} | {:.3} / {:.3} |",
            b_ / nf,
            c_ / nf
        );
    }
    Ok(())
}
