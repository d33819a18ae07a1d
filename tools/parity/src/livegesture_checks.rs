//! The LiveGesture family's checks (docs/parity.md): every graph, the log-mel frontend, the seeded
//! rollout (with the divergence analysis and the other forms), the chunk and batch invariances. The
//! suite's [`super::run`] reaches them through [`livegesture::model::for_family`], as it reaches
//! DiffSHEG's (`diffsheg.rs`).

use std::fs::File;
use std::time::Instant;

use anyhow::Result;
use ndarray::Array2;
use ndarray_npy::ReadNpyExt;

use livegesture::audio::{read_wav_16k_mono, AudioSpan};
use livegesture::backend::{Backend, BackendKind};
use livegesture::bundle::Bundle;
use livegesture::frontend::logmel;
use livegesture::model::livegesture::{LiveGestureGraphs, LiveGestureModel};
use livegesture::model::GraphForm;

use super::compare::MaxAbs;
use super::graphs::graph_rows;
use super::invariance::{batch_rows, chunk_rows};
use super::rollout::rollout_rows;
use super::{ref_err, Check, Divergence, ParityOptions, Row, BATCH_SIZES, CHUNK_SIZES, LOGMEL};

/// The pipelines the rollout, chunk and batch checks step: one per backend in the form it runs,
/// and the canonical form on each backend that runs another.
type Pipelines = Vec<(BackendKind, LiveGestureGraphs)>;

