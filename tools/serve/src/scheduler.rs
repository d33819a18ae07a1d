//! The server's one scheduler: a thread that owns the [`MotionModel`] and one [`MotionStream`] per
//! session, and steps the sessions whose audio completes a unit (a LiveGesture token, a DiffSHEG
//! window) together, in one [`MotionModel::step_many`] call per tick. It never names a model family:
//! the model decides how the streams of a tick share their graph runs (LiveGesture: every graph once
//! per token for all of them; DiffSHEG: the due windows on the denoiser's batch axis).
//!
//! Sessions send 16 kHz mono audio ([`Cmd::Audio`]). Audio that does not complete the stream's next
//! unit ([`MotionStream::next_unit_samples`]) is pushed at once (it only fills the stream's buffers);
//! audio that does is held, and from then on the session is *due*. Ticks fall on a fixed grid, a
//! whole number of slots per token (slots of about `batch_wait`: 33.3 ms for 30 ms); a tick steps
//! every due session in one `step_many` call and queues the frames, and when every live session is
//! due it steps at once. A real-time session completes its tokens at a steady phase, so it falls in
//! the same slot tick after tick, with the same company: batches of the sessions of one slot, and
//! the model keeps the caches of sessions stepped together stacked between ticks.
//!
//! A session keeps its slot (its *home*, the slot of its last step) against the jitter of message
//! arrival: with 20 ms messages the audio completing a token arrives 0 to 13.3 ms after the token's
//! end, so a session whose phase lies near a slot boundary would fall on either side of it, token
//! by token, and each change of company copies its caches (1.7 MB for `models/default`) between
//! cohorts (measured: 11 % of a server's CPU at 48 sessions, docs/serve.md#capacity-per-core). A
//! session due one slot *before* its home therefore waits for its home slot (at most one slot
//! more); one due later moves its home there (it cannot step earlier), so a session's home settles
//! on the later side of its jitter and stays. A session due two or more slots from home (a client
//! that paused, or caught up) takes the slot it is due in. A tick steps the sessions whose slot has
//! come (or every due one when all are due): one due after the tick's grid point waits for its own.
//! A tick steps at most as many sessions as take about one and a half slots (the cost per session
//! measured on the last steps); the others stay due and step right after, so a server behind its
//! grid does not fall into one long step of every session per token.
//! A session's frames are therefore those it gets on its own: a stream is chunk-size invariant, and
//! batching changes only the backend's rounding (docs/parity.md).
//!
//! At the end of a session's audio ([`Cmd::End`]) the session is due at once; its job ends the stream
//! with the input's own span (docs/output.md: the last unit completed with silence, exactly
//! [`AudioSpan::frames`] frames), then `done` is sent. On shutdown ([`Cmd::Drain`]) the units whose
//! audio has arrived are stepped, a partial one is not, and the session is closed with 1001.
//!
//! From `COALESCE_FROM` (16) sessions on, the thread wakes only at the grid's points and takes the
//! messages that arrived since the last one together (each message used to wake it: thousands of
//! thread switches per second at 64 sessions); what steps when is unchanged, as a due session steps
//! at its grid point anyway. A join or a shutdown then waits for the next point (at most a slot).
//!
//! Back-pressure: a session's reader takes one credit per frontend token boundary its audio crosses;
//! the scheduler gives them back once that audio has been pushed into the stream, so at most
//! `max_pending_tokens` tokens' worth of a session's audio waits here.

use std::collections::HashMap;
use std::io::Write as _;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Result;
use tokio::sync::{mpsc, Semaphore};

use livegesture::audio::AudioSpan;
use livegesture::frontend::FrontendConfig;
use livegesture::model::{MotionModel, MotionStream, StreamJob, StreamOptions};
use livegesture::output::Frame;

mod grid;

use super::messages::{Cmd, Joined, Out, SessionCtl, SessionStats};
use super::metrics::Metrics;
use super::protocol::{CLOSE_GOING_AWAY, CLOSE_INTERNAL, CLOSE_POLICY};
use grid::{grid_after, slot_deadline, slot_index, slots_per_token, tick_slot};

