//! Who may open a session (docs/deploy.md#who-may-connect): a shared token, an allowed-origins list
//! for browsers, and a per-client session limit. Checked on `GET /v1/stream` before the upgrade;
//! `/healthz`, `/metrics` and the page stay open (a load balancer and Prometheus need no token, the
//! page holds no secret: it only opens sessions, which take the token).
//!
//! - token (`--auth-token-file`): `Authorization: Bearer <token>` or the `token` query parameter
//!   (browsers cannot set headers on a WebSocket), compared in constant time; missing or wrong: HTTP
//!   401 with `WWW-Authenticate: Bearer`, reason `unauthorized`;
//! - origins (`--allowed-origin`): a request with an `Origin` header that is neither listed nor the
//!   page's own origin (the `Origin`'s host equals the request's `Host`) gets HTTP 403, reason
//!   `forbidden_origin`; requests without `Origin` (non-browser clients) are not affected; with no
//!   list every origin is allowed;
//! - per-client limit (`--max-sessions-per-client`): live sessions per client IP (the TCP peer, or
//!   the last `X-Forwarded-For` entry with `--trust-forwarded-for`, for a server behind a proxy that
//!   sets it); more get HTTP 429, reason `client_limit`. The slot is held by the connection itself
//!   ([`ConnIo`](crate::tls::ConnIo)), so it is released whenever the session's socket goes away, however it ended.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context, Result};
use axum::extract::{ConnectInfo, Request, State};
use axum::http::{header, HeaderMap, StatusCode, Uri};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use subtle::ConstantTimeEq;

use super::AppState;

/// The access settings of a server (all off by default: any client, any origin, no per-client limit).
#[derive(Debug, Clone, Default)]
pub struct AccessConfig {
    /// The shared secret a session must present; `None`: no token needed.
    pub token: Option<String>,
    /// Origins allowed besides the page's own, normalised `scheme://host[:port]` (lower case, no
    /// trailing slash); empty: any origin.
    pub allowed_origins: Vec<String>,
    /// Most live sessions per client; 0: no limit (only `max_sessions`).
    pub max_sessions_per_client: usize,
    /// Take the client's address from the last `X-Forwarded-For` entry (behind a proxy that sets it).
    pub trust_forwarded_for: bool,
}

impl AccessConfig {
    /// Reads the token from `path`: the file's content without surrounding whitespace, at least 16
    /// characters.
    pub fn read_token(path: &Path) -> Result<String> {
        let raw = std::fs::read_to_string(path)
            .with_context(|| format!("--auth-token-file {}: cannot read", path.display()))?;
        let t = raw.trim();
        if t.len() < 16 {
            bail!(
                "--auth-token-file {}: the token must be at least 16 characters (found {})",
                path.display(),
                t.len()
            );
        }
        if t.chars().any(|c| c.is_whitespace() || c.is_control()) {
            bail!(
                "--auth-token-file {}: the token must be one line without spaces",
                path.display()
            );
        }
        Ok(t.to_string())
    }

    /// Normalises an `--allowed-origin` value: `scheme://host[:port]`, scheme http or https.
    pub fn parse_origin(s: &str) -> Result<String> {
        let o = s.trim().trim_end_matches('/').to_ascii_lowercase();
        let rest = o
            .strip_prefix("https://")
            .or_else(|| o.strip_prefix("http://"));
        match rest {
            Some(h) if !h.is_empty() && !h.contains(['/', '?', '#', '@', ' ']) => Ok(o),
            _ => bail!(
                "--allowed-origin {s:?}: expected scheme://host[:port] with scheme http or https, e.g. https://example.org"
            ),
        }
    }
}

/// Live sessions per client key.
#[derive(Debug, Default)]
pub(crate) struct ClientTable {
    live: Mutex<HashMap<IpAddr, usize>>,
}

/// One session's place in the [`ClientTable`]; released on drop.
#[derive(Debug)]
pub(crate) struct ClientGuard {
    table: Arc<ClientTable>,
    key: IpAddr,
}

impl ClientTable {
    fn try_acquire(self: &Arc<Self>, key: IpAddr, max: usize) -> Option<ClientGuard> {
        let mut live = self.live.lock().unwrap_or_else(|e| e.into_inner());
        let n = live.entry(key).or_insert(0);
        if *n >= max {
            return None;
        }
        *n += 1;
        Some(ClientGuard {
            table: self.clone(),
            key,
        })
    }

