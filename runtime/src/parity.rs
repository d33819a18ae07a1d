//! The parity suite (SPEC section 7): proves that torch, ONNX Runtime and tract agree on a bundle.
//!
//! [`run`] checks any bundle against the torch reference vectors that travel with it
//! (`export/BUNDLE.md`) and against itself:
//!
//! | check | what | bound |
//! |---|---|---|
//! | `graph` | every graph, all chained steps of `reference/<graph>.npz` (`n_steps`, 10) from the manifest's zero caches, every output at every step and the caches after the last step: ort vs torch | [`ORT_VS_TORCH`] |
//! | `graph` | the same, tract vs ort (same inputs, each backend chaining its own caches; every output and cache at every step) | [`TRACT_VS_ORT`] |
//! | `graph` | the same, tract vs torch (implied by the two above) | [`TRACT_VS_TORCH`] |
//! | `graph` | torch step-by-step vs torch offline: measured by the exporter (it needs PyTorch) and read from the manifest's `checks` | [`TORCH_STEP_VS_OFFLINE`] |
//! | `rollout` | the whole seeded rollout (`reference/clip.wav` repeated `clip_repeats` times, the manifest's seed and sampling defaults): tokens identical at every step, frames (poses, trans, expressions, foot contact) | [`ROLLOUT_FRAMES`] |
//! | `logmel` | the Rust log-mel frontend on `reference/clip.wav` vs `reference/logmel.npy` | [`LOGMEL`] |
//! | `chunks` | chunks of 1 sample, 160, 3200, 16000 samples and the whole prefix give identical frames (on a prefix of the clip, [`ParityOptions::chunk_seconds`]) | exact |
//! | `batch` | [`Pipeline::step_batch`] with 1, 2 and 5 streams (different seeds, audio, one without guidance) vs separate runs: identical tokens, frames | [`BATCH_FRAMES`] (ort), [`TRACT_BATCH_FRAMES`] (tract) |
//!
//! Every comparison is one [`Row`]: the check, the graph (or what is compared), the comparison
//! (`ort vs torch`, ...), the output, the step of the largest error, the error, the bound and the
//! verdict. A failed row names the graph, the output, the step and the error.
//!
//! # Token divergence
//!
//! When two rollouts' tokens differ, [`find_divergence`] names the first diverging step and region
//! and the two tokens, and measures how close the draw was to a tie from each side's guided logits
//! ([`Margin`]): the sampler draws by inverse CDF, so what decides a token is where the uniform
//! draw falls among the cumulative probabilities. The draw is replayed from the seed (one uniform
//! per region per step), and the margin is the distance, in probability, from the draw to the
//! nearest edge of the sampled token's interval. A margin of the order of the logit errors
//! (< [`NEAR_TIE`]) is a numerical near-tie; a large one is a real difference.
//!
//! torch's logits are not stored in the bundle, so for torch-vs-backend divergences the margin comes
//! from the backend's own logits (and the other backend's when both ran).

use std::collections::HashMap;
use std::fmt;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use ndarray::{Array2, ArrayD, IxDyn};
use ndarray_npy::{NpzReader, ReadNpyExt};
use serde::Serialize;

use crate::audio::read_wav_16k_mono;
use crate::backend::{self, Backend, BackendKind, BackendOptions, Tensor, TensorData};
use crate::bundle::{Bundle, GraphSpec};
use crate::frontend::logmel;
use crate::output::Frame;
use crate::pipeline::{Pipeline, StepLogits, StreamOptions, TokenStep};
use crate::sampling::{guide, SplitMix64};

/// torch step-by-step vs torch offline causal forward (SPEC 7; measured at export, recorded in the
/// manifest's `checks`).
pub const TORCH_STEP_VS_OFFLINE: f64 = 1e-5;
/// onnxruntime vs torch, every graph output (SPEC 7).
pub const ORT_VS_TORCH: f64 = 1e-5;
/// tract vs onnxruntime, every graph output (SPEC 7).
pub const TRACT_VS_ORT: f64 = 1e-4;
/// tract vs torch: implied by the two bounds above (triangle inequality).
pub const TRACT_VS_TORCH: f64 = ORT_VS_TORCH + TRACT_VS_ORT;
/// Rollout frames, any two of torch, ort, tract (SPEC 7).
pub const ROLLOUT_FRAMES: f64 = 1e-4;
/// Rust log-mel frontend vs the Python one (SPEC 7).
pub const LOGMEL: f64 = 1e-4;
/// Batched vs separate stepping, frames, on ort (which computes every row alike: exact in practice).
pub const BATCH_FRAMES: f64 = 1e-6;
/// Batched vs separate stepping, frames, on tract: tract optimises one plan per batch size and its
/// kernels may sum in another order, so graph outputs differ by ~1e-7 between batch sizes, and the
/// rot6d -> axis-angle conversion amplifies that for near-degenerate rot6d (random-weight bundles).
/// The bound is tract's own tolerance (SPEC 7, "approximate").
pub const TRACT_BATCH_FRAMES: f64 = TRACT_VS_ORT;

/// The batched-vs-separate frame bound of a backend.
pub fn batch_bound(kind: BackendKind) -> f64 {
    match kind {
        BackendKind::Ort => BATCH_FRAMES,
        BackendKind::Tract => TRACT_BATCH_FRAMES,
    }
}
/// A sampling margin (probability) below this is reported as a numerical near-tie.
pub const NEAR_TIE: f64 = 1e-3;
/// Two candidate tokens whose guided logits are closer than this are a near-tie too: the sampler
/// orders tokens by guided logit, so such tokens can swap places (and CDF intervals).
pub const NEAR_TIE_LOGIT: f64 = 1e-3;
/// Chunk sizes of the chunk-invariance check (samples); the whole prefix is the reference.
pub const CHUNK_SIZES: [usize; 4] = [1, 160, 3200, 16000];
/// Batch sizes of the batching check.
pub const BATCH_SIZES: [usize; 3] = [1, 2, 5];

/// A reference file of the bundle is missing or unreadable: bad input (CLI exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("{}: {detail}", .path.display())]
pub struct ReferenceError {
    pub path: PathBuf,
    pub detail: String,
}

fn ref_err(path: &Path, detail: impl fmt::Display) -> ReferenceError {
    ReferenceError {
        path: path.to_path_buf(),
        detail: detail.to_string(),
    }
}

/// The parity checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, PartialOrd, Ord)]
#[serde(rename_all = "lowercase")]
pub enum Check {
    /// Every graph against the torch reference vectors and across backends.
    Graph,
    /// The whole seeded rollout.
    Rollout,
    /// The Rust log-mel frontend against the Python one.
    Logmel,
    /// Chunk-size invariance.
    Chunks,
    /// Batched stepping equals separate streams.
    Batch,
}

impl Check {
    /// All checks, in report order.
    pub const ALL: [Check; 5] = [
        Check::Graph,
        Check::Rollout,
        Check::Logmel,
        Check::Chunks,
        Check::Batch,
    ];

    /// Lower-case name (`graph`, `rollout`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Check::Graph => "graph",
            Check::Rollout => "rollout",
            Check::Logmel => "logmel",
            Check::Chunks => "chunks",
            Check::Batch => "batch",
        }
    }
}

