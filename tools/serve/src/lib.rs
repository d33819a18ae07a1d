//! `livegesture serve`: many live sessions over WebSocket (docs/serve.md), for any model family.
//!
//! One thread, the [`scheduler`], owns the [`MotionModel`] and one [`livegesture::model::MotionStream`] per
//! session, and steps the sessions whose audio completes a unit together, in one
//! [`MotionModel::step_many`] call per tick: the model decides how they share graph runs (LiveGesture:
//! every graph once per token for all of them; DiffSHEG: the due windows on the denoiser's batch
//! axis). Nothing here names a family; the protocol, the limits, the refusals and the drain are the
//! same for all.
//!
//! - [`scheduler`]: the scheduler thread;
//! - [`messages`]: what sessions and the scheduler send each other;
//! - [`protocol`]: query parameters, client messages and close codes;
//! - [`session`]: one WebSocket session (decoding, resampling, back-pressure, limits);
//! - [`metrics`]: counters and histograms, Prometheus text format;
//! - [`web`]: the browser page, embedded in the binary;
//! - [`access`]: who may open a session (token, origins, per-client limit);
//! - [`tls`]: the listener, plain TCP or TLS (rustls);
//! - `loadtest` (feature `loadtest`): the load test of a running server (docs/serve.md#load-test), a
//!   WebSocket client of this protocol.
//!
//! [`Server::start`] binds, loads the model on the scheduler thread and serves until
//! [`Server::shutdown`]: new connections are refused, every session's tokens whose audio has arrived
//! are stepped and sent, every session is closed with 1001, then [`Server::join`] returns.

pub mod access;
#[cfg(feature = "loadtest")]
pub mod loadtest;
pub mod messages;
pub mod metrics;
pub mod protocol;
pub mod scheduler;
pub mod session;
pub mod tls;
pub mod web;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use tokio::sync::{mpsc, watch, Notify};

use livegesture::bundle::Family;
use livegesture::model::MotionModel;

use messages::Cmd;
use metrics::Metrics;
use scheduler::{BatchScheduler, SchedConfig};

/// Limits and settings of a server.
#[derive(Debug, Clone)]
pub struct ServeConfig {
    /// Most concurrent sessions; more are refused with HTTP 503.
    pub max_sessions: usize,
    /// Largest accepted client message in bytes; larger ones close the session with 1009.
    pub max_message_bytes: usize,
    /// Frames waiting to be sent per session; a client that lets more pile up is disconnected (1008).
    pub queue_frames: usize,
    /// Completed tokens of one session waiting for their step; beyond this the server stops reading
    /// the session's socket until the scheduler catches up (TCP back-pressure).
    pub max_pending_tokens: usize,
    /// A session without any message for this long is closed with 1008.
    pub idle_timeout: Duration,
    /// About the slot of the tick grid (a token divided into whole slots): the longest a due
    /// session (audio completing a unit) waits for the others of its slot to join its step.
    pub batch_wait: Duration,
    /// On shutdown, how long to wait for sessions to finish before exiting anyway.
    pub drain_timeout: Duration,
    /// A folder whose files are also served (paths the server does not answer itself): the static
    /// build of the page with the WebAssembly runtime and a bundle (`scripts/build_web_static.sh`,
    /// docs/wasm.md), so that `/?engine=wasm` runs the model in the browser.
    pub web_dir: Option<std::path::PathBuf>,
    /// On shutdown, how long to stay up draining before the sessions are closed: `/healthz` says
    /// 503 and new sessions are refused at once, live sessions go on (those that end in time
    /// complete), then the rest get their arrived tokens and close 1001. Zero: close at once.
    pub drain_delay: Duration,
    /// Who may open a session ([`access`]).
    pub access: access::AccessConfig,
    /// TLS in the process ([`tls::load_config`]); `None`: plain TCP.
    pub tls: Option<Arc<tokio_rustls::rustls::ServerConfig>>,
    /// Before the first session, step this many throw-away streams together through two units of
    /// silence ([`scheduler::warm_up`]): the memory a burst of that many sessions first touches
    /// is touched at start, not while they wait (docs/serve.md#the-start-up-transient). 0: none.
    pub warm_sessions: usize,
}

impl Default for ServeConfig {
    fn default() -> Self {
        Self {
            max_sessions: 64,
            max_message_bytes: 1 << 20,
            queue_frames: 240,
            max_pending_tokens: 16,
            idle_timeout: Duration::from_secs(30),
            batch_wait: Duration::from_millis(30),
            drain_timeout: Duration::from_secs(10),
            web_dir: None,
            drain_delay: Duration::ZERO,
            access: access::AccessConfig::default(),
            tls: None,
            warm_sessions: 0,
        }
    }
}

