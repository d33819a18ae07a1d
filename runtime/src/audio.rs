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

use std::fs::File;
use std::io::{self, BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::str::FromStr;

use rubato::{
    calculate_cutoff, Resampler, SincFixedIn, SincInterpolationParameters, SincInterpolationType,
    WindowFunction,
};

/// The sample rate the model consumes.
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

// ----------------------------------------------------------------------------------------- resampler

struct SincState {
    rs: SincFixedIn<f64>,
    /// Input not yet processed (fewer than `RESAMPLE_BLOCK` frames between calls).
    pending: Vec<f64>,
    out_buf: Vec<Vec<f64>>,
    /// Leading outputs still to drop (those before stream time 0).
    to_skip: usize,
    /// Real input frames received (the alignment zeros not counted).
    n_in: u64,
    /// Outputs delivered.
    n_out: u64,
}

impl SincState {
    /// Processes one block (`None`: a block of zeros; shorter blocks are zero-padded) and appends
    /// the outputs that are not skipped to `out`.
    fn run_block(
        &mut self,
        block: Option<&[f64]>,
        out: &mut Vec<f32>,
    ) -> Result<(), rubato::ResampleError> {
        let (_, n) = match block {
            Some(b) if b.len() == RESAMPLE_BLOCK => {
                self.rs.process_into_buffer(&[b], &mut self.out_buf, None)?
            }
            Some(b) => self
                .rs
                .process_partial_into_buffer(Some(&[b]), &mut self.out_buf, None)?,
            None => {
                self.rs
                    .process_partial_into_buffer(None::<&[&[f64]]>, &mut self.out_buf, None)?
            }
        };
        let skip = self.to_skip.min(n);
        self.to_skip -= skip;
        out.extend(self.out_buf[0][skip..n].iter().map(|&x| x as f32));
        self.n_out += (n - skip) as u64;
        Ok(())
    }

    /// Appends input, processing every complete block.
    fn feed(
        &mut self,
        input: impl IntoIterator<Item = f64>,
        out: &mut Vec<f32>,
    ) -> Result<(), rubato::ResampleError> {
        for x in input {
            self.pending.push(x);
            if self.pending.len() == RESAMPLE_BLOCK {
                let block = std::mem::take(&mut self.pending);
                self.run_block(Some(&block), out)?;
                self.pending = block;
                self.pending.clear();
            }
        }
        Ok(())
    }
}

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// Converts a mono stream at any rate to 16 kHz. See the module docs: pass-through at 16 kHz, otherwise
/// a windowed-sinc resampler fed in fixed blocks, so the output is independent of input chunking.
///
/// Alignment: `rubato::SincFixedIn` (0.16) emits output `k` at input time `(k + 1) * t - 1`, with
/// `t = rate_in / 16000 = p / q` in lowest terms. Prepending `p - 1` zeros and dropping the first
/// `q - 1` outputs makes output `j` sample input time exactly `j * t`; a unit test pins this down.
pub struct Resampler16k {
    rate: u32,
    origin: String,
    sinc: Option<SincState>,
}

impl std::fmt::Debug for Resampler16k {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Resampler16k")
            .field("rate", &self.rate)
            .field("origin", &self.origin)
            .finish_non_exhaustive()
    }
}

impl Resampler16k {
    /// A resampler from `input_rate` Hz to 16 kHz; `origin` names the source in error messages.
    pub fn new(input_rate: u32, origin: impl Into<String>) -> Result<Self, AudioError> {
        let origin = origin.into();
        if input_rate == 0 {
            return Err(AudioError::InvalidSetting {
                origin,
                detail: "sample rate 0 Hz; expected a positive rate".into(),
            });
        }
        let mut r = Self {
            rate: input_rate,
            origin,
            sinc: None,
        };
        if input_rate != TARGET_RATE {
            r.sinc = Some(r.make_state()?);
        }
        Ok(r)
    }

    fn err(&self, detail: impl std::fmt::Display) -> AudioError {
        AudioError::Resample {
            origin: self.origin.clone(),
            rate: self.rate,
            detail: detail.to_string(),
        }
    }

    fn make_state(&self) -> Result<SincState, AudioError> {
        let sinc_len = 128;
        let window = WindowFunction::BlackmanHarris2;
        let params = SincInterpolationParameters {
            sinc_len,
            f_cutoff: calculate_cutoff(sinc_len, window),
            oversampling_factor: 256,
            interpolation: SincInterpolationType::Cubic,
            window,
        };
        let ratio = TARGET_RATE as f64 / self.rate as f64;
        let rs = SincFixedIn::<f64>::new(ratio, 1.0, params, RESAMPLE_BLOCK, 1)
            .map_err(|e| self.err(e))?;
        let g = gcd(self.rate as u64, TARGET_RATE as u64);
        let (p, q) = (self.rate as u64 / g, TARGET_RATE as u64 / g);
        let out_buf = rs.output_buffer_allocate(true);
        let mut st = SincState {
            rs,
            pending: Vec::with_capacity(RESAMPLE_BLOCK),
            out_buf,
            to_skip: (q - 1) as usize,
            n_in: 0,
            n_out: 0,
        };
        let mut out = Vec::new();
        st.feed(std::iter::repeat_n(0.0, (p - 1) as usize), &mut out)
            .map_err(|e| self.err(e))?;
        debug_assert!(out.is_empty());
        Ok(st)
    }

