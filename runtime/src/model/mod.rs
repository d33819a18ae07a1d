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
//! | `livegesture` | [`livegesture`] | 0 (causal, one token = 4 frames) | every graph once per token for all streams ([`MotionModel::step_many`]; with the tokens: [`livegesture::LiveGestureModel::step_many_steps`]) |
//! | `diffsheg` | [`diffsheg`] | its window N (first frame after N frames of audio; then every N - L frames) | CFG rows, and the due windows of all streams of one length, on the denoiser's batch axis |
//!
//! # Stepping many streams
//!
//! [`MotionModel::step_many`] takes one [`StreamJob`] per stream (audio to push, and optionally the
//! end of its input) and returns each stream's frames, exactly those the stream would return on its
//! own (up to the backend's batch-size rounding, docs/parity.md). A family that can run several
//! streams in one graph call does so; the default steps the streams one after another.
//! [`MotionStream::next_unit_samples`] tells a scheduler when pushing a stream's audio will produce
//! frames, so it can collect the streams that are due together (as `livegesture serve` does).
//!
//! # Adding a family
//!
//! 1. `bundle/`: its manifest section (see the [`crate::bundle`] docs);
//! 2. `model/<family>/`: a type implementing [`MotionModel`] and one implementing [`MotionStream`]
//!    (frames with consecutive indices from 0; `finish` follows [`AudioSpan::frames`]);
//! 3. its arm in [`for_family`] (the one place that maps a family to its code), a method in
//!    [`FamilyTool`], and the family's [`load_with`] and [`describe`] there;
//! 4. the parity suite and the benchmarks (crates `livegesture-parity`, `livegesture-bench` in tools/)
//!    implement [`FamilyTool`]: the compiler then asks for the family's checks and benchmarks.
//!
//! [`StreamOptions`] carries the settings of every family; a family refuses (in
//! [`MotionModel::new_stream`]) an option it does not support rather than ignoring it silently.

use std::any::Any;

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
    /// The DiffSHEG-only options that are set (for a family that refuses them), named as the
    /// fields here (`ddim_steps`; each door spells them its own way, [`crate::generate::InputError`]).
    pub fn diffsheg_options_set(&self) -> Vec<&'static str> {
        [
            ("ddim_steps", self.ddim_steps.is_some()),
            ("jumps", self.jumps.is_some()),
            ("window", self.window.is_some()),
            ("overlap", self.overlap.is_some()),
            ("blend_steps", self.blend_steps.is_some()),
            ("speaker", self.speaker.is_some()),
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

    /// Whether the frames carry the face channel (`Frame::face`; docs/face.md): a bundle with a
    /// `face` section. The default: no.
    fn has_face(&self) -> bool {
        false
    }

    /// A fresh stream (cold start) with `opts`; errors for options out of range or not supported by
    /// the family.
    fn new_stream(&self, opts: &StreamOptions) -> Result<Box<dyn MotionStream>>;

    /// Steps many streams together: each job's audio is pushed into its stream and, with
    /// [`StreamJob::end`], the stream is then finished ([`MotionStream::finish`]). Returns one result
    /// per job, in order: the frames the stream emitted, the same frames it would emit on its own.
    ///
    /// A family that can batch runs the units (tokens, windows) due in several streams in one graph
    /// call per graph; streams of another model (or family) in `jobs` are stepped on their own. The
    /// default steps every job on its own stream ([`StreamJob::run_alone`]). An error in a batched
    /// graph call fails every job in that call (their streams then refuse work until reset).
    fn step_many(&self, jobs: &mut [StreamJob<'_>]) -> Vec<Result<Vec<Frame>>> {
        jobs.iter_mut().map(StreamJob::run_alone).collect()
    }

    /// Prepares the backend for [`MotionModel::step_many`] calls of up to `max_streams` streams
    /// before the first of them (a server calls it before taking sessions), so that no call later
    /// pays for a one-time preparation (tract optimises a plan per batch size: up to a second each).
    /// The default prepares nothing.
    fn prepare_batches(&self, max_streams: usize) -> Result<()> {
        let _ = max_streams;
        Ok(())
    }

    /// How many times so far a stream's state had to be copied because the streams stepped with it
    /// in [`MotionModel::step_many`] changed (a family that keeps the state of streams stepped
    /// together stacked between calls: LiveGesture's cohorts). A server whose sessions keep their
    /// company tick after tick adds nothing here in the steady state. The default: 0.
    fn streams_regrouped(&self) -> u64 {
        0
    }

    /// [`MotionModel::step_many`] for jobs that push audio only.
    fn push_many(&self, jobs: &mut [(&mut dyn MotionStream, &[f32])]) -> Vec<Result<Vec<Frame>>> {
        let mut js: Vec<StreamJob<'_>> = jobs
            .iter_mut()
            .map(|(s, a)| StreamJob::push(&mut **s, a))
            .collect();
        self.step_many(&mut js)
    }
}

/// One stream's share of a batch step ([`MotionModel::step_many`]).
pub struct StreamJob<'a> {
    /// The stream (made by the model that steps it, to be batched).
    pub stream: &'a mut dyn MotionStream,
    /// 16 kHz mono samples to push (any length, also empty).
    pub audio: &'a [f32],
    /// After the audio, end the stream ([`MotionStream::finish`] with this input span).
    pub end: Option<AudioSpan>,
}

