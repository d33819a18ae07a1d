//! The parity checks of a DiffSHEG bundle (docs/diffsheg.md, docs/parity.md; docs/bundle.md "DiffSHEG bundles").
//!
//! | check | what | bound |
//! |---|---|---|
//! | `graph` | `speech_encoder`, `denoiser`: every call of `reference/<graph>.npz` (batches 2, 3, 1, 2; lengths N, shorter, L+1): ort vs torch, tract vs ort, tract vs torch | [`ORT_VS_TORCH`], [`TRACT_VS_ORT`], [`TRACT_VS_TORCH`] |
//! | `rollout` | the seeded FOPPAS rollout over `reference/rollout.npz`'s audio with its seed, speaker and options, on each backend vs torch and tract vs ort: normalised motion, poses, trans, expressions, foot contact; the window plan and noise positions | [`ROLLOUT_MOTION`], [`ROLLOUT_FRAMES`]; windows and noise positions exact |
//! | `rollout` | window 1's per-call trace (`window1.trace{c}`): `x` and `t` of every recorded call on each backend vs torch, and the torch trace replayed through the Rust sampler (exact) | [`TRACE_X`], exact |
//! | `logmel` | every window's log-mel input, Rust frontend vs Python | [`LOGMEL`] |
//! | `chunks` | the rollout audio pushed in chunks of 1 sample, 160 (10 ms), 3200 (200 ms), 16000 (1 s) samples vs the whole file at once: identical frames | exact |
//!
//! Bounds of the rollout: the sampler itself is exact given the graph outputs (the replay row shows
//! it), but graph differences of ~1e-6 (plus the Rust log-mel frontend's ~1e-5 on the encoder input)
//! pass through 25 x 2 chained DDIM passes per window and the overlap carried to the next window. The
//! bounds below are docs/parity.md's rollout bound (1e-4, scaled by the reference's magnitude), above
//! what the bundles measure (see [`ROLLOUT_MOTION`]); the manifest's `checks.rollout` records the
//! torch-vs-onnxruntime value of the Python exporter for comparison. ort: its backend does not yet run graphs whose outputs have a named
//! `frames` axis (it preallocates outputs), so its rows fail with that reason.

use std::sync::Arc;

use super::*;
use livegesture::model::diffsheg::foppas::{
    plan_windows, SamplerOptions, WindowSampler, MOTION_DIM,
};
use livegesture::model::diffsheg::model::DiffshegModel;
use livegesture::model::diffsheg::noise::NoiseStream;
use livegesture::model::diffsheg::reference::RolloutReference;
use livegesture::model::diffsheg::stream::WindowRecord;
use livegesture::model::{MotionStream, StreamOptions};

/// Rollout, normalised motion (the sampler's x), any backend vs torch or vs each other: docs/parity.md's
/// rollout frame bound, scaled by the reference's magnitude. Measured on the tiny bundle (5 windows x 5
/// steps x 2 jumps, 2026-11-23): tract vs torch 9.5e-7; on `models/diffsheg` (25 x 2 passes per window):
/// ort vs torch 6.1e-6, tract vs ort 6.2e-6 (2026-11-25).
pub const ROLLOUT_MOTION: f64 = 1e-4;
/// Rollout, de-normalised frames (poses as axis-angle, trans, expressions, foot contact), scaled;
/// measured tract vs torch on the tiny bundle: poses 1.6e-5, trans 5.4e-7, expressions 6.0e-7, foot
/// contact 4.2e-7.
pub const ROLLOUT_FRAMES: f64 = 1e-4;
/// Window 1's traced denoiser inputs x, any backend vs torch (scaled).
pub const TRACE_X: f64 = 1e-4;
/// Chunk sizes of the chunk-invariance check (samples): 1 sample, 10 ms, 200 ms, 1 s.
pub const CHUNK_SIZES: [usize; 4] = [1, 160, 3200, 16000];

fn max_abs_f32(got: &[f32], want: &[f32], width: usize, step: u64) -> MaxAbs {
    let mut m = MaxAbs::default();
    m.add_slices(step, got, want, |i| {
        format!("frame {}, feature {}", i / width.max(1), i % width.max(1))
    });
    m
}

