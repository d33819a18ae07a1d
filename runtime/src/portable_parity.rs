//! The parity checks that need no file system, no onnxruntime and no clock (docs/parity.md,
//! docs/wasm.md): every graph of a bundle against its reference vectors and the whole reference
//! rollout, on one backend, with the bundle's files read through [`Bundle::read`] (a folder or
//! files in memory, [`Bundle::from_files`]). It is what the WebAssembly binding's `Model.parity()`
//! runs in a browser (tract compiled to WebAssembly); natively a test runs it on the shipped bundles.
//! The full suite (`livegesture parity`, the `livegesture-parity` crate in tools/parity) adds onnxruntime, the chunk and batch
//! invariances, the log-mel frontend and the recorded export checks.
//!
//! | check | what | bound |
//! |---|---|---|
//! | graph | every graph of the manifest over its reference steps (LiveGesture: `step{s}.*`, chained caches; DiffSHEG: `call{c}.*`), every data output at every step and every new cache at the last step, vs the reference | [`GRAPH_BOUND`]: tract vs ort plus ort vs torch, scaled by max(1, max\|ref\|) |
//! | rollout | LiveGesture: the whole seeded reference rollout (clip x repeats, the manifest's seed and sampling defaults): identical tokens, frames; DiffSHEG: the seeded FOPPAS rollout over the reference audio with the manifest's rollout options: frame count, frames | [`ROLLOUT_FRAMES`] (scaled) |
//!
//! The bounds are defined here, once; the full suite re-exports them. Each line names the graph
//! (or rollout), the output, the step, the error and the scale it was judged at; a failed
//! comparison is a `FAIL` line.

use std::collections::HashMap;
use std::io::Cursor;

use anyhow::{anyhow, bail, Context, Result};
use ndarray::{ArrayD, IxDyn};
use ndarray_npy::NpzReader;
use serde::Serialize;

use crate::audio::{AudioSpan, WavStream};
use crate::backend::{Backend, Tensor, TensorData};
use crate::bundle::{Bundle, GraphSpec};
use crate::compare::{diff, diff_tensors, Diff};
use crate::model::livegesture::LiveGestureGraphs;
use crate::model::{self, StreamOptions};
use crate::output::Frame;

/// onnxruntime vs torch, every graph output (docs/parity.md).
pub const ORT_VS_TORCH: f64 = 1e-5;
/// tract vs onnxruntime, every graph output (docs/parity.md).
pub const TRACT_VS_ORT: f64 = 1e-4;
/// tract vs torch: implied by the two bounds above (triangle inequality).
pub const TRACT_VS_TORCH: f64 = ORT_VS_TORCH + TRACT_VS_ORT;
/// Rollout frames, any two of torch, ort, tract (docs/parity.md).
pub const ROLLOUT_FRAMES: f64 = 1e-4;
/// A graph here vs the reference (torch; onnxruntime for a reduced-precision bundle): tract's bound
/// vs torch, [`TRACT_VS_TORCH`] (the looser of the two backends' bounds).
pub const GRAPH_BOUND: f64 = TRACT_VS_TORCH;

/// The outcome: one line per comparison (`PASS ...` or `FAIL ...`).
#[derive(Debug, Default, Clone, Serialize)]
pub struct Report {
    pub passed: usize,
    pub failed: usize,
    pub lines: Vec<String>,
}

impl Report {
    fn line(&mut self, pass: bool, text: String) {
        if pass {
            self.passed += 1;
        } else {
            self.failed += 1;
        }
        self.lines
            .push(format!("{} {text}", if pass { "PASS" } else { "FAIL" }));
    }

    fn compare(&mut self, what: &str, d: &Diff, bound: f64) {
        let pass = d.within(bound);
        self.line(
            pass,
            format!("{what}: {} (bound {bound:e} x scale)", d.describe()),
        );
    }

    /// True when some comparison ran and none failed.
    pub fn ok(&self) -> bool {
        self.failed == 0 && self.passed > 0
    }

    /// `{"passed": n, "failed": n, "lines": [...]}`.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a report of numbers and strings serializes")
    }
}

/// The arrays of a reference npz, as tensors (float32 and int64).
struct Npz {
    name: String,
    arrays: HashMap<String, Tensor>,
}