    /// The input sample rate.
    pub fn input_rate(&self) -> u32 {
        self.rate
    }

    /// Pushes input samples; returns the 16 kHz samples now available (possibly none).
    pub fn push(&mut self, input: &[f32]) -> Result<Vec<f32>, AudioError> {
        let Some(st) = self.sinc.as_mut() else {
            return Ok(input.to_vec());
        };
        st.n_in += input.len() as u64;
        let mut out =
            Vec::with_capacity(input.len() * TARGET_RATE as usize / self.rate as usize + 16);
        let res = st.feed(input.iter().map(|&x| x as f64), &mut out);
        res.map_err(|e| self.err(e))?;
        Ok(out)
    }

    /// Ends the stream: flushes the filter tail so that exactly `floor(n_in * 16000 / rate)` samples
    /// have come out in total, returns the remaining ones, and resets for a new stream.
    pub fn finish(&mut self) -> Result<Vec<f32>, AudioError> {
        let Some(mut st) = self.sinc.take() else {
            return Ok(Vec::new());
        };
        let target = st.n_in * TARGET_RATE as u64 / self.rate as u64;
        let mut out = Vec::new();
        let pending = std::mem::take(&mut st.pending);
        if !pending.is_empty() {
            st.run_block(Some(&pending), &mut out)
                .map_err(|e| self.err(e))?;
        }
        let mut guard = 0;
        while st.n_out < target {
            st.run_block(None, &mut out).map_err(|e| self.err(e))?;
            guard += 1;
            if guard > 10_000 {
                return Err(self.err("the resampler did not flush its tail"));
            }
        }
        let excess = (st.n_out - target) as usize;
        out.truncate(out.len().saturating_sub(excess));
        self.sinc = Some(self.make_state()?);
        Ok(out)
    }
}

// ----------------------------------------------------------------------------------------- WAV probing

/// What a light RIFF walk (mirroring hound's) finds before decoding, for precise error messages.
#[derive(Debug, Default)]
struct Probe {
    format_tag: Option<u16>,
    bits: Option<u16>,
    valid_bits: Option<u16>,
    sub_tag: Option<u16>,
    data: Option<(u64, u64)>,
}

fn io_err(path: &Path, e: io::Error) -> AudioError {
    match e.kind() {
        io::ErrorKind::NotFound => AudioError::NotFound {
            path: path.to_path_buf(),
        },
        _ => AudioError::Io {
            origin: path.display().to_string(),
            source: e,
        },
    }
}

