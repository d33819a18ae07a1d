//! `livegesture serve --web-dir` (docs/wasm.md): the folder's files are served beside the page (the
//! WebAssembly runtime and a bundle, so `/?engine=wasm` runs in the browser); only plain relative
//! paths inside the folder, nothing without the option, the server's own routes first.

use crate::serve_common;

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};

use livegesture_serve::ServeConfig;
use serve_common::start_tiny;

/// `GET path` over a raw connection (the path is sent as given, unnormalised): (status, content type, body).
fn get(addr: SocketAddr, path: &str) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&raw[..split]).to_string();
    let status = head[9..12].parse().unwrap();
    let ctype = head
        .lines()
        .find_map(|l| {
            l.to_ascii_lowercase()
                .strip_prefix("content-type: ")
                .map(str::to_string)
        })
        .unwrap_or_default();
    (status, ctype, raw[split + 4..].to_vec())
}

#[test]
fn web_dir_files_are_served_and_nothing_outside_it() {
    let root = tempfile::tempdir().unwrap();
    let site = root.path().join("site");
    std::fs::create_dir_all(site.join("wasm")).unwrap();
    std::fs::write(site.join("wasm/x_bg.wasm"), b"\0asm-test").unwrap();
    std::fs::write(site.join("wasm/x.js"), b"export {};").unwrap();
    std::fs::write(root.path().join("secret.txt"), b"outside").unwrap();
    let server = start_tiny(ServeConfig {
        web_dir: Some(site.clone()),
        ..Default::default()
    });
    let addr = server.addr();
    let (st, ct, body) = get(addr, "/wasm/x_bg.wasm");
    assert_eq!(
        (st, ct.as_str(), &body[..]),
        (200, "application/wasm", &b"\0asm-test"[..])
    );
    let (st, ct, _) = get(addr, "/wasm/x.js");
    assert_eq!(st, 200);
    assert!(ct.starts_with("text/javascript"), "{ct}");
    // the server's own routes come first
    let (st, _, body) = get(addr, "/skeleton.json");
    assert_eq!(st, 200);
    assert!(String::from_utf8_lossy(&body).contains("\"parents\""));
    let (st, _, body) = get(addr, "/worker.js");
    assert_eq!(st, 200);
    assert!(String::from_utf8_lossy(&body).contains("livegesture_wasm.js"));
    // nothing outside the folder, nothing missing
    for bad in [
        "/../secret.txt",
        "/wasm/../../secret.txt",
        "/wasm/%2e%2e/%2e%2e/secret.txt",
        "/wasm//x.js",
        "/missing.wasm",
    ] {
        let (st, _, body) = get(addr, bad);
        assert_eq!(st, 404, "{bad}: {}", String::from_utf8_lossy(&body));
    }
    server.shutdown();
    server.join().unwrap();

    // without --web-dir: nothing beyond the page
    let server = start_tiny(ServeConfig::default());
    let (st, _, _) = get(server.addr(), "/wasm/x.js");
    assert_eq!(st, 404);
    server.shutdown();
    server.join().unwrap();
}
