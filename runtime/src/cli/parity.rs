//! `livegesture parity`: the parity suite (docs/parity.md) on a bundle, as a table.
//!
//! Runs [`livegesture::parity::run`] and prints one row per comparison (rows of one graph and
//! comparison that all pass are summarised by their worst output unless `--all`), then the notes,
//! any token divergence with its sampling margin, and every failure on a line of its own.
//! Exit code 0 when everything passes, 1 when any comparison fails, 2 for bad input (no bundle, a
//! missing or malformed reference file, bad arguments).
//!
//! `--against OLD` checks the bundle against a previous export instead ([`livegesture::parity::against`]):
//! every graph both carry on the same teacher-forced inputs, the rollout's tokens and frames on the
//! same audio and seed, with bounds set by `--against-graph-bound`, `--against-frames-bound` and
//! `--against-token-agreement`. `--junit FILE` writes the report as JUnit XML beside the table.

use std::path::PathBuf;

use anyhow::{Context, Result};

use livegesture::backend::{BackendKind, BackendOptions};
use livegesture::bundle::default_bundle_dir;
use livegesture::model::GraphForm;
use livegesture::parity::{self, AgainstOptions, Check, ParityOptions, ReferenceError};

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
    /// Show every output's row, not only the worst of each passing group.
    #[arg(long)]
    pub all: bool,
    /// ONNX Runtime shared library for the ort backend (default: $ORT_DYLIB_PATH, else searched).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
    /// Execution provider of the ort backend: cpu, openvino, webgpu, xnnpack, cuda, qnn (the library
    /// must have it; docs/targets-providers.md). The graphs are judged at the bound of ONNX Runtime's
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
    if let Some(path) = &a.json {
        let mut value = serde_json::to_value(&report)?;
        if let Some(obj) = value.as_object_mut() {
            obj.insert("passed".into(), report.passed().into());
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
