//! The LiveGesture family: audio chunks in, SMPL-X frames out, zero look-ahead.
//!
//! This reproduces `python/livegesture/stream.py` step for step. Per motion token `t`, as soon as its
//! audio has arrived:
//!
//! 1. the stream's [`StreamingLogMel`] yields the token's `mel_frames_per_token` log-mel frames;
//! 2. `audio_encoder` turns them into the audio token `a_t` (once per stream);
//! 3. every `expert_<region>` (in the fused form `experts_fused`, all regions at once) reads the
//!    previous token of its region (BOS at `t = 0`) and `a_t`; the conditional (`cond = 1`) and
//!    unconditional (`cond = 0`) guidance branches are two rows on the batch axis;
//! 4. `fusion` gives per-region logits for both branches;
//! 5. classifier-free guidance and the seeded SplitMix64 sampler ([`crate::sampling`]) draw one token
//!    per region, in region order;
//! 6. `decoder_<region>` turns the token into frames `4t .. 4t+3` of region features (in the fused
//!    form of a bundle that has it, `decoders_fused` does so for the four regions at once);
//! 7. rot6d is converted to axis-angle and the region features are assembled into [`Frame`]s
//!    (translation and expressions copied, foot contact from the lower region's contact dims, eyes at
//!    rest), following the region layout in the manifest.
//!
//! With guidance `gamma == 1.0` the unconditional branch is not run at all (one row per stream), as in
//! Python.
//!
//! # State and batching
//!
//! A [`Stream`] owns all per-stream state (frontend buffer, every graph's caches, previous tokens, the
//! PRNG, the token counter). Its size is fixed: it does not grow with the stream's length. A
//! [`LiveGestureGraphs`] owns the loaded graphs and is shared by any number of streams.
//!
//! Two ways to step many streams at once, every graph running once for all of them, both on the same
//! per-token chain (`chain`):
//!
//! - [`MotionModel::step_many`](crate::model::MotionModel::step_many) of a [`LiveGestureModel`] (what
//!   `serve` runs, what `bench` measures and the parity `batch` check verifies;
//!   [`LiveGestureModel::step_many_steps`] also returns the tokens): the caches of streams stepped
//!   together stay stacked between calls (`cohorts`); only streams that join or leave are copied;
//! - [`LiveGestureGraphs::step_batch`] on separately owned [`Stream`]s: their caches are copied into stacked
//!   buffers before each graph run and back after it (every cache copied twice per step; the buffers are
//!   reused, nothing is allocated; a single stream's caches are moved): the path of
//!   [`LiveGestureGraphs::step`], one stream at a time.
//!
//! Stepping streams one by one or together gives the same tokens and frames.
//!
//! After an error inside a graph the caches are incomplete: the stream refuses further work until
//! [`LiveGestureGraphs::reset`].
//!
//! # The end of the audio (docs/output.md)
//!
//! [`LiveGestureGraphs::finish`] completes the last partial token with silence and cuts its frames at the
//! audio's end, so a stream emits exactly [`AudioSpan::frames`] frames, `ceil(duration * 30)`, in
//! total; a [`crate::model::StreamJob`] with an end does the same in a batched step.
//!
//! # Layout
//!
//! - here: [`LiveGestureGraphs`] (the loaded graphs; streams, steps, finish);
//! - `stream`: [`Stream`], its options in use and counters, [`TokenStep`];
//! - `caches`: where each graph's caches live (separate per stream, or stacked in a cohort);
//! - `cohorts`: the caches of a [`LiveGestureModel`]'s streams kept stacked between
//!   [`MotionModel::step_many`](crate::model::MotionModel::step_many) calls;
//! - `chain`: the per-token chain, one function per stage (audio encoder, experts, fusion, sampling,
//!   decoders);
//! - `layout`: frames from the decoders' outputs (through [`crate::model::regions`]), the state
//!   size of a stream, what `info` shows;
//! - `model`: [`LiveGestureModel`] / [`LiveGestureStream`], the family's
//!   [`MotionModel`](crate::model::MotionModel) / [`MotionStream`](crate::model::MotionStream).

use anyhow::{ensure, Context, Result};
use ndarray::Array2;

