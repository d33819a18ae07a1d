"""Blinks: a seeded process (no audio), the same on every door (Python here, Rust in runtime/src/face/).

The stream's seed drives its own SplitMix64 (:class:`livegesture.sampling.SplitMix64`) seeded with
``seed XOR SALT``. The first blink starts at frame ``first_lo + floor(u * (first_hi - first_lo + 1))``; each
blink lasts ``duration`` frames with weight ``sin(pi * (k + 1) / (duration + 1))`` at its k-th frame, applied to
``eyeBlinkLeft`` and ``eyeBlinkRight``; the next starts ``gap_lo + floor(u * (gap_hi - gap_lo + 1))`` frames
after this one started (u: the generator's next float in [0, 1)). About 17 blinks a minute, a human resting
rate while talking.
"""
from __future__ import annotations

import math

import numpy as np

from ..sampling import SplitMix64

SALT = 0xB11CB11CB11CB11C
BLINK = {"prng": "SplitMix64(seed ^ 0xB11CB11CB11CB11C)", "first_lo": 15, "first_hi": 90, "gap_lo": 60,
         "gap_hi": 150, "duration": 7, "shape": "sin(pi * (k + 1) / (duration + 1))",
         "shapes": ["eyeBlinkLeft", "eyeBlinkRight"]}


class Blinker:
    def __init__(self, seed: int):
        self.rng = SplitMix64((int(seed) ^ SALT) & ((1 << 64) - 1))
        self.next_start = self._draw(BLINK["first_lo"], BLINK["first_hi"])
        self.frame = 0

    def _draw(self, lo: int, hi: int) -> int:
        return lo + int(math.floor(self.rng.next_f64() * (hi - lo + 1)))

    def next(self) -> float:
        """The blink weight of the next frame (frames in order from 0)."""
        k = self.frame - self.next_start
        D = BLINK["duration"]
        w = 0.0
        if 0 <= k < D:
            w = math.sin(math.pi * (k + 1) / (D + 1))
        if k == D - 1:
            self.next_start += self._draw(BLINK["gap_lo"], BLINK["gap_hi"])
        self.frame += 1
        return w


def blinks(seed: int, n_frames: int) -> np.ndarray:
    b = Blinker(seed)
    return np.array([b.next() for _ in range(n_frames)], dtype=np.float32)
