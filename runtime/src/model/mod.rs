//! Model families behind one streaming API: audio in, SMPL-X [`Frame`]s out.
//!
//! A bundle's manifest names its `family` ([`Family`]); [`load`] is the **one place** that maps a
//! family to its implementation. Everything above it (the CLI's `generate` and `stream`, the server)
//! works on the two traits below and never names a family.
//!
//! - [`MotionModel`] (one implementation per family) owns the loaded graphs of a bundle and makes
//!   streams. It is `Send + Sync`, so one loaded model serves any number of streams and threads.
//! - [`MotionStream`] owns **all** state of one stream (as kyutai moshi's `StreamingModule`: audio
//!   buffers, graph caches, PRNG, counters; no hidden globals): [`MotionStream::push_audio`] takes
//!   16 kHz mono samples in chunks of any size and returns the frames they complete,
//!   [`MotionStream::finish`] ends the stream so that its frames cover the whole input (docs/output.md),
//!   [`MotionStream::reset`] returns it to a cold start with the same options and seed.
//!
//! Input-rate conversion happens before a stream ([`crate::audio`]: WAV, raw PCM, resampling to
//! 16 kHz). The number of frames that covers an input is fixed by the input's **own** sample count and
//! rate, not by the resampled count: [`AudioSpan::frames`], `ceil(n_in * fps / rate_in)` in integers.
//! So `finish` takes the [`AudioSpan`] the caller received (the readers report it:
//! [`crate::audio::WavStream::input_span`], [`crate::audio::RawPcmStream::input_span`]).
//!
//! Shared by the families: [`regions`] turns per-region features into SMPL-X frames (rot6d ->
//! axis-angle, translation, expressions, foot contact) from the manifest's region layout.
//!
//! # Families
//!
//! | family | module | look-ahead | batched stepping |
//! |---|---|---|---|
//! | `livegesture` | [`livegesture`] | 0 (causal, one token = 4 frames) | [`livegesture::StreamBatch`] |
//! | `diffsheg` | [`diffsheg`] | its window N (first frame after N frames of audio; then every N - L frames) | CFG rows on the denoiser's batch axis |
//!
//! # Adding a family
//!
//! 1. `bundle/`: its manifest section (see the [`crate::bundle`] docs);
//! 2. `model/<family>/`: a type implementing [`MotionModel`] and one implementing [`MotionStream`]
//!    (frames with consecutive indices from 0; `finish` follows [`AudioSpan::frames`]);
//! 3. one arm in [`load`] and in [`describe`] (what `info` prints of the family);
//! 4. `parity` and `bench` (features of the same names) dispatch on the family in
//!    `parity::run` and `bench::run`: add the family's checks and benchmarks there.
//!
//! [`StreamOptions`] carries the settings of every family; a family refuses (in
//! [`MotionModel::new_stream`]) an option it does not support rather than ignoring it silently.

use anyhow::Result;

use crate::audio::AudioSpan;
use crate::backend::Backend;
use crate::bundle::{Bundle, Family};
use crate::output::Frame;

pub mod diffsheg;
pub mod livegesture;
pub mod regions;

/// Generation settings of one stream; `None` takes the bundle's default.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamOptions {
    /// Seed of the stream's SplitMix64 generator.
    pub seed: u64,
    /// Classifier-free guidance scale gamma (1.0 disables guidance).
    pub guidance: Option<f64>,
    /// Sampling temperature (> 0; LiveGesture).
    pub temperature: Option<f64>,
    /// Top-k (0 = all tokens; LiveGesture).
    pub top_k: Option<usize>,
    /// Keep each step's logits (LiveGesture's [`livegesture::TokenStep::logits`], for parity tools).
    pub record_logits: bool,
    /// DDIM steps, must divide the training steps (DiffSHEG).
    pub ddim_steps: Option<usize>,
    /// RePaint jumps per DDIM step, >= 1 (DiffSHEG).
    pub jumps: Option<usize>,
    /// Window length in frames, <= the bundle's `foppas.max_window` (DiffSHEG).
    pub window: Option<usize>,
    /// Overlap of consecutive windows in frames, < window (DiffSHEG).
    pub overlap: Option<usize>,
    /// Last DDIM steps that blend the overlap linearly (DiffSHEG).
    pub blend_steps: Option<usize>,
    /// Style (speaker) id, < the bundle's `speakers.count` (DiffSHEG).
    pub speaker: Option<usize>,
}

impl StreamOptions {
    /// The DiffSHEG-only options that are set (for a family that refuses them).
    pub fn diffsheg_options_set(&self) -> Vec<&'static str> {
        [
            ("--ddim-steps", self.ddim_steps.is_some()),
            ("--jumps", self.jumps.is_some()),
            ("--window", self.window.is_some()),
            ("--overlap", self.overlap.is_some()),
            ("--blend-steps", self.blend_steps.is_some()),
            ("--speaker", self.speaker.is_some()),
        ]
        .into_iter()
        .filter(|(_, set)| *set)
        .map(|(n, _)| n)
        .collect()
    }
}