/// What the `ready` message says about the model.
#[derive(Debug, Clone)]
pub struct ModelInfo {
    /// Model name from the manifest.
    pub model: String,
    /// The bundle's model family.
    pub family: Family,
    /// sha256 of the bundle's `manifest.json` (which holds the sha256 of every graph).
    pub bundle_sha256: String,
    pub backend: String,
    pub fps: u64,
    pub frames_per_token: u64,
    /// 16 kHz samples of the first token's audio span and of every later one (integer grid).
    pub frontend: livegesture::frontend::FrontendConfig,
    /// Whether frames carry the face channel (binary records of version 2; docs/face.md).
    pub face: bool,
}

pub(crate) struct AppState {
    pub cfg: ServeConfig,
    pub info: ModelInfo,
    pub metrics: Arc<Metrics>,
    pub cmd: mpsc::Sender<Cmd>,
    pub shutdown: watch::Receiver<bool>,
    pub draining: AtomicBool,
    /// Sessions holding a slot (reserved before the upgrade).
    pub slots: AtomicU64,
    pub next_sid: AtomicU64,
    /// Notified whenever a session ends.
    pub ended: Notify,
    /// Live sessions per client ([`access`]).
    pub clients: Arc<access::ClientTable>,
}

/// A running server.
pub struct Server {
    addr: SocketAddr,
    shutdown: watch::Sender<bool>,
    thread: Option<std::thread::JoinHandle<Result<()>>>,
    metrics: Arc<Metrics>,
    finished: Arc<Notify>,
    finished_flag: Arc<AtomicBool>,
}

impl Server {
    /// Binds `addr`, builds the model with `make_model` on the scheduler thread (any family's
    /// [`MotionModel`], e.g. from [`livegesture::model::load`]), and serves in background threads. Returns
    /// once the model is loaded and the socket is listening.
    pub fn start<F, M>(addr: SocketAddr, cfg: ServeConfig, make_model: F) -> Result<Server>
    where
        F: FnOnce() -> Result<(M, ModelInfo)> + Send + 'static,
        M: Into<Box<dyn MotionModel>>,
    {
        let metrics = Arc::new(Metrics::new());
        let (cmd_tx, cmd_rx) = mpsc::channel::<Cmd>(1024);
        let (info_tx, info_rx) = std::sync::mpsc::channel::<Result<ModelInfo>>();
        let sched_cfg = SchedConfig {
            batch_wait: cfg.batch_wait,
        };
        let m2 = metrics.clone();
        let max_sessions = cfg.max_sessions;
        let warm = cfg.warm_sessions.min(cfg.max_sessions);
        let sched = std::thread::Builder::new()
            .name("livegesture-scheduler".into())
            .spawn(move || {
                // the backend prepares every batch size before the first session (tract: no plan
                // is optimised while sessions wait)
                let loaded = make_model().and_then(|(m, info)| {
                    let m: Box<dyn MotionModel> = m.into();
                    m.prepare_batches(max_sessions)
                        .context("preparing the model's batch sizes")?;
                    scheduler::warm_up(m.as_ref(), warm)
                        .with_context(|| format!("warming up with {warm} streams"))?;
                    Ok((m, info))
                });
                match loaded {
                    Ok((m, info)) => {
                        let frontend = info.frontend.clone();
                        let _ = info_tx.send(Ok(info));
                        BatchScheduler::new(m, frontend, m2, sched_cfg).run(cmd_rx)
                    }
                    Err(e) => {
                        let _ = info_tx.send(Err(e));
                    }
                }
            })
            .context("starting the scheduler thread")?;
        let info = match info_rx.recv() {
            Ok(r) => r?,
            Err(_) => {
                let _ = sched.join();
                anyhow::bail!("the scheduler thread ended before loading the model");
            }
        };
        let std_listener = std::net::TcpListener::bind(addr)
            .with_context(|| format!("--addr {addr}: cannot listen"))?;
        std_listener.set_nonblocking(true)?;
        let local = std_listener.local_addr()?;
        // the shutdown request (Server::shutdown) and, after the drain delay, the sessions' signal
        let (req_tx, req_rx) = watch::channel(false);
        let (sd_tx, sd_rx) = watch::channel(false);
        let state = Arc::new(AppState {
            cfg: cfg.clone(),
            info,
            metrics: metrics.clone(),
            cmd: cmd_tx,
            shutdown: sd_rx.clone(),
            draining: AtomicBool::new(false),
            slots: AtomicU64::new(0),
            next_sid: AtomicU64::new(1),
            ended: Notify::new(),
            clients: Arc::default(),
        });
        let finished = Arc::new(Notify::new());
        let finished_flag = Arc::new(AtomicBool::new(false));
        let (f2, ff2) = (finished.clone(), finished_flag.clone());
        let thread = std::thread::Builder::new()
            .name("livegesture-server".into())
            .spawn(move || {
                let rt = tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(2)
                    .enable_all()
                    .build()
                    .context("building the async runtime")?;
                let r = rt.block_on(serve_until_shutdown(std_listener, state, req_rx, sd_tx));
                // the last command senders are gone with the state: the scheduler ends
                drop(rt);
                let _ = sched.join();
                ff2.store(true, Ordering::SeqCst);
                f2.notify_waiters();
                r
            })
            .context("starting the server thread")?;
        Ok(Server {
            addr: local,
            shutdown: req_tx,
            thread: Some(thread),
            metrics,
            finished,
            finished_flag,
        })
    }

