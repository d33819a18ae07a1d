//! What the `serve` tests of both families share (`serve`, `serve_diffsheg`, `serve_access`,
//! `serve_web_dir`, `loadtest`): a server on the tiny bundle, the tract backend and the server's [`ModelInfo`], test audio as WAV files and PCM messages, the
//! WebSocket client (connect, send a session, collect what the server sends) and the frame comparison.
//! Declared once in `main.rs`; each serve module uses it (`use crate::serve_common`), not every one every helper.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Stdio};
use std::thread::JoinHandle;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use livegesture::audio::{read_wav_16k_mono, AudioSpan};
use livegesture::backend::{self, Backend, BackendKind, BackendOptions};
use livegesture::bundle::Bundle;
use livegesture::compare::{self, Diff};
use livegesture::model::livegesture::LiveGestureGraphs;
use livegesture::output::{Beat2Motion, Frame};
use livegesture_parity_tests as common;
use livegesture_serve::{ModelInfo, ServeConfig, Server};
use tokio_tungstenite::tungstenite::Message;

/// The backend the tests run on: tract, CPU, one thread.
pub fn tract_backend() -> Box<dyn Backend> {
    backend::create(&BackendOptions {
        kind: BackendKind::Tract,
        execution_provider: "cpu".into(),
        intra_threads: 1,
        ort_library: None,
    })
    .expect("backend")
}

/// The `ModelInfo` a test server announces for `bundle` under the name `model`.
pub fn model_info(model: &str, bundle: &Bundle, backend: &str) -> ModelInfo {
    ModelInfo {
        model: model.into(),
        family: bundle.family(),
        bundle_sha256: "0".repeat(64),
        backend: backend.into(),
        fps: bundle.frontend().fps,
        frames_per_token: bundle.frontend().frames_per_token,
        frontend: bundle.frontend().clone(),
        // the test servers run the family's graphs without a face wrapper
        face: false,
    }
}

/// A server on a free local port running the tiny LiveGesture test bundle on tract (model `test`).
pub fn start_tiny(cfg: ServeConfig) -> Server {
    Server::start("127.0.0.1:0".parse().unwrap(), cfg, || {
        let bundle = Bundle::load(common::tiny_bundle()).expect("bundle");
        let p = LiveGestureGraphs::new(&bundle, tract_backend().as_ref()).expect("pipeline");
        let info = model_info("test", &bundle, p.backend_name());
        Ok((p, info))
    })
    .expect("server starts")
}

/// `seconds` of the bundle at `dir`'s reference speech clip at 16 kHz (repeated if shorter).
pub fn speech_of(dir: &Path, seconds: f64) -> Vec<f32> {
    let clip = read_wav_16k_mono(dir.join("reference/clip.wav")).unwrap();
    let n = (seconds * 16000.0) as usize;
    clip.iter().copied().cycle().take(n).collect()
}

pub fn write_wav(path: &Path, rate: u32, channels: u16, float: bool, samples: &[f32]) {
    let spec = hound::WavSpec {
        channels,
        sample_rate: rate,
        bits_per_sample: if float { 32 } else { 16 },
        sample_format: if float {
            hound::SampleFormat::Float
        } else {
            hound::SampleFormat::Int
        },
    };
    let mut w = hound::WavWriter::create(path, spec).unwrap();
    for &s in samples {
        if float {
            w.write_sample(s).unwrap();
        } else {
            w.write_sample(s16(s)).unwrap();
        }
    }
    w.finalize().unwrap();
}

pub fn s16(x: f32) -> i16 {
    (x * 32768.0).round().clamp(-32768.0, 32767.0) as i16
}

pub fn pcm_bytes(samples: &[f32], float: bool) -> Vec<u8> {
    let mut b = Vec::with_capacity(samples.len() * 4);
    for &s in samples {
        if float {
            b.extend_from_slice(&s.to_le_bytes());
        } else {
            b.extend_from_slice(&s16(s).to_le_bytes());
        }
    }
    b
}

/// What `generate` reads for these interleaved samples: written as a WAV file and read back by
/// `read_wav_16k_mono`; with the input's own sample count and rate (for the stream's `finish`).
pub fn generate_input(
    samples: &[f32],
    rate: u32,
    channels: u16,
    float: bool,
) -> (Vec<f32>, AudioSpan) {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("in.wav");
    write_wav(&wav, rate, channels, float, samples);
    let a16 = read_wav_16k_mono(&wav).unwrap();
    (
        a16,
        AudioSpan::new((samples.len() / channels as usize) as u64, rate),
    )
}

