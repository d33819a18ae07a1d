//! Whole-input generation, and streams fed with PCM at any sample rate: the path every door takes.
//!
//! `livegesture generate`, the Python module's `generate` and the C library's
//! `lg_stream_generate_wav` all run a WAV file through [`stream_wav`], so their frames are equal bit
//! for bit by construction (same reader, same chunks, same stream calls). Audio given as samples
//! (a Python array, a C buffer) goes through a [`PcmStream`], which converts any rate to 16 kHz with
//! the same resampler as the WAV reader ([`crate::audio::Resampler16k`]); neither the resampler nor
//! the model depends on how the audio is chunked (docs/streaming.md), so samples pushed in chunks of
//! any size give the frames of the same audio read from a WAV file.
//!
//! Coverage follows docs/output.md: a whole input of `n` samples at `rate` Hz gets
//! `ceil(n * 30 / rate)` frames ([`AudioSpan::frames`]).
//!
//! ```no_run
//! use livegesture::{backend, bundle::Bundle, generate, model};
//!
//! # fn main() -> anyhow::Result<()> {
//! let bundle = Bundle::load("models/default")?;
//! let be = backend::create(&backend::BackendOptions::default())?; // tract
//! let model = model::load(&bundle, be.as_ref())?;
//! let opts = model::StreamOptions { seed: 7, ..Default::default() };
//! let whole = generate::generate_wav(model.as_ref(), &opts, "speech.wav".as_ref())?;
//! println!("{} frames", whole.frames.len());
//! # Ok(())
//! # }
//! ```

use std::path::Path;

use anyhow::{Context, Result};

use crate::audio::{AudioError, AudioSpan, Resampler16k, WavStream, TARGET_RATE};
use crate::backend::{self, BackendOptions};
use crate::bundle::{default_bundle_dir, Bundle};
use crate::model::GraphForm;
use crate::model::{self, LoadOptions, MotionModel, MotionStream, StreamOptions};
use crate::output::Frame;

// the error types every door maps, defined where the models can use them without depending on this module
pub use crate::error::{classify, ErrorKind, InputError};

/// Loads the bundle in `dir` (`None`: [`default_bundle_dir`], i.e. `$LIVEGESTURE_BUNDLE`, else the
/// repository's `models/default`) and its family's model on the backend `backend`, as the CLI does.
/// Problems of the bundle or the options are [`ErrorKind::Input`] or [`ErrorKind::NotFound`].
pub fn open_model(
    dir: Option<&Path>,
    backend: &BackendOptions,
    form: GraphForm,
) -> Result<Box<dyn MotionModel>> {
    let bundle = Bundle::load(default_bundle_dir(dir))?;
    let be = backend::create(backend)?;
    let loaded = model::load_with(&bundle, be.as_ref(), &LoadOptions { form });
    loaded.with_context(|| {
        format!(
            "loading the bundle {} with {}",
            bundle.dir().display(),
            be.describe()
        )
    })
}

/// Checks the options a binding takes from its caller (as the CLI checks its flags) and makes a
/// stream of `model` with them; a refusal (out of range, another family's option) is an
/// [`InputError`].
pub fn new_stream(model: &dyn MotionModel, opts: &StreamOptions) -> Result<Box<dyn MotionStream>> {
    check_options(opts)?;
    model.new_stream(opts).map_err(|e| {
        if e.chain().any(|c| c.is::<InputError>()) {
            e
        } else {
            InputError::new(format!("{e:#}")).into()
        }
    })
}

/// The checks of [`StreamOptions`] that do not depend on the bundle (the family checks its own
/// ranges in [`MotionModel::new_stream`]): every door's options pass here, through [`new_stream`].
pub fn check_options(opts: &StreamOptions) -> Result<(), InputError> {
    if let Some(g) = opts.guidance.filter(|g| !g.is_finite()) {
        return Err(InputError::fields(
            vec!["guidance"],
            format!("must be a finite number, got {g}"),
        ));
    }
    if let Some(t) = opts.temperature.filter(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(InputError::fields(
            vec!["temperature"],
            format!("must be > 0, got {t}"),
        ));
    }
    Ok(())
}

