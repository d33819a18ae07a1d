//! `livegesture loadtest`: ramps real-time sessions against a server until p99 latency crosses a
//! bound (docs/serve.md#load-test).

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{ensure, Context, Result};

use livegesture_serve::loadtest::{self, CpuSource, LoadConfig};

use super::common::InputError;

#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:
  taskset -c 0 livegesture serve --backend ort --max-sessions 256 &
  taskset -c 1 livegesture loadtest --server-pid $! --levels 16,32,48,64 --plot load.svg
  livegesture loadtest ws://replica:8765 --audio speech/ --cores 4 --json report.json
  taskset -c 1 livegesture loadtest --server-pid $! --pattern burst --levels 48 --require 48

Exit status: 0 when the ramp ran (whatever it held), 1 when fewer sessions than --require were
held or the test could not run, 2 for bad arguments or unreadable audio.")]
pub struct Args {
    /// The server's WebSocket address.
    #[arg(default_value = "ws://127.0.0.1:8765")]
    pub url: String,
    /// Speech to stream: WAV files, or folders whose .wav files are all used (any rate and channel
    /// count; sent as 16 kHz mono s16le). Default: $LIVEGESTURE_REAL_SPEECH, else the real-speech
    /// recordings beside the repository the program was built from.
    #[arg(long, value_name = "PATH")]
    pub audio: Vec<PathBuf>,
    /// Concurrent sessions of each level, comma-separated, increasing.
    #[arg(
        short = 'l',
        long,
        value_delimiter = ',',
        default_value = "8,16,24,32,40,48,56,64"
    )]
    pub levels: Vec<usize>,
    /// How each level's sessions start: `ramp` (start phases spread over one token) or `burst`
    /// (opened one after another within --burst-spread seconds; defaults: --hold 8, --chunk-ms 10,
    /// JSON frames; run it on a fresh server).
    #[arg(long, value_enum, default_value = "ramp")]
    pub pattern: PatternArg,
    /// Burst: the seconds over which each level's sessions open.
    #[arg(long, default_value_t = 1.0)]
    pub burst_spread: f64,
    /// Seconds of audio every session streams at each level (in real time) [default: 20, burst: 8].
    #[arg(long)]
    pub hold: Option<f64>,
    /// A level is held when no session failed and the p99 token latency is below this (ms).
    #[arg(long, default_value_t = 150.0)]
    pub p99_ms: f64,
    /// Go on with the next levels after one that is not held.
    #[arg(long)]
    pub keep_going: bool,
    /// Seconds between levels.
    #[arg(long, default_value_t = 2.0)]
    pub pause: f64,
    /// Milliseconds of audio per message [default: 20, burst: 10].
    #[arg(long)]
    pub chunk_ms: Option<u32>,
    /// Ask for JSON frames (`output=json`) instead of binary records (the burst's default).
    #[arg(long)]
    pub json_frames: bool,
    /// Ask for binary records (`output=binary`; the ramp's default).
    #[arg(long, conflicts_with = "json_frames")]
    pub binary_frames: bool,
    /// Process id of a server on this machine: its CPU from /proc/PID/stat, its cores from its
    /// affinity (taskset).
    #[arg(long, value_name = "PID")]
    pub server_pid: Option<u32>,
    /// The server's Prometheus page, for its CPU when it is not local (default: /metrics of the
    /// URL's host over http, used when --server-pid is not given).
    #[arg(long, value_name = "URL")]
    pub metrics_url: Option<String>,
    /// Cores the server runs on, for sessions per core (default: from --server-pid's affinity).
    #[arg(long)]
    pub cores: Option<usize>,
    /// File holding the server's access token (sent as `Authorization: Bearer`).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// Also write the report as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Also plot latency and server CPU against sessions as SVG to this file.
    #[arg(long, value_name = "FILE")]
    pub plot: Option<PathBuf>,
    /// Exit with status 1 when fewer sessions than this were held.
    #[arg(long, value_name = "N")]
    pub require: Option<usize>,
    /// Instead of the ramp, a soak: the first level's sessions kept live with churn (each 3-20 s,
    /// then a new one) for this many seconds, the server's RSS (--server-pid) sampled every 10 s.
    #[arg(long, value_name = "SECONDS")]
    pub soak: Option<f64>,
    /// No progress lines on stderr.
    #[arg(short, long)]
    pub quiet: bool,
}

/// `--pattern`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PatternArg {
    Ramp,
    Burst,
}