impl fmt::Display for Check {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Check {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "graph" | "graphs" => Ok(Check::Graph),
            "rollout" | "rollouts" => Ok(Check::Rollout),
            "logmel" | "log-mel" | "frontend" => Ok(Check::Logmel),
            "chunks" | "chunk" => Ok(Check::Chunks),
            "batch" | "batches" => Ok(Check::Batch),
            other => Err(format!(
                "unknown check '{other}'; expected graph, rollout, logmel, chunks or batch"
            )),
        }
    }
}

/// What a row's error measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Metric {
    /// Largest absolute difference of corresponding values.
    MaxAbs,
    /// Number of token steps that differ (of `total`).
    DifferingSteps,
}

/// One comparison of the report.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub check: Check,
    /// The graph, or what is compared (`rollout`, `clip.wav`, `chunk 160`, `batch 5`).
    pub what: String,
    /// `ort vs torch`, `tract vs ort`, `tract vs torch`, `rust vs python`, `tract` (self-consistency).
    pub comparison: String,
    /// The output (graph output name, `tokens`, `poses`, ...).
    pub output: String,
    /// The step (token) of the largest error, or the first diverging step.
    pub step: Option<u64>,
    pub metric: Metric,
    /// The error: a max abs difference, or a count of differing steps.
    pub error: f64,
    /// Steps compared (for [`Metric::DifferingSteps`]) or values compared.
    pub compared: u64,
    pub bound: f64,
    pub pass: bool,
    /// Where the largest error is, why the check could not run, or the divergence report.
    pub detail: Option<String>,
}

impl Row {
    fn max_abs(
        check: Check,
        what: impl Into<String>,
        comparison: impl Into<String>,
        output: impl Into<String>,
        m: &MaxAbs,
        bound: f64,
    ) -> Row {
        Row {
            check,
            what: what.into(),
            comparison: comparison.into(),
            output: output.into(),
            step: m.step,
            metric: Metric::MaxAbs,
            error: m.err,
            compared: m.count,
            bound,
            pass: m.err <= bound && m.problem.is_none(),
            detail: m.problem.clone().or_else(|| m.location.clone()),
        }
    }

    fn failed(
        check: Check,
        what: impl Into<String>,
        comparison: impl Into<String>,
        output: impl Into<String>,
        bound: f64,
        why: String,
    ) -> Row {
        Row {
            check,
            what: what.into(),
            comparison: comparison.into(),
            output: output.into(),
            step: None,
            metric: Metric::MaxAbs,
            error: f64::INFINITY,
            compared: 0,
            bound,
            pass: false,
            detail: Some(why),
        }
    }

    /// The error as the table shows it.
    pub fn error_text(&self) -> String {
        match self.metric {
            Metric::MaxAbs if self.error.is_infinite() => "-".into(),
            Metric::MaxAbs if self.error == 0.0 => "0".into(),
            Metric::MaxAbs => format!("{:.3e}", self.error),
            Metric::DifferingSteps => format!("{} of {} steps", self.error, self.compared),
        }
    }

    /// The bound as the table shows it.
    pub fn bound_text(&self) -> String {
        match self.metric {
            Metric::MaxAbs if self.bound == 0.0 => "exact".into(),
            Metric::MaxAbs => format!("{:.1e}", self.bound),
            Metric::DifferingSteps => "0 (identical)".into(),
        }
    }

    /// One line naming everything about a failure (graph, output, step, error).
    pub fn failure_line(&self) -> String {
        let step = self
            .step
            .map(|s| format!(" at step {s}"))
            .unwrap_or_default();
        let mut s = format!(
            "FAIL {} {} ({}): output '{}'{step}: error {} > bound {}",
            self.check,
            self.what,
            self.comparison,
            self.output,
            self.error_text(),
            self.bound_text()
        );
        if let Some(d) = &self.detail {
            s.push_str("; ");
            s.push_str(d);
        }
        s
    }
}

/// The report of a parity run.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub bundle: PathBuf,
    pub backends: Vec<String>,
    pub rows: Vec<Row>,
    /// Remarks (what was run on which data, skipped comparisons).
    pub notes: Vec<String>,
    /// Token divergences found in rollouts.
    pub divergences: Vec<Divergence>,
    pub seconds: f64,
}

impl Report {
    /// True when every row passed.
    pub fn passed(&self) -> bool {
        self.rows.iter().all(|r| r.pass)
    }

    /// The rows that failed.
    pub fn failures(&self) -> Vec<&Row> {
        self.rows.iter().filter(|r| !r.pass).collect()
    }

    /// The rows of one check on one graph (or `what`).
    pub fn rows_for(&self, check: Check, what: &str) -> Vec<&Row> {
        self.rows
            .iter()
            .filter(|r| r.check == check && r.what == what)
            .collect()
    }

    /// The report as a text table. Without `all`, rows of one (check, what, comparison) that all
    /// pass are summarised by their worst output; failing rows are always shown one by one.
    pub fn table(&self, all: bool) -> String {
        let mut shown: Vec<(Row, usize)> = Vec::new();
        let mut i = 0;
        while i < self.rows.len() {
            let r = &self.rows[i];
            let mut j = i + 1;
            while j < self.rows.len()
                && self.rows[j].check == r.check
                && self.rows[j].what == r.what
                && self.rows[j].comparison == r.comparison
                && self.rows[j].metric == Metric::MaxAbs
                && r.metric == Metric::MaxAbs
            {
                j += 1;
            }
            let group = &self.rows[i..j];
            if all || group.len() == 1 || group.iter().any(|r| !r.pass) {
                shown.extend(group.iter().map(|r| (r.clone(), 1)));
            } else {
                // the worst relative to its bound; the first of equals
                let rel = |r: &Row| r.error / r.bound.max(f64::MIN_POSITIVE);
                let worst = group
                    .iter()
                    .fold(None::<&Row>, |w, r| match w {
                        Some(w) if rel(w) >= rel(r) => Some(w),
                        _ => Some(r),
                    })
                    .cloned()
                    .unwrap_or_else(|| r.clone());
                shown.push((worst, group.len()));
            }
            i = j;
        }
        let header = [
            "CHECK",
            "GRAPH/WHAT",
            "COMPARISON",
            "OUTPUT",
            "STEP",
            "MAX ABS ERROR",
            "BOUND",
            "RESULT",
        ];
        let cells: Vec<[String; 8]> = shown
            .iter()
            .map(|(r, n)| {
                let output = if *n > 1 {
                    format!("{} (worst of {n})", r.output)
                } else {
                    r.output.clone()
                };
                [
                    r.check.to_string(),
                    r.what.clone(),
                    r.comparison.clone(),
                    output,
                    r.step.map(|s| s.to_string()).unwrap_or_else(|| "-".into()),
                    r.error_text(),
                    r.bound_text(),
                    if r.pass { "PASS" } else { "FAIL" }.to_string(),
                ]
            })
            .collect();
        let mut widths: Vec<usize> = header.iter().map(|h| h.len()).collect();
        for c in &cells {
            for (w, s) in widths.iter_mut().zip(c) {
                *w = (*w).max(s.chars().count());
            }
        }
        let line = |c: &[String]| -> String {
            let mut s = String::new();
            for (k, (cell, w)) in c.iter().zip(&widths).enumerate() {
                if k > 0 {
                    s.push_str("  ");
                }
                s.push_str(&format!("{cell:<w$}"));
            }
            s.trim_end().to_string() + "\n"
        };
        let mut out = line(&header.map(String::from));
        out.push_str(&line(
            &widths.iter().map(|w| "-".repeat(*w)).collect::<Vec<_>>(),
        ));
        for c in &cells {
            out.push_str(&line(c));
        }
        out
    }

