"""Causal spatial-temporal fusion transformer, xAR-Fuse (paper section 3.2.2, supp. B.2).

At token step t it reads the hidden states h_t^r of the frozen region eXperts (four, or one for the full-body
SVQ) and the audio token a_t:

    h~_t^r = h_t^r + W_r h_t^r + region_embedding_r        (PILOR: per-region residual linear adapter)
    for each of ``fuse_blocks`` blocks:
        inter-region spatial attention across the 4 regions at time t
        causal global temporal attention, per region, over a window of ``fuse_window`` tokens (KV cache)
        causal audio-motion cross-attention over a_{t-Wa+1..t} (keys shared by the regions)
        feed-forward
    logits_t^r = classifier_r(LN(.))        (the region classifiers are shared with the eXperts)

Guided sampling happens outside the graph, in the runtime (``livegesture.sampling``).

Variants (``livegesture.variants``; config fields, all on by default): ``pilor`` (False: h~ = h +
region_embedding, Table 2a "w/o PILOR"), ``fuse_spatial`` / ``fuse_temporal`` / ``fuse_audio`` (False: the
block has no such attention layer, no LayerNorm and no cache for it; Table 2a "w/o spatial / temporal attn."),
``fusion = "none"`` (eXperts only: no adapter, no blocks, no final LayerNorm: ``logits_t^r = classifier_r(h_t^r)``,
exactly the eXperts' own predictions, so the bundle's ``fusion`` graph is the eXperts' classifiers and the
runtime runs it unchanged).
"""
from __future__ import annotations

import math

import torch
import torch.nn as nn

from ..config import LiveGestureConfig
from ..regions import model_regions
from .layers import AttentionOp, CacheSpec, FeedForward, WindowedAttention, check_cache, check_shape, window_bias


class SpatialAttention(nn.Module):
    """Full multi-head attention across the regions of one time step (no mask, no positions:
    regions are told apart by their learned region embeddings)."""

    def __init__(self, d: int, n_heads: int):
        super().__init__()
        self.h, self.hd, self.d = n_heads, d // n_heads, d
        self.qkv = nn.Linear(d, 3 * d)
        self.o = nn.Linear(d, d)

    def forward(self, x):  # (N, R, d)
        N, R, _ = x.shape
        q, k, v = self.qkv(x).reshape(N, R, 3, self.h, self.hd).permute(2, 0, 3, 1, 4)
        a = torch.softmax((q @ k.transpose(-1, -2)) / math.sqrt(self.hd), dim=-1)
        return self.o((a @ v).transpose(1, 2).reshape(N, R, self.d))

    def _step_qkv(self, x):  # (B, R, d) -> q, k, v (B, h, R, hd) with constant reshape sizes (lean step graph)
        return self.qkv(x).reshape(-1, int(x.shape[1]), 3, self.h, self.hd).permute(2, 0, 3, 1, 4)

    def _step_out(self, y):  # (B, h, R, hd) -> (B, R, d)
        return self.o(y.transpose(1, 2).reshape(-1, int(y.shape[2]), self.d))

    def step(self, x):  # (B, R, d): the same computation as forward
        q, k, v = self._step_qkv(x)
        a = torch.softmax((q @ k.transpose(-1, -2)) / math.sqrt(self.hd), dim=-1)
        return self._step_out(a @ v)

    def step_op(self, x):  # step with the attention core as one AttentionOp (ONNX Attention, no mask)
        q, k, v = self._step_qkv(x)
        return self._step_out(AttentionOp.apply(q, k, v, None, 1.0 / math.sqrt(self.hd)))


