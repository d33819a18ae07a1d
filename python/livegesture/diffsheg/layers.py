"""Building blocks of DiffSHEG (paper section 3.3), written out so the equations are visible.

- ``sinusoidal(pos, dim)``: the fixed sin/cos table (positions along the window; diffusion steps);
- ``LinearSelfAttention``: efficient attention of Shen et al. [36]: per head,
  ``out = softmax_feat(Q) (softmax_time(K)^T V)``; cost linear in the window length, no mask, so a shorter
  window (the last one) is the same function with the remaining positional rows dropped (section 3.5);
- ``AdaIN`` (the paper's "AdaIN stylization block"): ``h' = LN(h) * (1 + scale(g)) + shift(g)``, then SiLU,
  dropout and a zero-initialised projection, added residually; ``g`` = MLP(style) + MLP(step);
- ``StyleTransformerBlock``: linear self-attention -> AdaIN, feed-forward -> AdaIN (two AdaIN blocks per
  Transformer block, section 3.3);
- ``FusionResidualBlock``: ``x + MLP(LN(concat(x, conditions)))`` -- motion-speech fusion that predicts a
  residual of the motion features (section 3.3, appendix C).
"""
from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F


def sinusoidal(pos: torch.Tensor, dim: int, base: float = 10000.0) -> torch.Tensor:
    """pos (...,) float -> (..., dim): [cos(pos * f_i), sin(pos * f_i)], f_i = base^(-i / (dim/2))."""
    half = dim // 2
    freqs = torch.exp(-math.log(base) * torch.arange(half, dtype=torch.float32, device=pos.device) / half)
    ang = pos.float()[..., None] * freqs
    return torch.cat([torch.cos(ang), torch.sin(ang)], dim=-1)


def position_table(n: int, dim: int) -> torch.Tensor:
    return sinusoidal(torch.arange(n, dtype=torch.float32), dim)


class AdaIN(nn.Module):
    """h -> Linear(dropout(SiLU(LN(h) * (1 + scale) + shift))), (scale, shift) = Linear(SiLU(g))."""

    def __init__(self, d: int, d_cond: int, dropout: float):
        super().__init__()
        self.emb = nn.Linear(d_cond, 2 * d)
        self.norm = nn.LayerNorm(d)
        self.drop = nn.Dropout(dropout)
        self.out = nn.Linear(d, d)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, h: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        scale, shift = self.emb(F.silu(g)).unsqueeze(1).chunk(2, dim=-1)
        h = self.norm(h) * (1 + scale) + shift
        return self.out(self.drop(F.silu(h)))


class LinearSelfAttention(nn.Module):
    """x (B, n, d) -> (B, n, d). Per head: q = softmax over the head's features, k = softmax over time,
    context = k^T v (hd x hd), out = q context."""

    def __init__(self, d: int, n_heads: int):
        super().__init__()
        self.h, self.hd = n_heads, d // n_heads
        self.norm = nn.LayerNorm(d)
        self.q, self.k, self.v = nn.Linear(d, d), nn.Linear(d, d), nn.Linear(d, d)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, n, d = x.shape[0], x.shape[1], x.shape[2]
        y = self.norm(x)
        split = lambda z: z.reshape(B, n, self.h, self.hd).transpose(1, 2)   # (B, h, n, hd)  # noqa: E731
        q = torch.softmax(split(self.q(y)), dim=-1)
        k = torch.softmax(split(self.k(y)), dim=2)
        v = split(self.v(y))
        ctx = torch.matmul(k.transpose(2, 3), v)                              # (B, h, hd, hd)
        return torch.matmul(q, ctx).transpose(1, 2).reshape(B, n, d)


class StyleTransformerBlock(nn.Module):
    """Style-aware Transformer block: x += AdaIN(LinAttn(x), g); x += AdaIN(FFN(LN(x)), g)."""

    def __init__(self, d: int, n_heads: int, ff: int, dropout: float, d_cond: int | None = None):
        super().__init__()
        d_cond = d_cond or d
        self.attn = LinearSelfAttention(d, n_heads)
        self.ada1 = AdaIN(d, d_cond, dropout)
        self.ff_norm = nn.LayerNorm(d)
        self.ff1, self.ff2 = nn.Linear(d, ff), nn.Linear(ff, d)
        self.drop = nn.Dropout(dropout)
        self.ada2 = AdaIN(d, d_cond, dropout)

    def forward(self, x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        x = x + self.ada1(self.attn(x), g)
        return x + self.ada2(self.ff2(self.drop(F.gelu(self.ff1(self.ff_norm(x))))), g)


class PlainTransformerBlock(nn.Module):
    """The mid-level speech encoder's block (no style): x += LinAttn(x); x += FFN(LN(x))."""

    def __init__(self, d: int, n_heads: int, ff: int, dropout: float):
        super().__init__()
        self.attn = LinearSelfAttention(d, n_heads)
        self.ff_norm = nn.LayerNorm(d)
        self.ff1, self.ff2 = nn.Linear(d, ff), nn.Linear(ff, d)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.drop(self.attn(x))
        return x + self.ff2(self.drop(F.gelu(self.ff1(self.ff_norm(x)))))


class FusionResidualBlock(nn.Module):
    """Motion-speech fusion: x (B, n, d_x), cond (B, n, d_c) -> x + MLP(LN(concat(x, cond))) (B, n, d_x)."""

    def __init__(self, d_x: int, d_c: int, hidden: int):
        super().__init__()
        self.norm = nn.LayerNorm(d_x + d_c)
        self.fc1, self.fc2 = nn.Linear(d_x + d_c, hidden), nn.Linear(hidden, d_x)

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        return x + self.fc2(F.gelu(self.fc1(self.norm(torch.cat([x, cond], dim=-1)))))
