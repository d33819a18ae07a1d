#!/usr/bin/env python
"""Summarise and plot the benchmark matrix written by scripts/bench.sh.

    python bench/plot.py --results bench/results --plots docs/bench

Reads from --results:
  rust_<config>_<backend>.json   `livegesture bench --json` (one bundle on one backend)
  torch_<config>.json            `python -m livegesture.bench torch --json`
  ort_python_<config>.json       `bench/ort_python_peer.py --json` (the second peer)
  flops_<config>.json            `python export/flops.py --json`
  roofline.json                  `python -m livegesture.bench roofline --json`
  env.json                       machine, load average, commands (written by bench.sh)
Writes summary.json and summary.md (the tables of BENCHMARKS.md) into --results, and
step_latency.png and streams_per_core.png into --plots. Matplotlib with the Agg backend (no display).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

CONFIGS = ("default", "paper")
BACKENDS = ("tract", "ort")


def _load(p: Path):
    return json.loads(p.read_text()) if p.exists() else None


def roofline_ms(flops: float, weight_bytes: float, roof: dict, state_bytes: float = 0.0) -> dict:
    """Roofline time of one step: max(compute time at peak GFLOP/s, weight read time at read bandwidth).

    Also the same with the caches' traffic added to the memory term (`state_bytes` read and written once
    per step: the least a stateful step must move), as `roofline_state_ms`."""
    t_c = flops / (roof["peak_gflops"] * 1e9) * 1e3
    t_m = weight_bytes / (roof["read_bandwidth_gbs"] * 1e9) * 1e3
    t_s = t_m + 2 * state_bytes / (roof["copy_bandwidth_gbs"] * 1e9) * 1e3
    return {"compute_ms": t_c, "memory_ms": t_m, "roofline_ms": max(t_c, t_m),
            "bound": "compute" if t_c >= t_m else "memory",
            "state_memory_ms": t_s, "roofline_state_ms": max(t_c, t_s)}


def summarise(res: Path) -> dict:
    roof = _load(res / "roofline.json")
    # bench.sh measures the roofline before and after the matrix: the roofline is the best of both (a
    # shared machine's slow moment must not lower the roof and flatter the achieved fractions)
    roof_end = _load(res / "roofline_end.json")
    if roof and roof_end:
        roof = {**roof, **{k: max(roof[k], roof_end[k]) for k in roof
                           if isinstance(roof[k], float) and isinstance(roof_end.get(k), float)},
                "measured": "best of the measurements before and after the matrix"}
    env = _load(res / "env.json") or {}
    out = {"roofline": roof, "env": env, "runs": {}}
    for cfg in CONFIGS:
        fl = _load(res / f"flops_{cfg}.json")
        torch = _load(res / f"torch_{cfg}.json")
        for be in BACKENDS:
            r = _load(res / f"rust_{cfg}_{be}.json")
            if r is None:
                continue
            s = {"config": cfg, "backend": be, "parameters": r["parameters"], "guidance": r["guidance"],
                 "chain_ms": r["single"]["chain_ms"], "graphs_sum_ms": r["single"]["graphs_sum_ms"],
                 "graphs": {g["graph"]: g["ms"]["median"] for g in r["single"]["graphs"]},
                 "overhead_ms": r["single"]["overhead_ms_median"],
                 "frontend_ms": r["single"]["frontend_ms_per_token"],
                 "rtf": r["single"]["real_time_factor"],
                 "first_frame_ms": r["first_frame"]["total_ms"]["median"],
                 "first_frame_compute_ms": r["first_frame"]["compute_ms"]["median"],
                 "first_frame_cold_ms": r["first_frame"]["cold_pipeline_total_ms"],
                 "token0_chunk_arrival_ms": r["first_frame"]["token0_chunk_arrival_ms"],
                 "state_bytes": r["state_bytes_per_stream"],
                 "peak_rss_single_mib": (r["peak_rss_single_bytes"] or 0) / 2 ** 20,
                 "peak_rss_mib": (r["peak_rss_bytes"] or 0) / 2 ** 20,
                 "loadavg": [r["machine"]["loadavg_start"], r["machine"]["loadavg_end"]],
                 "batched": []}
            if torch:
                s["torch_ms"] = torch["step_ms_median"]
                s["rust_over_torch"] = s["chain_ms"]["median"] / torch["step_ms_median"]
            if fl and roof:
                # the model's arithmetic (older flops files: all counted MatMul/Gemm/Conv FLOPs)
                f1 = fl["_total"].get("model_flops_per_step_guided", fl["_total"]["flops_per_step_guided"])
                wb = fl["_total"]["weight_bytes"]
                rl = roofline_ms(f1, wb, roof, r["state_bytes_per_stream"])
                med = s["chain_ms"]["median"]
                s["flops_per_step"] = f1
                s["weight_bytes"] = wb
                s["roofline"] = rl
                s["achieved_gflops"] = f1 / (med * 1e-3) / 1e9
                s["roofline_fraction"] = rl["roofline_ms"] / med
                s["over_roofline"] = med / rl["roofline_ms"]
                s["roofline_state_fraction"] = rl["roofline_state_ms"] / med
            for b in r["batched"]:
                e = {"n": b["streams"], "step_ms": b["step_ms"]["median"], "p95": b["step_ms"]["p95"],
                     "timed_steps": b["timed_steps"], "capped": b["capped"], "churn": b["churn"],
                     "realtime_streams": b["realtime_streams"],
                     "realtime_streams_with_frontend": b["realtime_streams_with_frontend"]}
                if fl and roof:
                    fn = f1 * b["streams"]
                    rl = roofline_ms(fn, wb, roof, r["state_bytes_per_stream"] * b["streams"])
                    e["achieved_gflops"] = fn / (b["step_ms"]["median"] * 1e-3) / 1e9
                    e["compute_fraction"] = e["achieved_gflops"] / roof["peak_gflops"]
                    e["roofline_ms"] = rl["roofline_ms"]
                    e["roofline_fraction"] = rl["roofline_ms"] / b["step_ms"]["median"]
                    e["bound"] = rl["bound"]
                    e["roofline_state_ms"] = rl["roofline_state_ms"]
                    e["roofline_state_fraction"] = rl["roofline_state_ms"] / b["step_ms"]["median"]
                    e["graphs_ms"] = b.get("graphs_sum_ms_median")
                    e["overhead_ms"] = b.get("overhead_ms_median")
                s["batched"].append(e)
            out["runs"][f"{cfg}/{be}"] = s
    return out


def table_md(summ: dict) -> str:
    L = []
    runs = summ["runs"]
    L.append("| config | backend | whole chain median / p95 / p99 (ms) | RTF | first frame (ms): total / compute | "
             "state / stream | peak RSS 1 stream / all (MiB) | PyTorch eager (ms) | Rust / PyTorch |")
    L.append("|---|---|---|---|---|---|---|---|---|")
    for k, s in runs.items():
        c = s["chain_ms"]
        L.append(f"| {s['config']} | {s['backend']} | {c['median']:.2f} / {c['p95']:.2f} / {c['p99']:.2f} | "
                 f"{s['rtf']:.3f} | {s['first_frame_ms']:.1f} / {s['first_frame_compute_ms']:.2f} | "
                 f"{s['state_bytes'] / 2 ** 20:.2f} MiB | {s['peak_rss_single_mib']:.0f} / {s['peak_rss_mib']:.0f} | "
                 f"{s.get('torch_ms', float('nan')):.2f} | {s.get('rust_over_torch', float('nan')):.2f} |")
    L.append("")
    L.append("Per graph, one stream with guidance (median ms per token step; experts and fusion run both branches "
             "as a batch of 2):")
    L.append("")
    names = []
    for s in runs.values():
        for g in s["graphs"]:
            if g not in names:
                names.append(g)
    L.append("| config | backend | " + " | ".join(names) + " | sum | chain - sum |")
    L.append("|---|---|" + "---|" * (len(names) + 2))
    for s in runs.values():
        L.append(f"| {s['config']} | {s['backend']} | " + " | ".join(f"{s['graphs'].get(n, float('nan')):.3f}" for n in names)
                 + f" | {s['graphs_sum_ms']['median']:.3f} | {s['overhead_ms']:.3f} |")
    roof = summ.get("roofline")
    if roof:
        L.append("")
        L.append(f"Roofline (this machine, one core, `python -m livegesture.bench roofline`): peak f32 matmul "
                 f"{roof['peak_gflops']:.1f} GFLOP/s (sgemm 256: {roof['sgemm_256_gflops']:.1f}, 1024: "
                 f"{roof['sgemm_1024_gflops']:.1f}), read bandwidth {roof['read_bandwidth_gbs']:.1f} GB/s, "
                 f"copy bandwidth {roof['copy_bandwidth_gbs']:.1f} GB/s.")
        L.append("")
        L.append("| config | backend | N streams | MFLOP / step | weight MB / step | roofline ms (bound) | "
                 "roofline + state ms | measured ms (graphs) | achieved GFLOP/s | of peak compute | roofline / measured | "
                 "(roofline + state) / measured |")
        L.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for s in runs.values():
            if "roofline" not in s:
                continue
            L.append(f"| {s['config']} | {s['backend']} | 1 (chain) | {s['flops_per_step'] / 1e6:.1f} | "
                     f"{s['weight_bytes'] / 1e6:.1f} | {s['roofline']['roofline_ms']:.3f} ({s['roofline']['bound']}) | "
                     f"{s['roofline']['roofline_state_ms']:.3f} | "
                     f"{s['chain_ms']['median']:.2f} ({s['graphs_sum_ms']['median']:.2f}) | {s['achieved_gflops']:.2f} | "
                     f"{s['achieved_gflops'] / roof['peak_gflops']:.1%} | {s['roofline_fraction']:.1%} | "
                     f"{s['roofline_state_fraction']:.1%} |")
            for b in s["batched"]:
                if "roofline_ms" not in b:
                    continue
                L.append(f"| {s['config']} | {s['backend']} | {b['n']} (batched) | "
                         f"{s['flops_per_step'] * b['n'] / 1e6:.1f} | {s['weight_bytes'] / 1e6:.1f} | "
                         f"{b['roofline_ms']:.3f} ({b['bound']}) | {b['roofline_state_ms']:.3f} | "
                         f"{b['step_ms']:.2f} ({b['graphs_ms'] if b['graphs_ms'] is not None else float('nan'):.2f}) | "
                         f"{b['achieved_gflops']:.2f} | {b['compute_fraction']:.1%} | {b['roofline_fraction']:.1%} | "
                         f"{b['roofline_state_fraction']:.1%} |")
    L.append("")
    L.append("Batched stepping, real-time streams one core sustains (N x 133.3 ms / median batched step; "
             "with each stream's log-mel frontend added in parentheses):")
    L.append("")
    ns = sorted({b["n"] for s in runs.values() for b in s["batched"]})
    L.append("| config | backend | " + " | ".join(f"N={n}" for n in ns) + " |")
    L.append("|---|---|" + "---|" * len(ns))
    for s in runs.values():
        by = {b["n"]: b for b in s["batched"]}
        cells = []
        for n in ns:
            b = by.get(n)
            if b is None:
                cells.append("-")
            else:
                cap = f", {b['timed_steps']} steps" + (" (capped)" if b["capped"] else "")
                cells.append(f"{b['realtime_streams']:.1f} ({b['realtime_streams_with_frontend']:.1f}); "
                             f"{b['step_ms']:.1f} ms{cap}")
        L.append(f"| {s['config']} | {s['backend']} | " + " | ".join(cells) + " |")
    return "\n".join(L) + "\n"


def peers_md(res: Path, summ: dict) -> str:
    """The two peers of the Rust runtime on the same model, one core: the PyTorch eager loop and the exported
    graphs chained from Python with onnxruntime (bench/ort_python_peer.py, which first reproduces the bundle's
    reference rollout token for token)."""
    L = []
    for cfg in CONFIGS:
        p = _load(res / f"ort_python_{cfg}.json")
        if not p or "single" not in p:
            continue
        if not L:
            L += ["| config | PyTorch eager (ms) | ort from Python: step / its graph runs (ms) | Rust ort / tract (ms) | "
                  "Rust ort vs ort-Python | Rust ort vs PyTorch | N=32 batched step: ort-Python / Rust ort / Rust tract (ms) | "
                  "reference tokens reproduced |",
                  "|---|---|---|---|---|---|---|---|"]
        t = _load(res / f"torch_{cfg}.json")
        tm = t["step_ms_median"] if t else float("nan")
        rust = {be: summ["runs"].get(f"{cfg}/{be}") for be in BACKENDS}
        ro = rust["ort"]["chain_ms"]["median"] if rust.get("ort") else float("nan")
        rt = rust["tract"]["chain_ms"]["median"] if rust.get("tract") else float("nan")
        pm = p["single"]["step_ms"]["median"]

        def n32(x):
            return next((b for b in x if b.get("streams", b.get("n")) == 32), None)

        pb = n32(p.get("batched", []))
        rb = {be: n32(rust[be]["batched"]) if rust.get(be) else None for be in BACKENDS}
        cell = " / ".join(f"{b['step_ms']['median'] if isinstance(b['step_ms'], dict) else b['step_ms']:.1f}"
                          if b else "-" for b in (pb, rb.get("ort"), rb.get("tract")))
        chk = p.get("check", {})
        L.append(f"| {cfg} | {tm:.2f} | {pm:.2f} / {p['single']['graphs_sum_ms']:.2f} | {ro:.2f} / {rt:.2f} | "
                 f"{pm / ro:.1f}x faster | {tm / ro:.1f}x faster | {cell} | "
                 f"{chk.get('tokens_checked', 0)} of {chk.get('reference_tokens', '?')} |")
    return "\n".join(L) + "\n" if L else ""


def targets_md(summ: dict) -> str:
    """Issue 7's targets on one core: measured value, verdict and the factor by which a target is missed."""
    runs = summ["runs"]
    L = ["| target | measured | verdict |", "|---|---|---|"]

    def verdict(ok: bool, factor: float, by: str) -> str:
        return "met" if ok else f"**missed**: {factor:.2f}x over ({by})"

    parts = []
    for be in BACKENDS:
        s = runs.get(f"default/{be}")
        if s:
            m = s["chain_ms"]["median"]
            parts.append((be, m, verdict(m < 2.0, m / 2.0, f"by {m - 2.0:.2f} ms")))
    if parts:
        L.append("| default, 1 stream, guidance, whole chain < 2 ms on both backends | "
                 + ", ".join(f"{be} {m:.2f} ms" for be, m, _ in parts) + " | "
                 + "; ".join(f"{be}: {v}" for be, _, v in parts) + " |")
    paper = [runs[f"paper/{be}"] for be in BACKENDS if f"paper/{be}" in runs]
    if paper:
        f = min(paper, key=lambda s: s["chain_ms"]["median"])
        m = f["chain_ms"]["median"]
        L.append(f"| paper, 1 stream < 15 ms on the faster backend | {f['backend']} {m:.2f} ms | "
                 f"{verdict(m < 15.0, m / 15.0, f'by {m - 15.0:.1f} ms')} |")
        if "roofline" in f:
            r = f["roofline"]["roofline_ms"]
            L.append(f"| paper, 1 stream within 3x of its roofline | {f['backend']} {m:.2f} ms vs roofline {r:.2f} ms "
                     f"({f['roofline']['bound']}-bound) = {m / r:.2f}x | "
                     f"{verdict(m <= 3 * r, m / (3 * r), f'{m / r:.2f}x instead of 3x')} |")
    cells = []
    for key, s in runs.items():
        b = next((b for b in s["batched"] if b["n"] == 32 and "compute_fraction" in b), None)
        if b:
            cf = b["compute_fraction"]
            cells.append(f"{key} {cf:.1%} ({'met' if cf >= 0.5 else f'missed, {0.5 / cf:.1f}x short'})")
    if cells:
        L.append("| batched N = 32 >= 50% of compute roofline | " + "; ".join(cells) + " | "
                 + ("met" if all("met" in c for c in cells) else "**missed**") + " |")
    return "\n".join(L) + "\n"


