//! `livegesture parity`: the parity suite (docs/parity.md) on a bundle, as a table.
//!
//! Runs [`livegesture_parity::run`] and prints one row per comparison (rows of one graph and
//! comparison that all pass are summarised by their worst output unless `--all`), then the notes,
//! any token divergence with its sampling margin, and every failure on a line of its own.
//! Exit code 0 when everything passes, 1 when any comparison fails, 2 for bad input (no bundle, a
//! missing or malformed reference file, bad arguments).
//!
//! `--against OLD` checks the bundle against a previous export instead ([`livegesture_parity::against`]):
//! every graph both carry on the same teacher-forced inputs, the rollout's tokens and frames on the
//! same audio and seed, with bounds set by `--against-graph-bound`, `--against-frames-bound` and
//! `--against-token-agreement`. `--junit FILE` writes the report as JUnit XML beside the table.

use std::path::PathBuf;

use anyhow::{Context, Result};

use livegesture::backend::{BackendKind, BackendOptions};
use livegesture::bundle::default_bundle_dir;
use livegesture::model::GraphForm;
use livegesture_parity::{self as parity, AgainstOptions, Check, ParityOptions, ReferenceError};

use super::common::{BackendArg, InputError};

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Examples:\n  livegesture parity --bundle models/default\n  \
    livegesture parity --bundle target/tiny-bundle --backends tract --checks graph,logmel --json parity.json\n  \
    livegesture parity --bundle new-export --against models/default --junit parity.xml"
)]
pub struct Args {
    /// Model bundle folder (default: $LIVEGESTURE_BUNDLE, else the repository's models/default).
    #[arg(long, value_name = "DIR")]
    pub bundle: Option<PathBuf>,
    /// Backends to check, comma-separated (ort is the reference of tract when both run).
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [BackendArg::Ort, BackendArg::Tract])]
    pub backends: Vec<BackendArg>,
    /// Checks to run, comma-separated: graph, rollout, logmel, chunks, batch (default: every check
    /// that applies to the bundle; a named check that does not apply fails, saying so).
    #[arg(long, value_delimiter = ',', value_name = "CHECKS")]
    pub checks: Vec<Check>,
    /// Seconds of the reference clip used by the chunk-size and batch checks.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    pub chunk_seconds: f64,
    /// Write every row (and notes, divergences) as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Write the report as JUnit XML to this file (one test case per comparison).
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
    /// Check the bundle against this previous export of the model instead of its own reference
    /// vectors: every graph both carry on the same teacher-forced inputs, and the rollout (tokens
    /// and frames) on the same audio and seed (docs/parity.md).
    #[arg(long, value_name = "OLD_BUNDLE")]
    pub against: Option<PathBuf>,
    /// With --against: bound on every graph output, scaled by the old output's magnitude.
    #[arg(long, value_name = "B", default_value_t = AgainstOptions::default().graph_bound, requires = "against")]
    pub against_graph_bound: f64,
    /// With --against: bound on every rollout frame field, scaled like the graph bound.
    #[arg(long, value_name = "B", default_value_t = AgainstOptions::default().frames_bound, requires = "against")]
    pub against_frames_bound: f64,
    /// With --against: the fraction of rollout steps whose tokens must be identical (0..1).
    #[arg(long, value_name = "F", default_value_t = AgainstOptions::default().token_agreement, requires = "against")]
    pub against_token_agreement: f64,
    /// Judge the run as this deployment target (docs/targets.md), e.g. `aarch64`:
    /// tract within 1e-4 (scaled) of the torch references, a rollout divergence passes only as a
    /// near-tie with every frame before it within bound; the JSON report gains a `target` object
    /// naming the target and the instruction set and kernels tract chose (scripts/targets.sh).
    #[arg(long, value_name = "NAME")]
    pub target_name: Option<String>,
    /// Show every output's row, not only the worst of each passing group.
    #[arg(long)]
    pub all: bool,
    /// ONNX Runtime shared library for the ort backend (default: $ORT_DYLIB_PATH, else searched).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    /// Execution provider of the ort backend: cpu, openvino, webgpu, xnnpack, cuda, qnn (the library
    /// must have it; docs/targets.md). The graphs are judged at the bound of ONNX Runtime's
    /// CPU provider (1e-5 scaled, docs/parity.md).
    #[arg(long, value_name = "EP", default_value = "cpu")]
    pub ep: String,
    /// No progress lines on stderr.
    #[arg(short, long)]
    pub quiet: bool,
}

