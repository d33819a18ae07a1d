"""Export-time checks. Each failure names the graph, the output, the step, the error and the scale it was judged at.

Every bound is docs/parity.md's, scaled by the reference tensor's magnitude: ``max|a - b| <= bound x
max(1, max|ref|)`` per graph, output and step (:mod:`livegesture.compare`, the one comparison helper; a NaN or
Inf on either side fails).

1. torch step-by-step vs torch offline causal forward (1e-5 scaled, the offline forward the reference), over a
   sequence longer than every window: catches a step that reads the future or drops a cache update;
2. the ONNX graph: onnx.checker, opset >= 17, no If/Loop, static ranks, batch axis dynamic;
3. onnxruntime vs the torch step over chained steps with batch sizes 1, 2 and 5 (1e-5 scaled, torch the
   reference); a ring graph (docs/bundle.md#ring-caches) is chained at consecutive phases from a random one,
   each side's entries written into its caches at the phase (:func:`livegesture.forms.ring.write_entries`).
"""
from __future__ import annotations

import numpy as np
import torch

from livegesture.compare import diff
from livegesture.models.model import LiveGesture

from livegesture.forms.ring import ring_base, write_entries

from .graphs import call_step, component, random_inputs

STEP_VS_OFFLINE = 1e-5
ORT_VS_TORCH = 1e-5


class ExportCheckError(RuntimeError):
    pass


def fail(graph, output, step, err, bound, what, scale: float = 1.0, detail: str = ""):
    raise ExportCheckError(f"{what}: graph '{graph}', output '{output}', step {step}: max abs error {err:.3g} "
                           f"exceeds the bound {bound:g} x scale {scale:.4g} = {bound * scale:.3g}"
                           + (f" ({detail})" if detail else ""))


def _first_bad_step(a: torch.Tensor, b: torch.Tensor, time_axis: int, bound: float):
    """The first step along ``time_axis`` whose slice of ``a`` differs from ``b`` (the reference) by more than
    ``bound`` x its scale, as (step, error, scale, detail); else (None, worst error, its scale, ""), the worst
    relative to its scale."""
    worst = (-1.0, 1.0)
    for s in range(a.shape[time_axis]):
        d = diff(a.select(time_axis, s), b.select(time_axis, s))
        if not d.within(bound):
            return s, d.max_abs, d.scale, d.describe()
        if worst[0] < 0 or d.scaled_error > worst[0] / worst[1]:
            worst = (d.max_abs, d.scale)
    return None, worst[0], worst[1], ""


@torch.no_grad()
def check_step_vs_offline(model: LiveGesture, graph: str, seed: int = 0) -> tuple[float, float]:
    """Returns (error, scale) of the worst step relative to its scale; raises ExportCheckError naming the first
    failing step, its error and scale."""
    cfg = model.cfg
    T = max(cfg.history, cfg.audio_window, cfg.fuse_window) + 5
    g = torch.Generator().manual_seed(seed)
    B = 2
    comp = model.components()[graph]
    cache = comp.init_cache(B)
    seq = [random_inputs(model, graph, B, g) for _ in range(T)]
    if graph.startswith("expert_"):
        seq[0]["prev_token"][:] = cfg.bos_token
    outs = []
    for t in range(T):
        o, cache = call_step(model, graph, seq[t], cache)
        outs.append(o)
    stack = lambda k: torch.stack([s[k] for s in seq], 1)  # noqa: E731
    if graph == "audio_encoder":
        off = comp(torch.cat([s["mel"] for s in seq], 1))
        name, st = "audio", torch.stack([o["audio"] for o in outs], 1)
    elif graph.startswith("expert_"):
        off, _ = comp(stack("prev_token"), stack("audio"), seq[0]["cond"])
        name, st = "hidden", torch.stack([o["hidden"] for o in outs], 1)
    elif graph == "fusion":
        hid = torch.stack([stack(f"hidden_{r}") for r in model.region_names], 2)
        if "audio" in seq[0]:
            off = comp(hid, stack("audio"), seq[0]["cond"])
        else:   # a fusion that reads no audio (graphs.data_io): any audio gives the same forward
            off = comp(hid, torch.zeros(B, T, cfg.audio_dim), torch.ones(B))
        name, st = "logits", torch.stack([o["logits"] for o in outs], 1)
    else:
        off = comp.decode(stack("token")).reshape(B, T, cfg.frontend.frames_per_token, -1)
        name, st = "motion", torch.stack([o["motion"] for o in outs], 1)
    step, err, scale, detail = _first_bad_step(st, off, 1, STEP_VS_OFFLINE)
    if step is not None:
        fail(graph, name, step, err, STEP_VS_OFFLINE, "torch step-by-step vs offline causal forward", scale, detail)
    return err, scale


