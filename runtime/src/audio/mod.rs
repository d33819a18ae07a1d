//! Audio input: WAV files and raw PCM streams, converted to 16 kHz mono `f32`.
//!
//! # Conversions
//!
//! - **Sample values.** Integer PCM of `b` bits (8, 16, 24 or 32; 8-bit WAV is unsigned with offset
//!   128, as the WAV format defines) becomes `x / 2^(b-1)`, in `[-1, 1)`; 32-bit float is taken as is.
//!   Any other encoding (12-bit, 64-bit float, ADPCM, ...) is refused. NaN or infinite samples are
//!   refused with the sample's index.
//! - **Channels.** Any channel count is mixed to mono as the mean of the channels (computed in `f64`).
//!   A mono file's samples are passed through unchanged.
//! - **Sample rate.** Audio at exactly 16 kHz is passed through untouched. Any other rate is resampled
//!   with a windowed-sinc resampler (`rubato::SincFixedIn`, 128 taps, Blackman–Harris window, cubic
//!   interpolation between 256 oversampled sinc points, `f64` arithmetic). The resampler always
//!   consumes fixed blocks of [`RESAMPLE_BLOCK`] input frames, buffering what the caller hands in, so
//!   **the output does not depend on how the caller chunks the input**. Output sample `j` is the
//!   band-limited signal at input time exactly `j * rate_in / 16000` (no delay, no fractional offset),
//!   and when the stream ends the tail is flushed so that exactly `floor(n_in * 16000 / rate_in)`
//!   samples come out in total. Streaming latency is that of the block plus half the filter.
//!
//! # Streaming
//!
//! [`WavStream`] reads a file block by block and yields 16 kHz mono chunks, so memory does not grow
//! with the file's length; [`read_wav_16k_mono`] collects it for whole-file use. [`RawPcmStream`]
//! does the same for headerless PCM (`s16le`, `s32le`, `f32le`) from any reader such as stdin, with
//! [`RawPcmDecoder`] handling reads that end in the middle of a sample or frame.
//!
//! # Errors
//!
//! Every [`AudioError`] names the file (or stream) and says what was expected: missing file, empty
//! file, file without samples, truncated file, non-WAV file, unsupported encoding, non-finite samples,
//! a stream ending in the middle of a frame.

//!
//! # Layout
//!
//! - `resample`: [`Resampler16k`], any rate to 16 kHz, independent of the caller's chunking;
//! - `wav`: [`WavStream`] and [`read_wav_16k_mono`];
//! - `raw`: [`RawPcmDecoder`] and [`RawPcmStream`] for headerless PCM;
//! - here: the errors, the mono mix, and [`AudioSpan`] (how much input a source delivered, which
//!   fixes the number of frames that cover it, docs/output.md).

use std::io;
use std::path::PathBuf;

mod raw;
mod resample;
mod wav;

pub use raw::{RawFormat, RawPcmDecoder, RawPcmStream};
pub use resample::Resampler16k;
pub use wav::{read_wav_16k_mono, WavStream};

pub const TARGET_RATE: u32 = 16_000;

/// Input frames the resampler consumes per block (independent of the caller's chunking).
pub const RESAMPLE_BLOCK: usize = 1024;

/// Frames read from a WAV file per block by [`WavStream`] unless changed.
pub const DEFAULT_READ_FRAMES: usize = 4096;

const EXPECTED_ENCODINGS: &str = "8, 16, 24 or 32-bit integer PCM or 32-bit float";

