//! DiffSHEG behind the family-independent traits ([`MotionModel`], [`MotionStream`]).
//!
//! [`DiffshegModel`] shares the two loaded graphs between its streams behind a mutex (a graph run
//! needs its runner exclusively); a stream holds the lock while it runs a window. Each
//! [`DiffshegStream`] owns its whole state ([`FoppasStream`]: audio buffer, next window start, held
//! overlap, noise position). Emitted rows are de-normalised (`x * std + mean` in f32) and assembled into
//! frames by the shared region code ([`crate::model::regions`]).

use std::sync::Arc;

use anyhow::{bail, ensure, Context, Result};

use super::foppas::{SamplerOptions, MOTION_DIM};
use super::graphs::DiffshegGraphs;
use super::schedule::Schedule;
use super::stream::{Emitted, FoppasStream};
use crate::audio::AudioSpan;
use crate::backend::Backend;
use crate::bundle::{Bundle, DiffshegManifest, Family};
use crate::frontend::FrontendConfig;
use crate::model::regions::{assemble_frame, resolve_layouts, RegionLayout};
use crate::model::{MotionModel, MotionStream, StreamJob, StreamOptions};
use crate::output::Frame;

// the batch step of `step_many`: a child of this module (it uses the model's and stream's
// internals), so the two form no import cycle
mod batch;

/// Everything a DiffSHEG stream needs besides the graphs, shared by the streams of a model.
#[derive(Debug)]
pub struct Shared {
    /// The manifest's DiffSHEG sections.
    pub sections: DiffshegManifest,
    /// The schedule (from the manifest's exact bits).
    pub schedule: Arc<Schedule>,
    /// The frontend.
    pub frontend: FrontendConfig,
    /// Region layouts in `regions` order, with each region's offset in the motion vector.
    layouts: Vec<RegionLayout>,
    offsets: Vec<usize>,
}

impl Shared {
    fn new(bundle: &Bundle) -> Result<Self> {
        let sections = bundle.diffsheg()?.clone();
        let layouts = resolve_layouts(&sections.regions)?;
        let mut offsets = Vec::new();
        for l in &layouts {
            let e = sections
                .motion
                .layout
                .iter()
                .find(|e| e.region == l.name)
                .with_context(|| {
                    format!("manifest motion.layout: no entry for region '{}'", l.name)
                })?;
            ensure!(
                e.dim == l.dim,
                "manifest motion.layout: region '{}' has {} dims, regions says {}",
                l.name,
                e.dim,
                l.dim
            );
            offsets.push(e.offset);
        }
        Ok(Self {
            schedule: Arc::new(sections.schedule.clone()),
            sections,
            frontend: bundle.frontend().clone(),
            layouts,
            offsets,
        })
    }

    /// The sampler options for `opts` (bundle defaults for `None`), validated; the error names the
    /// option.
    pub fn sampler_options(&self, opts: &StreamOptions) -> Result<SamplerOptions> {
        if opts.temperature.is_some() || opts.top_k.is_some() {
            let set = [
                ("temperature", opts.temperature.is_some()),
                ("top_k", opts.top_k.is_some()),
            ];
            return Err(crate::error::InputError::fields(
                set.into_iter().filter(|s| s.1).map(|s| s.0).collect(),
                "only apply to LiveGesture bundles; a DiffSHEG bundle samples with DDIM (its options: ddim_steps, jumps, window, overlap)",
            )
            .into());
        }
        let d = self.sections.default_options();
        let o = SamplerOptions {
            steps: opts.ddim_steps.unwrap_or(d.steps),
            guidance: opts.guidance.unwrap_or(d.guidance),
            window: opts.window.unwrap_or(d.window),
            overlap: opts.overlap.unwrap_or(d.overlap),
            jumps: opts.jumps.unwrap_or(d.jumps),
            blend_steps: opts.blend_steps.unwrap_or(d.blend_steps),
        };
        o.validate(&self.schedule, self.sections.foppas.max_window)?;
        Ok(o)
    }

    /// The style id for `opts` (bundle default for `None`), checked.
    pub fn speaker(&self, opts: &StreamOptions) -> Result<i64> {
        let s = opts.speaker.unwrap_or(self.sections.speakers.default);
        ensure!(
            s < self.sections.speakers.count,
            "speaker must be in 0..{} (the bundle's speakers.count), got {s}",
            self.sections.speakers.count
        );
        Ok(s as i64)
    }

    /// Frames from emitted normalised rows: de-normalised, then assembled per region.
    pub fn frames(&self, e: &Emitted) -> Vec<Frame> {
        let mut rows = e.rows.clone();
        self.sections.denormalise(&mut rows);
        rows.chunks_exact(MOTION_DIM)
            .enumerate()
            .map(|(i, row)| {
                let slices = self
                    .layouts
                    .iter()
                    .zip(&self.offsets)
                    .map(|(l, &o)| &row[o..o + l.dim]);
                assemble_frame((e.start + i) as u64, &self.layouts, slices)
            })
            .collect()
    }
}

