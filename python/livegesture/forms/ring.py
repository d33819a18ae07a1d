"""Ring caches with a cohort phase: the torch reference of a step-graph cache layout (issue 42 item 1).

Measured at graph level (BENCHMARKS.md, "Where a token's time goes, and ring caches with a cohort phase": at
N = 48 the eXperts and the fusion took 0.49-0.73x the time of the shift layout). This module fixes the layout's
numerics and its contract; the exporter writes the ring forms ``fused_ring`` and ``attention_ring``
(docs/bundle.md#ring-caches) with the graphs named ``<graph>_ring`` (:func:`ring_graph`), and the runtime writes
the entries in place.

**The shift layout** (every shipped graph, :meth:`livegesture.models.layers.WindowedAttention.step`): an
attention cache holds the previous W - 1 keys (or values), oldest first, on its slot axis (-2); each step
concatenates the new entry and slices the last W - 1 out as its new cache, so the graph copies every cache
twice per step, and the runtime hands the graph a buffer for each new cache.

**The ring layout** (here): the same caches, names and shapes, read in place.

- A **phase** ``c`` (an int64 scalar; one for every row of the batch: the runtime steps a cohort's streams
  together, so it is the cohort's count of steps, independent of each stream's own ``step``) places the
  entries: the attention of window W writes at slot ``p = c mod (W - 1)``, and slot ``j`` holds the entry
  ``((p - 1 - j) mod (W - 1)) + 1`` tokens old (slot ``p`` the oldest). The shift layout is the ring at
  phase 0.
- The step reads the caches and returns, in place of each new attention cache, the **new entry**
  ``(batch, *lead, heads, 1, head_dim)``; ``step`` is returned as before. The caller writes every entry into
  slot ``p`` (:func:`write_entries`) and runs the next step at phase ``c + 1``.
- Scores and weighted values cover the W - 1 cached slots and the new entry separately. The rotated
  queries are the constant ``qrot`` table's column blocks gathered by ``(j - p) mod (W - 1)`` (the same for
  every row, so still one MatMul by a table, not a per-row rotation), and the window mask is the shift
  layout's mask gathered the same way: cold start stays exact (the mask still comes from each row's ``step``).
- A stream that joins steps at another phase has its rows rotated to it (:func:`to_phase`).

The outputs equal the shift layout's up to float rounding (the softmax and value sums run in another
order): measured 2-3e-6 on outputs of magnitude 5.6-7.6 for ``models/default``, within docs/parity.md's 1e-5
(scaled), not bit-identical; ``python/tests/test_ring.py`` holds every component to it over chained steps.
"""
from __future__ import annotations

import copy
import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..models.layers import AttentionOp, WindowedAttention, check_cache, check_shape, window_bias
from .experts_fused import FusedExperts


RING_SUFFIX = "_ring"
# the ring form of each shift-layout form that carries attention caches in its own graphs
RING_FORMS = {"fused_ring": "fused", "attention_ring": "attention"}


def ring_graph(graph: str) -> str:
    """The name of the ring variant of a shift-layout graph (``fusion`` -> ``fusion_ring``)."""
    return graph + RING_SUFFIX


def ring_base(graph: str) -> str | None:
    """The shift-layout graph a ring graph is the variant of (``fusion_ring`` -> ``fusion``); None otherwise."""
    return graph[:-len(RING_SUFFIX)] if graph.endswith(RING_SUFFIX) else None


def is_ring_cache(name: str) -> bool:
    """Every cache of a ring graph but ``step`` is an attention cache written at the phase."""
    return name != "step"