use crate::audio::AudioSpan;
use crate::backend::Backend;
use crate::bundle::Bundle;
use crate::frontend::{FrontendConfig, StreamingLogMel};
use crate::output::Frame;

pub use crate::model::StreamOptions;

mod caches;
mod chain;
mod cohorts;
mod layout;
mod model;
mod stream;

pub use layout::{describe, state_bytes};
pub use model::{LiveGestureModel, LiveGestureStream};
pub use stream::{cut_frames, StepLogits, Stream, TokenStep};

use crate::model::regions::{resolve_layouts, RegionLayout};
use crate::model::GraphForm;
use caches::{Caches, SeparateCaches, Slot};
use chain::Stage;
use stream::StreamState;

/// The loaded graphs of a bundle, shared by any number of [`Stream`]s.
pub struct LiveGestureGraphs {
    frontend: FrontendConfig,
    regions: Vec<RegionLayout>,
    bos: i64,
    codebook_size: usize,
    defaults: (f64, f64, usize),
    frames_per_token: usize,
    backend: String,
    audio_encoder: Stage,
    /// The region eXperts: one stage per region (canonical form) or one for all (fused form).
    experts: Vec<Stage>,
    /// The form of the eXperts, fusion and decoders (`canonical`, `fused` or `attention`).
    form: String,
    fusion: Stage,
    /// The region SVQ decoders: one stage per region (canonical form, and the fused form of a bundle
    /// without `decoders_fused`) or one for all (`decoders_fused`).
    decoders: Vec<Stage>,
    /// The ring caches of the form (docs/bundle.md#ring-caches; empty for the shift layout).
    ring: caches::RingMask,
    /// Buffers of [`LiveGestureGraphs::step_batch`] reused from step to step (taken by one step at
    /// a time; a step that finds them taken uses fresh ones).
    scratch: std::sync::Mutex<caches::Scratch>,
}

impl std::fmt::Debug for LiveGestureGraphs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveGestureGraphs")
            .field("backend", &self.backend)
            .field("form", &self.form)
            .field(
                "regions",
                &self.regions.iter().map(|r| &r.name).collect::<Vec<_>>(),
            )
            .finish_non_exhaustive()
    }
}

impl LiveGestureGraphs {
    /// Loads every graph of `bundle` with `backend`, the eXperts, fusion and decoders in the
    /// bundle's form for the backend (`backend_forms`, else canonical).
    pub fn new(bundle: &Bundle, backend: &dyn Backend) -> Result<Self> {
        Self::with_form(bundle, backend, GraphForm::Auto)
    }

