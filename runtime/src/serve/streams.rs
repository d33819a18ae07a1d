//! The per-session scheduler: one thread owns a [`MotionModel`] and one [`MotionStream`] per session,
//! and steps each session on its own, in the order its audio arrives. It serves the families without
//! a cross-stream batched step (DiffSHEG: FOPPAS windows; see `docs/serve.md`); LiveGesture bundles
//! keep the batched [`super::scheduler::Scheduler`].
//!
//! A session's audio ([`Cmd::Audio`]) is pushed into its stream at once; every window (unit) the
//! audio completes runs inside that push, and its frames are queued for sending as soon as the push
//! returns. So a session's frames are exactly those of `generate` on the same audio and seed, whatever
//! the message split: the stream sees the same samples in the same order (a [`MotionStream`] is
//! chunk-size invariant). Sessions are stepped one after another on this thread (the model's graphs
//! run one call at a time anyway: [`MotionModel`] implementations share their runners behind a
//! lock); a session whose window is running delays the others by that window's sampling time.
//!
//! At the end of the audio ([`Cmd::End`]) the stream's own end rule applies ([`MotionStream::finish`],
//! docs/output.md): the last window runs on audio padded with silence and the motion covers exactly
//! [`AudioSpan::frames`] frames. On shutdown ([`Cmd::Drain`]) the windows whose audio has arrived have
//! already run (their frames are queued before the drain is handled, commands are in order); the
//! partial window is not run, and the session is closed with 1001.
//!
//! Back-pressure uses the same credits as the batched scheduler: the session's reader takes one per
//! frontend token boundary its audio crosses; this scheduler gives them back once that audio has been
//! pushed, so at most `max_pending_tokens` tokens' worth of a session's audio waits in the command
//! queue.

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use tokio::sync::{mpsc, Semaphore};

use crate::audio::AudioSpan;
use crate::frontend::FrontendConfig;
use crate::model::{MotionModel, MotionStream, StreamOptions};
use crate::output::Frame;

use super::metrics::Metrics;
use super::protocol::{CLOSE_GOING_AWAY, CLOSE_INTERNAL};
use super::scheduler::{
    deliver_unit, Cmd, Joined, Out, SessionCtl, SessionLink, SessionStats, SessionTable,
};

struct Sess {
    stream: Box<dyn MotionStream>,
    out: mpsc::Sender<Out>,
    ctl: Arc<SessionCtl>,
    credits: Arc<Semaphore>,
    stats: SessionStats,
    /// 16 kHz samples forwarded by the session's reader (also those not pushed: after an end or a cut).
    samples_in: u64,
    /// Frontend tokens of `samples_in` (credits given back for them).
    tokens_in: u64,
    ended: bool,
    /// Finished or cut off: nothing more is pushed or sent; waits for its Leave.
    dead: bool,
}

/// Steps every session's own [`MotionStream`] (see the module docs).
pub struct StreamScheduler {
    model: Box<dyn MotionModel>,
    frontend: FrontendConfig,
    sessions: HashMap<u64, Sess>,
    metrics: Arc<Metrics>,
}

impl StreamScheduler {
    /// `frontend` is the grid the sessions' readers take credits on (the bundle's frontend).
    pub fn new(
        model: Box<dyn MotionModel>,
        frontend: FrontendConfig,
        metrics: Arc<Metrics>,
    ) -> Self {
        Self {
            model,
            frontend,
            sessions: HashMap::new(),
            metrics,
        }
    }

    /// Runs until every command sender is dropped.
    pub fn run(mut self, mut rx: mpsc::Receiver<Cmd>) {
        while let Some(c) = rx.blocking_recv() {
            self.handle(c);
        }
    }

    /// Queues `frames` (from a push or finish that started at `t0`, on audio that arrived at `at`).
    fn emit(&mut self, sid: u64, frames: Vec<Frame>, t0: Instant, at: Instant) {
        if frames.is_empty() {
            return;
        }
        let done = Instant::now();
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        self.metrics.step_seconds.observe((done - t0).as_secs_f64());
        self.metrics.steps_total.fetch_add(1, Ordering::Relaxed);
        self.metrics.batch_size.observe(1.0);
        if !deliver_unit(
            &mut s.stats,
            &s.out,
            &self.metrics,
            (done - at).as_secs_f64(),
            frames,
        ) {
            self.cut_slow(sid);
        }
    }

