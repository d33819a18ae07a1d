#!/usr/bin/env python
# usage: PYTHONPATH=python taskset -c 1 python bench/results/fuseddec-2026-11-25/probe_decoder_layouts.py CHECKPOINT BUNDLE
# (run from the repository root; CHECKPOINT models/default.train/checkpoint.pt, BUNDLE an export of it with decoders_fused).
# onnxruntime from Python does not flush subnormals (the Rust runtime does): its absolute times are higher.
"""Probe: decoders as four independent chains in one graph (caches side by side, split at the input, joined at
the output) vs the canonical graphs vs decoders_fused (shared activations). ort, 1 thread, interleaved."""
import sys, tempfile, time, warnings, numpy as np, torch, torch.nn as nn
TMP = tempfile.mkdtemp()
sys.path.insert(0, "export")
torch.set_num_threads(1)
from livegesture import checkpoint as ckpt
from livegesture.regions import REGION_NAMES
from livegesture.models.fused_decoders import FusedDecoders
import onnxruntime as ort
m = ckpt.load(sys.argv[1])
svqs = [m.svq[r] for r in REGION_NAMES]
fd = FusedDecoders(svqs).eval()
specs = fd.cache_specs()
class Indep(nn.Module):
    def __init__(self):
        super().__init__(); self.svqs = nn.ModuleList(svqs)
    def forward(self, token, *caches):
        R = len(self.svqs)
        per = [dict() for _ in range(R)]
        for s, c in zip(specs, caches):
            for r, part in enumerate(torch.split(c, c.shape[-1] // R, dim=-1)):
                per[r][s.name] = part
        outs, news = [], [dict() for _ in range(R)]
        for r, svq in enumerate(self.svqs):
            o, news[r] = svq.step(token[:, r], per[r]); outs.append(o["motion"])
        return (torch.cat(outs, -1),) + tuple(torch.cat([news[r][s.name] for r in range(R)], -1) for s in specs)
class Fused(nn.Module):
    def __init__(self):
        super().__init__(); self.fd = fd
    def forward(self, token, *caches):
        o, new = self.fd.step(token, {s.name: c for s, c in zip(specs, caches)})
        return (o["motion"],) + tuple(new[s.name] for s in specs)
names_in = ["token"] + [f"cache.{s.name}" for s in specs]; names_out = ["motion"] + [f"new_cache.{s.name}" for s in specs]
args = (torch.randint(0, 200, (2, 4)),) + tuple(s.zeros(2) for s in specs)
so = ort.SessionOptions(); so.intra_op_num_threads = 1; so.inter_op_num_threads = 1
sess = {}
for n, mod in (("indep", Indep()), ("fused", Fused())):
    p = f"{TMP}/{n}.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(mod.eval(), args, p, input_names=names_in, output_names=names_out,
                          dynamic_axes={k: {0: "batch"} for k in names_in + names_out}, opset_version=17, dynamo=False)
    sess[n] = ort.InferenceSession(p, so, providers=["CPUExecutionProvider"])
import onnx, collections
for n in sess:
    g = onnx.load(f"{TMP}/{n}.onnx").graph
    print(n, sum(1 for x in g.node if x.op_type != "Constant"), "nodes")
canon = {r: ort.InferenceSession(f"{sys.argv[2]}/decoder_{r}.onnx", so, providers=["CPUExecutionProvider"]) for r in REGION_NAMES}
cspecs = m.svq["upper"].cache_specs()
rng = np.random.RandomState(0)
for B in (1, 32):
    st = {"canonical": {r: {f"cache.{s.name}": s.zeros(B).numpy() for s in cspecs} for r in REGION_NAMES},
          "indep": {f"cache.{s.name}": s.zeros(B).numpy() for s in specs}, "fused": {f"cache.{s.name}": s.zeros(B).numpy() for s in specs}}
    for rnd in range(3):
        ts = {k: [] for k in st}
        for t in range(150 if B == 1 else 40):
            tok = rng.randint(0, 256, (B, 4)).astype(np.int64)
            order = list(st) if t % 2 == 0 else list(st)[::-1]
            for k in order:
                t0 = time.perf_counter()
                if k == "canonical":
                    for i, r in enumerate(REGION_NAMES):
                        out = canon[r].run(None, {"token": np.ascontiguousarray(tok[:, i]), **st[k][r]})
                        st[k][r] = {f"cache.{s.name}": o for s, o in zip(cspecs, out[1:])}
                else:
                    out = sess[k].run(None, {"token": tok, **st[k]})
                    st[k] = {f"cache.{s.name}": o for s, o in zip(specs, out[1:])}
                if t >= 5: ts[k].append(time.perf_counter() - t0)
        print(f"B={B} round {rnd}: " + ", ".join(f"{k} {np.median(v)*1e3:.3f} ms" for k, v in ts.items()), flush=True)
