//! Benchmarks of the streaming pipeline (BENCHMARKS.md; speed is measured here, never by timed tests).
//!
//! [`run`] loads a bundle on one backend and measures, on the calling thread:
//!
//! - **single stream**: whole-chain per-token step time ([`LiveGestureGraphs::step`]: every graph, both guidance
//!   branches, sampling, frames) and each graph's share (a [`TimingBackend`] wraps the real backend and
//!   times every graph run, conversions into and out of the backend included); the log-mel frontend
//!   per token; the real-time factor;
//! - **first-frame latency**: audio pushed in 10 ms chunks at wall-clock pace from sample 0; the time
//!   from the first sample's arrival until the first frame comes back, and the compute part after the
//!   chunk completing token 0's audio arrived;
//! - **state bytes per stream** ([`livegesture::model::livegesture::state_bytes`]) and **peak RSS** (`VmHWM`);
//! - **batched stepping**: [`MotionModel::step_many`] of a [`LiveGestureModel`] (the call `serve` makes
//!   per tick; the parity `batch` check verifies the same path) on N streams, one token of audio each
//!   per step, frontends included (caches kept stacked in the model's cohort between steps;
//!   optionally one stream leaving and a fresh one joining at every step, the leaving and joining
//!   timed with the step), and the streams one core sustains in real time.
//!
//! Warm-up steps (which also build tract's per-batch-size plans) are excluded from every figure.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use ndarray::Array2;
use serde::Serialize;

use livegesture::backend::Backend;
use livegesture::bundle::Bundle;
use livegesture::frontend::StreamingLogMel;
use livegesture::model::livegesture::{
    state_bytes, LiveGestureGraphs, LiveGestureModel, StreamOptions,
};
use livegesture::model::{for_family, FamilyTool, MotionModel, MotionStream, StreamJob};

pub mod diffsheg;
mod machine;
mod table;
mod timing;

pub use machine::{cpu_name, loadavg, online_cpus, peak_rss_bytes, Machine};
pub use table::format_table;
pub use timing::{Recorder, Stats, TimingBackend};

/// What to measure.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Audio fed to the streams (16 kHz mono after conversion), repeated as needed.
    pub audio: PathBuf,
    /// The streams' options, as every door takes them ([`StreamOptions`], checked by the family's
    /// `new_stream`): seed, guidance and the family's sampler settings (None: the bundle's). Each
    /// batched stream adds its index to the seed.
    pub options: StreamOptions,
    /// Untimed steps before the single-stream measurement.
    pub warmup: usize,
    /// Timed single-stream steps.
    pub steps: usize,
    /// First-frame latency trials (each a fresh stream).
    pub latency_trials: usize,
    /// Chunk length of the paced first-frame feed, in milliseconds.
    pub chunk_ms: f64,
    /// Stream counts for batched stepping (empty: skip).
    pub streams: Vec<usize>,
    /// Untimed batched steps per N.
    pub batch_warmup: usize,
    /// Most timed batched steps per N.
    pub batch_steps: usize,
    /// Fewest timed batched steps per N (even past the time cap).
    pub batch_min_steps: usize,
    /// Time cap per N for the timed batched steps, in seconds.
    pub batch_seconds: f64,
    /// Batched stepping with churn: at every step one stream leaves and a fresh one joins.
    pub churn: bool,
    /// LiveGesture: the form of the region eXperts and decoders to measure (docs/bundle.md#forms-and-precision; auto = the
    /// bundle's form for the backend).
    pub form: livegesture::model::GraphForm,
    /// A family that steps in windows (DiffSHEG): timed windows after the untimed ones.
    pub windows: usize,
    /// A family that samples by diffusion (DiffSHEG): the steps x jumps table, steps (empty: no
    /// table), jumps, and timed windows per cell.
    pub table_steps: Vec<usize>,
    pub table_jumps: Vec<usize>,
    pub table_windows: usize,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            audio: PathBuf::new(),
            options: StreamOptions::default(),
            warmup: 20,
            steps: 300,
            latency_trials: 5,
            chunk_ms: 10.0,
            streams: vec![1, 8, 32, 128],
            batch_warmup: 3,
            batch_steps: 100,
            batch_min_steps: 5,
            batch_seconds: 15.0,
            churn: true,
            form: Default::default(),
            windows: 5,
            table_steps: vec![10, 25, 50],
            table_jumps: vec![1, 2, 3],
            table_windows: 2,
        }
    }
}

