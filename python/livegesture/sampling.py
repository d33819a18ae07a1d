"""Classifier-free guidance on logits and the portable seeded sampler.

The sampler is specified so that Python and Rust (``runtime/src/sampling.rs``) draw the same token for the
same logits and seed, bit for bit:

PRNG: SplitMix64. State is one unsigned 64-bit integer, initialised to the seed. ``next_u64``::

    state = state + 0x9E3779B97F4A7C15            (mod 2^64)
    z = state
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9      (mod 2^64)
    z = (z ^ (z >> 27)) * 0x94D049BB133111EB      (mod 2^64)
    return z ^ (z >> 31)

``next_f64`` = ``(next_u64 >> 11) * 2^-53``, uniform in [0, 1).

Sampling one region's token from float32 conditional logits ``c`` and unconditional logits ``u``
(all arithmetic in IEEE float64, in this order):

1. ``g_i = u_i + gamma * (c_i - u_i)`` (with guidance disabled, ``g_i = c_i``);
2. ``g_i = g_i / temperature``;
3. order the indices by ``g`` descending, ties by index ascending; keep the first ``top_k``
   (all when top_k is 0 or >= K);
4. ``w_j = exp(g_j - g_first)`` for the kept indices in that order, ``S = sum`` accumulated in that order;
5. ``r = next_f64() * S``; walk the kept indices in order accumulating ``w``; the token is the first whose
   running sum exceeds ``r`` (the last kept index if rounding leaves none).

Each stream owns one generator. Per token step one uniform is drawn per region, in region order
(upper, hands, lower, face). ``exp`` is the C library's (Python ``math.exp``, Rust ``f64::exp``).
"""
from __future__ import annotations

import math

import numpy as np

MASK64 = (1 << 64) - 1
GOLDEN = 0x9E3779B97F4A7C15


class SplitMix64:
    def __init__(self, seed: int):
        self.state = int(seed) & MASK64

    def next_u64(self) -> int:
        self.state = (self.state + GOLDEN) & MASK64
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
        return z ^ (z >> 31)

    def next_f64(self) -> float:
        return (self.next_u64() >> 11) * (1.0 / 9007199254740992.0)


def guide(cond: np.ndarray, uncond: np.ndarray | None, gamma: float) -> np.ndarray:
    """Classifier-free guidance on logits: l_uncond + gamma * (l_cond - l_uncond), in float64."""
    c = np.asarray(cond, dtype=np.float32).astype(np.float64)
    if uncond is None:
        return c
    u = np.asarray(uncond, dtype=np.float32).astype(np.float64)
    return u + gamma * (c - u)


def sample_token(cond: np.ndarray, uncond: np.ndarray | None, rng: SplitMix64, gamma: float = 1.25,
                 temperature: float = 1.0, top_k: int = 0) -> int:
    """Draw one token from one region's logits (1-D arrays of length K). See the module docstring."""
    if temperature <= 0:
        raise ValueError(f"sampler: temperature must be > 0, got {temperature}")
    g = guide(cond, uncond, gamma) / temperature
    if not np.isfinite(g).all():
        raise ValueError("sampler: logits contain NaN or Inf")
    K = g.shape[-1]
    order = np.lexsort((np.arange(K), -g))  # g descending, index ascending
    if 0 < top_k < K:
        order = order[:top_k]
    g0 = float(g[order[0]])
    w = [math.exp(float(g[i]) - g0) for i in order]
    s = 0.0
    for x in w:
        s += x
    r = rng.next_f64() * s
    acc = 0.0
    for i, x in zip(order, w):
        acc += x
        if acc > r:
            return int(i)
    return int(order[-1])
