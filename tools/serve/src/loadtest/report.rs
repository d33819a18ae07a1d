//! A load test's report: per level, sessions completed and failed, unit latency percentiles and the
//! server's CPU; as a Markdown table, JSON, and an SVG plot (latency and CPU against sessions).

use std::fmt::Write as _;

use serde::Serialize;

use super::session::SessionResult;
use super::{LoadConfig, Pattern};

/// One level of the ramp.
#[derive(Debug, Clone, Serialize)]
pub struct LevelReport {
    /// Concurrent sessions.
    pub sessions: usize,
    /// Sessions that sent all their audio and got every frame and `done`.
    pub completed: usize,
    pub failed: usize,
    /// Units (LiveGesture tokens) whose latency was measured.
    pub units: usize,
    pub p50_ms: Option<f64>,
    pub p99_ms: Option<f64>,
    pub max_ms: Option<f64>,
    /// The tokens of every session's first second (completing message sent less than 1 s after the
    /// session's first audio message): a fresh session's start-up.
    pub first_second: Split,
    /// The tokens after every session's first second.
    pub after_first_second: Split,
    /// Server CPU over the level, % of one core (`None`: not measured).
    pub server_cpu_pct: Option<f64>,
    /// Sessions per step, on average (the server's `/metrics`; `None`: not read).
    pub mean_batch: Option<f64>,
    /// Time in steps (the batched model calls), % of the level's wall time (`/metrics`).
    pub step_pct: Option<f64>,
    /// The server's peak resident size during the level, MiB (`--server-pid`; `None`: not measured).
    pub server_rss_mib: Option<f64>,
    /// Seconds the level took.
    pub wall_s: f64,
    /// Every session completed and p99 is under the bound.
    pub held: bool,
    /// The first failed session's reason.
    pub first_failure: Option<String>,
}

/// Percentiles of a part of a level's tokens (the same quantile as the level's).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Split {
    pub units: usize,
    pub p50_ms: Option<f64>,
    pub p99_ms: Option<f64>,
}

impl Split {
    fn of(mut lat: Vec<f64>) -> Self {
        lat.sort_by(f64::total_cmp);
        Split {
            units: lat.len(),
            p50_ms: quantile(&lat, 0.5),
            p99_ms: quantile(&lat, 0.99),
        }
    }
}

/// Where a session's start-up ends: tokens sent before this (seconds after its first audio message)
/// are its first second.
pub const FIRST_SECOND_S: f64 = 1.0;

/// The quantile of the project's figures (linear interpolation, as `livegesture bench`).
pub use livegesture::stats::quantile;

impl LevelReport {
    pub fn new(
        sessions: usize,
        results: &[SessionResult],
        server_cpu_pct: Option<f64>,
        wall_s: f64,
        bound_ms: f64,
    ) -> Self {
        let mut lat: Vec<f64> = results
            .iter()
            .flat_map(|r| r.latencies_ms.iter().copied())
            .collect();
        lat.sort_by(f64::total_cmp);
        let failed = results.iter().filter(|r| r.failed.is_some()).count();
        let p99 = quantile(&lat, 0.99);
        let (mut early, mut late) = (Vec::new(), Vec::new());
        for r in results {
            for (i, &l) in r.latencies_ms.iter().enumerate() {
                // a latency without its send time (not measured) counts after the first second
                if r.sent_s.get(i).is_some_and(|&t| t < FIRST_SECOND_S) {
                    early.push(l);
                } else {
                    late.push(l);
                }
            }
        }
        LevelReport {
            sessions,
            completed: results.len() - failed,
            failed,
            units: lat.len(),
            p50_ms: quantile(&lat, 0.5),
            p99_ms: p99,
            max_ms: lat.last().copied(),
            first_second: Split::of(early),
            after_first_second: Split::of(late),
            server_cpu_pct,
            mean_batch: None,
            step_pct: None,
            server_rss_mib: None,
            wall_s,
            held: failed == 0 && p99.is_some_and(|p| p < bound_ms),
            first_failure: results.iter().find_map(|r| r.failed.clone()),
        }
    }

