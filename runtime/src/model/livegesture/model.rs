//! The LiveGesture family behind the family-independent traits ([`MotionModel`], [`MotionStream`]).
//!
//! [`LiveGestureModel`] shares one [`LiveGestureGraphs`] (the loaded graphs, immutable once loaded)
//! between its streams: each stream owns its state (frontend, caches, sampler) and a token step
//! takes the graphs by `&self`, so streams on different threads step at the same time (each graph
//! run with a run state or session of its own, `crate::backend::GraphRunner`). To step many
//! streams in one graph run per graph per token, use [`MotionModel::step_many`] (the caches of
//! streams stepped together stay stacked between calls, in the model's cohorts: see `cohorts`;
//! `step_many` calls of one model run one at a time; [`LiveGestureModel::step_many_steps`] is the same
//! path returning the token steps: the parity `batch` check verifies it, `bench` measures it).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

use anyhow::{anyhow, ensure, Result};
use ndarray::Array2;

use super::cohorts::{Cohorts, Member};
use super::{cut_frames, LiveGestureGraphs, Stream, TokenStep};
use crate::audio::AudioSpan;
use crate::backend::Backend;
use crate::bundle::{Bundle, Family};
use crate::model::{GraphForm, MotionModel, MotionStream, StreamJob, StreamOptions};
use crate::output::Frame;

/// A loaded LiveGesture bundle ([`MotionModel`] of the `livegesture` family).
#[derive(Debug, Clone)]
pub struct LiveGestureModel {
    graphs: Arc<LiveGestureGraphs>,
    /// Where the streams' caches stay stacked between [`MotionModel::step_many`] calls.
    cohorts: Arc<Mutex<Cohorts>>,
    backend: String,
    fps: u64,
    frames_per_token: u64,
}

fn lock<T>(p: &Mutex<T>) -> Result<MutexGuard<'_, T>> {
    p.lock().map_err(|_| {
        anyhow!("the model's stacked caches were left inconsistent by a panic in another stream")
    })
}

impl LiveGestureModel {
    /// Loads every graph of `bundle` (family `livegesture`) with `backend`, the region eXperts in
    /// the form `form` (docs/bundle.md#forms-and-precision; auto: the bundle's form for the backend).
    pub fn load_with_form(bundle: &Bundle, backend: &dyn Backend, form: GraphForm) -> Result<Self> {
        Ok(Self::from(LiveGestureGraphs::with_form(
            bundle, backend, form,
        )?))
    }

    /// The shared graphs (for LiveGesture-specific work: token steps, batches).
    pub fn graphs(&self) -> &Arc<LiveGestureGraphs> {
        &self.graphs
    }
}

impl From<LiveGestureGraphs> for LiveGestureModel {
    /// The model of already loaded graphs.
    fn from(graphs: LiveGestureGraphs) -> Self {
        let f = graphs.frontend();
        Self {
            backend: graphs.backend_name().to_string(),
            fps: f.fps,
            frames_per_token: f.frames_per_token,
            cohorts: Arc::new(Mutex::new(Cohorts::new(graphs.empty_caches()))),
            graphs: Arc::new(graphs),
        }
    }
}

impl From<LiveGestureGraphs> for Box<dyn MotionModel> {
    fn from(graphs: LiveGestureGraphs) -> Self {
        Box::new(LiveGestureModel::from(graphs))
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
            return Err(crate::error::InputError::fields(
                set,
                "only apply to DiffSHEG bundles; a LiveGesture bundle samples tokens (its options: guidance, temperature, top_k)",
            )
            .into());
        }
        let stream = self.graphs.new_stream(opts)?;
        let key = lock(&self.cohorts)?.key();
        Ok(Box::new(LiveGestureStream {
            graphs: Arc::clone(&self.graphs),
            cohorts: Arc::clone(&self.cohorts),
            key,
            away: false,
            stream,
            frames_per_token: self.frames_per_token,
        }))
    }

    /// Streams whose stacked caches were copied between cohorts (their step-mates changed).
    fn streams_regrouped(&self) -> u64 {
        self.cohorts.lock().map_or(0, |c| c.moved())
    }

    /// Every graph's backend prepares batch sizes up to `max_streams` streams, or the most one
    /// step runs (`MAX_STEP`: larger company steps in groups) ([`LiveGestureGraphs::prepare_batches`]).
    fn prepare_batches(&self, max_streams: usize) -> Result<()> {
        self.graphs
            .prepare_batches(max_streams.min(super::cohorts::MAX_STEP))
    }

    /// Pushes every job's audio into its stream's frontend, then steps token by token: each round
    /// runs every graph once for all streams that still have a completed token, on their caches
    /// kept stacked in a cohort between calls (`cohorts`: streams stepped together again are not
    /// copied; those that join or leave the cohort are). A job that ends its stream adds the
    /// silence-completed last token and its frames are cut at the end of the input, as
    /// [`MotionStream::finish`] does. The frames of [`LiveGestureModel::step_many_steps`].
    fn step_many(&self, jobs: &mut [StreamJob<'_>]) -> Vec<Result<Vec<Frame>>> {
        self.step_jobs(jobs, |job| {
            Ok(vec![TokenStep {
                token_index: 0,
                tokens: Vec::new(),
                logits: None,
                frames: job.run_alone()?,
            }])
        })
        .into_iter()
        .map(|r| r.map(|steps| steps.into_iter().flat_map(|s| s.frames).collect()))
        .collect()
    }
}

