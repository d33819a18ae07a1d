//! `livegesture serve`: the WebSocket server of docs/serve.md (see `docs/serve.md`).

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use sha2::{Digest, Sha256};

use livegesture::backend;
use livegesture::model::GraphForm;
use livegesture::model::{self, LoadOptions};
use livegesture_serve::access::AccessConfig;
use livegesture_serve::tls::load_config as load_tls;
use livegesture_serve::{ModelInfo, ServeConfig, Server};

use super::common::{check_form, InputError, ModelArgs};

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  livegesture serve --backend ort --addr 127.0.0.1:8765\n  then open http://127.0.0.1:8765/ (protocol: docs/serve.md)"
)]
pub struct Args {
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1:8765")]
    pub addr: SocketAddr,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Most concurrent sessions; more are refused with HTTP 503.
    #[arg(long, default_value_t = 64)]
    pub max_sessions: usize,
    /// Before the first session, step this many throw-away streams together (at most
    /// --max-sessions), so that a burst of sessions on a fresh server does not wait while memory is
    /// touched for the first time (docs/serve.md#the-start-up-transient). 0: no warm-up. Default:
    /// 48 for a LiveGesture bundle, 0 for DiffSHEG (whose windows cost far more to warm up).
    #[arg(long)]
    pub warm_sessions: Option<usize>,
    /// Largest client message in bytes (larger: close 1009).
    #[arg(long, default_value_t = 1 << 20)]
    pub max_message_bytes: usize,
    /// Frames queued for sending per session; a client that lets more pile up is disconnected (1008).
    #[arg(long, default_value_t = 240)]
    pub queue_frames: usize,
    /// Complete tokens of one session waiting for their step before its socket is no longer read.
    #[arg(long, default_value_t = 16)]
    pub max_pending_tokens: usize,
    /// Seconds without a client message before the session is closed (1008).
    #[arg(long, default_value_t = 30.0)]
    pub idle_timeout: f64,
    /// About the slot of the tick grid in milliseconds (a token divided into whole slots): the longest
    /// a complete token waits for the other sessions of its slot to join its batched step.
    #[arg(long, default_value_t = 30.0)]
    pub batch_wait_ms: f64,
    /// Seconds to wait for sessions to drain on SIGINT/SIGTERM.
    #[arg(long, default_value_t = 10.0)]
    pub drain_timeout: f64,
    /// Also serve this folder's files: the static page with the WebAssembly runtime and a bundle
    /// (scripts/build_web_static.sh -> target/web-static), so /?engine=wasm runs in the browser.
    #[arg(long, value_name = "DIR")]
    pub web_dir: Option<std::path::PathBuf>,
    /// Seconds to keep running on SIGINT/SIGTERM with /healthz at 503 and new sessions refused,
    /// before live sessions are closed (1001); sessions that end meanwhile complete. A load
    /// balancer's health check sees the replica leave in that time (docs/deploy.md).
    #[arg(long, default_value_t = 0.0)]
    pub drain_delay: f64,
    #[command(flatten)]
    pub access: AccessArgs,
}

/// Who may connect (docs/deploy.md#who-may-connect).
#[derive(Debug, clap::Args)]
pub struct AccessArgs {
    /// File holding a shared secret (one line, at least 16 characters); sessions must present it as
    /// `Authorization: Bearer <token>` or `?token=<token>` (else HTTP 401). /healthz, /metrics and
    /// the page stay open.
    #[arg(long, value_name = "FILE")]
    pub auth_token_file: Option<PathBuf>,
    /// Origin (scheme://host[:port]) whose pages may open sessions, besides the served page's own;
    /// repeat or separate with commas. Other Origins get HTTP 403. Not given: any origin.
    #[arg(long, value_name = "ORIGIN", value_delimiter = ',')]
    pub allowed_origin: Vec<String>,
    /// Most live sessions per client IP (HTTP 429 beyond); 0: no limit besides --max-sessions.
    #[arg(long, default_value_t = 0)]
    pub max_sessions_per_client: usize,
    /// Take the client IP for --max-sessions-per-client from the last X-Forwarded-For entry (only
    /// behind a proxy that sets it, e.g. HAProxy with `option forwardfor`).
    #[arg(long)]
    pub trust_forwarded_for: bool,
    /// TLS certificate chain (PEM): serve https and wss in the process (with --tls-key).
    #[arg(long, value_name = "PEM", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// TLS private key (PEM: PKCS#8, PKCS#1 or SEC1), with --tls-cert.
    #[arg(long, value_name = "PEM", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
}

impl AccessArgs {
    fn config(
        &self,
    ) -> Result<(
        AccessConfig,
        Option<Arc<tokio_rustls::rustls::ServerConfig>>,
    )> {
        let token = match &self.auth_token_file {
            Some(p) => {
                Some(AccessConfig::read_token(p).map_err(|e| InputError::new(format!("{e:#}")))?)
            }
            None => None,
        };
        let allowed_origins = self
            .allowed_origin
            .iter()
            .map(|o| AccessConfig::parse_origin(o).map_err(|e| InputError::new(format!("{e:#}"))))
            .collect::<Result<_, _>>()?;
        let tls = match (&self.tls_cert, &self.tls_key) {
            (Some(c), Some(k)) => {
                Some(load_tls(c, k).map_err(|e| InputError::new(format!("{e:#}")))?)
            }
            _ => None,
        };
        Ok((
            AccessConfig {
                token,
                allowed_origins,
                max_sessions_per_client: self.max_sessions_per_client,
                trust_forwarded_for: self.trust_forwarded_for,
            },
            tls,
        ))
    }
}

