//! The token scheduler of LiveGesture bundles: one thread owns the [`Pipeline`] and a [`StreamBatch`],
//! and steps every session that has a complete token in one batched run per graph per token tick.
//! (Other families: [`super::streams::StreamScheduler`], one stream per session, no batching.)
//!
//! Sessions send 16 kHz mono audio ([`Cmd::Audio`]); the scheduler runs each session's log-mel
//! frontend and queues the mel block of every completed token. A tick starts when the oldest queued
//! token has waited `batch_wait`, or at once when every session has a token queued; it steps all
//! sessions with a queued token together (sessions without one are parked outside the batch with
//! their caches, and come back when they have one). A session's tokens are therefore exactly those it
//! gets stepped alone.
//!
//! At the end of a session's audio ([`Cmd::End`]) the stream's own end rule applies, the one
//! `generate` and `stream` use (docs/output.md, [`StreamBatch::finish_audio`] / [`Stream::finish_audio`]):
//! the last partial token is completed with silence and frames at or past
//! [`AudioSpan::frames`] = `ceil(n_in * 30 / rate_in)` are dropped.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Result;
use ndarray::Array2;
use tokio::sync::{mpsc, oneshot, Notify, Semaphore};

use crate::audio::AudioSpan;
use crate::model::livegesture::{Pipeline, Stream, StreamBatch, StreamId, StreamOptions};
use crate::output::Frame;

use super::metrics::Metrics;
use super::protocol::{CLOSE_GOING_AWAY, CLOSE_INTERNAL, CLOSE_POLICY};

/// What the scheduler sends a session's writer.
#[derive(Debug)]
pub enum Out {
    Frame(Box<Frame>),
    /// All frames sent: `{"type":"done","frames":N}`, then close 1000.
    Done {
        frames: u64,
    },
    /// Close with this code and reason.
    Close(u16, String),
}

/// Shared between a session's tasks and the scheduler: how to cut the session short.
#[derive(Debug, Default)]
pub struct SessionCtl {
    kill: std::sync::Mutex<Option<(u16, String)>>,
    pub notify: Notify,
}

impl SessionCtl {
    /// Asks the session's writer to close with `code` and `reason` (the first request wins).
    pub fn kill(&self, code: u16, reason: String) {
        let mut k = self.kill.lock().unwrap_or_else(|e| e.into_inner());
        if k.is_none() {
            *k = Some((code, reason));
        }
        drop(k);
        self.notify.notify_one();
    }