/// Errors from reading or converting audio. Each names its source (a path, or a stream name such as
/// `<stdin>`) and says what was expected.
#[derive(Debug, thiserror::Error)]
pub enum AudioError {
    #[error("{}: no such file; expected a WAV file at this path", .path.display())]
    NotFound { path: PathBuf },
    #[error("{origin}: I/O error: {source}")]
    Io { origin: String, source: io::Error },
    #[error("{}: the file is empty (0 bytes); expected a RIFF/WAVE file", .path.display())]
    EmptyFile { path: PathBuf },
    #[error("{}: the WAV file contains no audio samples; expected at least one sample", .path.display())]
    NoSamples { path: PathBuf },
    #[error("{}: not a WAV file ({reason}); expected a RIFF/WAVE file", .path.display())]
    NotWav { path: PathBuf, reason: String },
    #[error("{}: the file is truncated ({detail}); expected a complete WAV file", .path.display())]
    Truncated { path: PathBuf, detail: String },
    #[error("{}: unsupported encoding: {found}; expected {EXPECTED_ENCODINGS}", .path.display())]
    UnsupportedEncoding { path: PathBuf, found: String },
    #[error("{}: malformed WAV file ({reason}); expected a valid RIFF/WAVE file with {EXPECTED_ENCODINGS}", .path.display())]
    Malformed { path: PathBuf, reason: String },
    #[error("{origin}: sample {index} is {value}; expected finite samples (no NaN or infinity)")]
    NonFinite {
        origin: String,
        index: u64,
        value: f32,
    },
    #[error("{origin}: the stream ended in the middle of a frame ({bytes} stray bytes); expected whole frames of {frame_bytes} bytes")]
    PartialFrame {
        origin: String,
        bytes: usize,
        frame_bytes: usize,
    },
    #[error("{origin}: invalid setting: {detail}")]
    InvalidSetting { origin: String, detail: String },
    #[error("{origin}: resampling from {rate} Hz failed: {detail}")]
    Resample {
        origin: String,
        rate: u32,
        detail: String,
    },
}

/// Description of a WAV file's contents.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WavInfo {
    /// Source sample rate in Hz.
    pub sample_rate: u32,
    /// Source channel count.
    pub channels: u16,
    /// Bits per sample.
    pub bits_per_sample: u16,
    /// True for IEEE float samples.
    pub is_float: bool,
    /// Frames (samples per channel) in the file.
    pub frames: u64,
}

/// How much audio a source delivered, counted at its **own** sample rate (before any conversion).
///
/// It fixes how many frames cover the audio (docs/output.md): [`AudioSpan::frames`]. The readers report it
/// ([`WavStream::input_span`], [`RawPcmStream::input_span`]) and a stream's `finish` takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AudioSpan {
    /// Samples per channel received.
    pub samples: u64,
    /// Their sample rate in Hz (> 0).
    pub sample_rate: u32,
}

impl AudioSpan {
    /// `samples` at `sample_rate` Hz.
    pub fn new(samples: u64, sample_rate: u32) -> Self {
        Self {
            samples,
            sample_rate,
        }
    }

    /// `samples` already at the model's 16 kHz.
    pub fn at_16k(samples: u64) -> Self {
        Self::new(samples, TARGET_RATE)
    }

    /// The number of frames at `fps` that covers this audio: `ceil(duration * fps)`, computed in
    /// integers as `(samples * fps + rate - 1) / rate` (so 5.86 s at 30 fps is 176 frames). A zero
    /// rate counts as 1 Hz.
    pub fn frames(&self, fps: u64) -> u64 {
        let rate = u128::from(self.sample_rate.max(1));
        (u128::from(self.samples) * u128::from(fps)).div_ceil(rate) as u64
    }

    /// Duration in seconds.
    pub fn seconds(&self) -> f64 {
        self.samples as f64 / f64::from(self.sample_rate.max(1))
    }
}

/// Mean of the channels of interleaved samples (`f64` sum, `f32` result). Mono passes through exactly.
fn mix_to_mono(interleaved: &[f64], channels: usize) -> Vec<f32> {
    if channels == 1 {
        return interleaved.iter().map(|&x| x as f32).collect();
    }
    interleaved
        .chunks_exact(channels)
        .map(|f| (f.iter().sum::<f64>() / channels as f64) as f32)
        .collect()
}

#[cfg(test)]
mod tests;