impl Npz {
    fn read(bundle: &Bundle, rel: &str) -> Result<Self> {
        let name = bundle.path(rel).display().to_string();
        let bytes = bundle.read(rel)?;
        let mut npz = NpzReader::new(Cursor::new(&bytes[..]))
            .with_context(|| format!("{name}: not a valid npz"))?;
        let names = npz
            .names()
            .with_context(|| format!("{name}: not a valid npz"))?;
        let mut arrays = HashMap::new();
        for n in names {
            let t = if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<f32> = a;
                Tensor::f32(a.shape().to_vec(), a.iter().copied().collect())?
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<i64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().copied().collect())?
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<u64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().map(|&v| v as i64).collect())?
            } else {
                // other dtypes (float64 traces) are not read here
                continue;
            };
            arrays.insert(n.trim_end_matches(".npy").to_string(), t);
        }
        Ok(Self {
            name: name.clone(),
            arrays,
        })
    }

    fn get(&self, key: &str) -> Result<&Tensor> {
        self.arrays
            .get(key)
            .ok_or_else(|| anyhow!("{}: no array '{key}'", self.name))
    }

    fn f32(&self, key: &str) -> Result<&[f32]> {
        self.get(key)?.as_f32(key)
    }

    fn int(&self, key: &str) -> Result<i64> {
        match &self.get(key)?.data {
            TensorData::I64(v) if v.len() == 1 => Ok(v[0]),
            _ => bail!("{}: '{key}' is not an integer scalar", self.name),
        }
    }
}

/// Runs every check on `bundle` with `backend` (see the module docs), each graph output judged at
/// [`GRAPH_BOUND`]; `label` names the side under test in the lines (e.g. `wasm tract`). A check that
/// cannot run (a reference file left out, a graph that does not load) is a `FAIL` line naming it, not
/// an error.
pub fn run(bundle: &Bundle, backend: &dyn Backend, label: &str) -> Report {
    run_with(bundle, backend, label, GRAPH_BOUND)
}

/// [`run`] with each graph output judged at `graph_bound` (scaled) against the reference (another
/// runtime's own bound, e.g. onnxruntime-web's); the rollout bounds are the same for every backend.
pub fn run_with(bundle: &Bundle, backend: &dyn Backend, label: &str, graph_bound: f64) -> Report {
    let mut report = Report::default();
    for spec in bundle.graphs() {
        if let Err(e) = graph(bundle, backend, label, graph_bound, spec, &mut report) {
            report.line(false, format!("graph {}: {e:#}", spec.name));
        }
    }
    let res = model::for_family(
        bundle,
        Rollout {
            backend,
            label,
            report: &mut report,
        },
    );
    if let Err(e) = res {
        report.line(false, format!("rollout: {e:#}"));
    }
    report
}

/// The whole reference rollout of the bundle's family ([`model::for_family`]: the one place that maps
/// a family to its code).
struct Rollout<'a> {
    backend: &'a dyn Backend,
    label: &'a str,
    report: &'a mut Report,
}

impl model::FamilyTool for Rollout<'_> {
    type Output = Result<()>;
    fn livegesture(self, bundle: &Bundle) -> Result<()> {
        livegesture_rollout(bundle, self.backend, self.label, self.report)
    }
    fn diffsheg(self, bundle: &Bundle) -> Result<()> {
        diffsheg_rollout(bundle, self.backend, self.label, self.report)
    }
}