/// Per-graph timings of single-stream steps.
#[derive(Debug, Clone, Serialize)]
pub struct GraphTiming {
    pub graph: String,
    pub ms: Stats,
    /// The graph's time in every timed step, in step order (0 where it did not run). Summing graphs
    /// per step before taking the median (`scripts/bench_ab.sh GRAPHS=...`) compares one graph with
    /// several on equal terms: a sum of per-graph medians drops the preemptions of a shared core
    /// that hit each short graph in fewer than half of the steps, which the median of one longer
    /// graph keeps.
    pub samples_ms: Vec<f64>,
}

/// Per-graph statistics from each graph's samples (`names[i]`'s samples in `samples[i]`).
fn graph_timings(names: &[String], samples: &[Vec<f64>]) -> Vec<GraphTiming> {
    names
        .iter()
        .zip(samples)
        .map(|(n, v)| GraphTiming {
            graph: n.clone(),
            ms: Stats::of(v),
            samples_ms: v.clone(),
        })
        .collect()
}

/// Single-stream results.
#[derive(Debug, Clone, Serialize)]
pub struct SingleStream {
    pub warmup_steps: usize,
    /// Whole chain per token step (all graphs, both guidance branches, sampling, frames).
    pub chain_ms: Stats,
    /// Each graph's run per token step.
    pub graphs: Vec<GraphTiming>,
    /// Sum of the graph runs per step.
    pub graphs_sum_ms: Stats,
    /// Chain minus graph runs (stacking, sampling, frame assembly), median.
    pub overhead_ms_median: f64,
    /// Log-mel frontend per token (median over tokens).
    pub frontend_ms_per_token: f64,
    /// (median chain + frontend) / token duration.
    pub real_time_factor: f64,
    /// Every timed whole-chain step, in order (for the latency distribution plot).
    pub chain_samples_ms: Vec<f64>,
}

/// First-frame latency with audio arriving at real-time pace.
#[derive(Debug, Clone, Serialize)]
pub struct FirstFrame {
    pub chunk_ms: f64,
    /// When token 0's audio is complete (its span), after the first sample.
    pub token0_audio_ms: f64,
    /// When the chunk completing token 0 arrives (token 0's span rounded up to the chunk grid).
    pub token0_chunk_arrival_ms: f64,
    /// First sample's arrival to first frame returned (fresh stream on a warmed-up pipeline).
    pub total_ms: Stats,
    /// First frame returned minus the arrival of the chunk completing token 0.
    pub compute_ms: Stats,
    /// The first stream of a freshly loaded pipeline (tract builds its plans on first use).
    pub cold_pipeline_total_ms: f64,
    pub cold_pipeline_compute_ms: f64,
}

/// Batched stepping of N streams.
#[derive(Debug, Clone, Serialize)]
pub struct Batched {
    pub streams: usize,
    pub churn: bool,
    pub warmup_steps: usize,
    pub timed_steps: usize,
    /// True when the time cap ended the timed steps before `batch_steps`.
    pub capped: bool,
    /// One `step_many` call (what `serve` runs per tick) pushing one token's audio into each of the
    /// N streams: their log-mel frontends, graphs, sampling, frames; with churn, one stream leaving
    /// (dropped) and a fresh one joining the cohort.
    pub step_ms: Stats,
    /// Graph runs per batched step (median of their sum).
    pub graphs_sum_ms_median: f64,
    /// Median of (step - graph runs): frontends, data inputs, sampling, frames, cohort moves, churn.
    pub overhead_ms_median: f64,
    /// Median step / N.
    pub per_stream_ms: f64,
    /// Without the frontend: N * token / (median step - N * single-stream frontend per token).
    pub realtime_streams: f64,
    /// N * token duration / median step: streams one core keeps in real time, frontend included.
    pub realtime_streams_with_frontend: f64,
    /// Per-graph times of the timed batched steps (each graph runs once per step on all N streams).
    pub graphs: Vec<GraphTiming>,
}

