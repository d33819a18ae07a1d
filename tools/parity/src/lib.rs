//! The parity suite (docs/parity.md): proves that torch, ONNX Runtime and tract agree on a bundle.
//!
//! [`run`] checks any bundle against the torch reference vectors that travel with it
//! (`docs/bundle.md`) and against itself:
//!
//! | check | what | bound |
//! |---|---|---|
//! | `graph` | every graph, all chained steps of `reference/<graph>.npz` (`n_steps`, 10) from the manifest's zero caches, every output at every step and the caches after the last step: ort vs torch | [`ORT_VS_TORCH`] |
//! | `graph` | the same, tract vs ort (same inputs, each backend chaining its own caches; every output and cache at every step) | [`TRACT_VS_ORT`] |
//! | `graph` | the same, tract vs torch (implied by the two above) | [`TRACT_VS_TORCH`] |
//! | `graph` | torch step-by-step vs torch offline: measured by the exporter (it needs PyTorch) and read from the manifest's `checks` | [`TORCH_STEP_VS_OFFLINE`] |
//! | `graph` | another form's graph (`experts_fused`, `decoders_fused`, `fusion_attention`) vs the canonical graphs in torch: measured by the exporter, read from `checks` | [`TORCH_FUSED_VS_CANONICAL`] |
//! | `rollout` | the whole seeded rollout (`reference/clip.wav` repeated `clip_repeats` times, the manifest's seed and sampling defaults): tokens identical at every step, frames (poses, trans, expressions, foot contact) | [`ROLLOUT_FRAMES`] |
//! | `rollout` | a bundle with several forms (docs/bundle.md#forms-and-precision): on each backend that runs a form other than canonical (the manifest's `backend_forms`, or `--form`), the canonical form's rollout vs that form's: identical tokens, frames | [`ROLLOUT_FRAMES`] |
//! | `logmel` | the Rust log-mel frontend on `reference/clip.wav` vs `reference/logmel.npy` | [`LOGMEL`] |
//! | `chunks` | chunks of 1 sample, 160, 3200, 16000 samples and the whole prefix give identical frames, the stream finished at the end of the prefix as `generate` does (docs/output.md: last partial token completed with silence, `ceil(duration x 30)` frames) (on a prefix of the clip, [`ParityOptions::chunk_seconds`]) | exact |
//! | `batch` | [`LiveGestureModel::step_many_steps`] (the `step_many` that `serve` runs) with 1, 2 and 5 streams (different seeds, audio, one without guidance) vs separate runs: identical tokens, frames | [`BATCH_FRAMES`] (ort), [`TRACT_BATCH_FRAMES`] (tract) |
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
use ndarray_npy::NpzReader;
use serde::Serialize;

mod against;
mod compare;
mod diffsheg;
mod divergence;
mod graphs;
mod invariance;
mod junit;
mod livegesture_checks;
mod reference;
mod report;
mod rollout;

pub use against::{against, AgainstInputError, AgainstOptions, AGAINST_CHECKS};
pub use divergence::{
    find_divergence, replay_uniform, sampling_margin, Divergence, Margin, RolloutTrace,
    SamplingParams,
};
pub use junit::junit_xml;
pub use reference::{ReferenceRollout, ReferenceVectors};
pub use report::{Metric, Report, Row};

use compare::MaxAbs;
use rollout::{frame_rows_steps, run_stream, token_row};

use livegesture::audio::{read_wav_16k_mono, AudioSpan};
use livegesture::backend::{self, Backend, BackendKind, BackendOptions, Tensor, TensorData};
use livegesture::bundle::{Bundle, GraphSpec};
use livegesture::model::livegesture::{
    LiveGestureGraphs, LiveGestureModel, StepLogits, StreamOptions, TokenStep,
};
use livegesture::model::GraphForm;
use livegesture::model::{MotionModel, StreamJob};
use livegesture::output::Frame;
use livegesture::sampling::{guide, Draw, SplitMix64, TokenDistribution};

