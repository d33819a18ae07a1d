//! Load test and soak for `livegesture serve` (loopback only; bounded in sessions and time).
//!
//! Ramp: for each level of concurrent sessions, every session streams speech in real time (20 ms
//! messages, 16 kHz s16le, start phases spread over one token) for `--hold` seconds; token latency is
//! measured per token from sending the message that completes the token's audio to receiving its last
//! frame. A level is sustained when no session failed and p99 < `--p99-ms`. The ramp stops at the first
//! level that is not.
//!
//! ```sh
//! taskset -c 0 livegesture serve --backend ort --max-sessions 256 &
//! cargo run --release --example serve_load -- ramp --levels 8,16,24,32,48,64 --hold 20
//! cargo run --release --example serve_load -- soak --sessions 16 --seconds 600 --pid $(pgrep -f 'livegesture serve')
//! ```
//!
//! Soak: `--sessions` live sessions with churn (each lasts 3..20 s, then ends with `end` and a new one
//! starts), for `--seconds`; the server's RSS (`/proc/PID/status` VmRSS) is sampled every 10 s.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;

const RATE: u64 = 16000;
const CHUNK: usize = 320; // 20 ms

fn arg(args: &[String], name: &str, default: &str) -> String {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .cloned()
        .unwrap_or_else(|| default.to_string())
}

fn load_audio(path: &str) -> Vec<i16> {
    let a = livegesture::audio::read_wav_16k_mono(path).expect("audio");
    a.iter()
        .map(|&x| (x * 32767.0).round().clamp(-32768.0, 32767.0) as i16)
        .collect()
}

#[derive(Default, Debug)]
struct Result_ {
    latencies_ms: Vec<f64>,
    failed: Option<String>,
    frames: u64,
}