    /// Loads every graph of `bundle` with `backend`, the region eXperts, fusion and decoders in the
    /// form `form` (a fused form without `decoders_fused`, from bundles exported before it, runs the
    /// canonical decoders; a form without its own `fusion` runs the canonical fusion). Asking for a
    /// form the bundle does not carry is an error naming the forms it has.
    pub fn with_form(bundle: &Bundle, backend: &dyn Backend, form: GraphForm) -> Result<Self> {
        let lg = bundle.livegesture()?;
        let names: Vec<String> = lg.region_names().iter().map(|s| s.to_string()).collect();
        let regions = resolve_layouts(&lg.regions)?;
        // the form's name in the manifest is its `Display` (`auto`: the bundle's form for the backend,
        // with the decoders the backend runs with it: `LiveGestureManifest::graphs_run_by`)
        let asked = (form != GraphForm::Auto).then(|| form.to_string());
        // a form the bundle does not carry is bad input (exit code 2), named in the manifest's terms
        let (form, graphs) = lg
            .graphs_run_by(backend.forms_of(), asked.as_deref())
            .ok_or_else(|| crate::bundle::BundleError::Manifest {
                path: bundle.dir().join("manifest.json"),
                detail: format!(
                    "forms: no '{}' form of the region eXperts, fusion and decoders was exported (the bundle has {:?})",
                    asked.as_deref().unwrap_or(lg.default_form(backend.forms_of())),
                    lg.form_graphs().keys().collect::<Vec<_>>()
                ),
            })?;
        let audio_encoder = Stage::new(bundle, backend, "audio_encoder", &names)?;
        let fusion = Stage::new(bundle, backend, &graphs.fusion, &names)?;
        let experts = graphs
            .experts
            .iter()
            .map(|g| Stage::new(bundle, backend, g, &names))
            .collect::<Result<Vec<_>>>()?;
        if experts.len() == 1 && names.len() > 1 {
            chain::check_fused_experts(&experts[0], names.len())?;
        }
        let decoders = graphs
            .decoders
            .iter()
            .map(|g| Stage::new(bundle, backend, g, &names))
            .collect::<Result<Vec<_>>>()?;
        let fpt = bundle.frontend().frames_per_token as usize;
        if decoders.len() == 1 && names.len() > 1 {
            let dims: Vec<usize> = regions.iter().map(|l| l.dim).collect();
            chain::check_fused_decoders(&decoders[0], &dims, fpt)?;
        }
        let per_region = if decoders.len() == names.len() {
            &decoders[..]
        } else {
            &[]
        };
        for (d, l) in per_region.iter().zip(&regions) {
            chain::check_decoder_output(d, &[l.dim], fpt)?;
        }
        let s = &lg.sampling;
        // which caches the graphs of the form write at the phase (a form is on ring caches or not)
        let mut ring = Vec::new();
        for (slot, stage) in std::iter::once((Slot::AudioEncoder, &audio_encoder))
            .chain(
                experts
                    .iter()
                    .enumerate()
                    .map(|(i, e)| (Slot::Expert(i), e)),
            )
            .chain(std::iter::once((Slot::Fusion, &fusion)))
            .chain(
                decoders
                    .iter()
                    .enumerate()
                    .map(|(i, d)| (Slot::Decoder(i), d)),
            )
        {
            if stage.spec.is_ring() {
                ensure!(
                    slot.branched(),
                    "graph '{}': ring caches in a graph without guidance branches (only the eXperts and the fusion have attention caches)",
                    stage.spec.name
                );
                ring.push((
                    slot,
                    stage.spec.caches.iter().map(|c| c.is_ring()).collect(),
                ));
            }
        }
        ensure!(
            ring.is_empty() || ring.len() == experts.len() + 1,
            "form '{form}': some of its eXperts and fusion graphs are on ring caches and some are not (docs/bundle.md#ring-caches)"
        );
        Ok(LiveGestureGraphs {
            frontend: bundle.frontend().clone(),
            regions,
            bos: lg.vocab.bos_token,
            codebook_size: lg.vocab.codebook_size,
            defaults: (s.guidance, s.temperature, s.top_k),
            frames_per_token: fpt,
            backend: backend.name().to_string(),
            audio_encoder,
            experts,
            form,
            fusion,
            decoders,
            ring: std::sync::Arc::new(ring),
            scratch: Default::default(),
        })
    }

    /// The form of the region eXperts, fusion and decoders these graphs run (`canonical`,
    /// `fused` or `attention`, docs/bundle.md#forms-and-precision).
    pub fn form(&self) -> &str {
        &self.form
    }

    /// The graphs of the SVQ decoders these graphs run: one per region, or `decoders_fused`
    /// ([`crate::bundle::LiveGestureManifest::default_decoders`]: tract's `auto` runs it with any
    /// form when the bundle has it).
    pub fn decoder_graphs(&self) -> Vec<&str> {
        self.decoders.iter().map(|d| d.spec.name.as_str()).collect()
    }

    /// The backend the graphs run on.
    pub fn backend_name(&self) -> &str {
        &self.backend
    }

    /// The frontend configuration (sample rate, token grid).
    pub fn frontend(&self) -> &FrontendConfig {
        &self.frontend
    }

    /// Region names in order.
    pub fn region_names(&self) -> Vec<&str> {
        self.regions.iter().map(|r| r.name.as_str()).collect()
    }

    /// Codebook size K.
    pub fn codebook_size(&self) -> usize {
        self.codebook_size
    }

