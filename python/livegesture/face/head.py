"""The causal viseme head.

Per motion token (133.3 ms) it takes the token's ``M = 8`` log-mel frames (the frontend the body graphs
use, :mod:`livegesture.frontend`) and returns the 4 frames' 15 viseme probabilities and their 52 ARKit
mouth/jaw weights (``visemes @ VISEME_ARKIT``, the table of :mod:`.names`, a constant in the graph):

  mel -> (mel - mean) / std -> causal conv (k 3) -> dilated causal conv pyramid (residual, GELU)
      -> frame j of the token: its two mel frames (2j, 2j+1), concatenated -> MLP -> 15 logits -> softmax

Video frame j of token t is the 30 fps frame 4t + j; its mel frames end at (8t + 2j + 1) / 60 s and
(8t + 2j + 2) / 60 s, i.e. within and at the end of the frame's own 33 ms: the head uses no audio after the
end of the frame, hence none after the end of the token (docs/face.md). Receptive field: 1 + 2 + 2 (1 + 2 + 4 +
8) = 33 mel frames (0.55 s).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..models.layers import CacheSpec, CausalConv1d, check_cache, check_shape, conv_as_gemm, gemm_weight
from .names import ARKIT_NAMES, VISEME_NAMES, viseme_arkit_matrix


@dataclass(frozen=True)
class FaceConfig:
    n_mels: int = 64
    mel_frames_per_token: int = 8
    frames_per_token: int = 4
    channels: int = 64
    kernel: int = 3
    dilations: tuple[int, ...] = (1, 2, 4, 8)
    hidden: int = 64

    def to_dict(self) -> dict:
        d = asdict(self)
        d["dilations"] = list(self.dilations)
        return d


class VisemeHead(nn.Module):
    name = "face"

    def __init__(self, cfg: FaceConfig = FaceConfig()):
        super().__init__()
        self.cfg = cfg
        C = cfg.channels
        if cfg.mel_frames_per_token % cfg.frames_per_token:
            raise ValueError("face: mel_frames_per_token must be a multiple of frames_per_token")
        self.P = cfg.mel_frames_per_token // cfg.frames_per_token      # mel frames per video frame (2)
        self.register_buffer("mel_mean", torch.zeros(cfg.n_mels))
        self.register_buffer("mel_std", torch.ones(cfg.n_mels))
        self.register_buffer("arkit_table", torch.from_numpy(viseme_arkit_matrix()))
        self.proj = CausalConv1d(cfg.n_mels, C, cfg.kernel)
        self.pyramid = nn.ModuleList(CausalConv1d(C, C, cfg.kernel, d) for d in cfg.dilations)
        self.mix = nn.ModuleList(nn.Linear(C, C) for _ in cfg.dilations)
        self.fc1 = nn.Linear(self.P * C, cfg.hidden)
        self.fc2 = nn.Linear(cfg.hidden, len(VISEME_NAMES))

    # --------------------------------------------------------------- shared
    def _trunk(self, x, conv):
        """x (B, T, n_mels) normalised, channels-last -> (B, T, C)."""
        x = F.gelu(conv(self.proj, x, "proj"))
        for i, (dil, mx) in enumerate(zip(self.pyramid, self.mix)):
            x = x + mx(F.gelu(conv(dil, x, f"pyramid{i}")))
        return x

    def _heads(self, h):
        """h (B, T_mel, C) -> logits (B, T_mel / P, 15)."""
        B, T, C = h.shape
        z = h.reshape(B, T // self.P, self.P * C)
        return self.fc2(F.gelu(self.fc1(z)))

    def outputs(self, logits):
        vis = torch.softmax(logits, dim=-1)
        return {"visemes": vis, "arkit_mouth": (vis @ self.arkit_table).clamp(0.0, 1.0)}

    # --------------------------------------------------------------- offline (training)
    def forward(self, mel: torch.Tensor) -> torch.Tensor:
        """mel (B, T_mel, n_mels), T_mel a multiple of P -> logits (B, T_mel / P, 15) (causal)."""
        check_shape(self.name, "mel", mel, (None, None, self.cfg.n_mels), torch.float32)
        if mel.shape[1] % self.P:
            raise ValueError(f"{self.name}: input 'mel' has {mel.shape[1]} frames, expected a multiple of {self.P}")
        x = (mel - self.mel_mean) / self.mel_std
        h = self._trunk(x, lambda m, x, n: m(x.transpose(1, 2)).transpose(1, 2))
        return self._heads(h)

    # --------------------------------------------------------------- streaming step (the ONNX graph)
    def cache_specs(self) -> list[CacheSpec]:
        specs = self.proj.cache_spec("proj")
        for i, dil in enumerate(self.pyramid):
            specs += dil.cache_spec(f"pyramid{i}")
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def step(self, mel: torch.Tensor, cache: dict) -> tuple[dict, dict]:
        """mel (B, M, n_mels): one token's mel frames -> ({'visemes': (B, 4, 15), 'arkit_mouth': (B, 4, 52)},
        new_cache)."""
        M = self.cfg.mel_frames_per_token
        check_shape(self.name, "mel", mel, (None, M, self.cfg.n_mels), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, mel.shape[0])
        new_cache: dict = {}
        x = (mel - self.mel_mean) / self.mel_std
        h = self._trunk(x, lambda m, x, n: m.step(x, cache, new_cache, n))
        return self.outputs(self._heads(h)), new_cache


__all__ = ["FaceConfig", "VisemeHead", "ARKIT_NAMES", "VISEME_NAMES"]