/// One real-time session of `seconds` of audio; returns its token latencies.
async fn session(
    url: String,
    audio: Arc<Vec<i16>>,
    offset: usize,
    seconds: f64,
    delay: Duration,
    seed: u64,
) -> Result_ {
    tokio::time::sleep(delay).await;
    let mut r = Result_::default();
    let (ws, _) = match tokio_tungstenite::connect_async(format!(
        "{url}/v1/stream?seed={seed}&output=binary"
    ))
    .await
    {
        Ok(x) => x,
        Err(e) => {
            r.failed = Some(format!("connect: {e}"));
            return r;
        }
    };
    let (mut tx, mut rx) = ws.split();
    // the first message is ready
    match rx.next().await {
        Some(Ok(Message::Text(t))) if t.contains("\"ready\"") => {}
        other => {
            r.failed = Some(format!("no ready: {other:?}"));
            return r;
        }
    }
    let total = (seconds * RATE as f64) as usize;
    // (cumulative samples after the message, send instant)
    let log: Arc<Mutex<Vec<(u64, Instant)>>> = Arc::new(Mutex::new(Vec::new()));
    let log2 = log.clone();
    let sender = tokio::spawn(async move {
        let t0 = Instant::now();
        let mut sent = 0usize;
        let mut buf = Vec::with_capacity(CHUNK * 2);
        while sent < total {
            let due = t0 + Duration::from_secs_f64(sent as f64 / RATE as f64);
            tokio::time::sleep_until(due.into()).await;
            buf.clear();
            for k in 0..CHUNK.min(total - sent) {
                let s = audio[(offset + sent + k) % audio.len()];
                buf.extend_from_slice(&s.to_le_bytes());
            }
            let n = buf.len() / 2;
            if tx.send(Message::Binary(buf.clone().into())).await.is_err() {
                return Err("send failed".to_string());
            }
            sent += n;
            log2.lock().unwrap().push((sent as u64, Instant::now()));
        }
        tx.send(Message::Text(r#"{"type":"end"}"#.into()))
            .await
            .map_err(|e| e.to_string())?;
        Ok(tx)
    });
    let mut done = false;
    while let Some(m) = rx.next().await {
        match m {
            Ok(Message::Binary(b)) if b.len() == 1104 => {
                let idx = u64::from_le_bytes(b[..8].try_into().unwrap());
                r.frames += 1;
                if idx % 4 == 3 {
                    let t = idx / 4;
                    let need = (t + 1) * 4 * RATE / 30; // token_end(t) at 16 kHz
                    let now = Instant::now();
                    let l = log.lock().unwrap();
                    if let Some(&(_, at)) = l.iter().find(|(c, _)| *c >= need) {
                        r.latencies_ms.push((now - at).as_secs_f64() * 1e3);
                    }
                }
            }
            Ok(Message::Text(t)) if t.contains("\"done\"") => done = true,
            Ok(Message::Close(c)) => {
                if !done {
                    r.failed = Some(format!("closed early: {c:?}"));
                }
                break;
            }
            Ok(_) => {}
            Err(e) => {
                r.failed = Some(format!("receive: {e}"));
                break;
            }
        }
    }
    match sender.await {
        Ok(Ok(_)) => {}
        Ok(Err(e)) => r.failed = r.failed.or(Some(e)),
        Err(e) => r.failed = r.failed.or(Some(e.to_string())),
    }
    if !done && r.failed.is_none() {
        r.failed = Some("no done".into());
    }
    r
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn rss_kib(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    s.lines()
        .find(|l| l.starts_with("VmRSS:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()
}

#[tokio::main(flavor = "multi_thread", worker_threads = 1)]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mode = args.get(1).cloned().unwrap_or_else(|| "ramp".into());
    let url = arg(&args, "--url", "ws://127.0.0.1:8765");
    let root = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../models/default/reference/clip.wav"
    );
    let audio = Arc::new(load_audio(&arg(&args, "--audio", root)));
    let p99_max: f64 = arg(&args, "--p99-ms", "150").parse().unwrap();
    if mode == "ramp" {
        let levels: Vec<usize> = arg(&args, "--levels", "8,16,24,32,48,64")
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        let hold: f64 = arg(&args, "--hold", "20").parse().unwrap();
        println!("| sessions | tokens | p50 ms | p99 ms | max ms | failed | sustained |");
        println!("|---|---|---|---|---|---|---|");
        let mut best = 0;
        for &n in &levels {
            let mut hs = Vec::new();
            for i in 0..n {
                // start phases spread over one token (133 ms)
                let delay = Duration::from_micros((i as u64 * 133_333 / n as u64) % 133_333);
                let off = (i * 7919 * 16) % audio.len();
                hs.push(tokio::spawn(session(
                    url.clone(),
                    audio.clone(),
                    off,
                    hold,
                    delay,
                    i as u64,
                )));
            }
            let mut lat = Vec::new();
            let mut failed = Vec::new();
            for h in hs {
                let r = h.await.unwrap();
                lat.extend(r.latencies_ms);
                if let Some(f) = r.failed {
                    failed.push(f);
                }
            }
            let n_tok = lat.len();
            let (p50, p99, mx) = (pct(&mut lat, 0.5), pct(&mut lat, 0.99), pct(&mut lat, 1.0));
            let ok = failed.is_empty() && p99 < p99_max;
            println!(
                "| {n} | {n_tok} | {p50:.1} | {p99:.1} | {mx:.1} | {} | {} |",
                failed.len(),
                if ok { "yes" } else { "no" }
            );
            if let Some(f) = failed.first() {
                eprintln!("  first failure: {f}");
            }
            if !ok {
                break;
            }
            best = n;
            tokio::time::sleep(Duration::from_secs(2)).await;
        }
        println!("\nsustained: {best} concurrent real-time sessions with p99 token latency < {p99_max} ms");
    } else if mode == "soak" {
        let n: usize = arg(&args, "--sessions", "16").parse().unwrap();
        let secs: f64 = arg(&args, "--seconds", "600").parse().unwrap();
        let pid: u32 = arg(&args, "--pid", "0").parse().unwrap();
        let t0 = Instant::now();
        let end = t0 + Duration::from_secs_f64(secs);
        let started = Arc::new(AtomicU64::new(0));
        let failed = Arc::new(AtomicU64::new(0));
        let lats = Arc::new(Mutex::new(Vec::<f64>::new()));
        let mut workers = Vec::new();
        for w in 0..n {
            let (url, audio, started, failed, lats) = (
                url.clone(),
                audio.clone(),
                started.clone(),
                failed.clone(),
                lats.clone(),
            );
            workers.push(tokio::spawn(async move {
                let mut k = 0u64;
                let mut first = true;
                while Instant::now() + Duration::from_secs(3) < end {
                    // 3..20 s sessions, deterministic per worker
                    let len = 3.0 + ((w as u64 * 31 + k * 17) % 18) as f64;
                    let len = len.min((end - Instant::now()).as_secs_f64());
                    let delay = if first {
                        Duration::from_millis(w as u64 * 137 % 2000)
                    } else {
                        Duration::ZERO
                    };
                    first = false;
                    started.fetch_add(1, Ordering::Relaxed);
                    let r = session(
                        url.clone(),
                        audio.clone(),
                        (k as usize * 4001) % audio.len(),
                        len,
                        delay,
                        k,
                    )
                    .await;
                    if r.failed.is_some() {
                        failed.fetch_add(1, Ordering::Relaxed);
                        eprintln!("soak: session failed: {:?}", r.failed);
                    }
                    lats.lock().unwrap().extend(r.latencies_ms);
                    k += 1;
                }
            }));
        }
        println!("| t (s) | server RSS (MiB) | sessions started | failed |");
        println!("|---|---|---|---|");
        let mut peak = 0;
        loop {
            let rss = rss_kib(pid).unwrap_or(0);
            peak = peak.max(rss);
            println!(
                "| {:.0} | {:.1} | {} | {} |",
                t0.elapsed().as_secs_f64(),
                rss as f64 / 1024.0,
                started.load(Ordering::Relaxed),
                failed.load(Ordering::Relaxed)
            );
            if Instant::now() >= end {
                break;
            }
            tokio::time::sleep(
                Duration::from_secs(10).min(end - Instant::now() + Duration::from_millis(10)),
            )
            .await;
        }
        for w in workers {
            let _ = w.await;
        }
        let mut l = lats.lock().unwrap().clone();
        println!(
            "\nsoak: {} sessions over {:.0} s ({} failed), {} tokens, latency p50 {:.1} ms p99 {:.1} ms, peak RSS {:.1} MiB",
            started.load(Ordering::Relaxed),
            secs,
            failed.load(Ordering::Relaxed),
            l.len(),
            pct(&mut l, 0.5),
            pct(&mut l, 0.99),
            peak as f64 / 1024.0
        );
    } else {
        eprintln!("usage: serve_load ramp|soak [options] (see the file's docs)");
        std::process::exit(2);
    }
}