fn read_exact_or_eof(f: &mut impl Read, buf: &mut [u8]) -> io::Result<bool> {
    match f.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

fn probe_wav(path: &Path) -> Result<Probe, AudioError> {
    let mut f = File::open(path).map_err(|e| io_err(path, e))?;
    let file_len = f.metadata().map_err(|e| io_err(path, e))?.len();
    if file_len == 0 {
        return Err(AudioError::EmptyFile {
            path: path.to_path_buf(),
        });
    }
    let mut head = [0u8; 12];
    let n = (file_len as usize).min(12);
    f.read_exact(&mut head[..n]).map_err(|e| io_err(path, e))?;
    let not_wav = |reason: &str| AudioError::NotWav {
        path: path.to_path_buf(),
        reason: reason.into(),
    };
    if head[..n.min(4)] != b"RIFF"[..n.min(4)] {
        return Err(not_wav("no RIFF tag at the start"));
    }
    if n < 12 {
        return Err(AudioError::Truncated {
            path: path.to_path_buf(),
            detail: format!("only {file_len} bytes, the RIFF header needs 12"),
        });
    }
    if &head[8..12] != b"WAVE" {
        return Err(not_wav("a RIFF file, but not of type WAVE"));
    }
    let mut p = Probe::default();
    let mut pos = 12u64;
    loop {
        let mut ch = [0u8; 8];
        if !read_exact_or_eof(&mut f, &mut ch).map_err(|e| io_err(path, e))? {
            let detail = if p.format_tag.is_none() {
                "it ends before the fmt chunk"
            } else {
                "it ends before the data chunk"
            };
            return Err(AudioError::Truncated {
                path: path.to_path_buf(),
                detail: detail.into(),
            });
        }
        let len = u32::from_le_bytes([ch[4], ch[5], ch[6], ch[7]]) as u64;
        pos += 8;
        match &ch[..4] {
            b"fmt " => {
                let mut fmt = vec![0u8; len.min(40) as usize];
                if !read_exact_or_eof(&mut f, &mut fmt).map_err(|e| io_err(path, e))? {
                    return Err(AudioError::Truncated {
                        path: path.to_path_buf(),
                        detail: "it ends inside the fmt chunk".into(),
                    });
                }
                let u16_at = |i: usize| fmt.get(i..i + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
                p.format_tag = u16_at(0);
                p.bits = u16_at(14);
                if p.format_tag == Some(0xFFFE) {
                    p.valid_bits = u16_at(18);
                    p.sub_tag = u16_at(24);
                }
                f.seek(SeekFrom::Start(pos + len))
                    .map_err(|e| io_err(path, e))?;
            }
            b"data" => {
                p.data = Some((pos, len));
                if pos + len > file_len {
                    return Err(AudioError::Truncated {
                        path: path.to_path_buf(),
                        detail: format!(
                            "the data chunk declares {len} bytes but only {} are present",
                            file_len - pos
                        ),
                    });
                }
                return Ok(p);
            }
            _ => {
                f.seek(SeekFrom::Start(pos + len))
                    .map_err(|e| io_err(path, e))?;
            }
        }
        pos += len;
        if pos > file_len {
            return Err(AudioError::Truncated {
                path: path.to_path_buf(),
                detail: "a chunk extends past the end of the file".into(),
            });
        }
    }
}

fn describe_encoding(p: &Probe) -> String {
    let tag = p.format_tag.map(|t| {
        if t == 0xFFFE {
            p.sub_tag.unwrap_or(t)
        } else {
            t
        }
    });
    let bits = match (p.valid_bits, p.bits) {
        (Some(v), _) if v > 0 => Some(v),
        (_, b) => b,
    };
    let bits_s = bits.map(|b| format!("{b}-bit ")).unwrap_or_default();
    match tag {
        Some(1) => format!("{bits_s}integer PCM"),
        Some(3) => format!("{bits_s}IEEE float"),
        Some(2) => "ADPCM (format tag 0x0002)".into(),
        Some(6) => "A-law (format tag 0x0006)".into(),
        Some(7) => "mu-law (format tag 0x0007)".into(),
        Some(t) => format!("format tag 0x{t:04X}"),
        None => "an unreadable fmt chunk".into(),
    }
}

fn encoding_supported(p: &Probe) -> bool {
    let tag = p.format_tag.map(|t| {
        if t == 0xFFFE {
            p.sub_tag.unwrap_or(t)
        } else {
            t
        }
    });
    let bits = match (p.valid_bits, p.bits) {
        (Some(v), _) if v > 0 => Some(v),
        (_, b) => b,
    };
    matches!(
        (tag, bits),
        (Some(1), Some(8 | 16 | 24 | 32)) | (Some(3), Some(32))
    )
}

// ----------------------------------------------------------------------------------------- WAV stream

enum Samples {
    Int {
        reader: hound::WavReader<BufReader<File>>,
        scale: f64,
    },
    Float {
        reader: hound::WavReader<BufReader<File>>,
    },
}

/// Reads a WAV file block by block, yielding 16 kHz mono `f32` chunks (see the module docs).
///
/// Memory is bounded by the block size whatever the file's length. Iterate it, or call
/// [`WavStream::next_chunk`]; after the last chunk it returns `None`.
pub struct WavStream {
    path: PathBuf,
    info: WavInfo,
    samples: Samples,
    read_frames: usize,
    frames_read: u64,
    resampler: Resampler16k,
    done: bool,
    interleaved: Vec<f64>,
}

impl std::fmt::Debug for WavStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WavStream")
            .field("path", &self.path)
            .field("info", &self.info)
            .finish_non_exhaustive()
    }
}

