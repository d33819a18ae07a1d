//! `livegesture info`: what a bundle is.

use anyhow::Result;
use serde_json::Value;

use livegesture::bundle::Bundle;
use livegesture::model;

use super::common::ModelArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

fn fmt_count(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn fmt_bytes(n: usize) -> String {
    if n >= 1 << 20 {
        format!("{:.2} MiB", n as f64 / (1u64 << 20) as f64)
    } else if n >= 1 << 10 {
        format!("{:.1} KiB", n as f64 / 1024.0)
    } else {
        format!("{n} B")
    }
}

fn print_value(indent: usize, key: &str, v: &Value) {
    let pad = " ".repeat(indent);
    match v {
        Value::Object(m) => {
            println!("{pad}{key}:");
            for (k, v) in m {
                print_value(indent + 2, k, v);
            }
        }
        Value::String(s) => println!("{pad}{key}: {s}"),
        Value::Number(n) if n.is_f64() => match n.as_f64() {
            Some(x) if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e6) => {
                println!("{pad}{key}: {x:.4e}")
            }
            Some(x) => println!(
                "{pad}{key}: {}",
                format!("{x:.4}")
                    .trim_end_matches('0')
                    .trim_end_matches('.')
            ),
            None => println!("{pad}{key}: {n}"),
        },
        other => println!("{pad}{key}: {other}"),
    }
}

/// One line of a reduced bundle's evaluation metrics beside the f32 model's (`precision.metrics`, written
/// by `export/quantize.py --record-metrics`): FGD, Beat Constancy, BEAT2 L1div.
fn metrics_beside_f32(weights: &str, metrics: &Value) -> Option<String> {
    let g = &metrics["generated"];
    let (r, f) = (&g[weights], &g["float32"]);
    let parts: Vec<String> = [("FGD", "fgd"), ("BC", "bc"), ("L1div", "l1div_beat2")]
        .iter()
        .filter_map(|(label, k)| {
            Some(format!(
                "{label} {:.4} (f32 {:.4})",
                r[*k].as_f64()?,
                f[*k].as_f64()?
            ))
        })
        .collect();
    (!parts.is_empty()).then(|| format!("metrics: {}", parts.join(", ")))
}

/// The inference runtimes this build runs, with their versions: tract's, and ONNX Runtime's as the
/// library found (`--ort-lib`, `ORT_DYLIB_PATH`, ...) reports it when it loads.
fn runtimes(a: &Args) -> Vec<String> {
    #[cfg(feature = "ort")]
    {
        let o = livegesture::backend::BackendOptions {
            kind: livegesture::backend::BackendKind::Ort,
            ort_library: a.model.ort_lib.clone(),
            ..Default::default()
        };
        if let Err(e) = livegesture::backend::create(&o) {
            let mut v = livegesture::backend::runtime_versions();
            v.push(format!("ONNX Runtime not loaded: {e:#}"));
            return v;
        }
    }
    let _ = a;
    livegesture::backend::runtime_versions()
}

