//! One DiffSHEG stream's windowing (`foppas.py`'s `DiffSHEGStream`): the audio buffer, when each window
//! runs, the held-back overlap, the noise position, and the per-window graph chain
//! (`speech_encoder` once per window, then the denoiser per DDIM step and jump, both guidance rows on
//! the batch axis of one call).
//!
//! The graphs are behind [`WindowGraphs`], so the windowing runs on any backend (and on the Python
//! reference's recorded outputs in tests). The output is normalised motion rows; de-normalisation and
//! frames are the model's business ([`super::DiffshegModel`]).

use std::sync::Arc;

use anyhow::{ensure, Context, Result};

use super::foppas::{guided_eps, SamplerOptions, WindowSampler, MOTION_DIM};
use super::noise::NoiseStream;
use super::schedule::Schedule;
use crate::frontend::{FrontendConfig, LogMelAnalyzer};

/// The two graphs of a window.
pub trait WindowGraphs {
    /// `speech_encoder`: raw log-mel frames (2n x n_mels, row-major) -> audio features (n x audio_dim).
    fn encode(&self, mel: &[f32], n: usize) -> Result<Vec<f32>>;

    /// `denoiser` on `conds.len()` rows sharing `x` (n x D), `t`, `audio` and `speaker`; row r has
    /// `cond = conds[r]`. Returns eps of every row (rows x n x D, row-major).
    fn denoise(
        &self,
        x: &[f32],
        n: usize,
        t: i64,
        audio: &[f32],
        speaker: i64,
        conds: &[f32],
    ) -> Result<Vec<f32>>;
}

/// One denoiser call of a recorded window: input x, timestep, guided eps.
#[derive(Debug, Clone)]
pub struct TraceCall {
    /// The call's x (n x D).
    pub x: Vec<f32>,
    /// DDIM timestep.
    pub t: i64,
    /// Guided eps (n x D, float64).
    pub eps: Vec<f64>,
}

/// Everything about one window, kept with recording on (parity tools).
#[derive(Debug, Clone)]
pub struct WindowRecord {
    /// First frame.
    pub start: usize,
    /// Frames.
    pub n: usize,
    /// Frames emitted by this window.
    pub emitted: usize,
    /// Known frames it started from (0 for the first).
    pub overlap_in: usize,
    /// Noise position before and after the window.
    pub noise_start: u64,
    pub noise_end: u64,
    /// Log-mel frames (2n x n_mels) and speech features (n x audio_dim).
    pub mel: Vec<f32>,
    pub audio: Vec<f32>,
    /// Known frames (L x D) and the window's result (n x D).
    pub known: Option<Vec<f32>>,
    pub x0: Vec<f32>,
    /// Every denoiser call (recorded for window 1 only, the first outpainting window).
    pub trace: Option<Vec<TraceCall>>,
}

/// Normalised motion rows emitted by one window: frames `start .. start + rows.len() / D`.
#[derive(Debug, Clone, PartialEq)]
pub struct Emitted {
    /// First frame index.
    pub start: usize,
    /// Rows (frames x D, row-major).
    pub rows: Vec<f32>,
}

/// The stream state (`foppas.state` in the manifest): `next_start`, `overlap`, `noise_position`,
/// and the frontend's sample buffer.
#[derive(Debug)]
pub struct FoppasStream {
    opts: SamplerOptions,
    schedule: Arc<Schedule>,
    speaker: i64,
    seed: u64,
    analyzer: LogMelAnalyzer,
    /// Samples kept; `buf[0]` is stream sample `buf_offset`.
    buf: Vec<f32>,
    buf_offset: u64,
    n_samples: u64,
    next_start: usize,
    overlap: Option<Vec<f32>>,
    noise: NoiseStream,
    emitted: usize,
    /// Set by [`FoppasStream::begin_finish`]: the frames that cover the whole input.
    finishing: Option<usize>,
    finished: bool,
    windows_run: usize,
    record: Option<Vec<WindowRecord>>,
}

/// A window begun by [`FoppasStream::start_window`]: where it lies and its log-mel frames. The
/// caller encodes the frames (`speech_encoder`), runs the window's [`WindowSampler`]
/// ([`FoppasStream::sampler`]) and hands the result to [`FoppasStream::complete_window`]; windows of
/// several streams can so share graph calls.
#[derive(Debug, Clone)]
pub struct WindowStart {
    /// First frame.
    pub start: usize,
    /// Frames.
    pub n: usize,
    /// True for the stream's last window (it emits all its frames).
    pub last: bool,
    /// Log-mel frames (2n x n_mels, row-major).
    pub mel: Vec<f32>,
    overlap_in: usize,
    noise_start: u64,
}