impl WavStream {
    /// Opens and validates a WAV file (header, encoding, length) without reading its samples.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, AudioError> {
        let path = path.as_ref().to_path_buf();
        let probe = probe_wav(&path)?;
        if probe.format_tag.is_some() && !encoding_supported(&probe) {
            return Err(AudioError::UnsupportedEncoding {
                found: describe_encoding(&probe),
                path,
            });
        }
        let reader = match hound::WavReader::open(&path) {
            Ok(r) => r,
            Err(e) => {
                return Err(match e {
                    hound::Error::IoError(io) if io.kind() == io::ErrorKind::UnexpectedEof => {
                        AudioError::Truncated {
                            path,
                            detail: "the header ends early".into(),
                        }
                    }
                    hound::Error::IoError(io) => io_err(&path, io),
                    hound::Error::Unsupported => AudioError::UnsupportedEncoding {
                        found: describe_encoding(&probe),
                        path,
                    },
                    other => AudioError::Malformed {
                        reason: other.to_string(),
                        path,
                    },
                })
            }
        };
        let spec = reader.spec();
        let frames = reader.duration() as u64;
        let info = WavInfo {
            sample_rate: spec.sample_rate,
            channels: spec.channels,
            bits_per_sample: spec.bits_per_sample,
            is_float: spec.sample_format == hound::SampleFormat::Float,
            frames,
        };
        let samples = match (spec.sample_format, spec.bits_per_sample) {
            (hound::SampleFormat::Float, 32) => Samples::Float { reader },
            (hound::SampleFormat::Int, b @ (8 | 16 | 24 | 32)) => Samples::Int {
                reader,
                scale: 1.0 / (1u64 << (b - 1)) as f64,
            },
            (fmt, b) => {
                let kind = if fmt == hound::SampleFormat::Float {
                    "IEEE float"
                } else {
                    "integer PCM"
                };
                return Err(AudioError::UnsupportedEncoding {
                    found: format!("{b}-bit {kind}"),
                    path,
                });
            }
        };
        if frames == 0 {
            return Err(AudioError::NoSamples { path });
        }
        if spec.sample_rate == 0 {
            return Err(AudioError::Malformed {
                reason: "sample rate is 0 Hz".into(),
                path,
            });
        }
        let resampler = Resampler16k::new(spec.sample_rate, path.display().to_string())?;
        Ok(Self {
            path,
            info,
            samples,
            read_frames: DEFAULT_READ_FRAMES,
            frames_read: 0,
            resampler,
            done: false,
            interleaved: Vec::new(),
        })
    }

    /// Sets how many source frames are read per block (at least 1).
    pub fn with_read_frames(mut self, frames: usize) -> Self {
        self.read_frames = frames.max(1);
        self
    }

    /// The file's format and length.
    pub fn info(&self) -> &WavInfo {
        &self.info
    }

    /// Number of 16 kHz samples the whole file yields: `floor(frames * 16000 / sample_rate)`
    /// (`frames` at 16 kHz).
    pub fn output_len(&self) -> u64 {
        self.info.frames * TARGET_RATE as u64 / self.info.sample_rate as u64
    }

    fn read_block(&mut self) -> Result<usize, AudioError> {
        let ch = self.info.channels as usize;
        let want = self.read_frames * ch;
        self.interleaved.clear();
        let path = &self.path;
        let map_err = |e: hound::Error| match e {
            hound::Error::IoError(io) if io.kind() == io::ErrorKind::UnexpectedEof => {
                AudioError::Truncated {
                    path: path.clone(),
                    detail: "the sample data ends early".into(),
                }
            }
            hound::Error::IoError(io) => io_err(path, io),
            other => AudioError::Malformed {
                path: path.clone(),
                reason: other.to_string(),
            },
        };
        match &mut self.samples {
            Samples::Int { reader, scale } => {
                for s in reader.samples::<i32>().take(want) {
                    self.interleaved.push(s.map_err(map_err)? as f64 * *scale);
                }
            }
            Samples::Float { reader } => {
                let base = self.frames_read * ch as u64;
                for (i, s) in reader.samples::<f32>().take(want).enumerate() {
                    let v = s.map_err(map_err)?;
                    if !v.is_finite() {
                        return Err(AudioError::NonFinite {
                            origin: self.path.display().to_string(),
                            index: base + i as u64,
                            value: v,
                        });
                    }
                    self.interleaved.push(v as f64);
                }
            }
        }
        if !self.interleaved.len().is_multiple_of(ch) {
            return Err(AudioError::Truncated {
                path: self.path.clone(),
                detail: "the last frame is incomplete".into(),
            });
        }
        Ok(self.interleaved.len() / ch)
    }

    /// The next chunk of 16 kHz mono samples (never empty), or `None` at the end of the file.
    pub fn next_chunk(&mut self) -> Result<Option<Vec<f32>>, AudioError> {
        while !self.done {
            let n = self.read_block()?;
            self.frames_read += n as u64;
            let mono = mix_to_mono(&self.interleaved, self.info.channels as usize);
            let mut out = self.resampler.push(&mono)?;
            if n == 0 || self.frames_read >= self.info.frames {
                self.done = true;
                out.extend(self.resampler.finish()?);
            }
            if !out.is_empty() {
                return Ok(Some(out));
            }
        }
        Ok(None)
    }
}

impl Iterator for WavStream {
    type Item = Result<Vec<f32>, AudioError>;

    fn next(&mut self) -> Option<Self::Item> {
        match self.next_chunk() {
            Ok(Some(c)) => Some(Ok(c)),
            Ok(None) => None,
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
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

/// Reads a whole WAV file as 16 kHz mono `f32` (see the module docs for the conversions).
pub fn read_wav_16k_mono(path: impl AsRef<Path>) -> Result<Vec<f32>, AudioError> {
    let mut s = WavStream::open(path)?;
    let mut out = Vec::with_capacity(s.output_len() as usize);
    while let Some(c) = s.next_chunk()? {
        out.extend(c);
    }
    Ok(out)
}

// ----------------------------------------------------------------------------------------- raw PCM

/// Headerless little-endian PCM sample formats accepted on stdin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawFormat {
    /// Signed 16-bit integers, scaled by `1 / 32768`.
    S16Le,
    /// Signed 32-bit integers, scaled by `1 / 2^31`.
    S32Le,
    /// 32-bit IEEE floats, taken as is (NaN and infinity refused).
    F32Le,
}

impl RawFormat {
    /// Bytes per sample.
    pub fn bytes_per_sample(self) -> usize {
        match self {
            RawFormat::S16Le => 2,
            RawFormat::S32Le | RawFormat::F32Le => 4,
        }
    }

    /// The format's name as the CLI spells it.
    pub fn name(self) -> &'static str {
        match self {
            RawFormat::S16Le => "s16le",
            RawFormat::S32Le => "s32le",
            RawFormat::F32Le => "f32le",
        }
    }
}

impl std::fmt::Display for RawFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RawFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "s16le" => Ok(RawFormat::S16Le),
            "s32le" => Ok(RawFormat::S32Le),
            "f32le" => Ok(RawFormat::F32Le),
            other => Err(format!(
                "unknown raw PCM format '{other}'; expected s16le, s32le or f32le"
            )),
        }
    }
}

/// Decodes raw interleaved PCM bytes into mono `f32` at the source rate. Bytes that do not complete a
/// frame (all channels of one sample instant) are kept for the next call, so reads may split samples
/// and frames anywhere.
#[derive(Debug)]
pub struct RawPcmDecoder {
    origin: String,
    format: RawFormat,
    channels: usize,
    carry: Vec<u8>,
    samples_decoded: u64,
    scratch: Vec<f64>,
}

