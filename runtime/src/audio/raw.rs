//! Headerless PCM (`s16le`, `s32le`, `f32le`) from any reader, such as stdin.

use std::io::{self, Read};
use std::str::FromStr;

use super::{mix_to_mono, AudioError, AudioSpan, Resampler16k};

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

    /// The input read so far (samples per channel, at the source's rate): after the last chunk, the
    /// whole input, which fixes the number of frames that cover it ([`AudioSpan::frames`]).
    pub fn input_span(&self) -> AudioSpan {
        self.resampler.input_span()
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
