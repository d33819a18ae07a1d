//! The face channel (docs/face.md): every frame's 15 viseme probabilities and 52 ARKit
//! blendshape weights, from the bundle's `face` graph on the same log-mel frames the body graphs read.
//!
//! - [`FaceManifest`]: the manifest's `face` section (names, graph, blink parameters), checked.
//! - [`FaceGraph`]: the loaded graph, shared by the streams of one model.
//! - [`FaceStream`]: one stream's state (its log-mel frontend, the graph's caches, its [`Blinker`]),
//!   fed the same audio as the body; it keeps the face values of frames the body has not emitted yet
//!   (a windowed family emits later) and attaches them by frame index ([`FaceStream::attach`]).
//! - [`FacedModel`] wraps any family's [`MotionModel`] so that every stream's frames carry the face:
//!   [`crate::model::load_with`] wraps a bundle that has a `face` section; a bundle without one gives
//!   frames without face values (`Frame::face` is `None`) and every writer leaves the face keys out.
//!
//! Causality: the graph's frame j of token t reads mel frames up to the end of frame 4t + j, and a
//! token's values exist once its audio has arrived: no audio after the end of the token that emits a
//! frame is used.

use std::collections::VecDeque;
use std::sync::Arc;

use anyhow::{anyhow, bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};

use crate::audio::AudioSpan;
use crate::backend::{Backend, GraphRunner, Tensor};
use crate::bundle::{Bundle, GraphSpec, Manifest};
use crate::frontend::StreamingLogMel;
use crate::model::{MotionModel, MotionStream, StreamJob, StreamOptions};
use crate::output::Frame;
use crate::sampling::SplitMix64;

pub mod mesh;
#[cfg(test)]
mod tests;

/// ARKit blendshape weights per frame.
pub const ARKIT_DIM: usize = 52;
/// Viseme probabilities per frame.
pub const VISEME_DIM: usize = 15;

/// Apple's 52 ARKit blendshape names in Apple's documented order.
pub const ARKIT_NAMES: [&str; ARKIT_DIM] = [
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// The OpenXR / Oculus viseme names in their order.
pub const VISEME_NAMES: [&str; VISEME_DIM] = [
    "sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "ih", "oh", "ou",
];

/// Index of `eyeBlinkLeft` / `eyeBlinkRight` in [`ARKIT_NAMES`].
const BLINK_SHAPES: [usize; 2] = [0, 7];

/// One frame's face.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaceValues {
    /// ARKit weights in [0, 1], [`ARKIT_NAMES`] order.
    pub arkit: [f32; ARKIT_DIM],
    /// Viseme probabilities (sum 1), [`VISEME_NAMES`] order.
    pub visemes: [f32; VISEME_DIM],
}

impl FaceValues {
    /// An error naming the frame and field if a value is not finite or out of its range.
    pub fn check(&self, index: u64) -> Result<()> {
        for (name, v) in [("arkit", &self.arkit[..]), ("visemes", &self.visemes[..])] {
            if let Some(i) = v
                .iter()
                .position(|x| !x.is_finite() || *x < 0.0 || *x > 1.0)
            {
                bail!(
                    "output: frame {index} has {name}[{i}] = {}; expected a finite value in [0, 1]",
                    v[i]
                );
            }
        }
        Ok(())
    }
}

/// The seeded blink process (docs/face.md; `python/livegesture/face/blink.py` is the same).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
pub struct BlinkParams {
    /// First blink start, frames: `first_lo + floor(u * (first_hi - first_lo + 1))`.
    pub first_lo: u64,
    /// See `first_lo`.
    pub first_hi: u64,
    /// Gap from one blink's start to the next one's, frames (as `first_*`).
    pub gap_lo: u64,
    /// See `gap_lo`.
    pub gap_hi: u64,
    /// Frames per blink; weight `sin(pi (k + 1) / (duration + 1))` at its k-th frame.
    pub duration: u64,
}