impl RawPcmDecoder {
    /// A decoder for `channels` interleaved channels of `format`; `origin` names the stream in errors.
    pub fn new(
        format: RawFormat,
        channels: u16,
        origin: impl Into<String>,
    ) -> Result<Self, AudioError> {
        let origin = origin.into();
        if channels == 0 {
            return Err(AudioError::InvalidSetting {
                origin,
                detail: "0 channels; expected at least 1".into(),
            });
        }
        Ok(Self {
            origin,
            format,
            channels: channels as usize,
            carry: Vec::new(),
            samples_decoded: 0,
            scratch: Vec::new(),
        })
    }

    /// Bytes per frame (`channels * bytes_per_sample`).
    pub fn frame_bytes(&self) -> usize {
        self.channels * self.format.bytes_per_sample()
    }

    /// Bytes held back because they do not complete a frame yet.
    pub fn pending_bytes(&self) -> usize {
        self.carry.len()
    }

    /// Decodes `bytes` (continuing any partial frame) into mono samples.
    pub fn decode(&mut self, bytes: &[u8]) -> Result<Vec<f32>, AudioError> {
        let fb = self.frame_bytes();
        let bps = self.format.bytes_per_sample();
        let mut data = std::mem::take(&mut self.carry);
        data.extend_from_slice(bytes);
        let whole = data.len() / fb * fb;
        self.scratch.clear();
        for (i, s) in data[..whole].chunks_exact(bps).enumerate() {
            let v = match self.format {
                RawFormat::S16Le => i16::from_le_bytes([s[0], s[1]]) as f64 / 32768.0,
                RawFormat::S32Le => {
                    i32::from_le_bytes([s[0], s[1], s[2], s[3]]) as f64 / 2_147_483_648.0
                }
                RawFormat::F32Le => {
                    let x = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
                    if !x.is_finite() {
                        // Keep the state consistent: the failed bytes are dropped, later calls go on.
                        let index = self.samples_decoded + i as u64;
                        self.samples_decoded += (whole / bps) as u64;
                        self.carry = data[whole..].to_vec();
                        return Err(AudioError::NonFinite {
                            origin: self.origin.clone(),
                            index,
                            value: x,
                        });
                    }
                    x as f64
                }
            };
            self.scratch.push(v);
        }
        self.samples_decoded += (whole / bps) as u64;
        self.carry = data[whole..].to_vec();
        Ok(mix_to_mono(&self.scratch, self.channels))
    }

    /// Ends the stream: an error if a partial frame is left over.
    pub fn finish(&mut self) -> Result<(), AudioError> {
        if self.carry.is_empty() {
            Ok(())
        } else {
            let bytes = self.carry.len();
            self.carry.clear();
            Err(AudioError::PartialFrame {
                origin: self.origin.clone(),
                bytes,
                frame_bytes: self.frame_bytes(),
            })
        }
    }
}

/// Reads raw PCM from any reader (such as stdin) and yields 16 kHz mono `f32` chunks as data arrives.
pub struct RawPcmStream<R: Read> {
    reader: R,
    decoder: RawPcmDecoder,
    resampler: Resampler16k,
    buf: Vec<u8>,
    done: bool,
}

impl<R: Read> std::fmt::Debug for RawPcmStream<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RawPcmStream")
            .field("decoder", &self.decoder)
            .finish_non_exhaustive()
    }
}

impl<R: Read> RawPcmStream<R> {
    /// A stream of `format` at `sample_rate` Hz with `channels` interleaved channels, read from
    /// `reader` in reads of up to 4096 bytes; `origin` (e.g. `<stdin>`) names it in errors.
    pub fn new(
        reader: R,
        format: RawFormat,
        sample_rate: u32,
        channels: u16,
        origin: impl Into<String>,
    ) -> Result<Self, AudioError> {
        let origin = origin.into();
        let decoder = RawPcmDecoder::new(format, channels, origin.clone())?;
        let resampler = Resampler16k::new(sample_rate, origin)?;
        Ok(Self {
            reader,
            decoder,
            resampler,
            buf: vec![0; 4096],
            done: false,
        })
    }

    /// Sets the maximum bytes per read (at least 1).
    pub fn with_read_bytes(mut self, n: usize) -> Self {
        self.buf = vec![0; n.max(1)];
        self
    }

    /// The next chunk of 16 kHz mono samples (never empty), or `None` at the end of the stream.
    pub fn next_chunk(&mut self) -> Result<Option<Vec<f32>>, AudioError> {
        while !self.done {
            let n = match self.reader.read(&mut self.buf) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    return Err(AudioError::Io {
                        origin: self.decoder.origin.clone(),
                        source: e,
                    })
                }
            };
            let mut out = if n == 0 {
                self.done = true;
                self.decoder.finish()?;
                self.resampler.finish()?
            } else {
                let mono = self.decoder.decode(&self.buf[..n])?;
                self.resampler.push(&mono)?
            };
            if n == 0 && out.is_empty() {
                return Ok(None);
            }
            if !out.is_empty() {
                return Ok(Some(std::mem::take(&mut out)));
            }
        }
        Ok(None)
    }
}

