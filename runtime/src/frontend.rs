//! The log-mel audio frontend, reproducing `python/livegesture/frontend.py` exactly.
//!
//! # Definition
//!
//! All arithmetic is in `f64`; the output is cast to `f32`.
//!
//! - Input: mono samples at `sample_rate` (16 kHz). Sample `n` has stream index `n >= 0`; samples
//!   before the stream start (`n < 0`) are zeros.
//! - Mel frames run at `mel_frames_per_token` (8) per motion token, i.e. 60 per second. Mel frame `m`
//!   ends (exclusive) at sample
//!   `e_m = (m + 1) * sample_rate * frames_per_token / (fps * mel_frames_per_token)` (integer
//!   division, `u64`), which is `(m + 1) * 800 / 3` for the default configuration. Mel frame `8t + 7`
//!   ends exactly where motion token `t`'s audio ends (`(t + 1) * frames_per_token * sample_rate / fps`),
//!   so features stay on the token grid forever: no floating hop, no drift after hours.
//! - Frame `m` analyses samples `[e_m - win_length, e_m)` (zeros before 0), multiplied by the periodic
//!   Hann window `w[n] = 0.5 - 0.5 cos(2 pi n / win_length)` and zero-padded at the end to `n_fft`.
//! - Power spectrum `|FFT|^2` of bins `0 ..= n_fft / 2` (a complex FFT of size `n_fft` with `rustfft`),
//!   an HTK mel filterbank (`mel = 2595 log10(1 + f / 700)`, `n_mels` triangles with edges equally
//!   spaced in mel between `f_min` and `f_max`, no area normalisation), then `ln(energy + log_offset)`.
//!
//! A frame depends only on samples before its end, so the frontend has zero look-ahead.
//!
//! # Streaming
//!
//! [`StreamingLogMel`] takes chunks of any size (down to one sample) and returns the
//! `(mel_frames_per_token, n_mels)` frames of every motion token the chunk completes. It keeps only the
//! samples later frames still need (at most one token span plus one analysis window), and it computes
//! each frame with the same routine as the offline [`logmel`], so the output is bit-identical for every
//! chunking of the same audio.
//!
//! Token `t` is complete once `token_end(t) <= samples received`; the number of complete tokens in `n`
//! samples is [`FrontendConfig::n_tokens`] = `((n + 1) * fps - 1) / (sample_rate * frames_per_token)`.

use std::sync::Arc;

use anyhow::{bail, ensure, Result};
use ndarray::Array2;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

/// Frontend hyper-parameters. Field names match the Python dataclass `FrontendConfig`, so the
/// `frontend` object of a bundle manifest deserialises directly; unknown extra fields (the Python
/// `to_dict` adds descriptive strings such as `window` or `mel_scale`) are ignored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrontendConfig {
    /// Audio sample rate in Hz (16000).
    pub sample_rate: u64,
    /// Motion frames per second (30).
    pub fps: u64,
    /// Motion frames per motion token (4).
    pub frames_per_token: u64,
    /// Mel frames per motion token (8).
    pub mel_frames_per_token: u64,
    /// Analysis window length in samples (400).
    pub win_length: usize,
    /// FFT size (512); the windowed frame is zero-padded to this length.
    pub n_fft: usize,
    /// Number of mel bands (64).
    pub n_mels: usize,
    /// Lowest filterbank edge in Hz (0).
    pub f_min: f64,
    /// Highest filterbank edge in Hz (8000).
    pub f_max: f64,
    /// Added before the natural log (1e-6).
    pub log_offset: f64,
}

impl Default for FrontendConfig {
    fn default() -> Self {
        Self {
            sample_rate: 16000,
            fps: 30,
            frames_per_token: 4,
            mel_frames_per_token: 8,
            win_length: 400,
            n_fft: 512,
            n_mels: 64,
            f_min: 0.0,
            f_max: 8000.0,
            log_offset: 1e-6,
        }
    }
}