/// XORed into the stream's seed for the blink generator.
pub const BLINK_SALT: u64 = 0xB11C_B11C_B11C_B11C;

/// One stream's blinks, frame by frame from frame 0.
#[derive(Debug, Clone)]
pub struct Blinker {
    p: BlinkParams,
    rng: SplitMix64,
    next_start: u64,
    frame: u64,
}

impl Blinker {
    /// The process of a stream with `seed`.
    pub fn new(p: BlinkParams, seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ BLINK_SALT);
        let next_start = draw(&mut rng, p.first_lo, p.first_hi);
        Self {
            p,
            rng,
            next_start,
            frame: 0,
        }
    }

    /// The blink weight of the next frame.
    pub fn next_weight(&mut self) -> f32 {
        let d = self.p.duration;
        let mut w = 0.0;
        if self.frame >= self.next_start {
            let k = self.frame - self.next_start;
            if k < d {
                w = (std::f64::consts::PI * (k + 1) as f64 / (d + 1) as f64).sin();
            }
            if k + 1 == d {
                self.next_start += draw(&mut self.rng, self.p.gap_lo, self.p.gap_hi);
            }
        }
        self.frame += 1;
        w as f32
    }
}

fn draw(rng: &mut SplitMix64, lo: u64, hi: u64) -> u64 {
    lo + (rng.next_f64() * (hi - lo + 1) as f64).floor() as u64
}

/// The manifest's `face` section.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
pub struct FaceManifest {
    /// The graph computing visemes and ARKit mouth weights per token.
    pub graph: String,
    /// Viseme names (must be [`VISEME_NAMES`]).
    pub visemes: Vec<String>,
    /// ARKit names (must be [`ARKIT_NAMES`]).
    pub arkit: Vec<String>,
    /// The blink process.
    pub blink: BlinkParams,
}

impl FaceManifest {
    /// Checks the section against the fixed names and the manifest's graph (no file read).
    pub fn check(&self, m: &Manifest) -> Result<(), String> {
        if self.visemes != VISEME_NAMES {
            return Err(format!(
                "face.visemes is {:?}; expected {:?}",
                self.visemes, VISEME_NAMES
            ));
        }
        if self.arkit != ARKIT_NAMES {
            return Err("face.arkit is not Apple's 52 ARKit names in Apple's order (eyeBlinkLeft ... tongueOut)".into());
        }
        let b = &self.blink;
        if b.first_lo > b.first_hi
            || b.gap_lo > b.gap_hi
            || b.duration == 0
            || b.gap_lo < b.duration
        {
            return Err(format!("face.blink {b:?}: expected first_lo <= first_hi, duration >= 1 and duration <= gap_lo <= gap_hi"));
        }
        let g = m
            .graphs
            .iter()
            .find(|g| g.name == self.graph)
            .ok_or_else(|| format!("face.graph '{}' is not among the graphs", self.graph))?;
        let names: Vec<&str> = g.inputs.iter().map(|i| i.name.as_str()).collect();
        if names != ["mel"] {
            return Err(format!(
                "graph '{}': inputs {names:?}, expected [\"mel\"] (plus caches)",
                g.name
            ));
        }
        let outs: Vec<&str> = g.outputs.iter().map(|o| o.name.as_str()).collect();
        if outs != ["visemes", "arkit_mouth"] {
            return Err(format!(
                "graph '{}': outputs {outs:?}, expected [\"visemes\", \"arkit_mouth\"] (plus caches)",
                g.name
            ));
        }
        Ok(())
    }
}

/// The `face` section of a manifest, if any, parsed and checked (errors name the field).
pub fn manifest_face(m: &Manifest) -> Result<Option<&FaceManifest>, String> {
    match &m.face {
        None => Ok(None),
        Some(f) => f.check(m).map(|()| Some(f)),
    }
}

