"""Streaming building blocks shared by the components: causal convolutions with caches and
windowed causal attention with rotary positions relative to the window.

Cache conventions (the manifest describes them; Rust builds the initial state from it):

- every cache is a float32 (or int64 for the step counter) tensor with batch on axis 0;
- caches start as zeros; attention caches come with a step counter ``step`` (int64, shape (B,)) counting
  the steps already taken, from which the masks of not-yet-filled window slots are derived, so the cold
  start is exact without warm-up;
- a conv cache holds the last ``(kernel - 1) * dilation`` input frames; an attention cache holds the keys
  and values (keys before rotation) of the previous ``window - 1`` positions, oldest first.
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


def check_cache(component: str, specs: list[CacheSpec], cache: dict, batch: int):
    missing = [s.name for s in specs if s.name not in cache]
    if missing:
        raise ValueError(f"{component}: cache is missing {missing}")
    for s in specs:
        dt = torch.int64 if s.dtype == "int64" else torch.float32
        check_shape(component, f"cache.{s.name}", cache[s.name], (batch,) + tuple(s.shape), dt)


class CausalConv1d(nn.Module):
    """Conv1d with left-only padding. ``step`` keeps the last ``(k - 1) * d`` input frames as its cache."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int = 1):
        super().__init__()
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)
        self.pad = (kernel - 1) * dilation
        self.c_in = c_in

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # (B, C, T)
        return self.conv(F.pad(x, (self.pad, 0)))

    def cache_spec(self, name: str) -> list[CacheSpec]:
        return [CacheSpec(name, (self.c_in, self.pad))] if self.pad > 0 else []

    def step(self, x: torch.Tensor, cache: dict, new_cache: dict, name: str) -> torch.Tensor:
        if self.pad == 0:
            return self.conv(x)
        xx = torch.cat([cache[name], x], dim=2)
        new_cache[name] = xx[:, :, xx.shape[2] - self.pad:]
        return self.conv(xx)


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
        self.register_buffer("slot", torch.arange(window - 1, dtype=torch.int64), persistent=False)

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

    def cache_spec(self, name: str) -> list[CacheSpec]:
        return [CacheSpec(name, (self.w - 1, 2 * self.d))]

    def step(self, x: torch.Tensor, kv_in: torch.Tensor, step: torch.Tensor, cache: dict, new_cache: dict,
             name: str) -> torch.Tensor:
        """x (B, d_model), or (B, n_q, d_model) for several queries at the current time sharing the keys;
        kv_in (B, d_kv) the current key source; step (B,) int64 steps taken before this one."""
        B = x.shape[0]
        single = x.dim() == 2
        xq = x[:, None, :] if single else x
        kv_new = self.kv(kv_in)[:, None, :]                      # (B, 1, 2d)
        kv_all = torch.cat([cache[name], kv_new], dim=1)         # (B, W, 2d), oldest first
        new_cache[name] = kv_all[:, 1:, :]
        k, v = kv_all.chunk(2, dim=-1)
        q = self._heads(self.q(xq))                              # (B, h, n_q, hd)
        k, v = self._heads(k), self._heads(v)                    # (B, h, W, hd)
        if self.rope:
            q = apply_rope(q, self.win_cos[self.w - 1:], self.win_sin[self.w - 1:])
            k = apply_rope(k, self.win_cos, self.win_sin)
        scores = (q @ k.transpose(-1, -2)) / math.sqrt(self.hd)  # (B, h, n_q, W)
        # cache slot j holds time (t - (W-1) + j): valid iff j >= W - 1 - min(t, W - 1); the current key is always valid
        filled = torch.minimum(step, torch.full_like(step, self.w - 1))
        valid_old = self.slot[None, :] >= (self.w - 1 - filled)[:, None]              # (B, W-1)
        valid = torch.cat([valid_old, torch.ones_like(valid_old[:, :1])], dim=1)     # (B, W)
        scores = scores.masked_fill(~valid[:, None, None, :], float("-inf"))
        y = torch.softmax(scores, dim=-1) @ v                    # (B, h, n_q, hd)
        y = self.o(y.transpose(1, 2).reshape(B, xq.shape[1], self.d))
        return y[:, 0, :] if single else y


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

    def step(self, x, kv_src, step, cache, new_cache, name):
        h = self.ln1(x)
        x = x + self.attn.step(h, kv_src if self.is_cross else h, step, cache, new_cache, name)
        return x + self.ffn(self.ln2(x))
