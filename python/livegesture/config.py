"""One dataclass holds a whole LiveGesture model's hyper-parameters. Three named configs:

- ``tiny``: for tests (seconds on a CPU), same structure, tiny widths and windows;
- ``default``: the model we train on the synthetic corpus and ship in ``models/default``;
- ``paper``: the LiveGesture paper's values where it gives one (supp. B: K 2048, 128-d codes, embedding 128 -> 256,
  history 32, eXperts 2 x (3 + 3), 3 fuse blocks), the project's choice where it gives none (widths of the SVQ
  and the audio encoder, mel bins, heads, the fusion's windows; docs/model.md), for users with BEAT2 and a GPU.
"""
from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field

from .frontend import FrontendConfig


@dataclass(frozen=True)
class LiveGestureConfig:
    name: str = "default"
    frontend: FrontendConfig = field(default_factory=FrontendConfig)

    # SVQ tokenizer (per region)
    codebook_size: int = 256          # K
    code_dim: int = 64                # codebook vector size
    svq_width: int = 128              # conv channels of encoder/decoder
    svq_latent: int = 128             # autoencoder latent size
    svq_res_depth: int = 2            # dilated residual layers per ResNet1D block
    svq_dilation_growth: int = 3      # dilations 1, 3, 9, ...
    svq_head_hidden: int = 128        # projection head W^region hidden width
    ema_decay: float = 0.99

    # streamable audio encoder
    audio_channels: int = 64
    audio_dilations: tuple[int, ...] = (1, 2, 4, 8)
    audio_kernel: int = 3
    audio_dim: int = 128              # audio token size a_t

    # region eXperts (xAR)
    embed_dim: int = 64               # token embedding (codebook embedding size in the paper)
    d_model: int = 128
    n_heads: int = 4
    history: int = 32                 # temporal self-attention window (tokens)
    audio_window: int = 32            # audio cross-attention window (tokens)
    expert_blocks: int = 2
    expert_cross_layers: int = 1      # causal audio cross-attention layers per block
    expert_self_layers: int = 1       # causal temporal self-attention layers per block
    ffn_mult: int = 4

    # xAR-Fuse
    fuse_blocks: int = 2
    fuse_window: int = 32             # causal temporal attention window (tokens)

    # variant switches (livegesture.variants; the paper's full model by default, docs/model.md "Variants")
    variant: str = "full"             # the name of the variant this config is (recorded in checkpoints, manifests)
    pilor: bool = True                # PILOR residual adapters before xAR-Fuse (Table 2a)
    fuse_spatial: bool = True         # inter-region spatial attention in the fuse blocks (Table 2a)
    fuse_temporal: bool = True        # causal global temporal attention in the fuse blocks (Table 2a)
    fuse_audio: bool = True           # causal audio-motion cross-attention in the fuse blocks
    fusion: str = "xar"               # "xar": xAR-Fuse; "none": eXperts only (the eXperts' own classifiers)
    audio_fusion: str = "cross"       # "cross": audio-motion cross-attention; "additive": audio added (Table 4)
    regions: str = "per-region"       # region set (livegesture.regions.REGION_SETS): "per-region" (upper, hands,
    #                                   lower, face: one SVQ and eXpert each) or "full-body" (one region, Table 6)

    # inference defaults
    guidance: float = 1.25
    temperature: float = 1.0
    top_k: int = 32

    @property
    def bos_token(self) -> int:
        return self.codebook_size

    @property
    def mask_token(self) -> int:
        return self.codebook_size + 1

    @property
    def head_dim(self) -> int:
        return self.d_model // self.n_heads

    def to_dict(self) -> dict:
        d = asdict(self)
        d["frontend"] = asdict(self.frontend)
        d["audio_dilations"] = list(self.audio_dilations)
        return d

    @staticmethod
    def from_dict(d: dict) -> "LiveGestureConfig":
        d = dict(d)
        d["frontend"] = FrontendConfig(**{k: v for k, v in d.get("frontend", {}).items()
                                          if k in {f.name for f in dataclasses.fields(FrontendConfig)}})
        d["audio_dilations"] = tuple(d.get("audio_dilations", (1, 2, 4, 8)))
        names = {f.name for f in dataclasses.fields(LiveGestureConfig)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"config: unknown fields {sorted(unknown)}")
        return LiveGestureConfig(**d)


TINY = LiveGestureConfig(
    name="tiny",
    frontend=FrontendConfig(n_mels=16),
    codebook_size=32, code_dim=8, svq_width=16, svq_latent=16, svq_res_depth=2, svq_head_hidden=16,
    audio_channels=16, audio_dilations=(1, 2), audio_dim=16,
    embed_dim=8, d_model=16, n_heads=2, history=6, audio_window=5,
    expert_blocks=1, expert_cross_layers=1, expert_self_layers=1, ffn_mult=2,
    fuse_blocks=1, fuse_window=7, top_k=8,
)

DEFAULT = LiveGestureConfig()

PAPER = LiveGestureConfig(
    name="paper",
    frontend=FrontendConfig(n_mels=80),
    codebook_size=2048, code_dim=128, svq_width=512, svq_latent=512, svq_res_depth=3, svq_head_hidden=512,
    audio_channels=128, audio_dilations=(1, 2, 4, 8), audio_dim=256,
    embed_dim=128, d_model=256, n_heads=8, history=32, audio_window=32,
    expert_blocks=2, expert_cross_layers=3, expert_self_layers=3, ffn_mult=4,
    fuse_blocks=3, fuse_window=32, top_k=0,
)

CONFIGS = {c.name: c for c in (TINY, DEFAULT, PAPER)}


def get_config(name: str) -> LiveGestureConfig:
    try:
        return CONFIGS[name]
    except KeyError:
        raise ValueError(f"unknown config {name!r}; choose one of {sorted(CONFIGS)}") from None