    pub fn take_kill(&self) -> Option<(u16, String)> {
        self.kill.lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// Figures of a session when it ends (for its log line).
#[derive(Debug, Clone, Default)]
pub struct SessionStats {
    pub tokens: u64,
    pub frames: u64,
    /// 16 kHz samples received from the client (without the end-of-stream silence).
    pub samples_16k: u64,
    /// Token latencies in seconds (message completing the token's audio -> frames queued).
    pub latencies: Vec<f64>,
}

/// Accounts one produced unit (a token, or a DiffSHEG window) of a session that took `latency_s` from the
/// audio completing it, and queues its `frames`. Returns false when the session's queue is full (a client
/// that does not read): the caller cuts it.
pub(super) fn deliver_unit(
    stats: &mut SessionStats,
    out: &mpsc::Sender<Out>,
    metrics: &Metrics,
    latency_s: f64,
    frames: impl IntoIterator<Item = Frame>,
) -> bool {
    stats.tokens += 1;
    metrics.tokens_total.fetch_add(1, Ordering::Relaxed);
    stats.latencies.push(latency_s);
    metrics.token_latency_seconds.observe(latency_s);
    for f in frames {
        if out.try_send(Out::Frame(Box::new(f))).is_err() {
            return false;
        }
        stats.frames += 1;
        metrics.frames_total.fetch_add(1, Ordering::Relaxed);
    }
    true
}

/// What a joining session gets back.
#[derive(Debug, Clone)]
pub struct Joined {
    pub guidance: f64,
    /// Frames emitted together (LiveGesture: a token, 4; DiffSHEG: a window step, N - L).
    pub frames_per_unit: u64,
    /// Audio, in frames, a unit waits for past its own end (LiveGesture 0; DiffSHEG the overlap L).
    pub lookahead_frames: u64,
    /// 16 kHz samples the first frame waits for (LiveGesture: the first token's audio span; DiffSHEG:
    /// the first window's N frames).
    pub first_frame_samples_16k: u64,
}

/// Commands from sessions to the scheduler.
#[derive(Debug)]
pub enum Cmd {
    Join {
        sid: u64,
        opts: StreamOptions,
        out: mpsc::Sender<Out>,
        ctl: Arc<SessionCtl>,
        credits: Arc<Semaphore>,
        reply: oneshot::Sender<Result<Joined, String>>,
    },
    /// 16 kHz mono samples; `at` is when the message carrying them arrived.
    Audio {
        sid: u64,
        samples: Vec<f32>,
        at: Instant,
    },
    /// The end of the audio: the client's samples per channel at its own rate (the motion covers
    /// [`AudioSpan::frames`] = ceil(n_in * 30 / rate_in) frames).
    End { sid: u64, input: AudioSpan },
    /// Shutdown: step the tokens whose audio has arrived, then close 1001.
    Drain { sid: u64 },
    /// The client is gone (or was refused): drop the session; `stats` gets its figures.
    Leave {
        sid: u64,
        stats: oneshot::Sender<SessionStats>,
    },
}

struct Sess {
    /// The session's place in the batch, or its stream parked outside it (exactly one is set).
    id: Option<StreamId>,
    parked: Option<Box<Stream>>,
    out: mpsc::Sender<Out>,
    ctl: Arc<SessionCtl>,
    credits: Arc<Semaphore>,
    /// Mel blocks of the completed tokens not stepped yet, with the arrival of the audio completing them.
    pending: VecDeque<(Array2<f32>, Instant)>,
    stats: SessionStats,
    end_frames: Option<u64>,
    draining: bool,
    /// Finished or cut off: nothing more is stepped or sent; waits for its Leave.
    dead: bool,
}

/// Scheduler settings.
#[derive(Debug, Clone)]
pub struct SchedConfig {
    /// How long the oldest queued token waits for others to join its step.
    pub batch_wait: Duration,
}

pub struct Scheduler {
    pipeline: Pipeline,
    batch: StreamBatch,
    sessions: HashMap<u64, Sess>,
    by_stream: HashMap<StreamId, u64>,
    metrics: Arc<Metrics>,
    cfg: SchedConfig,
}

impl Scheduler {
    pub fn new(pipeline: Pipeline, metrics: Arc<Metrics>, cfg: SchedConfig) -> Self {
        let batch = pipeline.new_batch();
        Self {
            pipeline,
            batch,
            sessions: HashMap::new(),
            by_stream: HashMap::new(),
            metrics,
            cfg,
        }
    }

    /// Runs until every command sender is dropped.
    pub fn run(mut self, mut rx: mpsc::Receiver<Cmd>) {
        let rt = match tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
        {
            Ok(rt) => rt,
            Err(e) => {
                eprintln!("livegesture serve: scheduler: cannot build its timer runtime: {e}");
                return;
            }
        };
        loop {
            let oldest = self
                .sessions
                .values()
                .filter(|s| !s.dead)
                .filter_map(|s| s.pending.front().map(|p| p.1))
                .min();
            let cmd = match oldest {
                None => match rx.blocking_recv() {
                    Some(c) => Some(c),
                    None => break,
                },
                Some(t0) => {
                    let all_ready = self
                        .sessions
                        .values()
                        .all(|s| s.dead || !s.pending.is_empty());
                    let deadline = t0 + self.cfg.batch_wait;
                    let now = Instant::now();
                    if all_ready || now >= deadline {
                        // take whatever has already arrived without waiting, then step
                        match rx.try_recv() {
                            Ok(c) => Some(c),
                            Err(_) => {
                                self.tick();
                                continue;
                            }
                        }
                    } else {
                        match rt.block_on(async {
                            tokio::time::timeout(deadline - now, rx.recv()).await
                        }) {
                            Ok(Some(c)) => Some(c),
                            Ok(None) => break,
                            Err(_) => None,
                        }
                    }
                }
            };
            if let Some(c) = cmd {
                self.handle(c);
            }
        }
    }
}

impl SessionTable for Scheduler {
    fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    fn out(&self, sid: u64) -> Option<&mpsc::Sender<Out>> {
        self.sessions.get(&sid).map(|s| &s.out)
    }

    fn join(&mut self, sid: u64, opts: &StreamOptions, link: SessionLink) -> Result<Joined> {
        let SessionLink { out, ctl, credits } = link;
        let frames_per_unit = self.pipeline.frontend().frames_per_token;
        let first_frame_samples_16k = self.pipeline.frontend().token_end(0);
        self.pipeline.new_stream(opts).map(|st| {
            let guidance = st.guidance();
            self.sessions.insert(
                sid,
                Sess {
                    id: None,
                    parked: Some(Box::new(st)),
                    out,
                    ctl,
                    credits,
                    pending: VecDeque::new(),
                    stats: SessionStats::default(),
                    end_frames: None,
                    draining: false,
                    dead: false,
                },
            );
            Joined {
                guidance,
                frames_per_unit,
                lookahead_frames: 0,
                first_frame_samples_16k,
            }
        })
    }

    /// Feeds a session's frontend with the client's audio.
    fn push(&mut self, sid: u64, samples: &[f32], at: Instant) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        if s.dead || s.end_frames.is_some() {
            return;
        }
        let r = match (s.id, s.parked.as_mut()) {
            (Some(id), _) => self.batch.push_audio(id, samples),
            (None, Some(st)) => st.push_audio(samples),
            (None, None) => return,
        };
        s.stats.samples_16k += samples.len() as u64;
        self.metrics
            .audio_samples_total
            .fetch_add(samples.len() as u64, Ordering::Relaxed);
        match r {
            Ok(mels) => s.pending.extend(mels.into_iter().map(|m| (m, at))),
            Err(e) => {
                let msg = format!("internal error in the audio frontend: {e:#}");
                self.kill(sid, CLOSE_INTERNAL, msg);
            }
        }
    }

    fn end(&mut self, sid: u64, input: AudioSpan) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        if s.dead || s.end_frames.is_some() {
            return;
        }
        // docs/output.md, the streams' own rule: the last partial token completed with silence,
        // the frame count from the input's own samples and rate
        let r = match (s.id, s.parked.as_mut()) {
            (Some(id), _) => self.batch.finish_audio(id, input),
            (None, Some(st)) => st.finish_audio(input),
            (None, None) => return,
        };
        match r {
            Ok((mels, total)) => {
                s.end_frames = Some(total);
                let at = Instant::now();
                s.pending.extend(mels.into_iter().map(|m| (m, at)));
                self.finish_if_complete(sid);
            }
            Err(e) => {
                let msg = format!("internal error at the end of the audio: {e:#}");
                self.kill(sid, CLOSE_INTERNAL, msg);
            }
        }
    }