impl FrontendConfig {
    /// Checks that the configuration describes a computable frontend.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("sample_rate", self.sample_rate),
            ("fps", self.fps),
            ("frames_per_token", self.frames_per_token),
            ("mel_frames_per_token", self.mel_frames_per_token),
            ("win_length", self.win_length as u64),
            ("n_fft", self.n_fft as u64),
            ("n_mels", self.n_mels as u64),
        ] {
            ensure!(v > 0, "frontend config: {name} must be > 0, got {v}");
        }
        ensure!(
            self.win_length <= self.n_fft,
            "frontend config: win_length ({}) must not exceed n_fft ({})",
            self.win_length,
            self.n_fft
        );
        ensure!(
            self.f_min.is_finite()
                && self.f_max.is_finite()
                && 0.0 <= self.f_min
                && self.f_min < self.f_max,
            "frontend config: expected 0 <= f_min < f_max, got f_min={} f_max={}",
            self.f_min,
            self.f_max
        );
        ensure!(
            self.log_offset.is_finite() && self.log_offset >= 0.0,
            "frontend config: log_offset must be finite and >= 0, got {}",
            self.log_offset
        );
        Ok(())
    }

    /// Number of FFT bins kept, `n_fft / 2 + 1`.
    pub fn n_bins(&self) -> usize {
        self.n_fft / 2 + 1
    }

    /// Exclusive end sample of mel frame `m` (integer arithmetic).
    pub fn frame_end(&self, m: u64) -> u64 {
        (m + 1) * self.sample_rate * self.frames_per_token / (self.fps * self.mel_frames_per_token)
    }

    /// Exclusive end sample of motion token `t`'s audio span.
    pub fn token_end(&self, t: u64) -> u64 {
        (t + 1) * self.frames_per_token * self.sample_rate / self.fps
    }

    /// Number of complete motion tokens in `n_samples` samples.
    pub fn n_tokens(&self, n_samples: u64) -> u64 {
        ((n_samples + 1) * self.fps - 1) / (self.sample_rate * self.frames_per_token)
    }
}

/// HTK mel scale: `2595 log10(1 + f / 700)`.
pub fn hz_to_mel(f: f64) -> f64 {
    2595.0 * (1.0 + f / 700.0).log10()
}

/// Inverse HTK mel scale: `700 (10^(m / 2595) - 1)`.
pub fn mel_to_hz(m: f64) -> f64 {
    700.0 * (10f64.powf(m / 2595.0) - 1.0)
}

/// `n` points from `start` to `stop` inclusive, computed as numpy's `linspace` does
/// (`start + i * step`, last point exactly `stop`).
fn linspace(start: f64, stop: f64, n: usize) -> Vec<f64> {
    match n {
        0 => Vec::new(),
        1 => vec![start],
        _ => {
            let step = (stop - start) / (n - 1) as f64;
            let mut v: Vec<f64> = (0..n).map(|i| i as f64 * step + start).collect();
            v[n - 1] = stop;
            v
        }
    }
}

/// The `(n_mels, n_fft / 2 + 1)` triangular HTK mel filterbank, built exactly as the Python
/// `mel_filterbank`: bin `k` has frequency `k * sample_rate / n_fft`; filter `i` is
/// `max(0, min((f - lo) / (c - lo), (hi - f) / (hi - c)))` with `lo, c, hi` consecutive mel-spaced edges.
pub fn mel_filterbank(cfg: &FrontendConfig) -> Array2<f64> {
    let n_bins = cfg.n_bins();
    let freqs: Vec<f64> = (0..n_bins)
        .map(|k| k as f64 * cfg.sample_rate as f64 / cfg.n_fft as f64)
        .collect();
    let edges: Vec<f64> = linspace(hz_to_mel(cfg.f_min), hz_to_mel(cfg.f_max), cfg.n_mels + 2)
        .into_iter()
        .map(mel_to_hz)
        .collect();
    let mut fb = Array2::<f64>::zeros((cfg.n_mels, n_bins));
    for i in 0..cfg.n_mels {
        let (lo, c, hi) = (edges[i], edges[i + 1], edges[i + 2]);
        for (k, &f) in freqs.iter().enumerate() {
            let up = (f - lo) / (c - lo);
            let down = (hi - f) / (hi - c);
            fb[[i, k]] = 0.0f64.max(up.min(down));
        }
    }
    fb
}

/// Periodic Hann window `0.5 - 0.5 cos(2 pi n / len)`.
pub fn hann_periodic(len: usize) -> Vec<f64> {
    (0..len)
        .map(|n| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * n as f64 / len as f64).cos())
        .collect()
}

/// One mel filter stored sparsely: its first non-zero bin and the weights from there on. Skipping
/// zero weights does not change the result (adding `+0.0` products to a sum is exact).
#[derive(Debug, Clone)]
struct SparseFilter {
    first_bin: usize,
    weights: Vec<f64>,
}

/// The per-frame analyser shared by the offline and streaming paths: window, FFT, power, mel, log.
pub struct LogMelAnalyzer {
    cfg: FrontendConfig,
    window: Vec<f64>,
    filters: Vec<SparseFilter>,
    fft: Arc<dyn Fft<f64>>,
    buf: Vec<Complex<f64>>,
    scratch: Vec<Complex<f64>>,
    power: Vec<f64>,
}

