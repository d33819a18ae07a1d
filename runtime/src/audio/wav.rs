//! WAV files: probing the header (for precise errors), then block-wise reading with hound.
//!
//! The source is any `Read + Seek` ([`WavStream::from_reader`]): a file ([`WavStream::open`]), bytes
//! in memory ([`WavStream::from_bytes`], what the WebAssembly binding decodes), a network buffer.

use std::fs::File;
use std::io::{self, BufReader, Cursor, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::{
    mix_to_mono, AudioError, AudioSpan, Resampler16k, WavInfo, DEFAULT_READ_FRAMES, TARGET_RATE,
};

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

/// Walks the RIFF chunks of `f` from its start, then rewinds it to the start.
fn probe_wav<R: Read + Seek>(f: &mut R, path: &Path) -> Result<Probe, AudioError> {
    let file_len = f.seek(SeekFrom::End(0)).map_err(|e| io_err(path, e))?;
    f.seek(SeekFrom::Start(0)).map_err(|e| io_err(path, e))?;
    let p = probe_chunks(f, path, file_len)?;
    f.seek(SeekFrom::Start(0)).map_err(|e| io_err(path, e))?;
    Ok(p)
}

fn probe_chunks<R: Read + Seek>(
    f: &mut R,
    path: &Path,
    file_len: u64,
) -> Result<Probe, AudioError> {
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
        if !read_exact_or_eof(f, &mut ch).map_err(|e| io_err(path, e))? {
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
                if !read_exact_or_eof(f, &mut fmt).map_err(|e| io_err(path, e))? {
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

enum Samples<R: Read> {
    Int {
        reader: hound::WavReader<R>,
        scale: f64,
    },
    Float {
        reader: hound::WavReader<R>,
    },
}

/// Reads a WAV file block by block, yielding 16 kHz mono `f32` chunks (see the module docs).
///
/// Memory is bounded by the block size whatever the file's length. Iterate it, or call
/// [`WavStream::next_chunk`]; after the last chunk it returns `None`. The source is a file
/// ([`WavStream::open`]) or any `Read + Seek` ([`WavStream::from_reader`], [`WavStream::from_bytes`]);
/// all three decode alike (same checks, same errors, naming the source).
pub struct WavStream<R: Read = BufReader<File>> {
    path: PathBuf,
    info: WavInfo,
    samples: Samples<R>,
    read_frames: usize,
    frames_read: u64,
    resampler: Resampler16k,
    done: bool,
    interleaved: Vec<f64>,
}

impl<R: Read> std::fmt::Debug for WavStream<R> {
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
        let path = path.as_ref();
        let f = File::open(path).map_err(|e| io_err(path, e))?;
        WavStream::from_reader(BufReader::new(f), path)
    }
}

impl<B: AsRef<[u8]>> WavStream<Cursor<B>> {
    /// A WAV file held in memory (`bytes`), validated as [`WavStream::open`] validates a file;
    /// `name` stands for it in errors (e.g. `upload.wav`, a URL).
    pub fn from_bytes(bytes: B, name: impl AsRef<Path>) -> Result<Self, AudioError> {
        WavStream::from_reader(Cursor::new(bytes), name)
    }
}

impl<R: Read + Seek> WavStream<R> {
    /// A WAV file read from `reader` (from its start), validated as [`WavStream::open`] validates a
    /// file; `name` stands for it in errors.
    pub fn from_reader(mut reader: R, name: impl AsRef<Path>) -> Result<Self, AudioError> {
        let path = name.as_ref().to_path_buf();
        let probe = probe_wav(&mut reader, &path)?;
        if probe.format_tag.is_some() && !encoding_supported(&probe) {
            return Err(AudioError::UnsupportedEncoding {
                found: describe_encoding(&probe),
                path,
            });
        }
        let reader = match hound::WavReader::new(reader) {
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
}

impl<R: Read> WavStream<R> {
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

    /// The input read so far (samples per channel, at the source's rate): after the last chunk, the
    /// whole input, which fixes the number of frames that cover it ([`AudioSpan::frames`]).
    pub fn input_span(&self) -> AudioSpan {
        self.resampler.input_span()
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

impl<R: Read> Iterator for WavStream<R> {
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

/// Reads a whole WAV file as 16 kHz mono `f32` (see the module docs for the conversions).
pub fn read_wav_16k_mono(path: impl AsRef<Path>) -> Result<Vec<f32>, AudioError> {
    let mut s = WavStream::open(path)?;
    let mut out = Vec::with_capacity(s.output_len() as usize);
    while let Some(c) = s.next_chunk()? {
        out.extend(c);
    }
    Ok(out)
}