/// From this many sessions on, the scheduler thread sleeps until the next point of the tick grid
/// and then takes every message that arrived meanwhile, instead of waking for each message (with 20
/// ms messages, 50 wake-ups per session per second: 3200 at 64 sessions, each a switch between
/// threads on a core the graphs need). Below it a due session still steps at once when every
/// session is due (a lone user waits for no grid point).
const COALESCE_FROM: usize = 16;

/// The fewest sessions a tick's cap ([`BatchScheduler::tick_cap`]) allows.
const MIN_TICK: usize = 8;

/// Scheduler settings.
#[derive(Debug, Clone)]
pub struct SchedConfig {
    /// About the slot of the tick grid: a due session waits at most this long for the sessions of
    /// its slot (the token divided into a whole number of slots; zero: it steps at once).
    pub batch_wait: Duration,
}

struct Sess {
    stream: Box<dyn MotionStream>,
    out: mpsc::Sender<Out>,
    ctl: Arc<SessionCtl>,
    credits: Arc<Semaphore>,
    stats: SessionStats,
    /// Audio held for the next tick (it completes a unit), in arrival order.
    held: Vec<f32>,
    /// When the session became due (the arrival of the audio completing a unit, or of the end).
    due_since: Option<Instant>,
    /// When a due session steps: the grid point of its slot (see the module docs).
    deadline: Option<Instant>,
    /// The slot of the token grid (`0 .. slots_per_token`) of the session's last step.
    home: Option<u64>,
    /// 16 kHz samples forwarded by the reader (pushed, held, or dropped after an end or a cut).
    samples_in: u64,
    /// 16 kHz samples pushed into the stream (or dropped): credits are given back for these.
    samples_done: u64,
    /// Frontend tokens of `samples_done` whose credits were given back.
    tokens_credited: u64,
    /// The end of the audio, once the client sent it.
    end: Option<AudioSpan>,
    draining: bool,
    frames_per_unit: u64,
    /// Finished or cut off: nothing more is pushed or sent; waits for its Leave.
    dead: bool,
}

/// The scheduler's own trace (`$LIVEGESTURE_SERVE_TRACE=FILE`, docs/serve.md#the-scheduler-trace):
/// one line per join and per tick, times in ms from the first join. Where a session's latency goes
/// on the scheduler thread: joining, pushing audio, waiting for a tick and the step itself.
struct Trace {
    out: std::io::BufWriter<std::fs::File>,
    t0: Option<Instant>,
    /// Since the last tick: time pushing audio that completes no unit, and its messages.
    audio: Duration,
    audio_msgs: u64,
}

impl Trace {
    fn from_env() -> Option<Trace> {
        let path = std::env::var_os("LIVEGESTURE_SERVE_TRACE")?;
        match std::fs::File::create(&path) {
            Ok(f) => {
                let mut out = std::io::BufWriter::new(f);
                let _ = writeln!(
                    out,
                    "# event t_ms dur_ms | tick: t_ms late_ms step_ms batch live wait_ms audio_ms audio_msgs"
                );
                Some(Trace {
                    out,
                    t0: None,
                    audio: Duration::ZERO,
                    audio_msgs: 0,
                })
            }
            Err(e) => {
                eprintln!(
                    "livegesture serve: LIVEGESTURE_SERVE_TRACE={}: cannot write it ({e}); no trace",
                    std::path::Path::new(&path).display()
                );
                None
            }
        }
    }

    fn ms(&self, t: Instant) -> f64 {
        self.t0.map_or(0.0, |t0| {
            t.saturating_duration_since(t0).as_secs_f64() * 1e3
        })
    }

    fn join(&mut self, at: Instant, took: Duration) {
        let t0 = *self.t0.get_or_insert(at);
        let _ = writeln!(
            self.out,
            "join {:.3} {:.3}",
            at.saturating_duration_since(t0).as_secs_f64() * 1e3,
            took.as_secs_f64() * 1e3
        );
    }
}

/// Steps the sessions' streams, due ones together (see the module docs).
pub struct BatchScheduler {
    trace: Option<Trace>,
    model: Box<dyn MotionModel>,
    /// The grid the sessions' readers take credits on (the bundle's frontend).
    frontend: FrontendConfig,
    sessions: HashMap<u64, Sess>,
    metrics: Arc<Metrics>,
    /// The tick grid: ticks fall on `epoch + k * slot`.
    epoch: Instant,
    slot: Duration,
    /// Slots per token: grid point `k` is slot `k % slots_per_token` of its token.
    slots_per_token: u64,
    /// A step's time per session (seconds; moving average of steps of at least 4 sessions).
    step_per_session: Option<f64>,
}