/// A loaded DiffSHEG bundle ([`MotionModel`] of the `diffsheg` family).
#[derive(Debug, Clone)]
pub struct DiffshegModel {
    pub(super) graphs: Arc<DiffshegGraphs>,
    pub(super) shared: Arc<Shared>,
    backend: String,
}

impl DiffshegModel {
    /// Loads `speech_encoder` and `denoiser` of `bundle` (family `diffsheg`) with `backend`.
    pub fn load(bundle: &Bundle, backend: &dyn Backend) -> Result<Self> {
        let shared = Shared::new(bundle)?;
        let load = |name: &str| -> Result<_> {
            let spec = bundle.graph(name)?;
            backend.load_from(bundle, spec).with_context(|| {
                format!("loading graph '{name}' with the {} backend", backend.name())
            })
        };
        let enc_spec = bundle.graph("speech_encoder")?;
        let n_mels = enc_spec
            .inputs
            .first()
            .and_then(|i| i.shape.last())
            .and_then(|d| match d {
                crate::bundle::Dim::Fixed(n) => Some(*n),
                _ => None,
            })
            .context("graph 'speech_encoder': input 'mel' has no fixed mel axis")?;
        let audio_dim = enc_spec
            .outputs
            .first()
            .and_then(|o| o.shape.last())
            .and_then(|d| match d {
                crate::bundle::Dim::Fixed(n) => Some(*n),
                _ => None,
            })
            .context("graph 'speech_encoder': output 'audio' has no fixed feature axis")?;
        ensure!(
            n_mels == shared.frontend.n_mels,
            "graph 'speech_encoder' takes {n_mels} mel bands, the frontend makes {}",
            shared.frontend.n_mels
        );
        let graphs = DiffshegGraphs {
            encoder: load("speech_encoder")?,
            denoiser: load("denoiser")?,
            n_mels,
            audio_dim,
        };
        Ok(Self {
            graphs: Arc::new(graphs),
            shared: Arc::new(shared),
            backend: backend.name().to_string(),
        })
    }

    /// The shared graphs (for parity and bench tools that run them directly).
    pub fn graphs(&self) -> &Arc<DiffshegGraphs> {
        &self.graphs
    }

    /// Sections, schedule, frontend and region layouts.
    pub fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }

    /// A DiffSHEG stream (the concrete type; [`MotionModel::new_stream`] boxes it), recording every
    /// window with `record`.
    pub fn stream(&self, opts: &StreamOptions, record: bool) -> Result<DiffshegStream> {
        let so = self.shared.sampler_options(opts)?;
        let speaker = self.shared.speaker(opts)?;
        Ok(DiffshegStream {
            graphs: Arc::clone(&self.graphs),
            shared: Arc::clone(&self.shared),
            inner: FoppasStream::new(
                &self.shared.frontend,
                Arc::clone(&self.shared.schedule),
                so,
                speaker,
                opts.seed,
                record,
            )?,
            poisoned: false,
        })
    }
}

impl MotionModel for DiffshegModel {
    fn family(&self) -> Family {
        Family::DiffSheg
    }

    fn backend_name(&self) -> &str {
        &self.backend
    }

    fn fps(&self) -> u64 {
        self.shared.frontend.fps
    }

    fn new_stream(&self, opts: &StreamOptions) -> Result<Box<dyn MotionStream>> {
        Ok(Box::new(self.stream(opts, false)?))
    }

    /// The windows due in several streams run together: windows of the same length share each
    /// `speech_encoder` and `denoiser` call, every stream's rows (both guidance rows with guidance)
    /// on the batch axis (`batch`).
    fn step_many(&self, jobs: &mut [StreamJob<'_>]) -> Vec<Result<Vec<Frame>>> {
        batch::step_many(self, jobs)
    }
}

/// One DiffSHEG stream ([`MotionStream`]).
#[derive(Debug)]
pub struct DiffshegStream {
    pub(super) graphs: Arc<DiffshegGraphs>,
    pub(super) shared: Arc<Shared>,
    pub(super) inner: FoppasStream,
    pub(super) poisoned: bool,
}

impl DiffshegStream {
    /// The FOPPAS state (options, noise position, recorded windows).
    pub fn foppas(&self) -> &FoppasStream {
        &self.inner
    }

