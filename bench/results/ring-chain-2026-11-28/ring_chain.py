"""Experiment: the canonical chain of models/default with ring-layout eXperts and fusion (livegesture.forms.ring),
exported from the checkpoint, run from Python with onnxruntime: (1) does it reproduce the reference rollout's
tokens? (2) whole batched step at N streams, shift vs ring, interleaved, thread CPU time."""
import sys, time, warnings, json
from pathlib import Path
import numpy as np, torch, onnxruntime as ort
sys.path.insert(0, "/work/wt/streams/export")
from livegesture import checkpoint
from livegesture.forms.ring import RingStep
from livegesture.ort_chain import Chain, Streams, token_mels, reference
from livegesture.regions import REGION_NAMES
from graphs import StepGraph, component

BUNDLE = Path("/work/wt/streams/models/default")
OUT = Path("/tmp/speed4/ringchain"); OUT.mkdir(parents=True, exist_ok=True)
RING = [f"expert_{r}" for r in REGION_NAMES] + ["fusion"]

class RingGraph(torch.nn.Module):
    def __init__(self, model, graph):
        super().__init__()
        self.inner = StepGraph(model, graph)
        self.ring = RingStep(component(model, graph))
        self.graph = graph
    def forward(self, phase, *args):
        w = self.inner; n = len(w.inputs)
        inp = {s["name"]: a for s, a in zip(w.inputs, args[:n])}
        cache = {s.name: a for s, a in zip(w.cache_specs, args[n:])}
        if self.graph == "fusion":
            out, new = self.ring.step({r: inp[f"hidden_{r}"] for r in REGION_NAMES}, inp["audio"], inp["cond"], cache=cache, phase=phase)
        else:
            out, new = self.ring.step(inp["prev_token"], inp["audio"], inp["cond"], cache=cache, phase=phase)
        return tuple(out[o["name"]] for o in w.outputs) + tuple(new[s.name] for s in w.cache_specs)

if not all((OUT / f"{g}.onnx").exists() for g in RING):
    model = checkpoint.load("/work/wt/streams/models/default.train/checkpoint.pt")
    from graphs import random_inputs
    for g in RING:
        rg = RingGraph(model, g).eval()
        gen = torch.Generator().manual_seed(0)
        inp = random_inputs(model, g, 2, gen)
        cache = component(model, g).init_cache(2)
        args = (torch.tensor(3),) + tuple(inp[i["name"]] for i in rg.inner.inputs) + tuple(cache[s.name] for s in rg.inner.cache_specs)
        names_in = ["phase"] + rg.inner.input_names(); names_out = rg.inner.output_names()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(rg, args, str(OUT / f"{g}.onnx"), input_names=names_in, output_names=names_out,
                              dynamic_axes={n: {0: "batch"} for n in names_in[1:] + names_out}, opset_version=17,
                              do_constant_folding=True, dynamo=False)
        print("exported", g, flush=True)

class RingChain(Chain):
    def __init__(self, bundle, phase0=7):
        super().__init__(bundle)
        opts = ort.SessionOptions(); opts.intra_op_num_threads = 1; opts.inter_op_num_threads = 1
        for g in RING:
            self.sessions[g] = ort.InferenceSession(str(OUT / f"{g}.onnx"), opts, providers=["CPUExecutionProvider"])
            self.out_names[g] = [o.name for o in self.sessions[g].get_outputs()]
        self.phase = phase0
    def run(self, name, feed, caches):
        if name not in RING:
            return super().run(name, feed, caches)
        res = self.sessions[name].run(None, {**feed, **caches, "phase": np.array(self.phase, np.int64)})
        out = dict(zip(self.out_names[name], res))
        for c in self.specs[name]["caches"]:
            e = out[c["output"]]
            if c["name"] == "step":
                caches[c["input"]] = e
            else:
                buf = caches[c["input"]]
                buf[..., self.phase % buf.shape[-2], :] = e[..., 0, :]
        if name == "fusion":
            self.phase += 1
        return out

GCPU = {"shift": 0.0, "ring": 0.0}
_base_run = Chain.run
def _timed_base_run(self, name, feed, caches):
    c0 = time.thread_time(); out = _base_run(self, name, feed, caches)
    GCPU["ring" if isinstance(self, RingChain) else "shift"] += time.thread_time() - c0; return out
Chain.run = _timed_base_run
_ring_run = RingChain.run
def _timed_ring_run(self, name, feed, caches):
    if name not in RING: return _ring_run(self, name, feed, caches)
    c0 = time.thread_time(); out = _ring_run(self, name, feed, caches)
    GCPU["ring"] += time.thread_time() - c0; return out
RingChain.run = _timed_ring_run
mode = sys.argv[1]
if mode == "tokens":
    ch = RingChain(BUNDLE)
    audio, seed, want = reference(ch)
    mels = token_mels(ch, audio)
    n = min(len(want), len(mels))
    s = Streams(ch, 1, [seed], [0])
    first = None
    for t in range(n):
        got, _ = s.step(mels[t][None])
        if first is None and not np.array_equal(got[0], want[t]):
            first = t
            break
    print(json.dumps({"reference_tokens": int(len(want)), "checked": n, "first_difference": first}))
else:
    N = int(sys.argv[2]); rounds = int(sys.argv[3])
    base, ring = Chain(BUNDLE), RingChain(BUNDLE)
    audio, seed, _ = reference(base)
    mels = token_mels(base, audio)
    sb = Streams(base, N, list(range(N)), [0] * N); sr = Streams(ring, N, list(range(N)), [0] * N)
    idx = lambda t: np.stack([mels[(t + 13 * i) % len(mels)] for i in range(N)])
    t = 0
    for _ in range(3):
        sb.step(idx(t)); sr.step(idx(t)); t += 1
    tb, tr = [], []
    GCPU["shift"] = GCPU["ring"] = 0.0
    for _ in range(rounds):
        k = 4
        c0 = time.thread_time()
        for j in range(k): sb.step(idx(t + j))
        c1 = time.thread_time()
        for j in range(k): sr.step(idx(t + j))
        c2 = time.thread_time()
        t += k
        tb.append((c1 - c0) / k * 1e3); tr.append((c2 - c1) / k * 1e3)
    r = [b / a for a, b in zip(tb, tr)]
    print(f"graph runs (thread CPU, incl. the ring writes) per step: shift {GCPU['shift'] / rounds / 4 * 1e3:.1f} ms, ring {GCPU['ring'] / rounds / 4 * 1e3:.1f} ms")
    print(f"N={N} whole step (canonical chain from Python, thread CPU): shift {np.median(tb):.1f} ms, ring {np.median(tr):.1f} ms, ring/shift per-round median {np.median(r):.3f} [{min(r):.2f}-{max(r):.2f}]")
    if len(sys.argv) > 4:
        for name, ch in (("shift", base), ("ring", ring)):
            ms = {g: float(np.median(v[-rounds * 4:])) for g, v in ch.graph_ms.items()}
            print(name, "graphs sum %.1f ms:" % sum(ms.values()), {g: round(v, 2) for g, v in ms.items()})