/// The face graph of a loaded bundle, shared by its streams as the graphs of the families are: the
/// runner is shared (its runs take `&self`, each with a run state or session of its own,
/// [`GraphRunner`]), the caches belong to each stream, so streams on different threads run it at the
/// same time.
pub struct FaceGraph {
    runner: Box<dyn GraphRunner>,
    spec: GraphSpec,
    section: FaceManifest,
    frontend: crate::frontend::FrontendConfig,
}

impl std::fmt::Debug for FaceGraph {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FaceGraph")
            .field("graph", &self.spec.name)
            .finish_non_exhaustive()
    }
}

impl FaceGraph {
    /// Loads the bundle's face graph; `None` for a bundle without a `face` section.
    pub fn load(bundle: &Bundle, backend: &dyn Backend) -> Result<Option<Arc<Self>>> {
        let m = bundle.manifest();
        let Some(section) =
            manifest_face(m).map_err(|e| anyhow!("{}: {e}", bundle.manifest_path().display()))?
        else {
            return Ok(None);
        };
        let spec = bundle.graph(&section.graph)?.clone();
        let runner = backend
            .load_from(bundle, &spec)
            .with_context(|| format!("loading the face graph '{}'", spec.name))?;
        Ok(Some(Arc::new(Self {
            runner,
            spec,
            section: section.clone(),
            frontend: bundle.frontend().clone(),
        })))
    }

    /// Frames per token.
    fn frames_per_token(&self) -> usize {
        self.frontend.frames_per_token as usize
    }

    /// One token of one stream: `mel` (M, n_mels) row-major and the stream's caches (replaced by the new
    /// ones) -> the token's frames' (visemes, arkit_mouth).
    fn step(
        &self,
        mel: Vec<f32>,
        caches: &mut Vec<Tensor>,
    ) -> Result<Vec<([f32; VISEME_DIM], [f32; ARKIT_DIM])>> {
        let m = self.frontend.mel_frames_per_token as usize;
        let n_mels = self.frontend.n_mels;
        let mut inputs = vec![Tensor::f32(vec![1, m, n_mels], mel)?];
        inputs.append(caches);
        let out = self.runner.run(&inputs)?;
        ensure!(
            out.len() == 2 + self.spec.caches.len(),
            "face graph '{}': {} outputs, expected {}",
            self.spec.name,
            out.len(),
            2 + self.spec.caches.len()
        );
        *caches = out[2..].to_vec();
        let f = self.frames_per_token();
        let vis = out[0].as_f32("face visemes")?;
        let ark = out[1].as_f32("face arkit_mouth")?;
        ensure!(
            vis.len() == f * VISEME_DIM && ark.len() == f * ARKIT_DIM,
            "face graph '{}': outputs of {} and {} values, expected {} and {}",
            self.spec.name,
            vis.len(),
            ark.len(),
            f * VISEME_DIM,
            f * ARKIT_DIM
        );
        Ok((0..f)
            .map(|j| {
                let mut v = [0f32; VISEME_DIM];
                v.copy_from_slice(&vis[j * VISEME_DIM..(j + 1) * VISEME_DIM]);
                let mut a = [0f32; ARKIT_DIM];
                a.copy_from_slice(&ark[j * ARKIT_DIM..(j + 1) * ARKIT_DIM]);
                (v, a)
            })
            .collect())
    }
}

/// One stream's face state (see the module docs).
pub struct FaceStream {
    graph: Arc<FaceGraph>,
    mel: StreamingLogMel,
    caches: Vec<Tensor>,
    blink: Blinker,
    seed: u64,
    /// Face values of frames `first_pending ..`, not yet attached.
    pending: VecDeque<FaceValues>,
    first_pending: u64,
}