    /// Live sessions of `key`.
    #[cfg(test)]
    pub(crate) fn live(&self, key: IpAddr) -> usize {
        let live = self.live.lock().unwrap_or_else(|e| e.into_inner());
        live.get(&key).copied().unwrap_or(0)
    }
}

impl Drop for ClientGuard {
    fn drop(&mut self) {
        let mut live = self.table.live.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = live.get_mut(&self.key) {
            *n -= 1;
            if *n == 0 {
                live.remove(&self.key);
            }
        }
    }
}

/// What a connection holds for as long as it is open (the per-client slot of its session).
pub(crate) type Hold = Arc<Mutex<Option<ClientGuard>>>;

/// The connect info of every request: the TCP peer and the connection's hold on its client slot (`Hold`).
#[derive(Debug, Clone)]
pub struct ClientAddr {
    pub peer: SocketAddr,
    pub(crate) hold: Hold,
}

fn refuse(st: &AppState, status: StatusCode, reason: &str, msg: &str) -> Response {
    st.metrics.refuse(reason);
    let mut r = (status, format!("{msg}\n")).into_response();
    if status == StatusCode::UNAUTHORIZED {
        r.headers_mut().insert(
            header::WWW_AUTHENTICATE,
            header::HeaderValue::from_static("Bearer realm=\"livegesture\""),
        );
    }
    r
}

/// The token the request presents: `Authorization: Bearer`, else the `token` query parameter.
fn presented_token(headers: &HeaderMap, uri: &Uri) -> Option<String> {
    if let Some(v) = headers.get(header::AUTHORIZATION) {
        let v = v.to_str().ok()?;
        let (scheme, rest) = v.split_once(' ')?;
        return scheme
            .eq_ignore_ascii_case("bearer")
            .then(|| rest.trim().to_string());
    }
    let q = uri.query()?;
    form_pairs(q)
        .into_iter()
        .find(|(k, _)| k == "token")
        .map(|(_, v)| v)
}

fn form_pairs(q: &str) -> Vec<(String, String)> {
    serde_urlencoded::from_str(q).unwrap_or_default()
}

/// The URI without the `token` query parameter (the session's parameter parser refuses unknown ones).
fn without_token(uri: &Uri) -> Uri {
    let Some(q) = uri.query() else {
        return uri.clone();
    };
    let kept: Vec<&str> = q
        .split('&')
        .filter(|p| !p.is_empty() && p.split('=').next() != Some("token"))
        .collect();
    let pq = if kept.is_empty() {
        uri.path().to_string()
    } else {
        format!("{}?{}", uri.path(), kept.join("&"))
    };
    let mut parts = uri.clone().into_parts();
    parts.path_and_query = pq.parse().ok();
    Uri::from_parts(parts).unwrap_or_else(|_| uri.clone())
}

/// Whether `origin` may open a session: listed, or the page's own (same host as the request).
fn origin_allowed(cfg: &AccessConfig, headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return true;
    };
    if cfg.allowed_origins.is_empty() {
        return true;
    }
    let Ok(origin) = origin.to_str() else {
        return false;
    };
    let o = origin.trim_end_matches('/').to_ascii_lowercase();
    if cfg.allowed_origins.contains(&o) {
        return true;
    }
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .map(|h| h.to_ascii_lowercase());
    let authority = o
        .strip_prefix("https://")
        .or_else(|| o.strip_prefix("http://"));
    matches!((authority, host), (Some(a), Some(h)) if a == h)
}

/// The client's address for the per-client limit.
fn client_key(cfg: &AccessConfig, peer: SocketAddr, headers: &HeaderMap) -> IpAddr {
    if cfg.trust_forwarded_for {
        let last = headers
            .get_all("x-forwarded-for")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(','))
            .filter_map(|s| s.trim().parse::<IpAddr>().ok())
            .next_back();
        if let Some(ip) = last {
            return ip;
        }
    }
    peer.ip()
}