    /// A human summary: notes, divergences, failures and the verdict.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for n in &self.notes {
            s.push_str(&format!("note: {n}\n"));
        }
        for d in &self.divergences {
            s.push_str(&format!("divergence: {d}\n"));
        }
        let failures = self.failures();
        for f in &failures {
            if f.check == Check::Rollout
                && f.metric == Metric::DifferingSteps
                && !self.divergences.is_empty()
            {
                // the divergence line above already says everything about it
                let mut short = (*f).clone();
                short.detail = Some("see the divergence above".into());
                s.push_str(&short.failure_line());
            } else {
                s.push_str(&f.failure_line());
            }
            s.push('\n');
        }
        if failures.is_empty() {
            s.push_str(&format!(
                "parity: all {} comparisons PASS ({}; {:.1} s)\n",
                self.rows.len(),
                self.backends.join(", "),
                self.seconds
            ));
        } else {
            s.push_str(&format!(
                "parity: {} of {} comparisons FAIL ({}; {:.1} s)\n",
                failures.len(),
                self.rows.len(),
                self.backends.join(", "),
                self.seconds
            ));
        }
        s
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct ParityOptions {
    /// Backends, each run on its own; ort is the reference of tract when both run.
    pub backends: Vec<BackendKind>,
    /// Settings of the ort backend (library, execution provider, threads).
    pub ort: BackendOptions,
    /// Checks to run (all by default).
    pub checks: Vec<Check>,
    /// Seconds of the reference clip used by the chunk and batch checks.
    pub chunk_seconds: f64,
}

impl Default for ParityOptions {
    fn default() -> Self {
        Self {
            backends: vec![BackendKind::Ort, BackendKind::Tract],
            ort: BackendOptions {
                kind: BackendKind::Ort,
                ..Default::default()
            },
            checks: Check::ALL.to_vec(),
            chunk_seconds: 3.0,
        }
    }
}

// ------------------------------------------------------------------------------------ comparisons

/// A running max abs difference with where it happened.
#[derive(Debug, Clone, Default)]
struct MaxAbs {
    err: f64,
    step: Option<u64>,
    location: Option<String>,
    count: u64,
    problem: Option<String>,
}

fn unravel(mut i: usize, shape: &[usize]) -> Vec<usize> {
    let mut idx = vec![0; shape.len()];
    for (k, &d) in shape.iter().enumerate().rev() {
        if d > 0 {
            idx[k] = i % d;
            i /= d;
        }
    }
    idx
}

impl MaxAbs {
    /// Folds the comparison of two tensors at `step` in. NaN anywhere counts as an infinite error.
    fn add(&mut self, step: u64, got: &Tensor, want: &Tensor) {
        if got.shape != want.shape || got.dtype() != want.dtype() {
            self.problem.get_or_insert_with(|| {
                format!(
                    "step {step}: {} {:?} vs {} {:?} (shapes or types differ)",
                    got.dtype(),
                    got.shape,
                    want.dtype(),
                    want.shape
                )
            });
            self.err = f64::INFINITY;
            self.step.get_or_insert(step);
            return;
        }
        let diffs: Box<dyn Iterator<Item = (f64, f64)>> = match (&got.data, &want.data) {
            (TensorData::F32(a), TensorData::F32(b)) => {
                Box::new(a.iter().zip(b).map(|(&x, &y)| (x as f64, y as f64)))
            }
            (TensorData::I64(a), TensorData::I64(b)) => {
                Box::new(a.iter().zip(b).map(|(&x, &y)| (x as f64, y as f64)))
            }
            _ => unreachable!("dtypes checked above"),
        };
        let mut worst: Option<(usize, f64, f64, f64)> = None;
        for (i, (x, y)) in diffs.enumerate() {
            let d = if x.is_nan() || y.is_nan() {
                f64::INFINITY
            } else {
                (x - y).abs()
            };
            if worst.is_none_or(|w| d > w.1) {
                worst = Some((i, d, x, y));
            }
        }
        self.count += got.len() as u64;
        if let Some((i, d, x, y)) = worst {
            if self.step.is_none() || d > self.err {
                self.err = d;
                self.step = Some(step);
                self.location = Some(format!(
                    "largest at step {step}, index {:?}: {x} vs {y}",
                    unravel(i, &got.shape)
                ));
            }
        }
    }

    fn add_f32(&mut self, step: u64, index: String, got: f32, want: f32) {
        let d = if got.is_nan() || want.is_nan() {
            f64::INFINITY
        } else {
            (got as f64 - want as f64).abs()
        };
        self.count += 1;
        if self.step.is_none() || d > self.err {
            self.err = d;
            self.step = Some(step);
            self.location = Some(format!("largest at {index}: {got} vs {want}"));
        }
    }
}

// ------------------------------------------------------------------------------ reference vectors

/// The arrays of one `reference/<graph>.npz`, as tensors.
#[derive(Debug, Clone)]
pub struct ReferenceVectors {
    path: PathBuf,
    arrays: HashMap<String, Tensor>,
}

impl ReferenceVectors {
    /// Reads every array of the npz (float32 and int64; other dtypes are refused).
    pub fn load(path: &Path) -> Result<Self, ReferenceError> {
        let f = File::open(path).map_err(|e| ref_err(path, format!("cannot open: {e}")))?;
        let mut npz =
            NpzReader::new(f).map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let names = npz
            .names()
            .map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let mut arrays = HashMap::new();
        for n in names {
            let t = if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<f32> = a;
                Tensor::f32(a.shape().to_vec(), a.iter().copied().collect())
            } else if let Ok(a) = npz.by_name::<_, IxDyn>(&n) {
                let a: ArrayD<i64> = a;
                Tensor::i64(a.shape().to_vec(), a.iter().copied().collect())
            } else {
                return Err(ref_err(
                    path,
                    format!("array '{n}' is neither float32 nor int64"),
                ));
            };
            arrays.insert(n, t.map_err(|e| ref_err(path, e))?);
        }
        Ok(Self {
            path: path.to_path_buf(),
            arrays,
        })
    }

    /// The array `key`, or an error naming the file and the key.
    pub fn get(&self, key: &str) -> Result<&Tensor, ReferenceError> {
        self.arrays
            .get(key)
            .ok_or_else(|| ref_err(&self.path, format!("no array '{key}'")))
    }

    /// An integer scalar such as `n_steps`.
    pub fn scalar(&self, key: &str) -> Result<i64, ReferenceError> {
        match &self.get(key)?.data {
            TensorData::I64(v) if v.len() == 1 => Ok(v[0]),
            _ => Err(ref_err(
                &self.path,
                format!("'{key}' is not an integer scalar"),
            )),
        }
    }
}

