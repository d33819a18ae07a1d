"""The whole DiffSHEG model: speech encoders + UniEG denoiser + the data statistics it was trained with.

Exported graphs (``components()``): ``speech_encoder`` (mel window -> per-frame audio features) and
``denoiser`` (x_t, t, audio, speaker, cond -> eps). Motion is the normalised concatenation of the four
LiveGesture regions in ``MOTION_LAYOUT`` order; de-normalisation (``x * std + mean``) happens outside.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn

from ..regions import REGION_BY_NAME, REGION_NAMES
from .audio import SpeechEncoder
from .config import DiffSHEGConfig
from .denoiser import EXP_DIM, GES_DIM, MOTION_DIM, UniEG

# regions in the order of the motion vector: gesture branch (upper, hands, lower), then expression (face)
MOTION_ORDER = ("upper", "hands", "lower", "face")
assert MOTION_ORDER == REGION_NAMES


def motion_layout() -> list[dict]:
    out, off = [], 0
    for r in MOTION_ORDER:
        out.append({"region": r, "offset": off, "dim": REGION_BY_NAME[r].dim,
                    "branch": "expression" if r == "face" else "gesture"})
        off += REGION_BY_NAME[r].dim
    assert off == MOTION_DIM and MOTION_DIM - EXP_DIM == GES_DIM
    return out


class DiffSHEG(nn.Module):
    family = "diffsheg"

    def __init__(self, cfg: DiffSHEGConfig):
        super().__init__()
        self.cfg = cfg
        self.speech_encoder = SpeechEncoder(cfg)
        self.denoiser = UniEG(cfg)
        self.register_buffer("motion_mean", torch.zeros(MOTION_DIM))
        self.register_buffer("motion_std", torch.ones(MOTION_DIM))
        # BEAT2 speaker number of each style id (index); -1 = unused slot
        self.register_buffer("speaker_numbers", torch.full((cfg.n_speakers,), -1, dtype=torch.int64))

    def components(self) -> dict[str, nn.Module]:
        return {"speech_encoder": self.speech_encoder, "denoiser": self.denoiser}

    def forward(self, mel, x_t, t, speaker, cond):
        """Training: mel (B, 2n, n_mels), x_t (B, n, D), t (B,), speaker (B,), cond (B,) -> eps (B, n, D)."""
        return self.denoiser(x_t, t, self.speech_encoder(mel), speaker, cond)

    # ------------------------------------------------------------------ statistics and style ids
    def set_normalisation(self, stats: dict):
        """stats: {'mel': {'mean','std'}, region: {'mean','std'}} as LiveGesture's."""
        with torch.no_grad():
            if "mel" in stats:
                self.speech_encoder.mel_mean.copy_(torch.as_tensor(stats["mel"]["mean"], dtype=torch.float32))
                self.speech_encoder.mel_std.copy_(torch.as_tensor(stats["mel"]["std"], dtype=torch.float32))
            if all(r in stats for r in MOTION_ORDER):
                self.motion_mean.copy_(torch.as_tensor(np.concatenate([stats[r]["mean"] for r in MOTION_ORDER]),
                                                       dtype=torch.float32))
                self.motion_std.copy_(torch.as_tensor(np.concatenate([stats[r]["std"] for r in MOTION_ORDER]),
                                                      dtype=torch.float32))

    def normalisation(self) -> dict:
        out = {"mel": {"mean": self.speech_encoder.mel_mean.tolist(), "std": self.speech_encoder.mel_std.tolist()}}
        for e in motion_layout():
            sl = slice(e["offset"], e["offset"] + e["dim"])
            out[e["region"]] = {"mean": self.motion_mean[sl].tolist(), "std": self.motion_std[sl].tolist()}
        return out

    def set_speakers(self, numbers: list[int]):
        if len(numbers) > self.cfg.n_speakers:
            raise ValueError(f"diffsheg: {len(numbers)} speakers but the config has {self.cfg.n_speakers} style ids")
        with torch.no_grad():
            self.speaker_numbers.fill_(-1)
            self.speaker_numbers[: len(numbers)] = torch.as_tensor(numbers, dtype=torch.int64)

    def speaker_index(self, beat2_speaker: int) -> int:
        idx = (self.speaker_numbers == int(beat2_speaker)).nonzero()
        if len(idx) == 0:
            raise ValueError(f"diffsheg: BEAT2 speaker {beat2_speaker} was not in training "
                             f"(known: {[int(s) for s in self.speaker_numbers if s >= 0]})")
        return int(idx[0])

    def default_speaker(self) -> int:
        """Style id used when none is given: BEAT2 speaker 2 if trained on, else id 0."""
        try:
            return self.speaker_index(2)
        except ValueError:
            return 0

    def denormalise(self, x: np.ndarray) -> np.ndarray:
        """(..., D) float32 normalised -> features: ``x * std + mean``, two float32 roundings (no FMA)."""
        x = np.asarray(x, dtype=np.float32)
        return (x * self.motion_std.cpu().numpy()) + self.motion_mean.cpu().numpy()
