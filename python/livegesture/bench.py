"""Benchmarks on the Python side (BENCHMARKS.md): the machine's single-core limits and the PyTorch eager
streaming loop, the reference the Rust runtime is compared against.

    python -m livegesture.bench roofline --json roofline.json
    python -m livegesture.bench torch --config default --tokens 300 --json torch_default.json
    python -m livegesture.bench torch --checkpoint runs/default/final.pt --tokens 300

Figures are medians over repeats on one thread (``torch.set_num_threads(1)``). Run them on a quiet machine.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np
import torch


def _times(fn, repeats: int) -> np.ndarray:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return np.array(ts)


def roofline(repeats: int = 25) -> dict:
    """Single-core f32 matrix-multiply throughput (GFLOP/s) and memory bandwidth (GB/s).

    Each figure is measured ``repeats`` times and reported as the median and as the best run. The roofline
    uses the best runs (``peak_gflops``, ``read_bandwidth_gbs``, ``copy_bandwidth_gbs``): what the core
    can do when nothing else on a shared machine gets in the way, so achieved fractions are not flattered
    by a slow measurement."""
    torch.set_num_threads(1)
    out = {}

    def both(key, work, fn):
        ts = _times(fn, repeats)
        out[key] = work / float(np.min(ts)) / 1e9
        out[key + "_median"] = work / float(np.median(ts)) / 1e9

    for n in (256, 1024):
        a, b = torch.randn(n, n), torch.randn(n, n)
        torch.mm(a, b)
        both(f"sgemm_{n}_gflops", 2 * n ** 3, lambda: torch.mm(a, b))
    # matrix-vector (batch 2, the guided single-stream case): bandwidth-bound
    w, x = torch.randn(4096, 4096), torch.randn(2, 4096)
    both("gemv_4096_b2_gflops", 2 * 2 * 4096 * 4096, lambda: x @ w)
    src = torch.empty(64 * 1024 * 1024 // 4).uniform_()
    dst = torch.empty_like(src)
    both("copy_bandwidth_gbs", 2 * src.numel() * 4, lambda: dst.copy_(src))       # read + write
    both("read_bandwidth_gbs", src.numel() * 4, lambda: src.sum())
    out["peak_gflops"] = max(out["sgemm_256_gflops"], out["sgemm_1024_gflops"])
    out["repeats"] = repeats
    out["machine"] = {"processor": platform.processor() or platform.machine(), "cpu": _cpu_name(),
                      "torch": torch.__version__, "threads": 1}
    return out


def _cpu_name() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.machine()


def torch_stream(model, tokens: int, seed: int = 0) -> dict:
    """Per-token step time of the PyTorch eager streaming loop (all components, both guidance branches)."""
    from .stream import LiveGestureStream
    torch.set_num_threads(1)
    s = LiveGestureStream(model, seed=seed)
    rng = np.random.RandomState(seed)
    M, n_mels = model.cfg.frontend.mel_frames_per_token, model.cfg.frontend.n_mels
    mels = rng.randn(tokens + 5, M, n_mels).astype(np.float32) * 2 - 6
    for i in range(5):
        s.step_token(mels[i])
    ts = []
    for i in range(tokens):
        t0 = time.perf_counter()
        s.step_token(mels[5 + i])
        ts.append(time.perf_counter() - t0)
    ts = np.array(ts) * 1e3
    return {"config": model.cfg.name, "tokens": tokens, "guided": s.guided,
            "step_ms_median": float(np.median(ts)), "step_ms_p95": float(np.percentile(ts, 95)),
            "step_ms_p99": float(np.percentile(ts, 99)), "real_time_factor": float(np.median(ts)) / (1000 * 4 / 30)}


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m livegesture.bench", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("roofline", help="single-core matmul throughput and memory bandwidth")
    r.add_argument("--json")
    t = sub.add_parser("torch", help="PyTorch eager streaming loop, per-token step time")
    src = t.add_mutually_exclusive_group(required=True)
    src.add_argument("--config")
    src.add_argument("--checkpoint")
    t.add_argument("--tokens", type=int, default=300)
    t.add_argument("--json")
    args = ap.parse_args(argv)
    if args.cmd == "roofline":
        res = roofline()
    else:
        from . import checkpoint as ckpt
        model = ckpt.load(args.checkpoint) if args.checkpoint else ckpt.random_model(args.config)
        res = torch_stream(model, args.tokens)
    print(json.dumps(res, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