    /// A fresh stream (cold start: zero caches from the manifest, BOS previous tokens, seeded PRNG).
    pub fn new_stream(&self, opts: &StreamOptions) -> Result<Stream> {
        let gamma = opts.guidance.unwrap_or(self.defaults.0);
        let temperature = opts.temperature.unwrap_or(self.defaults.1);
        let top_k = opts.top_k.unwrap_or(self.defaults.2);
        ensure!(
            gamma.is_finite(),
            "guidance must be a finite number, got {gamma}"
        );
        ensure!(
            temperature.is_finite() && temperature > 0.0,
            "temperature must be > 0, got {temperature}"
        );
        let state = StreamState::new(
            opts,
            gamma,
            temperature,
            top_k,
            StreamingLogMel::new(&self.frontend)?,
            self.bos,
            self.regions.len(),
        );
        Ok(Stream {
            caches: self.initial_caches(state.branch_rows(), 1),
            state,
            poisoned: false,
        })
    }

    /// Zero caches from the manifest with `branch_rows` rows in the expert and fusion graphs and
    /// `rows` in the others.
    fn initial_caches(&self, branch_rows: usize, rows: usize) -> Caches {
        Caches {
            audio_encoder: caches::zeros_for(&self.audio_encoder.spec.caches, rows),
            experts: self
                .experts
                .iter()
                .map(|e| caches::zeros_for(&e.spec.caches, branch_rows))
                .collect(),
            fusion: caches::zeros_for(&self.fusion.spec.caches, branch_rows),
            decoders: self
                .decoders
                .iter()
                .map(|d| caches::zeros_for(&d.spec.caches, rows))
                .collect(),
            phase: 0,
            ring: self.ring.clone(),
        }
    }

    /// True when the form's eXperts and fusion run on ring caches (docs/bundle.md#ring-caches).
    pub fn ring_caches(&self) -> bool {
        !self.ring.is_empty()
    }

    /// Prepares every graph's backend for steps of up to `max_streams` streams before the first
    /// of them ([`crate::backend::GraphRunner::prepare_batches`] with every batch size, in rows: the
    /// expert and fusion graphs carry two rows per guided stream): tract optimises the plans of the
    /// row counts of its ladder that cover these sizes
    /// ([`crate::backend::tract::TRACT_ROW_BUCKETS`]; other counts run padded to the next one) and
    /// one with the batch left symbolic for larger ones, so that no later step optimises a plan;
    /// ort prepares nothing.
    pub fn prepare_batches(&self, max_streams: usize) -> Result<()> {
        let (one, two): (Vec<usize>, Vec<usize>) = (
            (1..=max_streams.max(1)).collect(),
            (1..=2 * max_streams.max(1)).collect(),
        );
        self.audio_encoder.runner().prepare_batches(&one)?;
        for e in &self.experts {
            e.runner().prepare_batches(&two)?;
        }
        self.fusion.runner().prepare_batches(&two)?;
        for d in &self.decoders {
            d.runner().prepare_batches(&one)?;
        }
        Ok(())
    }

    /// Every cache with zero rows (the layout of stacked caches).
    fn empty_caches(&self) -> Caches {
        self.initial_caches(0, 0)
    }

    /// Resets `stream` to a cold start with its original options (and seed).
    pub fn reset(&self, stream: &mut Stream) -> Result<()> {
        *stream = self.new_stream(&stream.state.opts.clone())?;
        Ok(())
    }

    /// Pushes audio (16 kHz mono, any chunk size) and returns the frames of every token it completes.
    pub fn push(&self, stream: &mut Stream, chunk: &[f32]) -> Result<Vec<Frame>> {
        Ok(self
            .push_steps(stream, chunk)?
            .into_iter()
            .flat_map(|s| s.frames)
            .collect())
    }

    /// Like [`LiveGestureGraphs::push`], returning each token step (tokens, optional logits, frames).
    pub fn push_steps(&self, stream: &mut Stream, chunk: &[f32]) -> Result<Vec<TokenStep>> {
        ensure!(
            !stream.poisoned,
            "the stream failed earlier; reset it before pushing more audio"
        );
        let mels = stream.state.push_audio(chunk)?;
        mels.iter().map(|mel| self.step(stream, mel)).collect()
    }

    /// Ends `stream` (docs/output.md): completes its last partial token with silence and returns the frames
    /// still missing, cut at the end of `input` (the audio the caller received, at its own rate), so
    /// that the stream has emitted exactly [`AudioSpan::frames`] frames. The stream then refuses more
    /// audio until [`LiveGestureGraphs::reset`]. Errors when `input` does not match the audio pushed (see
    /// [`Stream::finish_audio`]).
    pub fn finish(&self, stream: &mut Stream, input: AudioSpan) -> Result<Vec<Frame>> {
        Ok(self
            .finish_steps(stream, input)?
            .into_iter()
            .flat_map(|s| s.frames)
            .collect())
    }

