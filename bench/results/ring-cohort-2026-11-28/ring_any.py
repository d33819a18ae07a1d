"""Prototype (not product): export graph G of models/default in the cohort-phase ring form (see ring_proto.py):
step / _step_queries / step_op of WindowedAttention patched. Usage: ring_any.py GRAPH OUT.onnx"""
import sys, math, warnings, torch
sys.path.insert(0, "/work/wt/streams/export"); sys.path.insert(0, "/work/wt/streams/python")
from livegesture import checkpoint
from livegesture.models import layers as L
from graphs import StepGraph, component, random_inputs
sys.path.insert(0, "/tmp/speed4")
import ring_fusion_lib as R   # ring_step, PH

def ring_step_op(self, x, kv_in, bias, cache, new_cache, name, lead=()):
    W, h, hd, d = self.w, self.h, self.hd, self.d
    lead = tuple(lead)
    kv_new = self.kv(kv_in)
    k_new = kv_new[:, :d].reshape((-1,) + lead + (h, 1, hd))
    v_new = kv_new[:, d:].reshape((-1,) + lead + (h, 1, hd))
    new_cache[f"{name}.k"], new_cache[f"{name}.v"] = k_new, v_new
    jr = torch.remainder(torch.arange(W - 1) - R.PH["p"], W - 1)
    idx = torch.cat([jr, torch.tensor([W - 1])])                      # ring slots then the new key
    k = torch.cat([cache[f"{name}.k"], k_new], -2).reshape((-1, h, W, hd))
    v = torch.cat([cache[f"{name}.v"], v_new], -2).reshape((-1, h, W, hd))
    if self.rope:
        kc, ks = torch.index_select(self.key_cos, 0, idx), torch.index_select(self.key_sin, 0, idx)
        k = k * kc + torch.index_select(k, 3, self.key_swap) * ks
    b = torch.index_select(bias, bias.dim() - 1, idx)
    if x.dim() == 3:
        nq = int(x.shape[1])
        q = self.q(x).reshape((-1, nq, h, hd)).transpose(1, 2)
        mask = b.reshape((-1, 1, 1, W)) + torch.zeros((1, 1, nq, 1))
        y = L.AttentionOp.apply(q, k, v, mask, 1.0 / math.sqrt(hd))
        return self.o(y.transpose(1, 2).reshape((-1, nq, d)))
    q = self.q(x).reshape((-1, h, 1, hd))
    y = L.AttentionOp.apply(q, k, v, b.reshape((-1, 1, 1, W)), 1.0 / math.sqrt(hd))
    return self.o(y.reshape((-1, d)))

graph, out = sys.argv[1], sys.argv[2]
model = checkpoint.load("/work/wt/streams/models/default.train/checkpoint.pt")
w = StepGraph(model, graph).eval()
specs = w.cache_specs
g = torch.Generator().manual_seed(0)
inp = random_inputs(model, graph, 2, g)
B = 2
cache = {s.name: (torch.full((B,), 40) if s.name == "step" else torch.randn(B, *s.shape)) for s in specs}
with torch.no_grad():
    ref = w(*[inp[i["name"]] for i in w.inputs], *[cache[s.name] for s in specs])
L.WindowedAttention.step = R.ring_step
L.WindowedAttention._step_queries = lambda self, x, kv_in, bias, cache, new_cache, name, lead: R.ring_step(self, x, kv_in, bias, cache, new_cache, name, lead)
L.WindowedAttention.step_op = ring_step_op
class RG(torch.nn.Module):
    def __init__(self):
        super().__init__(); self.w = w
    def forward(self, phase, *a):
        R.PH["p"] = phase
        return self.w(*a)
rg = RG().eval()
with torch.no_grad():
    for P in (0, 5, 30):
        rc = [cache[s.name] if s.name == "step" else torch.roll(cache[s.name], P, dims=-2) for s in specs]
        got = rg(torch.tensor(P), *[inp[i["name"]] for i in w.inputs], *rc)
        print(graph, "phase", P, "max|ring - shift| =", float((got[0] - ref[0]).abs().max()), "max|ref|", float(ref[0].abs().max()))
args = (torch.tensor(3),) + tuple(inp[i["name"]] for i in w.inputs) + tuple(cache[s.name] for s in specs)
names_in, names_out = ["phase"] + w.input_names(), w.output_names()
from graphs import to_attention_opset
import onnx
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    torch.onnx.export(rg, args, out, input_names=names_in, output_names=names_out,
                      dynamic_axes={n: {0: "batch"} for n in names_in[1:] + names_out}, opset_version=17,
                      do_constant_folding=True, dynamo=False, custom_opsets={L.ATTENTION_DOMAIN: 1})
m = onnx.load(out)
if any(n.domain == L.ATTENTION_DOMAIN for n in m.graph.node):
    to_attention_opset(m, graph); onnx.save(m, out)
print("exported", out)