impl BatchScheduler {
    pub fn new(
        model: Box<dyn MotionModel>,
        frontend: FrontendConfig,
        metrics: Arc<Metrics>,
        cfg: SchedConfig,
    ) -> Self {
        let slot = tick_slot(&frontend, cfg.batch_wait);
        Self {
            trace: Trace::from_env(),
            model,
            sessions: HashMap::new(),
            metrics,
            slots_per_token: slots_per_token(&frontend, slot),
            step_per_session: None,
            slot,
            frontend,
            epoch: Instant::now(),
        }
    }

    /// When to step, once a session is due: at once when every live session is due, else at the
    /// earliest grid point among the due sessions' slots. `None`: nothing is due.
    fn due(&self) -> Option<(Instant, bool)> {
        let t0 = self
            .sessions
            .values()
            .filter(|s| !s.dead)
            .filter_map(|s| s.deadline)
            .min()?;
        let all = self
            .sessions
            .values()
            .all(|s| s.dead || s.due_since.is_some());
        Some((t0, all))
    }

    /// Handles every command already queued; false once every sender is gone.
    fn drain(&mut self, rx: &mut mpsc::Receiver<Cmd>) -> bool {
        loop {
            match rx.try_recv() {
                Ok(c) => self.handle(c),
                Err(mpsc::error::TryRecvError::Empty) => return true,
                Err(mpsc::error::TryRecvError::Disconnected) => return false,
            }
        }
    }

    /// The most sessions one tick steps: as many as take about one and a half slots at the measured
    /// cost per session (at least [`MIN_TICK`]; no bound without a grid or before a measurement).
    /// A server behind its grid would otherwise step every due session in one long step, and keep
    /// doing so, all its sessions then being due together: measured on tract at 32 sessions, one step
    /// of 120 ms per token, every frame waiting for it.
    fn tick_cap(&self) -> usize {
        match self.step_per_session {
            Some(per) if !self.slot.is_zero() && per > 0.0 => {
                ((1.5 * self.slot.as_secs_f64() / per) as usize).max(MIN_TICK)
            }
            _ => usize::MAX,
        }
    }

    /// Whether the thread wakes only at the grid's points (from [`COALESCE_FROM`] sessions on).
    fn coalesce(&self) -> bool {
        !self.slot.is_zero() && self.sessions.len() >= COALESCE_FROM
    }

