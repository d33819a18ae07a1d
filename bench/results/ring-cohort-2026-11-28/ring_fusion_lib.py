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

