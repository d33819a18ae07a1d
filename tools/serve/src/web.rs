//! The browser page, embedded in the binary: `runtime/web/dist/` (built by vite from `runtime/web/`,
//! committed, so `cargo build` needs no npm; rebuild with `cd runtime/web && npm ci && npm run build`),
//! `/skeleton.json`, the project's skeleton ([`livegesture::skeleton`]) the page poses, and `/face.bin`,
//! the face mesh the page's figure wears ([`livegesture::face::mesh`], docs/face.md).

use std::sync::Arc;

use axum::http::header;
use axum::response::IntoResponse;
use axum::routing::get;
use axum::Router;

use super::AppState;
pub use livegesture::skeleton::skeleton_json;

const INDEX_HTML: &[u8] = include_bytes!("../../../runtime/web/dist/index.html");
const APP_JS: &[u8] = include_bytes!("../../../runtime/web/dist/assets/app.js");
const WORKLET_JS: &[u8] = include_bytes!("../../../runtime/web/dist/worklet.js");
const WORKER_JS: &[u8] = include_bytes!("../../../runtime/web/dist/worker.js");

fn asset(body: &'static [u8], mime: &'static str) -> impl IntoResponse {
    (
        [
            (header::CONTENT_TYPE, mime),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
}

/// A file of `--web-dir` (docs/wasm.md): the WebAssembly runtime (`wasm/`) and the bundle
/// (`bundle/`) of the static build. Only plain relative paths inside the folder; 404 otherwise.
async fn web_dir_file(
    axum::extract::State(state): axum::extract::State<Arc<AppState>>,
    uri: axum::http::Uri,
) -> axum::response::Response {
    use axum::http::StatusCode;
    let not_found = || (StatusCode::NOT_FOUND, "not found").into_response();
    let Some(dir) = &state.cfg.web_dir else {
        return not_found();
    };
    let rel = uri.path().trim_start_matches('/');
    if rel.is_empty()
        || rel
            .split('/')
            .any(|c| c.is_empty() || c == "." || c == ".." || c.contains('\\'))
    {
        return not_found();
    }
    let path = dir.join(rel);
    let mime = match path.extension().and_then(|e| e.to_str()) {
        Some("wasm") => "application/wasm",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("json") => "application/json",
        Some("html") => "text/html; charset=utf-8",
        Some("wav") => "audio/wav",
        _ => "application/octet-stream",
    };
    match tokio::fs::read(&path).await {
        Ok(body) => (
            [
                (header::CONTENT_TYPE, mime),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            body,
        )
            .into_response(),
        Err(_) => not_found(),
    }
}

pub(crate) fn routes() -> Router<Arc<AppState>> {
    Router::new()
        .route(
            "/",
            get(|| async { asset(INDEX_HTML, "text/html; charset=utf-8") }),
        )
        .route(
            "/index.html",
            get(|| async { asset(INDEX_HTML, "text/html; charset=utf-8") }),
        )
        .route(
            "/assets/app.js",
            get(|| async { asset(APP_JS, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/worklet.js",
            get(|| async { asset(WORKLET_JS, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/worker.js",
            get(|| async { asset(WORKER_JS, "text/javascript; charset=utf-8") }),
        )
        .fallback(web_dir_file)
        .route(
            "/face.bin",
            get(|| async {
                asset(
                    livegesture::face::mesh::asset_bytes(),
                    "application/octet-stream",
                )
            }),
        )
        .route(
            "/skeleton.json",
            get(|| async {
                (
                    [(header::CONTENT_TYPE, "application/json")],
                    skeleton_json(),
                )
            }),
        )
}
