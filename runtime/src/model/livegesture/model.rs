//! The LiveGesture family behind the family-independent traits ([`MotionModel`], [`MotionStream`]).
//!
//! [`LiveGestureModel`] shares one [`Pipeline`] (the loaded graphs) between its streams behind a
//! mutex: a graph run needs the runner exclusively (tract caches a plan per batch size, ort binds
//! its outputs), and a stream steps only while it holds the lock, so streams on other threads wait
//! for each other's token steps. To run many streams in parallel, load one model per thread; to
//! step many streams in one graph run, use a [`super::StreamBatch`] directly.

use std::sync::{Arc, Mutex, MutexGuard};

use anyhow::{anyhow, Result};

use super::{FormChoice, Pipeline, Stream};
use crate::audio::AudioSpan;
use crate::backend::Backend;
use crate::bundle::{Bundle, Family};
use crate::model::{MotionModel, MotionStream, StreamOptions};
use crate::output::Frame;

/// A loaded LiveGesture bundle ([`MotionModel`] of the `livegesture` family).
#[derive(Debug, Clone)]
pub struct LiveGestureModel {
    pipeline: Arc<Mutex<Pipeline>>,
    backend: String,
    fps: u64,
    frames_per_token: u64,
}

fn lock(p: &Mutex<Pipeline>) -> Result<MutexGuard<'_, Pipeline>> {
    p.lock().map_err(|_| {
        anyhow!("the model's graphs were left inconsistent by a panic in another stream")
    })
}

impl LiveGestureModel {
    /// Loads every graph of `bundle` (family `livegesture`) with `backend`, the region eXperts in
    /// the bundle's form for the backend.
    pub fn load(bundle: &Bundle, backend: &dyn Backend) -> Result<Self> {
        Self::load_with_form(bundle, backend, FormChoice::Auto)
    }

    /// As [`Self::load`], the region eXperts in the form `form` (docs/bundle.md#forms-and-precision).
    pub fn load_with_form(
        bundle: &Bundle,
        backend: &dyn Backend,
        form: FormChoice,
    ) -> Result<Self> {
        let pipeline = Pipeline::with_form(bundle, backend, form)?;
        let f = bundle.frontend();
        Ok(Self {
            backend: pipeline.backend_name().to_string(),
            fps: f.fps,
            frames_per_token: f.frames_per_token,
            pipeline: Arc::new(Mutex::new(pipeline)),
        })
    }

    /// The shared pipeline (for LiveGesture-specific work: token steps, batches).
    pub fn pipeline(&self) -> &Arc<Mutex<Pipeline>> {
        &self.pipeline
    }
}

impl MotionModel for LiveGestureModel {
    fn family(&self) -> Family {
        Family::LiveGesture
    }

    fn backend_name(&self) -> &str {
        &self.backend
    }

    fn fps(&self) -> u64 {
        self.fps
    }

    fn new_stream(&self, opts: &StreamOptions) -> Result<Box<dyn MotionStream>> {
        let set = opts.diffsheg_options_set();
        if !set.is_empty() {
            anyhow::bail!(
                "{} only apply to DiffSHEG bundles; a LiveGesture bundle samples tokens (--guidance, --temperature, --top-k)",
                set.join(", ")
            );
        }
        let stream = lock(&self.pipeline)?.new_stream(opts)?;
        Ok(Box::new(LiveGestureStream {
            pipeline: Arc::clone(&self.pipeline),
            stream,
            frames_per_token: self.frames_per_token,
        }))
    }
}

/// One LiveGesture stream ([`MotionStream`]): a [`Stream`] and the model it steps on.
#[derive(Debug)]
pub struct LiveGestureStream {
    pipeline: Arc<Mutex<Pipeline>>,
    stream: Stream,
    frames_per_token: u64,
}

impl LiveGestureStream {
    /// The stream's LiveGesture state (tokens, options in use).
    pub fn stream(&self) -> &Stream {
        &self.stream
    }
}

impl MotionStream for LiveGestureStream {
    fn push_audio(&mut self, samples: &[f32]) -> Result<Vec<Frame>> {
        lock(&self.pipeline)?.push(&mut self.stream, samples)
    }

    fn finish(&mut self, input: AudioSpan) -> Result<Vec<Frame>> {
        lock(&self.pipeline)?.finish(&mut self.stream, input)
    }

    fn reset(&mut self) -> Result<()> {
        lock(&self.pipeline)?.reset(&mut self.stream)
    }

    fn frames_emitted(&self) -> u64 {
        self.stream.frames_done()
    }

    fn samples_received(&self) -> u64 {
        self.stream.samples_received()
    }

    fn frames_per_unit(&self) -> u64 {
        self.frames_per_token
    }

    fn lookahead_frames(&self) -> u64 {
        0
    }

    fn guidance(&self) -> f64 {
        self.stream.guidance()
    }
}
