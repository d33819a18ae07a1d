//! Benchmarks of a DiffSHEG bundle (one thread): per-window graph times, whole-window sampling time,
//! compute per second of audio, first-frame latency and look-ahead, state bytes, and a DDIM steps x
//! jumps speed table.
//!
//! - **Per window**: a stream is fed one window step of audio at a time (N - L frames); every push
//!   that runs a window is timed whole (frontend, encoder, every denoiser call, sampler, frames), and
//!   each graph run is timed by a [`TimingBackend`]. The first (plain DDIM) window and the
//!   outpainting windows (RePaint jumps) are reported apart.
//! - **Compute per second of audio** = outpainting-window time / ((N - L) / fps): a steady stream emits
//!   N - L frames per window. Its inverse is the real-time factor; `fps` = frames per compute second.
//! - **First frame**: a cold stream (plans already built) gets the first window's audio at once; the
//!   first frame leaves after N frames of audio (the look-ahead) plus that window's sampling time.
//! - **Steps x jumps**: the outpainting-window time for each (DDIM steps, jumps) pair, as compute per
//!   second of audio, for a script to join with quality figures.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use serde::Serialize;

use super::{
    cpu_name, loadavg, online_cpus, peak_rss_bytes, BenchConfig, Machine, Recorder, Stats,
    TimingBackend,
};
use livegesture::backend::Backend;
use livegesture::bundle::Bundle;
use livegesture::model::diffsheg::foppas::SamplerOptions;
use livegesture::model::diffsheg::model::DiffshegModel;
use livegesture::model::{MotionStream, StreamOptions};

/// Times of the two graphs, per call, in ms.
#[derive(Debug, Clone, Serialize)]
pub struct GraphTimes {
    pub graph: String,
    /// Calls per outpainting window.
    pub calls_per_window: f64,
    pub per_call: Stats,
    /// Sum over a window, median of windows.
    pub per_window_ms: f64,
}

/// One cell of the steps x jumps table.
#[derive(Debug, Clone, Serialize)]
pub struct StepsJumps {
    pub ddim_steps: usize,
    pub jumps: usize,
    pub denoiser_calls_per_window: usize,
    pub window_ms: Stats,
    /// Compute seconds per second of audio (median window / ((N - L) / fps)).
    pub compute_per_audio_second: f64,
    /// Frames per compute second.
    pub fps: f64,
}

/// The report.
#[derive(Debug, Clone, Serialize)]
pub struct DiffshegBenchReport {
    pub bundle: String,
    pub config: Option<String>,
    pub backend: String,
    pub backend_description: String,
    pub audio: String,
    pub machine: Machine,
    pub load_seconds: f64,
    pub ddim_steps: usize,
    pub jumps: usize,
    pub window: usize,
    pub overlap: usize,
    pub guidance: f64,
    pub denoiser_rows: usize,
    /// The first window (plain DDIM, S calls), whole push in ms (one sample per trial).
    pub first_window_ms: Stats,
    /// Outpainting windows ((S-1) U + 1 calls), whole push in ms.
    pub window_ms: Stats,
    pub graphs: Vec<GraphTimes>,
    /// Compute seconds per second of audio, steady state.
    pub compute_per_audio_second: f64,
    pub realtime_factor: f64,
    pub fps: f64,
    /// Look-ahead: audio a window waits for before its first frame (N frames), in ms.
    pub lookahead_ms: f64,
    /// First-frame latency = look-ahead + the first window's compute, in ms (median of trials).
    pub first_frame_ms: f64,
    pub first_frame_compute: Stats,
    pub state_bytes_per_stream: usize,
    pub steps_x_jumps: Vec<StepsJumps>,
    pub peak_rss_bytes: Option<u64>,
    pub wall_seconds: f64,
}

fn ms(s: f64) -> f64 {
    s * 1e3
}

/// The options of `cfg`, DDIM steps and jumps replaced where given (a table cell).
fn options(cfg: &BenchConfig, steps: Option<usize>, jumps: Option<usize>) -> StreamOptions {
    StreamOptions {
        ddim_steps: steps.or(cfg.options.ddim_steps),
        jumps: jumps.or(cfg.options.jumps),
        ..cfg.options.clone()
    }
}

/// What [`run_windows`] measures: (first window ms, outpainting window ms, graph events per
/// outpainting window, state bytes after the run, the sampler options the stream ran with).
type WindowRun = (f64, Vec<f64>, Vec<Vec<(usize, f64)>>, usize, SamplerOptions);

