//! `livegesture loadtest`: how many real-time sessions a `livegesture serve` holds (docs/serve.md#load-test).
//!
//! Against any server (a URL): for each level of concurrent sessions, every session streams real
//! speech at real-time pace (16 kHz s16le mono, 20 ms messages, start phases spread over one token),
//! for `hold` seconds, and measures each unit's latency, from sending the message that completes the
//! unit's audio to receiving the unit's last frame. A level is **held** when every session completed
//! (all its frames, then `done`) and the p99 latency is under the bound; the ramp stops at the first
//! level that is not (unless asked to go on). The server's CPU per level comes from
//! `/proc/<pid>/stat` of a local server, or from the `process_cpu_seconds_total` of its `/metrics`.
//!
//! - [`session`]: one session;
//! - [`report`]: the report as a table, JSON and an SVG plot;
//! - [`soak`]: many sessions with churn for a long time, the server's memory sampled;
//! - here: the audio, the ramp, the server's CPU.

pub mod report;
pub mod session;
pub mod soak;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};

pub use report::{LevelReport, Report};
use session::{SessionPlan, SessionResult, RATE};

/// One recording, 16 kHz mono.
#[derive(Debug, Clone)]
pub struct Clip {
    pub name: String,
    pub samples: Vec<i16>,
}

/// Reads the WAV files `paths` (files, or folders whose `*.wav` are all taken, sorted) at 16 kHz
/// mono. Errors name the file.
pub fn load_clips(paths: &[PathBuf]) -> Result<Vec<Clip>> {
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut in_dir: Vec<PathBuf> = std::fs::read_dir(p)
                .with_context(|| format!("--audio {}: cannot list the folder", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.extension().is_some_and(|x| x.eq_ignore_ascii_case("wav")))
                .collect();
            in_dir.sort();
            ensure!(
                !in_dir.is_empty(),
                "--audio {}: the folder has no .wav file",
                p.display()
            );
            files.extend(in_dir);
        } else {
            files.push(p.clone());
        }
    }
    ensure!(!files.is_empty(), "no audio: pass --audio FILE|DIR");
    files
        .iter()
        .map(|f| {
            let a = livegesture::audio::read_wav_16k_mono(f)
                .with_context(|| format!("--audio {}", f.display()))?;
            ensure!(
                !a.is_empty(),
                "--audio {}: the recording is empty",
                f.display()
            );
            Ok(Clip {
                name: f
                    .file_stem()
                    .map_or_else(String::new, |s| s.to_string_lossy().into()),
                samples: a
                    .iter()
                    .map(|&x| (x * 32768.0).round().clamp(-32768.0, 32767.0) as i16)
                    .collect(),
            })
        })
        .collect()
}

/// `n` samples of the recordings played one after the other from recording `first` on (looping).
fn session_audio(clips: &[Clip], first: usize, n: usize) -> Vec<i16> {
    let mut out = Vec::with_capacity(n);
    let mut k = first;
    while out.len() < n {
        let c = &clips[k % clips.len()].samples;
        out.extend_from_slice(&c[..c.len().min(n - out.len())]);
        k += 1;
    }
    out
}

/// Where the server's CPU time comes from.
#[derive(Debug, Clone)]
pub enum CpuSource {
    /// `/proc/<pid>/stat` (utime + stime) of a server on this machine.
    Pid(u32),
    /// `process_cpu_seconds_total` of the server's `/metrics` (an `http://host:port/metrics` URL).
    Metrics(String),
    None,
}

impl CpuSource {
    /// The server's CPU seconds so far (`None`: not known).
    pub async fn seconds(&self) -> Option<f64> {
        match self {
            CpuSource::Pid(pid) => proc_cpu_seconds(*pid),
            CpuSource::Metrics(url) => metrics_cpu_seconds(url).await,
            CpuSource::None => None,
        }
    }

    pub fn describe(&self) -> String {
        match self {
            CpuSource::Pid(pid) => format!("/proc/{pid}/stat"),
            CpuSource::Metrics(url) => format!("{url} (process_cpu_seconds_total)"),
            CpuSource::None => "not measured".into(),
        }
    }
}