    fn drain(&mut self, sid: u64) {
        if let Some(s) = self.sessions.get_mut(&sid) {
            s.draining = true;
        }
        self.finish_if_complete(sid);
    }

    fn leave(&mut self, sid: u64) -> Option<SessionStats> {
        self.retire(sid);
        self.sessions.remove(&sid).map(|s| s.stats)
    }

    /// Takes the session's stream out of the batch; nothing more is stepped or sent for it.
    fn retire(&mut self, sid: u64) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        s.dead = true;
        s.pending.clear();
        if let Some(id) = s.id.take() {
            self.by_stream.remove(&id);
            match self.batch.remove(id) {
                Ok(st) => s.parked = Some(Box::new(st)),
                Err(e) => eprintln!("livegesture serve: session {sid}: leaving the batch: {e:#}"),
            }
        }
    }

    /// Cuts a session short: its writer closes with `code` and `reason`.
    fn kill(&mut self, sid: u64, code: u16, reason: String) {
        self.retire(sid);
        if let Some(s) = self.sessions.get(&sid) {
            s.ctl.kill(code, reason);
        }
    }
}

impl Scheduler {
    /// Sends done (or, draining, close 1001) when the session has nothing left to step.
    fn finish_if_complete(&mut self, sid: u64) {
        let Some(s) = self.sessions.get(&sid) else {
            return;
        };
        if s.dead || !s.pending.is_empty() {
            return;
        }
        let msg = if let Some(frames) = s.end_frames {
            Out::Done {
                frames: s.stats.frames.min(frames),
            }
        } else if s.draining {
            Out::Close(CLOSE_GOING_AWAY, "server shutting down".into())
        } else {
            return;
        };
        self.send_last(sid, msg);
    }