// long: the command's steps in order (options, audio, the ramp or soak, the report files, the bound)
pub fn run(a: Args) -> Result<()> {
    let bad = |m: String| anyhow::Error::new(InputError::new(m));
    let burst = a.pattern == PatternArg::Burst;
    let hold = a.hold.unwrap_or(if burst { 8.0 } else { 20.0 });
    let chunk_ms = a.chunk_ms.unwrap_or(if burst { 10 } else { 20 });
    let binary = if burst {
        a.binary_frames
    } else {
        !a.json_frames
    };
    if !(a.burst_spread.is_finite() && a.burst_spread >= 0.0 && a.burst_spread <= 600.0) {
        return Err(bad(format!(
            "--burst-spread {}: expected 0 <= seconds <= 600",
            a.burst_spread
        )));
    }
    let pattern = if burst {
        loadtest::Pattern::Burst {
            spread: Duration::from_secs_f64(a.burst_spread),
        }
    } else {
        loadtest::Pattern::Ramp
    };
    if a.levels.is_empty() || a.levels.contains(&0) || a.levels.windows(2).any(|w| w[0] >= w[1]) {
        return Err(bad(format!(
            "--levels {:?}: expected increasing positive session counts",
            a.levels
        )));
    }
    if !(hold.is_finite() && hold > 0.0 && hold <= 3600.0) {
        return Err(bad(format!("--hold {hold}: expected 0 < seconds <= 3600")));
    }
    if !(a.p99_ms.is_finite() && a.p99_ms > 0.0) {
        return Err(bad(format!(
            "--p99-ms {}: expected a positive number",
            a.p99_ms
        )));
    }
    if !(a.pause.is_finite() && a.pause >= 0.0) {
        return Err(bad(format!("--pause {}: expected seconds >= 0", a.pause)));
    }
    if chunk_ms == 0 || chunk_ms > 1000 {
        return Err(bad(format!("--chunk-ms {chunk_ms}: expected 1 to 1000")));
    }
    if a.cores == Some(0) {
        return Err(bad("--cores 0: expected at least one core".into()));
    }
    if !a.url.starts_with("ws://") {
        return Err(bad(format!(
            "{}: expected a ws://host:port URL (the load test speaks plain WebSocket)",
            a.url
        )));
    }
    let audio = if a.audio.is_empty() {
        vec![loadtest::default_audio().map_err(|e| bad(format!("{e:#}")))?]
    } else {
        a.audio.clone()
    };
    let clips = loadtest::load_clips(&audio).map_err(|e| bad(format!("{e:#}")))?;
    let token = match &a.token_file {
        Some(f) => {
            let t = std::fs::read_to_string(f)
                .map_err(|e| bad(format!("--token-file {}: {e}", f.display())))?;
            let t = t.trim().to_string();
            if t.is_empty() {
                return Err(bad(format!(
                    "--token-file {}: the file is empty",
                    f.display()
                )));
            }
            Some(t)
        }
        None => None,
    };
    let host = a.url["ws://".len()..].split('/').next().unwrap_or("");
    let metrics_url = a
        .metrics_url
        .clone()
        .unwrap_or_else(|| format!("http://{host}/metrics"));
    let cpu = match (a.server_pid, &a.metrics_url) {
        (Some(pid), _) => {
            ensure!(
                loadtest::proc_cpu_seconds(pid).is_some(),
                "--server-pid {pid}: no such process on this machine (/proc/{pid}/stat)"
            );
            CpuSource::Pid(pid)
        }
        (None, Some(u)) => CpuSource::Metrics(u.clone()),
        (None, None) => CpuSource::Metrics(metrics_url.clone()),
    };
    let cores = a
        .cores
        .or_else(|| a.server_pid.and_then(loadtest::proc_cpus));
    let cfg = LoadConfig {
        url: a.url.clone(),
        token,
        levels: a.levels.clone(),
        hold: Duration::from_secs_f64(hold),
        p99_ms: a.p99_ms,
        chunk: (chunk_ms as usize * 16).max(1),
        binary,
        pause: Duration::from_secs_f64(a.pause),
        keep_going: a.keep_going,
        cpu,
        cores,
        metrics_url: Some(metrics_url),
        pattern,
    };
    if !a.quiet {
        eprintln!(
            "loadtest: {} recordings ({:.1} s), {} of levels {:?}, {} s each in {} ms messages, p99 bound {} ms, server CPU from {}",
            clips.len(),
            clips.iter().map(|c| c.samples.len()).sum::<usize>() as f64 / 16000.0,
            cfg.pattern.name(),
            cfg.levels,
            hold,
            chunk_ms,
            a.p99_ms,
            cfg.cpu.describe()
        );
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("building the async runtime")?;
    let quiet = a.quiet;
    if let Some(secs) = a.soak {
        if !(secs.is_finite() && secs > 0.0) {
            return Err(bad(format!("--soak {secs}: expected seconds > 0")));
        }
        let table = rt.block_on(loadtest::soak::run(
            &cfg,
            &clips,
            cfg.levels[0],
            secs,
            a.server_pid,
            Duration::from_secs(10),
            |line| {
                if !quiet {
                    eprintln!("{line}");
                }
            },
        ))?;
        print!("{table}");
        return Ok(());
    }
    let report = rt.block_on(loadtest::run(&cfg, &clips, |line| {
        if !quiet {
            eprintln!("{line}");
        }
    }))?;
    print!("{}", report.table());
    if let Some(p) = &a.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(p, text + "\n").with_context(|| format!("--json {}", p.display()))?;
    }
    if let Some(p) = &a.plot {
        let title = format!(
            "livegesture loadtest {} ({}): {} s per level, p99 bound {} ms",
            a.url,
            cfg.pattern.name(),
            hold,
            a.p99_ms
        );
        std::fs::write(p, report.svg(&title)).with_context(|| format!("--plot {}", p.display()))?;
    }
    if let Some(n) = a.require {
        loadtest::require(&report, n)?;
    }
    Ok(())
}