/// utime + stime of `pid` in seconds (`/proc/<pid>/stat`, fields 14 and 15).
pub fn proc_cpu_seconds(pid: u32) -> Option<f64> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // the command name (field 2) may hold spaces: count fields after its closing parenthesis
    let rest = &s[s.rfind(')')? + 1..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: u64 = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / clock_ticks())
}

fn clock_ticks() -> f64 {
    // SAFETY: sysconf only reads a configuration value.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 {
        t as f64
    } else {
        100.0
    }
}

/// The CPUs `pid` may run on (`Cpus_allowed_list` of `/proc/<pid>/status`, e.g. `0` under
/// `taskset -c 0`).
pub fn proc_cpus(pid: u32) -> Option<usize> {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let list = s
        .lines()
        .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))?
        .trim();
    let mut n = 0;
    for part in list.split(',') {
        let mut ab = part.split('-');
        let a: usize = ab.next()?.trim().parse().ok()?;
        let b: usize = ab.next().map_or(Some(a), |b| b.trim().parse().ok())?;
        n += b.checked_sub(a)? + 1;
    }
    (n > 0).then_some(n)
}

/// The server's step figures from its `/metrics`: (steps, seconds in steps, sessions stepped).
#[derive(Debug, Clone, Copy, Default)]
pub struct StepFigures {
    pub steps: f64,
    pub seconds: f64,
    pub sessions: f64,
}

/// [`StepFigures`] of the Prometheus page at `url` (`None`: not reachable or not a livegesture
/// server).
pub async fn step_figures(url: &str) -> Option<StepFigures> {
    let body = http_get(url).await.ok()?;
    let get = |name: &str| -> Option<f64> {
        body.lines()
            .find_map(|l| l.strip_prefix(name)?.strip_prefix(' '))?
            .trim()
            .parse()
            .ok()
    };
    Some(StepFigures {
        steps: get("livegesture_step_seconds_count")?,
        seconds: get("livegesture_step_seconds_sum")?,
        sessions: get("livegesture_batch_size_sum")?,
    })
}

/// `process_cpu_seconds_total` from a Prometheus text page at `url` (plain `http://` only).
async fn metrics_cpu_seconds(url: &str) -> Option<f64> {
    let body = http_get(url).await.ok()?;
    body.lines()
        .find_map(|l| l.strip_prefix("process_cpu_seconds_total "))?
        .trim()
        .parse()
        .ok()
}

/// A plain HTTP/1.0 GET of `url` (`http://host[:port]/path`); returns the body of a 200.
async fn http_get(url: &str) -> Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let rest = url
        .strip_prefix("http://")
        .with_context(|| format!("{url}: only http:// URLs are read"))?;
    let (host, path) = rest.split_once('/').unwrap_or((rest, ""));
    let mut s = tokio::time::timeout(Duration::from_secs(5), tokio::net::TcpStream::connect(host))
        .await
        .with_context(|| format!("{url}: connect timed out"))??;
    s.write_all(format!("GET /{path} HTTP/1.0\r\nHost: {host}\r\n\r\n").as_bytes())
        .await?;
    let mut buf = Vec::new();
    tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut buf))
        .await
        .with_context(|| format!("{url}: read timed out"))??;
    let text = String::from_utf8_lossy(&buf);
    let (head, body) = text
        .split_once("\r\n\r\n")
        .with_context(|| format!("{url}: not an HTTP response"))?;
    ensure!(
        head.lines()
            .next()
            .is_some_and(|l| l.split_whitespace().nth(1) == Some("200")),
        "{url}: {}",
        head.lines().next().unwrap_or("")
    );
    Ok(body.to_string())
}

/// How a level's sessions start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    /// Start phases spread over one token (133 ms): the sessions' token boundaries fall evenly
    /// over the token, as long-running sessions' do.
    Ramp,
    /// Sessions opened one after another, evenly over `spread` (a room of users joining at once):
    /// run it on a fresh server for its start-up.
    Burst { spread: Duration },
}