/// Pushes one window step of audio at a time; returns [`WindowRun`].
fn run_windows(
    model: &DiffshegModel,
    opts: &StreamOptions,
    audio: &[f32],
    timed: usize,
    rec: &Recorder,
) -> Result<WindowRun> {
    let mut s = model.stream(opts, false)?;
    let so = *s.foppas().options();
    let fe = &model.shared().frontend;
    let sr = fe.sample_rate as f64;
    let fps = fe.fps as f64;
    let step = so.window - so.overlap;
    let mut sent = 0usize;
    let mut first = f64::NAN;
    let mut times = Vec::new();
    let mut events = Vec::new();
    rec.drain();
    let mut k = 0usize;
    // window k runs when sample (k * step + N) * sr / fps has arrived; window 0 (plain DDIM) is
    // timed apart, window 1 untimed, windows 2.. timed
    while times.len() < timed {
        let need = (((k * step + so.window) as f64) * sr / fps).floor() as usize;
        ensure!(
            need <= audio.len(),
            "bench: not enough audio for {} windows",
            timed + 2
        );
        let t = Instant::now();
        let frames = s.push_audio(&audio[sent..need])?;
        let dt = ms(t.elapsed().as_secs_f64());
        std::hint::black_box(&frames);
        ensure!(!frames.is_empty(), "bench: window {k} did not run");
        let ev = rec.drain();
        if k == 0 {
            first = dt;
        } else if k >= 2 {
            times.push(dt);
            events.push(ev);
        }
        sent = need;
        k += 1;
    }
    Ok((first, times, events, s.foppas().state_bytes(), so))
}

/// Runs the DiffSHEG benchmark.
// long: the benchmark's measurements in the order the report prints them (each a short block)
pub fn run(
    bundle: &Bundle,
    backend: &dyn Backend,
    shared: &BenchConfig,
    mut progress: impl FnMut(&str),
) -> Result<DiffshegBenchReport> {
    let wall = Instant::now();
    let load_start = loadavg();
    let clip = livegesture::audio::read_wav_16k_mono(&shared.audio)
        .with_context(|| format!("reading {}", shared.audio.display()))?;
    ensure!(
        !clip.is_empty(),
        "{}: the audio has no samples",
        shared.audio.display()
    );
    ensure!(shared.windows >= 1, "bench: at least one timed window");
    let rec = Arc::new(Recorder::default());
    let timing = TimingBackend::new(backend, rec.clone());
    let t0 = Instant::now();
    let model = DiffshegModel::load(bundle, &timing)?;
    let load_seconds = t0.elapsed().as_secs_f64();
    let names = rec.names();
    let fe = model.shared().frontend.clone();
    let (sr, fps) = (fe.sample_rate as f64, fe.fps as f64);

    // enough audio for the longest run: window count of the main run or a table cell, + 3
    let base = model
        .shared()
        .sampler_options(&options(shared, None, None))?;
    let n_windows = shared.windows.max(shared.table_windows) + 4;
    let need =
        (((n_windows * (base.window - base.overlap) + base.window) as f64) * sr / fps) as usize + 1;
    let mut audio = Vec::with_capacity(need);
    while audio.len() < need {
        audio.extend_from_slice(&clip);
    }
    audio.truncate(need);

    // warm-up: every plan (batch rows x window length) built once
    progress("warm-up (plans)");
    run_windows(&model, &options(shared, None, None), &audio, 1, &rec)?;

    progress("windows");
    let (_, times, events, state_bytes, so) = run_windows(
        &model,
        &options(shared, None, None),
        &audio,
        shared.windows,
        &rec,
    )?;
    let window_ms = Stats::of(&times);
    let mut graphs = Vec::new();
    for (id, name) in names.iter().enumerate() {
        let mut per_call = Vec::new();
        let mut per_window = Vec::new();
        for ev in &events {
            let v: Vec<f64> = ev.iter().filter(|e| e.0 == id).map(|e| ms(e.1)).collect();
            per_window.push(v.iter().sum::<f64>());
            per_call.extend(v);
        }
        graphs.push(GraphTimes {
            graph: name.clone(),
            calls_per_window: per_call.len() as f64 / events.len().max(1) as f64,
            per_call: Stats::of(&per_call),
            per_window_ms: Stats::of(&per_window).median,
        });
    }
    let audio_per_window = (so.window - so.overlap) as f64 / fps;
    let compute = window_ms.median / 1e3 / audio_per_window;

    progress("first frame");
    let mut first_times = Vec::new();
    for _ in 0..shared.latency_trials.max(1) {
        let mut s = model.stream(&options(shared, None, None), false)?;
        let need = ((so.window as f64) * sr / fps).floor() as usize;
        let t = Instant::now();
        let frames = s.push_audio(&audio[..need])?;
        first_times.push(ms(t.elapsed().as_secs_f64()));
        ensure!(!frames.is_empty(), "bench: the first window did not run");
    }
    let first_frame_compute = Stats::of(&first_times);
    let lookahead_ms = 1e3 * so.window as f64 / fps;

    let mut table = Vec::new();
    for &steps in &shared.table_steps {
        for &jumps in &shared.table_jumps {
            progress(&format!("steps x jumps: {steps} x {jumps}"));
            let o = options(shared, Some(steps), Some(jumps));
            let (_, t, _, _, so2) =
                run_windows(&model, &o, &audio, shared.table_windows.max(1), &rec)
                    .with_context(|| format!("{steps} DDIM steps x {jumps} jumps"))?;
            let st = Stats::of(&t);
            let median = st.median;
            let c = st.median / 1e3 / audio_per_window;
            table.push(StepsJumps {
                ddim_steps: steps,
                jumps,
                denoiser_calls_per_window: so2.calls_per_window(true),
                window_ms: st,
                compute_per_audio_second: c,
                fps: (so2.window - so2.overlap) as f64 / (median / 1e3),
            });
        }
    }

    Ok(DiffshegBenchReport {
        bundle: bundle.dir().display().to_string(),
        config: bundle.manifest().model.config_name.clone(),
        backend: backend.name().to_string(),
        backend_description: backend.describe(),
        audio: shared.audio.display().to_string(),
        machine: Machine {
            cpu: cpu_name(),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            usable_cpus: online_cpus(),
            loadavg_start: load_start,
            loadavg_end: loadavg(),
        },
        load_seconds,
        ddim_steps: so.steps,
        jumps: so.jumps,
        window: so.window,
        overlap: so.overlap,
        guidance: so.guidance,
        denoiser_rows: so.rows(),
        first_window_ms: first_frame_compute.clone(),
        window_ms,
        graphs,
        compute_per_audio_second: compute,
        realtime_factor: 1.0 / compute,
        fps: (so.window - so.overlap) as f64 / (Stats::of(&times).median / 1e3),
        lookahead_ms,
        first_frame_ms: lookahead_ms + first_frame_compute.median,
        first_frame_compute,
        state_bytes_per_stream: state_bytes,
        steps_x_jumps: table,
        peak_rss_bytes: peak_rss_bytes(),
        wall_seconds: wall.elapsed().as_secs_f64(),
    })
}