/// Middleware of `GET /v1/stream`: token, origin, per-client limit (in that order), then the upgrade.
pub(crate) async fn check(
    State(st): State<Arc<AppState>>,
    ConnectInfo(client): ConnectInfo<ClientAddr>,
    mut req: Request,
    next: Next,
) -> Response {
    let cfg = &st.cfg.access;
    if let Some(expected) = &cfg.token {
        let ok = presented_token(req.headers(), req.uri())
            .is_some_and(|t| bool::from(t.as_bytes().ct_eq(expected.as_bytes())));
        if !ok {
            return refuse(
                &st,
                StatusCode::UNAUTHORIZED,
                "unauthorized",
                "a valid token is required: Authorization: Bearer <token> or ?token=<token>",
            );
        }
    }
    if !origin_allowed(cfg, req.headers()) {
        return refuse(
            &st,
            StatusCode::FORBIDDEN,
            "forbidden_origin",
            "this Origin may not open sessions (see --allowed-origin)",
        );
    }
    let guard = if cfg.max_sessions_per_client > 0 {
        let key = client_key(cfg, client.peer, req.headers());
        match st.clients.try_acquire(key, cfg.max_sessions_per_client) {
            Some(g) => Some(g),
            None => {
                return refuse(
                    &st,
                    StatusCode::TOO_MANY_REQUESTS,
                    "client_limit",
                    &format!(
                        "this client already has {} live sessions (--max-sessions-per-client)",
                        cfg.max_sessions_per_client
                    ),
                )
            }
        }
    } else {
        None
    };
    let uri = without_token(req.uri());
    *req.uri_mut() = uri;
    let resp = next.run(req).await;
    if resp.status() == StatusCode::SWITCHING_PROTOCOLS {
        // the connection now carries the session: it holds the slot until it closes
        *client.hold.lock().unwrap_or_else(|e| e.into_inner()) = guard;
    }
    resp
}

/// Middleware of every route: the plain peer address as `ConnectInfo<SocketAddr>` (what the session
/// handler reads).
pub(crate) async fn peer_info(
    ConnectInfo(client): ConnectInfo<ClientAddr>,
    mut req: Request,
    next: Next,
) -> Response {
    req.extensions_mut().insert(ConnectInfo(client.peer));
    next.run(req).await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hm(pairs: &[(&str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(
                header::HeaderName::from_bytes(k.as_bytes()).unwrap(),
                v.parse().unwrap(),
            );
        }
        h
    }

    #[test]
    fn tokens_from_header_or_query() {
        let u: Uri = "/v1/stream?rate=16000&token=abc%2Bd&seed=1"
            .parse()
            .unwrap();
        assert_eq!(
            presented_token(&HeaderMap::new(), &u).as_deref(),
            Some("abc+d")
        );
        let h = hm(&[("authorization", "Bearer xyz")]);
        assert_eq!(presented_token(&h, &u).as_deref(), Some("xyz"));
        let h = hm(&[("authorization", "Basic xyz")]);
        assert_eq!(presented_token(&h, &u), None);
        assert_eq!(
            without_token(&u).to_string(),
            "/v1/stream?rate=16000&seed=1"
        );
        let u: Uri = "/v1/stream?token=a".parse().unwrap();
        assert_eq!(without_token(&u).to_string(), "/v1/stream");
    }

    #[test]
    fn origins() {
        let cfg = AccessConfig {
            allowed_origins: vec![AccessConfig::parse_origin("https://Good.example/").unwrap()],
            ..Default::default()
        };
        let ok = |o: &str, host: &str| origin_allowed(&cfg, &hm(&[("origin", o), ("host", host)]));
        assert!(ok("https://good.example", "srv:8765"));
        assert!(ok("http://srv:8765", "srv:8765"), "the page's own origin");
        assert!(!ok("https://evil.example", "srv:8765"));
        assert!(!ok("https://good.example.evil", "srv:8765"));
        assert!(origin_allowed(&cfg, &hm(&[("host", "srv")])), "no Origin");
        assert!(AccessConfig::parse_origin("ftp://x").is_err());
        assert!(AccessConfig::parse_origin("https://x/path").is_err());
    }

    #[test]
    fn client_table_releases() {
        let t = Arc::new(ClientTable::default());
        let ip: IpAddr = "10.0.0.1".parse().unwrap();
        let a = t.try_acquire(ip, 2).unwrap();
        let _b = t.try_acquire(ip, 2).unwrap();
        assert!(t.try_acquire(ip, 2).is_none());
        drop(a);
        assert_eq!(t.live(ip), 1);
        assert!(t.try_acquire(ip, 2).is_some());
        let cfg = AccessConfig {
            trust_forwarded_for: true,
            ..Default::default()
        };
        let h = hm(&[("x-forwarded-for", "1.2.3.4, 10.9.9.9")]);
        assert_eq!(
            client_key(&cfg, "127.0.0.1:1".parse().unwrap(), &h),
            "10.9.9.9".parse::<IpAddr>().unwrap()
        );
    }
}