impl Pattern {
    pub fn name(&self) -> &'static str {
        match self {
            Pattern::Ramp => "ramp",
            Pattern::Burst { .. } => "burst",
        }
    }

    /// When session `i` of `n` opens, after the level starts.
    fn delay(&self, i: usize, n: usize) -> Duration {
        let over = match self {
            Pattern::Ramp => Duration::from_nanos(133_333_333),
            Pattern::Burst { spread } => *spread,
        };
        over.mul_f64(i as f64 / n.max(1) as f64)
    }
}

/// A load test's settings.
#[derive(Debug, Clone)]
pub struct LoadConfig {
    /// `ws://host:port` of the server.
    pub url: String,
    pub token: Option<String>,
    /// Concurrent sessions of each level, increasing.
    pub levels: Vec<usize>,
    /// Seconds of audio each session streams (in real time).
    pub hold: Duration,
    /// A level is held when its p99 unit latency is under this (and no session failed).
    pub p99_ms: f64,
    /// Samples per message (16 kHz).
    pub chunk: usize,
    pub binary: bool,
    /// Pause between levels.
    pub pause: Duration,
    /// Go on after a level that is not held.
    pub keep_going: bool,
    pub cpu: CpuSource,
    /// Cores the server runs on (for sessions per core).
    pub cores: Option<usize>,
    /// The server's Prometheus page (its steps: mean batch, share of the time in steps).
    pub metrics_url: Option<String>,
    pub pattern: Pattern,
}

/// Runs the ramp (see the module docs); `progress` gets one line per level as it ends.
pub async fn run(cfg: &LoadConfig, clips: &[Clip], progress: impl Fn(&str)) -> Result<Report> {
    ensure!(!clips.is_empty(), "no audio");
    ensure!(!cfg.levels.is_empty(), "no levels");
    ensure!(
        cfg.url.starts_with("ws://"),
        "{}: expected a ws://host:port URL (the load test speaks plain WebSocket; test a TLS server through its plain listener or the balancer's)",
        cfg.url
    );
    let n = (cfg.hold.as_secs_f64() * RATE as f64) as usize;
    let rss_before = match cfg.cpu {
        CpuSource::Pid(pid) => soak::proc_rss_bytes(pid).map(|b| b as f64 / 1048576.0),
        _ => None,
    };
    let mut levels = Vec::new();
    for (li, &sessions) in cfg.levels.iter().enumerate() {
        if li > 0 {
            tokio::time::sleep(cfg.pause).await;
        }
        let cpu0 = cfg.cpu.seconds().await;
        let steps0 = match &cfg.metrics_url {
            Some(u) => step_figures(u).await,
            None => None,
        };
        let t0 = Instant::now();
        // the server's peak resident size over the level (a local server)
        let rss_peak = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let sampler = match cfg.cpu {
            CpuSource::Pid(pid) => {
                let peak = rss_peak.clone();
                Some(tokio::spawn(async move {
                    loop {
                        if let Some(b) = soak::proc_rss_bytes(pid) {
                            peak.fetch_max(b, std::sync::atomic::Ordering::Relaxed);
                        }
                        tokio::time::sleep(Duration::from_millis(200)).await;
                    }
                }))
            }
            _ => None,
        };
        let mut hs = Vec::with_capacity(sessions);
        for i in 0..sessions {
            let plan = SessionPlan {
                url: cfg.url.clone(),
                token: cfg.token.clone(),
                audio: Arc::new(session_audio(clips, li * 7 + i, n)),
                chunk: cfg.chunk,
                delay: cfg.pattern.delay(i, sessions),
                seed: i as u64,
                binary: cfg.binary,
                timeout: cfg.hold * 2 + Duration::from_secs(30),
            };
            hs.push(tokio::spawn(session::run(plan)));
        }
        let mut results: Vec<SessionResult> = Vec::with_capacity(sessions);
        for h in hs {
            results.push(h.await.unwrap_or_else(|e| SessionResult {
                failed: Some(format!("the session's task failed: {e}")),
                ..Default::default()
            }));
        }
        let wall = t0.elapsed().as_secs_f64();
        let cpu1 = cfg.cpu.seconds().await;
        if let Some(h) = sampler {
            h.abort();
        }
        let rss = rss_peak.load(std::sync::atomic::Ordering::Relaxed);
        let cpu_pct = match (cpu0, cpu1) {
            (Some(a), Some(b)) if wall > 0.0 => Some((b - a) / wall * 100.0),
            _ => None,
        };
        let steps1 = match &cfg.metrics_url {
            Some(u) => step_figures(u).await,
            None => None,
        };
        let mut l = LevelReport::new(sessions, &results, cpu_pct, wall, cfg.p99_ms);
        l.server_rss_mib = (rss > 0).then(|| rss as f64 / 1048576.0);
        if let (Some(a), Some(b)) = (steps0, steps1) {
            let n = b.steps - a.steps;
            if n > 0.0 {
                l.mean_batch = Some((b.sessions - a.sessions) / n);
                l.step_pct = Some((b.seconds - a.seconds) / wall * 100.0);
            }
        }
        progress(&l.progress_line());
        let held = l.held;
        levels.push(l);
        if !held && !cfg.keep_going {
            break;
        }
    }
    let mut r = Report::new(cfg, levels);
    r.server_rss_before_mib = rss_before;
    Ok(r)
}