impl FaceStream {
    /// A cold stream with `seed` (the blinks' seed: the stream's seed).
    pub fn new(graph: Arc<FaceGraph>, seed: u64) -> Result<Self> {
        let mel = StreamingLogMel::new(&graph.frontend)?;
        let caches = graph.spec.caches.iter().map(|c| c.zeros(1)).collect();
        let blink = Blinker::new(graph.section.blink, seed);
        Ok(Self {
            graph,
            mel,
            caches,
            blink,
            seed,
            pending: VecDeque::new(),
            first_pending: 0,
        })
    }

    /// Back to a cold start.
    pub fn reset(&mut self) -> Result<()> {
        *self = Self::new(self.graph.clone(), self.seed)?;
        Ok(())
    }

    /// Pushes 16 kHz samples (the same the body gets); computes the face of every token they complete.
    pub fn push(&mut self, samples: &[f32]) -> Result<()> {
        for tok in self.mel.push(samples)? {
            let mel = tok.iter().copied().collect();
            for (vis, mut arkit) in self.graph.step(mel, &mut self.caches)? {
                let w = self.blink.next_weight();
                for &i in &BLINK_SHAPES {
                    arkit[i] = arkit[i].max(w).clamp(0.0, 1.0);
                }
                self.pending.push_back(FaceValues {
                    arkit,
                    visemes: vis,
                });
            }
        }
        Ok(())
    }

    /// Sets `frames`' face (consecutive indices, each at or after the last one attached). At the end of a
    /// stream (`end`) the audio of the last partial token is completed with silence first, as the body's.
    pub fn attach(&mut self, frames: &mut [Frame], end: bool) -> Result<()> {
        if end {
            let need = frames.last().map_or(0, |f| f.index + 1);
            let tpf = self.graph.frontend.frames_per_token;
            while self.first_pending + (self.pending.len() as u64) < need {
                let t = self.mel.tokens_emitted();
                let missing = self.graph.frontend.token_end(t) - self.mel.samples_received();
                ensure!(
                    missing <= self.graph.frontend.token_end(0) * 2,
                    "face: frame {} needs audio far beyond the stream's end ({} samples); expected at most one token of silence",
                    need - 1,
                    missing
                );
                let before = self.pending.len();
                self.push(&vec![0.0; missing as usize])?;
                ensure!(
                    self.pending.len() == before + tpf as usize,
                    "face: completing the last token gave no frames"
                );
            }
        }
        for f in frames.iter_mut() {
            ensure!(
                f.index >= self.first_pending,
                "face: frame {} arrived after frame {} (frames must come in order)",
                f.index,
                self.first_pending
            );
            while self.first_pending < f.index {
                self.pending.pop_front();
                self.first_pending += 1;
            }
            let v = self.pending.pop_front().ok_or_else(|| {
                anyhow!(
                    "face: frame {} has no face values yet (the face stream is at frame {}); the body emitted a frame before its audio arrived",
                    f.index,
                    self.first_pending
                )
            })?;
            self.first_pending += 1;
            f.face = Some(v);
        }
        Ok(())
    }
}

/// A model whose streams' frames carry the face (see the module docs).
pub struct FacedModel {
    inner: Box<dyn MotionModel>,
    graph: Arc<FaceGraph>,
}

impl FacedModel {
    /// `inner` with the face of `graph`.
    pub fn new(inner: Box<dyn MotionModel>, graph: Arc<FaceGraph>) -> Self {
        Self { inner, graph }
    }

    /// The wrapped family model.
    pub fn inner(&self) -> &dyn MotionModel {
        self.inner.as_ref()
    }
}

/// A stream of a [`FacedModel`]: the family's stream and its face.
pub struct FacedStream {
    inner: Box<dyn MotionStream>,
    face: FaceStream,
}

impl FacedStream {
    fn after(&mut self, audio: &[f32], frames: &mut [Frame], end: bool) -> Result<()> {
        self.face.push(audio)?;
        self.face.attach(frames, end)
    }
}