    /// Makes a session due since `at`: it steps at the grid point of its slot given its home slot
    /// (`home`; none: the slot it is due in; see the module docs).
    fn make_due(&mut self, sid: u64, at: Instant, home: Option<u64>) {
        let deadline = slot_deadline(self.epoch, self.slot, self.slots_per_token, at, home);
        if let Some(s) = self.sessions.get_mut(&sid) {
            s.due_since = Some(at);
            s.deadline = Some(deadline);
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
            if self.coalesce() {
                // many sessions: wake at the grid's points, not for every message (module docs).
                // What arrived during the last step first: a session it made due may be due now
                // (sleeping to the next point with it unseen let a server behind its grid step
                // every session in one long step per token, measured on tract at 32 sessions)
                if !self.drain(&mut rx) {
                    return;
                }
                let now = Instant::now();
                let next = grid_after(self.epoch, self.slot, now);
                let wake = self.due().map_or(next, |(d, _)| d.min(next));
                if wake > now {
                    std::thread::sleep(wake - now);
                    if !self.drain(&mut rx) {
                        return;
                    }
                }
                if let Some((deadline, all_due)) = self.due() {
                    if all_due || Instant::now() >= deadline {
                        self.tick(deadline, all_due);
                    }
                }
                continue;
            }
            let cmd = match self.due() {
                None => match rx.blocking_recv() {
                    Some(c) => Some(c),
                    None => break,
                },
                Some((deadline, all_due)) => {
                    let now = Instant::now();
                    if all_due || now >= deadline {
                        // take whatever has already arrived without waiting, then step
                        match rx.try_recv() {
                            Ok(c) => Some(c),
                            Err(_) => {
                                self.tick(deadline, all_due);
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
                let t = Instant::now();
                let r = self.join(sid, &opts, out, ctl, credits);
                if let Some(tr) = &mut self.trace {
                    tr.join(t, t.elapsed());
                }
                let _ = reply.send(r.map_err(|e| format!("{e:#}")));
            }
            Cmd::Audio { sid, samples, at } => {
                let t = self.trace.is_some().then(Instant::now);
                self.audio(sid, samples, at);
                if let (Some(tr), Some(t)) = (&mut self.trace, t) {
                    tr.audio += t.elapsed();
                    tr.audio_msgs += 1;
                }
            }
            Cmd::End { sid, input } => self.end(sid, input),
            Cmd::Drain { sid } => {
                if let Some(s) = self.sessions.get_mut(&sid) {
                    s.draining = true;
                }
                self.close_if_complete(sid);
            }
            Cmd::Leave { sid, stats } => {
                if let Some(s) = self.sessions.remove(&sid) {
                    let _ = stats.send(s.stats);
                }
            }
        }
    }

    fn join(
        &mut self,
        sid: u64,
        opts: &StreamOptions,
        out: mpsc::Sender<Out>,
        ctl: Arc<SessionCtl>,
        credits: Arc<Semaphore>,
    ) -> Result<Joined> {
        let stream = livegesture::generate::new_stream(self.model.as_ref(), opts)?;
        let joined = Joined {
            guidance: stream.guidance(),
            frames_per_unit: stream.frames_per_unit(),
            lookahead_frames: stream.lookahead_frames(),
            // a fresh stream's next unit is its first: the audio the first frame waits for
            first_frame_samples_16k: stream.next_unit_samples(),
        };
        self.sessions.insert(
            sid,
            Sess {
                frames_per_unit: stream.frames_per_unit().max(1),
                stream,
                out,
                ctl,
                credits,
                stats: SessionStats::default(),
                held: Vec::new(),
                due_since: None,
                deadline: None,
                home: None,
                samples_in: 0,
                samples_done: 0,
                tokens_credited: 0,
                end: None,
                draining: false,
                dead: false,
            },
        );
        Ok(joined)
    }

    /// The client's audio: pushed at once when it completes no unit, else held for the next tick.
    fn audio(&mut self, sid: u64, samples: Vec<f32>, at: Instant) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        s.samples_in += samples.len() as u64;
        if s.dead || s.end.is_some() {
            s.samples_done = s.samples_in;
            self.give_credits(sid);
            return;
        }
        s.stats.samples_16k += samples.len() as u64;
        self.metrics
            .audio_samples_total
            .fetch_add(samples.len() as u64, Ordering::Relaxed);
        if s.due_since.is_none() && s.samples_in < s.stream.next_unit_samples() {
            // fills the stream's buffers only
            let r = s.stream.push_audio(&samples);
            s.samples_done = s.samples_in;
            match r {
                Ok(frames) => {
                    self.deliver(sid, frames, at);
                }
                Err(e) => {
                    let msg = format!("internal error in the audio frontend: {e:#}");
                    self.kill(sid, CLOSE_INTERNAL, msg);
                }
            }
            self.give_credits(sid);
        } else {
            s.held.extend_from_slice(&samples);
            if s.due_since.is_none() {
                let home = s.home;
                self.make_due(sid, at, home);
            }
        }
    }

    fn end(&mut self, sid: u64, input: AudioSpan) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        if s.dead || s.end.is_some() {
            return;
        }
        s.end = Some(input);
        if s.due_since.is_none() {
            // the end steps in the slot it arrives in (no company to keep after it)
            self.make_due(sid, Instant::now(), None);
        }
    }

    /// Gives back the credits of the session's audio that has been pushed (or dropped).
    fn give_credits(&mut self, sid: u64) {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return;
        };
        let tokens = self.frontend.n_tokens(s.samples_done);
        if tokens > s.tokens_credited {
            s.credits.add_permits((tokens - s.tokens_credited) as usize);
            s.tokens_credited = tokens;
        }
    }

    /// One [`MotionModel::step_many`] call for every session whose slot has come (`all`: every due
    /// session; `deadline`: the earliest of their grid points).
    fn tick(&mut self, deadline: Instant, all: bool) {
        let now = Instant::now();
        let (epoch, slot, n) = (self.epoch, self.slot, self.slots_per_token);
        // the sessions whose slot has come, the earliest first, at most `tick_cap` of them: the
        // others stay due and step right after (their frames do not wait for one long step)
        let mut ready: Vec<(Instant, u64)> = self
            .sessions
            .iter()
            .filter(|(_, s)| !s.dead && s.due_since.is_some())
            .map(|(sid, s)| (s.deadline.unwrap_or(now), *sid))
            .filter(|(at, _)| all || *at <= now)
            .collect();
        ready.sort_unstable();
        ready.truncate(self.tick_cap());
        let mut chosen: Vec<u64> = ready.iter().map(|r| r.1).collect();
        chosen.sort_unstable();
        let mut sids = Vec::new();
        let mut jobs = Vec::new();
        let mut homes = Vec::new();
        for (sid, s) in self.sessions.iter_mut() {
            if chosen.binary_search(sid).is_err() {
                continue;
            }
            let at = s.deadline.unwrap_or(now);
            homes.push(slot_index(epoch, slot, n, at));
            sids.push((
                *sid,
                s.due_since.unwrap_or_else(Instant::now),
                s.end.is_some(),
            ));
            jobs.push(StreamJob {
                stream: s.stream.as_mut(),
                audio: &s.held,
                end: s.end,
            });
        }
        if jobs.is_empty() {
            return;
        }
        let t0 = Instant::now();
        let results = self.model.step_many(&mut jobs);
        drop(jobs);
        let done = Instant::now();
        if let Some(tr) = &mut self.trace {
            let oldest = sids.iter().map(|s| s.1).min().unwrap_or(t0);
            let ms = |d: Duration| d.as_secs_f64() * 1e3;
            let _ = writeln!(
                tr.out,
                "tick {:.3} {:.3} {:.3} {} {} {:.3} {:.3} {}",
                tr.ms(t0),
                ms(t0.saturating_duration_since(deadline)),
                ms(done - t0),
                sids.len(),
                self.sessions.values().filter(|s| !s.dead).count(),
                ms(t0.saturating_duration_since(oldest)),
                ms(tr.audio),
                tr.audio_msgs
            );
            tr.audio = Duration::ZERO;
            tr.audio_msgs = 0;
            // a server killed hard keeps its trace so far
            let _ = tr.out.flush();
        }
        self.metrics.step_seconds.observe((done - t0).as_secs_f64());
        if sids.len() >= 4 {
            let per = (done - t0).as_secs_f64() / sids.len() as f64;
            self.step_per_session =
                Some(self.step_per_session.map_or(per, |e| 0.9 * e + 0.1 * per));
        }
        self.metrics.steps_total.fetch_add(1, Ordering::Relaxed);
        self.metrics.batch_size.observe(sids.len() as f64);
        self.metrics
            .streams_regrouped_total
            .store(self.model.streams_regrouped(), Ordering::Relaxed);
        for (((sid, at, ended), r), home) in sids.into_iter().zip(results).zip(homes) {
            let Some(s) = self.sessions.get_mut(&sid) else {
                continue;
            };
            s.held.clear();
            s.due_since = None;
            s.deadline = None;
            s.home = Some(home);
            s.samples_done = s.samples_in;
            self.give_credits(sid);
            match r {
                Ok(frames) => {
                    if !self.deliver(sid, frames, at) {
                        continue;
                    }
                    if ended {
                        let frames = self.sessions.get(&sid).map_or(0, |s| s.stats.frames);
                        self.send_last(sid, Out::Done { frames });
                    } else {
                        self.close_if_complete(sid);
                    }
                }
                Err(e) => {
                    let m = format!("internal error in a graph run: {e:#}");
                    eprintln!("livegesture serve: session {sid}: {m}");
                    self.kill(sid, CLOSE_INTERNAL, m);
                }
            }
        }
    }

    /// Queues `frames` (of audio that arrived at `at`); a full queue is a slow client, cut off
    /// (returns false).
    fn deliver(&mut self, sid: u64, frames: Vec<Frame>, at: Instant) -> bool {
        let Some(s) = self.sessions.get_mut(&sid) else {
            return false;
        };
        if frames.is_empty() || s.dead {
            return !s.dead;
        }
        let latency = Instant::now().saturating_duration_since(at).as_secs_f64();
        let units = (frames.len() as u64).div_ceil(s.frames_per_unit);
        s.stats.tokens += units;
        self.metrics
            .tokens_total
            .fetch_add(units, Ordering::Relaxed);
        s.stats.latencies.push(latency);
        self.metrics.token_latency_seconds.observe(latency);
        let mut full = false;
        for f in frames {
            if s.out.try_send(Out::Frame(Box::new(f))).is_err() {
                full = true;
                break;
            }
            s.stats.frames += 1;
            self.metrics.frames_total.fetch_add(1, Ordering::Relaxed);
        }
        if full {
            self.cut_slow(sid);
        }
        !full
    }

    /// On shutdown: close 1001 once nothing whose audio has arrived is left to step.
    fn close_if_complete(&mut self, sid: u64) {
        let Some(s) = self.sessions.get(&sid) else {
            return;
        };
        if s.dead || !s.draining || s.due_since.is_some() {
            return;
        }
        self.send_last(
            sid,
            Out::Close(CLOSE_GOING_AWAY, "server shutting down".into()),
        );
    }

    /// Queues the session's last message (done, or close 1001 on shutdown) and retires it; a full
    /// queue is a slow client, cut off.
    fn send_last(&mut self, sid: u64, msg: Out) {
        let sent = self
            .sessions
            .get(&sid)
            .is_some_and(|s| s.out.try_send(msg).is_ok());
        if sent {
            self.retire(sid);
        } else {
            self.cut_slow(sid);
        }
    }

    /// Nothing more is pushed or sent for the session; it waits for its Leave.
    fn retire(&mut self, sid: u64) {
        if let Some(s) = self.sessions.get_mut(&sid) {
            s.dead = true;
            s.held = Vec::new();
            s.due_since = None;
            s.deadline = None;
            s.samples_done = s.samples_in;
        }
        self.give_credits(sid);
    }

    /// Cuts a session short: its writer closes with `code` and `reason`.
    fn kill(&mut self, sid: u64, code: u16, reason: String) {
        self.retire(sid);
        if let Some(s) = self.sessions.get(&sid) {
            s.ctl.kill(code, reason);
        }
    }

    /// A client whose outbound queue is full: counted (`livegesture_refusals_total{reason="slow_client"}`), closed 1008.
    fn cut_slow(&mut self, sid: u64) {
        self.metrics.refuse("slow_client");
        self.kill(
            sid,
            CLOSE_POLICY,
            "client too slow: its outbound frame queue is full".into(),
        );
    }
}

/// Steps `n` throw-away streams (default options) together through two units of silence in
/// [`MotionModel::step_many`] calls, then drops them (0: nothing). A fresh server's first burst of
/// sessions otherwise spends its first second touching memory for the first time (the stacked
/// caches of its cohorts and the backend's buffers for their batch sizes: page faults, measured
/// in docs/serve.md#the-start-up-transient) while its sessions wait; this touches it before the
/// first session. A pure function of nothing the sessions see: their frames are unchanged.
pub fn warm_up(model: &dyn MotionModel, n: usize) -> Result<()> {
    if n == 0 {
        return Ok(());
    }
    let mut streams = (0..n)
        .map(|_| livegesture::generate::new_stream(model, &StreamOptions::default()))
        .collect::<Result<Vec<_>>>()?;
    for _ in 0..2 {
        let audio: Vec<Vec<f32>> = streams
            .iter()
            .map(|s| {
                let need = s.next_unit_samples().saturating_sub(s.samples_received());
                vec![0.0; need as usize]
            })
            .collect();
        let mut jobs: Vec<StreamJob<'_>> = streams
            .iter_mut()
            .zip(&audio)
            .map(|(s, a)| StreamJob {
                stream: s.as_mut(),
                audio: a,
                end: None,
            })
            .collect();
        for r in model.step_many(&mut jobs) {
            r?;
        }
    }
    Ok(())
}