/// One graph over its reference steps (module docs).
fn graph(
    bundle: &Bundle,
    backend: &dyn Backend,
    label: &str,
    graph_bound: f64,
    spec: &GraphSpec,
    report: &mut Report,
) -> Result<()> {
    let rel = spec
        .reference
        .clone()
        .unwrap_or_else(|| format!("reference/{}.npz", spec.name));
    let refv = Npz::read(bundle, &rel)?;
    let first = &spec.inputs[0].name;
    // LiveGesture: chained steps with caches; DiffSHEG: independent calls without caches
    let (prefix, n) = if refv.arrays.contains_key(&format!("step0.input.{first}")) {
        ("step", refv.int("n_steps")? as usize)
    } else {
        let mut n = 0;
        while refv.arrays.contains_key(&format!("call{n}.input.{first}")) {
            n += 1;
        }
        ("call", n)
    };
    anyhow::ensure!(n > 0, "{}: no reference steps", refv.name);
    let runner = backend.load_from(bundle, spec)?;
    let batch = refv.get(&format!("{prefix}0.input.{first}"))?.batch();
    let mut caches: Vec<Tensor> = spec.caches.iter().map(|c| c.zeros(batch)).collect();
    let mut worst: Vec<Option<(Diff, usize)>> = vec![None; spec.outputs.len()];
    for s in 0..n {
        let mut inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&format!("{prefix}{s}.input.{}", i.name)).cloned())
            .collect::<Result<_>>()?;
        inputs.extend(caches);
        let mut out = runner
            .run(&inputs)
            .with_context(|| format!("{label}, {prefix} {s}"))?;
        // a graph on ring caches (docs/bundle.md#ring-caches): its new entries are written into the
        // caches it read at the step's phase; the caches after the write are chained and compared
        caches = spec.chain_caches(inputs, &mut out)?;
        for (k, o) in spec.outputs.iter().enumerate() {
            let want = refv.get(&format!("{prefix}{s}.output.{}", o.name))?;
            // shapes and element types checked, int64 exactly (compare::diff_tensors)
            let d = diff_tensors(&out[k], want);
            worst[k] = Some(match worst[k].take() {
                None => (d, s),
                Some((w, ws)) => {
                    let w2 = w.clone().worst(d);
                    let at = if w2 == w { ws } else { s };
                    (w2, at)
                }
            });
        }
        if s == n - 1 {
            for (k, c) in spec.caches.iter().enumerate() {
                let want = refv.get(&format!("{prefix}{s}.new_cache.{}", c.name))?;
                let d = diff_tensors(&caches[k], want);
                report.compare(
                    &format!(
                        "graph {} output {} {prefix} {s}: {label} vs {}",
                        spec.name,
                        c.output,
                        bundle.reference_name()
                    ),
                    &d,
                    graph_bound,
                );
            }
        }
    }
    for (k, o) in spec.outputs.iter().enumerate() {
        if let Some((d, s)) = &worst[k] {
            report.compare(
                &format!(
                    "graph {} output {} (worst of {n} {prefix}s, at {prefix} {s}): {label} vs {}",
                    spec.name,
                    o.name,
                    bundle.reference_name()
                ),
                d,
                graph_bound,
            );
        }
    }
    Ok(())
}

/// The frame fields of a rollout, in the reference file's names.
const FIELDS: [&str; 4] = ["poses", "trans", "expressions", "foot_contact"];

fn field(frames: &[Frame], k: usize) -> Vec<f32> {
    frames
        .iter()
        .flat_map(|f| match k {
            0 => f.poses.to_vec(),
            1 => f.trans.to_vec(),
            2 => f.expressions.to_vec(),
            _ => f.foot_contact.to_vec(),
        })
        .collect()
}

/// The reference clip (16 kHz mono), decoded by the runtime's WAV reader from the bundle's bytes.
fn clip_16k(bundle: &Bundle, rel: &str) -> Result<Vec<f32>> {
    let bytes = bundle.read(rel)?;
    let name = bundle.path(rel);
    let mut wav = WavStream::from_bytes(&bytes[..], &name)?;
    anyhow::ensure!(
        wav.info().sample_rate == 16_000,
        "{}: the reference clip is at {} Hz; expected 16000",
        name.display(),
        wav.info().sample_rate
    );
    let mut out = Vec::new();
    while let Some(c) = wav.next_chunk()? {
        out.extend(c);
    }
    Ok(out)
}