    /// One batched step of every session with a queued token.
    fn tick(&mut self) {
        let sids: Vec<u64> = self.sessions.keys().copied().collect();
        // sessions without a queued token leave the batch (their caches parked with them) ...
        for sid in &sids {
            let s = self.sessions.get_mut(sid).expect("session");
            if !s.dead && !s.pending.is_empty() {
                continue;
            }
            if let Some(id) = s.id.take() {
                self.by_stream.remove(&id);
                match self.batch.remove(id) {
                    Ok(st) => s.parked = Some(Box::new(st)),
                    Err(e) => {
                        let m = format!("internal error: {e:#}");
                        self.kill(*sid, CLOSE_INTERNAL, m);
                    }
                }
            }
        }
        // ... and those with one join it
        for sid in &sids {
            let s = self.sessions.get_mut(sid).expect("session");
            if s.dead || s.pending.is_empty() || s.id.is_some() {
                continue;
            }
            let Some(st) = s.parked.take() else { continue };
            match self.batch.add(*st) {
                Ok(id) => {
                    s.id = Some(id);
                    self.by_stream.insert(id, *sid);
                }
                Err(e) => {
                    let m = format!("internal error: {e:#}");
                    self.kill(*sid, CLOSE_INTERNAL, m);
                }
            }
        }
        let order = self.batch.ids();
        if order.is_empty() {
            return;
        }
        let mut mels = Vec::with_capacity(order.len());
        let mut owners = Vec::with_capacity(order.len());
        for id in &order {
            let sid = self.by_stream[id];
            let s = self.sessions.get_mut(&sid).expect("session");
            let (m, at) = s.pending.pop_front().expect("a ready session has a token");
            mels.push(m);
            owners.push((sid, at));
        }
        let t0 = Instant::now();
        let r = self.pipeline.step_stream_batch(&mut self.batch, &mels);
        let done = Instant::now();
        self.metrics.step_seconds.observe((done - t0).as_secs_f64());
        self.metrics.steps_total.fetch_add(1, Ordering::Relaxed);
        self.metrics.batch_size.observe(order.len() as f64);
        match r {
            Ok(steps) => {
                for ((sid, at), step) in owners.into_iter().zip(steps) {
                    let Some(s) = self.sessions.get_mut(&sid) else {
                        continue;
                    };
                    s.credits.add_permits(1);
                    let end = s.end_frames;
                    let frames = step
                        .frames
                        .into_iter()
                        .filter(|f| end.is_none_or(|n| f.index < n));
                    let sent = deliver_unit(
                        &mut s.stats,
                        &s.out,
                        &self.metrics,
                        (done - at).as_secs_f64(),
                        frames,
                    );
                    if !sent {
                        self.cut_slow(sid);
                    } else {
                        self.finish_if_complete(sid);
                    }
                }
            }
            Err(e) => {
                let m = format!("internal error in a graph run: {e:#}");
                eprintln!("livegesture serve: {m}");
                for (sid, _) in owners {
                    self.kill(sid, CLOSE_INTERNAL, m.clone());
                }
            }
        }
    }
}

/// A joining session's outbound queue, kill switch and credits (from [`Cmd::Join`]).
pub(super) struct SessionLink {
    pub out: mpsc::Sender<Out>,
    pub ctl: Arc<SessionCtl>,
    pub credits: Arc<Semaphore>,
}

/// The session commands as both schedulers handle them: [`Scheduler`] (LiveGesture, batched steps)
/// and [`super::streams::StreamScheduler`] (one stream per session) implement the per-session parts;
/// the dispatch, a session's last message and the cut-off of a slow client are shared.
pub(super) trait SessionTable {
    fn metrics(&self) -> &Metrics;
    /// The session's outbound queue (None: no such session).
    fn out(&self, sid: u64) -> Option<&mpsc::Sender<Out>>;
    /// Opens the session's stream and registers it.
    fn join(&mut self, sid: u64, opts: &StreamOptions, link: SessionLink) -> Result<Joined>;
    /// The client's audio (16 kHz mono), arrived at `at`.
    fn push(&mut self, sid: u64, samples: &[f32], at: Instant);
    /// The end of the audio (docs/output.md): the stream's own end rule, then done.
    fn end(&mut self, sid: u64, input: AudioSpan);
    /// Shutdown: what has arrived is stepped, then close 1001.
    fn drain(&mut self, sid: u64);
    /// Drops the session; its figures.
    fn leave(&mut self, sid: u64) -> Option<SessionStats>;
    /// Nothing more is stepped or sent for the session; it waits for its Leave.
    fn retire(&mut self, sid: u64);
    /// Cuts a session short: its writer closes with `code` and `reason`.
    fn kill(&mut self, sid: u64, code: u16, reason: String);

    fn handle(&mut self, cmd: Cmd) {
        match cmd {
            Cmd::Join {
                sid,
                opts,
                out,
                ctl,
                credits,
                reply,
            } => {
                let r = self.join(sid, &opts, SessionLink { out, ctl, credits });
                let _ = reply.send(r.map_err(|e| format!("{e:#}")));
            }
            Cmd::Audio { sid, samples, at } => self.push(sid, &samples, at),
            Cmd::End { sid, input } => self.end(sid, input),
            Cmd::Drain { sid } => self.drain(sid),
            Cmd::Leave { sid, stats } => {
                if let Some(s) = self.leave(sid) {
                    let _ = stats.send(s);
                }
            }
        }
    }

    /// Queues the session's last message (done, or close 1001 on shutdown) and retires it; a full
    /// queue is a slow client, cut off.
    fn send_last(&mut self, sid: u64, msg: Out) {
        let sent = self.out(sid).is_some_and(|o| o.try_send(msg).is_ok());
        if sent {
            self.retire(sid);
        } else {
            self.cut_slow(sid);
        }
    }

    /// A client whose outbound queue is full: counted (`livegesture_refusals_total{reason="slow_client"}`), closed 1008.
    fn cut_slow(&mut self, sid: u64) {
        self.metrics().refuse("slow_client");
        self.kill(sid, CLOSE_POLICY, slow_reason());
    }
}

fn slow_reason() -> String {
    "client too slow: its outbound frame queue is full".into()
}
