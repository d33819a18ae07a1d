"""SMPL-X body regions (EMAGE masks, as the LiveGesture paper uses them) and the motion layout.

A BEAT2 frame is ``poses`` (55 joints x 3 axis-angle), ``trans`` (3) and ``expressions`` (100).
Each region's feature vector is laid out as follows (docs/motion.md):

- upper: 13 joints x rot6d                                   = 78
- hands: 30 joints x rot6d                                   = 180
- lower: 9 joints x rot6d, translation (3), foot contact (4)  = 61
- face:  jaw rot6d (6), expressions (100)                    = 106

Eyes (joints 23, 24) belong to no region and are output at rest.
The order of ``REGIONS`` is the region order everywhere: graphs, manifest, sampler, Rust.

A model's regions are a **region set** (the config's ``regions`` field, :func:`model_regions`):
``per-region`` (the four above, the paper's compositional SVQ) or ``full-body`` (one region, ``body``, whose
feature vector is the four regions' features side by side in region order, 425 dims: the full-body SVQ of the
paper's Table 6, supp. I). A region made of others (``members``) is composed from their features
(:func:`compose`) and split back into them (:func:`split`); the data pipeline, the statistics and the
SMPL-X assembly work on the four base regions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
    members: tuple[str, ...] = ()  # a region made of base regions' features side by side, in this order

    @property
    def base(self) -> tuple[str, ...]:
        """The base regions whose features this region's vector holds, in order."""
        return self.members or (self.name,)


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

# the full-body SVQ's one region (Table 6, supp. I): every base region's features side by side
BODY = Region("body", tuple(j for r in REGIONS for j in r.joints), sum(r.dim for r in REGIONS), has_trans=True,
              has_contact=True, has_expressions=True, members=REGION_NAMES)

REGION_SETS: dict[str, tuple[Region, ...]] = {"per-region": REGIONS, "full-body": (BODY,)}
_COMPOSITE = {r.name: r for rs in REGION_SETS.values() for r in rs if r.members}


def model_regions(cfg) -> tuple[Region, ...]:
    """The regions of a model config (its ``regions`` field; configs without one: the four base regions)."""
    name = getattr(cfg, "regions", "per-region")
    try:
        return REGION_SETS[name]
    except KeyError:
        raise ValueError(f"config: regions {name!r}: expected one of {', '.join(REGION_SETS)}") from None


def compose(base: dict, regions) -> dict:
    """``{base region: (..., dim)}`` -> ``{region: (..., dim)}`` for ``regions`` (a composite region's vector is
    its members' side by side; numpy arrays or torch tensors, concatenated on the last axis)."""
    out = {}
    for r in regions:
        parts = [base[m] for m in r.base]
        if len(parts) == 1:
            out[r.name] = parts[0]
        elif isinstance(parts[0], np.ndarray):
            out[r.name] = np.concatenate(parts, -1)
        else:
            import torch
            out[r.name] = torch.cat(parts, -1)
    return out


def split(feats: dict) -> dict:
    """The inverse of :func:`compose`: every composite region's vector (``body``) cut into its base regions'
    (on the last axis); base regions are passed through."""
    out = {}
    for name, v in feats.items():
        r = _COMPOSITE.get(name)
        if r is None:
            out[name] = v
            continue
        if v.shape[-1] != r.dim:
            raise ValueError(f"region {name!r}: {v.shape[-1]} features, expected {r.dim}")
        off = 0
        for m in r.members:
            d = REGION_BY_NAME[m].dim
            out[m] = v[..., off:off + d]
            off += d
    return out


def frame_start_sample(k: int, sample_rate: int = SAMPLE_RATE, fps: int = FPS) -> int:
    """First audio sample of motion frame k: ``k * sample_rate // fps`` (integer arithmetic, no drift)."""
    return k * sample_rate // fps


def token_end_sample(t: int, sample_rate: int = SAMPLE_RATE, fps: int = FPS) -> int:
    """One past the last audio sample of token t (frames 4t..4t+3)."""
    return frame_start_sample(FRAMES_PER_TOKEN * (t + 1), sample_rate, fps)


def _base_parts(r: Region, off: int) -> list[dict]:
    parts = [{"name": "rot6d", "joints": list(r.joints), "offset": off, "dim": 6 * len(r.joints)}]
    off += 6 * len(r.joints)
    if r.has_trans:
        parts.append({"name": "trans", "offset": off, "dim": 3})
        off += 3
    if r.has_contact:
        parts.append({"name": "foot_contact", "joints": list(FOOT_JOINTS), "offset": off, "dim": 4})
        off += 4
    if r.has_expressions:
        parts.append({"name": "expressions", "offset": off, "dim": N_EXPRESSIONS})
    return parts


def region_layout(regions=REGIONS) -> list[dict]:
    """The region table as written to the manifest (a composite region: its members' parts one after the
    other, a ``rot6d`` part per member)."""
    out = []
    for r in regions:
        parts, off = [], 0
        for m in r.base:
            parts += _base_parts(REGION_BY_NAME[m], off)
            off += REGION_BY_NAME[m].dim
        assert off == r.dim, (r.name, off)
        out.append({"name": r.name, "dim": r.dim, "joints": list(r.joints), "parts": parts})
    return out
