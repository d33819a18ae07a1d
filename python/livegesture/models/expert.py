"""Region-eXpert autoregressive transformer, xAR (paper section 3.2.1, supp. B.2).

At token step t the eXpert of region r reads the previous token x_{t-1}^r (BOS at t = 0) and the audio
token a_t, and predicts x_t^r:

    e_t  = MLP(Embed(x_{t-1}^r))                                  (embed_dim -> d_model)
    for each of ``expert_blocks`` blocks:
        ``expert_cross_layers`` x causal audio cross-attention over a_{t-Wa+1..t}
        ``expert_self_layers``  x causal temporal self-attention over e_{t-H+1..t}
    h_t^r = LN(.)          (hidden state, fed to xAR-Fuse)
    logits = classifier_r(h_t^r)   (K classes; the classifier is shared with xAR-Fuse)

Variant ``additive-audio`` (config ``audio_fusion = "additive"``, LiveGesture Table 4): no cross-attention
layers; ``e_t = MLP(Embed(x_{t-1})) + W_a a_t`` instead (``audio_add``).

Classifier-free guidance: ``cond`` (B,) is 1 for the conditional branch and 0 for the unconditional one,
whose audio tokens are replaced by a learned null embedding (the same substitution as CFG dropout in
training). Both branches are just streams on the batch axis.
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..config import LiveGestureConfig
from .layers import AttnLayer, CacheSpec, check_cache, check_shape, window_bias


class RegionExpert(nn.Module):
    def __init__(self, region: str, cfg: LiveGestureConfig):
        super().__init__()
        self.region, self.cfg = region, cfg
        self.name = f"expert_{region}"
        d = cfg.d_model
        self.embed = nn.Embedding(cfg.codebook_size + 2, cfg.embed_dim)   # + BOS, MASK
        self.embed_mlp = nn.Sequential(nn.Linear(cfg.embed_dim, d), nn.GELU(), nn.Linear(d, d))
        self.null_audio = nn.Parameter(torch.zeros(cfg.audio_dim))
        if cfg.audio_fusion not in ("cross", "additive"):
            raise ValueError(f"config: audio_fusion {cfg.audio_fusion!r}: expected 'cross' or 'additive'")
        # variant additive-audio (Table 4): no cross-attention layers, the audio token added to the embedding
        self.additive = cfg.audio_fusion == "additive"
        layers = []
        for _ in range(cfg.expert_blocks):
            layers += [AttnLayer(d, cfg.n_heads, cfg.audio_window, cfg.ffn_mult, d_kv=cfg.audio_dim)
                       for _ in range(0 if self.additive else cfg.expert_cross_layers)]
            layers += [AttnLayer(d, cfg.n_heads, cfg.history, cfg.ffn_mult) for _ in range(cfg.expert_self_layers)]
        self.layers = nn.ModuleList(layers)
        self.norm = nn.LayerNorm(d)
        self.classifier = nn.Linear(d, cfg.codebook_size)
        if self.additive:
            self.audio_add = nn.Linear(cfg.audio_dim, d)

    def layer_names(self) -> list[str]:
        return [f"layer{i}.{'xattn' if l.is_cross else 'sattn'}" for i, l in enumerate(self.layers)]

    def _audio(self, audio, cond):
        c = cond.to(audio.dtype)
        while c.dim() < audio.dim():
            c = c.unsqueeze(-1)
        return c * audio + (1 - c) * self.null_audio

    def forward(self, prev_tokens: torch.Tensor, audio: torch.Tensor, cond: torch.Tensor,
                noise_sigma: float = 0.0, noise_p: float = 0.0):
        """Offline causal forward. prev_tokens (B, T) int64 (x_{t-1}, BOS first), audio (B, T, audio_dim),
        cond (B,) -> (hidden (B, T, d_model), logits (B, T, K)).

        ``noise_sigma``/``noise_p``: training-time Gaussian noise on the history embeddings, applied to a
        whole sequence with probability ``noise_p`` (exposure-bias mitigation, paper section 3.3)."""
        B, T = prev_tokens.shape
        check_shape(self.name, "audio", audio, (B, T, self.cfg.audio_dim), torch.float32)
        x = self.embed_mlp(self.embed(prev_tokens))
        if noise_sigma > 0 and noise_p > 0:
            on = (torch.rand(B, 1, 1, device=x.device) < noise_p).to(x.dtype)
            x = x + on * noise_sigma * torch.randn_like(x)
        a = self._audio(audio, cond)
        if self.additive:
            x = x + self.audio_add(a)
        for layer in self.layers:
            x = layer(x, a)
        h = self.norm(x)
        return h, self.classifier(h)

    def cache_specs(self) -> list[CacheSpec]:
        specs = [CacheSpec("step", (), "int64")]
        for name, layer in zip(self.layer_names(), self.layers):
            specs += layer.attn.cache_spec(name)
        return specs

    def init_cache(self, batch: int, device=None) -> dict:
        return {s.name: s.zeros(batch, device) for s in self.cache_specs()}

    def step(self, prev_token: torch.Tensor, audio: torch.Tensor, cond: torch.Tensor, cache: dict):
        """prev_token (B,) int64, audio (B, audio_dim), cond (B,) float32 ->
        ({'hidden': (B, d_model)}, new_cache)."""
        check_shape(self.name, "prev_token", prev_token, (None,), torch.int64)
        B = prev_token.shape[0]
        check_shape(self.name, "audio", audio, (B, self.cfg.audio_dim), torch.float32)
        check_shape(self.name, "cond", cond, (B,), torch.float32)
        check_cache(self.name, self.cache_specs(), cache, B)
        new_cache: dict = {}
        step = cache["step"]
        x = self.embed_mlp(self.embed(prev_token))
        a = self._audio(audio, cond)
        if self.additive:
            x = x + self.audio_add(a)
        bias = {w: window_bias(step, w) for w in {l.attn.w for l in self.layers}}   # one mask per window size
        for name, layer in zip(self.layer_names(), self.layers):
            x = layer.step(x, a, bias[layer.attn.w], cache, new_cache, name)
        new_cache["step"] = step + 1
        return {"hidden": self.norm(x)}, new_cache

    def logits(self, hidden: torch.Tensor) -> torch.Tensor:
        return self.classifier(hidden)
