"""Speech encoders (paper section 3.3, "Speech Encoding").

log-mel frames (the project's frontend, ``livegesture.frontend``: 2 mel frames per 30 fps motion frame; the
window's frames ``2 s .. 2 (s + n) - 1`` for motion frames ``s .. s + n - 1``), normalised with corpus
statistics, feed two encoders whose per-frame outputs are concatenated: ``audio = [mid | high]`` (B, n,
mid_dim + high_dim):

- **mid-level** (shared by the expression and the gesture branch, as in the paper): a stride-2 conv pairs
  the two mel frames of each motion frame, sinusoidal positions, then ``mid_layers`` Transformer blocks
  with linear self-attention over the window;
- **high-level** (the slot of the paper's frozen HuBERT, which cannot be downloaded here): a learned
  non-causal dilated conv stack over the mel frames (residual, dilations ``high_dilations``), a stride-2
  conv to 30 fps, LayerNorm. It is trained with the model. To use real HuBERT (or any) features instead,
  replace ``HighLevelEncoder`` with a projection of those features resampled to 30 fps (one row per motion
  frame of the window) to ``high_dim`` and retrain: the denoiser's ``audio`` input does not change.

Everything sees only the window's own mel frames (no state between windows).
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from .config import DiffSHEGConfig
from .layers import PlainTransformerBlock, position_table


class MidLevelEncoder(nn.Module):
    def __init__(self, cfg: DiffSHEGConfig):
        super().__init__()
        d = cfg.mid_dim
        self.pair = nn.Conv1d(cfg.frontend.n_mels, d, kernel_size=2, stride=2)
        self.register_buffer("pos", position_table(cfg.window, d), persistent=False)
        self.blocks = nn.ModuleList(PlainTransformerBlock(d, max(1, d // 32), 2 * d, cfg.dropout)
                                    for _ in range(cfg.mid_layers))
        self.norm = nn.LayerNorm(d)

    def forward(self, mel_cf: torch.Tensor) -> torch.Tensor:   # (B, n_mels, 2n) -> (B, n, d)
        x = self.pair(mel_cf).transpose(1, 2)
        x = x + self.pos[: x.shape[1]]
        for b in self.blocks:
            x = b(x)
        return self.norm(x)


class HighLevelEncoder(nn.Module):
    def __init__(self, cfg: DiffSHEGConfig):
        super().__init__()
        C = cfg.high_channels
        self.proj = nn.Conv1d(cfg.frontend.n_mels, C, 3, padding=1)
        self.dil = nn.ModuleList(nn.Conv1d(C, C, 3, padding=d, dilation=d) for d in cfg.high_dilations)
        self.mix = nn.ModuleList(nn.Conv1d(C, C, 1) for _ in cfg.high_dilations)
        self.down = nn.Conv1d(C, cfg.high_dim, kernel_size=2, stride=2)
        self.norm = nn.LayerNorm(cfg.high_dim)

    def forward(self, mel_cf: torch.Tensor) -> torch.Tensor:   # (B, n_mels, 2n) -> (B, n, high_dim)
        x = F.gelu(self.proj(mel_cf))
        for d, m in zip(self.dil, self.mix):
            x = x + m(F.gelu(d(x)))
        return self.norm(self.down(x).transpose(1, 2))


class SpeechEncoder(nn.Module):
    """mel (B, 2n, n_mels) raw log-mel -> audio (B, n, mid_dim + high_dim)."""

    def __init__(self, cfg: DiffSHEGConfig):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("mel_mean", torch.zeros(cfg.frontend.n_mels))
        self.register_buffer("mel_std", torch.ones(cfg.frontend.n_mels))
        self.mid = MidLevelEncoder(cfg)
        self.high = HighLevelEncoder(cfg)

    def forward(self, mel: torch.Tensor) -> torch.Tensor:
        x = ((mel - self.mel_mean) / self.mel_std).transpose(1, 2)
        return torch.cat([self.mid(x), self.high(x)], dim=-1)
