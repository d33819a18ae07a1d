"""The UniEG denoiser (paper section 3.3, Figure 2): epsilon prediction for a whole window at once.

Inputs: ``x_t`` (B, n, D) noisy normalised motion in region order (upper, hands, lower | face), ``t``
(B,) int64 diffusion step in [0, 1000), ``audio`` (B, n, audio_dim) from the speech encoders,
``speaker`` (B,) int64 style id, ``cond`` (B,) float32: 1 uses the audio, 0 substitutes the learned null
audio (classifier-free guidance; the unconditional branch).

1. global condition ``g = MLP(sinusoidal(t)) + MLP(Embed(speaker))`` (fed to every AdaIN);
2. audio ``a = cond * audio + (1 - cond) * null_audio``;
3. expression branch (face = jaw rot6d + 100 expressions, the last 106 features):
   ``h = FusionRes(x_t^E, a)`` -> Linear -> + positions -> style-aware blocks;
   ``eps^E = Linear(LN(h)) + k(g) * x_t^E`` (k: a per-feature gain from the global condition, initialised to 1;
   our addition: with d_model below the branch width the noise in x_t cannot pass through the blocks);
4. predicted clean expression (eq. 5), computed in float32 inside the graph and DETACHED:
   ``x0^E = (x_t^E - sqrt(1 - alpha_bar_t) eps^E) / sqrt(alpha_bar_t)``;
5. gesture branch (upper + hands + lower, the first 319 features):
   ``h = FusionRes(x_t^G, concat(x0^E, a))`` -> Linear -> + positions -> blocks; ``eps^G`` as in 3.;
6. ``eps = concat(eps^G, eps^E)`` in the layout of ``x_t``.

The expression never sees the gesture (uni-directional flow); gradients of the gesture loss do not reach
the expression branch through x0^E.

Variants (``livegesture.variants``; the config's ``flow``, ``detach``, ``x0_condition``; the paper's ablations of
section 4.5 / Table 1): ``flow = "reverse"`` (gesture first: the gesture branch reads the audio, the expression
branch reads ``concat(x0^G, a)``), ``flow = "concat"`` (naive concatenation: one branch over the whole motion
``x_t`` with the audio, its width ``d_model`` x 1.41 rounded to a multiple of the heads, as the paper's "enlarge
the latent dimension by 1.41 times"), ``detach = False`` (the gesture loss reaches the first branch through x0),
``x0_condition = False`` (the second branch reads the audio only: two independent branches). The step graph's
inputs and outputs are the same for every variant.
"""
from __future__ import annotations

import dataclasses

import torch
import torch.nn as nn
import torch.nn.functional as F

from .config import DiffSHEGConfig
from .layers import FusionResidualBlock, StyleTransformerBlock, position_table, sinusoidal
from .schedule import alphas_cumprod

EXP_DIM = 106        # face region: jaw rot6d (6) + expressions (100)
GES_DIM = 78 + 180 + 61
MOTION_DIM = GES_DIM + EXP_DIM
FLOWS = ("uni", "reverse", "concat")      # condition flow: expression -> gesture, gesture -> expression, one branch