impl std::fmt::Debug for LogMelAnalyzer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogMelAnalyzer")
            .field("cfg", &self.cfg)
            .finish_non_exhaustive()
    }
}

impl LogMelAnalyzer {
    /// Builds the window, filterbank and FFT plan for `cfg` (validated first).
    pub fn new(cfg: &FrontendConfig) -> Result<Self> {
        cfg.validate()?;
        let fb = mel_filterbank(cfg);
        let filters = fb
            .outer_iter()
            .map(|row| {
                let nz: Vec<usize> = row
                    .iter()
                    .enumerate()
                    .filter(|(_, &w)| w != 0.0)
                    .map(|(k, _)| k)
                    .collect();
                match (nz.first(), nz.last()) {
                    (Some(&a), Some(&b)) => SparseFilter {
                        first_bin: a,
                        weights: row.slice(ndarray::s![a..=b]).to_vec(),
                    },
                    _ => SparseFilter {
                        first_bin: 0,
                        weights: Vec::new(),
                    },
                }
            })
            .collect();
        let fft = FftPlanner::<f64>::new().plan_fft_forward(cfg.n_fft);
        let scratch = vec![Complex::new(0.0, 0.0); fft.get_inplace_scratch_len()];
        Ok(Self {
            cfg: cfg.clone(),
            window: hann_periodic(cfg.win_length),
            filters,
            fft,
            buf: vec![Complex::new(0.0, 0.0); cfg.n_fft],
            scratch,
            power: vec![0.0; cfg.n_bins()],
        })
    }

    /// The configuration this analyser was built for.
    pub fn config(&self) -> &FrontendConfig {
        &self.cfg
    }

    /// Computes one log-mel frame. `sample(i)` returns the frame's `i`-th sample
    /// (`0 <= i < win_length`, zero for samples before the stream start); `out` has `n_mels` entries.
    fn frame_with(&mut self, sample: impl Fn(usize) -> f64, out: &mut [f32]) {
        debug_assert_eq!(out.len(), self.cfg.n_mels);
        for (i, c) in self.buf.iter_mut().enumerate() {
            let re = if i < self.cfg.win_length {
                sample(i) * self.window[i]
            } else {
                0.0
            };
            *c = Complex::new(re, 0.0);
        }
        self.fft
            .process_with_scratch(&mut self.buf, &mut self.scratch);
        for (p, c) in self.power.iter_mut().zip(&self.buf) {
            *p = c.re * c.re + c.im * c.im;
        }
        for (o, f) in out.iter_mut().zip(&self.filters) {
            let mut e = 0.0f64;
            for (w, p) in f.weights.iter().zip(&self.power[f.first_bin..]) {
                e += p * w;
            }
            *o = (e + self.cfg.log_offset).ln() as f32;
        }
    }

    /// Computes one log-mel frame from exactly `win_length` samples (already including any zeros
    /// before the stream start) into `out` (`n_mels` values).
    pub fn frame(&mut self, window_samples: &[f64], out: &mut [f32]) -> Result<()> {
        ensure!(
            window_samples.len() == self.cfg.win_length,
            "frontend: a frame needs {} samples, got {}",
            self.cfg.win_length,
            window_samples.len()
        );
        ensure!(
            out.len() == self.cfg.n_mels,
            "frontend: output needs {} mel bins, got {}",
            self.cfg.n_mels,
            out.len()
        );
        self.frame_with(|i| window_samples[i], out);
        Ok(())
    }
}

fn check_finite(samples: &[f32], first_index: u64) -> Result<()> {
    if let Some(i) = samples.iter().position(|x| !x.is_finite()) {
        bail!(
            "frontend: audio contains a non-finite sample ({}) at stream sample {}; expected finite samples",
            samples[i],
            first_index + i as u64
        );
    }
    Ok(())
}

/// Log-mel frames of all complete tokens of a whole clip: `(n_tokens * mel_frames_per_token, n_mels)`.
///
/// Trailing samples that do not complete a token are ignored, as in the Python `logmel`.
pub fn logmel(samples: &[f32], cfg: &FrontendConfig) -> Result<Array2<f32>> {
    let mut an = LogMelAnalyzer::new(cfg)?;
    check_finite(samples, 0)?;
    let n_frames = cfg.n_tokens(samples.len() as u64) * cfg.mel_frames_per_token;
    let mut out = Array2::<f32>::zeros((n_frames as usize, cfg.n_mels));
    let win = cfg.win_length as i64;
    for (m, mut row) in out.outer_iter_mut().enumerate() {
        let start = cfg.frame_end(m as u64) as i64 - win;
        let row = row
            .as_slice_mut()
            .expect("rows of a standard-layout array are contiguous");
        an.frame_with(
            |i| {
                let n = start + i as i64;
                if n < 0 {
                    0.0
                } else {
                    samples[n as usize] as f64
                }
            },
            row,
        );
    }
    Ok(out)
}