fn secs(name: &str, v: f64) -> Result<Duration> {
    if v.is_finite() && v > 0.0 && v < 1e7 {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(InputError::new(format!(
            "--{name} must be a positive number of seconds, got {v}"
        ))
        .into())
    }
}

pub fn run(a: Args, form: GraphForm) -> Result<()> {
    if a.max_sessions == 0
        || a.max_message_bytes == 0
        || a.queue_frames == 0
        || a.max_pending_tokens == 0
    {
        return Err(InputError::new(
            "--max-sessions, --max-message-bytes, --queue-frames and --max-pending-tokens must be at least 1",
        )
        .into());
    }
    let (access, tls) = a.access.config()?;
    if !a.addr.ip().is_loopback() && access.token.is_none() {
        eprintln!("livegesture serve: warning: listening on {} beyond loopback without --auth-token-file: anyone who reaches it may open sessions", a.addr);
    }
    let scheme = if tls.is_some() { "https" } else { "http" };
    let mut cfg = ServeConfig {
        max_sessions: a.max_sessions,
        max_message_bytes: a.max_message_bytes,
        queue_frames: a.queue_frames,
        max_pending_tokens: a.max_pending_tokens,
        idle_timeout: secs("idle-timeout", a.idle_timeout)?,
        batch_wait: secs("batch-wait-ms", a.batch_wait_ms / 1e3)?,
        drain_timeout: secs("drain-timeout", a.drain_timeout)?,
        web_dir: a.web_dir.clone(),
        drain_delay: if a.drain_delay == 0.0 {
            Duration::ZERO
        } else {
            secs("drain-delay", a.drain_delay)?
        },
        access,
        tls,
        warm_sessions: 0,
    };
    if let Some(d) = &a.web_dir {
        if !d.join("wasm").is_dir() {
            return Err(InputError::new(format!(
                "--web-dir {}: no wasm/ folder here; expected the static page of scripts/build_web_static.sh",
                d.display()
            ))
            .into());
        }
    }
    let bundle = a.model.bundle()?;
    check_form(&bundle, form)?;
    cfg.warm_sessions = a.warm_sessions.unwrap_or(
        if bundle.family() == livegesture::bundle::Family::LiveGesture {
            48
        } else {
            0
        },
    );
    let backend_opts = a.model.backend_options()?;
    let manifest = std::fs::read(bundle.manifest_path())
        .with_context(|| format!("reading {}", bundle.manifest_path().display()))?;
    let server = Server::start(a.addr, cfg, move || {
        let be = backend::create(&backend_opts)?;
        let family = bundle.family();
        let loading = || {
            format!(
                "loading the bundle {} with {}",
                bundle.dir().display(),
                be.describe()
            )
        };
        let model =
            model::load_with(&bundle, be.as_ref(), &LoadOptions { form }).with_context(loading)?;
        let backend_name = model.backend_name().to_string();
        let m = bundle.manifest();
        let info = ModelInfo {
            model: m
                .model
                .name
                .clone()
                .or_else(|| m.model.config_name.clone())
                .unwrap_or_else(|| bundle.dir().display().to_string()),
            family,
            bundle_sha256: hex::encode(Sha256::digest(&manifest)),
            backend: backend_name,
            fps: bundle.frontend().fps,
            frames_per_token: bundle.frontend().frames_per_token,
            frontend: bundle.frontend().clone(),
            face: model.has_face(),
        };
        Ok((model, info))
    })?;
    // The signal handlers are installed before the "listening" line: a supervisor (or a test) that
    // reads that line and sends SIGTERM at once must get a drain, not the default action (death by
    // signal, exit -15), which it would get if the line came first.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (mut term, mut int) = rt.block_on(async {
        use tokio::signal::unix::{signal, SignalKind};
        Ok::<_, anyhow::Error>((
            signal(SignalKind::terminate())?,
            signal(SignalKind::interrupt())?,
        ))
    })?;
    eprintln!(
        "livegesture serve: listening on {scheme}://{} (WebSocket /v1/stream, page /, /healthz, /metrics)",
        server.addr()
    );
    let signalled = rt.block_on(async {
        tokio::select! {
            _ = int.recv() => Some("SIGINT"),
            _ = term.recv() => Some("SIGTERM"),
            _ = server.finished() => None,
        }
    });
    if let Some(sig) = signalled {
        eprintln!("livegesture serve: {sig}: draining (no new sessions; finishing arrived tokens or windows; closing 1001)");
        server.shutdown();
    }
    server.join()?;
    eprintln!("livegesture serve: stopped");
    Ok(())
}
