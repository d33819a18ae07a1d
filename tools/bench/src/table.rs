//! The benchmark report as a plain-text table.

use super::*;

/// A human-readable table of `r`.
pub fn format_table(r: &BenchReport) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "bundle {} (config {}, {:.1} M parameters), backend {}, guidance {}",
        r.bundle,
        r.config.as_deref().unwrap_or("?"),
        r.parameters as f64 / 1e6,
        r.backend_description,
        r.guidance
    );
    let _ = writeln!(
        o,
        "machine: {}, {} cores ({} usable by this process), load {} -> {}",
        r.machine.cpu,
        r.machine.cores,
        r.machine.usable_cpus,
        r.machine.loadavg_start,
        r.machine.loadavg_end
    );
    let _ = writeln!(
        o,
        "\nper-token step, one stream ({} timed steps after {} warm-up), ms:",
        r.single.chain_ms.n, r.single.warmup_steps
    );
    let _ = writeln!(o, "  {:<16} {:>9} {:>9} {:>9}", "", "median", "p95", "p99");
    let row = |o: &mut String, name: &str, s: &Stats| {
        let _ = writeln!(
            o,
            "  {:<16} {:>9.3} {:>9.3} {:>9.3}",
            name, s.median, s.p95, s.p99
        );
    };
    for g in &r.single.graphs {
        row(&mut o, &g.graph, &g.ms);
    }
    row(&mut o, "sum of graphs", &r.single.graphs_sum_ms);
    row(&mut o, "whole chain", &r.single.chain_ms);
    let _ = writeln!(
        o,
        "  overhead (chain - graphs) {:.3} ms, log-mel frontend {:.3} ms/token",
        r.single.overhead_ms_median, r.single.frontend_ms_per_token
    );
    let _ = writeln!(
        o,
        "  real-time factor {:.4} (token = {:.1} ms)",
        r.single.real_time_factor, r.token_ms
    );
    let f = &r.first_frame;
    let _ = writeln!(
        o,
        "\nfirst frame, audio at real-time pace in {:.0} ms chunks ({} trials): {:.1} ms median from the first sample \
         (token 0's audio ends at {:.1} ms, its chunk arrives at {:.1} ms; compute after that {:.2} ms median); \
         cold pipeline {:.1} ms (compute {:.1} ms)",
        f.chunk_ms,
        f.total_ms.n,
        f.total_ms.median,
        f.token0_audio_ms,
        f.token0_chunk_arrival_ms,
        f.compute_ms.median,
        f.cold_pipeline_total_ms,
        f.cold_pipeline_compute_ms
    );
    let _ = writeln!(
        o,
        "state per stream: {} bytes ({} without guidance); peak RSS {:.1} MiB after single stream, {:.1} MiB at the end",
        r.state_bytes_per_stream,
        r.state_bytes_per_stream_unguided,
        r.peak_rss_single_bytes.unwrap_or(0) as f64 / 1048576.0,
        r.peak_rss_bytes.unwrap_or(0) as f64 / 1048576.0
    );
    if !r.batched.is_empty() {
        let _ = writeln!(
            o,
            "\nbatched stepping (one core):\n  {:>5} {:>6} {:>11} {:>9} {:>9} {:>9} {:>13} {:>13}",
            "N", "steps", "step med ms", "p95", "graphs", "ms/strm", "RT streams", "RT w/ frontend"
        );
        for b in &r.batched {
            let _ = writeln!(
                o,
                "  {:>5} {:>6} {:>11.2} {:>9.2} {:>9.2} {:>9.3} {:>13.1} {:>13.1}{}",
                b.streams,
                b.timed_steps,
                b.step_ms.median,
                b.step_ms.p95,
                b.graphs_sum_ms_median,
                b.per_stream_ms,
                b.realtime_streams,
                b.realtime_streams_with_frontend,
                if b.capped { "  (time-capped)" } else { "" }
            );
        }
        if let Some(first) = r.batched.first() {
            let _ = write!(
                o,
                "\nbatched, per graph (median ms per batched step):\n  {:>5}",
                "N"
            );
            for g in &first.graphs {
                let _ = write!(o, " {:>14}", g.graph);
            }
            let _ = writeln!(o);
            for b in &r.batched {
                let _ = write!(o, "  {:>5}", b.streams);
                for g in &b.graphs {
                    let _ = write!(o, " {:>14.3}", g.ms.median);
                }
                let _ = writeln!(o);
            }
        }
    }
    o
}
