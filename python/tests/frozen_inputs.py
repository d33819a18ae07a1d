"""Fixed, seeded inputs for the refactor-equivalence tests (``test_refactor_frozen.py``): the
frozen outputs in ``data/frozen_onsets_skeleton.npz`` were computed from them by the code as it was
before the onset detectors, the forward kinematics and the rotation helpers were merged."""
from __future__ import annotations

import numpy as np


def fixed_audio(sr: int, seconds: float = 9.0) -> np.ndarray:
    """Speech-like test signal: syllable-rate bursts of harmonic tones and noise with sharp attacks and
    decays, two silent pauses (speech gating), a low noise floor; float32 like decoded audio."""
    rng = np.random.default_rng(20261125)
    n = int(seconds * sr)
    t = np.arange(n) / sr
    x = rng.normal(0.0, 3e-4, n)
    pos = 0.3
    while pos < seconds - 0.4:
        if 3.0 <= pos < 3.9 or 6.2 <= pos < 7.4:   # pauses
            pos += 0.2
            continue
        dur = rng.uniform(0.08, 0.25)
        i0, i1 = int(pos * sr), int(min(seconds, pos + dur) * sr)
        tt = t[i0:i1] - pos
        f0 = rng.uniform(90, 260)
        env = np.minimum(tt / 0.005, 1.0) * np.exp(-tt / rng.uniform(0.04, 0.15))
        tone = sum(np.sin(2 * np.pi * f0 * k * tt + rng.uniform(0, 6.28)) / k for k in range(1, 6))
        x[i0:i1] += rng.uniform(0.05, 0.4) * env * (tone + rng.uniform(0.0, 1.0) * rng.normal(0, 1, i1 - i0))
        pos += dur + rng.uniform(0.02, 0.2)
    return x.astype(np.float32)


def fixed_poses(frames: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """(frames, 165) axis-angle poses (rotation angles up to ~2.5 rad, some joints exactly zero, one tiny
    rotation that takes the series branch) and (frames, 3) translations."""
    rng = np.random.default_rng(55)
    p = rng.normal(0.0, 0.8, (frames, 165))
    p[:, 66:75] = 0.0
    p[0, 3:6] = 1e-7
    tr = rng.normal(0.0, 0.3, (frames, 3))
    return p, tr
