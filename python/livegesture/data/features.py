"""BEAT2 motion <-> per-region feature vectors, and per-region normalisation statistics.

The layout follows :mod:`livegesture.regions` exactly (docs/motion.md):

- upper: joints ``UPPER_JOINTS`` as rot6d                                  (78)
- hands: joints 25..54 as rot6d                                            (180)
- lower: joints ``LOWER_JOINTS`` as rot6d, ``trans`` (3, absolute metres),
  foot contact (4, joints 7, 8, 10, 11)                                    (61)
- face:  jaw (22) rot6d, then the 100 expressions                           (106)

rot6d is the first two ROWS of the rotation matrix (:mod:`livegesture.rotation`). Joint rot6d blocks
appear in the order of the region's joint list.

Foot contact (EMAGE convention): positions come from :func:`livegesture.skeleton.forward_kinematics`;
``contact[t, i] = 1.0`` when foot joint i moves less than ``FOOT_CONTACT_THRESHOLD_M`` (0.01 m) from
frame t to frame t + 1; the last frame repeats the previous frame's value (a single frame is in
contact). :func:`features_to_motion` ignores the contact dims (they are derived quantities).

Inverse: :func:`features_to_motion` decodes rot6d by Gram-Schmidt and returns BEAT2 motion
``poses`` (T, 165), ``trans`` (T, 3), ``expressions`` (T, 100); joints of a region that is not given,
and the eyes (23, 24), are at rest (zero axis-angle); a missing lower region gives ``trans = 0``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import rotation
from ..regions import (FOOT_CONTACT_THRESHOLD_M, FOOT_JOINTS, N_EXPRESSIONS, N_JOINTS, REGION_BY_NAME,
                       REGION_NAMES, REGIONS)
from ..skeleton import forward_kinematics

__all__ = [
    "motion_to_features", "features_to_motion", "foot_contact", "region_parts", "NormStats",
    "compute_norm_stats", "RunningStats",
]


def _as_motion(poses, trans, expressions):
    poses = np.asarray(poses)
    trans = np.asarray(trans)
    expressions = np.asarray(expressions)
    if poses.ndim != 2 or poses.shape[1] != 3 * N_JOINTS:
        raise ValueError(f"poses must be (T, {3 * N_JOINTS}), got {poses.shape}")
    T = poses.shape[0]
    if trans.shape != (T, 3):
        raise ValueError(f"trans must be ({T}, 3), got {trans.shape}")
    if expressions.shape != (T, N_EXPRESSIONS):
        raise ValueError(f"expressions must be ({T}, {N_EXPRESSIONS}), got {expressions.shape}")
    return poses, trans, expressions


def foot_contact(poses: np.ndarray, trans: np.ndarray,
                 threshold: float = FOOT_CONTACT_THRESHOLD_M) -> np.ndarray:
    """(T, 165), (T, 3) -> (T, 4) float32 contact of joints 7, 8, 10, 11 (1.0 = in contact)."""
    poses = np.asarray(poses)
    T = poses.shape[0]
    if T == 0:
        return np.zeros((0, len(FOOT_JOINTS)), dtype=np.float32)
    joints = forward_kinematics(poses, trans)[:, list(FOOT_JOINTS)]
    if T == 1:
        return np.ones((1, len(FOOT_JOINTS)), dtype=np.float32)
    moved = np.linalg.norm(joints[1:] - joints[:-1], axis=-1)
    c = (moved < threshold).astype(np.float32)
    return np.concatenate([c, c[-1:]], axis=0)


def motion_to_features(poses: np.ndarray, trans: np.ndarray, expressions: np.ndarray,
                       contact: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """BEAT2 motion -> {region: (T, dim) float32}. ``contact`` (T, 4) overrides the computed contact."""
    poses, trans, expressions = _as_motion(poses, trans, expressions)
    T = poses.shape[0]
    r6 = rotation.np_axis_angle_to_rot6d(poses.reshape(T, N_JOINTS, 3))  # (T, 55, 6) float64
    if contact is None:
        contact = foot_contact(poses, trans)
    elif contact.shape != (T, len(FOOT_JOINTS)):
        raise ValueError(f"contact must be ({T}, {len(FOOT_JOINTS)}), got {contact.shape}")
    out = {}
    for r in REGIONS:
        parts = [r6[:, list(r.joints)].reshape(T, -1)]
        if r.has_trans:
            parts.append(np.asarray(trans, dtype=np.float64))
        if r.has_contact:
            parts.append(np.asarray(contact, dtype=np.float64))
        if r.has_expressions:
            parts.append(np.asarray(expressions, dtype=np.float64))
        f = np.concatenate(parts, axis=1).astype(np.float32)
        assert f.shape[1] == r.dim
        out[r.name] = f
    return out


def region_parts(name: str, feats: np.ndarray) -> dict[str, np.ndarray]:
    """Split one region's (..., dim) features into ``rot6d`` (..., J, 6) and, where the region has them,
    ``trans`` (..., 3), ``contact`` (..., 4), ``expressions`` (..., 100)."""
    r = REGION_BY_NAME[name]
    feats = np.asarray(feats)
    if feats.shape[-1] != r.dim:
        raise ValueError(f"region {name!r}: features must end in {r.dim}, got {feats.shape}")
    nj = len(r.joints)
    out = {"rot6d": feats[..., :6 * nj].reshape(feats.shape[:-1] + (nj, 6))}
    off = 6 * nj
    if r.has_trans:
        out["trans"] = feats[..., off:off + 3]
        off += 3
    if r.has_contact:
        out["contact"] = feats[..., off:off + len(FOOT_JOINTS)]
        off += len(FOOT_JOINTS)
    if r.has_expressions:
        out["expressions"] = feats[..., off:off + N_EXPRESSIONS]
        off += N_EXPRESSIONS
    return out


def features_to_motion(region_feats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{region: (..., T, dim)} (any subset of the regions, un-normalised) -> BEAT2 motion
    ``poses`` (..., T, 165), ``trans`` (..., T, 3), ``expressions`` (..., T, 100), all float32."""
    unknown = set(region_feats) - set(REGION_NAMES)
    if unknown:
        raise ValueError(f"features_to_motion: unknown regions {sorted(unknown)}")
    if not region_feats:
        raise ValueError("features_to_motion: no region given")
    lead = None
    for name, f in region_feats.items():
        shp = np.shape(f)[:-1]
        if lead is None:
            lead = shp
        elif shp != lead:
            raise ValueError(f"features_to_motion: region {name!r} has leading shape {shp}, expected {lead}")
    poses = np.zeros(lead + (N_JOINTS, 3), dtype=np.float64)
    trans = np.zeros(lead + (3,), dtype=np.float64)
    expressions = np.zeros(lead + (N_EXPRESSIONS,), dtype=np.float64)
    for name, f in region_feats.items():
        r = REGION_BY_NAME[name]
        parts = region_parts(name, np.asarray(f, dtype=np.float64))
        poses[..., list(r.joints), :] = rotation.np_rot6d_to_axis_angle(parts["rot6d"])
        if r.has_trans:
            trans = parts["trans"].copy()
        if r.has_expressions:
            expressions = parts["expressions"].copy()
    return {
        "poses": poses.reshape(lead + (3 * N_JOINTS,)).astype(np.float32),
        "trans": trans.astype(np.float32),
        "expressions": expressions.astype(np.float32),
    }