/// torch step-by-step vs torch offline causal forward (docs/parity.md; measured at export, recorded in the
/// manifest's `checks`).
pub const TORCH_STEP_VS_OFFLINE: f64 = 1e-5;
/// torch fused form vs the canonical graphs it replaces, every output and cache (docs/bundle.md#forms-and-precision; measured
/// at export, recorded in the manifest's `checks`).
pub const TORCH_FUSED_VS_CANONICAL: f64 = 1e-5;
// graph and rollout bounds: defined once, with the checks that run without files or onnxruntime
// (the browser's parity)
pub use livegesture::portable_parity::{
    ORT_VS_TORCH, ROLLOUT_FRAMES, TRACT_VS_ORT, TRACT_VS_TORCH,
};
/// Rust log-mel frontend vs the Python one (docs/parity.md).
pub const LOGMEL: f64 = 1e-4;
/// Batched vs separate stepping, frames, on ort (which computes every row alike: exact in practice).
pub const BATCH_FRAMES: f64 = 1e-6;
/// Batched vs separate stepping, frames, on tract: tract optimises one plan per batch size and its
/// kernels may sum in another order, so graph outputs differ by ~1e-7 between batch sizes, and the
/// rot6d -> axis-angle conversion amplifies that for near-degenerate rot6d (random-weight bundles).
/// The bound is tract's own tolerance (docs/parity.md, "approximate").
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

/// The checks that apply to a bundle of `family` (docs/parity.md): DiffSHEG has no batched stepping.
pub fn family_checks(family: livegesture::bundle::Family) -> &'static [Check] {
    match family {
        livegesture::bundle::Family::LiveGesture => &Check::ALL,
        livegesture::bundle::Family::DiffSheg => {
            &[Check::Graph, Check::Rollout, Check::Logmel, Check::Chunks]
        }
    }
}

/// Why a requested check of a run produced no row: it does not apply to the family (or to
/// `--against`, whose checks are `against_checks`), or it ran and compared nothing.
fn why_no_rows(
    family: livegesture::bundle::Family,
    against_checks: Option<&[Check]>,
) -> impl Fn(Check) -> String + '_ {
    move |c| {
        let names = |cs: &[Check]| cs.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ");
        let of_family = family_checks(family);
        if !of_family.contains(&c) {
            format!(
                "it does not apply to a {family} bundle (its checks: {})",
                names(of_family)
            )
        } else if let Some(a) = against_checks.filter(|a| !a.contains(&c)) {
            format!(
                "--against compares {} only (run '{c}' without --against)",
                names(a)
            )
        } else {
            "it ran but produced no comparison".into()
        }
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct ParityOptions {
    /// Backends, each run on its own; ort is the reference of tract when both run.
    pub backends: Vec<BackendKind>,
    /// Settings of the ort backend (library, execution provider, threads).
    pub ort: BackendOptions,
    /// Checks to run; empty (the default): every check that applies to the bundle's family
    /// ([`family_checks`]; with `--against`, [`AGAINST_CHECKS`]). A check named here that does not
    /// apply, or that compares nothing, is a failed row naming it.
    pub checks: Vec<Check>,
    /// Seconds of the reference clip used by the chunk and batch checks.
    pub chunk_seconds: f64,
    /// The form of the region eXperts and decoders the pipeline checks run (auto: the bundle's form
    /// per backend).
    pub form: GraphForm,
    /// Judge the run as a deployment target (docs/targets.md): tract's graph
    /// rows against the torch references within [`TRACT_VS_ORT`] (1e-4, scaled) instead of
    /// [`TRACT_VS_TORCH`]; a rollout whose tokens diverge passes when its first divergence is a
    /// near-tie ([`Divergence::near_tie`]), with every frame before it within [`ROLLOUT_FRAMES`];
    /// a divergence that is not a near-tie (or whose margin is unknown) fails.
    pub target: bool,
}

impl Default for ParityOptions {
    fn default() -> Self {
        Self {
            backends: vec![BackendKind::Ort, BackendKind::Tract],
            ort: BackendOptions {
                kind: BackendKind::Ort,
                ..Default::default()
            },
            checks: Vec::new(),
            chunk_seconds: 3.0,
            form: GraphForm::Auto,
            target: false,
        }
    }
}

// ------------------------------------------------------------------------------------------- run

/// The checks of the bundle's family: each family's own module appends its rows, notes and
/// divergences (`livegesture_checks`, `diffsheg`).
struct FamilyChecks<'a, 'l> {
    backends: &'a [(BackendKind, Box<dyn Backend>)],
    opts: &'a ParityOptions,
    rows: &'a mut Vec<Row>,
    notes: &'a mut Vec<String>,
    divergences: &'a mut Vec<Divergence>,
    log: &'a mut (dyn FnMut(&str) + 'l),
}

