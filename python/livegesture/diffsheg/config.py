"""One dataclass holds a whole DiffSHEG model's hyper-parameters and its sampling defaults.

- ``tiny``: tests (a random-weights export in seconds);
- ``default``: trained on the synthetic corpus on one CPU thread in ~30-40 minutes, shipped in models/diffsheg;
- ``paper``: a paper-sized model (latent 512, feed-forward 1024, 8 heads, 8 style-aware transformer layers per
  branch, audio latent 256, 128 mel bins): the project's choice, the paper gives no widths or depths;
  88-frame windows at 30 fps with an overlap of 10 (the project's choice; the paper's runtime test overlaps 4
  frames at 15 fps), DDIM 25 steps (the paper's, section 3.5).

The guidance scale is the project's choice: the paper gives none (the authors' SHOW scripts use 1.15). Configs
keep 1.25; the shipped models/diffsheg bundle samples with 3.0, set at export (``export.py --guidance 3``,
docs/experiments.md, the guidance study).
"""
from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field

from ..frontend import FrontendConfig


@dataclass(frozen=True)
class DiffSHEGConfig:
    name: str = "default"
    frontend: FrontendConfig = field(default_factory=FrontendConfig)

    # audio encoders (mel -> per-frame speech features at 30 fps: [mid-level | high-level])
    mid_dim: int = 64                 # mid-level speech encoder (Transformer over mel), shared by both branches
    mid_layers: int = 1
    high_dim: int = 64                # the HuBERT slot: a learned high-level encoder (dilated conv stack)
    high_channels: int = 64
    high_dilations: tuple[int, ...] = (1, 2, 4, 8)

    # UniEG denoiser
    d_model: int = 128
    n_heads: int = 4
    ff_dim: int = 256
    exp_layers: int = 2               # style-aware transformer blocks of the expression branch
    ges_layers: int = 2               # ... of the gesture branch
    fusion_hidden: int = 256          # motion-speech fusion residual MLP width
    n_speakers: int = 8               # style ids (speaker embedding table)
    dropout: float = 0.1

    # variant switches (livegesture.variants; the paper's DiffSHEG by default, docs/diffsheg.md "Variants")
    variant: str = "full"             # the name of the variant this config is (recorded in checkpoints, manifests)
    flow: str = "uni"                 # "uni" (expression -> gesture), "reverse", "concat" (section 4.5, Table 1)
    detach: bool = True               # x0 of the first branch detached before the second branch reads it
    x0_condition: bool = True         # the second branch reads the first branch's x0

    # diffusion + sampling defaults (the paper's: 1000-step DDPM, 25 DDIM steps, section 3.5; the rest the project's)
    diffusion_steps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    ddim_steps: int = 25
    guidance: float = 1.25            # not a paper value (see the module doc); models/diffsheg exports 3.0
    window: int = 88                  # N: frames per window (the longest window; positional table length)
    overlap: int = 10                 # L_o
    jumps: int = 2                    # U: RePaint resampling jumps per DDIM step
    blend_steps: int = 2              # linear blend of the overlap in the last `blend_steps` DDIM steps

    @property
    def audio_dim(self) -> int:
        return self.mid_dim + self.high_dim

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frontend"] = asdict(self.frontend)
        d["high_dilations"] = list(self.high_dilations)
        return d

    @staticmethod
    def from_dict(d: dict) -> "DiffSHEGConfig":
        d = dict(d)
        d["frontend"] = FrontendConfig(**{k: v for k, v in d.get("frontend", {}).items()
                                          if k in {f.name for f in dataclasses.fields(FrontendConfig)}})
        d["high_dilations"] = tuple(d.get("high_dilations", (1, 2, 4, 8)))
        names = {f.name for f in dataclasses.fields(DiffSHEGConfig)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"diffsheg config: unknown fields {sorted(unknown)}")
        return DiffSHEGConfig(**d)


TINY = DiffSHEGConfig(
    name="tiny", frontend=FrontendConfig(n_mels=16),
    mid_dim=8, mid_layers=1, high_dim=8, high_channels=8, high_dilations=(1, 2),
    d_model=16, n_heads=2, ff_dim=32, exp_layers=1, ges_layers=1, fusion_hidden=32, n_speakers=8,
    ddim_steps=5, window=24, overlap=4, jumps=2, blend_steps=2,
)

DEFAULT = DiffSHEGConfig()

PAPER = DiffSHEGConfig(
    name="paper", frontend=FrontendConfig(n_mels=128),
    mid_dim=256, mid_layers=4, high_dim=256, high_channels=256, high_dilations=(1, 2, 4, 8, 16),
    d_model=512, n_heads=8, ff_dim=1024, exp_layers=8, ges_layers=8, fusion_hidden=1024, n_speakers=8,
)

CONFIGS = {c.name: c for c in (TINY, DEFAULT, PAPER)}


def get_config(name: str) -> DiffSHEGConfig:
    try:
        return CONFIGS[name]
    except KeyError:
        raise ValueError(f"unknown diffsheg config {name!r}; choose one of {sorted(CONFIGS)}") from None
