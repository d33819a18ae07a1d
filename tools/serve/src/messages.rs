//! The messages between a session's tasks ([`super::session`]) and the scheduler thread
//! ([`super::scheduler`]): commands in, frames and control messages out, the kill switch, and a
//! session's figures.

use std::sync::Arc;
use std::time::Instant;

use tokio::sync::{mpsc, oneshot, Notify, Semaphore};

use livegesture::audio::AudioSpan;
use livegesture::model::StreamOptions;
use livegesture::output::Frame;

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
