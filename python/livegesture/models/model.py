"""The whole LiveGesture model: audio encoder, one SVQ tokenizer and one eXpert per region (the config's region
set, ``livegesture.regions.model_regions``: the four regions, or one for the full-body SVQ), xAR-Fuse."""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn

from ..config import LiveGestureConfig
from ..regions import compose, model_regions
from .audio_encoder import AudioEncoder
from .expert import RegionExpert
from .fuse import XARFuse
from .svq import SVQ


class LiveGesture(nn.Module):
    family = "livegesture"        # the family registry's name (livegesture.families)

    def __init__(self, cfg: LiveGestureConfig):
        super().__init__()
        self.cfg = cfg
        self.regions = model_regions(cfg)
        self.region_names = tuple(r.name for r in self.regions)
        self.audio_encoder = AudioEncoder(cfg)
        self.svq = nn.ModuleDict({r.name: SVQ(r.name, r.dim, cfg) for r in self.regions})
        self.experts = nn.ModuleDict({r: RegionExpert(r, cfg) for r in self.region_names})
        # xAR-Fuse predicts with the same region classifiers as the eXperts (paper supp. B.2)
        self.fuse = XARFuse(cfg, nn.ModuleList(self.experts[r].classifier for r in self.region_names))

    def components(self) -> dict[str, nn.Module]:
        """Every exported step component by graph name, in manifest order."""
        out = {"audio_encoder": self.audio_encoder}
        out.update({f"expert_{r}": self.experts[r] for r in self.region_names})
        out["fusion"] = self.fuse
        out.update({f"decoder_{r}": self.svq[r] for r in self.region_names})
        return out

    def set_normalisation(self, stats: dict):
        """stats: {'mel': {'mean', 'std'}, region: {'mean', 'std'}} (lists or arrays; regions: the model's, or the
        base regions a composite region is made of)."""
        stats = dict(stats)
        for r in self.regions:
            if r.name not in stats and r.members and all(m in stats for m in r.members):
                stats[r.name] = {k: compose({m: np.asarray(stats[m][k], np.float32) for m in r.members}, (r,))[r.name]
                                 for k in ("mean", "std")}
        with torch.no_grad():
            if "mel" in stats:
                self.audio_encoder.mel_mean.copy_(torch.as_tensor(stats["mel"]["mean"], dtype=torch.float32))
                self.audio_encoder.mel_std.copy_(torch.as_tensor(stats["mel"]["std"], dtype=torch.float32))
            for r in self.region_names:
                if r in stats:
                    self.svq[r].mean.copy_(torch.as_tensor(stats[r]["mean"], dtype=torch.float32))
                    self.svq[r].std.copy_(torch.as_tensor(stats[r]["std"], dtype=torch.float32))

    def normalisation(self) -> dict:
        out = {"mel": {"mean": self.audio_encoder.mel_mean.tolist(), "std": self.audio_encoder.mel_std.tolist()}}
        for r in self.region_names:
            out[r] = {"mean": self.svq[r].mean.tolist(), "std": self.svq[r].std.tolist()}
        return out
