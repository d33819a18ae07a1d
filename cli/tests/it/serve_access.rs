//! Who may connect to `livegesture serve` (docs/deploy.md): the token (401), the allowed origins
//! (403), the per-client session limit (429), TLS in the process (a certificate made here, a session
//! over wss), the drain delay (/healthz 503 at once, live sessions go on), and the metrics an
//! autoscaler reads. Every refusal is checked with its status, its reason and its metric.

use livegesture_parity_tests as common;

use crate::serve_common;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use futures_util::SinkExt;
use livegesture_serve::access::AccessConfig;
use livegesture_serve::ServeConfig;
use serve_common::{http_get, metric, pcm_bytes, speech_of, start_tiny, within};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::{HeaderName, HeaderValue};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::WebSocketStream;

const TOKEN: &str = "s3cret-token-0123456789";

fn with_access(access: AccessConfig) -> ServeConfig {
    ServeConfig {
        access,
        ..Default::default()
    }
}

/// Opens `/v1/stream{q}` with extra headers: 101 and the socket, or the refusal's status and body.
async fn open(
    addr: SocketAddr,
    q: &str,
    headers: &[(&str, &str)],
) -> Result<serve_common::Ws, (u16, String)> {
    let mut req = format!("ws://{addr}/v1/stream{q}")
        .into_client_request()
        .unwrap();
    for (k, v) in headers {
        req.headers_mut().insert(
            HeaderName::from_bytes(k.as_bytes()).unwrap(),
            HeaderValue::from_str(v).unwrap(),
        );
    }
    match tokio_tungstenite::connect_async(req).await {
        Ok((ws, _)) => Ok(ws),
        Err(tokio_tungstenite::tungstenite::Error::Http(r)) => Err((
            r.status().as_u16(),
            String::from_utf8_lossy(r.body().as_deref().unwrap_or_default()).into_owned(),
        )),
        Err(e) => panic!("{e}"),
    }
}

/// What a session got: frames, the `done` message, the close code.
#[derive(Debug, Default)]
struct Got {
    frames: usize,
    done: bool,
    close: Option<u16>,
}

/// Reads until the server closes (plain or TLS socket).
async fn read_all<S>(ws: &mut WebSocketStream<S>) -> Got
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    use futures_util::StreamExt;
    let mut g = Got::default();
    while let Some(m) = ws.next().await {
        match m {
            Ok(Message::Text(t)) if t.contains("\"index\"") => g.frames += 1,
            Ok(Message::Text(t)) if t.contains("\"done\"") => g.done = true,
            Ok(Message::Close(c)) => {
                g.close = c.map(|c| u16::from(c.code));
                break;
            }
            Ok(_) => {}
            Err(_) => break,
        }
    }
    g
}