/// Folds `other` into `acc` (keeps the worst).
fn fold(acc: &mut MaxAbs, other: MaxAbs) {
    acc.merge(other);
}

/// One backend's run of the reference rollout.
struct Run {
    kind: BackendKind,
    frames: Vec<Frame>,
    motion: Vec<f32>,
    records: Vec<WindowRecord>,
}

pub(super) fn rollout_options(bundle: &Bundle, path: &Path) -> Result<(SamplerOptions, i64)> {
    let d = bundle.diffsheg()?;
    let raw: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(bundle.manifest_path()).context("reading manifest.json")?,
    )?;
    let ro = &raw["reference"]["rollout_options"];
    let get = |k: &str| -> Result<usize> {
        ro[k].as_u64().map(|v| v as usize).ok_or_else(|| {
            anyhow::Error::new(ref_err(
                path,
                format!("manifest reference.rollout_options.{k} is missing"),
            ))
        })
    };
    let o = SamplerOptions {
        steps: get("steps")?,
        guidance: ro["guidance"].as_f64().ok_or_else(|| {
            ref_err(
                path,
                "manifest reference.rollout_options.guidance is missing",
            )
        })?,
        window: get("window")?,
        overlap: get("overlap")?,
        jumps: get("jumps")?,
        blend_steps: get("blend_steps")?,
    };
    o.validate(&d.schedule, d.foppas.max_window)?;
    let speaker = raw["reference"]["rollout_speaker"].as_i64().unwrap_or(0);
    Ok((o, speaker))
}

pub(super) fn stream_options(o: &SamplerOptions, seed: u64, speaker: i64) -> StreamOptions {
    StreamOptions {
        seed,
        guidance: Some(o.guidance),
        ddim_steps: Some(o.steps),
        window: Some(o.window),
        overlap: Some(o.overlap),
        jumps: Some(o.jumps),
        blend_steps: Some(o.blend_steps),
        speaker: Some(speaker as usize),
        ..Default::default()
    }
}

/// Pushes `audio` in chunks of `chunk` samples, then finishes at its 16 kHz length.
pub fn run_chunked(
    stream: &mut dyn MotionStream,
    audio: &[f32],
    chunk: usize,
) -> Result<Vec<Frame>> {
    let mut frames = Vec::new();
    for c in audio.chunks(chunk.max(1)) {
        frames.extend(stream.push_audio(c)?);
    }
    frames.extend(stream.finish(AudioSpan::at_16k(audio.len() as u64))?);
    Ok(frames)
}