impl<'a> StreamJob<'a> {
    /// Pushes `audio` into `stream`.
    pub fn push(stream: &'a mut dyn MotionStream, audio: &'a [f32]) -> Self {
        Self {
            stream,
            audio,
            end: None,
        }
    }

    /// Pushes `audio` into `stream`, then finishes it with `end` (docs/output.md).
    pub fn push_and_finish(
        stream: &'a mut dyn MotionStream,
        audio: &'a [f32],
        end: AudioSpan,
    ) -> Self {
        Self {
            stream,
            audio,
            end: Some(end),
        }
    }

    /// The job on its own stream: `push_audio`, then `finish` when the job ends the stream.
    pub fn run_alone(&mut self) -> Result<Vec<Frame>> {
        let mut out = self.stream.push_audio(self.audio)?;
        if let Some(end) = self.end {
            out.extend(self.stream.finish(end)?);
        }
        Ok(out)
    }
}

impl std::fmt::Debug for StreamJob<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StreamJob")
            .field("audio", &self.audio.len())
            .field("end", &self.end)
            .finish_non_exhaustive()
    }
}

/// Lets a family's [`MotionModel::step_many`] recognise its own streams behind `dyn MotionStream`
/// (implemented for every stream type).
pub trait StreamAny: Any {
    /// The stream as [`Any`], for downcasting to the family's stream type.
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

impl<T: Any> StreamAny for T {
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// One stream: all its state, stepped by pushing audio (see the module docs).
///
/// Frames come out in order with consecutive indices from 0, `time_s = index / fps`. After an error
/// the stream refuses further work until [`MotionStream::reset`]; after [`MotionStream::finish`] too.
pub trait MotionStream: Send + StreamAny {
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

    /// The number of 16 kHz samples pushed in all at which the next unit's frames come out (a
    /// scheduler pushes a stream's audio once it reaches this, to step due streams together);
    /// `u64::MAX` once the stream is finished. For a fresh stream: the audio the first frame waits for.
    fn next_unit_samples(&self) -> u64;
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
    struct Describe;
    impl FamilyTool for Describe {
        type Output = Result<Description>;
        fn livegesture(self, bundle: &Bundle) -> Self::Output {
            livegesture::describe(bundle)
        }
        fn diffsheg(self, bundle: &Bundle) -> Self::Output {
            diffsheg::describe(bundle)
        }
    }
    for_family(bundle, Describe)
}

/// Code that differs per model family, outside the model (the tools: parity checks, benchmarks,
/// what `info` shows): one method per family. [`for_family`] runs the method of a bundle's family,
/// so a tool never matches on [`Family`] itself, and a new family is a compile error in every tool
/// until it handles it.
pub trait FamilyTool {
    /// What the tool returns.
    type Output;
    /// A `livegesture` bundle.
    fn livegesture(self, bundle: &Bundle) -> Self::Output;
    /// A `diffsheg` bundle.
    fn diffsheg(self, bundle: &Bundle) -> Self::Output;
}

/// Runs `tool`'s method for `bundle`'s family: the one place that maps a family to its code
/// ([`load_with`] and [`describe`] go through it too).
pub fn for_family<T: FamilyTool>(bundle: &Bundle, tool: T) -> T::Output {
    match bundle.family() {
        Family::LiveGesture => tool.livegesture(bundle),
        Family::DiffSheg => tool.diffsheg(bundle),
    }
}

/// Which form of a bundle's graphs to load (docs/bundle.md#forms-and-precision), a choice of
/// [`LoadOptions`] that names no family: a bundle exported in several forms (a LiveGesture bundle's
/// region eXperts, fusion and decoders) runs the one chosen; a bundle with one form (DiffSHEG)
/// accepts only `Auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GraphForm {
    /// The form the bundle's manifest names for the backend (`backend_forms`), else canonical.
    #[default]
    Auto,
    /// One `expert_<region>` graph per region.
    Canonical,
    /// The four eXperts as one graph on a region axis (`experts_fused`) and, where the bundle has
    /// it, the four SVQ decoders as one graph (`decoders_fused`).
    Fused,
    /// The canonical eXperts and decoders and the fusion with its attention cores as the ONNX
    /// `Attention` op (`fusion_attention`).
    Attention,
    /// The fused form on ring caches (`experts_fused_ring`, `fusion_ring`; docs/bundle.md#ring-caches).
    FusedRing,
    /// The attention form on ring caches (`expert_<region>_ring`, `fusion_attention_ring`).
    AttentionRing,
}

impl std::fmt::Display for GraphForm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GraphForm::Auto => "auto",
            GraphForm::Canonical => "canonical",
            GraphForm::Fused => "fused",
            GraphForm::Attention => "attention",
            GraphForm::FusedRing => "fused_ring",
            GraphForm::AttentionRing => "attention_ring",
        })
    }
}