# ----------------------------------------------------------------------------- normalisation

class RunningStats:
    """Accumulates per-region sums in float64 (Chan's parallel update) to compute mean and std."""

    def __init__(self):
        self.n: dict[str, int] = {}
        self.mean: dict[str, np.ndarray] = {}
        self.m2: dict[str, np.ndarray] = {}

    def update(self, feats: dict[str, np.ndarray]):
        for name, f in feats.items():
            x = np.asarray(f, dtype=np.float64).reshape(-1, np.shape(f)[-1])
            if len(x) == 0:
                continue
            nb, mb = len(x), x.mean(0)
            m2b = ((x - mb) ** 2).sum(0)
            if name not in self.n:
                self.n[name], self.mean[name], self.m2[name] = nb, mb, m2b
                continue
            na, ma = self.n[name], self.mean[name]
            n = na + nb
            d = mb - ma
            self.mean[name] = ma + d * nb / n
            self.m2[name] = self.m2[name] + m2b + d * d * na * nb / n
            self.n[name] = n

    def finish(self, std_floor: float = 1e-3) -> "NormStats":
        if not self.n:
            raise ValueError("normalisation statistics: no frames were seen")
        mean = {k: self.mean[k].astype(np.float32) for k in self.n}
        std = {k: np.maximum(np.sqrt(self.m2[k] / self.n[k]), std_floor).astype(np.float32) for k in self.n}
        return NormStats(mean=mean, std=std, n_frames=dict(self.n), std_floor=std_floor)