/// Everything one `bench` run measures.
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    pub bundle: String,
    pub config: Option<String>,
    pub parameters: u64,
    pub backend: String,
    pub backend_description: String,
    pub guidance: f64,
    pub audio: String,
    pub token_ms: f64,
    pub machine: Machine,
    pub load_seconds: f64,
    pub single: SingleStream,
    pub first_frame: FirstFrame,
    pub state_bytes_per_stream: usize,
    pub state_bytes_per_stream_unguided: usize,
    /// VmHWM after loading, the single-stream and latency runs (before batched stepping).
    pub peak_rss_single_bytes: Option<u64>,
    pub batched: Vec<Batched>,
    /// VmHWM at the end of the run.
    pub peak_rss_bytes: Option<u64>,
    pub wall_seconds: f64,
}

/// The mel blocks of `samples`, one per complete token.
fn mel_blocks(bundle: &Bundle, samples: &[f32]) -> Result<(Vec<Array2<f32>>, f64)> {
    let mut fe = StreamingLogMel::new(bundle.frontend())?;
    let t0 = Instant::now();
    let mut out = Vec::new();
    // token-sized pushes, as a live stream would see them
    let per = (bundle.frontend().token_end(1) - bundle.frontend().token_end(0)) as usize;
    for c in samples.chunks(per.max(1)) {
        out.extend(fe.push(c)?);
    }
    let ms_per_token = t0.elapsed().as_secs_f64() * 1e3 / out.len().max(1) as f64;
    Ok((out, ms_per_token))
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Paced first-frame measurement on a fresh stream: returns (total ms, compute ms).
fn first_frame_once(
    pipe: &mut LiveGestureGraphs,
    opts: &StreamOptions,
    audio: &[f32],
    chunk: usize,
    sr: f64,
) -> Result<(f64, f64)> {
    let mut s = pipe.new_stream(opts)?;
    let start = Instant::now(); // the first sample arrives
    let mut sent = 0usize;
    loop {
        ensure!(sent < audio.len(), "no frame before the audio ran out");
        let end = (sent + chunk).min(audio.len());
        // the chunk is available once its last sample has arrived
        let arrival = Duration::from_secs_f64(end as f64 / sr);
        let now = start.elapsed();
        if arrival > now {
            std::thread::sleep(arrival - now);
        }
        let frames = pipe.push(&mut s, &audio[sent..end])?;
        if !frames.is_empty() {
            let done = start.elapsed();
            return Ok((ms(done), ms(done.saturating_sub(arrival))));
        }
        sent = end;
    }
}

/// Runs the whole benchmark for `bundle` on `backend` (one thread).
// long: the benchmark's measurements in the order the report prints them (each a short block)
pub fn run(
    bundle: &Bundle,
    backend: &dyn Backend,
    cfg: &BenchConfig,
    mut progress: impl FnMut(&str),
) -> Result<BenchReport> {
    // the figures below are the LiveGesture family's ([`run_family`] runs the bundle's family's)
    bundle.livegesture().with_context(|| {
        format!(
            "{}: bench::run measures LiveGesture bundles; use bench::run_family",
            bundle.dir().display()
        )
    })?;
    let wall = Instant::now();
    let load_start = loadavg();
    let rec = Arc::new(Recorder::default());
    let timing = TimingBackend::new(backend, rec.clone());
    let t0 = Instant::now();
    let mut pipe = LiveGestureGraphs::with_form(bundle, &timing, cfg.form)?;
    let load_seconds = t0.elapsed().as_secs_f64();
    let fe = bundle.frontend().clone();
    let sr = fe.sample_rate as f64;
    let token_ms = 1e3 * fe.frames_per_token as f64 / fe.fps as f64;

    let clip = livegesture::audio::read_wav_16k_mono(&cfg.audio)
        .with_context(|| format!("reading {}", cfg.audio.display()))?;
    ensure!(
        !clip.is_empty(),
        "{}: the audio has no samples",
        cfg.audio.display()
    );
    // enough audio for the longest single stream run, the clip repeated
    let need_tokens = cfg.warmup + cfg.steps + 2;
    let need = fe.token_end(need_tokens as u64) as usize + fe.win_length;
    let mut audio = Vec::with_capacity(need);
    while audio.len() < need {
        audio.extend_from_slice(&clip);
    }
    audio.truncate(need);
    let (mels, frontend_ms) = mel_blocks(bundle, &audio)?;
    ensure!(mels.len() > cfg.warmup + cfg.steps, "not enough mel blocks");

    let opts = cfg.options.clone();

    // first frame on the freshly loaded pipeline (tract optimises its plans here)
    progress("first frame, cold pipeline");
    let chunk = ((cfg.chunk_ms / 1e3) * sr).round().max(1.0) as usize;
    let (cold_total, cold_compute) = first_frame_once(&mut pipe, &opts, &audio, chunk, sr)?;
    rec.drain();

    // single stream
    progress("single stream");
    let names = rec.names();
    let mut s = pipe.new_stream(&opts)?;
    let guidance = s.guidance();
    let mut chain = Vec::with_capacity(cfg.steps);
    let mut per_graph: Vec<Vec<f64>> = vec![Vec::with_capacity(cfg.steps); names.len()];
    let mut sums = Vec::with_capacity(cfg.steps);
    for (i, mel) in mels.iter().take(cfg.warmup + cfg.steps).enumerate() {
        let t = Instant::now();
        let step = pipe.step(&mut s, mel)?;
        let dt = ms(t.elapsed());
        std::hint::black_box(&step);
        let ev = rec.drain();
        if i >= cfg.warmup {
            chain.push(dt);
            let mut step_graph = vec![0.0; names.len()];
            for (id, secs) in ev {
                step_graph[id] += secs * 1e3;
            }
            sums.push(step_graph.iter().sum::<f64>());
            for (v, x) in per_graph.iter_mut().zip(step_graph) {
                v.push(x);
            }
        }
    }
    let chain_stats = Stats::of(&chain);
    let sum_stats = Stats::of(&sums);
    let overhead: Vec<f64> = chain.iter().zip(&sums).map(|(c, g)| c - g).collect();
    let single = SingleStream {
        warmup_steps: cfg.warmup,
        real_time_factor: (chain_stats.median + frontend_ms) / token_ms,
        overhead_ms_median: Stats::of(&overhead).median,
        chain_ms: chain_stats,
        graphs: graph_timings(&names, &per_graph),
        graphs_sum_ms: sum_stats,
        frontend_ms_per_token: frontend_ms,
        chain_samples_ms: chain,
    };

    // first frame on the warm pipeline
    progress("first-frame latency");
    let mut totals = Vec::new();
    let mut computes = Vec::new();
    for _ in 0..cfg.latency_trials.max(1) {
        let (a, b) = first_frame_once(&mut pipe, &opts, &audio, chunk, sr)?;
        totals.push(a);
        computes.push(b);
    }
    rec.drain();
    let t0_end = fe.token_end(0) as f64;
    let first_frame = FirstFrame {
        chunk_ms: chunk as f64 / sr * 1e3,
        token0_audio_ms: t0_end / sr * 1e3,
        token0_chunk_arrival_ms: (t0_end / chunk as f64).ceil() * chunk as f64 / sr * 1e3,
        total_ms: Stats::of(&totals),
        compute_ms: Stats::of(&computes),
        cold_pipeline_total_ms: cold_total,
        cold_pipeline_compute_ms: cold_compute,
    };
    let peak_rss_single_bytes = peak_rss_bytes();

    // batched stepping: the model's `step_many` (the last use of the graphs)
    let model = LiveGestureModel::from(pipe);
    let mut batched = Vec::new();
    for &n in &cfg.streams {
        progress(&format!("batched, {n} streams"));
        batched.push(run_batched(
            &model,
            &rec,
            &opts,
            &audio,
            n,
            cfg,
            token_ms,
            frontend_ms,
        )?);
        rec.drain();
    }

    let model = &bundle.manifest().model;
    Ok(BenchReport {
        bundle: bundle.dir().display().to_string(),
        config: model.config_name.clone().or_else(|| model.name.clone()),
        parameters: model.parameters.values().sum(),
        backend: backend.name().to_string(),
        backend_description: backend.describe(),
        guidance,
        audio: cfg.audio.display().to_string(),
        token_ms,
        machine: Machine {
            cpu: cpu_name(),
            cores: online_cpus(),
            usable_cpus: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1),
            loadavg_start: load_start,
            loadavg_end: loadavg(),
        },
        load_seconds,
        single,
        first_frame,
        state_bytes_per_stream: state_bytes(bundle, guidance != 1.0)?,
        state_bytes_per_stream_unguided: state_bytes(bundle, false)?,
        peak_rss_single_bytes,
        batched,
        peak_rss_bytes: peak_rss_bytes(),
        wall_seconds: wall.elapsed().as_secs_f64(),
    })
}

