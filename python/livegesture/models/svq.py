"""Streamable Vector-Quantized motion tokenizer (SVQ), one per region (paper section 3.1, supp. B.1).

- Encoder E (bidirectional, training only): conv stem, then 2 x (stride-2 conv + dilated ResNet1D):
  4x downsampling, one latent per motion token (4 frames).
- Quantizer: linear projection of the latent into the ``code_dim`` code space, nearest codebook entry
  (K entries, EMA updates with decay 0.99 and dead-code reset), straight-through gradients; the
  projection head W^region (a small MLP) maps the dequantised code back into the decoder's latent space.
- Causal stream decoder D_CS (strictly causal, left-only padding): 2 x (nearest upsample x2 + causal
  conv + causal dilated ResNet1D), output conv; frames 4t..4t+3 depend only on tokens <= t.

``step`` (the exported ``decoder_<region>`` graph) takes one token index per stream and returns its 4
frames of region features, de-normalised with the region's statistics.
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..config import LiveGestureConfig
from .layers import CacheSpec, CausalConv1d, check_cache, check_shape, conv_as_gemm


class ResBlock1D(nn.Module):
    """x + conv1x1(relu(conv3_dilated(relu(x)))), causal (left pad 2d) or centred (pad d)."""

    def __init__(self, c: int, dilation: int, causal: bool):
        super().__init__()
        self.causal = causal
        if causal:
            self.conv = CausalConv1d(c, c, 3, dilation)
        else:
            self.conv = nn.Conv1d(c, c, 3, dilation=dilation, padding=dilation)
        self.mix = nn.Conv1d(c, c, 1)

    def forward(self, x):
        return x + self.mix(F.relu(self.conv(F.relu(x))))

    def step(self, x, cache, new_cache, name):  # channels-last (B, T, C)
        y = F.relu(self.conv.step(F.relu(x), cache, new_cache, name))
        return x + conv_as_gemm(self.mix, y)


def _dilations(cfg: LiveGestureConfig):
    return [cfg.svq_dilation_growth ** i for i in range(cfg.svq_res_depth)]


def upsample2(x: torch.Tensor) -> torch.Tensor:
    """Nearest-neighbour temporal upsampling by 2: (B, C, T) -> (B, C, 2T).

    Channels and frames are static in every graph (only the batch is dynamic), so the reshape uses
    constant sizes and exports without shape arithmetic."""
    C, T = int(x.shape[1]), int(x.shape[2])
    return torch.stack([x, x], dim=-1).reshape(-1, C, 2 * T)


def upsample2_channels_last(x: torch.Tensor) -> torch.Tensor:
    """:func:`upsample2` for channels-last x: (B, T, C) -> (B, 2T, C)."""
    T, C = int(x.shape[1]), int(x.shape[2])
    return torch.stack([x, x], dim=2).reshape(-1, 2 * T, C)


class SVQEncoder(nn.Module):
    def __init__(self, d_in: int, cfg: LiveGestureConfig):
        super().__init__()
        W = cfg.svq_width
        layers = [nn.Conv1d(d_in, W, 3, padding=1), nn.ReLU()]
        for _ in range(2):
            layers.append(nn.Conv1d(W, W, 4, stride=2, padding=1))
            layers += [ResBlock1D(W, d, causal=False) for d in reversed(_dilations(cfg))]
        layers.append(nn.Conv1d(W, cfg.svq_latent, 3, padding=1))
        self.net = nn.Sequential(*layers)

    def forward(self, x):  # (B, d_in, 4T) -> (B, latent, T)
        return self.net(x)


class SVQDecoder(nn.Module):
    def __init__(self, d_out: int, cfg: LiveGestureConfig):
        super().__init__()
        W = cfg.svq_width
        self.inp = CausalConv1d(cfg.svq_latent, W, 3)
        self.up_convs = nn.ModuleList(CausalConv1d(W, W, 3) for _ in range(2))
        self.res = nn.ModuleList(nn.ModuleList(ResBlock1D(W, d, causal=True) for d in _dilations(cfg))
                                 for _ in range(2))
        self.out1 = CausalConv1d(W, W, 3)
        self.out2 = CausalConv1d(W, d_out, 3)

    def _run(self, z, conv, res, up=upsample2):
        x = F.relu(conv(self.inp, z, "inp"))
        for s in range(2):
            x = up(x)
            x = conv(self.up_convs[s], x, f"up{s}")
            for j, blk in enumerate(self.res[s]):
                x = res(blk, x, f"up{s}.res{j}")
        x = F.relu(conv(self.out1, x, "out1"))
        return conv(self.out2, x, "out2")

    def forward(self, z):  # (B, latent, T) -> (B, d_out, 4T)
        return self._run(z, lambda m, x, n: m(x), lambda b, x, n: b(x))

    def cache_specs(self) -> list[CacheSpec]:
        specs = self.inp.cache_spec("inp")
        for s in range(2):
            specs += self.up_convs[s].cache_spec(f"up{s}")
            for j, blk in enumerate(self.res[s]):
                specs += blk.conv.cache_spec(f"up{s}.res{j}")
        return specs + self.out1.cache_spec("out1") + self.out2.cache_spec("out2")

    def step(self, z, cache, new_cache):  # channels-last: z (B, 1, latent) -> (B, 4, d_out)
        return self._run(z, lambda m, x, n: m.step(x, cache, new_cache, n),
                         lambda b, x, n: b.step(x, cache, new_cache, n), upsample2_channels_last)


class Quantizer(nn.Module):
    """Codebook with EMA updates (decay ``ema_decay``) and dead-code reset, straight-through estimator."""

    def __init__(self, cfg: LiveGestureConfig):
        super().__init__()
        K, D = cfg.codebook_size, cfg.code_dim
        self.K, self.decay = K, cfg.ema_decay
        self.pre = nn.Linear(cfg.svq_latent, D)          # latent -> code space
        self.register_buffer("codebook", torch.randn(K, D) * 0.1)
        self.register_buffer("ema_count", torch.ones(K))
        self.register_buffer("ema_sum", self.codebook.clone())
        self.register_buffer("usage", torch.zeros(K))    # EMA of assignments, for dead-code reset

    def nearest(self, e: torch.Tensor) -> torch.Tensor:  # e (N, D) -> (N,)
        d = (e * e).sum(-1, keepdim=True) - 2 * e @ self.codebook.t() + (self.codebook ** 2).sum(-1)[None]
        return d.argmin(-1)

    def forward(self, z: torch.Tensor, update: bool = False):
        """z (B, latent, T) -> (quantised code vectors (B, T, D) with straight-through, indices (B, T),
        codebook loss, projected latents (B, T, D))."""
        e = self.pre(z.transpose(1, 2))
        flat = e.reshape(-1, e.shape[-1])
        idx = self.nearest(flat.detach())
        q = self.codebook[idx].view_as(e)
        if update and self.training:
            self._ema_update(flat.detach(), idx)
        # standard VQ codebook loss (commitment term on the projection; the codebook itself moves by EMA)
        cb_loss = F.mse_loss(e, q.detach())
        q_st = e + (q - e).detach()
        return q_st, idx.view(e.shape[:2]), cb_loss, e

    @torch.no_grad()
    def _ema_update(self, flat: torch.Tensor, idx: torch.Tensor):
        onehot = F.one_hot(idx, self.K).type(flat.dtype)
        count = onehot.sum(0)
        self.ema_count.mul_(self.decay).add_(count, alpha=1 - self.decay)
        self.ema_sum.mul_(self.decay).add_(onehot.t() @ flat, alpha=1 - self.decay)
        n = self.ema_count.sum()
        smoothed = (self.ema_count + 1e-5) / (n + self.K * 1e-5) * n
        self.codebook.copy_(self.ema_sum / smoothed[:, None])
        self.usage.mul_(0.99).add_(count, alpha=0.01)

    @torch.no_grad()
    def reset_dead_codes(self, recent: torch.Tensor, threshold: float = 1e-3) -> int:
        """Re-seed codes whose usage EMA fell below ``threshold`` with random recent encoder outputs."""
        dead = (self.usage < threshold).nonzero().flatten()
        if len(dead) == 0 or len(recent) == 0:
            return 0
        pick = recent[torch.randint(len(recent), (len(dead),), device=recent.device)]
        self.codebook[dead] = pick
        self.ema_sum[dead] = pick
        self.ema_count[dead] = 1.0
        self.usage[dead] = 1.0
        return int(len(dead))


class SVQ(nn.Module):
    def __init__(self, region: str, d_in: int, cfg: LiveGestureConfig):
        super().__init__()
        self.region, self.d_in, self.cfg = region, d_in, cfg
        self.name = f"decoder_{region}"
        self.register_buffer("mean", torch.zeros(d_in))
        self.register_buffer("std", torch.ones(d_in))
        self.encoder = SVQEncoder(d_in, cfg)
        self.quantizer = Quantizer(cfg)
        self.head = nn.Sequential(nn.Linear(cfg.code_dim, cfg.svq_head_hidden), nn.GELU(),
                                  nn.Linear(cfg.svq_head_hidden, cfg.svq_latent))
        self.decoder = SVQDecoder(d_in, cfg)

    # ------------------------------------------------------------------ training paths
    def autoencode(self, x: torch.Tensor) -> torch.Tensor:
        """Stage 1: x (B, 4T, d_in) normalised -> reconstruction (B, 4T, d_in), no quantisation."""
        return self.decoder(self.encoder(x.transpose(1, 2))).transpose(1, 2)

    def quantize(self, x: torch.Tensor, update: bool = False):
        """Stage 2: x (B, 4T, d_in) -> (reconstruction, tokens (B, T), codebook loss)."""
        q, idx, cb, _ = self.quantizer(self.encoder(x.transpose(1, 2)), update=update)
        rec = self.decoder(self.head(q).transpose(1, 2)).transpose(1, 2)
        return rec, idx, cb

    @torch.no_grad()
    def tokenize(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, 4T, d_in) normalised -> tokens (B, T) int64."""
        e = self.quantizer.pre(self.encoder(x.transpose(1, 2)).transpose(1, 2))
        return self.quantizer.nearest(e.reshape(-1, e.shape[-1])).view(e.shape[:2])

    # ------------------------------------------------------------------ decoder entry points
    def decode(self, tokens: torch.Tensor) -> torch.Tensor:
        """Offline causal decode: tokens (B, T) int64 -> region features (B, 4T, d_in), de-normalised."""
        z = self.head(self.quantizer.codebook[tokens]).transpose(1, 2)
        return self.decoder(z).transpose(1, 2) * self.std + self.mean

    def cache_specs(self) -> list[CacheSpec]:
        return self.decoder.cache_specs()

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def step(self, token: torch.Tensor, cache: dict) -> tuple[dict, dict]:
        """token (B,) int64 -> ({'motion': (B, 4, d_in)}, new_cache)."""
        check_shape(self.name, "token", token, (None,), torch.int64)
        check_cache(self.name, self.cache_specs(), cache, token.shape[0])
        new_cache: dict = {}
        z = self.head(self.quantizer.codebook[token])[:, None, :]         # (B, 1, latent), channels-last
        y = self.decoder.step(z, cache, new_cache)                         # (B, 4, d_in)
        return {"motion": y * self.std + self.mean}, new_cache