// ------------------------------------------------------------------------------------ graph check

/// Outputs (graph order) of every chained step of one graph on one backend.
type StepOutputs = Vec<Vec<Tensor>>;

fn chain_graph(
    backend: &dyn Backend,
    bundle: &Bundle,
    spec: &GraphSpec,
    refv: &ReferenceVectors,
    n_steps: usize,
) -> Result<StepOutputs> {
    let mut runner = backend.load(spec, &bundle.graph_path(spec))?;
    let batch = refv
        .get(&format!("step0.input.{}", spec.inputs[0].name))?
        .batch();
    let mut caches: Vec<Tensor> = spec.caches.iter().map(|c| c.zeros(batch)).collect();
    let mut all = Vec::with_capacity(n_steps);
    for s in 0..n_steps {
        let mut inputs: Vec<Tensor> = spec
            .inputs
            .iter()
            .map(|i| refv.get(&format!("step{s}.input.{}", i.name)).cloned())
            .collect::<Result<_, _>>()?;
        inputs.extend(caches);
        let out = runner
            .run(&inputs)
            .with_context(|| format!("{} step {s}", backend.name()))?;
        caches = out[spec.outputs.len()..].to_vec();
        all.push(out);
    }
    Ok(all)
}

fn graph_rows(
    bundle: &Bundle,
    spec: &GraphSpec,
    backends: &[(BackendKind, Box<dyn Backend>)],
    rows: &mut Vec<Row>,
) -> Result<(), ReferenceError> {
    let rel = spec
        .reference
        .clone()
        .unwrap_or_else(|| format!("reference/{}.npz", spec.name));
    let path = bundle.path(&rel);
    let refv = ReferenceVectors::load(&path)?;
    let n_steps = refv.scalar("n_steps")?;
    if n_steps < 1 {
        return Err(ref_err(&path, format!("n_steps is {n_steps}")));
    }
    let n_steps = n_steps as usize;
    let last = n_steps - 1;
    // check the reference holds everything before running anything
    for s in 0..n_steps {
        for i in &spec.inputs {
            refv.get(&format!("step{s}.input.{}", i.name))?;
        }
        for o in &spec.outputs {
            refv.get(&format!("step{s}.output.{}", o.name))?;
        }
    }
    for c in &spec.caches {
        refv.get(&format!("step{last}.new_cache.{}", c.name))?;
    }
    // SPEC 7's first row, torch step-by-step vs torch offline, is measured by the exporter (it needs
    // the PyTorch model) and recorded in the manifest's `checks`: reported as recorded.
    if let Some(e) = bundle.manifest().checks[&spec.name]["torch_step_vs_offline_max_abs"].as_f64()
    {
        rows.push(Row {
            check: Check::Graph,
            what: spec.name.clone(),
            comparison: "torch step vs offline".into(),
            output: "(all, recorded by export)".into(),
            step: None,
            metric: Metric::MaxAbs,
            error: e,
            compared: 0,
            bound: TORCH_STEP_VS_OFFLINE,
            pass: e <= TORCH_STEP_VS_OFFLINE,
            detail: Some("measured by export/export.py, read from manifest.json `checks`".into()),
        });
    }
    let mut runs: Vec<(BackendKind, std::result::Result<StepOutputs, String>)> = Vec::new();
    for (kind, be) in backends {
        let r =
            chain_graph(be.as_ref(), bundle, spec, &refv, n_steps).map_err(|e| format!("{e:#}"));
        runs.push((*kind, r));
    }
    let outputs = spec.output_names();
    for (kind, run) in &runs {
        let (comparison, bound) = match kind {
            BackendKind::Ort => ("ort vs torch", ORT_VS_TORCH),
            BackendKind::Tract => ("tract vs torch", TRACT_VS_TORCH),
        };
        let steps = match run {
            Ok(s) => s,
            Err(e) => {
                rows.push(Row::failed(
                    Check::Graph,
                    &spec.name,
                    comparison,
                    "(all)",
                    bound,
                    format!("{kind} could not run the graph: {e}"),
                ));
                continue;
            }
        };
        for (k, o) in spec.outputs.iter().enumerate() {
            let mut m = MaxAbs::default();
            for (s, out) in steps.iter().enumerate() {
                m.add(
                    s as u64,
                    &out[k],
                    refv.get(&format!("step{s}.output.{}", o.name))?,
                );
            }
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                comparison,
                &o.name,
                &m,
                bound,
            ));
        }
        for (k, c) in spec.caches.iter().enumerate() {
            let mut m = MaxAbs::default();
            m.add(
                last as u64,
                &steps[last][spec.outputs.len() + k],
                refv.get(&format!("step{last}.new_cache.{}", c.name))?,
            );
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                comparison,
                &c.output,
                &m,
                bound,
            ));
        }
    }
    let ort = runs.iter().find(|r| r.0 == BackendKind::Ort);
    let tract = runs.iter().find(|r| r.0 == BackendKind::Tract);
    if let (Some((_, Ok(o))), Some((_, Ok(t)))) = (ort, tract) {
        for (k, name) in outputs.iter().enumerate() {
            let mut m = MaxAbs::default();
            for s in 0..n_steps {
                m.add(s as u64, &t[s][k], &o[s][k]);
            }
            rows.push(Row::max_abs(
                Check::Graph,
                &spec.name,
                "tract vs ort",
                *name,
                &m,
                TRACT_VS_ORT,
            ));
        }
    } else if ort.is_some() && tract.is_some() {
        rows.push(Row::failed(
            Check::Graph,
            &spec.name,
            "tract vs ort",
            "(all)",
            TRACT_VS_ORT,
            "not compared: a backend could not run the graph (see above)".into(),
        ));
    }
    Ok(())
}

// ------------------------------------------------------------------------------ divergence report

/// How close one side's draw was to picking the other token (see the module docs).
#[derive(Debug, Clone, Serialize)]
pub struct Margin {
    /// Whose logits (`ort`, `tract`).
    pub source: String,
    /// The token these logits give with the replayed uniform draw.
    pub sampled: i64,
    /// The replayed uniform draw in `[0, 1)`.
    pub uniform: f64,
    /// Distance (probability) from the draw to the nearest edge of the sampled token's interval.
    pub cdf_margin: f64,
    /// Guided logit (after temperature) of the first side's token minus that of the second side's.
    pub token_gap: f64,
    /// Guided logit gap between the two most likely tokens.
    pub top2_gap: f64,
    /// Probabilities of the two candidate tokens (after top-k).
    pub p_first: f64,
    pub p_second: f64,
}

impl Margin {
    /// See [`Divergence::near_tie`].
    pub fn is_near_tie(&self) -> bool {
        self.cdf_margin < NEAR_TIE || self.token_gap.abs() < NEAR_TIE_LOGIT
    }
}

/// The first step where two rollouts' tokens differ.
#[derive(Debug, Clone, Serialize)]
pub struct Divergence {
    /// The two sides, e.g. `ort` and `torch`.
    pub first: String,
    pub second: String,
    pub step: u64,
    pub region: String,
    pub region_index: usize,
    pub first_token: i64,
    pub second_token: i64,
    /// Steps with any differing token (from the first divergence on, states differ too).
    pub differing_steps: u64,
    /// Margins from each side's logits that are known.
    pub margins: Vec<Margin>,
    /// Largest guided-logit difference between the two sides at that step and region (when both
    /// logits are known).
    pub logit_difference: Option<f64>,
}