impl LiveGestureModel {
    /// [`MotionModel::step_many`] returning each job's token steps (tokens, frames; the frames of a
    /// job that ends its stream cut at the end of its input): the one batched path, which `serve`
    /// runs (as `step_many`), `bench` measures and the parity `batch` check verifies. Every job's
    /// stream must be one of this model's (made by its `new_stream`); a job of another model
    /// fails with an error saying so (`step_many` steps those on their own).
    pub fn step_many_steps(&self, jobs: &mut [StreamJob<'_>]) -> Vec<Result<Vec<TokenStep>>> {
        self.step_jobs(jobs, |_| {
            Err(anyhow!(
                "step_many_steps steps the streams of this model only; this job's stream was made by another model"
            ))
        })
    }

    /// The batched step of [`MotionModel::step_many`]; `foreign` runs a job whose stream is not
    /// this model's.
    fn step_jobs(
        &self,
        jobs: &mut [StreamJob<'_>],
        mut foreign: impl FnMut(&mut StreamJob<'_>) -> Result<Vec<TokenStep>>,
    ) -> Vec<Result<Vec<TokenStep>>> {
        let mut results: Vec<Option<Result<Vec<TokenStep>>>> = jobs.iter().map(|_| None).collect();
        let mut mine: Vec<Pending<'_>> = Vec::new();
        for (i, job) in jobs.iter_mut().enumerate() {
            let ours = job
                .stream
                .as_any_mut()
                .downcast_mut::<LiveGestureStream>()
                .is_some_and(|s| Arc::ptr_eq(&s.graphs, &self.graphs));
            if !ours {
                results[i] = Some(foreign(job));
                continue;
            }
            let (audio, end) = (job.audio, job.end);
            let Some(s) = job.stream.as_any_mut().downcast_mut::<LiveGestureStream>() else {
                continue;
            };
            match prepare(&mut s.stream, audio, end) {
                Ok((mels, total)) => mine.push(Pending {
                    job: i,
                    key: s.key,
                    away: &mut s.away,
                    stream: &mut s.stream,
                    mels,
                    total,
                    steps: Vec::new(),
                    failed: None,
                }),
                Err(e) => results[i] = Some(Err(e)),
            }
        }
        if !mine.is_empty() {
            match lock(&self.cohorts) {
                Ok(mut c) => step_rounds(&self.graphs, &mut c, &mut mine),
                Err(e) => {
                    for m in &mut mine {
                        m.failed = Some(format!("{e:#}"));
                    }
                }
            }
        }
        for m in mine {
            results[m.job] = Some(match m.failed {
                Some(e) => Err(anyhow!(e)),
                None => {
                    let mut steps = m.steps;
                    if let Some(total) = m.total {
                        cut_frames(&mut steps, total);
                    }
                    Ok(steps)
                }
            });
        }
        results
            .into_iter()
            .map(|r| r.unwrap_or_else(|| Err(anyhow!("the stream was not stepped"))))
            .collect()
    }
}

/// A stream of [`LiveGestureModel::step_many_steps`] with its completed tokens' mel blocks.
struct Pending<'a> {
    job: usize,
    key: u64,
    away: &'a mut bool,
    stream: &'a mut Stream,
    mels: VecDeque<Array2<f32>>,
    /// Frames that cover the input, when the job ends the stream.
    total: Option<u64>,
    steps: Vec<TokenStep>,
    failed: Option<String>,
}

/// Feeds a job's audio (and, ending it, the silence-completed last token) to the stream's frontend.
fn prepare(
    stream: &mut Stream,
    audio: &[f32],
    end: Option<AudioSpan>,
) -> Result<(VecDeque<Array2<f32>>, Option<u64>)> {
    ensure!(
        !stream.is_poisoned(),
        "the stream failed earlier; reset it before pushing more audio"
    );
    let mut mels: VecDeque<_> = stream.push_audio(audio)?.into();
    let mut total = None;
    if let Some(end) = end {
        match stream.finish_audio(end) {
            Ok((more, t)) => {
                mels.extend(more);
                total = Some(t);
            }
            Err(e) => {
                // the audio's tokens are in the frontend but will not be stepped
                if !mels.is_empty() {
                    stream.poisoned = true;
                }
                return Err(e);
            }
        }
    }
    Ok((mels, total))
}

/// Steps the streams' tokens in rounds, one token of every stream that has one per round.
fn step_rounds(p: &LiveGestureGraphs, c: &mut Cohorts, mine: &mut [Pending<'_>]) {
    loop {
        let mut owners = Vec::new();
        let mut blocks = Vec::new();
        let mut members: Vec<Member<'_>> = Vec::new();
        for (k, m) in mine.iter_mut().enumerate() {
            if m.failed.is_some() {
                continue;
            }
            if let Some(b) = m.mels.pop_front() {
                owners.push(k);
                blocks.push(b);
                members.push(Member {
                    key: m.key,
                    away: &mut *m.away,
                    stream: &mut *m.stream,
                });
            }
        }
        if members.is_empty() {
            return;
        }
        // whole cohorts step apart (`Cohorts::plan`); usually one group
        let keys: Vec<u64> = members.iter().map(|m| m.key).collect();
        let plan = c.plan(&keys);
        let mut blocks: Vec<Option<Array2<f32>>> = blocks.into_iter().map(Some).collect();
        let mut results: Vec<Option<Result<TokenStep, String>>> =
            (0..members.len()).map(|_| None).collect();
        let mut slots: Vec<Option<Member<'_>>> = members.into_iter().map(Some).collect();
        for group in plan {
            let mut part: Vec<Member<'_>> = group.iter().filter_map(|&i| slots[i].take()).collect();
            let part_blocks: Vec<Array2<f32>> =
                group.iter().filter_map(|&i| blocks[i].take()).collect();
            match c.step(p, &mut part, &part_blocks) {
                Ok(steps) => {
                    for (&i, st) in group.iter().zip(steps) {
                        results[i] = Some(Ok(st));
                    }
                }
                Err(e) => {
                    let msg = format!("{e:#}");
                    for &i in &group {
                        results[i] = Some(Err(msg.clone()));
                    }
                }
            }
        }
        drop(slots);
        for (k, r) in owners.into_iter().zip(results) {
            match r {
                Some(Ok(st)) => mine[k].steps.push(st),
                Some(Err(msg)) => mine[k].failed = Some(msg),
                None => mine[k].failed = Some("a stream was left out of its step".into()),
            }
        }
    }
}

/// One LiveGesture stream ([`MotionStream`]): a [`Stream`] and the model it steps on.
#[derive(Debug)]
pub struct LiveGestureStream {
    graphs: Arc<LiveGestureGraphs>,
    cohorts: Arc<Mutex<Cohorts>>,
    /// The stream's key in `cohorts`.
    key: u64,
    /// Its caches are in a cohort (its own are empty meanwhile).
    away: bool,
    stream: Stream,
    frames_per_token: u64,
}

impl Drop for LiveGestureStream {
    fn drop(&mut self) {
        if self.away {
            if let Ok(mut c) = self.cohorts.lock() {
                c.forget(self.key, &mut self.away);
            }
        }
    }
}

impl LiveGestureStream {
    /// The stream's LiveGesture state (tokens, options in use).
    pub fn stream(&self) -> &Stream {
        &self.stream
    }
}

impl MotionStream for LiveGestureStream {
    /// Audio that completes no token only fills the frontend (the caches may stay in their
    /// cohort); a token is stepped on the stream alone, its caches called home first.
    fn push_audio(&mut self, samples: &[f32]) -> Result<Vec<Frame>> {
        let g = &self.graphs;
        ensure!(
            !self.stream.is_poisoned(),
            "the stream failed earlier; reset it before pushing more audio"
        );
        let mels = self.stream.push_audio(samples)?;
        if mels.is_empty() {
            return Ok(Vec::new());
        }
        lock(&self.cohorts)?.recall(self.key, &mut self.away, &mut self.stream)?;
        let mut out = Vec::new();
        for m in &mels {
            out.extend(g.step(&mut self.stream, m)?.frames);
        }
        Ok(out)
    }

    fn finish(&mut self, input: AudioSpan) -> Result<Vec<Frame>> {
        lock(&self.cohorts)?.recall(self.key, &mut self.away, &mut self.stream)?;
        self.graphs.finish(&mut self.stream, input)
    }

    fn reset(&mut self) -> Result<()> {
        lock(&self.cohorts)?.forget(self.key, &mut self.away);
        self.graphs.reset(&mut self.stream)
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

    fn next_unit_samples(&self) -> u64 {
        self.stream.next_token_samples()
    }
}