impl FoppasStream {
    /// A cold stream.
    pub fn new(
        frontend: &FrontendConfig,
        schedule: Arc<Schedule>,
        opts: SamplerOptions,
        speaker: i64,
        seed: u64,
        record: bool,
    ) -> Result<Self> {
        Ok(Self {
            opts,
            schedule,
            speaker,
            seed,
            analyzer: LogMelAnalyzer::new(frontend)?,
            buf: Vec::new(),
            buf_offset: 0,
            n_samples: 0,
            next_start: 0,
            overlap: None,
            noise: NoiseStream::new(seed),
            emitted: 0,
            finishing: None,
            finished: false,
            windows_run: 0,
            record: record.then(Vec::new),
        })
    }

    /// Back to a cold start with the same options, speaker and seed.
    pub fn reset(&mut self) {
        self.buf.clear();
        self.buf_offset = 0;
        self.n_samples = 0;
        self.next_start = 0;
        self.overlap = None;
        self.noise = NoiseStream::new(self.seed);
        self.emitted = 0;
        self.finishing = None;
        self.finished = false;
        self.windows_run = 0;
        if let Some(r) = &mut self.record {
            r.clear();
        }
    }

    /// The options in use.
    pub fn options(&self) -> &SamplerOptions {
        &self.opts
    }

    /// Style id in use.
    pub fn speaker(&self) -> i64 {
        self.speaker
    }

    /// Samples pushed so far.
    pub fn samples_received(&self) -> u64 {
        self.n_samples
    }

    /// Frames emitted so far.
    pub fn frames_emitted(&self) -> usize {
        self.emitted
    }

    /// Normals drawn so far.
    pub fn noise_position(&self) -> u64 {
        self.noise.position
    }

    /// Samples held in the frontend buffer.
    pub fn buffered_samples(&self) -> usize {
        self.buf.len()
    }

    /// True after [`FoppasStream::finish`].
    pub fn is_finished(&self) -> bool {
        self.finished
    }

    /// True when the stream records its windows (parity tools).
    pub fn is_recording(&self) -> bool {
        self.record.is_some()
    }

    /// The recorded windows (recording on).
    pub fn records(&self) -> &[WindowRecord] {
        self.record.as_deref().unwrap_or(&[])
    }

    /// Bytes of state between windows: the held overlap, the counters, the frontend buffer (f32).
    pub fn state_bytes(&self) -> usize {
        self.overlap.as_ref().map_or(0, |o| o.len() * 4) + 8 * 3 + self.buf.len() * 4
    }

    /// The sample at whose arrival the window starting at `start` runs: `(start + N) * 16000 // 30`.
    fn window_ready_sample(&self, start: usize) -> u64 {
        let sr = self.analyzer.config().sample_rate;
        let fps = self.analyzer.config().fps;
        (start + self.opts.window) as u64 * sr / fps
    }

    /// Pushes samples (any chunk size) and runs every window whose audio is complete.
    pub fn push(&mut self, graphs: &dyn WindowGraphs, samples: &[f32]) -> Result<Vec<Emitted>> {
        self.accept(samples)?;
        let mut out = Vec::new();
        while let Some((n, last)) = self.next_window() {
            out.push(self.run_window(graphs, n, last)?);
        }
        Ok(out)
    }

    /// Buffers samples without running any window (see [`FoppasStream::next_window`]). Errors,
    /// changing nothing, for a finished stream or a non-finite sample.
    pub fn accept(&mut self, samples: &[f32]) -> Result<()> {
        ensure!(
            !self.finished && self.finishing.is_none(),
            "the stream has finished; reset it before pushing more audio"
        );
        if let Some(i) = samples.iter().position(|x| !x.is_finite()) {
            anyhow::bail!(
                "audio contains a non-finite sample ({}) at stream sample {}; expected finite samples",
                samples[i],
                self.n_samples + i as u64
            );
        }
        self.buf.extend_from_slice(samples);
        self.n_samples += samples.len() as u64;
        Ok(())
    }