impl livegesture::model::FamilyTool for FamilyChecks<'_, '_> {
    type Output = Result<()>;
    fn livegesture(self, bundle: &Bundle) -> Result<()> {
        livegesture_checks::run(
            bundle,
            self.backends,
            self.opts,
            self.rows,
            self.notes,
            self.divergences,
            self.log,
        )
    }
    fn diffsheg(self, bundle: &Bundle) -> Result<()> {
        // DiffSHEG's rollout is compared frame by frame (no sampled tokens): it reports no divergences
        diffsheg::run(
            bundle,
            self.backends,
            self.opts,
            self.rows,
            self.notes,
            self.log,
        )
    }
}

/// Runs the parity suite on the bundle in `dir`. `log` receives progress lines.
///
/// Errors when the bundle is invalid ([`livegesture::bundle::BundleError`]), a reference file is missing
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
    // no check named: every check of the family
    let resolved;
    let opts = if opts.checks.is_empty() {
        resolved = ParityOptions {
            checks: family_checks(bundle.family()).to_vec(),
            ..opts.clone()
        };
        &resolved
    } else {
        opts
    };
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
    if let Some(p) = &bundle.manifest().precision {
        if bundle.is_reduced_precision() {
            // docs/bundle.md#forms-and-precision: a reduced-precision bundle's graphs are checked against the
            // f32 bundle's torch reference vectors with the bound the tool that derived it measured and
            // stated per graph; its rollout against the one that tool stepped with the reduced graphs
            notes.push(format!(
                "precision {}: graph rows 'vs f32 torch' compare with the f32 bundle's torch reference vectors, each with the bound stated in checks.<graph>.reduced_vs_f32_torch_bound; rollout rows 'vs reference' with the reduced graphs' own rollout ({}); tract vs ort keeps its 1e-4 bound; error against the f32 model (manifest precision.error_vs_f32): {}",
                p.weights,
                p.reference.as_deref().unwrap_or("producer not stated"),
                summarise_precision_error(&p.error_vs_f32)
            ));
        }
    }

    livegesture::model::for_family(
        &bundle,
        FamilyChecks {
            backends: &backends,
            opts,
            rows: &mut rows,
            notes: &mut notes,
            divergences: &mut divergences,
            log: &mut *log,
        },
    )?;
    if opts.target {
        target_graph_bounds(&mut rows);
    }
    report::fail_checks_without_rows(&mut rows, &opts.checks, why_no_rows(bundle.family(), None));
    Ok(Report {
        bundle: bundle.dir().to_path_buf(),
        backends: kinds.iter().map(|k| k.to_string()).collect(),
        rows,
        notes,
        divergences,
        runtimes: backend::runtime_versions(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// docs/targets.md: tract on any instruction set within 1e-4 (scaled) of the torch references.
/// The suite's own tract-vs-torch bound is [`TRACT_VS_TORCH`] (ort's bound plus tract's against
/// ort); a target run tightens those rows to [`TRACT_VS_ORT`] and judges them again.
fn target_graph_bounds(rows: &mut [Row]) {
    for r in rows.iter_mut() {
        if r.check == Check::Graph
            && r.metric == Metric::MaxAbs
            && r.bound == TRACT_VS_TORCH
            && r.comparison.starts_with("tract vs ")
        {
            r.bound = TRACT_VS_ORT;
            r.pass = r.pass && r.error <= TRACT_VS_ORT * r.scale;
        }
    }
}

/// One line of a reduced bundle's recorded error against the f32 model: the worst graph output and the
/// rollout's token agreement.
fn summarise_precision_error(e: &serde_json::Value) -> String {
    let worst = e["graphs_max_abs"].as_object().map(|g| {
        g.iter()
            .flat_map(|(name, outs)| {
                outs.as_object()
                    .into_iter()
                    .flatten()
                    .filter_map(move |(o, v)| v.as_f64().map(|x| (x, format!("{name}.{o}"))))
            })
            .fold(
                (0.0f64, String::new()),
                |a, b| if b.0 > a.0 { b } else { a },
            )
    });
    let mut parts = Vec::new();
    if let Some((x, what)) = worst {
        parts.push(format!("graphs max abs {x:.3e} ({what})"));
    }
    let r = &e["rollout"];
    if let Some(t) = r["teacher_forced_identical_tokens"].as_f64() {
        parts.push(format!("teacher-forced identical tokens {:.2}%", 100.0 * t));
    }
    if let Some(t) = r["free_running_identical_tokens"].as_f64() {
        parts.push(format!("free-running identical tokens {:.2}%", 100.0 * t));
    }
    if parts.is_empty() {
        "not recorded".into()
    } else {
        parts.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn divergence(cdf_margin: f64, token_gap: f64) -> Divergence {
        Divergence {
            first: "tract".into(),
            second: "torch".into(),
            step: 7,
            region: "hands".into(),
            region_index: 1,
            first_token: 3,
            second_token: 4,
            differing_steps: 20,
            margins: vec![Margin {
                source: "tract".into(),
                sampled: 3,
                uniform: 0.5,
                cdf_margin,
                token_gap,
                top2_gap: 0.1,
                p_first: 0.3,
                p_second: 0.3,
            }],
            logit_difference: None,
        }
    }

    /// docs/targets.md: a divergence passes a target run only when it is a near-tie.
    #[test]
    fn target_rule_accepts_only_near_tie_divergences() {
        let a: Vec<Vec<i64>> = (0..30).map(|t| vec![t, 1, 2, 3]).collect();
        let mut b = a.clone();
        for t in b.iter_mut().skip(7) {
            t[1] = 4;
        }
        let row = || rollout::token_row(Check::Rollout, "rollout", "tract vs torch", &b, &a, None);
        let near = divergence(2e-4, 0.5);
        let far = divergence(0.2, 0.5);
        // the suite's own rule: any divergence fails
        assert!(!row().pass);
        assert!(!rollout::target_token_row(row(), Some(&near), true, false).pass);
        // a target run: a near-tie passes, a real difference, an unknown margin or a length change fails
        assert!(rollout::target_token_row(row(), Some(&near), true, true).pass);
        assert!(!rollout::target_token_row(row(), Some(&far), true, true).pass);
        let mut unknown = near.clone();
        unknown.margins.clear();
        assert!(!rollout::target_token_row(row(), Some(&unknown), true, true).pass);
        assert!(!rollout::target_token_row(row(), Some(&near), false, true).pass);
        assert!(!rollout::target_token_row(row(), None, true, true).pass);
    }

    /// docs/targets.md: tract within 1e-4 (scaled) of torch, tighter than the suite's 1.1e-4.
    #[test]
    fn target_rule_tightens_tract_vs_torch_graph_rows() {
        let mut m = MaxAbs::default();
        let x = Tensor::f32(vec![2], vec![0.5, 1.0]).unwrap();
        let y = Tensor::f32(vec![2], vec![0.5, 1.0 + 1.05e-4]).unwrap();
        m.add(0, &x, &y);
        let tract = Row::max_abs(
            Check::Graph,
            "g",
            "tract vs torch",
            "out",
            &m,
            TRACT_VS_TORCH,
        );
        let ort = Row::max_abs(Check::Graph, "g", "ort vs torch", "out", &m, ORT_VS_TORCH);
        assert!(tract.pass && !ort.pass);
        let mut rows = vec![tract, ort];
        target_graph_bounds(&mut rows);
        assert!(
            !rows[0].pass,
            "1.05e-4 is over the target's 1e-4: {:?}",
            rows[0]
        );
        assert_eq!(rows[0].bound, TRACT_VS_ORT);
        assert_eq!(rows[1].bound, ORT_VS_TORCH);
    }

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
        assert_eq!(m.scale, 2.5);
        assert_eq!(m.step, Some(3));
        // a NaN on either side fails, whatever the bound
        for (x, y) in [(0, 1), (1, 0)] {
            let n = Tensor::f32(vec![1, 2], vec![f32::NAN, 2.0]).unwrap();
            let pair = [&n, &a];
            let mut m = MaxAbs::default();
            m.add(5, pair[x], pair[y]);
            assert!(m.err.is_infinite() && !m.within(f64::MAX), "{m:?}");
            assert_eq!(m.step, Some(5));
            assert!(m.problem.as_deref().unwrap_or("").contains("non-finite"));
        }
        // nothing compared fails
        assert!(!MaxAbs::default().within(1.0));
    }

    /// docs/parity.md: bounds scale with the reference's magnitude. Values near 40 a few float32 ulps
    /// apart pass 1e-5 (absolute error above 1e-5); the same absolute error near 1 fails.
    #[test]
    fn the_bound_scales_with_the_reference() {
        let reference: Vec<f32> = (0..32).map(|i| 39.0 + i as f32 * 0.05).collect();
        let mut got = reference.clone();
        let ulp = 32.0f32 * f32::EPSILON; // the spacing of float32 values in [32, 64)
        got[20] += 4.0 * ulp;
        let (g, r) = (
            Tensor::f32(vec![32], got.clone()).unwrap(),
            Tensor::f32(vec![32], reference.clone()).unwrap(),
        );
        let mut m = MaxAbs::default();
        m.add(0, &g, &r);
        assert!(
            m.err > 1e-5,
            "the absolute error must exceed 1e-5: {}",
            m.err
        );
        assert!(m.within(ORT_VS_TORCH), "{m:?}");
        let row = Row::max_abs(
            Check::Graph,
            "g",
            "ort vs torch",
            "hidden",
            &m,
            ORT_VS_TORCH,
        );
        assert!(row.pass && row.scale > 39.0);
        // the same absolute error on values near 1 fails, and the failure names the scale
        let small: Vec<f32> = reference.iter().map(|x| x / 40.0).collect();
        let mut bad = small.clone();
        bad[7] += m.err as f32;
        let mut m = MaxAbs::default();
        m.add(
            2,
            &Tensor::f32(vec![32], bad).unwrap(),
            &Tensor::f32(vec![32], small).unwrap(),
        );
        let row = Row::max_abs(
            Check::Graph,
            "g",
            "ort vs torch",
            "hidden",
            &m,
            ORT_VS_TORCH,
        );
        assert!(!row.pass);
        let line = row.failure_line();
        for part in ["g", "hidden", "step 2", "x scale"] {
            assert!(line.contains(part), "{line}");
        }
        // an absolute comparison ignores the magnitude
        let mut m = MaxAbs::absolute();
        m.add(0, &g, &r);
        assert!(!m.within(ORT_VS_TORCH) && m.scale == 1.0);
    }

    /// The margin's draw is the sampler's own (one definition): the same token for every seed,
    /// including exact ties between -0.0 and 0.0, which the sampler orders by index as numpy does.
    #[test]
    fn margins_replay_the_samplers_draw() {
        use livegesture::sampling::sample_token;
        let cases: [(&[f32], Option<&[f32]>); 2] = [
            (&[-0.0, 0.0, -3.0, 0.0], None),
            (
                &[0.25, -1.0, 1.5, 1.5, -2.0],
                Some(&[0.5, -1.0, 1.0, 1.5, -1.0]),
            ),
        ];
        for (cond, uncond) in cases {
            for (gamma, temperature, top_k) in [(1.0, 1.0, 1), (1.25, 0.7, 3), (2.0, 1.3, 0)] {
                for seed in 0..100u64 {
                    let p = SamplingParams {
                        seed,
                        guidance: gamma,
                        temperature,
                        top_k,
                        regions: vec!["r".into()],
                    };
                    let u = replay_uniform(seed, 1, 0, 0);
                    let mut rng = SplitMix64::new(seed);
                    let tok =
                        sample_token(cond, uncond, &mut rng, gamma, temperature, top_k).unwrap();
                    let m = sampling_margin("x", cond, uncond, &p, u, tok as i64, 0).unwrap();
                    assert_eq!(
                        m.sampled, tok as i64,
                        "seed {seed}, gamma {gamma}, top-k {top_k}"
                    );
                }
            }
        }
    }
}