/// Runs the `livegesture generate` binary on `audio` (16 kHz mono, written as a 16-bit WAV) with
/// `bundle`, tract and `seed`, and reads back the npz it wrote.
pub fn generate_binary(bundle: &Path, audio: &[f32], seed: u64) -> Beat2Motion {
    let dir = tempfile::tempdir().unwrap();
    let wav = dir.path().join("a.wav");
    write_wav(&wav, 16000, 1, false, audio);
    let npz = dir.path().join("a.npz");
    let st = crate::support::livegesture()
        .arg("generate")
        .arg(&wav)
        .arg("-o")
        .arg(&npz)
        .args([
            "--seed",
            &seed.to_string(),
            "--backend",
            "tract",
            "--bundle",
        ])
        .arg(bundle)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
    livegesture::output::read_beat2_npz(&npz).unwrap()
}

/// Asserts that a session's frames are the generate binary's (`m`): the same count, and poses,
/// expressions and translation each within `bound` (scaled, `livegesture::compare`: NaN or Inf on
/// either side fails); a failure names the field, the frame and the value pair.
pub fn assert_matches_generate(got: &[Frame], m: &Beat2Motion, bound: f64) {
    assert_eq!(m.len(), got.len(), "frame count: generate vs the session");
    for (name, width) in [("poses", 165), ("expressions", 100), ("trans", 3)] {
        let field = |f: &Frame| -> Vec<f32> {
            match name {
                "poses" => f.poses.to_vec(),
                "expressions" => f.expressions.to_vec(),
                _ => f.trans.to_vec(),
            }
        };
        let of_npz = match name {
            "poses" => &m.poses,
            "expressions" => &m.expressions,
            _ => &m.trans,
        };
        let g: Vec<f32> = got.iter().flat_map(field).collect();
        let w: Vec<f32> = of_npz.iter().copied().collect();
        assert_eq!(w.len(), got.len() * width, "{name}: npz width");
        let d = compare::diff(&g, &w);
        let frame = d.index.unwrap_or(0) / width;
        if let Err(e) = d.ensure(bound, format!("serve vs the generate binary: {name}")) {
            panic!("{e} (frame {frame})");
        }
    }
}

/// The frames as the npz `generate` writes ([`Beat2Motion`]), for tests of the comparisons.
pub fn motion_of(frames: &[Frame]) -> Beat2Motion {
    let rows = |f: fn(&Frame) -> &[f32], w: usize| {
        ndarray::Array2::from_shape_vec(
            (frames.len(), w),
            frames.iter().flat_map(|x| f(x).to_vec()).collect(),
        )
        .unwrap()
    };
    Beat2Motion {
        poses: rows(|f| &f.poses[..], 165),
        trans: rows(|f| &f.trans[..], 3),
        expressions: rows(|f| &f.expressions[..], 100),
    }
}

#[derive(Debug, Default)]
pub struct Outcome {
    pub ready: Option<serde_json::Value>,
    pub frames: Vec<Frame>,
    pub done: Option<u64>,
    pub close: Option<(u16, String)>,
}

pub fn url(addr: SocketAddr, q: &str) -> String {
    format!("ws://{addr}/v1/stream{q}")
}

pub type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

pub async fn connect(addr: SocketAddr, q: &str) -> Ws {
    let (ws, resp) = tokio_tungstenite::connect_async(url(addr, q))
        .await
        .expect("upgrade");
    assert_eq!(resp.status(), 101);
    ws
}

pub async fn collect(ws: &mut Ws, out: &mut Outcome) {
    while let Some(m) = ws.next().await {
        match m {
            Ok(Message::Text(t)) => {
                let v: serde_json::Value = serde_json::from_str(&t).expect("server text is JSON");
                match v.get("type").and_then(|t| t.as_str()) {
                    Some("ready") => out.ready = Some(v),
                    Some("done") => out.done = v["frames"].as_u64(),
                    Some(other) => panic!("unexpected control message {other}"),
                    None => out
                        .frames
                        .push(Frame::from_json_line(&t).expect("frame JSON")),
                }
            }
            Ok(Message::Binary(b)) => out
                .frames
                .push(Frame::decode_binary(&b).expect("frame record")),
            Ok(Message::Close(c)) => {
                out.close = c.map(|c| (u16::from(c.code), c.reason.to_string()));
            }
            Ok(_) => {}
            Err(_) => break,
        }
    }
}