impl<R: Read> Iterator for RawPcmStream<R> {
    type Item = Result<Vec<f32>, AudioError>;

    fn next(&mut self) -> Option<Self::Item> {
        match self.next_chunk() {
            Ok(Some(c)) => Some(Ok(c)),
            Ok(None) => None,
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn tone(n: usize, rate: u32, f: f64, amp: f64) -> Vec<f64> {
        (0..n)
            .map(|i| amp * (2.0 * std::f64::consts::PI * f * i as f64 / rate as f64).sin())
            .collect()
    }

    fn write_int(path: &Path, rate: u32, channels: u16, bits: u16, frames: &[Vec<f64>]) {
        let spec = hound::WavSpec {
            channels,
            sample_rate: rate,
            bits_per_sample: bits,
            sample_format: hound::SampleFormat::Int,
        };
        let mut w = hound::WavWriter::create(path, spec).unwrap();
        let max = (1i64 << (bits - 1)) as f64;
        for fr in frames {
            for &x in fr {
                let v = (x * max).round().clamp(-max, max - 1.0) as i32;
                w.write_sample(v).unwrap();
            }
        }
        w.finalize().unwrap();
    }

    fn write_float(path: &Path, rate: u32, channels: u16, frames: &[Vec<f32>]) {
        let spec = hound::WavSpec {
            channels,
            sample_rate: rate,
            bits_per_sample: 32,
            sample_format: hound::SampleFormat::Float,
        };
        let mut w = hound::WavWriter::create(path, spec).unwrap();
        for fr in frames {
            for &x in fr {
                w.write_sample(x).unwrap();
            }
        }
        w.finalize().unwrap();
    }

    /// A hand-made WAV header: format tag, channels, rate, bits, then `data_bytes` of data.
    fn handmade(
        path: &Path,
        tag: u16,
        channels: u16,
        rate: u32,
        bits: u16,
        data: &[u8],
        declared: u32,
    ) {
        let block = channels * bits.div_ceil(8);
        let mut v = Vec::new();
        v.extend(b"RIFF");
        v.extend((36 + declared).to_le_bytes());
        v.extend(b"WAVEfmt ");
        v.extend(16u32.to_le_bytes());
        v.extend(tag.to_le_bytes());
        v.extend(channels.to_le_bytes());
        v.extend(rate.to_le_bytes());
        v.extend((rate * block as u32).to_le_bytes());
        v.extend(block.to_le_bytes());
        v.extend(bits.to_le_bytes());
        v.extend(b"data");
        v.extend(declared.to_le_bytes());
        v.extend(data);
        std::fs::write(path, v).unwrap();
    }

    #[test]
    fn int_depths_decode_exactly_at_16k() {
        let dir = tempfile::tempdir().unwrap();
        let x = tone(1600, 16000, 440.0, 0.5);
        for bits in [8u16, 16, 24, 32] {
            let p = dir.path().join(format!("i{bits}.wav"));
            let frames: Vec<Vec<f64>> = x.iter().map(|&v| vec![v]).collect();
            write_int(&p, 16000, 1, bits, &frames);
            let y = read_wav_16k_mono(&p).unwrap();
            assert_eq!(y.len(), 1600, "{bits}");
            // quantisation step, or f32 rounding for 32-bit
            let tol = (1.0 / (1u64 << (bits - 1)) as f64).max(1e-7);
            for (a, b) in x.iter().zip(&y) {
                assert!((a - *b as f64).abs() <= tol, "{bits}-bit: {a} vs {b}");
            }
        }
    }

    #[test]
    fn float_passthrough_and_stereo_mix() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.wav");
        let frames: Vec<Vec<f32>> = (0..1000).map(|i| vec![i as f32 / 1000.0 - 0.5]).collect();
        write_float(&p, 16000, 1, &frames);
        let y = read_wav_16k_mono(&p).unwrap();
        assert_eq!(y, frames.iter().map(|f| f[0]).collect::<Vec<_>>());
        let info = WavStream::open(&p).unwrap().info().clone();
        assert!(info.is_float && info.channels == 1 && info.frames == 1000);

        let p2 = dir.path().join("s.wav");
        let st: Vec<Vec<f32>> = (0..1000)
            .map(|i| vec![0.25, (i % 3) as f32 * 0.25])
            .collect();
        write_float(&p2, 16000, 2, &st);
        let y = read_wav_16k_mono(&p2).unwrap();
        for (f, v) in st.iter().zip(&y) {
            assert_eq!(*v, (f[0] + f[1]) / 2.0);
        }
        let p3 = dir.path().join("q.wav");
        let q: Vec<Vec<f32>> = (0..100).map(|_| vec![0.1, 0.2, 0.3, 0.4]).collect();
        write_float(&p3, 16000, 4, &q);
        for v in read_wav_16k_mono(&p3).unwrap() {
            assert!((v - 0.25).abs() < 1e-7);
        }
    }

    #[test]
    fn resamples_44k1_tone() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.wav");
        let n = 44100;
        let x = tone(n, 44100, 1000.0, 0.5);
        let frames: Vec<Vec<f64>> = x.iter().map(|&v| vec![v, v]).collect();
        write_int(&p, 44100, 2, 16, &frames);
        let y = read_wav_16k_mono(&p).unwrap();
        assert_eq!(y.len(), 16000);
        // Same tone at 16 kHz, aligned (delay removed); skip the edges.
        let want = tone(16000, 16000, 1000.0, 0.5);
        let err = (200..15800)
            .map(|i| (want[i] - y[i] as f64).abs())
            .fold(0.0, f64::max);
        assert!(err < 2e-3, "max error {err}");
        // Streaming with different read block sizes gives identical output.
        for rf in [1usize, 333, 100_000] {
            let z: Vec<f32> = WavStream::open(&p)
                .unwrap()
                .with_read_frames(rf)
                .flat_map(|c| c.unwrap())
                .collect();
            assert_eq!(z, y, "read_frames {rf}");
        }
    }

