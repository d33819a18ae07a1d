"""SMPL-X body regions (EMAGE masks, as the LiveGesture paper uses them) and the motion layout.

A BEAT2 frame is ``poses`` (55 joints x 3 axis-angle), ``trans`` (3) and ``expressions`` (100).
Each region's feature vector is laid out as follows (docs/motion.md):

- upper: 13 joints x rot6d                                   = 78
- hands: 30 joints x rot6d                                   = 180
- lower: 9 joints x rot6d, translation (3), foot contact (4)  = 61
- face:  jaw rot6d (6), expressions (100)                    = 106

Eyes (joints 23, 24) belong to no region and are output at rest.
The order of ``REGIONS`` is the region order everywhere: graphs, manifest, sampler, Rust.
"""
from __future__ import annotations

from dataclasses import dataclass

FPS = 30
SAMPLE_RATE = 16000
FRAMES_PER_TOKEN = 4
N_JOINTS = 55
N_EXPRESSIONS = 100

UPPER_JOINTS = (3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21)
HANDS_JOINTS = tuple(range(25, 55))
LOWER_JOINTS = (0, 1, 2, 4, 5, 7, 8, 10, 11)
JAW_JOINT = 22
EYE_JOINTS = (23, 24)
FOOT_JOINTS = (7, 8, 10, 11)
FOOT_CONTACT_THRESHOLD_M = 0.01


@dataclass(frozen=True)
class Region:
    name: str
    joints: tuple[int, ...]  # joints whose rot6d come first in the feature vector
    dim: int
    has_trans: bool = False
    has_contact: bool = False
    has_expressions: bool = False


REGIONS: tuple[Region, ...] = (
    Region("upper", UPPER_JOINTS, 78),
    Region("hands", HANDS_JOINTS, 180),
    Region("lower", LOWER_JOINTS, 61, has_trans=True, has_contact=True),
    Region("face", (JAW_JOINT,), 106, has_expressions=True),
)
REGION_NAMES = tuple(r.name for r in REGIONS)
REGION_BY_NAME = {r.name: r for r in REGIONS}

for _r in REGIONS:
    _d = 6 * len(_r.joints) + 3 * _r.has_trans + 4 * _r.has_contact + N_EXPRESSIONS * _r.has_expressions
    assert _d == _r.dim, (_r.name, _d)


def frame_start_sample(k: int, sample_rate: int = SAMPLE_RATE, fps: int = FPS) -> int:
    """First audio sample of motion frame k: ``k * sample_rate // fps`` (integer arithmetic, no drift)."""
    return k * sample_rate // fps


def token_end_sample(t: int, sample_rate: int = SAMPLE_RATE, fps: int = FPS) -> int:
    """One past the last audio sample of token t (frames 4t..4t+3)."""
    return frame_start_sample(FRAMES_PER_TOKEN * (t + 1), sample_rate, fps)


def region_layout() -> list[dict]:
    """The region table as written to the manifest."""
    out = []
    for r in REGIONS:
        parts = [{"name": "rot6d", "joints": list(r.joints), "offset": 0, "dim": 6 * len(r.joints)}]
        off = 6 * len(r.joints)
        if r.has_trans:
            parts.append({"name": "trans", "offset": off, "dim": 3})
            off += 3
        if r.has_contact:
            parts.append({"name": "foot_contact", "joints": list(FOOT_JOINTS), "offset": off, "dim": 4})
            off += 4
        if r.has_expressions:
            parts.append({"name": "expressions", "offset": off, "dim": N_EXPRESSIONS})
            off += N_EXPRESSIONS
        out.append({"name": r.name, "dim": r.dim, "joints": list(r.joints), "parts": parts})
    return out