def ring_order(window: int, phase: torch.Tensor) -> torch.Tensor:
    """(W - 1,) int64: ring slot ``j`` holds the entry of shift slot ``(j - p) mod (W - 1)``, p = phase mod (W - 1).
    Computed as ``(j + (W - 1) - p) mod (W - 1)`` so that no ``Mod`` of the graph sees a negative operand: tract 0.23
    takes an int64 ``Mod`` (fmod 0) with C's sign (of the dividend), where ONNX and torch take the divisor's, and a
    negative index gathers from the end of the table (the fusion's W-entry tables: the wrong entry)."""
    p = torch.remainder(phase, window - 1)
    return torch.remainder(torch.arange(window - 1, device=phase.device) + (window - 1) - p, window - 1)


def _qrot_blocks(qrot: torch.Tensor, hd: int, window: int, order: torch.Tensor):
    """The shift layout's (hd, W * hd) query-rotation table as (hd, (W - 1) * hd) for the ring's cached slots
    and (hd, hd) for the new entry (shift slot W - 1, no rotation)."""
    q3 = qrot.reshape(hd, window, hd)
    cached = torch.index_select(q3[:, :window - 1], 1, order).reshape(hd, (window - 1) * hd)
    return cached, q3[:, window - 1]


def ring_attend(q, qrot, kc, vc, k_new, v_new, bias, phase, window: int, hd: int):
    """One query per row: q (rows, h, hd); kc, vc (rows, h, W - 1, hd) in ring order; k_new, v_new (rows, h, hd);
    bias (rows, 1, W) the shift layout's mask -> the weighted values (rows, h, hd)."""
    order = ring_order(window, phase)
    qc, qn = _qrot_blocks(qrot, hd, window, order)
    h = q.shape[1]
    s_c = ((q @ qc).reshape((-1, h, window - 1, hd)) * kc).sum(-1) + torch.index_select(bias[..., :window - 1], 2, order)
    s_n = ((q @ qn) * k_new).sum(-1, keepdim=True)
    p = torch.softmax(torch.cat([s_c, s_n], -1), dim=-1)
    return (p[..., :window - 1, None] * vc).sum(-2) + p[..., window - 1:] * v_new