/// The report as text.
pub fn format_table(r: &DiffshegBenchReport) -> String {
    let mut s = String::new();
    use std::fmt::Write;
    let _ = writeln!(
        s,
        "DiffSHEG bench: {} ({}) on {} [{}], {} ({} cores, load {} -> {})",
        r.bundle,
        r.config.as_deref().unwrap_or("?"),
        r.backend,
        r.backend_description,
        r.machine.cpu,
        r.machine.cores,
        r.machine.loadavg_start,
        r.machine.loadavg_end
    );
    let _ = writeln!(
        s,
        "sampler: {} DDIM steps, jumps {}, window {}, overlap {}, guidance {} ({} denoiser rows per call); audio {}",
        r.ddim_steps, r.jumps, r.window, r.overlap, r.guidance, r.denoiser_rows, r.audio
    );
    let st = |x: &Stats| format!("median {:.2} ms (p95 {:.2}, n {})", x.median, x.p95, x.n);
    let _ = writeln!(s, "window (outpainting, whole push): {}", st(&r.window_ms));
    for g in &r.graphs {
        let _ = writeln!(
            s,
            "  {:<15} {:>5.1} calls/window, per call {}, per window {:.2} ms",
            g.graph,
            g.calls_per_window,
            st(&g.per_call),
            g.per_window_ms
        );
    }
    let _ = writeln!(
        s,
        "compute per second of audio: {:.3} s (real-time factor {:.2}x, {:.1} frames/s)",
        r.compute_per_audio_second, r.realtime_factor, r.fps
    );
    let _ = writeln!(
        s,
        "first frame: look-ahead {:.0} ms ({} frames of audio) + first window {} = {:.0} ms",
        r.lookahead_ms,
        r.window,
        st(&r.first_frame_compute),
        r.first_frame_ms
    );
    let _ = writeln!(
        s,
        "state per stream: {} bytes (held overlap, counters, audio buffer)",
        r.state_bytes_per_stream
    );
    if !r.steps_x_jumps.is_empty() {
        let _ = writeln!(s, "steps x jumps (outpainting windows):");
        let _ = writeln!(
            s,
            "  {:>5} {:>5} {:>6} {:>12} {:>14} {:>8}",
            "steps", "jumps", "calls", "window ms", "compute/audio", "fps"
        );
        for c in &r.steps_x_jumps {
            let _ = writeln!(
                s,
                "  {:>5} {:>5} {:>6} {:>12.2} {:>14.3} {:>8.1}",
                c.ddim_steps,
                c.jumps,
                c.denoiser_calls_per_window,
                c.window_ms.median,
                c.compute_per_audio_second,
                c.fps
            );
        }
    }
    if let Some(b) = r.peak_rss_bytes {
        let _ = writeln!(s, "peak RSS: {:.1} MiB", b as f64 / 1048576.0);
    }
    let _ = writeln!(
        s,
        "wall: {:.1} s, load {:.2} s",
        r.wall_seconds, r.load_seconds
    );
    s
}