    #[test]
    fn resampler_alignment_is_exact() {
        // A smooth pulse centred at 0.1 s must come out centred at output sample 1600.
        for rate in [
            8000u32, 11025, 22050, 24000, 32000, 44100, 48000, 96000, 44101,
        ] {
            let c = rate as f64 * 0.1;
            let x: Vec<f32> = (0..rate as usize / 5)
                .map(|i| {
                    let d = (i as f64 - c) / (rate as f64 / 2000.0);
                    (-d * d).exp() as f32
                })
                .collect();
            let mut r = Resampler16k::new(rate, "t").unwrap();
            let mut y = r.push(&x).unwrap();
            y.extend(r.finish().unwrap());
            assert_eq!(y.len() as u64, x.len() as u64 * 16000 / rate as u64);
            let (num, den) = y.iter().enumerate().fold((0.0, 0.0), |(n, d), (i, &v)| {
                (n + i as f64 * v as f64, d + v as f64)
            });
            let centroid = num / den;
            assert!(
                (centroid - 1600.0).abs() < 0.01,
                "rate {rate}: pulse centred at {centroid}, expected 1600"
            );
        }
    }

    #[test]
    fn resampler_is_chunking_invariant() {
        let x: Vec<f32> = tone(30_000, 22050, 300.0, 0.7)
            .into_iter()
            .map(|v| v as f32)
            .collect();
        let mut whole = Resampler16k::new(22050, "t").unwrap();
        let mut a = whole.push(&x).unwrap();
        a.extend(whole.finish().unwrap());
        assert_eq!(a.len(), 30_000 * 16000 / 22050);
        for c in [1usize, 17, 1024, 5000] {
            let mut r = Resampler16k::new(22050, "t").unwrap();
            let mut b = Vec::new();
            for ch in x.chunks(c) {
                b.extend(r.push(ch).unwrap());
            }
            b.extend(r.finish().unwrap());
            assert_eq!(a, b, "chunk {c}");
        }
        // after finish the resampler is reusable
        let mut again = whole.push(&x).unwrap();
        again.extend(whole.finish().unwrap());
        assert_eq!(again, a);
    }

    #[test]
    fn errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.wav");
        let e = read_wav_16k_mono(&missing).unwrap_err();
        assert!(matches!(e, AudioError::NotFound { .. }));
        assert!(e.to_string().contains("missing.wav"));

        let empty = dir.path().join("empty.wav");
        std::fs::write(&empty, b"").unwrap();
        let e = read_wav_16k_mono(&empty).unwrap_err();
        assert!(matches!(e, AudioError::EmptyFile { .. }), "{e}");
        assert!(e.to_string().contains("empty.wav"));

        let nos = dir.path().join("nosamples.wav");
        write_int(&nos, 16000, 1, 16, &[]);
        assert!(matches!(
            read_wav_16k_mono(&nos).unwrap_err(),
            AudioError::NoSamples { .. }
        ));

        let garbage = dir.path().join("garbage.wav");
        std::fs::write(&garbage, b"this is not audio at all, just some text\n").unwrap();
        let e = read_wav_16k_mono(&garbage).unwrap_err();
        assert!(matches!(e, AudioError::NotWav { .. }), "{e}");
        assert!(
            e.to_string().contains("garbage.wav") && e.to_string().contains("expected a RIFF/WAVE")
        );

        let riff_other = dir.path().join("avi.wav");
        std::fs::write(&riff_other, b"RIFF\x10\0\0\0AVI LIST\0\0\0\0").unwrap();
        assert!(matches!(
            read_wav_16k_mono(&riff_other).unwrap_err(),
            AudioError::NotWav { .. }
        ));

        let trunc = dir.path().join("trunc.wav");
        let frames: Vec<Vec<f64>> = tone(4000, 16000, 200.0, 0.3)
            .into_iter()
            .map(|v| vec![v])
            .collect();
        write_int(&trunc, 16000, 1, 16, &frames);
        let bytes = std::fs::read(&trunc).unwrap();
        std::fs::write(&trunc, &bytes[..bytes.len() - 1001]).unwrap();
        let e = read_wav_16k_mono(&trunc).unwrap_err();
        assert!(matches!(e, AudioError::Truncated { .. }), "{e}");
        assert!(e.to_string().contains("trunc.wav"));
        std::fs::write(&trunc, &bytes[..30]).unwrap();
        assert!(matches!(
            read_wav_16k_mono(&trunc).unwrap_err(),
            AudioError::Truncated { .. }
        ));
        std::fs::write(&trunc, &bytes[..3]).unwrap();
        assert!(matches!(
            read_wav_16k_mono(&trunc).unwrap_err(),
            AudioError::Truncated { .. }
        ));