class RingWindowedAttention(WindowedAttention):
    """:class:`WindowedAttention` whose ``step``, ``_step_queries`` and ``step_op`` read ring caches at
    ``self.phase`` (set by :class:`RingStep` before each step) and return the new entries (module docs)."""

    phase: torch.Tensor

    def _new_entries(self, kv_in, new_cache, name, lead):
        h, hd, d = self.h, self.hd, self.d
        kv_new = self.kv(kv_in)
        k_new = kv_new[:, :d].reshape((-1,) + lead + (h, 1, hd))
        v_new = kv_new[:, d:].reshape((-1,) + lead + (h, 1, hd))
        new_cache[f"{name}.k"], new_cache[f"{name}.v"] = k_new, v_new
        return k_new, v_new

    def step(self, x, kv_in, bias, cache, new_cache, name, lead=()):
        W, h, hd, d = self.w, self.h, self.hd, self.d
        lead = tuple(lead)
        if x.dim() == 3:
            return self._step_queries(x, kv_in, bias, cache, new_cache, name, lead)
        k_new, v_new = self._new_entries(kv_in, new_cache, name, lead)
        kc = cache[f"{name}.k"].reshape((-1, h, W - 1, hd))
        vc = cache[f"{name}.v"].reshape((-1, h, W - 1, hd))
        q = self.q(x).reshape((-1, h, hd))
        y = ring_attend(q, self.qrot, kc, vc, k_new.reshape((-1, h, hd)), v_new.reshape((-1, h, hd)), bias,
                        self.phase, W, hd)
        return self.o(y.reshape((-1, d)))

    def _step_queries(self, x, kv_in, bias, cache, new_cache, name, lead):
        W, h, hd, d = self.w, self.h, self.hd, self.d
        nq = int(x.shape[1])
        k_new, v_new = self._new_entries(kv_in, new_cache, name, tuple(lead))
        order = ring_order(W, self.phase)
        qc, qn = _qrot_blocks(self.qrot, hd, W, order)
        kc = cache[f"{name}.k"].reshape((1, -1, h, W - 1, hd))
        vc = cache[f"{name}.v"].reshape((-1, h, W - 1, hd))
        q = self.q(x.transpose(0, 1)).reshape((nq, -1, h, hd))
        b = torch.index_select(bias[..., :W - 1], bias.dim() - 1, order)
        s_c = ((q @ qc).reshape((nq, -1, h, W - 1, hd)) * kc).sum(-1) + b.reshape((1, -1, 1, W - 1))
        s_n = ((q @ qn) * k_new.reshape((1, -1, h, hd))).sum(-1, keepdim=True)
        p = torch.softmax(torch.cat([s_c, s_n], -1), dim=-1).permute(1, 2, 0, 3)   # (rows, h, n_q, W)
        y = p[..., :W - 1] @ vc + p[..., W - 1:] * v_new.reshape((-1, h, 1, hd))
        return self.o(y.transpose(1, 2).reshape((-1, nq, d)))

    def step_op(self, x, kv_in, bias, cache, new_cache, name, lead=()):
        W, h, hd, d = self.w, self.h, self.hd, self.d
        k_new, v_new = self._new_entries(kv_in, new_cache, name, tuple(lead))
        order = torch.cat([ring_order(W, self.phase), torch.tensor([W - 1], device=bias.device)])
        k = torch.cat([cache[f"{name}.k"], k_new], -2).reshape((-1, h, W, hd))
        v = torch.cat([cache[f"{name}.v"], v_new], -2).reshape((-1, h, W, hd))
        if self.rope:
            k = (k * torch.index_select(self.key_cos, 0, order)
                 + torch.index_select(k, 3, self.key_swap) * torch.index_select(self.key_sin, 0, order))
        b = torch.index_select(bias, bias.dim() - 1, order)
        if x.dim() == 3:
            nq = int(x.shape[1])
            q = self.q(x).reshape((-1, nq, h, hd)).transpose(1, 2)
            mask = b.reshape((-1, 1, 1, W)) + torch.zeros((1, 1, nq, 1), device=b.device)
            y = AttentionOp.apply(q, k, v, mask, 1.0 / math.sqrt(hd))
            return self.o(y.transpose(1, 2).reshape((-1, nq, d)))
        q = self.q(x).reshape((-1, h, 1, hd))
        y = AttentionOp.apply(q, k, v, b.reshape((-1, 1, 1, W)), 1.0 / math.sqrt(hd))
        return self.o(y.reshape((-1, d)))


class RingFusedExperts(FusedExperts):
    """:class:`FusedExperts` on ring caches: ``step(prev_token, audio, cond, cache, phase)`` (module docs)."""

    def step(self, prev_token, audio, cond, cache, phase=None):
        R, d = self.R, self.d
        check_shape(self.name, "prev_token", prev_token, (None, R), torch.int64)
        B = prev_token.shape[0]
        check_shape(self.name, "audio", audio, (B, self.cfg.audio_dim), torch.float32)
        check_shape(self.name, "cond", cond, (B,), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, B)
        if phase is None:
            raise ValueError(f"{self.name}: the ring form needs the cohort's phase")
        new_cache: dict = {}
        step = cache["step"]
        e = F.embedding(prev_token + self.embed_offset, self.embed).reshape(-1, R * self.embed_dim)
        x = self._lin(self._split(F.gelu(self._lin(self._split(e, self.embed_dim), "mlp0")), d), "mlp2")
        c = cond.to(audio.dtype)[:, None, None]
        a = (c * audio[:, None, :] + (1 - c) * self.null_audio).reshape(-1, R * self.cfg.audio_dim)
        a_blocks = self._split(a, self.cfg.audio_dim)
        if self.additive:
            x = x + self._lin(a_blocks, "audio_add")
        bias = {w: window_bias(step, w) for w in {m["w"] for m in self.layer_meta}}
        for li, m in enumerate(self.layer_meta):
            p = f"l{li}_"
            W, h, hd, name = m["w"], m["h"], m["hd"], m["name"]
            hx = self._ln(x, p + "ln1", m["ln_eps"])
            kv = self._lin(a_blocks if m["cross"] else hx, p + "kv").reshape(-1, R, 2 * d)
            k_new = kv[..., :d].reshape(-1, R * h, 1, hd)
            v_new = kv[..., d:].reshape(-1, R * h, 1, hd)
            new_cache[f"{name}.k"], new_cache[f"{name}.v"] = k_new, v_new
            q = self._lin(hx, p + "q").reshape(-1, R * h, hd)
            y = ring_attend(q, getattr(self, p + "qrot"), cache[f"{name}.k"], cache[f"{name}.v"],
                            k_new[:, :, 0], v_new[:, :, 0], bias[W], phase, W, hd).reshape(-1, R * d)
            x = x + self._lin(self._split(y, d), p + "o")
            hf = self._ln(x, p + "ln2", m["ln_eps"])
            x = x + self._lin(self._split(F.gelu(self._lin(hf, p + "fc1")), self.cfg.ffn_mult * d), p + "fc2")
        new_cache["step"] = step + 1
        return {"hidden": torch.stack(self._ln(x, "norm", self.eps), 1)}, new_cache


