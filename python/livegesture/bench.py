"""Benchmarks on the Python side (BENCHMARKS.md): the machine's single-core limits and the PyTorch eager
streaming loop, the reference the Rust runtime is compared against.

    python -m livegesture.bench roofline --json roofline.json
    python -m livegesture.bench weights --bundle models/default --backend ort --json weights_ort.json
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


def default_decoders(man: dict, backend: str) -> list[str]:
    """The SVQ decoder graphs ``backend`` runs with its form (the runtime's ``default_decoders``): the form's
    own, except that tract runs the bundle's fused decoders (the one graph of a form listing a single decoder
    graph) in place of per-region ones when the bundle has them (docs/bundle.md#forms-and-precision)."""
    forms = man.get("forms", {})
    own = list(forms.get(man.get("backend_forms", {}).get(backend), {}).get("decoders", []))
    if backend == "tract" and len(own) > 1:
        for f in forms.values():
            if len(f.get("decoders", [])) == 1:
                return list(f["decoders"])
    return own


def _form_graphs(man: dict, backend: str) -> list[str]:
    """The graphs one token step of ``backend`` runs (its form, docs/bundle.md#forms-and-precision), in chain
    order, plus the face graph when the bundle has a face channel."""
    forms, backend_forms = man.get("forms", {}), man.get("backend_forms", {})
    if backend not in backend_forms:
        raise ValueError(f"manifest.json: backend_forms has no entry for backend {backend!r} "
                         f"(it has {sorted(backend_forms)})")
    form = forms.get(backend_forms[backend])
    if form is None:
        raise ValueError(f"manifest.json: backend_forms.{backend} names form {backend_forms[backend]!r}, "
                         f"which forms does not define (it has {sorted(forms)})")
    graphs = ["audio_encoder", *form["experts"], form.get("fusion", "fusion"), *default_decoders(man, backend)]
    if man.get("face"):
        graphs.append(man["face"]["graph"])
    return graphs


def _float_bytes(path) -> list[np.ndarray]:
    """Every float tensor a graph stores (initializers and ``Constant`` node values): what a step reads
    besides its activations and caches."""
    import onnx
    from onnx import numpy_helper
    try:
        m = onnx.load(str(path))
    except Exception as e:  # noqa: BLE001 - any unreadable file: one clear error naming it
        raise ValueError(f"{path}: cannot be read as an ONNX graph ({e})") from e
    out = [numpy_helper.to_array(i) for i in m.graph.initializer]
    for n in m.graph.node:
        if n.op_type == "Constant":
            out += [numpy_helper.to_array(a.t) for a in n.attribute if a.name == "value"]
    return [a for a in out if a.dtype.kind == "f"]


def weights_roofline(bundle, backend: str, repeats: int = 15, evict_mb: int = 128) -> dict:
    """The single-core roofline of one guided token step over the bundle's REAL bytes (issue 42 item 1).

    Method: the float tensors of every graph ``backend``'s form runs per token (initializers and constants)
    are copied into one contiguous float32 buffer, and so is one guided stream's state (every cache the
    graphs read, both guidance rows where the graph runs both). A timed ``sum`` streams that buffer from
    memory, after ``evict_mb`` MiB of other data were read (so the buffer is not in any cache level, as in
    the chain, where each graph's weights are evicted by the others': BENCHMARKS.md "Why the targets are
    missed"); the best of ``repeats`` runs is the time one core needs to read those bytes. The compute bound
    is the model's FLOPs (``export/flops.py``, both guidance branches, query-rotation tables left out) at the
    best single-core sgemm rate. The roofline is the larger of the two; the chain is judged against it
    (the 1.6x target of issue 42)."""
    import json as _json
    from pathlib import Path
    torch.set_num_threads(1)
    bundle = Path(bundle)
    mpath = bundle / "manifest.json"
    if not mpath.is_file():
        raise ValueError(f"{mpath}: no such file (not a bundle directory)")
    man = _json.loads(mpath.read_text())
    files = {g["name"]: g for g in man["graphs"]}
    names = _form_graphs(man, backend)
    parts, per_graph, state_parts, state_bytes = [], {}, [], 0
    for n in names:
        if n not in files:
            raise ValueError(f"{mpath}: the {backend} form runs graph {n!r}, which graphs does not list")
        path = bundle / files[n]["file"]
        if not path.is_file():
            raise ValueError(f"{path}: graph {n!r} of the {backend} form is missing")
        ts = _float_bytes(path)
        per_graph[n] = int(sum(a.nbytes for a in ts))
        parts += [a.astype(np.float32, copy=False).ravel() for a in ts]
        rows = 2 if n.startswith(("expert", "fusion")) else 1          # both guidance branches
        for c in files[n].get("caches", []):
            if c.get("dtype", "float32") != "float32":
                continue
            shape = [d for d in c["shape"] if d != "batch"]
            nb = rows * int(np.prod(shape)) * 4
            state_bytes += nb
            state_parts.append(np.random.default_rng(0).standard_normal(nb // 4).astype(np.float32))
    weights = np.concatenate(parts)
    both = np.concatenate([weights] + state_parts)
    evict = np.ones(evict_mb * 1024 * 1024 // 4, np.float32)

    def cold(buf):
        ts = []
        for _ in range(repeats):
            evict.sum()
            t0 = time.perf_counter()
            buf.sum()
            ts.append(time.perf_counter() - t0)
        return float(np.min(ts)), float(np.median(ts))

    w_best, w_med = cold(weights)
    ws_best, ws_med = cold(both)
    # FLOPs of the model's arithmetic (the canonical graphs; every form computes the same)
    import importlib.util
    fp = Path(__file__).resolve().parents[2] / "export" / "flops.py"
    if not fp.is_file():
        raise ValueError(f"{fp}: export/flops.py is needed for the FLOP count (run from a checkout)")
    spec = importlib.util.spec_from_file_location("lg_flops", fp)
    flops_mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(flops_mod)
    model_flops = flops_mod.bundle_counts(bundle)["_total"]["model_flops_per_step_guided"]
    a, b = torch.randn(1024, 1024), torch.randn(1024, 1024)
    torch.mm(a, b)
    peak = 2 * 1024 ** 3 / float(np.min(_times(lambda: torch.mm(a, b), repeats))) / 1e9
    compute_ms = model_flops / peak / 1e6
    memory_ms = ws_best * 1e3
    return {"bundle": str(bundle), "backend": backend, "form": man["backend_forms"][backend], "graphs": names,
            "weight_bytes": int(weights.nbytes), "weight_bytes_per_graph": per_graph,
            "state_bytes": int(state_bytes), "model_mflop": model_flops / 1e6,
            "weights_read_ms": w_best * 1e3, "weights_read_ms_median": w_med * 1e3,
            "weights_read_gbs": weights.nbytes / w_best / 1e9,
            "weights_and_state_read_ms": memory_ms, "weights_and_state_read_ms_median": ws_med * 1e3,
            "peak_gflops": peak, "compute_ms": compute_ms,
            "roofline_ms": max(memory_ms, compute_ms), "bound": "memory" if memory_ms >= compute_ms else "compute",
            "target_ms": 1.6 * max(memory_ms, compute_ms), "repeats": repeats, "evict_mb": evict_mb,
            "machine": {"cpu": _cpu_name(), "torch": torch.__version__, "numpy": np.__version__, "threads": 1}}


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
    w = sub.add_parser("weights", help="one token's single-core roofline over the bundle's real weight bytes")
    w.add_argument("--bundle", required=True)
    w.add_argument("--backend", required=True, help="whose form's graphs (the manifest's backend_forms)")
    w.add_argument("--repeats", type=int, default=15)
    w.add_argument("--json")
    t = sub.add_parser("torch", help="PyTorch eager streaming loop, per-token step time")
    src = t.add_mutually_exclusive_group(required=True)
    src.add_argument("--config")
    src.add_argument("--checkpoint")
    t.add_argument("--tokens", type=int, default=300)
    t.add_argument("--json")
    args = ap.parse_args(argv)
    if args.cmd == "roofline":
        res = roofline()
    elif args.cmd == "weights":
        try:
            res = weights_roofline(args.bundle, args.backend, args.repeats)
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
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