impl MotionModel for FacedModel {
    fn family(&self) -> crate::bundle::Family {
        self.inner.family()
    }
    fn backend_name(&self) -> &str {
        self.inner.backend_name()
    }
    fn fps(&self) -> u64 {
        self.inner.fps()
    }
    fn has_face(&self) -> bool {
        true
    }
    fn new_stream(&self, opts: &StreamOptions) -> Result<Box<dyn MotionStream>> {
        Ok(Box::new(FacedStream {
            inner: self.inner.new_stream(opts)?,
            face: FaceStream::new(self.graph.clone(), opts.seed)?,
        }))
    }
    fn prepare_batches(&self, max_streams: usize) -> Result<()> {
        self.inner.prepare_batches(max_streams)
    }
    fn streams_regrouped(&self) -> u64 {
        self.inner.streams_regrouped()
    }
    fn step_many(&self, jobs: &mut [StreamJob<'_>]) -> Vec<Result<Vec<Frame>>> {
        // the body steps batched in the family's model; each stream's face after it (batch 1)
        if !jobs.iter_mut().all(|j| {
            j.stream
                .as_any_mut()
                .downcast_mut::<FacedStream>()
                .is_some()
        }) {
            return jobs.iter_mut().map(StreamJob::run_alone).collect();
        }
        let meta: Vec<(&[f32], bool)> = jobs.iter().map(|j| (j.audio, j.end.is_some())).collect();
        let mut faces: Vec<&mut FaceStream> = Vec::with_capacity(jobs.len());
        let mut inner_jobs: Vec<StreamJob<'_>> = Vec::with_capacity(jobs.len());
        for j in jobs.iter_mut() {
            let Some(FacedStream { inner, face }) =
                j.stream.as_any_mut().downcast_mut::<FacedStream>()
            else {
                unreachable!("checked above")
            };
            faces.push(face);
            inner_jobs.push(StreamJob {
                stream: inner.as_mut(),
                audio: j.audio,
                end: j.end,
            });
        }
        let results = self.inner.step_many(&mut inner_jobs);
        drop(inner_jobs);
        results
            .into_iter()
            .zip(faces)
            .zip(meta)
            .map(|((r, face), (audio, end))| {
                let mut frames = r?;
                face.push(audio)?;
                face.attach(&mut frames, end)?;
                Ok(frames)
            })
            .collect()
    }
}

impl MotionStream for FacedStream {
    fn push_audio(&mut self, samples: &[f32]) -> Result<Vec<Frame>> {
        let mut frames = self.inner.push_audio(samples)?;
        self.after(samples, &mut frames, false)?;
        Ok(frames)
    }
    fn finish(&mut self, input: AudioSpan) -> Result<Vec<Frame>> {
        let mut frames = self.inner.finish(input)?;
        self.after(&[], &mut frames, true)?;
        Ok(frames)
    }
    fn reset(&mut self) -> Result<()> {
        self.inner.reset()?;
        self.face.reset()
    }
    fn frames_emitted(&self) -> u64 {
        self.inner.frames_emitted()
    }
    fn samples_received(&self) -> u64 {
        self.inner.samples_received()
    }
    fn frames_per_unit(&self) -> u64 {
        self.inner.frames_per_unit()
    }
    fn lookahead_frames(&self) -> u64 {
        self.inner.lookahead_frames()
    }
    fn guidance(&self) -> f64 {
        self.inner.guidance()
    }
    fn next_unit_samples(&self) -> u64 {
        self.inner.next_unit_samples()
    }
}

/// Wraps `model` with the bundle's face when the bundle has one.
pub fn with_face(
    model: Box<dyn MotionModel>,
    bundle: &Bundle,
    backend: &dyn Backend,
) -> Result<Box<dyn MotionModel>> {
    Ok(match FaceGraph::load(bundle, backend)? {
        Some(g) => Box::new(FacedModel::new(model, g)),
        None => model,
    })
}