class FuseBlock(nn.Module):
    """One fusion block; a layer switched off by the config (``fuse_spatial``, ``fuse_temporal``, ``fuse_audio``)
    is absent (no weights, no cache), not computed and discarded."""

    def __init__(self, cfg: LiveGestureConfig):
        super().__init__()
        d = cfg.d_model
        self.has_spatial, self.has_temporal = cfg.fuse_spatial, cfg.fuse_temporal
        self.has_cross = cfg.fuse_audio and cfg.audio_fusion == "cross"     # additive: the audio is added instead
        if self.has_spatial:
            self.ln_s, self.spatial = nn.LayerNorm(d), SpatialAttention(d, cfg.n_heads)
        if self.has_temporal:
            self.ln_t, self.temporal = nn.LayerNorm(d), WindowedAttention(d, cfg.n_heads, cfg.fuse_window)
        if self.has_cross:
            self.ln_a, self.cross = nn.LayerNorm(d), WindowedAttention(d, cfg.n_heads, cfg.audio_window, cfg.audio_dim)
        self.ln_f, self.ffn = nn.LayerNorm(d), FeedForward(d, cfg.ffn_mult)


class XARFuse(nn.Module):
    name = "fusion"

    def __init__(self, cfg: LiveGestureConfig, classifiers: nn.ModuleList | None = None):
        super().__init__()
        self.cfg = cfg
        self.region_names = tuple(r.name for r in model_regions(cfg))
        d, R = cfg.d_model, len(self.region_names)
        self.R = R
        if cfg.fusion not in ("xar", "none"):
            raise ValueError(f"config: fusion {cfg.fusion!r}: expected 'xar' (xAR-Fuse) or 'none' (eXperts only)")
        self.fused = cfg.fusion == "xar"
        self.has_pilor = self.fused and cfg.pilor
        if self.has_pilor:
            self.pilor = nn.ModuleList(nn.Linear(d, d) for _ in range(R))
            for lin in self.pilor:   # start as the identity adapter: h~ = h
                nn.init.zeros_(lin.weight)
                nn.init.zeros_(lin.bias)
        if self.fused:
            self.region_embed = nn.Parameter(torch.zeros(R, d))
            self.null_audio = nn.Parameter(torch.zeros(cfg.audio_dim))
        # registration order as before the variants (the exported graph's initializer names follow it)
        self.blocks = nn.ModuleList(FuseBlock(cfg) for _ in range(cfg.fuse_blocks if self.fused else 0))
        if self.fused:
            self.norm = nn.LayerNorm(d)
        # variant additive-audio (Table 4): the audio token projected and added to every region's state
        self.additive = self.fused and cfg.fuse_audio and cfg.audio_fusion == "additive"
        if self.additive:
            self.audio_add = nn.Linear(cfg.audio_dim, d)
        self.classifiers = classifiers if classifiers is not None else \
            nn.ModuleList(nn.Linear(d, cfg.codebook_size) for _ in range(R))

    @property
    def uses_audio(self) -> bool:
        """Whether the step reads ``audio`` and ``cond`` (not without audio cross-attention: the exported graph
        then has no such inputs)."""
        return self.fused and (self.additive or any(b.has_cross for b in self.blocks))

    def _adapt(self, h):  # h (..., R, d)
        if not self.fused:
            return h
        if not self.has_pilor:
            return h + self.region_embed
        return torch.stack([h[..., r, :] + self.pilor[r](h[..., r, :]) for r in range(self.R)], dim=-2) \
            + self.region_embed

    def _audio(self, audio, cond):
        if not self.fused:
            return audio
        c = cond.to(audio.dtype)
        while c.dim() < audio.dim():
            c = c.unsqueeze(-1)
        return c * audio + (1 - c) * self.null_audio

    def _classify(self, x):  # (..., R, d) -> (..., R, K)
        if self.fused:
            x = self.norm(x)
        return torch.stack([self.classifiers[r](x[..., r, :]) for r in range(self.R)], dim=-2)

    def forward(self, hidden: torch.Tensor, audio: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """Offline causal forward. hidden (B, T, R, d), audio (B, T, audio_dim), cond (B,) -> logits (B, T, R, K)."""
        B, T = hidden.shape[:2]
        d, R = self.cfg.d_model, self.R
        check_shape(self.name, "hidden", hidden, (B, T, R, d), torch.float32)
        check_shape(self.name, "audio", audio, (B, T, self.cfg.audio_dim), torch.float32)
        x = self._adapt(hidden)
        a = self._audio(audio, cond)
        if self.additive:
            x = x + self.audio_add(a)[:, :, None, :]
        a_rep = a[:, None].expand(B, R, T, a.shape[-1]).reshape(B * R, T, -1)
        for blk in self.blocks:
            if blk.has_spatial:
                x = x + blk.spatial(blk.ln_s(x).reshape(B * T, R, d)).reshape(B, T, R, d)
            if blk.has_temporal:
                xt = blk.ln_t(x).permute(0, 2, 1, 3).reshape(B * R, T, d)
                x = x + blk.temporal(xt, xt).reshape(B, R, T, d).permute(0, 2, 1, 3)
            if blk.has_cross:
                xa = blk.ln_a(x).permute(0, 2, 1, 3).reshape(B * R, T, d)
                x = x + blk.cross(xa, a_rep).reshape(B, R, T, d).permute(0, 2, 1, 3)
            x = x + blk.ffn(blk.ln_f(x))
        return self._classify(x)

    def cache_specs(self) -> list[CacheSpec]:
        specs = [CacheSpec("step", (), "int64")]
        for i, blk in enumerate(self.blocks):
            if blk.has_temporal:
                specs += blk.temporal.cache_spec(f"block{i}.tattn", lead=(self.R,))
            if blk.has_cross:
                specs += blk.cross.cache_spec(f"block{i}.xattn")
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def step(self, hidden: dict, audio: torch.Tensor, cond: torch.Tensor, cache: dict, attention_op: bool = False):
        """hidden {region: (B, d)}, audio (B, audio_dim), cond (B,) -> ({'logits': (B, R, K)}, new_cache).

        ``attention_op``: the attention cores as the ONNX ``Attention`` op (``step_op`` of the attention layers;
        the docs/bundle.md#forms-and-precision form ``attention``, graph ``fusion_attention``, :mod:`livegesture.forms.fusion_attention`):
        same inputs, caches and outputs."""
        d, R = self.cfg.d_model, self.R
        B = audio.shape[0]
        for r in self.region_names:
            if r not in hidden:
                raise ValueError(f"{self.name}: input 'hidden_{r}' is missing")
            check_shape(self.name, f"hidden_{r}", hidden[r], (B, d), torch.float32)
        check_shape(self.name, "audio", audio, (B, self.cfg.audio_dim), torch.float32)
        check_shape(self.name, "cond", cond, (B,), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, B)
        new_cache: dict = {}
        step = cache["step"]
        x = self._adapt(torch.stack([hidden[r] for r in self.region_names], dim=1))   # (B, R, d)
        a = self._audio(audio, cond)
        if self.additive:
            x = x + self.audio_add(a)[:, None, :]
        # one additive mask per window, shared by the blocks; the temporal attention runs on B * R rows
        # (stream-major, region-minor), so its mask is repeated per region with a broadcast, not an Expand
        bias_a = window_bias(step, self.cfg.audio_window)[:, None]     # (B, 1, 1, W): R queries per stream
        bias_t = window_bias(step, self.cfg.fuse_window)
        bias_t = (bias_t[:, None] + torch.zeros((1, R, 1, 1), device=bias_t.device)).reshape(
            -1, 1, self.cfg.fuse_window)
        for i, blk in enumerate(self.blocks):
            def core(layer):
                return layer.step_op if attention_op else layer.step
            if blk.has_spatial:
                x = x + core(blk.spatial)(blk.ln_s(x))
            if blk.has_temporal:
                # temporal attention on B * R rows (stream-major, region-minor); its caches keep the region axis
                xt = blk.ln_t(x).reshape(-1, d)
                x = x + core(blk.temporal)(xt, xt, bias_t, cache, new_cache, f"block{i}.tattn",
                                           lead=(R,)).reshape(-1, R, d)
            if blk.has_cross:
                x = x + core(blk.cross)(blk.ln_a(x), a, bias_a, cache, new_cache, f"block{i}.xattn")
            x = x + blk.ffn(blk.ln_f(x))
        new_cache["step"] = step + 1
        return {"logits": self._classify(x)}, new_cache