/// One stream of the batched measurement: a stream of the model, where it reads the audio, the
/// samples pushed into it and the next token it completes.
struct Fed {
    stream: Box<dyn MotionStream>,
    pos: usize,
    pushed: u64,
    token: u64,
}

impl Fed {
    /// A fresh stream (cold start) whose frontend holds all of token 0's audio but its last sample,
    /// read from `start` in `audio`.
    fn new(
        model: &LiveGestureModel,
        opts: StreamOptions,
        audio: &[f32],
        start: usize,
    ) -> Result<Self> {
        let mut stream = model.new_stream(&opts)?;
        let prime = model.graphs().frontend().token_end(0).saturating_sub(1) as usize;
        ensure!(
            audio.len() > 2 * prime,
            "bench: the audio is shorter than two tokens"
        );
        let start = start % (audio.len() - prime);
        let frames = stream.push_audio(&audio[start..start + prime])?;
        ensure!(frames.is_empty(), "priming a stream completed a token");
        Ok(Fed {
            stream,
            pos: start + prime,
            pushed: prime as u64,
            token: 0,
        })
    }

    /// The samples that complete its next token (token ends fall on whole samples unevenly, so
    /// their count varies by one), read on from where it is (from the start once `audio` ends).
    fn next_token<'a>(
        &mut self,
        fe: &livegesture::frontend::FrontendConfig,
        audio: &'a [f32],
    ) -> &'a [f32] {
        let n = (fe.token_end(self.token) - self.pushed) as usize;
        if self.pos + n > audio.len() {
            self.pos = 0;
        }
        let chunk = &audio[self.pos..self.pos + n];
        self.pos += n;
        self.pushed += n as u64;
        self.token += 1;
        chunk
    }
}

