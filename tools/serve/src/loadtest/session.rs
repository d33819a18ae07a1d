//! One load-test session: a WebSocket client that streams speech in real time and measures the
//! latency of every unit (a LiveGesture token, a DiffSHEG window step) it gets back.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::Message;

/// 16 kHz: the rate the sessions send at (`rate=16000&format=s16le&channels=1`).
pub const RATE: u64 = 16000;

/// What one session is asked to do.
#[derive(Debug, Clone)]
pub struct SessionPlan {
    /// `ws://host:port` (the `/v1/stream` path and the query are added).
    pub url: String,
    /// `Authorization: Bearer` token, if the server wants one.
    pub token: Option<String>,
    /// 16 kHz mono samples to send, in real time.
    pub audio: Arc<Vec<i16>>,
    /// Samples per message.
    pub chunk: usize,
    /// Wait this long before connecting (spreads the sessions' phases).
    pub delay: Duration,
    pub seed: u64,
    /// `output=binary` (else `json`).
    pub binary: bool,
    /// Give up (session failed: "hung") after this long in all.
    pub timeout: Duration,
}

/// What one session measured.
#[derive(Debug, Default, Clone)]
pub struct SessionResult {
    /// Unit latencies: from sending the message that completed a unit's audio to receiving the
    /// unit's last frame.
    pub latencies_ms: Vec<f64>,
    /// For each latency: when its unit's completing message was sent, in seconds after the
    /// session's first audio message (the first second of a session is its start-up).
    pub sent_s: Vec<f64>,
    pub frames: u64,
    /// `None`: the session sent all its audio and got `done` with every frame.
    pub failed: Option<String>,
}

/// The `ready` message's figures the client needs.
#[derive(Debug, Clone, Copy)]
struct Ready {
    fps: u64,
    frames_per_unit: u64,
    lookahead_frames: u64,
}

impl Ready {
    fn parse(text: &str) -> Result<Ready, String> {
        let v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("ready: not JSON ({e})"))?;
        if v.get("type").and_then(|t| t.as_str()) != Some("ready") {
            return Err(format!(
                "expected the ready message, got {}",
                crate::protocol::truncate(text, 80)
            ));
        }
        let num = |k: &str| {
            v.get(k)
                .and_then(serde_json::Value::as_u64)
                .ok_or_else(|| format!("ready: no unsigned integer '{k}'"))
        };
        let r = Ready {
            fps: num("fps")?,
            frames_per_unit: num("frames_per_unit")?,
            lookahead_frames: num("lookahead_frames")?,
        };
        if r.fps == 0 || r.frames_per_unit == 0 {
            return Err("ready: fps and frames_per_unit must be positive".into());
        }
        Ok(r)
    }

    /// 16 kHz samples that complete unit `u`'s audio (its frames and the look-ahead past them).
    fn unit_samples(&self, u: u64) -> u64 {
        ((u + 1) * self.frames_per_unit + self.lookahead_frames) * RATE / self.fps
    }
}

/// The frame index of a frame message (binary record or JSON line).
fn frame_index(m: &Message) -> Option<u64> {
    match m {
        Message::Binary(b) if b.len() >= 8 => Some(u64::from_le_bytes(b[..8].try_into().ok()?)),
        // the index leads the frame's JSON object (docs/serve.md): read it without parsing the
        // poses, so that the client's own work stays out of the latency it measures
        Message::Text(t) => {
            let rest = t.strip_prefix("{\"index\":")?;
            let end = rest.find(|c: char| !c.is_ascii_digit())?;
            (end > 0 && rest[end..].starts_with(',')).then(|| rest[..end].parse().ok())?
        }
        _ => None,
    }
}

/// Runs one session (never panics: every problem is a failed session with its reason).
pub async fn run(plan: SessionPlan) -> SessionResult {
    let timeout = plan.timeout;
    match tokio::time::timeout(timeout, run_inner(plan)).await {
        Ok(r) => r,
        Err(_) => SessionResult {
            failed: Some(format!(
                "hung: not done after {:.0} s",
                timeout.as_secs_f64()
            )),
            ..Default::default()
        },
    }
}