/// The frames covering a whole input, and that input's length at its own rate.
#[derive(Debug, Clone, PartialEq)]
pub struct Generation {
    /// `span.frames(fps)` frames, indices from 0.
    pub frames: Vec<Frame>,
    /// The input, counted at its own sample rate.
    pub span: AudioSpan,
}

/// Streams the whole of `wav` through `stream` (a fresh one) and finishes it at the audio's end, as
/// `livegesture generate` does. `on_frames` gets each batch of frames in order, with the 16 kHz
/// samples pushed so far (for progress). Returns the input's span. `origin` names the input in errors.
pub fn stream_wav<R: std::io::Read>(
    stream: &mut dyn MotionStream,
    wav: &mut WavStream<R>,
    origin: &str,
    on_frames: &mut dyn FnMut(&[Frame], u64) -> Result<()>,
) -> Result<AudioSpan> {
    while let Some(chunk) = wav.next_chunk()? {
        let frames = stream.push_audio(&chunk).with_context(|| {
            format!(
                "{origin}: generating motion at {:.2} s",
                stream.samples_received() as f64 / f64::from(TARGET_RATE)
            )
        })?;
        on_frames(&frames, stream.samples_received())?;
    }
    // docs/output.md: the last partial unit is completed with silence, frames cut at the audio's end
    let span = wav.input_span();
    let frames = stream
        .finish(span)
        .with_context(|| format!("{origin}: finishing the motion at the end of the audio"))?;
    on_frames(&frames, stream.samples_received())?;
    Ok(span)
}

/// All frames of the WAV file at `path` with a new stream of `model` (see [`stream_wav`]).
pub fn generate_wav(
    model: &dyn MotionModel,
    opts: &StreamOptions,
    path: &Path,
) -> Result<Generation> {
    let mut wav = WavStream::open(path)?;
    generate_from(model, opts, &mut wav, &path.display().to_string())
}

/// All frames of a WAV file held in memory (`bytes`; `name` stands for it in errors) with a new
/// stream of `model`: the frames [`generate_wav`] gives for the same file (the same reader, chunks
/// and stream calls; what the WebAssembly binding's `generate` runs).
pub fn generate_wav_bytes(
    model: &dyn MotionModel,
    opts: &StreamOptions,
    bytes: &[u8],
    name: &str,
) -> Result<Generation> {
    let mut wav = WavStream::from_bytes(bytes, name)?;
    generate_from(model, opts, &mut wav, name)
}

fn generate_from<R: std::io::Read>(
    model: &dyn MotionModel,
    opts: &StreamOptions,
    wav: &mut WavStream<R>,
    origin: &str,
) -> Result<Generation> {
    let mut stream = new_stream(model, opts)?;
    let mut frames = Vec::new();
    let span = stream_wav(stream.as_mut(), wav, origin, &mut |f, _| {
        frames.extend_from_slice(f);
        Ok(())
    })?;
    Ok(Generation { frames, span })
}

/// All frames of mono `samples` at `sample_rate` Hz with a new stream of `model`; `origin` names the
/// input in errors. Refuses an empty input (as the WAV reader refuses a file without samples) and
/// NaN or infinite samples.
pub fn generate_pcm(
    model: &dyn MotionModel,
    opts: &StreamOptions,
    samples: &[f32],
    sample_rate: u32,
    origin: &str,
) -> Result<Generation> {
    if samples.is_empty() {
        return Err(InputError::new(format!(
            "{origin}: the audio contains no samples; expected at least one sample"
        ))
        .into());
    }
    let mut stream = PcmStream::new(new_stream(model, opts)?, origin);
    let mut frames = stream.push(samples, sample_rate)?;
    frames.extend(stream.finish()?);
    Ok(Generation {
        frames,
        span: stream.span(),
    })
}

/// The message a binding reports for a panic it caught ([`std::panic::catch_unwind`]) in `what`: the
/// panic's text, so that no panic crosses into C or Python as a crash.
pub fn panic_message(what: &str, payload: &(dyn std::any::Any + Send)) -> String {
    let detail = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into());
    format!("{what}: internal error (a panic in the runtime: {detail}); please report it")
}