    /// The next window that is due, `(frames, last)`: one whose audio has arrived, or, after
    /// [`FoppasStream::begin_finish`], the next of the windows that cover the input. `None` when
    /// nothing is due.
    pub fn next_window(&self) -> Option<(usize, bool)> {
        if self.finished {
            return None;
        }
        let s = self.next_start;
        match self.finishing {
            Some(t) => Some((self.opts.window.min(t - s), s + self.opts.window >= t)),
            None => {
                (self.window_ready_sample(s) <= self.n_samples).then_some((self.opts.window, false))
            }
        }
    }

    /// The number of samples pushed in all at which the next window runs; `u64::MAX` once the stream
    /// is finished (or finishing).
    pub fn next_window_samples(&self) -> u64 {
        if self.finished || self.finishing.is_some() {
            u64::MAX
        } else {
            self.window_ready_sample(self.next_start)
        }
    }

    /// Ends the stream so that exactly `total_frames` frames are emitted in all (for 16 kHz input
    /// `ceil(n_samples * 30 / 16000)`): pads with silence and runs the remaining windows.
    pub fn finish(
        &mut self,
        graphs: &dyn WindowGraphs,
        total_frames: usize,
    ) -> Result<Vec<Emitted>> {
        if self.finished {
            return Ok(Vec::new());
        }
        if let Some(e) = self.begin_finish(total_frames)? {
            return Ok(vec![e]);
        }
        let mut out = Vec::new();
        while let Some((n, last)) = self.next_window() {
            out.push(self.run_window(graphs, n, last)?);
        }
        Ok(out)
    }

    /// Begins the end of the stream at `total_frames` frames in all (see [`FoppasStream::finish`]):
    /// pads the audio with silence. Returns the held overlap's rows when they alone complete the
    /// stream (it is then finished); otherwise the windows still to run come from
    /// [`FoppasStream::next_window`]. Run the windows due by audio first.
    pub fn begin_finish(&mut self, total_frames: usize) -> Result<Option<Emitted>> {
        ensure!(
            !self.finished && self.finishing.is_none(),
            "the stream has finished; reset it before finishing it again"
        );
        let t = total_frames;
        ensure!(
            t >= self.next_start + self.overlap.as_ref().map_or(0, |o| o.len() / MOTION_DIM),
            "finish: {t} frames requested, but windows up to frame {} have already run",
            self.next_start + self.overlap.as_ref().map_or(0, |o| o.len() / MOTION_DIM)
        );
        if t == 0 {
            self.finished = true;
            return Ok(None);
        }
        let cfg = self.analyzer.config();
        let need = t as u64 * cfg.sample_rate / cfg.fps;
        let have = self.buf_offset + self.buf.len() as u64;
        if need > have {
            self.buf
                .resize(self.buf.len() + (need - have) as usize, 0.0);
        }
        let l = self.opts.overlap;
        let s = self.next_start;
        if let Some(held) = &self.overlap {
            if t - s <= l {
                let rows = held[..(t - s) * MOTION_DIM].to_vec();
                self.emitted = t;
                self.overlap = None;
                self.finished = true;
                return Ok(Some(Emitted { start: s, rows }));
            }
        }
        self.finishing = Some(t);
        Ok(None)
    }

    /// Log-mel frames `2s .. 2(s+n) - 1` from the buffer (zeros before sample 0).
    fn mel(&mut self, s: usize, n: usize) -> Result<Vec<f32>> {
        let cfg = self.analyzer.config().clone();
        let n_mels = cfg.n_mels;
        let win = cfg.win_length;
        let mut out = vec![0f32; 2 * n * n_mels];
        let mut frame = vec![0f64; win];
        for (k, row) in out.chunks_exact_mut(n_mels).enumerate() {
            let m = (2 * s + k) as u64;
            let start = cfg.frame_end(m) as i64 - win as i64;
            for (i, v) in frame.iter_mut().enumerate() {
                let idx = start + i as i64;
                *v = if idx < 0 {
                    0.0
                } else {
                    let j = (idx as u64)
                        .checked_sub(self.buf_offset)
                        .context("frontend: a sample the window needs was dropped")?
                        as usize;
                    *self
                        .buf
                        .get(j)
                        .context("frontend: a sample the window needs has not arrived")?
                        as f64
                };
            }
            self.analyzer.frame(&frame, row)?;
        }
        Ok(out)
    }