impl Divergence {
    /// True when, from every known side's logits, the draw was fragile: it sat within [`NEAR_TIE`]
    /// of an edge of the sampled token's CDF interval, or the two candidate tokens' guided logits
    /// are within [`NEAR_TIE_LOGIT`] (so a tiny logit change swaps their order and intervals).
    /// `None` when no logits are known.
    pub fn near_tie(&self) -> Option<bool> {
        if self.margins.is_empty() {
            None
        } else {
            Some(self.margins.iter().all(Margin::is_near_tie))
        }
    }
}

impl fmt::Display for Divergence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} vs {}: tokens first differ at step {}, region '{}': {} {} vs {} {} ({} differing steps)",
            self.first,
            self.second,
            self.step,
            self.region,
            self.first,
            self.first_token,
            self.second,
            self.second_token,
            self.differing_steps
        )?;
        for m in &self.margins {
            write!(
                f,
                "; {} logits: draw u={:.6} gives token {}, {:.2e} from its interval edge (p {}={:.4}, p {}={:.4}), guided-logit gap {:.3e}, top-2 gap {:.3e}",
                m.source,
                m.uniform,
                m.sampled,
                m.cdf_margin,
                self.first_token,
                m.p_first,
                self.second_token,
                m.p_second,
                m.token_gap,
                m.top2_gap
            )?;
        }
        if let Some(d) = self.logit_difference {
            write!(
                f,
                "; guided logits differ by up to {d:.3e} between the sides"
            )?;
        }
        match self.near_tie() {
            Some(true) => write!(
                f,
                "; verdict: numerical near-tie (draw within {NEAR_TIE:.0e} of an interval edge, or the two tokens' \
                 guided logits within {NEAR_TIE_LOGIT:.0e}): a tiny logit difference flips this draw, so if the \
                 graph checks pass this is numerical noise, not a bug"
            ),
            Some(false) => write!(
                f,
                "; verdict: NOT a near-tie (draw >= {NEAR_TIE:.0e} from the interval edges, logit gap >= \
                 {NEAR_TIE_LOGIT:.0e}): the logits really differ, look for a bug"
            ),
            None => write!(f, "; no logits known on either side, margin not computed"),
        }
    }
}

/// Sampling parameters of a rollout, to replay its draws.
#[derive(Debug, Clone)]
pub struct SamplingParams {
    pub seed: u64,
    pub guidance: f64,
    pub temperature: f64,
    pub top_k: usize,
    /// Region names in sampling order.
    pub regions: Vec<String>,
}

/// One side of a rollout comparison: its tokens per step (region order) and, if known, its logits.
#[derive(Debug, Clone)]
pub struct RolloutTrace {
    pub name: String,
    pub tokens: Vec<Vec<i64>>,
    pub logits: Option<Vec<StepLogits>>,
}

/// The uniform draw of `region` at `step` (one draw per region per step, in region order).
pub fn replay_uniform(seed: u64, n_regions: usize, step: u64, region: usize) -> f64 {
    let mut rng = SplitMix64::new(seed);
    for _ in 0..step * n_regions as u64 + region as u64 {
        rng.next_u64();
    }
    rng.next_f64()
}

/// The margin of one side's draw between tokens `first` and `second` (see [`Margin`]).
pub fn sampling_margin(
    source: &str,
    cond: &[f32],
    uncond: Option<&[f32]>,
    p: &SamplingParams,
    uniform: f64,
    first: i64,
    second: i64,
) -> Result<Margin> {
    let mut g = guide(cond, uncond, p.guidance)?;
    for x in g.iter_mut() {
        *x /= p.temperature;
    }
    let k = g.len();
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_unstable_by(|&a, &b| g[b].total_cmp(&g[a]).then(a.cmp(&b)));
    let top2_gap = if k > 1 {
        g[order[0]] - g[order[1]]
    } else {
        f64::INFINITY
    };
    let kept = if p.top_k > 0 && p.top_k < k {
        p.top_k
    } else {
        k
    };
    let order = &order[..kept];
    let g0 = g[order[0]];
    let w: Vec<f64> = order.iter().map(|&i| (g[i] - g0).exp()).collect();
    let s: f64 = w.iter().sum();
    let r = uniform * s;
    let (mut acc, mut sampled, mut lo, mut hi) = (0.0f64, order[kept - 1], 0.0, s);
    for (&i, &x) in order.iter().zip(&w) {
        if acc + x > r {
            sampled = i;
            lo = acc;
            hi = acc + x;
            break;
        }
        acc += x;
    }
    let prob = |t: i64| -> f64 {
        order
            .iter()
            .zip(&w)
            .find(|(&i, _)| i as i64 == t)
            .map(|(_, &x)| x / s)
            .unwrap_or(0.0)
    };
    let at = |t: i64| g.get(t as usize).copied().unwrap_or(f64::NAN);
    Ok(Margin {
        source: source.to_string(),
        sampled: sampled as i64,
        uniform,
        cdf_margin: ((r - lo).min(hi - r) / s).max(0.0),
        token_gap: at(first) - at(second),
        top2_gap,
        p_first: prob(first),
        p_second: prob(second),
    })
}

/// The first step and region where `a` and `b` differ, with margins from whichever logits are known.
pub fn find_divergence(
    a: &RolloutTrace,
    b: &RolloutTrace,
    p: &SamplingParams,
) -> Result<Option<Divergence>> {
    let n = a.tokens.len().min(b.tokens.len());
    let differing = a
        .tokens
        .iter()
        .zip(&b.tokens)
        .filter(|(x, y)| x != y)
        .count() as u64;
    let Some(step) = (0..n).find(|&t| a.tokens[t] != b.tokens[t]) else {
        return Ok(None);
    };
    let region = (0..a.tokens[step].len())
        .find(|&r| a.tokens[step].get(r) != b.tokens[step].get(r))
        .unwrap_or(0);
    let (ta, tb) = (
        a.tokens[step][region],
        b.tokens[step].get(region).copied().unwrap_or(-1),
    );
    let nr = p.regions.len().max(a.tokens[step].len());
    let u = replay_uniform(p.seed, nr, step as u64, region);
    let mut margins = Vec::new();
    let mut guided = Vec::new();
    for side in [a, b] {
        let Some(l) = side.logits.as_ref().and_then(|l| l.get(step)) else {
            continue;
        };
        let k = l.cond.len() / nr;
        let c = &l.cond[region * k..(region + 1) * k];
        let un = l.uncond.as_ref().map(|u| &u[region * k..(region + 1) * k]);
        margins.push(sampling_margin(&side.name, c, un, p, u, ta, tb)?);
        guided.push(guide(c, un, p.guidance)?);
    }
    let logit_difference = (guided.len() == 2).then(|| {
        guided[0]
            .iter()
            .zip(&guided[1])
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    });
    Ok(Some(Divergence {
        first: a.name.clone(),
        second: b.name.clone(),
        step: step as u64,
        region: p
            .regions
            .get(region)
            .cloned()
            .unwrap_or_else(|| format!("#{region}")),
        region_index: region,
        first_token: ta,
        second_token: tb,
        differing_steps: differing + (a.tokens.len().max(b.tokens.len()) - n) as u64,
        margins,
        logit_difference,
    }))
}