        let b12 = dir.path().join("b12.wav");
        handmade(&b12, 1, 1, 16000, 12, &[0; 20], 20);
        let e = read_wav_16k_mono(&b12).unwrap_err();
        assert!(matches!(e, AudioError::UnsupportedEncoding { .. }), "{e}");
        assert!(e.to_string().contains("12-bit integer PCM"), "{e}");

        let f64p = dir.path().join("f64.wav");
        handmade(&f64p, 3, 1, 16000, 64, &[0; 32], 32);
        let e = read_wav_16k_mono(&f64p).unwrap_err();
        assert!(
            e.to_string().contains("64-bit IEEE float") && e.to_string().contains("32-bit float"),
            "{e}"
        );

        let adpcm = dir.path().join("adpcm.wav");
        handmade(&adpcm, 2, 1, 16000, 4, &[0; 32], 32);
        assert!(matches!(
            read_wav_16k_mono(&adpcm).unwrap_err(),
            AudioError::UnsupportedEncoding { .. }
        ));

        let nan = dir.path().join("nan.wav");
        write_float(&nan, 16000, 1, &[vec![0.0], vec![0.5], vec![f32::NAN]]);
        let e = read_wav_16k_mono(&nan).unwrap_err();
        assert!(matches!(e, AudioError::NonFinite { index: 2, .. }), "{e}");
        assert!(e.to_string().contains("nan.wav"));
    }

    #[test]
    fn raw_pcm_split_anywhere() {
        // Stereo s16le at 16 kHz, fed one byte at a time vs all at once.
        let mut bytes = Vec::new();
        for i in 0..500i32 {
            bytes.extend(((i * 37 % 2000 - 1000) as i16).to_le_bytes());
            bytes.extend(((i * 11 % 600) as i16).to_le_bytes());
        }
        let mut d = RawPcmDecoder::new(RawFormat::S16Le, 2, "<stdin>").unwrap();
        let all = d.decode(&bytes).unwrap();
        assert_eq!(all.len(), 500);
        let mut d = RawPcmDecoder::new(RawFormat::S16Le, 2, "<stdin>").unwrap();
        let mut one = Vec::new();
        for b in &bytes {
            one.extend(d.decode(std::slice::from_ref(b)).unwrap());
        }
        assert_eq!(one, all);
        d.finish().unwrap();
        assert_eq!(
            all[1],
            ((37 - 1000) as f64 / 32768.0 + 11.0 / 32768.0) as f32 / 2.0
        );

        // Partial frame at the end is an error naming the stream.
        let mut d = RawPcmDecoder::new(RawFormat::F32Le, 1, "<stdin>").unwrap();
        d.decode(&[0, 0, 0]).unwrap();
        let e = d.finish().unwrap_err().to_string();
        assert!(e.contains("<stdin>") && e.contains("3 stray bytes"), "{e}");

        // f32le NaN refused with its index
        let mut d = RawPcmDecoder::new(RawFormat::F32Le, 1, "<stdin>").unwrap();
        let mut b = Vec::new();
        b.extend(0.5f32.to_le_bytes());
        b.extend(f32::INFINITY.to_le_bytes());
        assert!(matches!(
            d.decode(&b).unwrap_err(),
            AudioError::NonFinite { index: 1, .. }
        ));

        // s32le scaling
        let mut d = RawPcmDecoder::new(RawFormat::S32Le, 1, "x").unwrap();
        assert_eq!(d.decode(&i32::MIN.to_le_bytes()).unwrap(), vec![-1.0]);
        assert_eq!("F32LE".parse::<RawFormat>().unwrap(), RawFormat::F32Le);
        assert!("u8".parse::<RawFormat>().is_err());
        assert!(RawPcmDecoder::new(RawFormat::S16Le, 0, "x").is_err());
    }

    #[test]
    fn raw_stream_resamples_and_is_read_size_invariant() {
        let x: Vec<f32> = tone(48_000, 48000, 440.0, 0.4)
            .into_iter()
            .map(|v| v as f32)
            .collect();
        let mut bytes = Vec::new();
        for v in &x {
            bytes.write_all(&v.to_le_bytes()).unwrap();
        }
        let collect = |rb: usize| -> Vec<f32> {
            RawPcmStream::new(
                io::Cursor::new(bytes.clone()),
                RawFormat::F32Le,
                48000,
                1,
                "<stdin>",
            )
            .unwrap()
            .with_read_bytes(rb)
            .flat_map(|c| c.unwrap())
            .collect()
        };
        let a = collect(4096);
        assert_eq!(a.len(), 16000);
        assert_eq!(collect(7), a);
        assert_eq!(collect(1 << 20), a);
        // at 16 kHz: untouched
        let mut b16 = Vec::new();
        for v in &x[..1000] {
            b16.extend(v.to_le_bytes());
        }
        let y: Vec<f32> =
            RawPcmStream::new(io::Cursor::new(b16), RawFormat::F32Le, 16000, 1, "<stdin>")
                .unwrap()
                .flat_map(|c| c.unwrap())
                .collect();
        assert_eq!(y, x[..1000].to_vec());
    }
}