/// A loaded bundle of one family: its graphs on one backend. Makes [`MotionStream`]s.
pub trait MotionModel: Send + Sync {
    /// The family this model implements.
    fn family(&self) -> Family;

    /// The backend the graphs run on (`tract`, `ort`).
    fn backend_name(&self) -> &str;

    /// Output frames per second (30).
    fn fps(&self) -> u64;

    /// A fresh stream (cold start) with `opts`; errors for options out of range or not supported by
    /// the family.
    fn new_stream(&self, opts: &StreamOptions) -> Result<Box<dyn MotionStream>>;
}

/// One stream: all its state, stepped by pushing audio (see the module docs).
///
/// Frames come out in order with consecutive indices from 0, `time_s = index / fps`. After an error
/// the stream refuses further work until [`MotionStream::reset`]; after [`MotionStream::finish`] too.
pub trait MotionStream: Send {
    /// Pushes 16 kHz mono samples (any chunk size, also empty) and returns the frames they complete.
    fn push_audio(&mut self, samples: &[f32]) -> Result<Vec<Frame>>;

    /// Ends the stream (docs/output.md): completes the last partial unit (token, window) with silence and
    /// returns the remaining frames, cut so that the stream has emitted exactly
    /// `input.frames(fps)` frames in total. `input` is the audio the caller received, counted at its
    /// own rate. Errors when `input` does not match what was pushed (more than one unit of audio
    /// missing, or fewer frames than already emitted).
    fn finish(&mut self, input: AudioSpan) -> Result<Vec<Frame>>;

    /// Back to a cold start with the same options and seed (also after an error or `finish`).
    fn reset(&mut self) -> Result<()>;

    /// Frames emitted so far.
    fn frames_emitted(&self) -> u64;

    /// 16 kHz samples pushed so far (the silence added by `finish` not counted).
    fn samples_received(&self) -> u64;

    /// Frames emitted together, as one unit: a token (4) for LiveGesture, a window step for DiffSHEG.
    fn frames_per_unit(&self) -> u64;

    /// Look-ahead, in frames: how far past the end of a unit the audio must reach before the unit's
    /// frames are emitted. 0 for LiveGesture (a token leaves as soon as its own audio is complete);
    /// a windowed family reports the audio it waits for beyond the unit it emits.
    fn lookahead_frames(&self) -> u64;

    /// The classifier-free guidance scale gamma in use (the option, or the bundle's default).
    fn guidance(&self) -> f64;
}

/// What `info` shows of a bundle's family-specific part, read from the manifest alone (no graph is
/// loaded).
#[derive(Debug, Clone, Default)]
pub struct Description {
    /// `(label, text)` lines in display order.
    pub lines: Vec<(String, String)>,
    /// The same facts as JSON fields (`info --json`).
    pub json: serde_json::Map<String, serde_json::Value>,
    /// Batch rows one stream occupies in each graph, with the bundle's default options (graphs not
    /// listed: 1).
    pub rows_per_stream: std::collections::BTreeMap<String, usize>,
}

/// Describes the family-specific part of `bundle` (see [`Description`]).
pub fn describe(bundle: &Bundle) -> Result<Description> {
    match bundle.family() {
        Family::LiveGesture => livegesture::describe(bundle),
        Family::DiffSheg => diffsheg::describe(bundle),
    }
}

/// Choices made when a bundle is loaded, among what the bundle carries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// LiveGesture: the form of the region eXperts and decoders (docs/bundle.md#forms-and-precision; auto = the bundle's
    /// form for the backend). DiffSHEG bundles carry one form: anything but auto is refused.
    pub form: livegesture::FormChoice,
}

/// Loads the model of `bundle`'s family with `backend` and the default [`LoadOptions`].
pub fn load(bundle: &Bundle, backend: &dyn Backend) -> Result<Box<dyn MotionModel>> {
    load_with(bundle, backend, &LoadOptions::default())
}

/// Loads the model of `bundle`'s family with `backend`. With [`describe`], the only place that maps a
/// family to its implementation.
pub fn load_with(
    bundle: &Bundle,
    backend: &dyn Backend,
    opts: &LoadOptions,
) -> Result<Box<dyn MotionModel>> {
    match bundle.family() {
        Family::LiveGesture => Ok(Box::new(livegesture::LiveGestureModel::load_with_form(
            bundle, backend, opts.form,
        )?)),
        Family::DiffSheg => {
            anyhow::ensure!(
                opts.form == livegesture::FormChoice::Auto,
                "{}: a DiffSHEG bundle has one graph form; the form choice ({}) applies to LiveGesture's region eXperts",
                bundle.dir().display(),
                opts.form
            );
            Ok(Box::new(diffsheg::DiffshegModel::load(bundle, backend)?))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send_sync<T: Send + Sync + ?Sized>() {}
    fn assert_send<T: Send + ?Sized>() {}

    #[test]
    fn models_are_shared_and_streams_move_between_threads() {
        assert_send_sync::<dyn MotionModel>();
        assert_send::<dyn MotionStream>();
    }
}