/// A parity run in which some comparison failed (exit code 1).
#[derive(Debug, thiserror::Error)]
#[error("parity: {failed} of {total} comparisons failed")]
pub struct ParityFailed {
    pub failed: usize,
    pub total: usize,
}

// long: the command's steps in order (options, the suite, the report as text, JSON and JUnit, the exit)
pub fn run(a: Args, form: GraphForm) -> Result<()> {
    if !(a.chunk_seconds.is_finite() && a.chunk_seconds > 0.0) {
        return Err(InputError::new(format!(
            "--chunk-seconds must be > 0, got {}",
            a.chunk_seconds
        ))
        .into());
    }
    for (flag, file) in [("--json", &a.json), ("--junit", &a.junit)] {
        if let Some(parent) = file
            .as_ref()
            .and_then(|j| j.parent())
            .filter(|p| !p.as_os_str().is_empty())
        {
            if !parent.is_dir() {
                return Err(InputError::new(format!(
                    "{flag}: the folder {} does not exist",
                    parent.display()
                ))
                .into());
            }
        }
    }
    let against = AgainstOptions {
        graph_bound: a.against_graph_bound,
        frames_bound: a.against_frames_bound,
        token_agreement: a.against_token_agreement,
    };
    if a.against.is_some() {
        for (flag, v, ok) in [
            (
                "--against-graph-bound",
                against.graph_bound,
                against.graph_bound >= 0.0,
            ),
            (
                "--against-frames-bound",
                against.frames_bound,
                against.frames_bound >= 0.0,
            ),
            (
                "--against-token-agreement",
                against.token_agreement,
                (0.0..=1.0).contains(&against.token_agreement),
            ),
        ] {
            if !(v.is_finite() && ok) {
                return Err(InputError::new(format!(
                    "{flag} must be {}, got {v}",
                    if flag.ends_with("agreement") {
                        "in 0..1"
                    } else {
                        "a number >= 0"
                    }
                ))
                .into());
            }
        }
    }
    let dir = default_bundle_dir(a.bundle.as_deref());
    let opts = ParityOptions {
        backends: a.backends.iter().map(|&b| b.into()).collect(),
        ort: BackendOptions {
            kind: BackendKind::Ort,
            ort_library: a.ort_lib.clone(),
            execution_provider: a.ep.clone(),
            ..Default::default()
        },
        // none named: every check that applies to the bundle (a named one that does not is a failed row)
        checks: a.checks.clone(),
        chunk_seconds: a.chunk_seconds,
        form,
        target: a.target_name.is_some(),
    };
    if form != GraphForm::Auto {
        super::common::check_form(&livegesture::bundle::Bundle::load(&dir)?, form)?;
    }
    let quiet = a.quiet;
    let mut log = |m: &str| {
        if !quiet {
            eprintln!("parity: {m}");
        }
    };
    if !quiet {
        match &a.against {
            Some(old) => eprintln!(
                "parity: checking {} against {}",
                dir.display(),
                old.display()
            ),
            None => eprintln!("parity: checking {}", dir.display()),
        }
    }
    let result = match &a.against {
        Some(old) => {
            if !old.join("manifest.json").is_file() {
                return Err(InputError::new(format!(
                    "--against {}: no manifest.json there (expected a bundle folder)",
                    old.display()
                ))
                .into());
            }
            parity::against(&dir, old, &opts, &against, &mut log)
        }
        None => parity::run(&dir, &opts, &mut log),
    };
    let report = match result {
        Ok(r) => r,
        Err(e) if e.chain().any(|c| c.is::<ReferenceError>()) => {
            return Err(InputError::new(format!("{e:#} (the bundle's reference vectors are incomplete; re-export it with export/export.py)")).into())
        }
        Err(e) if e.chain().any(|c| c.is::<parity::AgainstInputError>()) => {
            return Err(InputError::new(format!("{e:#}")).into())
        }
        Err(e) => return Err(e),
    };
    print!("{}", report.table(a.all));
    println!();
    print!("{}", report.summary());
    let target = a.target_name.as_ref().map(|name| {
        let t = target_report(name, &report);
        println!("target {name}: {}", t["cpu"]);
        t
    });
    if let Some(path) = &a.json {
        let mut value = serde_json::to_value(&report)?;
        if let Some(obj) = value.as_object_mut() {
            obj.insert("passed".into(), report.passed().into());
            if let Some(t) = target {
                obj.insert("target".into(), t);
            }
        }
        let text = serde_json::to_string_pretty(&value)?;
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &a.junit {
        std::fs::write(path, parity::junit_xml(&report))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if report.passed() {
        Ok(())
    } else {
        Err(ParityFailed {
            failed: report.failures().len().max(1),
            total: report.rows.len(),
        }
        .into())
    }
}

/// The `target` object of a `--target-name` report: the target's name, the instruction set the
/// process sees and what tract chose on it, and the per-target summary docs/targets.md tabulates
/// (comparisons, worst scaled error per graph, tokens identical before the first divergence).
fn target_report(name: &str, report: &parity::Report) -> serde_json::Value {
    use livegesture_parity::Metric;
    use serde_json::json;
    let mut worst: std::collections::BTreeMap<String, f64> = Default::default();
    for r in report.rows.iter().filter(|r| {
        r.check == Check::Graph && r.metric == Metric::MaxAbs && r.comparison.contains(" vs ")
    }) {
        let key = format!("{} {}", r.what, r.comparison);
        let e = if r.error.is_finite() {
            r.error / r.scale.max(f64::MIN_POSITIVE)
        } else {
            f64::INFINITY
        };
        let w = worst.entry(key).or_insert(0.0);
        *w = w.max(e);
    }
    let tokens: Vec<serde_json::Value> = report
        .rows
        .iter()
        .filter(|r| r.metric == Metric::DifferingSteps)
        .map(|r| {
            json!({
                "what": r.what, "comparison": r.comparison, "steps": r.compared,
                "identical_before_divergence": r.step.unwrap_or(r.compared),
                "differing_steps": r.error, "pass": r.pass,
            })
        })
        .collect();
    json!({
        "name": name,
        "build_target": env!("LIVEGESTURE_TARGET"),
        "cpu": cpu_report(),
        "comparisons": report.rows.len(),
        "failed": report.failures().len(),
        "worst_scaled_error_per_graph": worst.into_iter()
            .map(|(k, v)| (k, if v.is_finite() { json!(v) } else { json!(null) }))
            .collect::<serde_json::Map<_, _>>(),
        "tokens": tokens,
        "divergences": report.divergences.iter().map(|d| json!({
            "between": format!("{} vs {}", d.first, d.second), "step": d.step, "region": d.region,
            "near_tie": d.near_tie(),
            "cdf_margin": d.margins.iter().map(|m| m.cdf_margin).fold(f64::INFINITY, f64::min),
        })).collect::<Vec<_>>(),
    })
}

/// The instruction set this process sees and what tract's linear algebra chose on it (its ISA
/// ladder rung, matrix-multiply tiers and f32 kernels, element-wise kernels), and the CPU features
/// ONNX Runtime's MLAS dispatches on (it picks its kernels from CPUID at start and does not report
/// them; under `qemu-x86_64 -cpu MODEL` CPUID is the model's).
fn cpu_report() -> serde_json::Value {
    use serde_json::json;
    use tract_onnx::tract_core::tract_linalg as linalg;
    let isa = linalg::isa::native();
    let f32 = tract_onnx::prelude::DatumType::F32;
    // the f32 kernels written for this architecture that this build compiled and this CPU runs (the
    // portable Rust ones left out). Not "needs a feature": NEON is aarch64's baseline, so arm64simd's
    // kernels need nothing and a filter on that dropped them all.
    let mmm: Vec<String> = linalg::mmm_routines::runnable_for(&isa)
        .iter()
        .filter(|k| k.internal_type() == f32 && k.arch().is_some() && k.built())
        .map(|k| k.name().to_string())
        .collect();
    // the kernel tract's dispatch picks for plain f32 matmuls of the shapes a step graph runs: a
    // matrix times one column (one frame), a few columns, a block, and a column count unknown
    // when the plan is made
    let picks: serde_json::Map<String, serde_json::Value> = [
        ("m256_k256_n1", Some(1)),
        ("m256_k256_n8", Some(8)),
        ("m256_k256_n64", Some(64)),
        ("m256_k256_n?", None),
    ]
    .into_iter()
    .map(|(label, n)| {
        let q = linalg::mmm::Query::plain(f32, Some(256), Some(256), n);
        let pick = linalg::MmmDispatch::native()
            .pick(&q)
            .map(|(k, _, _)| k.name().to_string());
        (label.to_string(), json!(pick))
    })
    .collect();
    let routines: serde_json::Map<String, serde_json::Value> = [
        ("sigmoid", linalg::Func::Sigmoid),
        ("tanh", linalg::Func::Tanh),
        ("exp", linalg::Func::Exp),
        ("erf", linalg::Func::Erf),
        ("softmax_rows", linalg::Func::SoftmaxRows),
        ("reduce_sum", linalg::Func::ReduceSum),
    ]
    .into_iter()
    .map(|(n, f)| {
        (
            n.to_string(),
            json!(
                linalg::routines::best_for(f, tract_onnx::prelude::DatumType::F32, &isa)
                    .map(|r| r.name())
            ),
        )
    })
    .collect();
    #[allow(unused_mut)]
    let mut features: Vec<&str> = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        for (n, on) in [
            ("sse4.2", std::arch::is_x86_feature_detected!("sse4.2")),
            ("avx", std::arch::is_x86_feature_detected!("avx")),
            ("avx2", std::arch::is_x86_feature_detected!("avx2")),
            ("fma", std::arch::is_x86_feature_detected!("fma")),
            ("avx512f", std::arch::is_x86_feature_detected!("avx512f")),
        ] {
            if on {
                features.push(n);
            }
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        for (n, on) in [
            ("neon", std::arch::is_aarch64_feature_detected!("neon")),
            ("fp16", std::arch::is_aarch64_feature_detected!("fp16")),
            (
                "dotprod",
                std::arch::is_aarch64_feature_detected!("dotprod"),
            ),
            ("i8mm", std::arch::is_aarch64_feature_detected!("i8mm")),
            ("sve", std::arch::is_aarch64_feature_detected!("sve")),
        ] {
            if on {
                features.push(n);
            }
        }
    }
    json!({
        "arch": std::env::consts::ARCH,
        "cpu_features": features,
        "tract_isa": format!("{isa:?}"),
        "tract_rung": isa.nickname(),
        "tract_mmm_tiers": linalg::mmm_tiers::for_isa(&isa).iter().map(|t| t.name).collect::<Vec<_>>(),
        "tract_f32_mmm_kernels": mmm,
        "tract_f32_mmm_picks": picks,
        "tract_f32_routines": routines,
        "ort": "MLAS dispatches on cpu_features (CPUID); it does not report its kernels",
    })
}
