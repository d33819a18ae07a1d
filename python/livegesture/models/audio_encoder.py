"""Streamable audio encoder (paper section 3.2.3).

log-mel frames (from ``livegesture.frontend``, ``M = mel_frames_per_token`` per token)
  -> normalisation with corpus statistics
  -> causal conv projection (kernel 3, left-only padding)
  -> dilated causal conv pyramid (residual, dilations ``audio_dilations``)
  -> per-token aggregation: a conv of kernel M and stride M over each token's M frames
  -> LayerNorm -> audio token a_t (``audio_dim``).

a_t depends only on mel frames up to the end of token t: zero look-ahead.
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..config import LiveGestureConfig
from .layers import CacheSpec, CausalConv1d, check_cache, check_shape, conv_as_gemm, gemm_weight


class AudioEncoder(nn.Module):
    name = "audio_encoder"

    def __init__(self, cfg: LiveGestureConfig):
        super().__init__()
        self.cfg = cfg
        n_mels, C = cfg.frontend.n_mels, cfg.audio_channels
        self.M = cfg.frontend.mel_frames_per_token
        self.register_buffer("mel_mean", torch.zeros(n_mels))
        self.register_buffer("mel_std", torch.ones(n_mels))
        self.proj = CausalConv1d(n_mels, C, cfg.audio_kernel)
        self.pyramid = nn.ModuleList(CausalConv1d(C, C, cfg.audio_kernel, d) for d in cfg.audio_dilations)
        self.pyramid_mix = nn.ModuleList(nn.Conv1d(C, C, 1) for _ in cfg.audio_dilations)
        self.aggregate = nn.Conv1d(C, cfg.audio_dim, self.M, stride=self.M)
        self.norm = nn.LayerNorm(cfg.audio_dim)

    def _trunk(self, x, conv, mix=lambda m, x: m(x)):
        x = F.gelu(conv(self.proj, x, "proj"))
        for i, (dil, mx) in enumerate(zip(self.pyramid, self.pyramid_mix)):
            x = x + mix(mx, F.gelu(conv(dil, x, f"pyramid{i}")))
        return x

    def forward(self, mel: torch.Tensor) -> torch.Tensor:
        """mel (B, M*T, n_mels) -> audio tokens (B, T, audio_dim)."""
        check_shape(self.name, "mel", mel, (None, None, self.cfg.frontend.n_mels), torch.float32)
        if mel.shape[1] % self.M:
            raise ValueError(f"{self.name}: input 'mel' has {mel.shape[1]} frames, expected a multiple of {self.M}")
        x = ((mel - self.mel_mean) / self.mel_std).transpose(1, 2)
        x = self._trunk(x, lambda m, x, n: m(x))
        return self.norm(self.aggregate(x).transpose(1, 2))

    def cache_specs(self) -> list[CacheSpec]:
        specs = self.proj.cache_spec("proj")
        for i, dil in enumerate(self.pyramid):
            specs += dil.cache_spec(f"pyramid{i}")
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def step(self, mel: torch.Tensor, cache: dict) -> tuple[dict, dict]:
        """mel (B, M, n_mels): one token's mel frames -> ({'audio': (B, audio_dim)}, new_cache)."""
        check_shape(self.name, "mel", mel, (None, self.M, self.cfg.frontend.n_mels), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, mel.shape[0])
        new_cache: dict = {}
        # channels-last (B, M, C) throughout: every conv is one Gemm over streams and frames, and the
        # per-token aggregation (kernel M, stride M over the token's M frames) is one Gemm over M * C
        x = (mel - self.mel_mean) / self.mel_std
        x = self._trunk(x, lambda m, x, n: m.step(x, cache, new_cache, n),
                        conv_as_gemm)
        agg = self.aggregate
        a = self.norm(F.linear(x.reshape(-1, self.M * x.shape[2]), gemm_weight(agg), agg.bias))
        return {"audio": a}, new_cache