// long: the report printed section by section (bundle, graphs, forms, face, runtimes), text or JSON
pub fn run(a: Args) -> Result<()> {
    let b: Bundle = a.model.bundle()?;
    let runtimes = runtimes(&a);
    let m = b.manifest();
    let family = model::describe(&b)?;
    let total_params: u64 = m.model.parameters.values().sum();
    let rows = |g: &str| family.rows_per_stream.get(g).copied().unwrap_or(1);
    if a.json {
        let graphs: Vec<Value> = m
            .graphs
            .iter()
            .map(|g| {
                serde_json::json!({
                    "name": g.name, "file": g.file, "parameters": m.model.parameters.get(&g.name),
                    "caches": g.caches.len(), "cache_bytes_per_row": g.cache_row_bytes(),
                    "rows_per_stream": rows(&g.name),
                })
            })
            .collect();
        let mut v = serde_json::json!({
            "bundle": b.dir(), "family": m.family, "config": m.model.config_name,
            "parameters": total_params, "graphs": graphs, "frontend": m.frontend,
            "provenance": m.provenance, "checks": m.checks, "precision": b.precision(),
            "reduced_precision": m.precision, "runtimes": runtimes,
        });
        if let Value::Object(o) = &mut v {
            o.extend(family.json);
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "bundle        {} (verified: {} files match their sha256)",
        b.dir().display(),
        m.files.len()
    );
    println!(
        "model         {} (family {}, config '{}'), {} parameters",
        m.model.name.as_deref().unwrap_or("?"),
        m.family,
        m.model.config_name.as_deref().unwrap_or("?"),
        fmt_count(total_params)
    );
    match &m.precision {
        Some(p) if b.is_reduced_precision() => println!(
            "precision     {} weights (reduced-precision bundle, docs/bundle.md#forms-and-precision); reference vectors: {}",
            p.weights,
            p.reference.as_deref().unwrap_or("producer not stated")
        ),
        _ => println!("precision     float32"),
    }
    if let Some(p) = m.precision.as_ref().filter(|_| b.is_reduced_precision()) {
        if let Some(line) = metrics_beside_f32(&p.weights, &p.metrics) {
            println!("              {line}");
        }
    }
    if let Some(t) = m.provenance.get("training") {
        match t {
            Value::String(s) => println!("training      {s}"),
            other => print_value(0, "training     ", other),
        }
    }
    println!("runtimes      {}", runtimes.join("; "));
    let f = &m.frontend;
    println!(
        "audio         {} Hz mono, log-mel {} bands ({} per token), window {} / FFT {}",
        f.sample_rate, f.n_mels, f.mel_frames_per_token, f.win_length, f.n_fft
    );
    println!(
        "motion        SMPL-X at {} fps, {} frames per token ({:.1} tokens/s, {:.1} ms per token)",
        f.fps,
        f.frames_per_token,
        f.fps as f64 / f.frames_per_token as f64,
        1000.0 * f.frames_per_token as f64 / f.fps as f64
    );
    for (label, text) in &family.lines {
        println!("{label:<13} {text}");
    }
    println!("graphs");
    println!(
        "  {:<16} {:<22} {:>12} {:>7} {:>14} {:>5}",
        "name", "file", "parameters", "caches", "cache/row", "rows"
    );
    for g in &m.graphs {
        println!(
            "  {:<16} {:<22} {:>12} {:>7} {:>14} {:>5}",
            g.name,
            g.file,
            m.model
                .parameters
                .get(&g.name)
                .map(|&p| fmt_count(p))
                .unwrap_or_default(),
            g.caches.len(),
            fmt_bytes(g.cache_row_bytes()),
            rows(&g.name)
        );
    }
    if let Some(r) = b.reference() {
        println!(
            "reference     rollout of {} tokens, seed {}, audio: {}",
            r.rollout_tokens
                .map(|t| t.to_string())
                .unwrap_or_else(|| "?".into()),
            r.rollout_seed
                .map(|t| t.to_string())
                .unwrap_or_else(|| "?".into()),
            r.rollout_audio
                .as_deref()
                .or(r.clip_source.as_deref())
                .unwrap_or("?")
        );
    }
    if let Value::Object(checks) = &m.checks {
        let worst = |key: &str| {
            checks
                .values()
                .filter_map(|c| c.get(key).and_then(Value::as_f64))
                .fold(None, |acc: Option<f64>, x| {
                    Some(acc.map_or(x, |a| a.max(x)))
                })
        };
        if let (Some(a), Some(o)) = (
            worst("torch_step_vs_offline_max_abs"),
            worst("ort_vs_torch_max_abs"),
        ) {
            println!("export checks torch step vs offline max abs {a:.2e}; onnxruntime vs torch max abs {o:.2e}");
        }
    }
    if let Value::Object(p) = &m.provenance {
        println!("provenance");
        for (k, v) in p {
            if k != "training" {
                print_value(2, k, v);
            }
        }
    }
    Ok(())
}