fn frame_fields(f: &Frame) -> [(&'static str, &[f32]); 4] {
    [
        ("poses", &f.poses[..]),
        ("trans", &f.trans[..]),
        ("expressions", &f.expressions[..]),
        ("foot_contact", &f.foot_contact[..]),
    ]
}

/// The frames as one (T, width) array per field, in [`frame_fields`] order.
fn field_arrays(frames: &[Frame]) -> Vec<(&'static str, Vec<f32>)> {
    FIELD_NAMES
        .iter()
        .enumerate()
        .map(|(k, &name)| {
            let data = frames
                .iter()
                .flat_map(|f| frame_fields(f)[k].1.iter().copied())
                .collect();
            (name, data)
        })
        .collect()
}

/// The frame fields compared, in [`frame_fields`] order.
const FIELD_NAMES: [&str; 4] = ["poses", "trans", "expressions", "foot_contact"];

/// The rollout rows of one run against a reference (Python's, or another backend's run): the
/// normalised motion and each frame field.
fn rollout_rows(
    rows: &mut Vec<Row>,
    cmp: &str,
    run: &Run,
    motion_ref: &[f32],
    fields_ref: &[(&'static str, Vec<f32>)],
) {
    let m = max_abs_f32(&run.motion, motion_ref, MOTION_DIM, 0);
    rows.push(Row::max_abs(
        Check::Rollout,
        "rollout",
        cmp.to_string(),
        "motion (normalised)",
        &m,
        ROLLOUT_MOTION,
    ));
    for (name, m) in frames_vs(&run.frames, fields_ref) {
        rows.push(Row::max_abs(
            Check::Rollout,
            "rollout",
            cmp.to_string(),
            name,
            &m,
            ROLLOUT_FRAMES,
        ));
    }
}

/// Frames vs arrays of (T, width) per field (in [`FIELD_NAMES`] order), one MaxAbs per field.
fn frames_vs(frames: &[Frame], want: &[(&'static str, Vec<f32>)]) -> Vec<(&'static str, MaxAbs)> {
    let got = field_arrays(frames);
    want.iter()
        .zip(&got)
        .map(|((name, w), (_, g))| {
            let width = w.len() / frames.len().max(1);
            (*name, max_abs_f32(g, w, width, 0))
        })
        .collect()
}

/// The DiffSHEG checks (module docs); rows and notes are appended.
// long: the DiffSHEG checks in the order of docs/parity.md, each a short block adding its rows; to split into one function per check
pub(super) fn run(
    bundle: &Bundle,
    backends: &[(BackendKind, Box<dyn Backend>)],
    opts: &ParityOptions,
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
    log: &mut dyn FnMut(&str),
) -> Result<()> {
    let want = |c: Check| opts.checks.contains(&c);
    if want(Check::Graph) {
        let t = Instant::now();
        for g in bundle.graphs() {
            // the face graph (docs/face.md) is a step graph with caches, checked as the LiveGesture graphs are
            if g.caches.is_empty() {
                graph_calls(bundle, g, backends, rows)?;
            } else {
                super::graphs::graph_rows(bundle, g, backends, rows)?;
            }
        }
        log(&format!("graphs: {:.1} s", t.elapsed().as_secs_f64()));
    }
    if !(want(Check::Rollout) || want(Check::Logmel) || want(Check::Chunks)) {
        return Ok(());
    }
    let rel = bundle.reference_rollout();
    let path = bundle.path(&rel);
    let mut reference =
        RolloutReference::open(&path).map_err(|e| ref_err(&path, format!("{e:#}")))?;
    let r = |e: anyhow::Error| ref_err(&path, format!("{e:#}"));
    let audio = reference.f32("audio").map_err(r)?.data;
    let seed = reference.scalar("seed").map_err(r)?;
    let t_frames = reference.scalar("frames").map_err(r)? as usize;
    let windows = reference.windows().map_err(r)?;
    let motion_ref = reference.f32("motion").map_err(r)?.data;
    let mut fields_ref = Vec::new();
    for k in FIELD_NAMES {
        fields_ref.push((k, reference.f32(k).map_err(r)?.data));
    }
    let (so, speaker) = rollout_options(bundle, &path)?;
    let sopts = stream_options(&so, seed, speaker);
    notes.push(format!(
        "rollout: reference/rollout.npz audio ({} samples, {} frames, {} windows), seed {seed}, speaker {speaker}, \
         {} DDIM steps, guidance {}, window {}, overlap {}, jumps {}, blend steps {}",
        audio.len(),
        t_frames,
        windows.len(),
        so.steps,
        so.guidance,
        so.window,
        so.overlap,
        so.jumps,
        so.blend_steps
    ));

    let mut models: Vec<(BackendKind, DiffshegModel)> = Vec::new();
    for (k, be) in backends {
        match DiffshegModel::load(bundle, be.as_ref()) {
            Ok(m) => models.push((*k, m)),
            Err(e) => rows.push(Row::failed(
                Check::Rollout,
                "model",
                k.to_string(),
                "(all)",
                0.0,
                format!("{k} could not load the DiffSHEG model: {e:#}"),
            )),
        }
    }

    // the sampler alone: the torch trace of window 1 replayed through the Rust sampler
    if want(Check::Rollout) {
        rows.push(replay_row(bundle, &mut reference, &so, seed, &path)?);
    }

    let mut runs: Vec<Run> = Vec::new();
    for (k, m) in &models {
        let t = Instant::now();
        let res = (|| -> Result<Run> {
            let mut s = m.stream(&sopts, true)?;
            let frames = run_chunked(&mut s, &audio, audio.len().max(1))?;
            let records = s.foppas().records().to_vec();
            let mut motion = Vec::with_capacity(t_frames * MOTION_DIM);
            for w in &records {
                motion.extend_from_slice(&w.x0[..w.emitted * MOTION_DIM]);
            }
            Ok(Run {
                kind: *k,
                frames,
                motion,
                records,
            })
        })();
        match res {
            Ok(run) => runs.push(run),
            Err(e) => rows.push(Row::failed(
                Check::Rollout,
                "rollout",
                format!("{k} vs torch"),
                "(all)",
                ROLLOUT_FRAMES,
                format!("{e:#}"),
            )),
        }
        log(&format!(
            "rollout on {k}: {:.1} s",
            t.elapsed().as_secs_f64()
        ));
    }

    for run in &runs {
        let cmp = format!("{} vs torch", run.kind);
        if want(Check::Rollout) {
            // the window plan and noise positions are exact
            let plan = plan_windows(t_frames, so.window, so.overlap);
            let got: Vec<[u64; 6]> = run
                .records
                .iter()
                .map(|w| {
                    [
                        w.start as u64,
                        w.n as u64,
                        w.emitted as u64,
                        w.overlap_in as u64,
                        w.noise_start,
                        w.noise_end,
                    ]
                })
                .collect();
            let same = got == windows && plan.len() == windows.len();
            rows.push(Row {
                check: Check::Rollout,
                what: "windows".into(),
                comparison: cmp.clone(),
                output: "start, n, emitted, overlap, noise positions".into(),
                step: None,
                metric: Metric::MaxAbs,
                error: if same { 0.0 } else { f64::INFINITY },
                compared: windows.len() as u64,
                bound: 0.0,
                scale: 1.0,
                pass: same && !windows.is_empty(),
                detail: (!same).then(|| format!("rust {got:?} vs python {windows:?}")),
            });
            if run.frames.len() != t_frames {
                rows.push(Row::failed(
                    Check::Rollout,
                    "rollout",
                    cmp.clone(),
                    "frames",
                    0.0,
                    format!("{} frames, expected {t_frames}", run.frames.len()),
                ));
            }
            rollout_rows(rows, &cmp, run, &motion_ref, &fields_ref);
            // window 1's trace
            if let Some(trace) = run.records.get(1).and_then(|w| w.trace.as_ref()) {
                let calls = reference.scalar("window1.trace.calls").map_err(r)? as usize;
                let mut mx = MaxAbs::default();
                let mut problem = None;
                if trace.len() != calls {
                    problem = Some(format!("{} calls, the reference has {calls}", trace.len()));
                }
                for c in (0..calls).filter(|&c| c < 4 || c + 1 == calls) {
                    let x = reference
                        .f32(&format!("window1.trace{c}.x"))
                        .map_err(r)?
                        .data;
                    let t = reference
                        .scalar(&format!("window1.trace{c}.t"))
                        .map_err(r)? as i64;
                    match trace.get(c) {
                        Some(tc) => {
                            if tc.t != t {
                                problem = Some(format!("call {c}: t = {} vs {t}", tc.t));
                            }
                            fold(&mut mx, max_abs_f32(&tc.x, &x, MOTION_DIM, c as u64));
                        }
                        None => problem = Some(format!("call {c} missing")),
                    }
                }
                if problem.is_some() {
                    mx.problem = problem;
                    mx.err = f64::INFINITY;
                }
                rows.push(Row::max_abs(
                    Check::Rollout,
                    "window 1 trace",
                    cmp.clone(),
                    "x (denoiser input)",
                    &mx,
                    TRACE_X,
                ));
                // x_T of window 1 is pure noise: exact on every backend
                if let Some(tc) = trace.first() {
                    let x = reference.f32("window1.trace0.x").map_err(r)?.data;
                    let m = max_abs_f32(&tc.x, &x, MOTION_DIM, 0);
                    rows.push(Row::max_abs(
                        Check::Rollout,
                        "window 1 trace",
                        cmp.clone(),
                        "x_T (noise)",
                        &m,
                        0.0,
                    ));
                }
            }
        }
        if want(Check::Logmel) {
            // docs/parity.md: the frontend's bound is absolute (max abs 1e-4), judged at scale 1
            let mut mx = MaxAbs::absolute();
            let bands = bundle.frontend().n_mels.max(1);
            for (k, w) in run.records.iter().enumerate() {
                let want_mel = reference.f32(&format!("window{k}.mel")).map_err(r)?.data;
                mx.add_slices(k as u64, &w.mel, &want_mel, |i| {
                    format!("window {k}, mel frame {}, band {}", i / bands, i % bands)
                });
            }
            rows.push(Row::max_abs(
                Check::Logmel,
                "window mels",
                format!("rust vs python ({})", run.kind),
                "log-mel",
                &mx,
                LOGMEL,
            ));
        }
    }
    // backends against each other
    if want(Check::Rollout) && runs.len() == 2 {
        let (a, b) = (&runs[1], &runs[0]);
        let cmp = format!("{} vs {}", a.kind, b.kind);
        rollout_rows(rows, &cmp, a, &b.motion, &field_arrays(&b.frames));
    }

    if want(Check::Chunks) {
        let t = Instant::now();
        notes.push(format!(
            "chunks: the rollout audio ({:.2} s) in chunks of {CHUNK_SIZES:?} samples vs the whole file at once, finished to {t_frames} frames",
            audio.len() as f64 / 16000.0
        ));
        for (k, m) in &models {
            let whole = match runs.iter().find(|r| r.kind == *k) {
                Some(r) => r.frames.clone(),
                None => continue,
            };
            for chunk in CHUNK_SIZES {
                let what = match chunk {
                    1 => "chunk 1 sample".to_string(),
                    c => format!("chunk {c} ({} ms)", c / 16),
                };
                let cmp = format!("{k}: chunked vs whole");
                let res = m
                    .stream(&sopts, false)
                    .and_then(|mut s| run_chunked(&mut s, &audio, chunk));
                match res {
                    Ok(frames) => {
                        let mut mx = MaxAbs::default();
                        if frames.len() != whole.len() {
                            mx.problem =
                                Some(format!("{} frames vs {}", frames.len(), whole.len()));
                            mx.err = f64::INFINITY;
                        }
                        for (_, m) in frames_vs(&frames, &field_arrays(&whole)) {
                            fold(&mut mx, m);
                        }
                        rows.push(Row::max_abs(Check::Chunks, what, cmp, "frames", &mx, 0.0));
                    }
                    Err(e) => rows.push(Row::failed(
                        Check::Chunks,
                        what,
                        cmp,
                        "frames",
                        0.0,
                        format!("{e:#}"),
                    )),
                }
            }
        }
        log(&format!("chunks: {:.1} s", t.elapsed().as_secs_f64()));
    }
    Ok(())
}

/// The torch trace of window 1 through the Rust sampler: every recorded call's x (calls 1-3 from the
/// previous calls' eps and the noise) and the window's result from the last call, bit for bit.
fn replay_row(
    bundle: &Bundle,
    reference: &mut RolloutReference,
    so: &SamplerOptions,
    seed: u64,
    path: &Path,
) -> Result<Row> {
    let r = |e: anyhow::Error| ref_err(path, format!("{e:#}"));
    let d = bundle.diffsheg()?;
    let schedule = Arc::new(d.schedule.clone());
    let windows = reference.windows().map_err(r)?;
    let w1 = windows
        .get(1)
        .ok_or_else(|| ref_err(path, "the rollout has fewer than 2 windows"))?;
    let n = w1[1] as usize;
    let known = reference.f32("window1.known").map_err(r)?.data;
    let calls = reference.scalar("window1.trace.calls").map_err(r)? as usize;
    let noise = NoiseStream {
        seed,
        position: w1[4],
    };
    let mut mx = MaxAbs::default();
    let mut w = WindowSampler::new(n, Some(&known), *so, schedule.clone(), noise)?;
    for c in 0..calls.min(4) {
        let x = reference
            .f32(&format!("window1.trace{c}.x"))
            .map_err(r)?
            .data;
        let eps = reference
            .f64(&format!("window1.trace{c}.eps"))
            .map_err(r)?
            .data;
        let call = w.next_call().context("the sampler asked for fewer calls")?;
        fold(&mut mx, max_abs_f32(call.x, &x, MOTION_DIM, c as u64));
        w.feed(&eps)?;
    }
    let last = calls - 1;
    let x = reference
        .f32(&format!("window1.trace{last}.x"))
        .map_err(r)?
        .data;
    let eps = reference
        .f64(&format!("window1.trace{last}.eps"))
        .map_err(r)?
        .data;
    let mut w =
        WindowSampler::new(n, Some(&known), *so, schedule, noise)?.resume_at_last_step(&x)?;
    w.feed(&eps)?;
    let (x0, _) = w.finish()?;
    let want = reference.f32("window1.x0").map_err(r)?.data;
    fold(&mut mx, max_abs_f32(&x0, &want, MOTION_DIM, last as u64));
    Ok(Row::max_abs(
        Check::Rollout,
        "window 1 trace",
        "rust sampler vs python (torch eps replayed)",
        "x, x0",
        &mx,
        0.0,
    ))
}

/// The graph check of one DiffSHEG graph: every `call{c}` of its reference file.
fn graph_calls(
    bundle: &Bundle,
    spec: &GraphSpec,
    backends: &[(BackendKind, Box<dyn Backend>)],
    rows: &mut Vec<Row>,
) -> Result<(), ReferenceError> {
    let (path, refv) = super::graphs::graph_reference(bundle, spec)?;
    let mut calls = 0;
    while refv
        .get(&format!("call{calls}.input.{}", spec.inputs[0].name))
        .is_ok()
    {
        calls += 1;
    }
    if calls == 0 {
        return Err(ref_err(
            &path,
            format!("no calls (call0.input.{})", spec.inputs[0].name),
        ));
    }
    for c in 0..calls {
        for i in &spec.inputs {
            refv.get(&format!("call{c}.input.{}", i.name))?;
        }
        for o in &spec.outputs {
            refv.get(&format!("call{c}.output.{}", o.name))?;
        }
    }
    let mut outs: Vec<(BackendKind, Result<Vec<Vec<Tensor>>>)> = Vec::new();
    for (k, be) in backends {
        let res = (|| -> Result<Vec<Vec<Tensor>>> {
            let mut runner = be.load(spec, &bundle.graph_path(spec))?;
            (0..calls)
                .map(|c| {
                    let inputs: Vec<Tensor> = spec
                        .inputs
                        .iter()
                        .map(|i| refv.get(&format!("call{c}.input.{}", i.name)).cloned())
                        .collect::<Result<_, _>>()?;
                    runner.run(&inputs).with_context(|| format!("{k} call {c}"))
                })
                .collect()
        })();
        outs.push((*k, res));
    }
    let ort = outs
        .iter()
        .find(|(k, _)| *k == BackendKind::Ort)
        .and_then(|(_, r)| r.as_ref().ok());
    for (k, res) in &outs {
        let vs_torch = if *k == BackendKind::Ort {
            ORT_VS_TORCH
        } else {
            TRACT_VS_TORCH
        };
        match res {
            Ok(all) => {
                for (oi, o) in spec.outputs.iter().enumerate() {
                    let mut m = MaxAbs::default();
                    for (c, out) in all.iter().enumerate() {
                        if let Ok(want) = refv.get(&format!("call{c}.output.{}", o.name)) {
                            m.add(c as u64, &out[oi], want);
                        }
                    }
                    rows.push(Row::max_abs(
                        Check::Graph,
                        spec.name.clone(),
                        format!("{k} vs torch"),
                        o.name.clone(),
                        &m,
                        vs_torch,
                    ));
                    if *k == BackendKind::Tract {
                        if let Some(ort) = ort {
                            let mut m = MaxAbs::default();
                            for (c, (a, b)) in all.iter().zip(ort).enumerate() {
                                m.add(c as u64, &a[oi], &b[oi]);
                            }
                            rows.push(Row::max_abs(
                                Check::Graph,
                                spec.name.clone(),
                                "tract vs ort",
                                o.name.clone(),
                                &m,
                                TRACT_VS_ORT,
                            ));
                        }
                    }
                }
            }
            Err(e) => rows.push(Row::failed(
                Check::Graph,
                spec.name.clone(),
                format!("{k} vs torch"),
                "(all)",
                vs_torch,
                format!("{k} could not run graph '{}': {e:#}", spec.name),
            )),
        }
    }
    Ok(())
}
