//! Chunk-size and batch invariance: the same frames however the audio is chunked or streams batched.

use super::*;

pub(super) fn chunk_rows(
    p: &mut LiveGestureGraphs,
    kind: BackendKind,
    audio: &[f32],
    seed: u64,
    rows: &mut Vec<Row>,
) {
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let comparison = format!("{kind}: chunked vs whole");
    let whole = match run_stream(p, &opts, audio, audio.len(), true) {
        Ok(w) => w,
        Err(e) => {
            rows.push(Row::failed(
                Check::Chunks,
                "whole prefix",
                comparison,
                "frames",
                0.0,
                format!("{e:#}"),
            ));
            return;
        }
    };
    let whole_tokens: Vec<Vec<i64>> = whole.iter().map(|s| s.tokens.clone()).collect();
    for chunk in CHUNK_SIZES {
        let what = if chunk == 1 {
            "chunk 1 sample".to_string()
        } else {
            format!("chunk {chunk}")
        };
        match run_stream(p, &opts, audio, chunk, true) {
            Ok(got) => {
                let tokens: Vec<Vec<i64>> = got.iter().map(|s| s.tokens.clone()).collect();
                rows.push(token_row(
                    Check::Chunks,
                    &what,
                    &comparison,
                    &tokens,
                    &whole_tokens,
                    None,
                ));
                let n = got.len().min(whole.len());
                frame_rows_steps(
                    Check::Chunks,
                    &what,
                    &comparison,
                    &[(String::new(), &got[..n], &whole[..n])],
                    0.0,
                    rows,
                );
            }
            Err(e) => rows.push(Row::failed(
                Check::Chunks,
                what,
                comparison.clone(),
                "frames",
                0.0,
                format!("{e:#}"),
            )),
        }
    }
}

pub(super) fn batch_rows(
    model: &LiveGestureModel,
    kind: BackendKind,
    clip: &[f32],
    len: usize,
    seed: u64,
    rows: &mut Vec<Row>,
) {
    let n_streams = *BATCH_SIZES.iter().max().unwrap_or(&1);
    // different seeds and audio (offsets into the clip); stream 3 runs without guidance
    let streams: Vec<(StreamOptions, Vec<f32>)> = (0..n_streams)
        .map(|i| {
            let off = (i * 7919 * 3) % clip.len().saturating_sub(len).max(1);
            let opts = StreamOptions {
                seed: seed.wrapping_add(i as u64 * 1000 + 1),
                guidance: (i == 3).then_some(1.0),
                ..Default::default()
            };
            let end = (off + len).min(clip.len());
            (opts, clip[off..end].to_vec())
        })
        .collect();
    let comparison = format!("{kind}: batched vs separate");
    let bound = batch_bound(kind);
    let mut single = Vec::new();
    for (o, a) in &streams {
        match run_stream(model.graphs(), o, a, 3200, false) {
            Ok(s) => single.push(s),
            Err(e) => {
                rows.push(Row::failed(
                    Check::Batch,
                    "separate runs",
                    comparison,
                    "frames",
                    bound,
                    format!("{e:#}"),
                ));
                return;
            }
        }
    }
    for b in BATCH_SIZES {
        let what = format!("batch {b}");
        match run_batched(model, &streams[..b], 3200) {
            Ok(batched) => {
                let (mut differing, mut compared, mut first) = (0u64, 0u64, None);
                let mut pairs = Vec::new();
                for (i, (g, w)) in batched.iter().zip(&single).enumerate() {
                    let n = g.len().min(w.len());
                    compared += g.len().max(w.len()) as u64;
                    differing += (g.len().max(w.len()) - n) as u64;
                    for (x, y) in g.iter().zip(w) {
                        if x.tokens != y.tokens {
                            differing += 1;
                            first.get_or_insert((
                                i,
                                x.token_index,
                                x.tokens.clone(),
                                y.tokens.clone(),
                            ));
                        }
                    }
                    if g.len() != w.len() {
                        first.get_or_insert((i, n as u64, Vec::new(), Vec::new()));
                    }
                    pairs.push((format!("stream {i}, "), &g[..n], &w[..n]));
                }
                rows.push(Row {
                    check: Check::Batch,
                    what: what.clone(),
                    comparison: comparison.clone(),
                    output: "tokens".into(),
                    step: first.as_ref().map(|f| f.1),
                    metric: Metric::DifferingSteps,
                    error: differing as f64,
                    compared,
                    bound: 0.0,
                    scale: 1.0,
                    pass: differing == 0 && compared > 0,
                    detail: first.map(|(i, t, a, b)| {
                        format!(
                            "stream {i} first differs at step {t}: batched {a:?} vs separate {b:?}"
                        )
                    }),
                });
                frame_rows_steps(Check::Batch, &what, &comparison, &pairs, bound, rows);
            }
            Err(e) => rows.push(Row::failed(
                Check::Batch,
                what,
                comparison.clone(),
                "frames",
                bound,
                format!("{e:#}"),
            )),
        }
    }
}

/// Steps `streams` together with [`LiveGestureModel::step_many_steps`] (the path `serve` runs as
/// `step_many`), feeding each its audio in `chunk`s: every call pushes one chunk into every stream.
pub(super) fn run_batched(
    model: &LiveGestureModel,
    streams: &[(StreamOptions, Vec<f32>)],
    chunk: usize,
) -> Result<Vec<Vec<TokenStep>>> {
    let mut st = streams
        .iter()
        .map(|(o, _)| model.new_stream(o))
        .collect::<Result<Vec<_>>>()?;
    let mut out: Vec<Vec<TokenStep>> = vec![Vec::new(); streams.len()];
    let len = streams.iter().map(|(_, a)| a.len()).min().unwrap_or(0);
    let mut pos = 0;
    while pos < len {
        let end = (pos + chunk).min(len);
        let mut jobs: Vec<StreamJob<'_>> = st
            .iter_mut()
            .zip(streams)
            .map(|(s, (_, a))| StreamJob::push(s.as_mut(), &a[pos..end]))
            .collect();
        for (i, r) in model.step_many_steps(&mut jobs).into_iter().enumerate() {
            out[i].extend(r?);
        }
        pos = end;
    }
    Ok(out)
}

#[cfg(test)]
#[path = "invariance_tests.rs"]
mod tests;