    pub fn progress_line(&self) -> String {
        let mut s = format!(
            "loadtest: {} sessions: {} completed, {} failed, {} tokens, p50 {} ms, p99 {} ms (first second {} ms, after it {} ms), server CPU {}: {}",
            self.sessions,
            self.completed,
            self.failed,
            self.units,
            opt(self.p50_ms, 1),
            opt(self.p99_ms, 1),
            opt(self.first_second.p99_ms, 1),
            opt(self.after_first_second.p99_ms, 1),
            opt(self.server_cpu_pct, 0).replace('-', "n/a") + "%",
            if self.held { "held" } else { "not held" }
        );
        if let Some(f) = &self.first_failure {
            let _ = write!(s, " (first failure: {f})");
        }
        s
    }
}

fn opt(v: Option<f64>, prec: usize) -> String {
    v.map_or_else(|| "-".into(), |x| format!("{x:.prec$}"))
}

/// The whole ramp.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub url: String,
    /// `ramp` or `burst` (docs/serve.md#load-test).
    pub pattern: &'static str,
    /// Burst: the seconds over which each level's sessions open.
    pub burst_spread_s: Option<f64>,
    pub chunk_ms: f64,
    pub p99_bound_ms: f64,
    pub hold_s: f64,
    pub output: &'static str,
    /// Where the server CPU figures come from.
    pub cpu_source: String,
    /// Cores the server runs on (`None`: not known).
    pub cores: Option<usize>,
    pub levels: Vec<LevelReport>,
    /// The server's resident size before the first level, MiB (`--server-pid`).
    pub server_rss_before_mib: Option<f64>,
    /// The largest level held (0: none).
    pub sessions_held: usize,
    /// `sessions_held / cores`.
    pub sessions_per_core: Option<f64>,
}

impl Report {
    pub fn new(cfg: &LoadConfig, levels: Vec<LevelReport>) -> Self {
        let held = levels
            .iter()
            .filter(|l| l.held)
            .map(|l| l.sessions)
            .max()
            .unwrap_or(0);
        Report {
            url: cfg.url.clone(),
            pattern: cfg.pattern.name(),
            burst_spread_s: match cfg.pattern {
                Pattern::Burst { spread } => Some(spread.as_secs_f64()),
                Pattern::Ramp => None,
            },
            chunk_ms: cfg.chunk as f64 / 16.0,
            p99_bound_ms: cfg.p99_ms,
            hold_s: cfg.hold.as_secs_f64(),
            output: if cfg.binary { "binary" } else { "json" },
            cpu_source: cfg.cpu.describe(),
            cores: cfg.cores,
            levels,
            server_rss_before_mib: None,
            sessions_held: held,
            sessions_per_core: cfg.cores.map(|c| held as f64 / c as f64),
        }
    }

    /// The Markdown table and the summary line.
    pub fn table(&self) -> String {
        let mut s = String::from(
            "| sessions | completed | failed | tokens | p50 ms | p99 ms | max ms | p99 first s ms | p99 after ms | server CPU % | in steps % | sessions per step | server RSS MiB | held |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        );
        for l in &self.levels {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                l.sessions,
                l.completed,
                l.failed,
                l.units,
                opt(l.p50_ms, 1),
                opt(l.p99_ms, 1),
                opt(l.max_ms, 1),
                opt(l.first_second.p99_ms, 1),
                opt(l.after_first_second.p99_ms, 1),
                opt(l.server_cpu_pct, 0),
                opt(l.step_pct, 0),
                opt(l.mean_batch, 1),
                opt(l.server_rss_mib, 0),
                if l.held { "yes" } else { "no" }
            );
        }
        let per_core = match (self.cores, self.sessions_per_core) {
            (Some(c), Some(p)) => format!("{p:.1} sessions per core ({c} cores)"),
            _ => "sessions per core: cores not known (pass --cores or --server-pid)".into(),
        };
        let _ = writeln!(
            s,
            "\nheld: {} real-time sessions with p99 token latency < {} ms ({per_core}); {}, {} s per level, {} ms messages, output={}, server CPU from {}",
            self.sessions_held,
            self.p99_bound_ms,
            match self.burst_spread_s {
                Some(s) => format!("burst (each level's sessions opened within {s} s)"),
                None => "ramp".into(),
            },
            self.hold_s,
            self.chunk_ms,
            self.output,
            self.cpu_source
        );
        if let Some(m) = self.server_rss_before_mib {
            let _ = writeln!(
                s,
                "server RSS before the first level: {m:.0} MiB (peak of each level in the table)"
            );
        }
        s
    }