/// Streaming log-mel frontend: push chunks of any size, get the mel frames of each completed token.
///
/// Memory is bounded: only the samples that later frames still need are kept (at most one token's
/// span plus one window, whatever the chunk size). Output is bit-identical to [`logmel`] for every
/// chunking of the same audio.
#[derive(Debug)]
pub struct StreamingLogMel {
    an: LogMelAnalyzer,
    /// Samples kept; `buf[0]` is stream sample `buf_offset`.
    buf: Vec<f64>,
    buf_offset: u64,
    /// Samples received so far.
    n_samples: u64,
    /// Next token to emit.
    next_token: u64,
}

impl StreamingLogMel {
    /// A fresh stream (cold start: samples before the first one are zeros).
    pub fn new(cfg: &FrontendConfig) -> Result<Self> {
        Ok(Self {
            an: LogMelAnalyzer::new(cfg)?,
            buf: Vec::new(),
            buf_offset: 0,
            n_samples: 0,
            next_token: 0,
        })
    }

    /// The configuration of this stream.
    pub fn config(&self) -> &FrontendConfig {
        self.an.config()
    }

    /// Forgets all audio and starts a new stream at sample 0.
    pub fn reset(&mut self) {
        self.buf.clear();
        self.buf_offset = 0;
        self.n_samples = 0;
        self.next_token = 0;
    }

    /// Samples received since the start (or the last reset).
    pub fn samples_received(&self) -> u64 {
        self.n_samples
    }

    /// Tokens emitted so far; also the index of the next token to be emitted.
    pub fn tokens_emitted(&self) -> u64 {
        self.next_token
    }

    /// Samples currently held (bounded by one token span plus one window).
    pub fn buffered_samples(&self) -> usize {
        self.buf.len()
    }

    /// Pushes a chunk of samples and returns one `(mel_frames_per_token, n_mels)` array per token the
    /// chunk completes, in order (possibly none).
    ///
    /// A chunk containing NaN or infinity is rejected as a whole, before any of it is consumed, so the
    /// stream state is unchanged by a failed push.
    pub fn push(&mut self, chunk: &[f32]) -> Result<Vec<Array2<f32>>> {
        check_finite(chunk, self.n_samples)?;
        let mut out = Vec::new();
        let mut rest = chunk;
        while !rest.is_empty() {
            let end = self.an.cfg.token_end(self.next_token);
            let need = (end - self.n_samples) as usize;
            let take = need.min(rest.len());
            self.buf.extend(rest[..take].iter().map(|&x| x as f64));
            self.n_samples += take as u64;
            rest = &rest[take..];
            if self.n_samples == end {
                out.push(self.emit_token());
            }
        }
        Ok(out)
    }

