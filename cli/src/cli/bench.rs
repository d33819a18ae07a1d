//! `livegesture bench`: per-graph and whole-chain step times, first-frame latency, state and memory,
//! batched streams per core (see the `livegesture_bench` module). One thread; `scripts/bench.sh` runs
//! the whole matrix.

use std::path::PathBuf;

use anyhow::{Context, Result};

use livegesture::model::GraphForm;
use livegesture_bench::{run_family, BenchConfig};

use super::common::{GenArgs, InputError, ModelArgs};

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  livegesture bench --bundle models/default --backend ort --streams 1,8,32,128 --json ort.json"
)]
pub struct Args {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Audio fed to the streams, repeated as needed (default: the bundle's reference clip).
    #[arg(long, value_name = "WAV")]
    pub audio: Option<PathBuf>,
    /// The streams' options, as `generate` takes them (benchmarks are quoted with the bundle's
    /// guidance, on).
    #[command(flatten)]
    pub gen: GenArgs,
    /// Untimed single-stream warm-up steps.
    #[arg(long, default_value_t = 20)]
    pub warmup: usize,
    /// Timed single-stream token steps.
    #[arg(long, default_value_t = 300)]
    pub steps: usize,
    /// First-frame latency trials (fresh streams fed at real-time pace).
    #[arg(long, default_value_t = 5)]
    pub latency_trials: usize,
    /// Stream counts for batched stepping, comma-separated (empty string: skip).
    #[arg(long, value_name = "N,N,...", default_value = "1,8,32,128")]
    pub streams: String,
    /// Most timed batched steps per stream count.
    #[arg(long, default_value_t = 100)]
    pub batch_steps: usize,
    /// Untimed batched warm-up steps per stream count.
    #[arg(long, default_value_t = 3)]
    pub batch_warmup: usize,
    /// Fewest timed batched steps per stream count (even past --batch-seconds).
    #[arg(long, default_value_t = 5)]
    pub batch_min_steps: usize,
    /// Time cap for the timed batched steps of one stream count, in seconds.
    #[arg(long, default_value_t = 15.0)]
    pub batch_seconds: f64,
    /// Batched stepping without churn (by default one stream leaves and a fresh one joins every step).
    #[arg(long)]
    pub no_churn: bool,
    /// DiffSHEG: timed outpainting windows (after two untimed ones).
    #[arg(long, default_value_t = 5)]
    pub windows: usize,
    /// DiffSHEG: DDIM steps of the steps x jumps table, comma-separated (empty: no table).
    #[arg(long, value_name = "S,S,...", default_value = "10,25,50")]
    pub table_steps: String,
    /// DiffSHEG: jumps of the steps x jumps table, comma-separated.
    #[arg(long, value_name = "U,U,...", default_value = "1,2,3")]
    pub table_jumps: String,
    /// DiffSHEG: timed outpainting windows per table cell.
    #[arg(long, default_value_t = 2)]
    pub table_windows: usize,
    /// Write the results as JSON here.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// No progress messages on stderr.
    #[arg(long, short)]
    pub quiet: bool,
}

fn positive_list(flag: &str, v: &str) -> Result<Vec<usize>> {
    Ok(v.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| InputError::new(format!("{flag}: '{s}' is not a positive integer")))
        })
        .collect::<Result<Vec<_>, _>>()?)
}

pub fn run(a: Args, form: GraphForm) -> Result<()> {
    let streams = positive_list("--streams", &a.streams)?;
    if a.steps == 0 {
        return Err(InputError::new("--steps must be at least 1").into());
    }
    let bundle = a.model.bundle()?;
    super::common::check_form(&bundle, form)?;
    let audio = match a.audio {
        Some(p) => p,
        None => bundle.path(&bundle.reference_clip()),
    };
    let cfg = BenchConfig {
        audio,
        options: a.gen.stream_options()?,
        warmup: a.warmup,
        steps: a.steps,
        latency_trials: a.latency_trials,
        streams,
        batch_warmup: a.batch_warmup,
        batch_steps: a.batch_steps,
        batch_min_steps: a.batch_min_steps,
        batch_seconds: a.batch_seconds,
        churn: !a.no_churn,
        form,
        windows: a.windows.max(1),
        table_steps: positive_list("--table-steps", &a.table_steps)?,
        table_jumps: positive_list("--table-jumps", &a.table_jumps)?,
        table_windows: a.table_windows.max(1),
        ..Default::default()
    };
    // the backend alone: the bench wraps it to time each graph
    let be = livegesture::backend::create(&a.model.backend_options()?)?;
    let quiet = a.quiet;
    let report = run_family(&bundle, be.as_ref(), &cfg, |what| {
        if !quiet {
            eprintln!("[bench] {what}");
        }
    })
    .with_context(|| format!("benchmarking {} on {}", bundle.dir().display(), be.name()))?;
    print!("{}", report.table());
    if let Some(p) = &a.json {
        std::fs::write(p, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}
