"""Motion frames as the streaming loops of both families emit them (``livegesture.stream``,
``livegesture.diffsheg.foppas``), and their stacking into whole-clip arrays (docs/output.md)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Frame:
    index: int
    time_s: float
    poses: np.ndarray        # (165,)
    trans: np.ndarray        # (3,)
    expressions: np.ndarray  # (100,)
    foot_contact: np.ndarray  # (4,)


def frames_to_arrays(frames: list[Frame]) -> dict[str, np.ndarray]:
    if not frames:
        return {"poses": np.zeros((0, 165), np.float32), "trans": np.zeros((0, 3), np.float32),
                "expressions": np.zeros((0, 100), np.float32), "foot_contact": np.zeros((0, 4), np.float32)}
    return {"poses": np.stack([f.poses for f in frames]), "trans": np.stack([f.trans for f in frames]),
            "expressions": np.stack([f.expressions for f in frames]),
            "foot_contact": np.stack([f.foot_contact for f in frames])}