#[allow(clippy::too_many_arguments)]
fn run_batched(
    model: &LiveGestureModel,
    rec: &Recorder,
    opts: &StreamOptions,
    audio: &[f32],
    n: usize,
    cfg: &BenchConfig,
    token_ms: f64,
    frontend_ms: f64,
) -> Result<Batched> {
    // each stream starts at its own place in the audio and has its own seed; every step is one
    // `step_many` call (what `serve` runs per tick) pushing one token's samples into every stream,
    // so the streams' log-mel frontends are timed with the step; their caches stay stacked in the
    // model's cohort between steps
    let fe = model.graphs().frontend();
    let with_seed = |seed: u64| StreamOptions {
        seed,
        ..opts.clone()
    };
    let per = fe.token_end(0) as usize;
    let mut fed: Vec<Fed> = (0..n)
        .map(|i| {
            Fed::new(
                model,
                with_seed(opts.seed.wrapping_add(i as u64)),
                audio,
                i * 7 * per,
            )
        })
        .collect::<Result<_>>()?;
    let mut next_seed = opts.seed.wrapping_add(n as u64);
    let mut times = Vec::new();
    let mut graph_sums = Vec::new();
    let names = rec.names();
    let mut per_graph: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let total = cfg.batch_warmup + cfg.batch_steps;
    let cap = Duration::from_secs_f64(cfg.batch_seconds);
    let mut timed_start: Option<Instant> = None;
    let mut capped = false;
    for step in 0..total {
        if step == cfg.batch_warmup {
            timed_start = Some(Instant::now());
        }
        if let Some(ts) = timed_start {
            if times.len() >= cfg.batch_min_steps && ts.elapsed() > cap {
                capped = true;
                break;
            }
        }
        // with churn, the stream at position `step % n` leaves and a fresh one (cold start) joins:
        // its creation is not timed, dropping the leaving stream (its rows leave the cohort) and
        // the joining stream's move into the cohort (in the step) are
        let mut dt = 0.0;
        if cfg.churn && step > 0 && n > 1 {
            let joining = Fed::new(model, with_seed(next_seed), audio, step * 13 * per)?;
            next_seed = next_seed.wrapping_add(1);
            let leaving = std::mem::replace(&mut fed[step % n], joining);
            let t = Instant::now();
            drop(leaving);
            dt += ms(t.elapsed());
        }
        let chunks: Vec<&[f32]> = fed.iter_mut().map(|f| f.next_token(fe, audio)).collect();
        let mut jobs: Vec<StreamJob<'_>> = fed
            .iter_mut()
            .zip(chunks)
            .map(|(f, c)| StreamJob::push(f.stream.as_mut(), c))
            .collect();
        let t = Instant::now();
        let out = model.step_many(&mut jobs);
        dt += ms(t.elapsed());
        drop(jobs);
        for r in out {
            let frames = r?;
            ensure!(
                frames.len() as u64 == fe.frames_per_token,
                "a batched step gave a stream {} frames, expected one token's {}",
                frames.len(),
                fe.frames_per_token
            );
            std::hint::black_box(&frames);
        }
        let mut step_graph = vec![0.0; names.len()];
        for (id, secs) in rec.drain() {
            step_graph[id] += secs * 1e3;
        }
        if step >= cfg.batch_warmup {
            times.push(dt);
            graph_sums.push(step_graph.iter().sum::<f64>());
            for (v, x) in per_graph.iter_mut().zip(step_graph) {
                v.push(x);
            }
        }
    }
    let st = Stats::of(&times);
    let nf = n as f64;
    let over: Vec<f64> = times.iter().zip(&graph_sums).map(|(t, g)| t - g).collect();
    Ok(Batched {
        streams: n,
        churn: cfg.churn && n > 1,
        warmup_steps: cfg.batch_warmup,
        timed_steps: times.len(),
        capped,
        graphs_sum_ms_median: Stats::of(&graph_sums).median,
        overhead_ms_median: Stats::of(&over).median,
        per_stream_ms: st.median / nf,
        realtime_streams: nf * token_ms / (st.median - nf * frontend_ms).max(f64::MIN_POSITIVE),
        realtime_streams_with_frontend: nf * token_ms / st.median,
        step_ms: st,
        graphs: graph_timings(&names, &per_graph),
    })
}

