//! The soak: a steady number of live sessions with churn (each 3-20 s of speech, then `end`, then a
//! new one) for a long time, with the server's resident memory sampled every `every` (a server
//! that keeps growing leaks).

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{ensure, Result};

use super::report::quantile;
use super::session::{self, SessionPlan, RATE};
use super::{session_audio, Clip, LoadConfig};

/// Resident memory of `pid` in bytes (`VmRSS` of `/proc/<pid>/status`).
pub fn proc_rss_bytes(pid: u32) -> Option<u64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kib: u64 = s
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .split_whitespace()
        .next()?
        .parse()
        .ok()?;
    Some(kib * 1024)
}

/// Keeps `sessions` sessions live for `seconds` (see the module docs); returns the table (one row
/// per sample: time, server RSS, sessions started, failed) and the summary line. `pid`: the server,
/// for its RSS (without it the RSS column stays empty).
pub async fn run(
    cfg: &LoadConfig,
    clips: &[Clip],
    sessions: usize,
    seconds: f64,
    pid: Option<u32>,
    every: Duration,
    progress: impl Fn(&str),
) -> Result<String> {
    ensure!(sessions > 0 && !clips.is_empty(), "nothing to soak with");
    let t0 = Instant::now();
    let end = t0 + Duration::from_secs_f64(seconds);
    let started = Arc::new(AtomicU64::new(0));
    let failed = Arc::new(AtomicU64::new(0));
    let lats: Arc<Mutex<Vec<f64>>> = Arc::default();
    let mut workers = Vec::new();
    for w in 0..sessions {
        let (cfg, started, failed, lats) =
            (cfg.clone(), started.clone(), failed.clone(), lats.clone());
        let clips = clips.to_vec();
        workers.push(tokio::spawn(async move {
            let mut k = 0u64;
            while Instant::now() + Duration::from_secs(3) < end {
                // 3..20 s sessions, deterministic per worker
                let len = 3.0 + ((w as u64 * 31 + k * 17) % 18) as f64;
                let len = len.min((end - Instant::now()).as_secs_f64());
                let n = (len * RATE as f64) as usize;
                let plan = SessionPlan {
                    url: cfg.url.clone(),
                    token: cfg.token.clone(),
                    audio: Arc::new(session_audio(&clips, w + k as usize, n)),
                    chunk: cfg.chunk,
                    delay: if k == 0 {
                        Duration::from_millis(w as u64 * 137 % 2000)
                    } else {
                        Duration::ZERO
                    },
                    seed: k,
                    binary: cfg.binary,
                    timeout: Duration::from_secs_f64(len * 2.0 + 30.0),
                };
                started.fetch_add(1, Ordering::Relaxed);
                let r = session::run(plan).await;
                if let Some(f) = r.failed {
                    failed.fetch_add(1, Ordering::Relaxed);
                    eprintln!("loadtest soak: a session failed: {f}");
                }
                lats.lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .extend(r.latencies_ms);
                k += 1;
            }
        }));
    }
    let mut table = String::from(
        "| t (s) | server RSS (MiB) | sessions started | failed |\n|---|---|---|---|\n",
    );
    let mut peak = 0;
    loop {
        let rss = pid.and_then(proc_rss_bytes);
        peak = peak.max(rss.unwrap_or(0));
        let row = format!(
            "| {:.0} | {} | {} | {} |",
            t0.elapsed().as_secs_f64(),
            rss.map_or_else(|| "-".into(), |b| format!("{:.1}", b as f64 / 1048576.0)),
            started.load(Ordering::Relaxed),
            failed.load(Ordering::Relaxed)
        );
        progress(&row);
        let _ = writeln!(table, "{row}");
        let now = Instant::now();
        if now >= end {
            break;
        }
        tokio::time::sleep(every.min(end - now + Duration::from_millis(10))).await;
    }
    for w in workers {
        let _ = w.await;
    }
    let mut l = lats.lock().unwrap_or_else(|e| e.into_inner()).clone();
    l.sort_by(f64::total_cmp);
    let f = |v: Option<f64>| v.map_or_else(|| "-".into(), |x| format!("{x:.1}"));
    let _ = writeln!(
        table,
        "\nsoak: {} sessions over {seconds:.0} s ({} failed), {} tokens, latency p50 {} ms p99 {} ms, peak server RSS {}",
        started.load(Ordering::Relaxed),
        failed.load(Ordering::Relaxed),
        l.len(),
        f(quantile(&l, 0.5)),
        f(quantile(&l, 0.99)),
        if peak > 0 {
            format!("{:.1} MiB", peak as f64 / 1048576.0)
        } else {
            "not measured (pass --server-pid)".into()
        }
    );
    Ok(table)
}