    /// After `finish`: `{"type":"done"}`, then close 1000.
    fn finish(&mut self, sid: u64) {
        let Some(s) = self.sessions.get(&sid) else {
            return;
        };
        if s.dead {
            return;
        }
        let msg = Out::Done {
            frames: s.stats.frames,
        };
        self.send_last(sid, msg);
    }
}

impl SessionTable for StreamScheduler {
    fn metrics(&self) -> &Metrics {
        &self.metrics
    }

    fn out(&self, sid: u64) -> Option<&mpsc::Sender<Out>> {
        self.sessions.get(&sid).map(|s| &s.out)
    }

    fn join(&mut self, sid: u64, opts: &StreamOptions, link: SessionLink) -> Result<Joined> {
        let SessionLink { out, ctl, credits } = link;
        let f = &self.frontend;
        self.model.new_stream(opts).map(|st| {
            // the first unit leaves once the audio reaches `lookahead_frames` past its end
            let first = st.frames_per_unit() + st.lookahead_frames();
            let joined = Joined {
                guidance: st.guidance(),
                frames_per_unit: st.frames_per_unit(),
                lookahead_frames: st.lookahead_frames(),
                first_frame_samples_16k: first * f.sample_rate / f.fps.max(1),
            };
            self.sessions.insert(
                sid,
                Sess {
                    stream: st,
                    out,
                    ctl,
                    credits,
                    stats: SessionStats::default(),
                    samples_in: 0,
                    tokens_in: 0,
                    ended: false,
                    dead: false,
                },
            );
            joined
        })
    }

    /// Pushes a session's audio into its stream and sends the frames of the windows it completes.
    fn push(&mut self, sid: u64, samples: &[f32], at: Instant) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        // the reader took a credit for every token boundary this audio crosses: give them back
        s.samples_in += samples.len() as u64;
        let tokens = self.frontend.n_tokens(s.samples_in);
        if tokens > s.tokens_in {
            s.credits.add_permits((tokens - s.tokens_in) as usize);
            s.tokens_in = tokens;
        }
        if s.dead || s.ended {
            return;
        }
        let t0 = Instant::now();
        let r = s.stream.push_audio(samples);
        s.stats.samples_16k += samples.len() as u64;
        self.metrics
            .audio_samples_total
            .fetch_add(samples.len() as u64, Ordering::Relaxed);
        match r {
            Ok(frames) => self.emit(sid, frames, t0, at),
            Err(e) => {
                let msg = format!("internal error in a graph run: {e:#}");
                eprintln!("livegesture serve: session {sid}: {msg}");
                self.kill(sid, CLOSE_INTERNAL, msg);
            }
        }
    }

    fn end(&mut self, sid: u64, input: AudioSpan) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        if s.dead || s.ended {
            return;
        }
        s.ended = true;
        let t0 = Instant::now();
        let r = s.stream.finish(input);
        match r {
            Ok(frames) => {
                self.emit(sid, frames, t0, t0);
                self.finish(sid);
            }
            Err(e) => {
                let msg = format!("internal error at the end of the audio: {e:#}");
                self.kill(sid, CLOSE_INTERNAL, msg);
            }
        }
    }

    fn drain(&mut self, sid: u64) {
        // every window whose audio arrived has run (Audio commands come first); the
        // partial one is not run
        let Some(s) = self.sessions.get(&sid) else {
            return;
        };
        if s.dead || s.ended {
            return;
        }
        self.send_last(
            sid,
            Out::Close(CLOSE_GOING_AWAY, "server shutting down".into()),
        );
    }

    fn leave(&mut self, sid: u64) -> Option<SessionStats> {
        self.sessions.remove(&sid).map(|s| s.stats)
    }

    fn retire(&mut self, sid: u64) {
        if let Some(s) = self.sessions.get_mut(&sid) {
            s.dead = true;
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
