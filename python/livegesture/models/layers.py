"""Streaming building blocks shared by the components: causal convolutions with caches and
windowed causal attention with rotary positions relative to the window.

Cache conventions (the manifest describes them; Rust builds the initial state from it):

- every cache is a float32 (or int64 for the step counter) tensor with batch on axis 0;
- caches start as zeros; attention caches come with a step counter ``step`` (int64, shape (B,)) counting
  the steps already taken, from which the masks of not-yet-filled window slots are derived, so the cold
  start is exact without warm-up;
- a conv cache holds the last ``(kernel - 1) * dilation`` input frames, channels-last ``(frames, channels)``
  (step graphs run channels-last so that every convolution is one Gemm over all streams and frames);
- an attention layer has two caches, ``<layer>.k`` (keys before rotation) and ``<layer>.v`` (values), with
  the previous ``window - 1`` positions per head, ``(heads, window - 1, head_dim)``, oldest first.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F


@dataclass(frozen=True)
class CacheSpec:
    name: str
    shape: tuple[int, ...]   # without the batch axis
    dtype: str = "float32"   # "float32" or "int64"
    init: str = "zeros"

    def zeros(self, batch: int, device=None) -> torch.Tensor:
        dt = torch.int64 if self.dtype == "int64" else torch.float32
        return torch.zeros((batch,) + tuple(self.shape), dtype=dt, device=device)


def check_shape(component: str, name: str, x: torch.Tensor, expected: tuple, dtype: torch.dtype | None = None):
    """Raise a ValueError naming the component, the tensor and expected vs actual shape/dtype.

    ``None`` in ``expected`` matches any size (the batch axis)."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{component}: input '{name}' must be a torch.Tensor, got {type(x).__name__}")
    shape = tuple(x.shape)
    ok = len(shape) == len(expected) and all(e is None or e == s for e, s in zip(expected, shape))
    if not ok:
        exp = "(" + ", ".join("B" if e is None else str(e) for e in expected) + ")"
        raise ValueError(f"{component}: input '{name}' has shape {shape}, expected {exp}")
    if dtype is not None and x.dtype != dtype:
        raise ValueError(f"{component}: input '{name}' has dtype {x.dtype}, expected {dtype}")


def worst_difference(worst: tuple, pairs, step: int) -> tuple[float, str, int, float]:
    """``worst`` (max abs difference, output name, step, scale) updated with ``pairs`` of (name, a, b) tensors at
    ``step``, each compared by :func:`livegesture.compare.diff` (``b`` the reference): the largest error relative
    to its scale ``max(1, max|b|)`` (docs/parity.md), the first one met on ties; a NaN or Inf on either side is an
    infinite error. Start from ``(-1.0, name, 0, 1.0)``. Used by the checks of a form against the canonical graphs
    (``check_fused_experts``, ``check_fused_decoders``, ``check_fusion_attention``); the caller judges
    ``err <= bound * scale``."""
    from ..compare import diff
    if len(worst) == 3:
        worst = (*worst, 1.0)
    for name, a, b in pairs:
        d = diff(a, b)
        if d.problem() is not None:
            err, scale = float("inf"), 1.0
        else:
            err, scale = d.max_abs, d.scale
        if worst[0] < 0 or err / scale > worst[0] / worst[3]:
            worst = (err, name, step, scale)
    return worst


def check_cache(component: str, specs: list[CacheSpec], cache: dict, batch: int):
    missing = [s.name for s in specs if s.name not in cache]
    if missing:
        raise ValueError(f"{component}: cache is missing {missing}")
    for s in specs:
        dt = torch.int64 if s.dtype == "int64" else torch.float32
        check_shape(component, f"cache.{s.name}", cache[s.name], (batch,) + tuple(s.shape), dt)


