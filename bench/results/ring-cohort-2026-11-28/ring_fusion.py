"""Prototype (not product): the fusion graph with cohort-phase ring caches (see ring_proto.py)."""
import sys, warnings, torch
sys.path.insert(0, "/work/wt/streams/export"); sys.path.insert(0, "/work/wt/streams/python")
from livegesture import checkpoint
from livegesture.models import layers as L
from graphs import StepGraph, call_step, component, random_inputs

PH = {}
def ring_step(self, x, kv_in, bias, cache, new_cache, name, lead=()):
    W, h, hd, d = self.w, self.h, self.hd, self.d
    lead = tuple(lead)
    kv_new = self.kv(kv_in)
    k_new = kv_new[:, :d].reshape((-1,) + lead + (h, 1, hd))
    v_new = kv_new[:, d:].reshape((-1,) + lead + (h, 1, hd))
    new_cache[f"{name}.k"], new_cache[f"{name}.v"] = k_new, v_new
    kc, vc = cache[f"{name}.k"], cache[f"{name}.v"]
    jr = torch.remainder(torch.arange(W - 1) - PH["p"], W - 1)
    q3 = self.qrot.reshape(hd, W, hd)
    qc = torch.index_select(q3[:, :W - 1], 1, jr).reshape(hd, (W - 1) * hd)
    qn = q3[:, W - 1]
    bias_c = torch.index_select(bias[..., :W - 1], bias.dim() - 1, jr)
    if x.dim() == 3:
        nq = int(x.shape[1])
        k = kc.reshape((1, -1, h, W - 1, hd)); v = vc.reshape((-1, h, W - 1, hd))
        q = self.q(x.transpose(0, 1)).reshape((nq, -1, h, hd))
        s_c = ((q @ qc).reshape((nq, -1, h, W - 1, hd)) * k).sum(-1) + bias_c.reshape((1, -1, 1, W - 1))
        s_n = ((q @ qn) * k_new.reshape((1, -1, h, hd))).sum(-1, keepdim=True)
        p = torch.softmax(torch.cat([s_c, s_n], -1), dim=-1).permute(1, 2, 0, 3)   # (rows, h, nq, W)
        y = p[..., :W - 1] @ v + p[..., W - 1:] * v_new.reshape((-1, h, 1, hd))
        return self.o(y.transpose(1, 2).reshape((-1, nq, d)))
    k = kc.reshape((-1, h, W - 1, hd)); v = vc.reshape((-1, h, W - 1, hd))
    q = self.q(x).reshape((-1, h, hd))
    s_c = ((q @ qc).reshape((-1, h, W - 1, hd)) * k).sum(-1) + bias_c
    s_n = ((q @ qn) * k_new.reshape((-1, h, hd))).sum(-1, keepdim=True)
    p = torch.softmax(torch.cat([s_c, s_n], -1), dim=-1)
    y = (p[..., :W - 1, None] * v).sum(-2) + p[..., W - 1:] * v_new.reshape((-1, h, hd))
    return self.o(y.reshape((-1, d)))

model = checkpoint.load("/work/wt/streams/models/default.train/checkpoint.pt")
base_wrapper = StepGraph(model, "fusion").eval()
comp = component(model, "fusion")
specs = comp.cache_specs()

class RingGraph(torch.nn.Module):
    def __init__(self):
        super().__init__(); self.w = base_wrapper
    def forward(self, phase, *args):
        PH["p"] = phase
        return self.w(*args)

g = torch.Generator().manual_seed(0)
inp = random_inputs(model, "fusion", 2, g)
B = 2
cache = {s.name: (torch.full((B,), 40) if s.name == "step" else torch.randn(B, *s.shape)) for s in specs}
with torch.no_grad():
    ref = base_wrapper(*[inp[i["name"]] for i in base_wrapper.inputs], *[cache[s.name] for s in specs])
orig = L.WindowedAttention.step
L.WindowedAttention.step = ring_step
L.WindowedAttention._step_queries = lambda self, x, kv_in, bias, cache, new_cache, name, lead: ring_step(self, x, kv_in, bias, cache, new_cache, name, lead)
rg = RingGraph().eval()
with torch.no_grad():
    for P in (0, 5, 30):
        rc = [cache[s.name] if s.name == "step" else torch.roll(cache[s.name], P, dims=-2) for s in specs]
        got = rg(torch.tensor(P), *[inp[i["name"]] for i in base_wrapper.inputs], *rc)
        print("phase", P, "max|ring - shift| logits =", float((got[0] - ref[0]).abs().max()), "max|logits|", float(ref[0].abs().max()))
args = (torch.tensor(3),) + tuple(inp[i["name"]] for i in base_wrapper.inputs) + tuple(cache[s.name] for s in specs)
names_in = ["phase"] + base_wrapper.input_names()
names_out = base_wrapper.output_names()
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    torch.onnx.export(rg, args, "/tmp/speed4/ring_fusion.onnx", input_names=names_in, output_names=names_out,
                      dynamic_axes={n: {0: "batch"} for n in names_in[1:] + names_out}, opset_version=17,
                      do_constant_folding=True, dynamo=False)
print("exported")