class Branch(nn.Module):
    def __init__(self, cfg: DiffSHEGConfig, d_x: int, d_cond: int, n_layers: int):
        super().__init__()
        d = cfg.d_model
        self.fuse = FusionResidualBlock(d_x, d_cond, cfg.fusion_hidden)
        self.inp = nn.Linear(d_x, d)
        self.register_buffer("pos", position_table(cfg.window, d), persistent=False)
        self.blocks = nn.ModuleList(StyleTransformerBlock(d, cfg.n_heads, cfg.ff_dim, cfg.dropout)
                                    for _ in range(n_layers))
        self.out_norm = nn.LayerNorm(d)
        self.out = nn.Linear(d, d_x)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)
        # style-aware skip gain k(g) (ours): eps is mostly the noise already in x_t, and d_model may be smaller
        # than the branch (319 gesture features through 128 channels in `default`), so the noise cannot pass
        # through the Transformer; eps = Out(h) + k(g) * x_t, k initialised to 1 (the high-noise solution)
        self.skip = nn.Linear(d, d_x)
        nn.init.zeros_(self.skip.weight)
        nn.init.ones_(self.skip.bias)

    def forward(self, x: torch.Tensor, cond: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        h = self.inp(self.fuse(x, cond))
        h = h + self.pos[: h.shape[1]]
        for b in self.blocks:
            h = b(h, g)
        return self.out(self.out_norm(h)) + self.skip(F.silu(g)).unsqueeze(1) * x


def concat_width(cfg: DiffSHEGConfig) -> int:
    """The naive-concatenation branch's width: d_model x 1.41 (section 4.5), a multiple of the heads."""
    return max(cfg.n_heads, round(cfg.d_model * 1.41 / cfg.n_heads) * cfg.n_heads)


class UniEG(nn.Module):
    def __init__(self, cfg: DiffSHEGConfig):
        super().__init__()
        self.cfg = cfg
        if cfg.flow not in FLOWS:
            raise ValueError(f"diffsheg config: flow {cfg.flow!r}: expected one of {', '.join(FLOWS)}")
        d = cfg.d_model
        self.t_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        self.speaker = nn.Embedding(cfg.n_speakers, d)
        self.s_mlp = nn.Sequential(nn.Linear(d, d), nn.SiLU(), nn.Linear(d, d))
        self.null_audio = nn.Parameter(torch.zeros(cfg.audio_dim))
        x0 = cfg.x0_condition
        if cfg.flow == "uni":
            self.exp = Branch(cfg, EXP_DIM, cfg.audio_dim, cfg.exp_layers)
            self.ges = Branch(cfg, GES_DIM, (EXP_DIM if x0 else 0) + cfg.audio_dim, cfg.ges_layers)
        elif cfg.flow == "reverse":
            self.ges = Branch(cfg, GES_DIM, cfg.audio_dim, cfg.ges_layers)
            self.exp = Branch(cfg, EXP_DIM, (GES_DIM if x0 else 0) + cfg.audio_dim, cfg.exp_layers)
        else:   # one branch over the whole motion, wider (its global condition projected to its width)
            w = concat_width(cfg)
            wide = dataclasses.replace(cfg, d_model=w, ff_dim=cfg.ff_dim * w // d)
            self.g_proj = nn.Linear(d, w)
            self.joint = Branch(wide, MOTION_DIM, cfg.audio_dim, max(cfg.exp_layers, cfg.ges_layers))
        ab = alphas_cumprod(cfg.diffusion_steps, cfg.beta_start, cfg.beta_end)
        self.register_buffer("sqrt_ab", torch.from_numpy(ab ** 0.5).float(), persistent=False)
        self.register_buffer("sqrt_1mab", torch.from_numpy((1.0 - ab) ** 0.5).float(), persistent=False)

    def forward(self, x_t, t, audio, speaker, cond):
        g = self.t_mlp(sinusoidal(t, self.cfg.d_model)) + self.s_mlp(self.speaker(speaker))
        c = cond[:, None, None]
        a = c * audio + (1.0 - c) * self.null_audio
        if self.cfg.flow == "concat":
            return self.joint(x_t, a, self.g_proj(g))
        x_g, x_e = x_t[..., :GES_DIM], x_t[..., GES_DIM:]
        first, second = (self.exp, self.ges) if self.cfg.flow == "uni" else (self.ges, self.exp)
        x_1, x_2 = (x_e, x_g) if self.cfg.flow == "uni" else (x_g, x_e)
        eps_1 = first(x_1, a, g)
        if self.cfg.x0_condition:
            x0_1 = (x_1 - self.sqrt_1mab[t][:, None, None] * eps_1) / self.sqrt_ab[t][:, None, None]
            eps_2 = second(x_2, torch.cat([x0_1.detach() if self.cfg.detach else x0_1, a], dim=-1), g)
        else:
            eps_2 = second(x_2, a, g)
        eps_e, eps_g = (eps_1, eps_2) if self.cfg.flow == "uni" else (eps_2, eps_1)
        return torch.cat([eps_g, eps_e], dim=-1)