    fn guarded(
        &mut self,
        f: impl FnOnce(&mut FoppasStream, &DiffshegGraphs) -> Result<Vec<Emitted>>,
    ) -> Result<Vec<Frame>> {
        ensure!(
            !self.poisoned,
            "the stream failed earlier; reset it before pushing more audio"
        );
        match f(&mut self.inner, &self.graphs) {
            Ok(em) => Ok(em.iter().flat_map(|e| self.shared.frames(e)).collect()),
            Err(e) => {
                self.poisoned = true;
                Err(e)
            }
        }
    }
}

impl DiffshegStream {
    /// The frames that cover `input` (the audio the caller received, at its own rate); errors when
    /// the samples pushed do not match it.
    pub(super) fn frames_covering(&self, input: AudioSpan) -> Result<usize> {
        let t = input.frames(self.shared.frontend.fps) as usize;
        let pushed = self.inner.samples_received();
        let cover = (t as u64) * self.shared.frontend.sample_rate / self.shared.frontend.fps;
        // the 16 kHz samples pushed must cover the input up to less than one frame (resampling)
        let frame = self.shared.frontend.sample_rate / self.shared.frontend.fps + 1;
        ensure!(
            pushed + 2 * frame >= cover && pushed <= cover + 2 * frame,
            "finish: {} input samples at {} Hz make {t} frames, but {pushed} samples at 16 kHz were pushed",
            input.samples,
            input.sample_rate
        );
        Ok(t)
    }
}

impl MotionStream for DiffshegStream {
    fn push_audio(&mut self, samples: &[f32]) -> Result<Vec<Frame>> {
        if let Some(i) = samples.iter().position(|x| !x.is_finite()) {
            // refused before anything is consumed: the stream stays usable
            bail!(
                "audio contains a non-finite sample ({}) at stream sample {}; expected finite samples",
                samples[i],
                self.inner.samples_received() + i as u64
            );
        }
        self.guarded(|s, g| s.push(g, samples))
    }

    fn finish(&mut self, input: AudioSpan) -> Result<Vec<Frame>> {
        let t = self.frames_covering(input)?;
        self.guarded(|s, g| s.finish(g, t))
    }

    fn reset(&mut self) -> Result<()> {
        self.inner.reset();
        self.poisoned = false;
        Ok(())
    }

    fn frames_emitted(&self) -> u64 {
        self.inner.frames_emitted() as u64
    }

    fn samples_received(&self) -> u64 {
        self.inner.samples_received()
    }

    fn frames_per_unit(&self) -> u64 {
        let o = self.inner.options();
        (o.window - o.overlap) as u64
    }

    fn lookahead_frames(&self) -> u64 {
        self.inner.options().overlap as u64
    }

    fn guidance(&self) -> f64 {
        self.inner.options().guidance
    }

    fn next_unit_samples(&self) -> u64 {
        self.inner.next_window_samples()
    }
}

/// What `info` shows of a DiffSHEG bundle (manifest only).
pub fn describe(bundle: &Bundle) -> Result<crate::model::Description> {
    let d = bundle.diffsheg()?;
    let o = d.default_options();
    let fps = bundle.frontend().fps as f64;
    let mut lines = vec![
        (
            "sampler".to_string(),
            format!(
                "DDIM {} steps (eta 0, of {} training steps), guidance {}{}, FOPPAS window {} frames, overlap {}, jumps {}, blend steps {}, max window {}",
                o.steps,
                d.diffusion.train_steps,
                o.guidance,
                if o.guidance == 1.0 { " (off)" } else { "" },
                o.window,
                o.overlap,
                o.jumps,
                o.blend_steps,
                d.foppas.max_window
            ),
        ),
        (
            "denoiser calls".to_string(),
            format!(
                "{} per window ({} for the first), {} row(s) each",
                o.calls_per_window(true),
                o.calls_per_window(false),
                o.rows()
            ),
        ),
        (
            "speakers".to_string(),
            format!("{} style ids, default {}", d.speakers.count, d.speakers.default),
        ),
        (
            "noise".to_string(),
            format!("{} counter-based Gaussian (portable, bit-identical to Python)", d.noise.prng),
        ),
        (
            "look-ahead".to_string(),
            format!(
                "{} frames ({:.2} s) before the first frame, then windows every {} frames, plus each window's sampling time",
                o.window,
                o.window as f64 / fps,
                o.window - o.overlap
            ),
        ),
    ];
    let state = o.overlap * MOTION_DIM * 4 + 24;
    lines.push((
        "state".to_string(),
        format!(
            "{:.1} KiB per stream between windows (held overlap {} x {MOTION_DIM} f32, next_start, noise_position) + the audio buffer (up to one window step)",
            state as f64 / 1024.0,
            o.overlap
        ),
    ));
    let mut json = serde_json::Map::new();
    json.insert(
        "sampler".into(),
        serde_json::json!({
            "ddim_steps": o.steps, "guidance": o.guidance, "window": o.window, "overlap": o.overlap,
            "jumps": o.jumps, "blend_steps": o.blend_steps, "max_window": d.foppas.max_window,
            "denoiser_calls_per_window": o.calls_per_window(true),
        }),
    );
    json.insert(
        "speakers".into(),
        serde_json::json!({"count": d.speakers.count, "default": d.speakers.default}),
    );
    json.insert("lookahead_frames".into(), serde_json::json!(o.window));
    json.insert("state_bytes_per_stream".into(), serde_json::json!(state));
    let rows_per_stream = [("denoiser".to_string(), o.rows())].into_iter().collect();
    Ok(crate::model::Description {
        lines,
        json,
        rows_per_stream,
    })
}