def check_onnx_structure(path: str, graph: str, min_opset: int = 17):
    import onnx
    m = onnx.load(path)
    onnx.checker.check_model(m, full_check=True)
    opset = max(o.version for o in m.opset_import if o.domain in ("", "ai.onnx"))
    if opset < min_opset:
        raise ExportCheckError(f"graph '{graph}': opset {opset} < {min_opset}")
    bad = sorted({n.op_type for n in m.graph.node if n.op_type in ("If", "Loop", "Scan")})
    if bad:
        raise ExportCheckError(f"graph '{graph}': data-dependent control flow {bad} is not allowed")
    for v in list(m.graph.input) + list(m.graph.output):
        dims = v.type.tensor_type.shape.dim
        if not dims or not dims[0].dim_param:
            raise ExportCheckError(f"graph '{graph}': tensor '{v.name}' has no dynamic batch axis 0")
        if any(not d.dim_param and d.dim_value <= 0 for d in dims[1:]):
            raise ExportCheckError(f"graph '{graph}': tensor '{v.name}' has a non-static axis beyond the batch")
    return m


@torch.no_grad()
def check_ort_vs_torch(model: LiveGesture, graph: str, path: str, n_steps: int = 8, batches=(1, 2, 5),
                       seed: int = 0) -> tuple[float, float]:
    """onnxruntime vs the torch step; returns (error, scale) of the worst comparison relative to its scale, or
    raises ExportCheckError naming the first failing graph, output, step, error and scale."""
    import onnxruntime as ort
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    comp = component(model, graph)
    specs = comp.cache_specs()
    out_names = [o.name for o in sess.get_outputs()]
    ring = ring_base(graph) is not None
    worst = (0.0, 1.0)   # (error, scale) of the worst comparison relative to its scale
    for B in batches:
        g = torch.Generator().manual_seed(seed + B)
        t_cache = comp.init_cache(B)
        o_cache = {s.name: t_cache[s.name].numpy() for s in specs}
        phase0 = None
        for step in range(n_steps):
            inp = random_inputs(model, graph, B, g)
            if ring:   # consecutive phases from the first step's random one
                phase0 = int(inp["phase"][0]) if phase0 is None else phase0
                inp["phase"][:] = phase0 + step
                t_cache_in = t_cache
            t_out, t_cache = call_step(model, graph, inp, t_cache)
            feed = {k: v.numpy() for k, v in inp.items()}
            feed.update({f"cache.{k}": v for k, v in o_cache.items()})
            res = dict(zip(out_names, sess.run(None, feed)))
            ref = {k: v.numpy() for k, v in t_out.items()}
            ref.update({f"new_cache.{k}": v.numpy() for k, v in t_cache.items()})
            for name, want in ref.items():
                got = res[name]
                if got.shape != want.shape:
                    raise ExportCheckError(f"onnxruntime vs torch: graph '{graph}', output '{name}', step {step}, "
                                           f"batch {B}: shape {got.shape}, expected {want.shape}")
                if not got.size:
                    continue
                d = diff(got, want)
                if not d.within(ORT_VS_TORCH):
                    fail(graph, name, step, d.max_abs, ORT_VS_TORCH, f"onnxruntime vs torch (batch {B})", d.scale,
                         d.describe())
                if d.scaled_error > worst[0] / worst[1]:
                    worst = (d.max_abs, d.scale)
            if ring:   # each side writes its own entries into its own caches at the phase
                new = {s.name: torch.from_numpy(res[f"new_cache.{s.name}"]) for s in specs}
                o_cache = {k: v.numpy() for k, v in write_entries(
                    {k: torch.from_numpy(v) for k, v in o_cache.items()}, new, phase0 + step).items()}
                t_cache = write_entries(t_cache_in, t_cache, phase0 + step)
            else:
                o_cache = {s.name: res[f"new_cache.{s.name}"] for s in specs}   # ORT chains its own caches
    return worst
