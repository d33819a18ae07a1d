//! Server metrics and their Prometheus text exposition (format 0.0.4), names prefixed `livegesture_`.

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// The window of [`Histogram::recent_max`]: the largest value of the last 10-20 s.
const RECENT: Duration = Duration::from_secs(10);

/// A histogram with fixed upper bounds (cumulative buckets are computed when rendered).
#[derive(Debug)]
pub struct Histogram {
    bounds: Vec<f64>,
    inner: Mutex<HistState>,
}

#[derive(Debug, Default, Clone)]
struct HistState {
    counts: Vec<u64>,
    sum: f64,
    count: u64,
    /// Largest value of the current and of the previous [`RECENT`] window, and the current one's start.
    recent: [f64; 2],
    recent_start: Option<Instant>,
}

impl HistState {
    fn roll(&mut self, now: Instant) {
        match self.recent_start {
            Some(t) if now.duration_since(t) < RECENT => {}
            Some(t) => {
                self.recent[1] = if now.duration_since(t) < 2 * RECENT {
                    self.recent[0]
                } else {
                    0.0
                };
                self.recent[0] = 0.0;
                self.recent_start = Some(now);
            }
            None => self.recent_start = Some(now),
        }
    }
}

impl Histogram {
    pub fn new(bounds: &[f64]) -> Self {
        Self {
            bounds: bounds.to_vec(),
            inner: Mutex::new(HistState {
                counts: vec![0; bounds.len()],
                ..Default::default()
            }),
        }
    }

    pub fn observe(&self, v: f64) {
        let mut s = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = self.bounds.iter().position(|&b| v <= b) {
            s.counts[i] += 1;
        }
        s.sum += v;
        s.count += 1;
        s.roll(Instant::now());
        if v > s.recent[0] {
            s.recent[0] = v;
        }
    }

    /// The largest value observed in the last 10-20 seconds (0 when none).
    pub fn recent_max(&self) -> f64 {
        let mut s = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        s.roll(Instant::now());
        s.recent[0].max(s.recent[1])
    }

    fn render(&self, out: &mut String, name: &str, help: &str) {
        let s = self.inner.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} histogram");
        let mut cum = 0;
        for (b, c) in self.bounds.iter().zip(&s.counts) {
            cum += c;
            let _ = writeln!(out, "{name}_bucket{{le=\"{}\"}} {cum}", fmt_f64(*b));
        }
        let _ = writeln!(out, "{name}_bucket{{le=\"+Inf\"}} {}", s.count);
        let _ = writeln!(out, "{name}_sum {}", fmt_f64(s.sum));
        let _ = writeln!(out, "{name}_count {}", s.count);
    }
}

/// The process's own figures under their standard Prometheus names (Linux `/proc/self`; empty
/// elsewhere): `process_cpu_seconds_total` (user + system) and `process_resident_memory_bytes`. A
/// load test reads the CPU of a server it cannot see (`livegesture loadtest`).
pub fn process_text() -> String {
    let mut o = String::new();
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // fields after the command name's closing parenthesis: utime and stime are the 12th and 13th
    let f: Vec<&str> = stat
        .rfind(')')
        .map_or("", |i| &stat[i + 1..])
        .split_whitespace()
        .collect();
    let tick = |i: usize| f.get(i).and_then(|v| v.parse::<u64>().ok());
    if let (Some(u), Some(s)) = (tick(11), tick(12)) {
        // USER_HZ is 100 on every Linux ABI the runtime builds for
        let secs = (u + s) as f64 / 100.0;
        let _ = writeln!(
            o,
            "# HELP process_cpu_seconds_total Total user and system CPU time spent in seconds.\n# TYPE process_cpu_seconds_total counter\nprocess_cpu_seconds_total {}",
            fmt_f64(secs)
        );
    }
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let rss_kib = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok());
    if let Some(k) = rss_kib {
        let _ = writeln!(
            o,
            "# HELP process_resident_memory_bytes Resident memory size in bytes.\n# TYPE process_resident_memory_bytes gauge\nprocess_resident_memory_bytes {}",
            k * 1024
        );
    }
    o
}

fn fmt_f64(v: f64) -> String {
    if v.is_finite() {
        format!("{v:?}")
    } else if v.is_nan() {
        "NaN".into()
    } else if v > 0.0 {
        "+Inf".into()
    } else {
        "-Inf".into()
    }
}

/// Reasons a session or connection is refused or cut (label values of `livegesture_refusals_total`).
pub const REFUSAL_REASONS: [&str; 12] = [
    "bad_request",
    "capacity",
    "shutting_down",
    "malformed",
    "unknown_message",
    "oversize",
    "idle",
    "slow_client",
    // who may connect (access.rs, tls.rs)
    "unauthorized",
    "forbidden_origin",
    "client_limit",
    "tls_handshake",
];

/// All counters and histograms of one server.
#[derive(Debug)]
pub struct Metrics {
    pub sessions_active: AtomicU64,
    pub sessions_total: AtomicU64,
    pub tokens_total: AtomicU64,
    pub frames_total: AtomicU64,
    pub steps_total: AtomicU64,
    /// The model's [`livegesture::model::MotionModel::streams_regrouped`] (set after each step).
    pub streams_regrouped_total: AtomicU64,
    pub audio_samples_total: AtomicU64,
    refusals: [AtomicU64; REFUSAL_REASONS.len()],
    pub batch_size: Histogram,
    pub step_seconds: Histogram,
    pub token_latency_seconds: Histogram,
}