def plot(res: Path, plots: Path, summ: dict):
    plots.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for ax, cfg in zip(axes, CONFIGS):
        data, labels = [], []
        for be in BACKENDS:
            r = _load(res / f"rust_{cfg}_{be}.json")
            if r:
                data.append(r["single"]["chain_samples_ms"])
                labels.append(be)
        t = _load(res / f"torch_{cfg}.json")
        if t and t.get("samples_ms"):
            data.append(t["samples_ms"])
            labels.append("pytorch eager")
        p = _load(res / f"ort_python_{cfg}.json")
        if p and p.get("single", {}).get("samples_ms"):
            data.append(p["single"]["samples_ms"])
            labels.append("onnxruntime from Python")
        if not data:
            ax.set_visible(False)
            continue
        lo = max(min(min(d) for d in data) * 0.8, 1e-3)
        hi = max(max(d) for d in data) * 1.2
        bins = np.logspace(np.log10(lo), np.log10(hi), 80)
        for d, lab in zip(data, labels):
            ax.hist(d, bins=bins, alpha=0.55, label=f"{lab} (median {np.median(d):.2f} ms)")
        ax.set_xscale("log")
        ax.set_xlabel("whole-chain token step (ms), one stream, guidance on, one thread")
        ax.set_ylabel("steps")
        ax.set_title(f"{cfg} config: per-step latency distribution")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(plots / "step_latency.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for key, s in summ["runs"].items():
        if not s["batched"]:
            continue
        n = [b["n"] for b in s["batched"]]
        v = [b["realtime_streams"] for b in s["batched"]]
        ax.plot(n, v, marker="o", label=key)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("streams stepped together (N)")
    ax.set_ylabel("real-time streams per core")
    ax.set_title("Batched stepping: streams one core keeps in real time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(plots / "streams_per_core.png", dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="bench/results")
    ap.add_argument("--plots", default="docs/bench")
    ap.add_argument("--doc", help="replace the text between '<!-- results:begin -->' and '<!-- results:end -->' "
                                  "in this file (BENCHMARKS.md) with the tables")
    args = ap.parse_args(argv)
    res = Path(args.results)
    summ = summarise(res)
    (res / "summary.json").write_text(json.dumps(summ, indent=1))
    peers = peers_md(res, summ)
    md = table_md(summ)
    if peers:
        md += ("\nThe peers on the same model, one core (the second peer: `bench/ort_python_peer.py`, the bundle's "
               "graphs chained from Python with onnxruntime, one InferenceSession per graph):\n\n" + peers)
    md += "\nTargets (issue 7), one core:\n\n" + targets_md(summ)
    (res / "summary.md").write_text(md)
    plot(res, Path(args.plots), summ)
    if args.doc:
        doc = Path(args.doc)
        text = doc.read_text()
        b, e = "<!-- results:begin -->", "<!-- results:end -->"
        if b in text and e in text:
            env = summ.get("env") or {}
            head = (f"Run {env.get('start', '?')} .. {env.get('end', '?')} on `{env.get('cpu', '?')}`, "
                    f"{env.get('cores', '?')} cores, load average {env.get('loadavg_start', '?')} at the start, "
                    f"{env.get('loadavg_end', '?')} at the end, commit `{env.get('commit', '?')}`.\n\n")
            pre, rest = text.split(b, 1)
            post = rest.split(e, 1)[1]
            doc.write_text(pre + b + "\n" + head + md + e + post)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
