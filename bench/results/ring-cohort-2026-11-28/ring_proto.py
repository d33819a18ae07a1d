"""Prototype (not product): experts_fused with cohort-phase ring caches. The caches are read-only graph
inputs in ring order (slot p = the oldest, shared by all rows: the cohort's phase); the graph outputs only the
new key/value entry per layer; scores over the W-1 cached slots use the shift layout's qrot blocks gathered
by (j - p) mod (W-1). Times it against the shipped-style export on ORT."""
import sys, time, json, warnings, numpy as np, torch, torch.nn.functional as F, onnxruntime as ort
sys.path.insert(0, "/work/wt/streams/export"); sys.path.insert(0, "/work/wt/streams/python")
from livegesture import checkpoint
from livegesture.forms.experts_fused import FusedExperts
from livegesture.models.layers import window_bias
from livegesture.regions import REGION_NAMES

model = checkpoint.load("/work/wt/streams/models/default.train/checkpoint.pt")
fe = FusedExperts([model.experts[r] for r in REGION_NAMES]).eval()

class Ring(torch.nn.Module):
    def __init__(self, fe):
        super().__init__(); self.fe = fe
    def forward(self, prev_token, audio, cond, phase, step, *caches):
        fe = self.fe; R, d = fe.R, fe.d
        e = F.embedding(prev_token + fe.embed_offset, fe.embed).reshape(-1, R * fe.embed_dim)
        x = fe._lin(fe._split(F.gelu(fe._lin(fe._split(e, fe.embed_dim), "mlp0")), d), "mlp2")
        c = cond.to(audio.dtype)[:, None, None]
        a = (c * audio[:, None, :] + (1 - c) * fe.null_audio).reshape(-1, R * fe.cfg.audio_dim)
        a_blocks = fe._split(a, fe.cfg.audio_dim)
        outs = []
        for li, m in enumerate(fe.layer_meta):
            p = f"l{li}_"; W, h, hd = m["w"], m["h"], m["hd"]
            jr = torch.remainder(torch.arange(W - 1) - phase, W - 1)       # ring slot j holds shift slot jr[j]
            bias = window_bias(step, W)                                       # (B,1,W) shift order
            bias_c = torch.index_select(bias[..., :W - 1], 2, jr)
            qrot = getattr(fe, p + "qrot").reshape(hd, W, hd)
            qrot_c = torch.index_select(qrot[:, :W - 1], 1, jr).reshape(hd, (W - 1) * hd)
            qrot_n = qrot[:, W - 1]
            hx = fe._ln(x, p + "ln1", m["ln_eps"])
            kv = fe._lin(a_blocks if m["cross"] else hx, p + "kv").reshape(-1, R, 2 * d)
            k_new = kv[..., :d].reshape(-1, R * h, 1, hd)
            v_new = kv[..., d:].reshape(-1, R * h, 1, hd)
            kc, vc = caches[2 * li], caches[2 * li + 1]
            q = fe._lin(hx, p + "q").reshape(-1, R * h, hd)
            qr = (q @ qrot_c).reshape(-1, R * h, W - 1, hd)
            s_c = (qr * kc).sum(-1) + bias_c
            s_n = ((q @ qrot_n)[:, :, None, :] * k_new).sum(-1)
            pr = torch.softmax(torch.cat([s_c, s_n], -1), dim=-1)
            y = (pr[..., :W - 1, None] * vc).sum(-2) + pr[..., W - 1:] * v_new[:, :, 0]
            y = y.reshape(-1, R * d)
            x = x + fe._lin(fe._split(y, d), p + "o")
            hf = fe._ln(x, p + "ln2", m["ln_eps"])
            x = x + fe._lin(fe._split(F.gelu(fe._lin(hf, p + "fc1")), fe.cfg.ffn_mult * d), p + "fc2")
            outs += [k_new, v_new]
        return (torch.stack(fe._ln(x, "norm", fe.eps), 1), step + 1, *outs)

ring = Ring(fe).eval()
B = 2
specs = [s for s in fe.cache_specs() if s.name != "step"]
caches = [torch.randn(B, *s.shape) for s in specs]
args = (torch.randint(0, 8, (B, 4)), torch.randn(B, 128), torch.ones(B), torch.tensor(3), torch.full((B,), 5), *caches)
names_in = ["prev_token", "audio", "cond", "phase", "step"] + [f"c{i}" for i in range(len(caches))]
names_out = ["hidden", "step_out"] + [f"n{i}" for i in range(len(caches))]
dyn = {n: {0: "batch"} for n in names_in + names_out if n != "phase"}
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    torch.onnx.export(ring, args, "/tmp/speed4/ring_experts.onnx", input_names=names_in, output_names=names_out,
                      dynamic_axes=dyn, opset_version=17, do_constant_folding=True, dynamo=False)
# correctness: ring step == shift step for a random history, phase p
with torch.no_grad():
    shift_caches = {s.name: torch.randn(B, *s.shape) for s in fe.cache_specs() if s.name != "step"}
    stepv = torch.tensor([40, 3]); prev = torch.randint(0, 8, (B, 4)); au = torch.randn(B, 128); cd = torch.tensor([1., 0.])
    ref, _ = fe.step(prev, au, cd, {"step": stepv, **shift_caches})
    for P in (0, 7, 30):
        ring_c = [torch.roll(shift_caches[s.name], P, dims=-2) for s in specs]  # shift slot js -> ring (js+P)%(W-1)
        got = ring(prev, au, cd, torch.tensor(P), stepv, *ring_c)[0]
        print("phase", P, "max|ring - shift| =", float((got - ref["hidden"]).abs().max()))