// ------------------------------------------------------------------------------------- rollouts

/// The bundle's reference rollout (`reference/rollout.npz`).
#[derive(Debug, Clone)]
pub struct ReferenceRollout {
    pub tokens: Vec<Vec<i64>>,
    pub poses: Array2<f32>,
    pub trans: Array2<f32>,
    pub expressions: Array2<f32>,
    pub foot_contact: Array2<f32>,
    pub clip_repeats: usize,
}

impl ReferenceRollout {
    /// Reads `reference/rollout.npz`.
    pub fn load(path: &Path) -> Result<Self, ReferenceError> {
        let f = File::open(path).map_err(|e| ref_err(path, format!("cannot open: {e}")))?;
        let mut npz =
            NpzReader::new(f).map_err(|e| ref_err(path, format!("not a valid npz: {e}")))?;
        let mut f32_2 = |k: &str| -> Result<Array2<f32>, ReferenceError> {
            npz.by_name(k)
                .map_err(|e| ref_err(path, format!("'{k}': {e}")))
        };
        let poses = f32_2("poses")?;
        let trans = f32_2("trans")?;
        let expressions = f32_2("expressions")?;
        let foot_contact = f32_2("foot_contact")?;
        let tokens: Array2<i64> = npz
            .by_name("tokens")
            .map_err(|e| ref_err(path, format!("'tokens': {e}")))?;
        let reps: ndarray::Array0<i64> = npz
            .by_name("clip_repeats")
            .map_err(|e| ref_err(path, format!("'clip_repeats': {e}")))?;
        let reps = reps.into_scalar();
        if reps < 1 {
            return Err(ref_err(path, format!("clip_repeats is {reps}")));
        }
        Ok(Self {
            tokens: tokens.outer_iter().map(|r| r.to_vec()).collect(),
            poses,
            trans,
            expressions,
            foot_contact,
            clip_repeats: reps as usize,
        })
    }
}

/// The frame fields compared by the rollout, chunk and batch checks.
const FRAME_FIELDS: [&str; 4] = ["poses", "trans", "expressions", "foot_contact"];

fn field(f: &Frame, k: usize) -> &[f32] {
    match k {
        0 => &f.poses,
        1 => &f.trans,
        2 => &f.expressions,
        _ => &f.foot_contact,
    }
}

/// Runs one stream over `audio` in chunks of `chunk` samples.
fn run_stream(
    p: &mut Pipeline,
    opts: &StreamOptions,
    audio: &[f32],
    chunk: usize,
) -> Result<Vec<TokenStep>> {
    let mut s = p.new_stream(opts)?;
    let mut steps = Vec::new();
    for c in audio.chunks(chunk.max(1)) {
        steps.extend(p.push_steps(&mut s, c)?);
    }
    Ok(steps)
}

/// Compares the frames of token steps pairwise: `pairs` are (label naming the stream in the report,
/// got, want).
fn frame_rows_steps(
    check: Check,
    what: &str,
    comparison: &str,
    pairs: &[(String, &[TokenStep], &[TokenStep])],
    bound: f64,
    rows: &mut Vec<Row>,
) {
    for (k, name) in FRAME_FIELDS.iter().enumerate() {
        let mut m = MaxAbs::default();
        for (label, got, want) in pairs {
            for (a, b) in got.iter().zip(want.iter()) {
                for (fa, fb) in a.frames.iter().zip(&b.frames) {
                    for (j, (x, y)) in field(fa, k).iter().zip(field(fb, k)).enumerate() {
                        if (*x as f64 - *y as f64).abs() > m.err || x.is_nan() || m.step.is_none() {
                            m.add_f32(
                                a.token_index,
                                format!("{label}frame {}, {name}[{j}]", fa.index),
                                *x,
                                *y,
                            );
                        } else {
                            m.count += 1;
                        }
                    }
                }
            }
        }
        rows.push(Row::max_abs(check, what, comparison, *name, &m, bound));
    }
}

fn token_row(
    check: Check,
    what: &str,
    comparison: &str,
    got: &[Vec<i64>],
    want: &[Vec<i64>],
    detail: Option<String>,
) -> Row {
    let n = got.len().min(want.len());
    let mut differing = got.iter().zip(want).filter(|(a, b)| a != b).count() as u64;
    differing += (got.len().max(want.len()) - n) as u64;
    let first = (0..n)
        .find(|&t| got[t] != want[t])
        .or((got.len() != want.len()).then_some(n));
    let detail = detail.or_else(|| {
        (got.len() != want.len()).then(|| format!("{} steps vs {}", got.len(), want.len()))
    });
    Row {
        check,
        what: what.into(),
        comparison: comparison.into(),
        output: "tokens".into(),
        step: first.map(|s| s as u64),
        metric: Metric::DifferingSteps,
        error: differing as f64,
        compared: got.len().max(want.len()) as u64,
        bound: 0.0,
        pass: differing == 0,
        detail,
    }
}

struct BackendRollout {
    kind: BackendKind,
    steps: Vec<TokenStep>,
}

