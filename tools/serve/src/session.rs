//! One WebSocket session: parameters, audio decoding and resampling, limits, the writer task.

use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Instant;

use axum::extract::rejection::QueryRejection;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::extract::ws::{CloseFrame, Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, Query, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use futures_util::stream::{SplitSink, StreamExt};
use futures_util::SinkExt;
use tokio::sync::{mpsc, oneshot, Semaphore};

use livegesture::model::StreamOptions;

use super::messages::{Cmd, Out, SessionCtl, SessionStats};
use super::protocol::*;
use super::AppState;

/// Releases the session slot when the session (or the refused upgrade) is over.
struct Slot(Arc<AppState>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.slots.fetch_sub(1, Ordering::SeqCst);
        self.0.ended.notify_waiters();
    }
}

fn refuse(st: &AppState, status: StatusCode, reason: &str, msg: String) -> Response {
    st.metrics.refuse(reason);
    (status, format!("{msg}\n")).into_response()
}

/// `GET /v1/stream`: validates the parameters and capacity, then upgrades.
pub(crate) async fn upgrade(
    State(st): State<Arc<AppState>>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    query: Result<Query<Vec<(String, String)>>, QueryRejection>,
    ws: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Response {
    let pairs = match query {
        Ok(Query(p)) => p,
        Err(e) => {
            return refuse(
                &st,
                StatusCode::BAD_REQUEST,
                "bad_request",
                format!("bad query string: {e}"),
            )
        }
    };
    let params = match SessionParams::parse(&pairs) {
        Ok(p) => p,
        Err(m) => return refuse(&st, StatusCode::BAD_REQUEST, "bad_request", m),
    };
    let ws = match ws {
        Ok(ws) => ws,
        Err(e) => {
            st.metrics.refuse("bad_request");
            return e.into_response();
        }
    };
    if st.draining.load(Ordering::SeqCst) || *st.shutdown.borrow() {
        return refuse(
            &st,
            StatusCode::SERVICE_UNAVAILABLE,
            "shutting_down",
            "the server is shutting down".into(),
        );
    }
    let max = st.cfg.max_sessions as u64;
    if st.slots.fetch_add(1, Ordering::SeqCst) >= max {
        st.slots.fetch_sub(1, Ordering::SeqCst);
        return refuse(
            &st,
            StatusCode::SERVICE_UNAVAILABLE,
            "capacity",
            format!("at capacity: {max} sessions are live; try again later"),
        );
    }
    let slot = Slot(st.clone());
    // tungstenite refuses anything past its limit itself; a little headroom lets the server close
    // with 1009 and a reason for messages somewhat over the limit
    let hard = st.cfg.max_message_bytes.saturating_mul(2).max(64 << 10);
    ws.max_message_size(hard)
        .max_frame_size(hard)
        .on_upgrade(move |socket| async move {
            run_session(socket, st, params, peer).await;
            drop(slot);
        })
}

fn close_msg(code: u16, reason: &str) -> Message {
    Message::Close(Some(CloseFrame {
        code,
        reason: Utf8Bytes::from(truncate(reason, 120)),
    }))
}

/// How a session ended (for its log line).
struct Ending {
    code: u16,
    reason: String,
}

async fn run_session(
    socket: WebSocket,
    st: Arc<AppState>,
    params: SessionParams,
    peer: SocketAddr,
) {
    let sid = st.next_sid.fetch_add(1, Ordering::SeqCst);
    let started = Instant::now();
    let (mut sink, mut source) = socket.split();
    let (out_tx, out_rx) = mpsc::channel::<Out>(st.cfg.queue_frames.max(1));
    let ctl = Arc::new(SessionCtl::default());
    let credits = Arc::new(Semaphore::new(st.cfg.max_pending_tokens.max(1)));
    let opts = StreamOptions {
        seed: params.seed,
        guidance: params.guidance,
        ..Default::default()
    };
    let (reply_tx, reply_rx) = oneshot::channel();
    let join = Cmd::Join {
        sid,
        opts,
        out: out_tx,
        ctl: ctl.clone(),
        credits: credits.clone(),
        reply: reply_tx,
    };
    let joined = match st.cmd.send(join).await {
        Ok(()) => reply_rx
            .await
            .map_err(|_| "the scheduler is gone".to_string())
            .and_then(|r| r),
        Err(_) => Err("the scheduler is gone".to_string()),
    };
    let joined = match joined {
        Ok(j) => j,
        Err(e) => {
            let _ = sink
                .send(close_msg(
                    CLOSE_INTERNAL,
                    &format!("cannot start the session: {e}"),
                ))
                .await;
            eprintln!("livegesture serve: session {sid} from {peer}: refused: {e}");
            return;
        }
    };
    st.metrics.sessions_active.fetch_add(1, Ordering::Relaxed);
    st.metrics.sessions_total.fetch_add(1, Ordering::Relaxed);
    let guidance = joined.guidance;
    let fps = st.info.fps.max(1) as f64;
    eprintln!(
        "livegesture serve: session {sid} start: peer {peer}, rate {} Hz, {} ch, {}, output {}, seed {}, guidance {guidance}",
        params.rate,
        params.channels,
        params.format,
        params.output.name(),
        params.seed
    );
    let info = &st.info;
    let ready = serde_json::json!({
        "type": "ready",
        "session": sid,
        "model": info.model,
        "family": info.family.name(),
        "bundle_sha256": info.bundle_sha256,
        "backend": info.backend,
        "fps": info.fps,
        "frames_per_token": info.frames_per_token,
        "token_duration_s": info.frames_per_token as f64 / info.fps as f64,
        "first_token_samples_16k": info.frontend.token_end(0),
        // frames leave in units (a token; a DiffSHEG window step), each once the audio reaches
        // `lookahead_frames` past its end
        "frames_per_unit": joined.frames_per_unit,
        "lookahead_frames": joined.lookahead_frames,
        "lookahead_s": joined.lookahead_frames as f64 / fps,
        "first_frame_samples_16k": joined.first_frame_samples_16k,
        "first_frame_after_s": joined.first_frame_samples_16k as f64 / 16000.0,
        "rate": params.rate,
        "channels": params.channels,
        "format": params.format.name(),
        "output": params.output.name(),
        "seed": params.seed,
        "guidance": guidance,
        "max_message_bytes": st.cfg.max_message_bytes,
        "idle_timeout_s": st.cfg.idle_timeout.as_secs_f64(),
        // the face channel, and the binary record that output=binary sends (docs/serve.md)
        "face": info.face,
        "binary_version": livegesture::output::binary_layout(info.face).0,
        "record_bytes": livegesture::output::binary_layout(info.face).1,
    });
    let ready_ok = sink
        .send(Message::Text(ready.to_string().into()))
        .await
        .is_ok();
    let writer = tokio::spawn(write_loop(
        sink,
        out_rx,
        ctl.clone(),
        params.output,
        ready_ok,
    ));
    let ending = read_loop(&mut source, &st, &params, sid, &ctl, &credits, writer).await;
    let (stx, srx) = oneshot::channel();
    let _ = st.cmd.send(Cmd::Leave { sid, stats: stx }).await;
    let stats = srx.await.unwrap_or_default();
    st.metrics.sessions_active.fetch_sub(1, Ordering::Relaxed);
    log_end(sid, started, &stats, &ending);
}

fn log_end(sid: u64, started: Instant, s: &SessionStats, e: &Ending) {
    let mut lat = s.latencies.clone();
    lat.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| -> f64 {
        if lat.is_empty() {
            f64::NAN
        } else {
            lat[((lat.len() - 1) as f64 * p).round() as usize] * 1e3
        }
    };
    eprintln!(
        "livegesture serve: session {sid} end: close {} ({}), {:.1} s, audio {:.2} s, {} tokens, {} frames, token latency p50 {:.1} ms p99 {:.1} ms",
        e.code,
        e.reason,
        started.elapsed().as_secs_f64(),
        s.samples_16k as f64 / 16000.0,
        s.tokens,
        s.frames,
        q(0.5),
        q(0.99)
    );
}

type Sink = SplitSink<WebSocket, Message>;

/// Sends the scheduler's frames and control messages; returns how the session was closed.
async fn write_loop(
    mut sink: Sink,
    mut rx: mpsc::Receiver<Out>,
    ctl: Arc<SessionCtl>,
    output: OutputKind,
    ok: bool,
) -> Ending {
    if !ok {
        return Ending {
            code: 1006,
            reason: "client gone".into(),
        };
    }
    let mut buf = Vec::with_capacity(livegesture::output::BINARY_RECORD_LEN_FACE);
    loop {
        let next = tokio::select! {
            biased;
            _ = ctl.notify.notified() => None,
            m = rx.recv() => m,
        };
        if let Some((code, reason)) = ctl.take_kill() {
            let _ = tokio::time::timeout(
                std::time::Duration::from_secs(2),
                sink.send(close_msg(code, &reason)),
            )
            .await;
            return Ending { code, reason };
        }
        let Some(out) = next else {
            continue;
        };
        let (msg, end) = match out {
            Out::Frame(f) => match output {
                OutputKind::Json => match f.to_json_line() {
                    Ok(s) => (Message::Text(s.into()), None),
                    Err(e) => {
                        let r = format!("internal error: {e:#}");
                        (
                            close_msg(CLOSE_INTERNAL, &r),
                            Some(Ending {
                                code: CLOSE_INTERNAL,
                                reason: r,
                            }),
                        )
                    }
                },
                OutputKind::Binary => {
                    buf.clear();
                    f.encode_binary(&mut buf);
                    (Message::Binary(buf.clone().into()), None)
                }
            },
            Out::Done { frames } => {
                let done = serde_json::json!({"type": "done", "frames": frames}).to_string();
                if sink.send(Message::Text(done.into())).await.is_err() {
                    return Ending {
                        code: 1006,
                        reason: "client gone".into(),
                    };
                }
                let r = format!("done: {frames} frames");
                (
                    close_msg(CLOSE_NORMAL, &r),
                    Some(Ending {
                        code: CLOSE_NORMAL,
                        reason: r,
                    }),
                )
            }
            Out::Close(code, reason) => (close_msg(code, &reason), Some(Ending { code, reason })),
        };
        // a send blocked on a slow client is abandoned when the scheduler cuts the session
        let sent = tokio::select! {
            biased;
            r = sink.send(msg) => r.is_ok(),
            _ = ctl.notify.notified() => {
                ctl.notify.notify_one(); // handled at the top of the loop
                continue;
            }
        };
        if !sent {
            return Ending {
                code: 1006,
                reason: "client gone".into(),
            };
        }
        if let Some(e) = end {
            return e;
        }
    }
}

/// Reads client messages until the end, an error, a refusal or shutdown.
async fn read_loop(
    source: &mut futures_util::stream::SplitStream<WebSocket>,
    st: &Arc<AppState>,
    params: &SessionParams,
    sid: u64,
    ctl: &Arc<SessionCtl>,
    credits: &Arc<Semaphore>,
    mut writer: tokio::task::JoinHandle<Ending>,
) -> Ending {
    let mut input = match SessionInput::new(params, format!("session {sid}")) {
        Ok(i) => i,
        Err(e) => return cut(st, ctl, writer, CLOSE_INTERNAL, e, None).await,
    };
    let fcfg = st.info.frontend.clone();
    let mut sent_16k: u64 = 0;
    let mut shutdown = st.shutdown.clone();
    let idle = st.cfg.idle_timeout;
    let limit = st.cfg.max_message_bytes;
    loop {
        let ended = input.ended();
        let msg = tokio::select! {
            biased;
            w = &mut writer => return w.unwrap_or(Ending { code: 1011, reason: "writer failed".into() }),
            r = shutdown.changed(), if !ended => {
                if r.is_err() || *shutdown.borrow_and_update() {
                    let _ = st.cmd.send(Cmd::Drain { sid }).await;
                    input.drain();
                }
                continue;
            }
            m = tokio::time::timeout(idle, source.next()), if !ended => m,
        };
        let at = Instant::now();
        let msg = match msg {
            Err(_) => {
                st.metrics.refuse("idle");
                let r = format!("idle: no message for {} s", idle.as_secs_f64());
                return cut(st, ctl, writer, CLOSE_POLICY, r, None).await;
            }
            Ok(None) => return client_gone(st, ctl, writer).await,
            Ok(Some(Err(e))) => {
                let text = e.to_string();
                if text.contains("too long")
                    || text.contains("Space limit")
                    || text.contains("size")
                {
                    st.metrics.refuse("oversize");
                    let r = format!("message over the size limit of {limit} bytes");
                    return cut(st, ctl, writer, CLOSE_TOO_BIG, r, None).await;
                }
                return client_gone(st, ctl, writer).await;
            }
            Ok(Some(Ok(m))) => m,
        };
        let len = match &msg {
            Message::Binary(b) => b.len(),
            Message::Text(t) => t.len(),
            _ => 0,
        };
        if len > limit {
            st.metrics.refuse("oversize");
            let r = format!("message of {len} bytes over the size limit of {limit} bytes");
            return cut(st, ctl, writer, CLOSE_TOO_BIG, r, None).await;
        }
        let handled = match msg {
            Message::Binary(bytes) => input.binary(&bytes).map(|s16| (s16, None)),
            Message::Text(text) => input.text(&text).map(|e| (e.tail, Some(e.input))),
            Message::Close(_) => return client_gone(st, ctl, writer).await,
            Message::Ping(_) | Message::Pong(_) => continue,
        };
        let (s16, end) = match handled {
            Ok(h) => h,
            Err(r) => {
                if let Some(m) = r.metric {
                    st.metrics.refuse(m);
                }
                return cut(st, ctl, writer, r.code, r.reason, Some(sid)).await;
            }
        };
        if !forward(st, sid, credits, &fcfg, &mut sent_16k, s16, at).await {
            return client_gone(st, ctl, writer).await;
        }
        if let Some(span) = end {
            let _ = st.cmd.send(Cmd::End { sid, input: span }).await;
        }
    }
}

/// Sends 16 kHz samples to the scheduler, taking one credit per token they complete (so at most
/// `max_pending_tokens` of this session wait for their step; beyond that the socket is not read).
async fn forward(
    st: &Arc<AppState>,
    sid: u64,
    credits: &Arc<Semaphore>,
    f: &livegesture::frontend::FrontendConfig,
    sent: &mut u64,
    samples: Vec<f32>,
    at: Instant,
) -> bool {
    let mut rest = &samples[..];
    while !rest.is_empty() {
        // the next token boundary
        let t = f.n_tokens(*sent);
        let boundary = f.token_end(t);
        let take = ((boundary - *sent) as usize).min(rest.len());
        let completes = *sent + take as u64 == boundary;
        if completes {
            match credits.acquire().await {
                Ok(p) => p.forget(),
                Err(_) => return false,
            }
        }
        let (piece, tail) = rest.split_at(take);
        let cmd = Cmd::Audio {
            sid,
            samples: piece.to_vec(),
            at,
        };
        if st.cmd.send(cmd).await.is_err() {
            return false;
        }
        *sent += take as u64;
        rest = tail;
    }
    true
}

/// Closes the session from the reader's side with a reason, and waits for the writer to send it.
async fn cut(
    st: &Arc<AppState>,
    ctl: &Arc<SessionCtl>,
    writer: tokio::task::JoinHandle<Ending>,
    code: u16,
    reason: String,
    _sid: Option<u64>,
) -> Ending {
    let _ = st;
    ctl.kill(code, reason.clone());
    match tokio::time::timeout(std::time::Duration::from_secs(3), writer).await {
        Ok(Ok(e)) => e,
        _ => Ending { code, reason },
    }
}

async fn client_gone(
    _st: &Arc<AppState>,
    ctl: &Arc<SessionCtl>,
    writer: tokio::task::JoinHandle<Ending>,
) -> Ending {
    ctl.kill(1006, "client gone".into());
    writer.abort();
    Ending {
        code: 1006,
        reason: "client gone".into(),
    }
}