impl std::str::FromStr for GraphForm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" | "" => Ok(GraphForm::Auto),
            "canonical" => Ok(GraphForm::Canonical),
            "fused" => Ok(GraphForm::Fused),
            "attention" => Ok(GraphForm::Attention),
            "fused_ring" => Ok(GraphForm::FusedRing),
            "attention_ring" => Ok(GraphForm::AttentionRing),
            other => Err(format!(
                "unknown form '{other}'; expected auto, canonical, fused, attention, fused_ring or attention_ring"
            )),
        }
    }
}

/// Choices made when a bundle is loaded, among what the bundle carries.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// The graph form (docs/bundle.md#forms-and-precision; auto = the bundle's form for the
    /// backend). A bundle with one form (DiffSHEG) refuses anything but auto.
    pub form: GraphForm,
}

/// Loads the model of `bundle`'s family with `backend` and the default [`LoadOptions`].
pub fn load(bundle: &Bundle, backend: &dyn Backend) -> Result<Box<dyn MotionModel>> {
    load_with(bundle, backend, &LoadOptions::default())
}

/// Loads the model of `bundle`'s family with `backend` (the family from the manifest, through
/// [`for_family`]).
pub fn load_with(
    bundle: &Bundle,
    backend: &dyn Backend,
    opts: &LoadOptions,
) -> Result<Box<dyn MotionModel>> {
    struct Load<'a> {
        backend: &'a dyn Backend,
        opts: &'a LoadOptions,
    }
    impl FamilyTool for Load<'_> {
        type Output = Result<Box<dyn MotionModel>>;
        fn livegesture(self, bundle: &Bundle) -> Self::Output {
            Ok(Box::new(livegesture::LiveGestureModel::load_with_form(
                bundle,
                self.backend,
                self.opts.form,
            )?))
        }
        fn diffsheg(self, bundle: &Bundle) -> Self::Output {
            check_load_options(bundle, self.opts)?;
            Ok(Box::new(diffsheg::DiffshegModel::load(
                bundle,
                self.backend,
            )?))
        }
    }
    let model = for_family(bundle, Load { backend, opts })?;
    crate::face::with_face(model, bundle, backend)
}

/// Checks that `opts` apply to `bundle`'s family (the form choice is LiveGesture's: a DiffSHEG bundle
/// has one graph form), without loading anything.
pub fn check_load_options(bundle: &Bundle, opts: &LoadOptions) -> Result<()> {
    struct Check<'a>(&'a LoadOptions);
    impl FamilyTool for Check<'_> {
        type Output = Result<()>;
        fn livegesture(self, _: &Bundle) -> Self::Output {
            Ok(())
        }
        fn diffsheg(self, bundle: &Bundle) -> Self::Output {
            anyhow::ensure!(
                self.0.form == GraphForm::Auto,
                "{} is a {} bundle, which has one graph form; the form choice ({}) applies to bundles exported in several forms",
                bundle.dir().display(),
                bundle.family(),
                self.0.form
            );
            Ok(())
        }
    }
    for_family(bundle, Check(opts))
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