/// Converts 16-bit PCM to `f32` as the WAV reader does: `x / 32768`, in `[-1, 1)`.
pub fn i16_to_f32(samples: &[i16]) -> Vec<f32> {
    samples.iter().map(|&x| f32::from(x) / 32768.0).collect()
}

/// An error naming the first NaN or infinite sample of `samples` (index counted from `offset`).
pub fn check_finite(samples: &[f32], origin: &str, offset: u64) -> Result<(), AudioError> {
    match samples.iter().position(|x| !x.is_finite()) {
        None => Ok(()),
        Some(i) => Err(AudioError::NonFinite {
            origin: origin.to_string(),
            index: offset + i as u64,
            value: samples[i],
        }),
    }
}

/// A [`MotionStream`] fed with mono PCM at any sample rate (the bindings' streams).
///
/// The first [`PcmStream::push`] fixes the rate (a later push at another rate is refused until
/// [`PcmStream::reset`]); audio not at 16 kHz goes through the stream's own
/// [`Resampler16k`]. [`PcmStream::finish`] flushes the resampler and ends the stream so that its frames
/// cover everything pushed (`ceil(n * 30 / rate)` frames). A push with a NaN or infinite sample is
/// refused as a whole, before any of it reaches the stream, which stays usable.
pub struct PcmStream {
    inner: Box<dyn MotionStream>,
    origin: String,
    resampler: Option<Resampler16k>,
    /// Samples pushed, at the input rate.
    received: u64,
    finished: bool,
}

impl std::fmt::Debug for PcmStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PcmStream")
            .field("origin", &self.origin)
            .field("sample_rate", &self.sample_rate())
            .field("received", &self.received)
            .field("finished", &self.finished)
            .finish_non_exhaustive()
    }
}

impl PcmStream {
    /// Wraps a fresh `stream`; `origin` names the audio in errors (e.g. `stream`).
    pub fn new(stream: Box<dyn MotionStream>, origin: impl Into<String>) -> Self {
        Self {
            inner: stream,
            origin: origin.into(),
            resampler: None,
            received: 0,
            finished: false,
        }
    }

    /// The sample rate fixed by the first push (`None` before it).
    pub fn sample_rate(&self) -> Option<u32> {
        self.resampler.as_ref().map(Resampler16k::input_rate)
    }

    /// The audio pushed so far, at its own rate (16 kHz before the first push).
    pub fn span(&self) -> AudioSpan {
        AudioSpan::new(self.received, self.sample_rate().unwrap_or(TARGET_RATE))
    }

    /// The model's stream (frames emitted, guidance in use, ...).
    pub fn stream(&self) -> &dyn MotionStream {
        self.inner.as_ref()
    }

    /// Whether [`PcmStream::finish`] has ended the stream.
    pub fn is_finished(&self) -> bool {
        self.finished
    }

    /// Pushes mono samples at `sample_rate` Hz (any chunk size, also empty); returns the frames they
    /// complete.
    pub fn push(&mut self, samples: &[f32], sample_rate: u32) -> Result<Vec<Frame>> {
        if self.finished {
            return Err(InputError::new(format!(
                "{}: the stream is finished; reset it to start a new input",
                self.origin
            ))
            .into());
        }
        if let Some(rate) = self.sample_rate().filter(|&r| r != sample_rate) {
            return Err(InputError::new(format!(
                "{}: sample rate {sample_rate} Hz differs from the {rate} Hz of this stream's first push; expected one rate per stream (reset it to change)",
                self.origin
            ))
            .into());
        }
        check_finite(samples, &self.origin, self.received)?;
        let resampler = match &mut self.resampler {
            Some(r) => r,
            none => none.insert(Resampler16k::new(sample_rate, self.origin.clone())?),
        };
        let audio = resampler.push(samples)?;
        self.received += samples.len() as u64;
        self.inner.push_audio(&audio).with_context(|| {
            format!(
                "{}: generating motion at {:.2} s",
                self.origin,
                self.inner.samples_received() as f64 / f64::from(TARGET_RATE)
            )
        })
    }

