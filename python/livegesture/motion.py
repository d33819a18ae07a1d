"""Region features -> output frames (docs/output.md). The Rust runtime (``runtime/src/pipeline.rs``) does the same.

Each region's decoded features are split by the layout of ``livegesture.regions`` (see
``livegesture.data.features``): rot6d per joint is decoded to axis-angle into the joint's slot of ``poses``
(55 x 3), lower's translation goes to ``trans``, face's expressions to ``expressions``; eyes stay at rest. A
composite region (the full-body SVQ's ``body``) is first cut into its base regions (``livegesture.regions.split``).
"""
from __future__ import annotations

import numpy as np

from .data.features import features_to_motion as _features_to_motion
from .data.features import region_parts
from .regions import split


def features_to_motion(feats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """feats {region: (T, dim)} de-normalised -> dict(poses (T,165), trans (T,3), expressions (T,100),
    foot_contact (T,4)), float32."""
    feats = split({k: np.asarray(v, dtype=np.float32) for k, v in feats.items()})
    out = _features_to_motion(feats)
    out["foot_contact"] = np.asarray(region_parts("lower", np.asarray(feats["lower"]))["contact"], dtype=np.float32)
    return out


def beat2_npz_dict(motion: dict[str, np.ndarray]) -> dict:
    """The exact key set of a BEAT2 motion file (docs/data.md and docs/output.md)."""
    return {"poses": np.asarray(motion["poses"], dtype=np.float32),
            "trans": np.asarray(motion["trans"], dtype=np.float32),
            "expressions": np.asarray(motion["expressions"], dtype=np.float32),
            "betas": np.zeros(300, dtype=np.float32),
            "model": np.array("smplx2020"), "gender": np.array("neutral"),
            "mocap_frame_rate": np.array(30, dtype=np.int64)}
