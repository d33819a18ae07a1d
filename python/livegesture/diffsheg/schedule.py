"""The diffusion schedule and DDIM timestep selection (paper section 3.2; DDIM as in section 3.5).

Definitions (IEEE float64; the manifest's ``diffusion`` section stores the resulting table, also as exact
bit patterns, so the runtime need not recompute it):

- ``T = 1000`` training steps, linear betas: ``beta_i = float64(i) * step + beta_start`` for i < T-1 and
  ``beta_{T-1} = beta_end``, with ``step = (beta_end - beta_start) / (T - 1)`` (numpy.linspace's arithmetic),
  ``beta_start = 1e-4``, ``beta_end = 0.02`` (Ho et al.'s linear schedule, used by the authors' code);
- ``alpha_i = 1.0 - beta_i``; ``alpha_bar_0 = alpha_0``, ``alpha_bar_i = alpha_bar_{i-1} * alpha_i``
  (a sequential cumulative product, i ascending);
- DDIM with S steps (default 25) uses the timesteps ``tau_j = j * (T // S)`` for j = 0 .. S-1 (S = 25:
  0, 40, ..., 960; the "ddimS" respacing of the authors' code base), visited from j = S-1 down to 0.
  Step j goes from ``tau_j`` to ``tau_{j-1}``; its "previous" cumulative alpha is ``alpha_bar[tau_{j-1}]``,
  and 1.0 for j = 0 (the clean sample). ``T // S`` must make ``(S-1) * (T // S) < T``; S must divide T
  for the paper's spacing (1 <= S <= T).
"""
from __future__ import annotations

import numpy as np

T_TRAIN = 1000
BETA_START = 1e-4
BETA_END = 0.02


def betas(T: int = T_TRAIN, start: float = BETA_START, end: float = BETA_END) -> np.ndarray:
    step = (end - start) / (T - 1)
    b = np.arange(T, dtype=np.float64) * step + start
    b[-1] = end
    return b


def alphas_cumprod(T: int = T_TRAIN, start: float = BETA_START, end: float = BETA_END) -> np.ndarray:
    a = 1.0 - betas(T, start, end)
    out = np.empty_like(a)
    acc = 1.0
    for i in range(T):
        acc = acc * float(a[i]) if i else float(a[0])
        out[i] = acc
    return out


def ddim_timesteps(steps: int, T: int = T_TRAIN) -> np.ndarray:
    """Ascending DDIM timesteps tau_0 .. tau_{S-1} (int64)."""
    if not 1 <= steps <= T:
        raise ValueError(f"ddim: steps must be in 1..{T}, got {steps}")
    return np.arange(steps, dtype=np.int64) * (T // steps)


def f64_bits(x: np.ndarray) -> list[str]:
    """Exact float64 values as 16-digit hex bit patterns (what the manifest stores)."""
    return [f"{int(v):016x}" for v in np.asarray(x, dtype=np.float64).view(np.uint64)]