    /// Pushes 16-bit mono PCM (converted as [`i16_to_f32`]).
    pub fn push_i16(&mut self, samples: &[i16], sample_rate: u32) -> Result<Vec<Frame>> {
        self.push(&i16_to_f32(samples), sample_rate)
    }

    /// Ends the input: the frames that remain, so that the stream has emitted `ceil(n * 30 / rate)`
    /// frames for the `n` samples pushed at `rate` Hz.
    pub fn finish(&mut self) -> Result<Vec<Frame>> {
        if self.finished {
            return Err(InputError::new(format!(
                "{}: the stream is already finished; reset it to start a new input",
                self.origin
            ))
            .into());
        }
        let mut frames = Vec::new();
        if let Some(r) = self.resampler.as_mut() {
            let tail = r.finish()?;
            frames = self.inner.push_audio(&tail).with_context(|| {
                format!("{}: generating motion at the end of the audio", self.origin)
            })?;
        }
        let span = self.span();
        frames.extend(self.inner.finish(span).with_context(|| {
            format!(
                "{}: finishing the motion at the end of the audio",
                self.origin
            )
        })?);
        self.finished = true;
        Ok(frames)
    }

    /// Back to a cold start with the same options and seed; the next push may use another rate.
    pub fn reset(&mut self) -> Result<()> {
        self.inner.reset()?;
        self.resampler = None;
        self.received = 0;
        self.finished = false;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_samples_are_named_with_their_index() {
        assert!(check_finite(&[0.0, 0.5, -1.0], "x", 0).is_ok());
        let e = check_finite(&[0.0, f32::NAN], "clip", 10).unwrap_err();
        assert_eq!(
            e.to_string(),
            "clip: sample 11 is NaN; expected finite samples (no NaN or infinity)"
        );
        assert!(check_finite(&[f32::INFINITY], "x", 0).is_err());
    }

    #[test]
    fn a_panic_message_names_the_call_and_the_panic() {
        let p = std::panic::catch_unwind(|| panic!("boom {}", 1)).unwrap_err();
        assert_eq!(
            panic_message("lg_x", p.as_ref()),
            "lg_x: internal error (a panic in the runtime: boom 1); please report it"
        );
        let p = std::panic::catch_unwind(|| panic!("static")).unwrap_err();
        assert!(panic_message("f", p.as_ref()).contains("runtime: static)"));
        let p = std::panic::catch_unwind(|| std::panic::panic_any(7u8)).unwrap_err();
        assert!(panic_message("f", p.as_ref()).contains("unknown panic"));
    }

    #[test]
    fn input_errors_name_their_fields_as_each_door_spells_them() {
        let e = InputError::fields(vec!["ddim_steps", "top_k"], "only apply to X");
        assert_eq!(e.to_string(), "ddim_steps, top_k only apply to X");
        let flag = |f: &str| format!("--{}", f.replace('_', "-"));
        assert_eq!(e.render(flag), "--ddim-steps, --top-k only apply to X");
        assert_eq!(InputError::new("bad").render(flag), "bad");
        // the option checks every door's options pass, naming the field
        let bad = StreamOptions {
            guidance: Some(f64::NAN),
            ..Default::default()
        };
        let e = check_options(&bad).unwrap_err();
        assert_eq!(e.fields, ["guidance"]);
        assert_eq!(e.to_string(), "guidance must be a finite number, got NaN");
        let bad = StreamOptions {
            temperature: Some(0.0),
            ..Default::default()
        };
        assert_eq!(check_options(&bad).unwrap_err().fields, ["temperature"]);
        assert!(check_options(&StreamOptions::default()).is_ok());
    }

    #[test]
    fn i16_converts_as_the_wav_reader() {
        assert_eq!(
            i16_to_f32(&[0, 16384, -32768, 32767]),
            vec![0.0, 0.5, -1.0, 32767.0 / 32768.0]
        );
    }
}
