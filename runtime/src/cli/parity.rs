//! `livegesture parity`: the parity suite (docs/parity.md) on a bundle, as a table.
//!
//! Runs [`livegesture::parity::run`] and prints one row per comparison (rows of one graph and
//! comparison that all pass are summarised by their worst output unless `--all`), then the notes,
//! any token divergence with its sampling margin, and every failure on a line of its own.
//! Exit code 0 when everything passes, 1 when any comparison fails, 2 for bad input (no bundle, a
//! missing or malformed reference file, bad arguments).

use std::path::PathBuf;

use anyhow::{Context, Result};

use livegesture::backend::{BackendKind, BackendOptions};
use livegesture::bundle::default_bundle_dir;
use livegesture::model::livegesture::FormChoice;
use livegesture::parity::{self, Check, ParityOptions, ReferenceError};

use super::common::{BackendArg, InputError};

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Examples:\n  livegesture parity --bundle models/default\n  \
    livegesture parity --bundle target/tiny-bundle --backends tract --checks graph,logmel --json parity.json"
)]
pub struct Args {
    /// Model bundle folder (default: $LIVEGESTURE_BUNDLE, else the repository's models/default).
    #[arg(long, value_name = "DIR")]
    pub bundle: Option<PathBuf>,
    /// Backends to check, comma-separated (ort is the reference of tract when both run).
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [BackendArg::Ort, BackendArg::Tract])]
    pub backends: Vec<BackendArg>,
    /// Checks to run, comma-separated: graph, rollout, logmel, chunks, batch (default: all).
    #[arg(long, value_delimiter = ',', value_name = "CHECKS")]
    pub checks: Vec<Check>,
    /// Seconds of the reference clip used by the chunk-size and batch checks.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    pub chunk_seconds: f64,
    /// Write every row (and notes, divergences) as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Show every output's row, not only the worst of each passing group.
    #[arg(long)]
    pub all: bool,
    /// ONNX Runtime shared library for the ort backend (default: $ORT_DYLIB_PATH, else searched).
    #[arg(long, value_name = "PATH")]
    pub ort_lib: Option<PathBuf>,
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

pub fn run(a: Args, form: FormChoice) -> Result<()> {
    if !(a.chunk_seconds.is_finite() && a.chunk_seconds > 0.0) {
        return Err(InputError(format!(
            "--chunk-seconds must be > 0, got {}",
            a.chunk_seconds
        ))
        .into());
    }
    if let Some(parent) = a
        .json
        .as_ref()
        .and_then(|j| j.parent())
        .filter(|p| !p.as_os_str().is_empty())
    {
        if !parent.is_dir() {
            return Err(InputError(format!(
                "--json: the folder {} does not exist",
                parent.display()
            ))
            .into());
        }
    }
    let dir = default_bundle_dir(a.bundle.as_deref());
    let opts = ParityOptions {
        backends: a.backends.iter().map(|&b| b.into()).collect(),
        ort: BackendOptions {
            kind: BackendKind::Ort,
            ort_library: a.ort_lib.clone(),
            ..Default::default()
        },
        checks: if a.checks.is_empty() {
            Check::ALL.to_vec()
        } else {
            a.checks.clone()
        },
        chunk_seconds: a.chunk_seconds,
        form,
    };
    if form != FormChoice::Auto {
        super::common::check_form(&livegesture::bundle::Bundle::load(&dir)?, form)?;
    }
    let quiet = a.quiet;
    let mut log = |m: &str| {
        if !quiet {
            eprintln!("parity: {m}");
        }
    };
    if !quiet {
        eprintln!("parity: checking {}", dir.display());
    }
    let report = match parity::run(&dir, &opts, &mut log) {
        Ok(r) => r,
        Err(e) if e.chain().any(|c| c.is::<ReferenceError>()) => {
            return Err(InputError(format!("{e:#} (the bundle's reference vectors are incomplete; re-export it with export/export.py)")).into())
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
    if report.passed() {
        Ok(())
    } else {
        Err(ParityFailed {
            failed: report.failures().len(),
            total: report.rows.len(),
        }
        .into())
    }
}