impl BackendRollout {
    fn trace(&self) -> RolloutTrace {
        RolloutTrace {
            name: self.kind.to_string(),
            tokens: self.steps.iter().map(|s| s.tokens.clone()).collect(),
            logits: Some(
                self.steps
                    .iter()
                    .map(|s| {
                        s.logits.clone().unwrap_or(StepLogits {
                            cond: Vec::new(),
                            uncond: None,
                        })
                    })
                    .collect(),
            ),
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn rollout_rows(
    bundle: &Bundle,
    pipelines: &mut [(BackendKind, Pipeline)],
    clip: &[f32],
    rows: &mut Vec<Row>,
    notes: &mut Vec<String>,
    divergences: &mut Vec<Divergence>,
    log: &mut dyn FnMut(&str),
) -> Result<(), ReferenceError> {
    let rel = bundle
        .reference()
        .and_then(|r| r.rollout.clone())
        .unwrap_or_else(|| "reference/rollout.npz".into());
    let path = bundle.path(&rel);
    let reference = ReferenceRollout::load(&path)?;
    let seed = bundle
        .reference()
        .and_then(|r| r.rollout_seed)
        .ok_or_else(|| ref_err(&bundle.manifest_path(), "reference.rollout_seed is missing"))?;
    let s = bundle.sampling();
    if let Some(g) = bundle.reference().and_then(|r| r.rollout_guidance) {
        if g != s.guidance {
            notes.push(format!(
                "the reference rollout was made with guidance {g}, the manifest's default is {}",
                s.guidance
            ));
        }
    }
    let params = SamplingParams {
        seed,
        guidance: s.guidance,
        temperature: s.temperature,
        top_k: s.top_k,
        regions: bundle
            .region_names()
            .iter()
            .map(|r| r.to_string())
            .collect(),
    };
    let mut audio = Vec::with_capacity(clip.len() * reference.clip_repeats);
    for _ in 0..reference.clip_repeats {
        audio.extend_from_slice(clip);
    }
    notes.push(format!(
        "rollout: reference/clip.wav x {} ({:.1} s), seed {seed}, guidance {}, temperature {}, top_k {}, {} torch tokens",
        reference.clip_repeats,
        audio.len() as f64 / 16000.0,
        s.guidance,
        s.temperature,
        s.top_k,
        reference.tokens.len()
    ));
    let opts = StreamOptions {
        seed,
        record_logits: true,
        ..Default::default()
    };
    let torch_trace = RolloutTrace {
        name: "torch".into(),
        tokens: reference.tokens.clone(),
        logits: None,
    };
    let mut runs: Vec<BackendRollout> = Vec::new();
    for (kind, p) in pipelines.iter_mut() {
        let t0 = Instant::now();
        match run_stream(p, &opts, &audio, 16000) {
            Ok(steps) => {
                log(&format!(
                    "rollout on {kind}: {} tokens in {:.1} s",
                    steps.len(),
                    t0.elapsed().as_secs_f64()
                ));
                runs.push(BackendRollout { kind: *kind, steps });
            }
            Err(e) => rows.push(Row::failed(
                Check::Rollout,
                "rollout",
                format!("{kind} vs torch"),
                "tokens",
                0.0,
                format!("{kind} failed: {e:#}"),
            )),
        }
    }
    // each backend vs torch
    for run in &runs {
        let comparison = format!("{} vs torch", run.kind);
        let trace = run.trace();
        let other: Vec<RolloutTrace> = runs
            .iter()
            .filter(|r| r.kind != run.kind)
            .map(BackendRollout::trace)
            .collect();
        let div = find_divergence(&trace, &torch_trace, &params).map_err(|e| ref_err(&path, e))?;
        let div = div.map(|mut d| {
            // margins from the other backend's logits too (torch stored none)
            for o in &other {
                if let Some(l) = o.logits.as_ref().and_then(|l| l.get(d.step as usize)) {
                    let nr = params.regions.len();
                    let k = l.cond.len() / nr;
                    let r = d.region_index;
                    let c = &l.cond[r * k..(r + 1) * k];
                    let un = l.uncond.as_ref().map(|u| &u[r * k..(r + 1) * k]);
                    let u = replay_uniform(seed, nr, d.step, r);
                    if let Ok(m) =
                        sampling_margin(&o.name, c, un, &params, u, d.first_token, d.second_token)
                    {
                        d.margins.push(m);
                    }
                }
            }
            d
        });
        let prefix = div.as_ref().map(|d| d.step as usize).unwrap_or(usize::MAX);
        rows.push(token_row(
            Check::Rollout,
            "rollout",
            &comparison,
            &trace.tokens,
            &reference.tokens,
            div.as_ref().map(|d| d.to_string()),
        ));
        // frames (over the steps before any divergence)
        let n = run.steps.len().min(reference.tokens.len()).min(prefix);
        let fpt = run.steps.first().map(|s| s.frames.len()).unwrap_or(4);
        for (k, name) in FRAME_FIELDS.iter().enumerate() {
            let want = match k {
                0 => &reference.poses,
                1 => &reference.trans,
                2 => &reference.expressions,
                _ => &reference.foot_contact,
            };
            let mut m = MaxAbs::default();
            for st in &run.steps[..n] {
                for fr in &st.frames {
                    let i = fr.index as usize;
                    if i >= want.nrows() {
                        m.problem.get_or_insert_with(|| {
                            format!(
                                "frame {i} is beyond the reference's {} frames",
                                want.nrows()
                            )
                        });
                        continue;
                    }
                    let row = want.row(i);
                    if row.len() != field(fr, k).len() {
                        m.problem.get_or_insert_with(|| {
                            format!(
                                "{name} has {} values per frame, reference {}",
                                field(fr, k).len(),
                                row.len()
                            )
                        });
                        continue;
                    }
                    for (j, (x, y)) in field(fr, k).iter().zip(row.iter()).enumerate() {
                        if (*x as f64 - *y as f64).abs() > m.err || x.is_nan() || m.step.is_none() {
                            m.add_f32(st.token_index, format!("frame {i}, {name}[{j}]"), *x, *y);
                        } else {
                            m.count += 1;
                        }
                    }
                }
            }
            let mut row = Row::max_abs(
                Check::Rollout,
                "rollout",
                &comparison,
                *name,
                &m,
                ROLLOUT_FRAMES,
            );
            if n < run.steps.len().max(reference.tokens.len()) && m.problem.is_none() {
                let d = format!(
                    "frames compared over the first {} frames, before the token divergence",
                    n * fpt
                );
                row.detail = Some(match row.detail {
                    Some(x) => format!("{x}; {d}"),
                    None => d,
                });
            }
            rows.push(row);
        }
        if let Some(d) = div {
            divergences.push(d);
        }
    }
    // tract vs ort
    let ort = runs.iter().find(|r| r.kind == BackendKind::Ort);
    let tract = runs.iter().find(|r| r.kind == BackendKind::Tract);
    if let (Some(o), Some(t)) = (ort, tract) {
        let (to, tt) = (o.trace(), t.trace());
        let div = find_divergence(&tt, &to, &params).map_err(|e| ref_err(&path, e))?;
        let prefix = div.as_ref().map(|d| d.step as usize).unwrap_or(usize::MAX);
        rows.push(token_row(
            Check::Rollout,
            "rollout",
            "tract vs ort",
            &tt.tokens,
            &to.tokens,
            div.as_ref().map(|d| d.to_string()),
        ));
        let n = t.steps.len().min(o.steps.len()).min(prefix);
        frame_rows_steps(
            Check::Rollout,
            "rollout",
            "tract vs ort",
            &[(String::new(), &t.steps[..n], &o.steps[..n])],
            ROLLOUT_FRAMES,
            rows,
        );
        // the fusion logits over the whole rollout (informative; same bound as the graphs)
        let mut m = MaxAbs::default();
        for (a, b) in t.steps[..n].iter().zip(&o.steps[..n]) {
            if let (Some(la), Some(lb)) = (&a.logits, &b.logits) {
                if let (Ok(x), Ok(y)) = (
                    Tensor::f32(vec![la.cond.len()], la.cond.clone()),
                    Tensor::f32(vec![lb.cond.len()], lb.cond.clone()),
                ) {
                    m.add(a.token_index, &x, &y);
                }
            }
        }
        rows.push(Row::max_abs(
            Check::Rollout,
            "rollout",
            "tract vs ort",
            "logits (cond)",
            &m,
            TRACT_VS_ORT,
        ));
        if let Some(d) = div {
            divergences.push(d);
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------- chunks and batches

fn chunk_rows(p: &mut Pipeline, kind: BackendKind, audio: &[f32], seed: u64, rows: &mut Vec<Row>) {
    let opts = StreamOptions {
        seed,
        ..Default::default()
    };
    let comparison = format!("{kind}: chunked vs whole");
    let whole = match run_stream(p, &opts, audio, audio.len()) {
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
        match run_stream(p, &opts, audio, chunk) {
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

fn batch_rows(
    p: &mut Pipeline,
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
        match run_stream(p, o, a, 3200) {
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
        match run_batched(p, &streams[..b], 3200) {
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
                    pass: differing == 0,
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

/// Steps `streams` together with [`Pipeline::step_batch`], feeding each its audio in `chunk`s.
fn run_batched(
    p: &mut Pipeline,
    streams: &[(StreamOptions, Vec<f32>)],
    chunk: usize,
) -> Result<Vec<Vec<TokenStep>>> {
    let mut st = streams
        .iter()
        .map(|(o, _)| p.new_stream(o))
        .collect::<Result<Vec<_>>>()?;
    let mut out: Vec<Vec<TokenStep>> = vec![Vec::new(); streams.len()];
    let len = streams.iter().map(|(_, a)| a.len()).min().unwrap_or(0);
    let mut pos = 0;
    while pos < len {
        let end = (pos + chunk).min(len);
        let mels: Vec<_> = st
            .iter_mut()
            .zip(streams)
            .map(|(s, (_, a))| s.push_audio(&a[pos..end]))
            .collect::<Result<_>>()?;
        let n = mels.iter().map(Vec::len).min().unwrap_or(0);
        for k in 0..n {
            let m: Vec<_> = mels.iter().map(|v| v[k].clone()).collect();
            let mut refs: Vec<&mut _> = st.iter_mut().collect();
            for (i, s) in p.step_batch(&mut refs, &m)?.into_iter().enumerate() {
                out[i].push(s);
            }
        }
        pos = end;
    }
    Ok(out)
}

// ------------------------------------------------------------------------------------------- run

/// Runs the parity suite on the bundle in `dir`. `log` receives progress lines.
///
/// Errors when the bundle is invalid ([`crate::bundle::BundleError`]), a reference file is missing
/// or malformed ([`ReferenceError`]), or a backend cannot start; a graph that a backend cannot load
/// or run becomes a failed row instead.
pub fn run(dir: &Path, opts: &ParityOptions, log: &mut dyn FnMut(&str)) -> Result<Report> {
    let t0 = Instant::now();
    let bundle = Bundle::load(dir)?;
    let mut kinds = opts.backends.clone();
    kinds.sort_by_key(|k| match k {
        BackendKind::Ort => 0,
        BackendKind::Tract => 1,
    });
    kinds.dedup();
    anyhow::ensure!(!kinds.is_empty(), "no backend selected");
    let mut backends: Vec<(BackendKind, Box<dyn Backend>)> = Vec::new();
    for k in &kinds {
        let o = BackendOptions {
            kind: *k,
            ..if *k == BackendKind::Ort {
                opts.ort.clone()
            } else {
                BackendOptions::default()
            }
        };
        backends.push((
            *k,
            backend::create(&o).with_context(|| {
                format!("starting the {k} backend for the parity checks (choose backends with --backends)")
            })?,
        ));
    }
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    let mut divergences = Vec::new();
    let want = |c: Check| opts.checks.contains(&c);

    let clip_rel = bundle
        .reference()
        .and_then(|r| r.clip.clone())
        .unwrap_or_else(|| "reference/clip.wav".into());
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
            graph_rows(&bundle, g, &backends, &mut rows)?;
        }
        log(&format!(
            "graphs: {} graphs on {} in {:.1} s",
            bundle.graphs().len(),
            kinds
                .iter()
                .map(|k| k.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            t.elapsed().as_secs_f64()
        ));
    }

    if want(Check::Logmel) {
        let rel = "reference/logmel.npy";
        let path = bundle.path(rel);
        let f = File::open(&path).map_err(|e| ref_err(&path, format!("cannot open: {e}")))?;
        let want_mel = Array2::<f32>::read_npy(f).map_err(|e| ref_err(&path, e))?;
        match logmel(&clip, bundle.frontend()) {
            Ok(got) => {
                let mut m = MaxAbs::default();
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
                    let mpt = bundle.frontend().mel_frames_per_token as usize;
                    for ((idx, x), y) in got.indexed_iter().zip(want_mel.iter()) {
                        if (*x as f64 - *y as f64).abs() > m.err || x.is_nan() || m.step.is_none() {
                            m.add_f32(
                                (idx.0 / mpt) as u64,
                                format!("mel frame {}, band {}", idx.0, idx.1),
                                *x,
                                *y,
                            );
                        } else {
                            m.count += 1;
                        }
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
    }

    let need_pipeline = [Check::Rollout, Check::Chunks, Check::Batch]
        .into_iter()
        .any(want);
    let mut pipelines: Vec<(BackendKind, Pipeline)> = Vec::new();
    if need_pipeline {
        for (k, be) in &backends {
            match Pipeline::new(&bundle, be.as_ref()) {
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
    if want(Check::Rollout) {
        rollout_rows(
            &bundle,
            &mut pipelines,
            &clip,
            &mut rows,
            &mut notes,
            &mut divergences,
            log,
        )?;
    }
    let seed = bundle.reference().and_then(|r| r.rollout_seed).unwrap_or(0);
    let prefix_len = ((opts.chunk_seconds * 16000.0).round() as usize).clamp(1, clip.len().max(1));
    if want(Check::Chunks) {
        let t = Instant::now();
        let prefix = &clip[..prefix_len.min(clip.len())];
        notes.push(format!(
            "chunks: on the first {:.2} s of reference/clip.wav ({} samples, {} tokens), chunk sizes {:?} samples vs the whole prefix at once",
            prefix.len() as f64 / 16000.0,
            prefix.len(),
            bundle.frontend().n_tokens(prefix.len() as u64),
            CHUNK_SIZES
        ));
        for (k, p) in pipelines.iter_mut() {
            chunk_rows(p, *k, prefix, seed, &mut rows);
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
        for (k, p) in pipelines.iter_mut() {
            batch_rows(p, *k, &clip, prefix_len, seed, &mut rows);
        }
        log(&format!("batch: {:.1} s", t.elapsed().as_secs_f64()));
    }
    Ok(Report {
        bundle: bundle.dir().to_path_buf(),
        backends: kinds.iter().map(|k| k.to_string()).collect(),
        rows,
        notes,
        divergences,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replayed_uniform_matches_the_generator() {
        let mut rng = SplitMix64::new(42);
        let draws: Vec<f64> = (0..12).map(|_| rng.next_f64()).collect();
        assert_eq!(replay_uniform(42, 4, 2, 1), draws[9]);
        assert_eq!(replay_uniform(42, 4, 0, 0), draws[0]);
    }

    #[test]
    fn check_names_parse() {
        for c in Check::ALL {
            assert_eq!(c.name().parse::<Check>().unwrap(), c);
        }
        assert!("nope".parse::<Check>().is_err());
    }

    #[test]
    fn max_abs_tracks_step_and_nan() {
        let mut m = MaxAbs::default();
        let a = Tensor::f32(vec![1, 2], vec![1.0, 2.0]).unwrap();
        let b = Tensor::f32(vec![1, 2], vec![1.0, 2.5]).unwrap();
        m.add(0, &a, &a);
        m.add(3, &a, &b);
        assert_eq!(m.err, 0.5);
        assert_eq!(m.step, Some(3));
        let n = Tensor::f32(vec![1, 2], vec![f32::NAN, 2.0]).unwrap();
        m.add(5, &n, &a);
        assert!(m.err.is_infinite());
        assert_eq!(m.step, Some(5));
    }
}