class CausalConv1d(nn.Module):
    """Conv1d with left-only padding. ``step`` keeps the last ``(k - 1) * d`` input frames as its cache.

    The offline ``forward`` is channels-first (B, C, T) like ``nn.Conv1d``. ``step`` is channels-last
    (B, T, C) and computes the same convolution as one matrix product: the k taps of every output frame are
    gathered with a constant index (im2col), giving (B*T, k*C_in) rows for a single Gemm with the
    (k*C_in, C_out) weight. One Gemm over all streams and frames is what a batched step needs: runtimes
    run a batched Conv as one small matrix product per batch item."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int = 1):
        super().__init__()
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)
        self.pad = (kernel - 1) * dilation
        self.c_in = c_in

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, C, T)
        return self.conv(F.pad(x, (self.pad, 0)))

    def cache_spec(self, name: str) -> list[CacheSpec]:
        return [CacheSpec(name, (self.pad, self.c_in))] if self.pad > 0 else []

    def step(self, x: torch.Tensor, cache: dict, new_cache: dict, name: str) -> torch.Tensor:
        """x (B, T, C_in) channels-last, the next T frames -> (B, T, C_out)."""
        return conv_as_gemm(self.conv, x, cache, new_cache, name)


def gemm_weight(conv: nn.Conv1d) -> torch.Tensor:
    """A Conv1d weight (C_out, C_in, k) as the (C_out, k * C_in) matrix of a channels-last product:
    [o, i*C_in + c] = W[o, c, i] (a constant expression, folded into one initializer at export)."""
    return conv.weight.permute(0, 2, 1).reshape(conv.weight.shape[0], -1)


def conv_as_gemm(conv: nn.Conv1d, x: torch.Tensor, cache: dict | None = None, new_cache: dict | None = None,
                 name: str = "") -> torch.Tensor:
    """``conv`` (stride 1, no padding of its own) over x (B, T, C_in), channels-last, preceded by the
    ``(k - 1) * dilation`` frames cached under ``name`` (none for k = 1), as Gather (im2col with a constant
    index) + one Gemm: y[t] = sum_i W[:, :, i] xx[t + i*dilation]."""
    k, dil = conv.kernel_size[0], conv.dilation[0]
    pad = (k - 1) * dil
    T, c_in = int(x.shape[1]), int(x.shape[2])
    if pad > 0:
        xx = torch.cat([cache[name], x], dim=1)               # (B, pad + T, C_in)
        new_cache[name] = xx[:, -pad:, :]                     # constant bounds
    else:
        xx = x
    if k == 1:
        cols = xx.reshape(-1, c_in)
    else:
        idx = (torch.arange(T)[:, None] + dil * torch.arange(k)[None, :]).to(x.device)   # (T, k), constant
        cols = xx[:, idx].reshape(-1, k * c_in)               # (B*T, k*C_in)
    return F.linear(cols, gemm_weight(conv), conv.bias).reshape(-1, T, conv.weight.shape[0])


class PerRegionWeights(nn.Module):
    """Base of the fused region forms (``FusedExperts``, ``FusedDecoders``): each region keeps its canonical
    weights as ``<key>_w<r>`` / ``<key>_b<r>``, stored as frozen parameters (so the ONNX export writes them as
    initializers like the canonical graphs', where tools that edit or quantize weights find them); index
    tables are non-persistent buffers. ``R`` is the number of regions."""

    R: int

    def _frozen(self, name: str, t: torch.Tensor):
        if t.is_floating_point():
            self.register_parameter(name, nn.Parameter(t.detach().clone().contiguous(), requires_grad=False))
        else:
            self.register_buffer(name, t.contiguous(), persistent=False)

    def _per_region(self, key: str, pairs):
        """Registers region r's (weight, bias) of ``pairs`` (in region order) as ``<key>_w<r>``, ``<key>_b<r>``."""
        for r, (w, b) in enumerate(pairs):
            self._frozen(f"{key}_w{r}", w)
            self._frozen(f"{key}_b{r}", b)

    def _lin(self, blocks, key: str) -> torch.Tensor:
        """The R region blocks (rows, d_in) -> (rows, sum of d_out): block r through region r's weights ``key``,
        one Gemm each (the canonical Gemm), concatenated. A batched MatMul with (R, d_in, d_out) weights would be
        one node, but onnxruntime packs a batched constant weight again at every run (measured 3x slower than
        the canonical graphs), while a 2-D Gemm weight is packed once when the graph loads."""
        return torch.cat([F.linear(blocks[r], getattr(self, f"{key}_w{r}"), getattr(self, f"{key}_b{r}"))
                          for r in range(self.R)], 1)


def rope_tables(n_pos: int, head_dim: int, base: float = 10000.0, offset: int = 0):
    """cos/sin tables (n_pos, head_dim) for positions offset .. offset + n_pos - 1, computed in float64."""
    inv = base ** (-torch.arange(0, head_dim, 2, dtype=torch.float64) / head_dim)
    pos = torch.arange(offset, offset + n_pos, dtype=torch.float64)
    ang = pos[:, None] * inv[None, :]
    ang = torch.cat([ang, ang], dim=-1)
    return torch.cos(ang).float(), torch.sin(ang).float()


def apply_rope(x: torch.Tensor, cos: torch.Tensor, sin: torch.Tensor) -> torch.Tensor:
    """x (..., T, head_dim); rotate-half convention."""
    h = x.shape[-1] // 2
    rot = torch.cat([-x[..., h:], x[..., :h]], dim=-1)
    return x * cos + rot * sin


def step_query_rotations(window: int, head_dim: int, rope: bool = True) -> torch.Tensor:
    """(head_dim, window * head_dim) float32: column block j maps a query to R_m q / sqrt(head_dim) with
    m = window - 1 - j (identity / sqrt(head_dim) without RoPE). Built in float64 from the same angles as
    :func:`rope_tables`. R_m q = q * cos_m + rotate_half(q) * sin_m, and rotate_half(q) = q @ P."""
    h = head_dim // 2
    P = torch.zeros(head_dim, head_dim, dtype=torch.float64)
    P[torch.arange(h, head_dim), torch.arange(h)] = -1.0
    P[torch.arange(h), torch.arange(h, head_dim)] = 1.0
    inv = 10000.0 ** (-torch.arange(0, head_dim, 2, dtype=torch.float64) / head_dim)
    blocks = []
    for j in range(window):
        m = window - 1 - j
        if rope:
            ang = torch.cat([m * inv, m * inv])
            blocks.append(torch.diag(torch.cos(ang)) + P * torch.sin(ang)[None, :])
        else:
            blocks.append(torch.eye(head_dim, dtype=torch.float64))
    return (torch.cat(blocks, dim=1) / math.sqrt(head_dim)).float()


ATTENTION_DOMAIN = "livegesture.attention"


class AttentionOp(torch.autograd.Function):
    """softmax(q k^T * scale + mask) v over 4-D (rows, heads, seq, head_dim) tensors: the ONNX ``Attention`` op
    (opset 23) with 4-D inputs, an additive float mask (or none) and ``scale``.

    The torch forward is the op's definition; the ONNX export writes one node ``Attention`` in the domain
    :data:`ATTENTION_DOMAIN` (the TorchScript exporter writes opset 17, which has no ``Attention``), and
    ``export/graphs.py:to_attention_opset`` moves it to the default domain at opset 23 (the graph's other ops
    have the same definition at 17 and 23; the exporter checks that). onnxruntime 1.31 wants the mask's query
    axis at full size (no broadcast there), so callers pass masks of shape (rows, 1, n_q, W)."""

    @staticmethod
    def forward(ctx, q, k, v, mask, scale: float):  # noqa: ARG004 - torch.autograd.Function signature
        s = (q @ k.transpose(-1, -2)) * scale
        if mask is not None:
            s = s + mask
        return torch.softmax(s, dim=-1) @ v

    @staticmethod
    def symbolic(g, q, k, v, mask, scale: float):
        ins = [q, k, v] if mask is None or _is_none(mask) else [q, k, v, mask]
        y = g.op(f"{ATTENTION_DOMAIN}::Attention", *ins, scale_f=float(scale))
        y.setType(q.type())   # (rows, heads, n_q, head_dim): the query's shape (values have head_dim too)
        return y


def _is_none(v) -> bool:
    """A TorchScript export value standing for ``None``."""
    try:
        return v.node().mustBeNone()
    except AttributeError:
        return False


def key_rotations(window: int, head_dim: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(cos, sin, swap) rotating the key in window slot j back by m = window - 1 - j positions, elementwise:
    R_-m k = k * cos + k[..., swap] * sin, cos and sin (window, head_dim) float32 (built from
    :func:`rope_tables`), swap the int64 half-swap index. <q, R_-m k> = <R_m q, k>, the score of the query at
    slot window - 1 (:meth:`WindowedAttention.step`)."""
    cos, sin = (t.flip(0) for t in rope_tables(window, head_dim))   # row j: m = window - 1 - j
    h = head_dim // 2
    sign = torch.cat([-torch.ones(h), torch.ones(h)])                # rotate_half(k) = k[..., swap] * sign
    swap = torch.cat([torch.arange(h, head_dim), torch.arange(h)])
    return cos.contiguous(), (-(sin * sign)).contiguous(), swap


def window_bias(step: torch.Tensor, window: int) -> torch.Tensor:
    """Additive attention mask (B, 1, window) for a step with ``step`` (B,) steps taken before it (heads
    broadcast on axis 1; insert a query axis, ``[:, None]``, for :meth:`WindowedAttention.step` with several
    queries).

    Cache slot j (oldest first; the current key is slot window - 1) holds time t - (window - 1) + j, which
    exists iff j + t >= window - 1. Valid slots get 0, not-yet-filled ones -inf (``x + -inf == -inf`` and
    ``x + 0 == x`` exactly, so this equals masking). Computed once per graph and shared by every attention
    layer with that window."""
    slot = torch.arange(window, dtype=torch.int64, device=step.device)
    valid = (slot[None, :] + step[:, None]) >= window - 1
    zero = torch.zeros((), dtype=torch.float32, device=step.device)
    return torch.where(valid, zero, torch.full_like(zero, float("-inf")))[:, None, :]


class WindowedAttention(nn.Module):
    """Multi-head attention where the query at time t sees keys at times (t - window, t].

    Self-attention (``d_kv == d_model``, keys from the same stream) or cross-attention (keys from another
    stream aligned on the same token grid, e.g. audio tokens). Rotary positions: offline, positions are the
    absolute token index; in ``step`` they are the slot index inside the window (the query sits at
    ``window - 1``), so attention depends only on the time difference and positions stay bounded on
    arbitrarily long streams.
    """

    def __init__(self, d_model: int, n_heads: int, window: int, d_kv: int | None = None, rope: bool = True):
        super().__init__()
        d_kv = d_kv or d_model
        self.d, self.h, self.w = d_model, n_heads, window
        self.hd = d_model // n_heads
        self.q = nn.Linear(d_model, d_model)
        self.kv = nn.Linear(d_kv, 2 * d_model)
        self.o = nn.Linear(d_model, d_model)
        self.rope = rope
        cos, sin = rope_tables(window, self.hd)
        self.register_buffer("win_cos", cos, persistent=False)
        self.register_buffer("win_sin", sin, persistent=False)
        self.register_buffer("qrot", step_query_rotations(window, self.hd, rope), persistent=False)
        kcos, ksin, swap = key_rotations(window, self.hd)
        self.register_buffer("key_cos", kcos, persistent=False)
        self.register_buffer("key_sin", ksin, persistent=False)
        self.register_buffer("key_swap", swap, persistent=False)

    def _heads(self, x):  # (B, T, d) -> (B, h, T, hd)
        return x.reshape(x.shape[0], x.shape[1], self.h, self.hd).transpose(1, 2)

    def forward(self, x: torch.Tensor, kv_in: torch.Tensor) -> torch.Tensor:
        """x (B, T, d_model), kv_in (B, T, d_kv) -> (B, T, d_model)."""
        T = x.shape[1]
        q = self._heads(self.q(x))
        k, v = self.kv(kv_in).chunk(2, dim=-1)
        k, v = self._heads(k), self._heads(v)
        if self.rope:
            cos, sin = rope_tables(T, self.hd)
            cos, sin = cos.to(x.device), sin.to(x.device)
            q, k = apply_rope(q, cos, sin), apply_rope(k, cos, sin)
        t = torch.arange(T, device=x.device)
        allowed = (t[None, :] <= t[:, None]) & (t[None, :] > t[:, None] - self.w)
        scores = (q @ k.transpose(-1, -2)) / math.sqrt(self.hd)
        scores = scores.masked_fill(~allowed, float("-inf"))
        y = torch.softmax(scores, dim=-1) @ v
        return self.o(y.transpose(1, 2).reshape(x.shape[0], T, self.d))

    def cache_spec(self, name: str, lead: tuple[int, ...] = ()) -> list[CacheSpec]:
        """Keys (before rotation) ``<name>.k`` and values ``<name>.v`` of the previous window - 1 positions,
        per head, oldest first: (*lead, h, W - 1, hd) each (``lead``: extra row axes per stream, e.g. the
        fusion's regions)."""
        shape = tuple(lead) + (self.h, self.w - 1, self.hd)
        return [CacheSpec(f"{name}.k", shape), CacheSpec(f"{name}.v", shape)]

    def step(self, x: torch.Tensor, kv_in: torch.Tensor, bias: torch.Tensor, cache: dict, new_cache: dict,
             name: str, lead: tuple[int, ...] = ()) -> torch.Tensor:
        """x (rows, d_model), or (rows, n_q, d_model) for several queries at the current time sharing the keys
        (:meth:`_step_queries`); kv_in (rows, d_kv) the current key source; bias from :func:`window_bias`,
        (rows, 1, window) for one query per row, (rows, 1, 1, window) for n_q queries.
        rows = B * prod(lead): the caches (:meth:`cache_spec`) have the ``lead`` axes after the batch.

        Keys and values are separate head-major caches, so the new key and value are appended with one
        Concat each and the caches need no Split or Transpose; the updated caches are Slices of those
        Concats in the caches' own layout (graph outputs without a copy). The query sits at window slot
        W - 1 and the key in slot j at W - 1 - m (m = W - 1 - j tokens earlier), so with rotary positions
        its score is <R_m q, k_j> / sqrt(hd) (R_m the RoPE rotation by m positions, the same dot product as
        <R_{W-1} q, R_j k_j> in exact arithmetic). The step computes all W rotated, scaled queries with one
        MatMul by the constant ``qrot`` (hd, W * hd), and the scores and the weighted values as Mul +
        ReduceSum of tensors of the keys' shape: no per-head batched MatMul (runtimes run those as one
        tiny product per stream and head), no RoPE on the cached keys, and only constant-size reshapes
        (-1 on the batch axis)."""
        W, h, hd, d = self.w, self.h, self.hd, self.d
        lead = tuple(lead)
        if x.dim() == 3:
            return self._step_queries(x, kv_in, bias, cache, new_cache, name, lead)
        # one query per row has no query axis at all, so the caches are used as they are and the output
        # projection is a 2-D Gemm (fewer nodes: a single stream's step is bound by per-node dispatch)
        k_all, v_all = self._append_kv(kv_in, cache, new_cache, name, lead)
        k = k_all.reshape((-1, h, W, hd))                         # (rows, h, W, hd)
        v = v_all.reshape((-1, h, W, hd))
        q = self.q(x).reshape((-1, h, hd))                        # (rows, h, hd)
        qr = (q @ self.qrot).reshape((-1, h, W, hd))              # (rows, h, W, hd): R_{W-1-j} q / sqrt(hd)
        scores = (qr * k).sum(-1) + bias                          # (rows, h, W)
        p = torch.softmax(scores, dim=-1)
        y = (p[..., None] * v).sum(-2).reshape((-1, d))           # (rows, d)
        return self.o(y)

    def _append_kv(self, kv_in, cache, new_cache, name, lead):
        """The new token's key and value appended to the caches ``{name}.k`` / ``{name}.v`` (B, *lead, h, W-1, hd):
        returns the W keys and values (B, *lead, h, W, hd), oldest first, and writes the last W - 1 of them to
        ``new_cache``."""
        h, hd, d = self.h, self.hd, self.d
        kv_new = self.kv(kv_in)                                   # (rows, 2d): [k | v]
        k_new = kv_new[:, :d].reshape((-1,) + lead + (h, 1, hd))
        v_new = kv_new[:, d:].reshape((-1,) + lead + (h, 1, hd))
        k_all = torch.cat([cache[f"{name}.k"], k_new], dim=-2)    # (B, *lead, h, W, hd), oldest first
        v_all = torch.cat([cache[f"{name}.v"], v_new], dim=-2)
        new_cache[f"{name}.k"] = k_all[..., 1:, :]
        new_cache[f"{name}.v"] = v_all[..., 1:, :]
        return k_all, v_all

    def _step_queries(self, x, kv_in, bias, cache, new_cache, name, lead):
        """:meth:`step` with n_q queries per row sharing the keys (the fusion's audio cross-attention), laid
        out query-major: the rotated queries are (n_q, rows, h, W, hd) and the keys (1, rows, h, W, hd), so
        the score product broadcasts the keys over the LEADING axis only (tract runs that as one unicast
        kernel; a broadcast over an inner axis takes its generic, index-per-element path, about 17x slower).
        The weighted values are one batched MatMul (rows, h, n_q, W) @ (rows, h, W, hd) (a broadcast Mul of
        p over the values' hd axis and v over the query axis has no fast path in tract either). Same math as
        the rows-major form of the one-query path (float rounding of the value sum aside); measured in
        BENCHMARKS.md, "tract and the fusion graph"."""
        W, h, hd, d = self.w, self.h, self.hd, self.d
        nq = int(x.shape[1])
        k_all, v_all = self._append_kv(kv_in, cache, new_cache, name, lead)
        k = k_all.reshape((1, -1, h, W, hd))                      # (1, rows, h, W, hd)
        v = v_all.reshape((-1, h, W, hd))                         # (rows, h, W, hd)
        q = self.q(x.transpose(0, 1)).reshape((nq, -1, h, hd))    # (n_q, rows, h, hd)
        qr = (q @ self.qrot).reshape((nq, -1, h, W, hd))          # R_{W-1-j} q / sqrt(hd)
        scores = (qr * k).sum(-1) + bias.reshape((1, -1, 1, W))   # (n_q, rows, h, W)
        p = torch.softmax(scores, dim=-1).permute(1, 2, 0, 3)     # (rows, h, n_q, W)
        y = (p @ v).transpose(1, 2).reshape((-1, nq, d))          # (rows, n_q, d)
        return self.o(y)

    def step_op(self, x: torch.Tensor, kv_in: torch.Tensor, bias: torch.Tensor, cache: dict, new_cache: dict,
                name: str, lead: tuple[int, ...] = ()) -> torch.Tensor:
        """:meth:`step` (same inputs, caches and result) with the attention core as one :class:`AttentionOp`
        (the ONNX ``Attention`` op): the W keys are rotated back elementwise by their distance to the query
        (:func:`key_rotations`; the caches keep the keys before rotation, as in :meth:`step`), the query is not
        rotated, scale 1/sqrt(hd). The form of the fusion graph ``fusion_attention`` (docs/bundle.md#forms-and-precision form
        ``attention``): tract runs the op as one fused kernel, 2.7-4.7x faster than :meth:`_step_queries` for the
        fusion's cross-attention; onnxruntime runs it slower than :meth:`step` (BENCHMARKS.md, "A tract form
        of the fusion")."""
        W, h, hd, d = self.w, self.h, self.hd, self.d
        k_all, v_all = self._append_kv(kv_in, cache, new_cache, name, tuple(lead))
        k = k_all.reshape((-1, h, W, hd))                         # (rows, h, W, hd)
        v = v_all.reshape((-1, h, W, hd))
        if self.rope:
            k = k * self.key_cos + torch.index_select(k, 3, self.key_swap) * self.key_sin
        if x.dim() == 3:                                          # n_q queries per row sharing the keys
            nq = int(x.shape[1])
            q = self.q(x).reshape((-1, nq, h, hd)).transpose(1, 2)                        # (rows, h, n_q, hd)
            mask = bias.reshape((-1, 1, 1, W)) + torch.zeros((1, 1, nq, 1), device=bias.device)
            y = AttentionOp.apply(q, k, v, mask, 1.0 / math.sqrt(hd))
            return self.o(y.transpose(1, 2).reshape((-1, nq, d)))
        q = self.q(x).reshape((-1, h, 1, hd))                     # (rows, h, 1, hd)
        y = AttentionOp.apply(q, k, v, bias.reshape((-1, 1, 1, W)), 1.0 / math.sqrt(hd))
        return self.o(y.reshape((-1, d)))


class FeedForward(nn.Module):
    def __init__(self, d: int, mult: int):
        super().__init__()
        self.fc1 = nn.Linear(d, d * mult)
        self.fc2 = nn.Linear(d * mult, d)

    def forward(self, x):
        return self.fc2(F.gelu(self.fc1(x)))


class AttnLayer(nn.Module):
    """Pre-LN residual layer: x + Attn(LN(x)), then x + FFN(LN(x))."""

    def __init__(self, d: int, n_heads: int, window: int, ffn_mult: int, d_kv: int | None = None):
        super().__init__()
        self.ln1 = nn.LayerNorm(d)
        self.attn = WindowedAttention(d, n_heads, window, d_kv)
        self.ln2 = nn.LayerNorm(d)
        self.ffn = FeedForward(d, ffn_mult)
        self.is_cross = d_kv is not None

    def forward(self, x, kv_src):
        h = self.ln1(x)
        x = x + self.attn(h, kv_src if self.is_cross else h)
        return x + self.ffn(self.ln2(x))

    def step(self, x, kv_src, bias, cache, new_cache, name):
        h = self.ln1(x)
        x = x + self.attn.step(h, kv_src if self.is_cross else h, bias, cache, new_cache, name)
        return x + self.ffn(self.ln2(x))
