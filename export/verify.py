"""Export-time checks. Each failure names the graph, the output, the step and the error.

1. torch step-by-step vs torch offline causal forward (docs/parity.md: max abs 1e-5), over a sequence
   longer than every window: catches a step that reads the future or drops a cache update;
2. the ONNX graph: onnx.checker, opset >= 17, no If/Loop, static ranks, batch axis dynamic;
3. onnxruntime vs the torch step over chained steps with batch sizes 1, 2 and 5 (max abs 1e-5).
"""
from __future__ import annotations

import numpy as np
import torch

from livegesture.models.model import LiveGesture
from livegesture.regions import REGION_NAMES

from graphs import call_step, component, random_inputs

STEP_VS_OFFLINE = 1e-5
ORT_VS_TORCH = 1e-5


class ExportCheckError(RuntimeError):
    pass


def fail(graph, output, step, err, bound, what):
    raise ExportCheckError(f"{what}: graph '{graph}', output '{output}', step {step}: max abs error {err:.3g} "
                           f"exceeds the bound {bound:g}")


def _first_bad_step(a: torch.Tensor, b: torch.Tensor, time_axis: int, bound: float):
    err = (a - b).abs()
    per_step = err.transpose(0, time_axis).reshape(err.shape[time_axis], -1).max(dim=1).values
    bad = (per_step > bound).nonzero()
    if len(bad):
        s = int(bad[0])
        return s, float(per_step[s])
    return None, float(per_step.max())


@torch.no_grad()
def check_step_vs_offline(model: LiveGesture, graph: str, seed: int = 0) -> float:
    """Returns the max abs error; raises ExportCheckError naming the first failing step."""
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
        hid = torch.stack([stack(f"hidden_{r}") for r in REGION_NAMES], 2)
        off = comp(hid, stack("audio"), seq[0]["cond"])
        name, st = "logits", torch.stack([o["logits"] for o in outs], 1)
    else:
        off = comp.decode(stack("token")).reshape(B, T, cfg.frontend.frames_per_token, -1)
        name, st = "motion", torch.stack([o["motion"] for o in outs], 1)
    step, err = _first_bad_step(off, st, 1, STEP_VS_OFFLINE)
    if step is not None:
        fail(graph, name, step, err, STEP_VS_OFFLINE, "torch step-by-step vs offline causal forward")
    return err


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
                       seed: int = 0) -> float:
    import onnxruntime as ort
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])
    comp = component(model, graph)
    specs = comp.cache_specs()
    out_names = [o.name for o in sess.get_outputs()]
    worst = 0.0
    for B in batches:
        g = torch.Generator().manual_seed(seed + B)
        t_cache = comp.init_cache(B)
        o_cache = {s.name: t_cache[s.name].numpy() for s in specs}
        for step in range(n_steps):
            inp = random_inputs(model, graph, B, g)
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
                err = float(np.abs(got.astype(np.float64) - want.astype(np.float64)).max()) if got.size else 0.0
                if err > ORT_VS_TORCH:
                    fail(graph, name, step, err, ORT_VS_TORCH, f"onnxruntime vs torch (batch {B})")
                worst = max(worst, err)
            o_cache = {s.name: res[f"new_cache.{s.name}"] for s in specs}   # ORT chains its own caches
    return worst