/// Sends `bytes` cut at `cuts` (message lengths, cycled), then `{"type":"end"}`, and collects.
pub async fn session(addr: SocketAddr, q: &str, bytes: &[u8], cuts: &[usize]) -> Outcome {
    let mut ws = connect(addr, q).await;
    let mut i = 0;
    let mut k = 0;
    while i < bytes.len() {
        let n = cuts[k % cuts.len()].min(bytes.len() - i);
        ws.send(Message::Binary(bytes[i..i + n].to_vec().into()))
            .await
            .unwrap();
        i += n;
        k += 1;
    }
    ws.send(Message::Text(r#"{"type":"end"}"#.into()))
        .await
        .unwrap();
    let mut out = Outcome::default();
    collect(&mut ws, &mut out).await;
    out
}

/// The comparison of a session's frames with `want` (`livegesture::compare` per field: NaN or Inf on
/// either side, or nothing compared, fail); panics on a count, index or timestamp mismatch.
pub fn frames_diff(got: &[Frame], want: &[Frame], what: &str) -> (&'static str, Diff) {
    assert_eq!(got.len(), want.len(), "{what}: frame count");
    for (g, w) in got.iter().zip(want) {
        assert_eq!(g.index, w.index, "{what}: index");
        assert!((g.time_s - w.time_s).abs() < 1e-12, "{what}: time_s");
    }
    common::frames_diff(got, want)
}

/// Largest |difference| of the frames (infinite when a value is NaN or Inf, or nothing is compared),
/// for the checks that two sessions differ.
pub fn max_diff(got: &[Frame], want: &[Frame], what: &str) -> f64 {
    frames_diff(got, want, what).1.max_abs
}

/// The session's frames equal `want` within 1e-4 (scaled, docs/parity.md); a failure names the field,
/// the error, the scale and where.
/// 44.1 kHz stereo f32le `bytes` sent in two ways of cutting them into messages (binary records, seed 9):
/// each gives `want` exactly and closes normally (1000), within `secs`.
pub fn assert_stereo_f32_splits(addr: SocketAddr, bytes: &[u8], want: &[Frame], secs: u64) {
    for cuts in [vec![4410 * 8], vec![8191, 5, 3]] {
        let got = within(
            secs,
            session(
                addr,
                "?rate=44100&channels=2&format=f32le&output=binary&seed=9",
                bytes,
                &cuts,
            ),
        );
        assert_equal(
            &got.frames,
            want,
            &format!("44.1 kHz stereo f32le, split {cuts:?}"),
        );
        assert_eq!(got.close.as_ref().map(|c| c.0), Some(1000));
    }
}

pub fn assert_equal(got: &[Frame], want: &[Frame], what: &str) {
    let (field, d) = frames_diff(got, want, what);
    if let Err(e) = d.ensure(
        1e-4,
        format!("{what}: frames differ from generate: {field}"),
    ) {
        panic!("{e}");
    }
}

pub fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

pub fn within<F: std::future::Future>(secs: u64, f: F) -> F::Output {
    rt().block_on(async {
        tokio::time::timeout(Duration::from_secs(secs), f)
            .await
            .expect("test timed out")
    })
}

/// `livegesture serve` on `bundle` as a child process (tract, any free port, 256 pending tokens):
/// the child, the address it listens on, and a thread collecting the rest of its log.
pub fn spawn_serve(bundle: &Path) -> (Child, SocketAddr, JoinHandle<String>) {
    spawn_serve_with(bundle, &["--max-pending-tokens", "256"])
}

/// [`spawn_serve`] with other options (`extra`, e.g. `--queue-frames 8`).
pub fn spawn_serve_with(bundle: &Path, extra: &[&str]) -> (Child, SocketAddr, JoinHandle<String>) {
    let mut child = crate::support::livegesture()
        .args(["serve", "--addr", "127.0.0.1:0", "--backend", "tract"])
        .args(extra)
        .arg("--bundle")
        .arg(bundle)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    let addr: SocketAddr = loop {
        line.clear();
        assert!(
            err.read_line(&mut line).unwrap() > 0,
            "serve ended before listening"
        );
        if let Some(rest) = line.split("listening on http://").nth(1) {
            break rest.split_whitespace().next().unwrap().parse().unwrap();
        }
    };
    let log = std::thread::spawn(move || {
        let mut all = String::new();
        for l in err.lines() {
            all.push_str(&l.unwrap());
            all.push('\n');
        }
        all
    });
    (child, addr, log)
}

/// Reads until `out` holds `n` frames (JSON lines; the other messages are skipped).
pub async fn read_frames(ws: &mut Ws, out: &mut Outcome, n: usize) {
    while out.frames.len() < n {
        match ws.next().await.unwrap().unwrap() {
            Message::Text(t) if t.contains("\"index\"") => {
                out.frames.push(Frame::from_json_line(&t).unwrap())
            }
            _ => {}
        }
    }
}

/// Waits for the child and its log; asserts it exited with 0.
pub fn exited_ok(mut child: Child, log: JoinHandle<String>) -> String {
    let status = child.wait().unwrap();
    let log = log.join().unwrap();
    assert!(status.success(), "serve exited with {status}\n{log}");
    log
}

/// The value of `name` in a Prometheus text exposition (`/metrics`).
pub fn metric(text: &str, name: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(name).and_then(|r| r.strip_prefix(' ')))
        .unwrap_or_else(|| panic!("{name} not in\n{text}"))
        .parse()
        .unwrap()
}

/// `GET path` over HTTP/1.1 with `Connection: close`: the whole response (head and body) as text.
pub async fn http_get(addr: SocketAddr, path: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    String::from_utf8_lossy(&buf).into_owned()
}