/// `--require N`: an error unless at least `n` sessions were held (the level's p99 under the bound,
/// every session completed).
pub fn require(report: &Report, n: usize) -> Result<()> {
    ensure!(
        report.sessions_held >= n,
        "held {} sessions, fewer than --require {n}{}",
        report.sessions_held,
        report
            .levels
            .iter()
            .find(|l| !l.held)
            .map_or_else(String::new, |l| format!(
                " ({} sessions: p99 {} ms, first second {} ms, after it {} ms, bound {} ms, {} failed)",
                l.sessions,
                l.p99_ms.map_or("-".into(), |v| format!("{v:.1}")),
                l.first_second.p99_ms.map_or("-".into(), |v| format!("{v:.1}")),
                l.after_first_second.p99_ms.map_or("-".into(), |v| format!("{v:.1}")),
                report.p99_bound_ms,
                l.failed
            ))
    );
    Ok(())
}

/// The real-speech recordings' folder: `$LIVEGESTURE_REAL_SPEECH`, else `shared/data/real-speech`
/// beside the repository this program was built from (docs/data.md#the-real-speech-recordings).
pub fn default_audio() -> Result<PathBuf> {
    if let Some(d) = std::env::var_os("LIVEGESTURE_REAL_SPEECH") {
        let d = PathBuf::from(d);
        if !d.is_dir() {
            bail!(
                "$LIVEGESTURE_REAL_SPEECH = {}: not a folder of WAV files",
                d.display()
            );
        }
        return Ok(d);
    }
    let beside = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/real-speech");
    if beside.is_dir() {
        return Ok(beside);
    }
    bail!(
        "no audio: pass --audio FILE|DIR (WAV files of speech) or set $LIVEGESTURE_REAL_SPEECH to the real-speech recordings' folder (docs/data.md)"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_audio_plays_the_recordings_in_turn() {
        let clips = vec![
            Clip {
                name: "a".into(),
                samples: vec![1, 2, 3],
            },
            Clip {
                name: "b".into(),
                samples: vec![7, 8],
            },
        ];
        assert_eq!(session_audio(&clips, 0, 7), vec![1, 2, 3, 7, 8, 1, 2]);
        assert_eq!(session_audio(&clips, 1, 4), vec![7, 8, 1, 2]);
        assert_eq!(session_audio(&clips, 0, 2), vec![1, 2]);
    }

    #[test]
    fn patterns_spread_the_starts() {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        assert_eq!(Pattern::Ramp.delay(0, 4), Duration::ZERO);
        assert!((ms(Pattern::Ramp.delay(3, 4)) - 100.0).abs() < 1e-3);
        let b = Pattern::Burst {
            spread: Duration::from_secs(1),
        };
        assert!((ms(b.delay(47, 48)) - 979.1667).abs() < 1e-3);
        assert!(ms(b.delay(47, 48)) < 1000.0, "all open within the spread");
        assert_eq!((Pattern::Ramp.name(), b.name()), ("ramp", "burst"));
    }

    /// A burst of 4 sessions on a fresh in-process server (models/default on tract, its reference
    /// clip, warmed up with 4 streams): every session completes, every token is measured and falls in the first second or
    /// after it, the level holds a generous bound; a bound it cannot meet fails `--require`.
    #[test]
    fn a_burst_on_a_fresh_server_is_measured_and_bounded() {
        use crate::{ModelInfo, ServeConfig, Server};
        use livegesture::backend::{BackendKind, BackendOptions};
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let dir = root.join("models/default");
        let server = Server::start(
            "127.0.0.1:0".parse().unwrap(),
            ServeConfig {
                max_sessions: 8,
                // as `serve` does by default (scheduler::warm_up), with this burst's size
                warm_sessions: 4,
                ..ServeConfig::default()
            },
            move || {
                let bundle = livegesture::bundle::Bundle::load(&dir)?;
                let be = livegesture::backend::create(&BackendOptions {
                    kind: BackendKind::Tract,
                    execution_provider: "cpu".into(),
                    intra_threads: 1,
                    ort_library: None,
                })?;
                let model = livegesture::model::load(&bundle, be.as_ref())?;
                let info = ModelInfo {
                    model: "default".into(),
                    family: bundle.family(),
                    bundle_sha256: "0".repeat(64),
                    backend: model.backend_name().into(),
                    fps: bundle.frontend().fps,
                    frames_per_token: bundle.frontend().frames_per_token,
                    frontend: bundle.frontend().clone(),
                    face: model.has_face(),
                };
                Ok((model, info))
            },
        )
        .expect("the server starts");
        let clips = load_clips(&[root.join("models/default/reference/clip.wav")]).unwrap();
        let mut cfg = LoadConfig {
            url: format!("ws://{}", server.addr()),
            token: None,
            levels: vec![4],
            hold: Duration::from_secs(3),
            p99_ms: 2000.0,
            chunk: 160,
            binary: false,
            pause: Duration::ZERO,
            keep_going: false,
            cpu: CpuSource::Pid(std::process::id()),
            cores: None,
            metrics_url: None,
            pattern: Pattern::Burst {
                spread: Duration::from_millis(500),
            },
        };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let report = rt.block_on(run(&cfg, &clips, |_| {})).unwrap();
        let l = &report.levels[0];
        assert_eq!((l.completed, l.failed), (4, 0), "{l:?}");
        // 3 s of audio: 22 full tokens per session (the frontend's grid), each measured once
        assert_eq!(l.units, 4 * 22, "{l:?}");
        assert_eq!(l.first_second.units + l.after_first_second.units, l.units);
        assert_eq!(
            l.first_second.units,
            4 * 7,
            "tokens 0-6 end within 1 s: {l:?}"
        );
        assert!(l.held, "4 sessions on tract within 2 s: {l:?}");
        assert_eq!(report.pattern, "burst");
        require(&report, 4).unwrap();
        // must fail: a bound the burst cannot meet (a second burst, on the now warm server)
        cfg.p99_ms = 0.001;
        let report = rt.block_on(run(&cfg, &clips, |_| {})).unwrap();
        assert!(!report.levels[0].held);
        let e = require(&report, 4).unwrap_err().to_string();
        assert!(
            e.contains("held 0 sessions, fewer than --require 4") && e.contains("first second"),
            "{e}"
        );
        server.shutdown();
        server.join().unwrap();
    }

    #[test]
    fn proc_figures_of_this_process() {
        let me = std::process::id();
        assert!(proc_cpu_seconds(me).is_some_and(|s| s >= 0.0));
        assert!(proc_cpus(me).is_some_and(|n| n >= 1));
        assert!(proc_cpu_seconds(u32::MAX).is_none());
    }
}