    /// Like [`LiveGestureGraphs::finish`], returning the token steps (their frames already cut).
    pub fn finish_steps(&self, stream: &mut Stream, input: AudioSpan) -> Result<Vec<TokenStep>> {
        ensure!(
            !stream.poisoned,
            "the stream failed earlier; reset it before finishing it"
        );
        let (mels, total) = stream.state.finish_audio(input)?;
        let mut out = mels
            .iter()
            .map(|mel| self.step(stream, mel))
            .collect::<Result<Vec<_>>>()?;
        cut_frames(&mut out, total);
        Ok(out)
    }

    /// One token step of one stream from its mel frames `(mel_frames_per_token, n_mels)`.
    pub fn step(&self, stream: &mut Stream, mel: &Array2<f32>) -> Result<TokenStep> {
        let mut v = self.step_batch(&mut [stream], std::slice::from_ref(mel))?;
        v.pop().context("step_batch returned no result")
    }

    fn check_mels(&self, n: usize, mels: &[Array2<f32>]) -> Result<()> {
        ensure!(n == mels.len(), "{n} streams but {} mel blocks", mels.len());
        let mpt = self.frontend.mel_frames_per_token as usize;
        let n_mels = self.frontend.n_mels;
        for m in mels {
            ensure!(
                m.dim() == (mpt, n_mels),
                "mel block has shape {:?}, expected ({mpt}, {n_mels})",
                m.dim()
            );
        }
        Ok(())
    }

    /// One token step of several separately owned streams at once (`mels[i]` for `streams[i]`):
    /// every graph runs once with the streams' caches stacked on the batch axis before the run and
    /// split back after it. Streams may differ in guidance. For a set of streams stepped together
    /// again and again, [`LiveGestureModel`]'s `step_many` avoids the stacking (its cohorts).
    pub fn step_batch(
        &self,
        streams: &mut [&mut Stream],
        mels: &[Array2<f32>],
    ) -> Result<Vec<TokenStep>> {
        self.check_mels(streams.len(), mels).context("step_batch")?;
        if streams.is_empty() {
            return Ok(Vec::new());
        }
        for s in streams.iter() {
            ensure!(
                !s.poisoned,
                "the stream failed earlier; reset it before stepping it again"
            );
        }
        for s in streams.iter_mut() {
            s.poisoned = true;
        }
        let mut states = Vec::with_capacity(streams.len());
        // the buffers of the last step, unless another thread's step holds them now
        let mut scratch = self
            .scratch
            .try_lock()
            .map(|mut s| std::mem::take(&mut *s))
            .unwrap_or_default();
        // ring caches: every stream's at the first one's phase (the others' rows rotated)
        let phase = streams[0].caches.phase;
        let mut store = SeparateCaches {
            caches: Vec::with_capacity(streams.len()),
            branch_rows: Vec::with_capacity(streams.len()),
            scratch: &mut scratch,
            phase,
        };
        for s in streams.iter_mut() {
            let s = &mut **s;
            if s.caches.phase != phase {
                s.caches.rephase(phase)?;
            }
            store.branch_rows.push(s.state.branch_rows());
            states.push(&mut s.state);
            store.caches.push(&mut s.caches);
        }
        let out = self.step_inner(&mut states, &mut store, mels);
        drop(store);
        // after a failed run the scratch buffers may be partial: they are rebuilt on the next step
        if out.is_ok() {
            if let Ok(mut s) = self.scratch.try_lock() {
                *s = scratch;
            }
        }
        let out = out?;
        for s in streams.iter_mut() {
            s.poisoned = false;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send<T: Send>() {}

    fn assert_sync<T: Sync>() {}

    #[test]
    fn streams_and_graphs_move_between_threads() {
        assert_send::<Stream>();
        assert_send::<LiveGestureGraphs>();
        // shared by the streams of every thread (steps take `&self`)
        assert_sync::<LiveGestureGraphs>();
    }
}