fn livegesture_rollout(
    bundle: &Bundle,
    backend: &dyn Backend,
    label: &str,
    report: &mut Report,
) -> Result<()> {
    let r = bundle
        .reference()
        .ok_or_else(|| anyhow!("manifest.json has no `reference`"))?;
    let rel = bundle.reference_rollout();
    let refv = Npz::read(bundle, &rel)?;
    let seed = r
        .rollout_seed
        .ok_or_else(|| anyhow!("manifest.json: reference.rollout_seed is missing"))?;
    let clip_rel = bundle.reference_clip();
    let clip = clip_16k(bundle, &clip_rel)?;
    let repeats = refv.int("clip_repeats")?.max(1) as usize;
    let audio: Vec<f32> = std::iter::repeat_n(&clip[..], repeats)
        .flatten()
        .copied()
        .collect();
    let want_tokens = refv.get("tokens")?;
    let regions = want_tokens.shape.get(1).copied().unwrap_or(1);
    let want_tokens = want_tokens.as_i64("tokens")?.to_vec();
    let p = LiveGestureGraphs::new(bundle, backend)?;
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let mut s = p.new_stream(&opts)?;
    let mut steps = Vec::new();
    for c in audio.chunks(16_000) {
        steps.extend(p.push_steps(&mut s, c)?);
    }
    let got_tokens: Vec<i64> = steps
        .iter()
        .flat_map(|s| s.tokens.iter().copied())
        .collect();
    let what = format!(
        "rollout tokens ({} tokens, seed {seed}, clip x {repeats}): {label} vs {}",
        want_tokens.len() / regions.max(1),
        bundle.reference_name()
    );
    let first_diff = got_tokens
        .iter()
        .zip(&want_tokens)
        .position(|(a, b)| a != b);
    let prefix_tokens = match first_diff {
        // nothing compared proves nothing: an empty rollout fails below
        None if got_tokens.len() == want_tokens.len() && !want_tokens.is_empty() => {
            report.line(true, format!("{what}: identical"));
            steps.len()
        }
        None => {
            report.line(
                false,
                format!(
                    "{what}: {} token steps vs {} in the reference",
                    got_tokens.len() / regions.max(1),
                    want_tokens.len() / regions.max(1)
                ),
            );
            got_tokens.len().min(want_tokens.len()) / regions.max(1)
        }
        Some(i) => {
            report.line(
                false,
                format!(
                    "{what}: first differing token at step {}, region {}: {} vs {}",
                    i / regions,
                    i % regions,
                    got_tokens[i],
                    want_tokens[i]
                ),
            );
            i / regions
        }
    };
    let frames: Vec<Frame> = steps[..prefix_tokens]
        .iter()
        .flat_map(|s| s.frames.iter().cloned())
        .collect();
    for (k, name) in FIELDS.iter().enumerate() {
        let want = refv.f32(name)?;
        let width = want.len() / refv.get(name)?.batch().max(1);
        let got = field(&frames, k);
        let n = got.len().min(want.len()) / width.max(1) * width;
        let d = diff(&got[..n], &want[..n]);
        report.compare(
            &format!(
                "rollout {name} ({} frames): {label} vs {}",
                n / width.max(1),
                bundle.reference_name()
            ),
            &d,
            ROLLOUT_FRAMES,
        );
    }
    Ok(())
}

fn diffsheg_rollout(
    bundle: &Bundle,
    backend: &dyn Backend,
    label: &str,
    report: &mut Report,
) -> Result<()> {
    bundle
        .reference()
        .ok_or_else(|| anyhow!("manifest.json has no `reference`"))?;
    let rel = bundle.reference_rollout();
    let refv = Npz::read(bundle, &rel)?;
    let raw: serde_json::Value = serde_json::from_slice(&bundle.read("manifest.json")?)?;
    let ro = &raw["reference"]["rollout_options"];
    let get = |k: &str| -> Result<usize> {
        ro[k]
            .as_u64()
            .map(|v| v as usize)
            .ok_or_else(|| anyhow!("manifest.json: reference.rollout_options.{k} is missing"))
    };
    let opts = StreamOptions {
        seed: refv.int("seed")? as u64,
        guidance: Some(ro["guidance"].as_f64().ok_or_else(|| {
            anyhow!("manifest.json: reference.rollout_options.guidance is missing")
        })?),
        ddim_steps: Some(get("steps")?),
        window: Some(get("window")?),
        overlap: Some(get("overlap")?),
        jumps: Some(get("jumps")?),
        blend_steps: Some(get("blend_steps")?),
        speaker: Some(raw["reference"]["rollout_speaker"].as_u64().unwrap_or(0) as usize),
        ..Default::default()
    };
    let audio = refv.f32("audio")?.to_vec();
    let m = model::load(bundle, backend)?;
    let mut s = m.new_stream(&opts)?;
    let mut frames = s.push_audio(&audio)?;
    frames.extend(s.finish(AudioSpan::at_16k(audio.len() as u64))?);
    let t_frames = refv.int("frames")? as usize;
    report.line(
        frames.len() == t_frames,
        format!(
            "rollout frames (seed {}): {} frames, reference {t_frames}",
            opts.seed,
            frames.len()
        ),
    );
    for (k, name) in FIELDS.iter().enumerate() {
        let d = diff(&field(&frames, k), refv.f32(name)?);
        report.compare(
            &format!(
                "rollout {name} ({} frames): {label} vs {}",
                frames.len(),
                bundle.reference_name()
            ),
            &d,
            ROLLOUT_FRAMES,
        );
    }
    Ok(())
}