class RingStep(nn.Module):
    """A component (a region eXpert, the fusion, :class:`FusedExperts`) stepping on ring caches:
    ``step(*inputs, cache=..., phase=...)`` returns (outputs, new entries and ``step``), the component's own
    weights (a deep copy whose windowed attentions are :class:`RingWindowedAttention`)."""

    def __init__(self, component: nn.Module):
        super().__init__()
        if isinstance(component, FusedExperts):
            ring = copy.deepcopy(component)
            ring.__class__ = RingFusedExperts
        else:
            ring = copy.deepcopy(component)
            for mod in ring.modules():
                if type(mod) is WindowedAttention:
                    mod.__class__ = RingWindowedAttention
        self.comp = ring.eval()

    def cache_specs(self):
        return self.comp.cache_specs()

    def init_cache(self, batch: int, device=None) -> dict:
        return self.comp.init_cache(batch, device)

    def step(self, *inputs, cache: dict, phase: torch.Tensor, **kw):
        phase = torch.as_tensor(phase, dtype=torch.int64)
        if isinstance(self.comp, RingFusedExperts):
            return self.comp.step(*inputs, cache, phase=phase)
        for mod in self.comp.modules():
            if isinstance(mod, RingWindowedAttention):
                mod.phase = phase
        return self.comp.step(*inputs, cache, **kw)


def write_entries(cache: dict, new: dict, phase: int) -> dict:
    """The caches after a ring step at ``phase``: each attention cache with its new entry written into slot
    ``phase mod (W - 1)`` (W - 1 the cache's slot axis, -2), ``step`` taken from ``new``; the runtime's in-place
    write. Returns a new dict (the inputs are not modified)."""
    out = {}
    for k, c in cache.items():
        e = new[k]
        if k == "step":
            out[k] = e
            continue
        if e.shape[-2] != 1 or e.shape[:-2] != c.shape[:-2] or e.shape[-1] != c.shape[-1]:
            raise ValueError(f"ring entry '{k}': shape {tuple(e.shape)} is not one slot of the cache "
                             f"{tuple(c.shape)}")
        c = c.clone()
        c[..., phase % c.shape[-2], :] = e[..., 0, :]
        out[k] = c
    return out


def to_phase(cache: dict, phase_from: int, phase_to: int) -> dict:
    """Caches laid out at ``phase_from`` rotated to ``phase_to`` (the shift layout is phase 0): what the runtime
    does to a stream's rows when they join a cohort at another phase."""
    return {k: c if k == "step" else torch.roll(c, (phase_to - phase_from) % c.shape[-2], dims=-2)
            for k, c in cache.items()}