    /// An SVG plot: p50 / p99 latency (with the bound) and server CPU against sessions.
    // long: one SVG plot drawn element by element (axes, ticks, two curves, the bound, the legend)
    pub fn svg(&self, title: &str) -> String {
        let (w, h) = (720.0, 520.0);
        let (left, right) = (70.0, 690.0);
        let x_max = self.levels.iter().map(|l| l.sessions).max().unwrap_or(1) as f64;
        let x_max = nice_ceil(x_max.max(1.0));
        let lat_max = self
            .levels
            .iter()
            .filter_map(|l| l.p99_ms)
            .fold(self.p99_bound_ms, f64::max);
        let lat_max = nice_ceil(lat_max * 1.1);
        let cpu_max = self
            .levels
            .iter()
            .filter_map(|l| l.server_cpu_pct)
            .fold(100.0, f64::max);
        let cpu_max = nice_ceil(cpu_max);
        let xp = |x: f64| left + (right - left) * x / x_max;
        let mut s = String::new();
        let _ = writeln!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
        );
        let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
        let _ = writeln!(
            s,
            r#"<text x="{}" y="20" text-anchor="middle" font-size="14">{}</text>"#,
            w / 2.0,
            xml_escape(title)
        );
        // two panels: latency (top), CPU (bottom)
        let panels = [
            (40.0, 300.0, lat_max, "token latency (ms)"),
            (350.0, 480.0, cpu_max, "server CPU (% of one core)"),
        ];
        for &(top, bottom, ymax, label) in &panels {
            let yp = |y: f64| bottom - (bottom - top) * y / ymax;
            for k in 0..=4 {
                let v = ymax * k as f64 / 4.0;
                let y = yp(v);
                let _ = writeln!(
                    s,
                    r##"<line x1="{left}" y1="{y:.1}" x2="{right}" y2="{y:.1}" stroke="#ddd"/><text x="{}" y="{:.1}" text-anchor="end">{v:.0}</text>"##,
                    left - 6.0,
                    y + 4.0
                );
            }
            for k in 0..=4 {
                let v = x_max * k as f64 / 4.0;
                let x = xp(v);
                let _ = writeln!(
                    s,
                    r#"<text x="{x:.1}" y="{}" text-anchor="middle">{v:.0}</text>"#,
                    bottom + 16.0
                );
            }
            let _ = writeln!(
                s,
                r#"<rect x="{left}" y="{top}" width="{}" height="{}" fill="none" stroke="black"/>"#,
                right - left,
                bottom - top
            );
            let _ = writeln!(
                s,
                r#"<text transform="translate(16,{:.1}) rotate(-90)" text-anchor="middle">{label}</text>"#,
                (top + bottom) / 2.0
            );
        }
        let _ = writeln!(
            s,
            r#"<text x="{}" y="{}" text-anchor="middle">concurrent real-time sessions</text>"#,
            (left + right) / 2.0,
            h - 8.0
        );
        let (top, bottom, ymax, _) = panels[0];
        let yl = |y: f64| bottom - (bottom - top) * y.min(ymax) / ymax;
        let yb = yl(self.p99_bound_ms);
        let _ = writeln!(
            s,
            r##"<line x1="{left}" y1="{yb:.1}" x2="{right}" y2="{yb:.1}" stroke="#c00" stroke-dasharray="6 4"/><text x="{}" y="{:.1}" fill="#c00" text-anchor="end">p99 bound {} ms</text>"##,
            right - 4.0,
            yb - 4.0,
            self.p99_bound_ms
        );
        let series = |f: &dyn Fn(&LevelReport) -> Option<f64>, y: &dyn Fn(f64) -> f64| {
            self.levels
                .iter()
                .filter_map(|l| f(l).map(|v| (xp(l.sessions as f64), y(v))))
                .collect::<Vec<_>>()
        };
        let (ct, cb, cmax, _) = panels[1];
        let yc = |y: f64| cb - (cb - ct) * y.min(cmax) / cmax;
        type Line<'a> = (Vec<(f64, f64)>, &'a str, &'a str);
        let lines: [Line; 3] = [
            (series(&|l| l.p50_ms, &yl), "#1f77b4", "p50"),
            (series(&|l| l.p99_ms, &yl), "#ff7f0e", "p99"),
            (series(&|l| l.server_cpu_pct, &yc), "#2ca02c", "server CPU"),
        ];
        for (k, (pts, color, name)) in lines.iter().enumerate() {
            if pts.is_empty() {
                continue;
            }
            let path: Vec<String> = pts.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
            let _ = writeln!(
                s,
                r#"<polyline points="{}" fill="none" stroke="{color}" stroke-width="2"/>"#,
                path.join(" ")
            );
            for (x, y) in pts {
                let _ = writeln!(
                    s,
                    r#"<circle cx="{x:.1}" cy="{y:.1}" r="3" fill="{color}"/>"#
                );
            }
            let ly = if k < 2 {
                top + 16.0 + 16.0 * k as f64
            } else {
                ct + 16.0
            };
            let _ = writeln!(
                s,
                r#"<line x1="{}" y1="{:.1}" x2="{}" y2="{:.1}" stroke="{color}" stroke-width="2"/><text x="{}" y="{:.1}">{name}</text>"#,
                left + 10.0,
                ly - 4.0,
                left + 30.0,
                ly - 4.0,
                left + 36.0,
                ly
            );
        }
        // the levels not held
        for l in self.levels.iter().filter(|l| !l.held) {
            let x = xp(l.sessions as f64);
            let _ = writeln!(
                s,
                r##"<text x="{x:.1}" y="{:.1}" fill="#c00" text-anchor="middle">not held</text>"##,
                top + 14.0
            );
        }
        s.push_str("</svg>\n");
        s
    }
}

