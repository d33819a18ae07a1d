"""Region features -> BEAT2 motion (SPEC section 8). The Rust runtime (``runtime/src/pipeline.rs``) does the same.

Each region's decoded features are split by the layout of ``livegesture.regions``: rot6d per joint is
decoded to axis-angle into the joint's slot of ``poses`` (55 x 3), lower's translation goes to ``trans``,
face's expressions to ``expressions``; eyes stay at rest (zero axis-angle).
"""
from __future__ import annotations

import numpy as np
import torch

from .regions import N_EXPRESSIONS, N_JOINTS, REGIONS
from .rotation import rot6d_to_axis_angle


def features_to_motion(feats: dict[str, np.ndarray | torch.Tensor]) -> dict[str, np.ndarray]:
    """feats {region: (T, dim)} de-normalised -> dict(poses (T,165), trans (T,3), expressions (T,100),
    foot_contact (T,4)), float32."""
    T = next(iter(feats.values())).shape[0]
    poses = np.zeros((T, N_JOINTS, 3), dtype=np.float32)
    trans = np.zeros((T, 3), dtype=np.float32)
    expr = np.zeros((T, N_EXPRESSIONS), dtype=np.float32)
    contact = np.zeros((T, 4), dtype=np.float32)
    for r in REGIONS:
        f = torch.as_tensor(np.asarray(feats[r.name], dtype=np.float32))
        n = len(r.joints)
        aa = rot6d_to_axis_angle(f[:, :6 * n].reshape(T, n, 6).double()).float().numpy()
        poses[:, list(r.joints)] = aa
        off = 6 * n
        if r.has_trans:
            trans[:] = f[:, off:off + 3].numpy()
            off += 3
        if r.has_contact:
            contact[:] = f[:, off:off + 4].numpy()
            off += 4
        if r.has_expressions:
            expr[:] = f[:, off:off + N_EXPRESSIONS].numpy()
    return {"poses": poses.reshape(T, N_JOINTS * 3), "trans": trans, "expressions": expr, "foot_contact": contact}


def beat2_npz_dict(motion: dict[str, np.ndarray]) -> dict:
    """The exact key set of a BEAT2 motion file (SPEC sections 3 and 8)."""
    return {"poses": np.asarray(motion["poses"], dtype=np.float32),
            "trans": np.asarray(motion["trans"], dtype=np.float32),
            "expressions": np.asarray(motion["expressions"], dtype=np.float32),
            "betas": np.zeros(300, dtype=np.float32),
            "model": np.array("smplx2020"), "gender": np.array("neutral"),
            "mocap_frame_rate": np.array(30, dtype=np.int64)}