    /// Computes the frames of token `next_token` (all its samples are present), then drops the
    /// samples no later frame needs.
    fn emit_token(&mut self) -> Array2<f32> {
        let mpt = self.an.cfg.mel_frames_per_token;
        let win = self.an.cfg.win_length as i64;
        let mut frames = Array2::<f32>::zeros((mpt as usize, self.an.cfg.n_mels));
        let first = self.next_token * mpt;
        for (j, mut row) in frames.outer_iter_mut().enumerate() {
            let start = self.an.cfg.frame_end(first + j as u64) as i64 - win;
            let off = self.buf_offset as i64;
            let buf = &self.buf;
            let row = row
                .as_slice_mut()
                .expect("rows of a standard-layout array are contiguous");
            self.an.frame_with(
                |i| {
                    let n = start + i as i64;
                    if n < 0 {
                        0.0
                    } else {
                        buf[(n - off) as usize]
                    }
                },
                row,
            );
        }
        self.next_token += 1;
        let keep_from = self
            .an
            .cfg
            .frame_end(self.next_token * mpt)
            .saturating_sub(self.an.cfg.win_length as u64);
        if keep_from > self.buf_offset {
            let drop = ((keep_from - self.buf_offset) as usize).min(self.buf.len());
            self.buf.drain(..drop);
            self.buf_offset += drop as u64;
        }
        frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signal(n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let t = i as f64 / 16000.0;
                (0.3 * (2.0 * std::f64::consts::PI * 220.0 * t).sin()
                    + 0.1 * (2.0 * std::f64::consts::PI * 3100.0 * t).sin()
                    + 0.01 * ((i * 7919 % 1000) as f64 / 500.0 - 1.0)) as f32
            })
            .collect()
    }

    #[test]
    fn integer_grid() {
        let c = FrontendConfig::default();
        assert_eq!(c.frame_end(0), 266);
        assert_eq!(c.frame_end(2), 800);
        // mel frame 8t+7 ends where token t ends
        for t in [0u64, 1, 2, 7, 1000, 123_456_789] {
            assert_eq!(c.frame_end(8 * t + 7), c.token_end(t));
        }
        assert_eq!(c.token_end(0), 2133);
        assert_eq!(c.n_tokens(0), 0);
        assert_eq!(c.n_tokens(2132), 0);
        assert_eq!(c.n_tokens(2133), 1);
        assert_eq!(c.n_tokens(16000), 7);
        // n_tokens agrees with token_end everywhere
        for n in 0..20_000u64 {
            let k = c.n_tokens(n);
            assert!(k == 0 || c.token_end(k - 1) <= n);
            assert!(c.token_end(k) > n);
        }
        // one day of audio: no drift, exact tokens
        let day = 16000u64 * 86400;
        assert_eq!(c.n_tokens(day), 86400 * 30 / 4);
    }

    #[test]
    fn filterbank_shape_and_peaks() {
        let c = FrontendConfig {
            n_mels: 16,
            ..Default::default()
        };
        let fb = mel_filterbank(&c);
        assert_eq!(fb.dim(), (16, 257));
        for row in fb.outer_iter() {
            assert!(row.iter().all(|&w| (0.0..=1.0).contains(&w)));
            assert!(row.iter().cloned().fold(0.0, f64::max) > 0.5);
        }
        assert!((hz_to_mel(mel_to_hz(1234.5)) - 1234.5).abs() < 1e-9);
    }

    #[test]
    fn config_json_ignores_extra_fields() {
        let j = r#"{"sample_rate":16000,"fps":30,"frames_per_token":4,"mel_frames_per_token":8,
            "win_length":400,"n_fft":512,"n_mels":64,"f_min":0.0,"f_max":8000.0,"log_offset":1e-6,
            "type":"logmel","window":"hann_periodic","norm":null}"#;
        let c: FrontendConfig = serde_json::from_str(j).unwrap();
        assert_eq!(c, FrontendConfig::default());
        let bad = FrontendConfig {
            win_length: 1024,
            ..Default::default()
        };
        assert!(bad
            .validate()
            .unwrap_err()
            .to_string()
            .contains("win_length"));
    }

    #[test]
    fn silence_is_log_offset() {
        let c = FrontendConfig::default();
        let m = logmel(&vec![0.0; 4000], &c).unwrap();
        assert_eq!(m.dim(), (8, 64));
        assert!(m.iter().all(|&v| v == (1e-6f64).ln() as f32));
    }

    #[test]
    fn streaming_matches_offline_for_any_chunking() {
        let c = FrontendConfig::default();
        let x = signal(16000 + 517);
        let off = logmel(&x, &c).unwrap();
        for chunk in [1usize, 7, 160, 2133, 3200, 100_000] {
            let mut s = StreamingLogMel::new(&c).unwrap();
            let mut frames = Vec::new();
            for ch in x.chunks(chunk) {
                for tok in s.push(ch).unwrap() {
                    assert_eq!(tok.dim(), (8, 64));
                    frames.extend(tok.iter().copied());
                }
                assert!(
                    s.buffered_samples() <= 2134 + 400,
                    "buffer grew to {}",
                    s.buffered_samples()
                );
            }
            assert_eq!(s.tokens_emitted(), c.n_tokens(x.len() as u64));
            assert_eq!(
                frames.as_slice(),
                off.as_slice().unwrap(),
                "chunk size {chunk}"
            );
        }
    }

    #[test]
    fn rejects_nan_without_consuming() {
        let c = FrontendConfig::default();
        let mut s = StreamingLogMel::new(&c).unwrap();
        s.push(&[0.1; 100]).unwrap();
        let err = s.push(&[0.0, f32::NAN]).unwrap_err().to_string();
        assert!(err.contains("non-finite") && err.contains("101"), "{err}");
        assert_eq!(s.samples_received(), 100);
        assert!(logmel(&[0.0, f32::INFINITY], &c).is_err());
    }
}