/// The smallest of 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 x 10^k at or above `v`.
fn nice_ceil(v: f64) -> f64 {
    if v <= 0.0 || !v.is_finite() {
        return 1.0;
    }
    let p = 10f64.powf(v.log10().floor());
    for m in [1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0] {
        if m * p >= v {
            return m * p;
        }
    }
    10.0 * p
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn res(lat: &[f64], failed: bool) -> SessionResult {
        SessionResult {
            latencies_ms: lat.to_vec(),
            sent_s: (0..lat.len()).map(|i| 0.5 * i as f64).collect(),
            frames: 8,
            failed: failed.then(|| "closed before done".to_string()),
        }
    }

    #[test]
    fn a_level_is_held_under_the_bound_without_failures() {
        let ok = LevelReport::new(
            2,
            &[res(&[10.0, 20.0], false), res(&[30.0], false)],
            Some(50.0),
            3.0,
            100.0,
        );
        assert!(ok.held);
        assert_eq!((ok.completed, ok.failed, ok.units), (2, 0, 3));
        assert_eq!((ok.p50_ms, ok.max_ms), (Some(20.0), Some(30.0)));
        // over the bound
        let slow = LevelReport::new(1, &[res(&[10.0, 200.0], false)], None, 3.0, 100.0);
        assert!(!slow.held);
        // a failed session
        let failed = LevelReport::new(2, &[res(&[10.0], false), res(&[], true)], None, 3.0, 100.0);
        assert!(!failed.held);
        assert_eq!(failed.first_failure.as_deref(), Some("closed before done"));
        // the first second (sent at 0 and 0.5 s) and after it (1.0 s on)
        let split = LevelReport::new(
            1,
            &[res(&[300.0, 200.0, 10.0, 20.0], false)],
            None,
            3.0,
            100.0,
        );
        assert_eq!(split.first_second.units, 2);
        assert_eq!(split.first_second.p50_ms, Some(250.0));
        assert_eq!(split.after_first_second.units, 2);
        assert_eq!(split.after_first_second.p50_ms, Some(15.0));
        assert!(!split.held, "the first second counts in the level's p99");
        // nothing measured is not held
        assert!(!LevelReport::new(1, &[res(&[], false)], None, 3.0, 100.0).held);
    }

    #[test]
    fn nice_ceilings() {
        assert_eq!(nice_ceil(0.0), 1.0);
        assert_eq!(nice_ceil(7.0), 8.0);
        assert_eq!(nice_ceil(150.0), 150.0);
        assert_eq!(nice_ceil(220.0), 250.0);
        assert_eq!(nice_ceil(527.0), 600.0);
        assert_eq!(nice_ceil(100.0), 100.0);
    }
}