/// A benchmark report of either family.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum FamilyReport {
    /// [`run`]'s report.
    LiveGesture(BenchReport),
    /// [`diffsheg::run`]'s report.
    DiffSheg(diffsheg::DiffshegBenchReport),
}

impl FamilyReport {
    /// The report as a text table.
    pub fn table(&self) -> String {
        match self {
            FamilyReport::LiveGesture(r) => format_table(r),
            FamilyReport::DiffSheg(r) => diffsheg::format_table(r),
        }
    }
}

/// Runs the benchmark of `bundle`'s family: [`run`] (LiveGesture) or [`diffsheg::run`] (DiffSHEG:
/// the audio, options, latency trials, windows and table of `cfg`).
pub fn run_family(
    bundle: &Bundle,
    backend: &dyn Backend,
    cfg: &BenchConfig,
    progress: impl FnMut(&str),
) -> Result<FamilyReport> {
    struct Bench<'a, P> {
        backend: &'a dyn Backend,
        cfg: &'a BenchConfig,
        progress: P,
    }
    impl<P: FnMut(&str)> FamilyTool for Bench<'_, P> {
        type Output = Result<FamilyReport>;
        fn livegesture(self, bundle: &Bundle) -> Self::Output {
            Ok(FamilyReport::LiveGesture(run(
                bundle,
                self.backend,
                self.cfg,
                self.progress,
            )?))
        }
        fn diffsheg(self, bundle: &Bundle) -> Self::Output {
            Ok(FamilyReport::DiffSheg(diffsheg::run(
                bundle,
                self.backend,
                self.cfg,
                self.progress,
            )?))
        }
    }
    for_family(
        bundle,
        Bench {
            backend,
            cfg,
            progress,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn graph_timings_keep_every_step_in_order() {
        // two short graphs, each preempted (+4 ms) in one step of three: the per-step sums (2, 6, 6;
        // median 6) are what `bench_ab.sh GRAPHS=...` takes the median of; the sum of the per-graph
        // medians (1 + 1 = 2) drops the preemptions
        let names = vec!["decoder_a".to_string(), "decoder_b".to_string()];
        let samples = vec![vec![1.0, 1.0, 5.0], vec![1.0, 5.0, 1.0]];
        let t = graph_timings(&names, &samples);
        assert_eq!(t[0].graph, "decoder_a");
        assert_eq!(t[0].samples_ms, samples[0]);
        assert_eq!(t[1].samples_ms, samples[1]);
        assert_eq!(t[0].ms.median + t[1].ms.median, 2.0);
        let sums: Vec<f64> = (0..3)
            .map(|i| t[0].samples_ms[i] + t[1].samples_ms[i])
            .collect();
        assert_eq!(Stats::of(&sums).median, 6.0);
    }
}
