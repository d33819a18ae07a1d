//! The server's listener: plain TCP, or TLS in the process with rustls (`--tls-cert`/`--tls-key`,
//! PEM files; docs/deploy.md#tls). Every accepted connection is a [`ConnIo`] that holds its
//! session's per-client slot ([`super::access`]) until the connection closes.
//!
//! TLS handshakes run in their own tasks (a slow or silent client does not hold up the accept loop)
//! with a 10 s limit; a failed handshake counts as refusal reason `tls_handshake`.

use std::io;
use std::net::SocketAddr;
use std::path::Path;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context as TaskContext, Poll};
use std::time::Duration;

use anyhow::{Context, Result};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tokio_rustls::rustls;
use tokio_rustls::rustls::pki_types::pem::PemObject;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::TlsAcceptor;

use super::access::{ClientAddr, Hold};
use super::metrics::Metrics;

/// How long a TLS handshake may take.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Loads a PEM certificate chain and private key into a rustls server configuration (HTTP/1.1).
pub fn load_config(cert: &Path, key: &Path) -> Result<Arc<rustls::ServerConfig>> {
    let certs: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(cert)
        .with_context(|| format!("--tls-cert {}: cannot read", cert.display()))?
        .collect::<Result<_, _>>()
        .with_context(|| format!("--tls-cert {}: not a PEM certificate chain", cert.display()))?;
    if certs.is_empty() {
        anyhow::bail!(
            "--tls-cert {}: no CERTIFICATE block found (expected a PEM certificate chain)",
            cert.display()
        );
    }
    let key = PrivateKeyDer::from_pem_file(key).with_context(|| {
        format!(
            "--tls-key {}: expected a PEM private key (PKCS#8, PKCS#1 or SEC1)",
            key.display()
        )
    })?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut cfg = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_no_client_auth()
        .with_single_cert(certs, key)
        .context("--tls-cert/--tls-key: the key does not fit the certificate, or is not usable")?;
    cfg.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Arc::new(cfg))
}

trait Io: AsyncRead + AsyncWrite + Send {}
impl<T: AsyncRead + AsyncWrite + Send> Io for T {}

/// One accepted connection (plain or TLS); releases its per-client slot when dropped.
pub struct ConnIo {
    io: Pin<Box<dyn Io>>,
    hold: Hold,
}

impl Drop for ConnIo {
    fn drop(&mut self) {
        self.hold.lock().unwrap_or_else(|e| e.into_inner()).take();
    }
}

impl AsyncRead for ConnIo {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        self.io.as_mut().poll_read(cx, buf)
    }
}

impl AsyncWrite for ConnIo {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.io.as_mut().poll_write(cx, buf)
    }
    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        self.io.as_mut().poll_write_vectored(cx, bufs)
    }
    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        self.io.as_mut().poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        self.io.as_mut().poll_shutdown(cx)
    }
}

/// The listener handed to `axum::serve`: connections from the accept task (TLS already done).
pub(crate) struct Incoming {
    rx: mpsc::Receiver<(ConnIo, ClientAddr)>,
    local: SocketAddr,
}

impl Incoming {
    /// Starts accepting on `listener` (must be called inside the runtime).
    pub(crate) fn start(
        listener: TcpListener,
        tls: Option<Arc<rustls::ServerConfig>>,
        metrics: Arc<Metrics>,
    ) -> io::Result<Incoming> {
        let local = listener.local_addr()?;
        let (tx, rx) = mpsc::channel(64);
        let acceptor = tls.map(TlsAcceptor::from);
        tokio::spawn(async move {
            loop {
                let (tcp, peer) = tokio::select! {
                    _ = tx.closed() => return,
                    r = listener.accept() => match r {
                        Ok(c) => c,
                        Err(e) => {
                            // out of file descriptors and the like: wait a little, as axum does
                            eprintln!("livegesture serve: accept: {e}");
                            tokio::time::sleep(Duration::from_millis(100)).await;
                            continue;
                        }
                    },
                };
                let _ = tcp.set_nodelay(true);
                let hold: Hold = Arc::new(Mutex::new(None));
                let addr = ClientAddr {
                    peer,
                    hold: hold.clone(),
                };
                match &acceptor {
                    None => {
                        let io = ConnIo {
                            io: Box::pin(tcp),
                            hold,
                        };
                        if tx.send((io, addr)).await.is_err() {
                            return;
                        }
                    }
                    Some(acc) => {
                        let (acc, tx, metrics) = (acc.clone(), tx.clone(), metrics.clone());
                        tokio::spawn(async move {
                            match tokio::time::timeout(HANDSHAKE_TIMEOUT, acc.accept(tcp)).await {
                                Ok(Ok(tls)) => {
                                    let io = ConnIo {
                                        io: Box::pin(tls),
                                        hold,
                                    };
                                    let _ = tx.send((io, addr)).await;
                                }
                                _ => metrics.refuse("tls_handshake"),
                            }
                        });
                    }
                }
            }
        });
        Ok(Incoming { rx, local })
    }
}

impl axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, Incoming>>
    for ClientAddr
{
    fn connect_info(stream: axum::serve::IncomingStream<'_, Incoming>) -> Self {
        stream.remote_addr().clone()
    }
}

impl axum::serve::Listener for Incoming {
    type Io = ConnIo;
    type Addr = ClientAddr;

    async fn accept(&mut self) -> (ConnIo, ClientAddr) {
        match self.rx.recv().await {
            Some(c) => c,
            // the accept task is gone (it only ends when this listener is dropped): wait forever
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> io::Result<ClientAddr> {
        Ok(ClientAddr {
            peer: self.local,
            hold: Arc::new(Mutex::new(None)),
        })
    }
}