    fn run_window(&mut self, graphs: &dyn WindowGraphs, n: usize, last: bool) -> Result<Emitted> {
        let w = self.start_window(n, last)?;
        let s = w.start;
        let d = MOTION_DIM;
        let audio = graphs
            .encode(&w.mel, n)
            .with_context(|| format!("window at frame {s}: speech_encoder"))?;
        let mut trace = self.wants_trace().then(Vec::new);
        let rows = self.opts.rows();
        let conds = [1.0f32, 0.0][..rows].to_vec();
        let (speaker, gamma) = (self.speaker, self.opts.guidance);
        let mut sampler = self.sampler(&w)?;
        while let Some(c) = sampler.next_call() {
            let out = graphs
                .denoise(c.x, n, c.t, &audio, speaker, &conds)
                .with_context(|| format!("window at frame {s}: denoiser at t = {}", c.t))?;
            ensure!(
                out.len() == rows * n * d,
                "denoiser returned {} values, expected {rows} x {n} x {d}",
                out.len()
            );
            let (cr, ur) = out.split_at(n * d);
            let eps = guided_eps(cr, (rows == 2).then_some(ur), gamma);
            if let Some(tr) = &mut trace {
                tr.push(TraceCall {
                    x: c.x.to_vec(),
                    t: c.t,
                    eps: eps.clone(),
                });
            }
            sampler.feed(&eps)?;
        }
        let (x0, noise) = sampler.finish()?;
        Ok(self.complete_window(w, audio, x0, noise, trace))
    }

    /// Begins the window of `n` frames at the next start (`last`: the stream's last window): its
    /// log-mel frames from the buffer.
    pub fn start_window(&mut self, n: usize, last: bool) -> Result<WindowStart> {
        let s = self.next_start;
        let overlap_in = self.overlap.as_ref().map_or(0, |o| o.len() / MOTION_DIM);
        let mel = self.mel(s, n)?;
        Ok(WindowStart {
            start: s,
            n,
            last,
            mel,
            overlap_in,
            noise_start: self.noise.position,
        })
    }

    /// The sampler of window `w`: from the held overlap and the stream's noise.
    pub fn sampler(&self, w: &WindowStart) -> Result<WindowSampler> {
        WindowSampler::new(
            w.n,
            self.overlap.as_deref(),
            self.opts,
            self.schedule.clone(),
            self.noise,
        )
    }

    /// True when the next window's denoiser calls are to be recorded (recording on, window 1).
    pub fn wants_trace(&self) -> bool {
        self.record.is_some() && self.windows_run == 1
    }

    /// Completes window `w` with its speech features `audio`, the sampler's clean motion `x0` and
    /// the noise after it: records it (recording on), holds the overlap, moves to the next window.
    pub fn complete_window(
        &mut self,
        w: WindowStart,
        audio: Vec<f32>,
        x0: Vec<f32>,
        noise: NoiseStream,
        trace: Option<Vec<TraceCall>>,
    ) -> Emitted {
        let d = MOTION_DIM;
        let (s, n, last) = (w.start, w.n, w.last);
        self.noise = noise;
        let emit = if last { n } else { n - self.opts.overlap };
        if let Some(r) = &mut self.record {
            r.push(WindowRecord {
                start: s,
                n,
                emitted: emit,
                overlap_in: w.overlap_in,
                noise_start: w.noise_start,
                noise_end: self.noise.position,
                mel: w.mel,
                audio,
                known: self.overlap.clone(),
                x0: x0.clone(),
                trace,
            });
        }
        self.windows_run += 1;
        let rows_out = x0[..emit * d].to_vec();
        self.emitted = s + emit;
        if last {
            self.overlap = None;
            self.finishing = None;
            self.finished = true;
        } else {
            let l = self.opts.overlap;
            self.overlap = (l > 0).then(|| x0[(n - l) * d..].to_vec());
            self.next_start = s + n - l;
            let cfg = self.analyzer.config();
            let keep_from = cfg
                .frame_end(2 * self.next_start as u64)
                .saturating_sub(cfg.win_length as u64);
            if keep_from > self.buf_offset {
                let drop = ((keep_from - self.buf_offset) as usize).min(self.buf.len());
                self.buf.drain(..drop);
                self.buf_offset += drop as u64;
            }
        }
        Emitted {
            start: s,
            rows: rows_out,
        }
    }
}