/// Sends `seconds` of speech and the end message; returns what the server sent.
async fn run_session<S>(ws: &mut WebSocketStream<S>, seconds: f64) -> Got
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    let audio = speech_of(&common::tiny_bundle(), seconds);
    ws.send(Message::Binary(pcm_bytes(&audio, false).into()))
        .await
        .unwrap();
    ws.send(Message::Text(r#"{"type":"end"}"#.into()))
        .await
        .unwrap();
    read_all(ws).await
}

fn completed(g: &Got) -> bool {
    g.close == Some(1000) && g.done && g.frames > 0
}

#[test]
fn a_token_is_required_as_bearer_or_query_and_compared_exactly() {
    let server = start_tiny(with_access(AccessConfig {
        token: Some(TOKEN.into()),
        ..Default::default()
    }));
    let addr = server.addr();
    within(60, async {
        for (q, h) in [
            ("", vec![]),
            ("?token=wrong", vec![]),
            ("?token=s3cret-token-012345678", vec![]), // a prefix
            (
                "",
                vec![("authorization", "Bearer s3cret-token-01234567890")],
            ), // longer
            ("", vec![("authorization", "Basic czNjcmV0")]),
        ] {
            let (status, body) = open(addr, q, &h).await.expect_err("refused");
            assert_eq!(status, 401, "{q} {h:?}");
            assert!(body.contains("token"), "{body}");
        }
        let bearer = format!("Bearer {TOKEN}");
        let mut ws = open(addr, "?seed=3", &[("authorization", &bearer)])
            .await
            .expect("bearer accepted");
        assert!(completed(&run_session(&mut ws, 0.5).await));
        // the query token is taken out before the session's parameters are read
        let mut ws = open(addr, &format!("?token={TOKEN}&rate=16000"), &[])
            .await
            .expect("query token accepted");
        assert!(completed(&run_session(&mut ws, 0.5).await));
        // /healthz and /metrics stay open
        assert!(http_get(addr, "/healthz").await.starts_with("HTTP/1.1 200"));
        let m = http_get(addr, "/metrics").await;
        assert_eq!(
            metric(&m, "livegesture_refusals_total{reason=\"unauthorized\"}"),
            5.0
        );
    });
    assert_eq!(server.metrics().refusals("unauthorized"), 5);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn foreign_origins_are_refused_listed_and_own_origins_accepted() {
    let server = start_tiny(with_access(AccessConfig {
        allowed_origins: vec![AccessConfig::parse_origin("https://app.example.org").unwrap()],
        ..Default::default()
    }));
    let addr = server.addr();
    within(60, async {
        let (status, body) = open(addr, "", &[("origin", "https://evil.example")])
            .await
            .expect_err("foreign origin refused");
        assert_eq!(status, 403);
        assert!(body.contains("Origin"), "{body}");
        let (status, _) = open(addr, "", &[("origin", "https://app.example.org.evil")])
            .await
            .expect_err("a suffix is not the listed origin");
        assert_eq!(status, 403);
        let _a = open(addr, "", &[("origin", "https://app.example.org")])
            .await
            .expect("listed origin");
        // the served page's own origin: the Host the client connects to
        let own = format!("http://{addr}");
        let _b = open(addr, "", &[("origin", &own)])
            .await
            .expect("own origin");
        let _c = open(addr, "", &[]).await.expect("no Origin: not a browser");
    });
    assert_eq!(server.metrics().refusals("forbidden_origin"), 2);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn one_client_cannot_take_more_than_its_sessions() {
    let server = start_tiny(with_access(AccessConfig {
        max_sessions_per_client: 2,
        trust_forwarded_for: true,
        ..Default::default()
    }));
    let addr = server.addr();
    within(60, async {
        let mut a = open(addr, "", &[]).await.expect("first");
        let _b = open(addr, "", &[]).await.expect("second");
        let (status, body) = open(addr, "", &[]).await.expect_err("third refused");
        assert_eq!(status, 429);
        assert!(body.contains("max-sessions-per-client"), "{body}");
        // another client (behind the proxy: its X-Forwarded-For) is not affected
        let _c = open(addr, "", &[("x-forwarded-for", "10.1.2.3")])
            .await
            .expect("another client");
        // the slot comes back when a session ends, however it ends
        assert!(completed(&run_session(&mut a, 0.3).await));
        drop(a);
        let mut ok = false;
        for _ in 0..50 {
            if let Ok(ws) = open(addr, "", &[]).await {
                drop(ws);
                ok = true;
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        assert!(ok, "the ended session's slot was not released");
    });
    assert!(server.metrics().refusals("client_limit") >= 1);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn draining_turns_healthz_503_at_once_and_lets_live_sessions_finish() {
    let server = start_tiny(ServeConfig {
        drain_delay: Duration::from_secs(3),
        ..Default::default()
    });
    let addr = server.addr();
    let server = within(60, async move {
        let m = http_get(addr, "/metrics").await;
        assert_eq!(metric(&m, "livegesture_draining"), 0.0);
        assert_eq!(metric(&m, "livegesture_sessions_capacity"), 64.0);
        assert!(m.contains("livegesture_tick_lag_seconds "), "{m}");
        let mut a = open(addr, "", &[]).await.expect("a");
        let mut b = open(addr, "", &[]).await.expect("b");
        server.shutdown();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let h = http_get(addr, "/healthz").await;
        assert!(h.starts_with("HTTP/1.1 503"), "{h}");
        let m = http_get(addr, "/metrics").await;
        assert_eq!(metric(&m, "livegesture_draining"), 1.0);
        assert_eq!(metric(&m, "livegesture_sessions_slots"), 2.0);
        let (status, body) = open(addr, "", &[]).await.expect_err("no new session");
        assert_eq!(status, 503);
        assert!(body.contains("shutting down"), "{body}");
        // a live session that ends within the delay completes
        assert!(completed(&run_session(&mut a, 0.5).await));
        // one that does not is closed with 1001 once the delay is over
        let g = read_all(&mut b).await;
        assert_eq!(g.close, Some(1001), "{g:?}");
        server
    });
    // the session refused while draining is counted
    assert_eq!(server.metrics().refusals("shutting_down"), 1);
    server.join().unwrap();
}

/// A self-signed certificate for `localhost` (rcgen), written as PEM files.
fn certificate(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf, Vec<u8>) {
    let ck = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let (c, k) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&c, ck.cert.pem()).unwrap();
    std::fs::write(&k, ck.key_pair.serialize_pem()).unwrap();
    (c, k, ck.cert.der().to_vec())
}

#[test]
fn sessions_over_tls_with_a_certificate_made_here() {
    use tokio_rustls::rustls::{self, pki_types::CertificateDer};
    let dir = tempfile::tempdir().unwrap();
    let (cert, key, der) = certificate(dir.path());
    let tls = livegesture_serve::tls::load_config(&cert, &key).expect("tls config");
    // a key that is not the certificate's is refused with both flags named
    let other = tempfile::tempdir().unwrap();
    let (_, key2, _) = certificate(other.path());
    let e = livegesture_serve::tls::load_config(&cert, &key2).unwrap_err();
    assert!(format!("{e:#}").contains("--tls-key"), "{e:#}");
    let e = livegesture_serve::tls::load_config(&key, &key).unwrap_err();
    assert!(format!("{e:#}").contains("--tls-cert"), "{e:#}");
    let server = start_tiny(ServeConfig {
        tls: Some(tls),
        access: AccessConfig {
            token: Some(TOKEN.into()),
            ..Default::default()
        },
        ..Default::default()
    });
    let addr = server.addr();
    let mut roots = rustls::RootCertStore::empty();
    roots.add(CertificateDer::from(der)).unwrap();
    let client = rustls::ClientConfig::builder_with_provider(Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(client));
    within(60, async {
        let connect = || async {
            let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
            connector
                .connect("localhost".try_into().unwrap(), tcp)
                .await
                .expect("TLS handshake")
        };
        let url = format!("wss://localhost:{}/v1/stream?token={TOKEN}", addr.port());
        let (mut ws, _) = tokio_tungstenite::client_async(url.as_str(), connect().await)
            .await
            .expect("wss session");
        assert!(completed(&run_session(&mut ws, 0.5).await));
        // the page over https
        {
            use tokio::io::{AsyncReadExt, AsyncWriteExt};
            let mut s = connect().await;
            s.write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
                .await
                .unwrap();
            let mut page = Vec::new();
            let _ = s.read_to_end(&mut page).await;
            let page = String::from_utf8_lossy(&page);
            assert!(page.starts_with("HTTP/1.1 200"), "{page}");
        }
        // plain HTTP on the TLS port: the handshake fails and is counted
        let _ = tokio::time::timeout(Duration::from_secs(5), http_get(addr, "/healthz")).await;
        for _ in 0..50 {
            if server.metrics().refusals("tls_handshake") > 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    });
    assert_eq!(server.metrics().refusals("tls_handshake"), 1);
    server.shutdown();
    server.join().unwrap();
}

#[test]
fn bad_access_flags_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let short = dir.path().join("token");
    std::fs::write(&short, "short\n").unwrap();
    let exe = env!("CARGO_BIN_EXE_livegesture");
    for (args, want) in [
        (
            vec!["--auth-token-file", short.to_str().unwrap()],
            "--auth-token-file",
        ),
        (vec!["--auth-token-file", "/nonexistent/t"], "cannot read"),
        (vec!["--allowed-origin", "example.org"], "--allowed-origin"),
        (
            vec![
                "--tls-cert",
                "/nonexistent/c",
                "--tls-key",
                "/nonexistent/k",
            ],
            "--tls-cert",
        ),
        (vec!["--tls-cert", "/nonexistent/c"], "--tls-key"),
    ] {
        let out = std::process::Command::new(exe)
            .arg("serve")
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert!(err.contains(want), "{args:?}: {err}");
    }
}