impl Default for Metrics {
    fn default() -> Self {
        Self::new()
    }
}

impl Metrics {
    pub fn new() -> Self {
        let lat = [
            0.001, 0.0025, 0.005, 0.01, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0,
            2.5, 5.0,
        ];
        Self {
            sessions_active: AtomicU64::new(0),
            sessions_total: AtomicU64::new(0),
            tokens_total: AtomicU64::new(0),
            frames_total: AtomicU64::new(0),
            steps_total: AtomicU64::new(0),
            streams_regrouped_total: AtomicU64::new(0),
            audio_samples_total: AtomicU64::new(0),
            refusals: Default::default(),
            batch_size: Histogram::new(&[
                1.0, 2.0, 4.0, 8.0, 16.0, 24.0, 32.0, 48.0, 64.0, 96.0, 128.0, 256.0,
            ]),
            step_seconds: Histogram::new(&lat),
            token_latency_seconds: Histogram::new(&lat),
        }
    }

    /// Counts a refusal; `reason` must be one of [`REFUSAL_REASONS`].
    pub fn refuse(&self, reason: &str) {
        if let Some(i) = REFUSAL_REASONS.iter().position(|r| *r == reason) {
            self.refusals[i].fetch_add(1, Ordering::Relaxed);
        } else {
            debug_assert!(false, "unknown refusal reason {reason}");
        }
    }

    pub fn refusals(&self, reason: &str) -> u64 {
        REFUSAL_REASONS
            .iter()
            .position(|r| *r == reason)
            .map_or(0, |i| self.refusals[i].load(Ordering::Relaxed))
    }

    /// The Prometheus text exposition.
    pub fn render(&self) -> String {
        let mut o = String::with_capacity(4096);
        let g = |o: &mut String, name: &str, kind: &str, help: &str, v: u64| {
            let _ = writeln!(o, "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {v}");
        };
        let ld = |a: &AtomicU64| a.load(Ordering::Relaxed);
        g(
            &mut o,
            "livegesture_sessions_active",
            "gauge",
            "Live WebSocket sessions.",
            ld(&self.sessions_active),
        );
        g(
            &mut o,
            "livegesture_sessions_total",
            "counter",
            "Sessions accepted since start.",
            ld(&self.sessions_total),
        );
        g(
            &mut o,
            "livegesture_tokens_total",
            "counter",
            "Motion tokens generated (one per session per token step).",
            ld(&self.tokens_total),
        );
        g(
            &mut o,
            "livegesture_frames_total",
            "counter",
            "Motion frames sent.",
            ld(&self.frames_total),
        );
        g(
            &mut o,
            "livegesture_steps_total",
            "counter",
            "Batched token steps (one run of every graph).",
            ld(&self.steps_total),
        );
        g(
            &mut o,
            "livegesture_streams_regrouped_total",
            "counter",
            "Streams whose stacked state was copied because their step-mates changed (0 in a steady state).",
            ld(&self.streams_regrouped_total),
        );
        g(
            &mut o,
            "livegesture_audio_samples_total",
            "counter",
            "16 kHz audio samples received.",
            ld(&self.audio_samples_total),
        );
        let _ = writeln!(o, "# HELP livegesture_refusals_total Requests refused and sessions closed by the server, by reason.\n# TYPE livegesture_refusals_total counter");
        for (r, c) in REFUSAL_REASONS.iter().zip(&self.refusals) {
            let _ = writeln!(o, "livegesture_refusals_total{{reason=\"{r}\"}} {}", ld(c));
        }
        self.batch_size.render(
            &mut o,
            "livegesture_batch_size",
            "Sessions stepped together per token step.",
        );
        self.step_seconds.render(
            &mut o,
            "livegesture_step_seconds",
            "Wall time of one batched token step (all graphs).",
        );
        self.token_latency_seconds.render(
            &mut o,
            "livegesture_token_latency_seconds",
            "From the message completing a token's audio to its frames queued for sending.",
        );
        let _ = writeln!(
            o,
            "# HELP livegesture_tick_lag_seconds Largest token latency of the last 10-20 s (what an autoscaler watches).\n# TYPE livegesture_tick_lag_seconds gauge\nlivegesture_tick_lag_seconds {}",
            fmt_f64(self.token_latency_seconds.recent_max())
        );
        o
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposition() {
        let m = Metrics::new();
        m.sessions_total.fetch_add(2, Ordering::Relaxed);
        m.refuse("capacity");
        m.step_seconds.observe(0.004);
        m.step_seconds.observe(0.04);
        m.step_seconds.observe(50.0);
        let t = m.render();
        assert!(t.contains("livegesture_sessions_total 2\n"), "{t}");
        assert!(t.contains("livegesture_refusals_total{reason=\"capacity\"} 1\n"));
        assert!(t.contains("livegesture_step_seconds_bucket{le=\"0.005\"} 1\n"));
        assert!(t.contains("livegesture_step_seconds_bucket{le=\"0.05\"} 2\n"));
        assert!(t.contains("livegesture_step_seconds_bucket{le=\"+Inf\"} 3\n"));
        assert!(t.contains("livegesture_step_seconds_count 3\n"));
        for line in t.lines().filter(|l| !l.starts_with('#')) {
            assert!(line.starts_with("livegesture_"), "{line}");
            let v = line.rsplit(' ').next().unwrap();
            assert!(v.parse::<f64>().is_ok(), "{line}");
        }
    }
}