@dataclass
class NormStats:
    """Per-region mean and std (float32). ``normalize``: (x - mean) / std; ``denormalize`` inverts it.
    Saved as JSON (``save``/``load``); ``to_dict`` is what goes into a manifest."""
    mean: dict[str, np.ndarray]
    std: dict[str, np.ndarray]
    n_frames: dict[str, int] = field(default_factory=dict)
    std_floor: float = 1e-3
    source: str = ""

    def normalize(self, feats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: ((np.asarray(v, dtype=np.float32) - self.mean[k]) / self.std[k]).astype(np.float32)
                for k, v in feats.items()}

    def denormalize(self, feats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {k: (np.asarray(v, dtype=np.float32) * self.std[k] + self.mean[k]).astype(np.float32)
                for k, v in feats.items()}

    def to_dict(self) -> dict:
        return {
            "regions": {k: {"mean": [float(x) for x in self.mean[k]], "std": [float(x) for x in self.std[k]],
                            "n_frames": int(self.n_frames.get(k, 0))} for k in self.mean},
            "std_floor": float(self.std_floor),
            "source": self.source,
        }

    @staticmethod
    def from_dict(d: dict) -> "NormStats":
        try:
            regs = d["regions"]
            mean = {k: np.asarray(v["mean"], dtype=np.float32) for k, v in regs.items()}
            std = {k: np.asarray(v["std"], dtype=np.float32) for k, v in regs.items()}
            n = {k: int(v.get("n_frames", 0)) for k, v in regs.items()}
        except (KeyError, TypeError, AttributeError) as e:
            raise ValueError(f"normalisation statistics: malformed dictionary ({e!r})") from None
        for k in mean:
            if k not in REGION_BY_NAME:
                raise ValueError(f"normalisation statistics: unknown region {k!r}")
            dim = REGION_BY_NAME[k].dim
            if mean[k].shape != (dim,) or std[k].shape != (dim,):
                raise ValueError(f"normalisation statistics: region {k!r} needs {dim} values, "
                                 f"got mean {mean[k].shape} std {std[k].shape}")
            if not (np.isfinite(mean[k]).all() and np.isfinite(std[k]).all() and (std[k] > 0).all()):
                raise ValueError(f"normalisation statistics: region {k!r} has non-finite or non-positive values")
        return NormStats(mean=mean, std=std, n_frames=n, std_floor=float(d.get("std_floor", 1e-3)),
                         source=str(d.get("source", "")))

    def save(self, path: str | Path):
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @staticmethod
    def load(path: str | Path) -> "NormStats":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: normalisation statistics file not found") from None
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not valid JSON ({e})") from None
        try:
            return NormStats.from_dict(d)
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None


def compute_norm_stats(feature_dicts, std_floor: float = 1e-3) -> NormStats:
    """Mean/std over all frames of an iterable of {region: (T, dim)} feature dicts."""
    rs = RunningStats()
    for f in feature_dicts:
        rs.update(f)
    return rs.finish(std_floor)