/// Runs the LiveGesture checks that `opts` asks for; rows, notes and divergences are appended.
pub(super) fn run(
    bundle: &Bundle,
    backends: &[(BackendKind, Box<dyn Backend>)],
    opts: &ParityOptions,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
    divergences: &mut Vec<Divergence>,
    log: &mut dyn FnMut(&str),
) -> Result<()> {
    let want = |c: Check| opts.checks.contains(&c);
    let clip_rel = bundle.reference_clip();
    let clip_path = bundle.path(&clip_rel);
    let need_clip = [Check::Rollout, Check::Logmel, Check::Chunks, Check::Batch]
        .into_iter()
        .any(want);
    let clip = if need_clip {
        read_wav_16k_mono(&clip_path).map_err(|e| ref_err(&clip_path, e))?
    } else {
        Vec::new()
    };

    if want(Check::Graph) {
        let t = Instant::now();
        for g in bundle.graphs() {
            graph_rows(bundle, g, backends, rows)?;
        }
        log(&format!(
            "graphs: {} graphs on {} in {:.1} s",
            bundle.graphs().len(),
            backends
                .iter()
                .map(|(k, _)| k.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            t.elapsed().as_secs_f64()
        ));
    }

    if want(Check::Logmel) {
        logmel_row(bundle, &clip, rows)?;
    }
    let (mut pipelines, mut other_forms) = load_pipelines(bundle, backends, opts, rows, notes)?;
    if want(Check::Rollout) {
        rollout_rows(
            bundle,
            &mut pipelines,
            &mut other_forms,
            &clip,
            rows,
            notes,
            divergences,
            opts.target,
            log,
        )?;
    }
    let seed = bundle.reference().and_then(|r| r.rollout_seed).unwrap_or(0);
    let prefix_len = ((opts.chunk_seconds * 16000.0).round() as usize).clamp(1, clip.len().max(1));
    if want(Check::Chunks) {
        let t = Instant::now();
        let prefix = &clip[..prefix_len.min(clip.len())];
        notes.push(format!(
            "chunks: on the first {:.2} s of reference/clip.wav ({} samples, {} tokens, finished to {} frames), chunk sizes {:?} samples vs the whole prefix at once",
            prefix.len() as f64 / 16000.0,
            prefix.len(),
            bundle.frontend().n_tokens(prefix.len() as u64),
            AudioSpan::at_16k(prefix.len() as u64).frames(bundle.frontend().fps),
            CHUNK_SIZES
        ));
        for (k, p) in pipelines.iter_mut() {
            chunk_rows(p, *k, prefix, seed, rows);
        }
        log(&format!("chunks: {:.1} s", t.elapsed().as_secs_f64()));
    }
    if want(Check::Batch) {
        let t = Instant::now();
        notes.push(format!(
            "batch: {} streams of {:.2} s from different offsets of reference/clip.wav with different seeds (stream 3 without guidance), batch sizes {:?} vs separate runs",
            BATCH_SIZES.iter().max().unwrap_or(&1),
            prefix_len as f64 / 16000.0,
            BATCH_SIZES
        ));
        // the last check: the pipelines become models (their `step_many`, the path `serve` runs)
        for (k, p) in std::mem::take(&mut pipelines) {
            batch_rows(&LiveGestureModel::from(p), k, &clip, prefix_len, seed, rows);
        }
        log(&format!("batch: {:.1} s", t.elapsed().as_secs_f64()));
    }
    Ok(())
}

/// The log-mel frontend against the Python frontend's `reference/logmel.npy` (one row).
fn logmel_row(bundle: &Bundle, clip: &[f32], rows: &mut Vec<Row>) -> Result<()> {
    let rel = "reference/logmel.npy";
    let path = bundle.path(rel);
    let f = File::open(&path).map_err(|e| ref_err(&path, format!("cannot open: {e}")))?;
    let want_mel = Array2::<f32>::read_npy(f).map_err(|e| ref_err(&path, e))?;
    match logmel(clip, bundle.frontend()) {
        Ok(got) => {
            // docs/parity.md: the frontend's bound is absolute (max abs 1e-4), judged at scale 1
            let mut m = MaxAbs::absolute();
            if got.dim() != want_mel.dim() {
                m.problem = Some(format!(
                    "{} frames x {} mels vs Python {} x {}",
                    got.nrows(),
                    got.ncols(),
                    want_mel.nrows(),
                    want_mel.ncols()
                ));
                m.err = f64::INFINITY;
            } else {
                // one comparison per token's mel frames
                let mpt = (bundle.frontend().mel_frames_per_token as usize).max(1);
                let bands = got.ncols().max(1);
                let (g, w) = (got.as_standard_layout(), want_mel.as_standard_layout());
                let (g, w) = (g.as_slice().unwrap_or(&[]), w.as_slice().unwrap_or(&[]));
                for (t, (a, b)) in g.chunks(mpt * bands).zip(w.chunks(mpt * bands)).enumerate() {
                    m.add_slices(t as u64, a, b, |i| {
                        format!("mel frame {}, band {}", t * mpt + i / bands, i % bands)
                    });
                }
            }
            rows.push(Row::max_abs(
                Check::Logmel,
                "clip.wav",
                "rust vs python",
                "log-mel",
                &m,
                LOGMEL,
            ));
        }
        Err(e) => rows.push(Row::failed(
            Check::Logmel,
            "clip.wav",
            "rust vs python",
            "log-mel",
            LOGMEL,
            format!("{e:#}"),
        )),
    }
    Ok(())
}

/// The pipelines of the rollout, chunk and batch checks (a backend that cannot load its form gets
/// a failed row instead), and the canonical form on each backend that runs another form.
fn load_pipelines(
    bundle: &Bundle,
    backends: &[(BackendKind, Box<dyn Backend>)],
    opts: &ParityOptions,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
) -> Result<(Pipelines, Pipelines)> {
    let want = |c: Check| opts.checks.contains(&c);
    let need_pipeline = [Check::Rollout, Check::Chunks, Check::Batch]
        .into_iter()
        .any(want);
    let mut pipelines: Pipelines = Vec::new();
    if need_pipeline {
        for (k, be) in backends {
            match LiveGestureGraphs::with_form(bundle, be.as_ref(), opts.form) {
                Ok(p) => pipelines.push((*k, p)),
                Err(e) => rows.push(Row::failed(
                    Check::Rollout,
                    "pipeline",
                    k.to_string(),
                    "(all)",
                    0.0,
                    format!("{k} could not load the pipeline: {e:#}"),
                )),
            }
        }
    }
    // docs/bundle.md#forms-and-precision: a backend that runs a form other than canonical (the bundle's `backend_forms`, or
    // `--form`) is checked against the canonical form on the rollout, on that backend. A backend that
    // runs the canonical form is checked by the other rows; the other forms are checked on it only
    // when `--form` makes it run them.
    let mut other_forms: Pipelines = Vec::new();
    if want(Check::Rollout) {
        let forms = bundle.livegesture()?.expert_forms();
        for (k, be) in backends {
            let Some(main) = pipelines
                .iter()
                .find(|(x, _)| x == k)
                .map(|(_, p)| p.form())
            else {
                continue;
            };
            if main == "canonical" {
                if forms.len() > 1 {
                    notes.push(format!(
                        "forms: {k} runs the canonical form; the bundle's other forms ({}) are not run on {k} (`--form` chooses one)",
                        forms
                            .keys()
                            .filter(|f| f.as_str() != "canonical")
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                }
                continue;
            }
            for f in forms.keys().filter(|f| f.as_str() == "canonical") {
                let choice: GraphForm = f.parse().map_err(|e: String| anyhow::anyhow!(e))?;
                match LiveGestureGraphs::with_form(bundle, be.as_ref(), choice) {
                    Ok(p) => other_forms.push((*k, p)),
                    Err(e) => rows.push(Row::failed(
                        Check::Rollout,
                        format!("rollout ({main} form)"),
                        k.to_string(),
                        "(all)",
                        0.0,
                        format!("{k} could not load the {f} form: {e:#}"),
                    )),
                }
            }
        }
    }
    Ok((pipelines, other_forms))
}