    /// The address the server listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// Starts the drain (see the module docs); returns at once.
    pub fn shutdown(&self) {
        let _ = self.shutdown.send(true);
    }

    /// Waits until the server has stopped (after [`Server::shutdown`], or a fatal error).
    pub fn join(mut self) -> Result<()> {
        match self.thread.take() {
            Some(t) => t
                .join()
                .map_err(|_| anyhow::anyhow!("the server thread panicked"))?,
            None => Ok(()),
        }
    }

    /// Resolves when the server thread has ended.
    pub async fn finished(&self) {
        loop {
            let n = self.finished.notified();
            if self.finished_flag.load(Ordering::SeqCst) {
                return;
            }
            n.await;
        }
    }
}

async fn serve_until_shutdown(
    std_listener: std::net::TcpListener,
    state: Arc<AppState>,
    mut req: watch::Receiver<bool>,
    sd: watch::Sender<bool>,
) -> Result<()> {
    let listener = tokio::net::TcpListener::from_std(std_listener)?;
    let listener = tls::Incoming::start(listener, state.cfg.tls.clone(), state.metrics.clone())?;
    // only sessions pass the access checks; the page, /healthz and /metrics stay open
    let stream = get(session::upgrade).layer(axum::middleware::from_fn_with_state(
        state.clone(),
        access::check,
    ));
    let app = Router::new()
        .route("/v1/stream", stream)
        .route("/healthz", get(healthz))
        .route("/metrics", get(metrics_text))
        .merge(web::routes())
        .layer(axum::middleware::from_fn(access::peer_info))
        .with_state(state.clone());
    // the listener stays open while draining: /healthz answers 503 and new sessions a 503 with a
    // reason (a balancer retries them elsewhere) instead of connection refused
    let (stop_tx, mut stop_rx) = watch::channel(false);
    let http = axum::serve(
        listener,
        app.into_make_service_with_connect_info::<access::ClientAddr>(),
    )
    .with_graceful_shutdown(async move {
        let _ = stop_rx.wait_for(|v| *v).await;
    });
    let http = tokio::spawn(async move { http.await });
    let _ = req.wait_for(|v| *v).await;
    state.draining.store(true, Ordering::SeqCst);
    // the drain delay: live sessions go on until they end or the delay is over
    let delay_end = tokio::time::Instant::now() + state.cfg.drain_delay;
    loop {
        let n = state.ended.notified();
        if state.slots.load(Ordering::SeqCst) == 0 {
            break;
        }
        if tokio::time::timeout_at(delay_end, n).await.is_err() {
            break;
        }
    }
    let _ = sd.send(true);
    // sessions see the same signal: they stop reading, their arrived tokens are stepped, close 1001
    let deadline = tokio::time::Instant::now() + state.cfg.drain_timeout;
    loop {
        let n = state.ended.notified();
        if state.slots.load(Ordering::SeqCst) == 0 {
            break;
        }
        if tokio::time::timeout_at(deadline, n).await.is_err() {
            eprintln!(
                "livegesture serve: drain timeout: {} sessions still open",
                state.slots.load(Ordering::SeqCst)
            );
            break;
        }
    }
    let _ = stop_tx.send(true);
    let _ = tokio::time::timeout(Duration::from_secs(2), http).await;
    Ok(())
}

async fn healthz(State(st): State<Arc<AppState>>) -> Response {
    if st.draining.load(Ordering::SeqCst) {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            "draining: the server is shutting down\n",
        )
            .into_response()
    } else {
        (
            StatusCode::OK,
            format!(
                "ok: model {} (family {}, {}), {} sessions\n",
                st.info.model,
                st.info.family,
                st.info.backend,
                st.metrics.sessions_active.load(Ordering::Relaxed)
            ),
        )
            .into_response()
    }
}

async fn metrics_text(State(st): State<Arc<AppState>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        st.metrics.render() + &capacity_text(&st) + &metrics::process_text(),
    )
        .into_response()
}

/// The gauges an autoscaler and a load balancer read besides [`Metrics::render`]: capacity, slots
/// taken, draining.
fn capacity_text(st: &AppState) -> String {
    let draining = st.draining.load(Ordering::SeqCst) || *st.shutdown.borrow();
    format!(
        "# HELP livegesture_sessions_capacity Most concurrent sessions (--max-sessions).\n\
         # TYPE livegesture_sessions_capacity gauge\n\
         livegesture_sessions_capacity {}\n\
         # HELP livegesture_sessions_slots Session slots taken (live sessions and upgrades in progress).\n\
         # TYPE livegesture_sessions_slots gauge\n\
         livegesture_sessions_slots {}\n\
         # HELP livegesture_draining 1 from the moment the server starts draining (/healthz is then 503).\n\
         # TYPE livegesture_draining gauge\n\
         livegesture_draining {}\n",
        st.cfg.max_sessions,
        st.slots.load(Ordering::SeqCst),
        u8::from(draining)
    )
}