// long: one session's async life in order: connect, send audio on its schedule, read frames, close
async fn run_inner(plan: SessionPlan) -> SessionResult {
    tokio::time::sleep(plan.delay).await;
    let mut r = SessionResult::default();
    let url = format!(
        "{}/v1/stream?seed={}&output={}",
        plan.url.trim_end_matches('/'),
        plan.seed,
        if plan.binary { "binary" } else { "json" }
    );
    let mut req = match url.as_str().into_client_request() {
        Ok(q) => q,
        Err(e) => {
            r.failed = Some(format!("{url}: {e}"));
            return r;
        }
    };
    if let Some(t) = &plan.token {
        match HeaderValue::from_str(&format!("Bearer {t}")) {
            Ok(h) => {
                req.headers_mut().insert("authorization", h);
            }
            Err(_) => {
                r.failed = Some("the token is not a valid header value".into());
                return r;
            }
        }
    }
    let ws = match tokio_tungstenite::connect_async(req).await {
        Ok((ws, _)) => ws,
        Err(tokio_tungstenite::tungstenite::Error::Http(resp)) => {
            let body = resp
                .body()
                .as_ref()
                .map(|b| String::from_utf8_lossy(b).trim().to_string())
                .unwrap_or_default();
            r.failed = Some(format!("refused: HTTP {} {body}", resp.status().as_u16()));
            return r;
        }
        Err(e) => {
            r.failed = Some(format!("connect: {e}"));
            return r;
        }
    };
    let (mut tx, mut rx) = ws.split();
    let ready = match rx.next().await {
        Some(Ok(Message::Text(t))) => match Ready::parse(&t) {
            Ok(x) => x,
            Err(e) => {
                r.failed = Some(e);
                return r;
            }
        },
        other => {
            r.failed = Some(format!("no ready message: {other:?}"));
            return r;
        }
    };
    // (cumulative samples after the message, when it was sent): increasing in both
    let log: Arc<Mutex<Vec<(u64, Instant)>>> = Arc::default();
    let log2 = log.clone();
    let (audio, chunk) = (plan.audio.clone(), plan.chunk.max(1));
    let sender = tokio::spawn(async move {
        let t0 = Instant::now();
        let mut sent = 0usize;
        let mut buf = Vec::with_capacity(chunk * 2);
        while sent < audio.len() {
            let due = t0 + Duration::from_secs_f64(sent as f64 / RATE as f64);
            tokio::time::sleep_until(due.into()).await;
            let n = chunk.min(audio.len() - sent);
            buf.clear();
            for s in &audio[sent..sent + n] {
                buf.extend_from_slice(&s.to_le_bytes());
            }
            if let Err(e) = tx.send(Message::Binary(buf.clone().into())).await {
                return Err(format!("send: {e}"));
            }
            sent += n;
            log2.lock()
                .unwrap_or_else(|e| e.into_inner())
                .push((sent as u64, Instant::now()));
        }
        tx.send(Message::Text(r#"{"type":"end"}"#.into()))
            .await
            .map_err(|e| format!("send end: {e}"))?;
        Ok(tx)
    });
    let expected = (plan.audio.len() as u64 * ready.fps).div_ceil(RATE);
    let mut done = None;
    while let Some(m) = rx.next().await {
        let m = match m {
            Ok(m) => m,
            Err(e) => {
                r.failed = Some(format!("receive: {e}"));
                break;
            }
        };
        if let Some(idx) = frame_index(&m) {
            r.frames += 1;
            if (idx + 1) % ready.frames_per_unit == 0 {
                let need = ready.unit_samples(idx / ready.frames_per_unit);
                let now = Instant::now();
                let l = log.lock().unwrap_or_else(|e| e.into_inner());
                let k = l.partition_point(|&(c, _)| c < need);
                if let (Some(&(_, at)), Some(&(_, first))) = (l.get(k), l.first()) {
                    r.latencies_ms
                        .push(now.saturating_duration_since(at).as_secs_f64() * 1e3);
                    r.sent_s
                        .push(at.saturating_duration_since(first).as_secs_f64());
                }
            }
            continue;
        }
        match m {
            Message::Text(t) if t.contains("\"done\"") => {
                let v: serde_json::Value = serde_json::from_str(&t).unwrap_or_default();
                done = v.get("frames").and_then(serde_json::Value::as_u64);
            }
            Message::Close(c) => {
                if done.is_none() {
                    r.failed = Some(format!("closed before done: {c:?}"));
                }
                break;
            }
            _ => {}
        }
    }
    match sender.await {
        Ok(Ok(_)) => {}
        Ok(Err(e)) => r.failed = r.failed.take().or(Some(e)),
        Err(e) => r.failed = r.failed.take().or(Some(e.to_string())),
    }
    if r.failed.is_none() {
        match done {
            None => r.failed = Some("the server closed without done".into()),
            Some(n) if n != expected || r.frames != expected => {
                r.failed = Some(format!(
                    "done says {n} frames, {} received, expected {expected}",
                    r.frames
                ))
            }
            Some(_) => {}
        }
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_samples_follow_the_token_grid() {
        // LiveGesture: token t ends at (t + 1) * 4 * 16000 / 30 samples (the frontend's grid)
        let lg = Ready {
            fps: 30,
            frames_per_unit: 4,
            lookahead_frames: 0,
        };
        let f = livegesture::frontend::FrontendConfig::default();
        for t in [0, 1, 2, 29, 1000] {
            assert_eq!(lg.unit_samples(t), f.token_end(t));
        }
        // DiffSHEG: the first window needs N = 88 frames (46933 samples), then every 78
        let ds = Ready {
            fps: 30,
            frames_per_unit: 78,
            lookahead_frames: 10,
        };
        assert_eq!(ds.unit_samples(0), 46933);
        assert_eq!(ds.unit_samples(1), (166 * 16000) / 30);
    }

    #[test]
    fn ready_is_checked() {
        let ok = r#"{"type":"ready","fps":30,"frames_per_unit":4,"lookahead_frames":0}"#;
        assert_eq!(Ready::parse(ok).unwrap().frames_per_unit, 4);
        assert!(Ready::parse(r#"{"type":"done"}"#)
            .unwrap_err()
            .contains("expected the ready"));
        assert!(Ready::parse(r#"{"type":"ready","fps":30}"#)
            .unwrap_err()
            .contains("frames_per_unit"));
        assert!(Ready::parse("nope").unwrap_err().contains("not JSON"));
    }

    #[test]
    fn frame_indices_of_both_outputs() {
        let mut b = 7u64.to_le_bytes().to_vec();
        b.extend([0u8; 16]);
        assert_eq!(frame_index(&Message::Binary(b.into())), Some(7));
        let j = r#"{"index":12,"time_s":0.4,"poses":[]}"#;
        assert_eq!(frame_index(&Message::Text(j.into())), Some(12));
        assert_eq!(
            frame_index(&Message::Text(r#"{"type":"done"}"#.into())),
            None
        );
    }
}
