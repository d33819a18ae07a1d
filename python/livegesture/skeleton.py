"""The project's own SMPL-X-like skeleton and forward kinematics.

The licensed SMPL-X model files cannot ship with the project, so joint positions (foot contact, Beat
Consistency, any position-based metric) come from a fixed kinematic tree defined here:

- the standard SMPL-X joint order and parent list (55 joints: 0 pelvis ... 21 right wrist, 22 jaw,
  23/24 eyes, 25-39 left hand, 40-54 right hand);
- rest offsets in metres chosen by hand to resemble an adult SMPL-X neutral body in its rest T-pose
  (Y up, the body faces +Z, the character's left is +X). They are plausible, not the official template.

Conventions (the same as SMPL-X with betas = 0 and no pose blend shapes):

- ``poses[..., 3j:3j+3]`` is joint j's axis-angle rotation relative to its parent; joint 0's is the
  global orientation;
- the root (pelvis) sits at ``trans + REST_OFFSETS[0]``; ``REST_OFFSETS[0]`` puts the pelvis 0.95 m
  above the origin so that with ``trans = 0`` and the rest pose the soles touch ``y = 0`` (roughly; the
  ankle joint rests 0.08 m above the ground). Real BEAT2 ``trans`` values have their own origin; every
  velocity-based quantity is independent of it;
- ``global_rot[j] = global_rot[parent[j]] @ R(poses[j])`` and
  ``joint[j] = joint[parent[j]] + global_rot[parent[j]] @ REST_OFFSETS[j]``.

With a user-supplied SMPL-X model, the official joint regressor can replace this skeleton for the
official evaluation setting; nothing else in the project depends on the exact offsets.

Public API: ``N_JOINTS``, ``PARENTS``, ``JOINT_NAMES``, ``REST_OFFSETS``, ``rest_joints()``,
``axis_angle_to_matrix_np``, ``forward_kinematics`` (numpy) and ``forward_kinematics_torch``.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

N_JOINTS = 55

PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
)

_FINGERS = ("index", "middle", "pinky", "ring", "thumb")
JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw",
    "left_eye_smplhf", "right_eye_smplhf",
) + tuple(f"{side}_{f}{k}" for side in ("left", "right") for f in _FINGERS for k in (1, 2, 3))

# Offsets from the parent joint, metres, left side (+X). Right-side joints mirror X.
_LEFT_HAND = {
    # finger: (proximal offset from wrist, middle offset, distal offset)
    "index": ((0.090, -0.004, 0.026), (0.036, -0.002, 0.000), (0.025, -0.002, 0.000)),
    "middle": ((0.095, -0.002, 0.004), (0.038, -0.002, 0.000), (0.027, -0.002, 0.000)),
    "pinky": ((0.078, -0.008, -0.036), (0.022, -0.002, 0.000), (0.019, -0.002, 0.000)),
    "ring": ((0.088, -0.005, -0.017), (0.033, -0.002, 0.000), (0.025, -0.002, 0.000)),
    "thumb": ((0.030, -0.015, 0.028), (0.028, -0.006, 0.020), (0.024, -0.002, 0.014)),
}


def _build_offsets() -> np.ndarray:
    off = np.zeros((N_JOINTS, 3), dtype=np.float64)
    body = {
        0: (0.0, 0.95, 0.0),        # pelvis (absolute, at trans = 0)
        1: (0.062, -0.090, -0.005),  # left hip
        2: (-0.062, -0.090, -0.005),
        3: (0.0, 0.110, -0.015),     # spine1
        4: (0.035, -0.380, 0.005),   # left knee
        5: (-0.035, -0.380, 0.005),
        6: (0.0, 0.130, 0.005),      # spine2
        7: (-0.010, -0.400, -0.040),  # left ankle
        8: (0.010, -0.400, -0.040),
        9: (0.0, 0.055, 0.025),      # spine3
        10: (0.020, -0.055, 0.120),  # left foot (ball of the foot)
        11: (-0.020, -0.055, 0.120),
        12: (0.0, 0.215, -0.035),    # neck
        13: (0.075, 0.120, -0.020),  # left collar
        14: (-0.075, 0.120, -0.020),
        15: (0.0, 0.090, 0.050),     # head
        16: (0.110, 0.035, -0.010),  # left shoulder
        17: (-0.110, 0.035, -0.010),
        18: (0.260, -0.012, -0.020),  # left elbow
        19: (-0.260, -0.012, -0.020),
        20: (0.252, 0.008, 0.000),   # left wrist
        21: (-0.252, 0.008, 0.000),
        22: (0.0, -0.010, 0.030),    # jaw
        23: (0.032, 0.060, 0.090),   # left eye
        24: (-0.032, 0.060, 0.090),
    }
    for j, v in body.items():
        off[j] = v
    for side, base in ((1.0, 25), (-1.0, 40)):
        for fi, f in enumerate(_FINGERS):
            for k in range(3):
                x, y, z = _LEFT_HAND[f][k]
                off[base + 3 * fi + k] = (side * x, y, z)
    return off


REST_OFFSETS: np.ndarray = _build_offsets()
REST_OFFSETS.setflags(write=False)


def rest_joints() -> np.ndarray:
    """(55, 3) joint positions of the rest pose with ``trans = 0``."""
    return forward_kinematics(np.zeros(3 * N_JOINTS))


def axis_angle_to_matrix_np(aa: np.ndarray) -> np.ndarray:
    """(..., 3) axis-angle -> (..., 3, 3) rotation matrices, float64 (scipy's ``Rotation.from_rotvec``)."""
    aa = np.asarray(aa, dtype=np.float64)
    flat = aa.reshape(-1, 3)
    if len(flat) == 0:
        return np.zeros(aa.shape[:-1] + (3, 3))
    return Rotation.from_rotvec(flat).as_matrix().reshape(aa.shape[:-1] + (3, 3))


def _check(poses, trans):
    if poses.shape[-1] != 3 * N_JOINTS:
        raise ValueError(f"forward_kinematics: poses must end in {3 * N_JOINTS}, got {poses.shape}")
    if trans.shape[-1] != 3 or trans.shape[:-1] != poses.shape[:-1]:
        raise ValueError(f"forward_kinematics: trans {trans.shape} does not match poses {poses.shape}")


def _chain(R, trans, offsets, stack):
    """The kinematic chain, written once for numpy and torch: local rotations R (..., 55, 3, 3), trans
    (..., 3), rest offsets (55, 3) -> (joints (..., 55, 3), global rotations (..., 55, 3, 3)), with
    ``global_rot[j] = global_rot[parent] @ R[j]`` and ``joint[j] = joint[parent] + global_rot[parent] @
    offset[j]`` (the root at ``trans + offset[0]``). ``stack(list, axis)`` joins the per-joint arrays."""
    G: list = [None] * N_JOINTS
    J: list = [None] * N_JOINTS
    for j in range(N_JOINTS):
        p = PARENTS[j]
        if p < 0:
            G[j] = R[..., j, :, :]
            J[j] = trans + offsets[j]
        else:
            G[j] = G[p] @ R[..., j, :, :]
            J[j] = J[p] + G[p] @ offsets[j]
    return stack(J, -2), stack(G, -3)


def forward_kinematics(poses: np.ndarray, trans: np.ndarray | None = None,
                       return_rotations: bool = False):
    """Joint positions of the project skeleton.

    poses (..., 165) axis-angle, trans (..., 3) metres (None = zeros) -> joints (..., 55, 3) float64.
    With ``return_rotations`` also returns the global rotations (..., 55, 3, 3).
    """
    poses = np.asarray(poses, dtype=np.float64)
    trans = np.zeros(poses.shape[:-1] + (3,)) if trans is None else np.asarray(trans, dtype=np.float64)
    _check(poses, trans)
    R = axis_angle_to_matrix_np(poses.reshape(poses.shape[:-1] + (N_JOINTS, 3)))
    J, G = _chain(R, trans, REST_OFFSETS, lambda xs, axis: np.stack(xs, axis=axis))
    return (J, G) if return_rotations else J


def forward_kinematics_torch(poses, trans=None):
    """Differentiable torch version of :func:`forward_kinematics` (the same chain):
    (..., 165), (..., 3) -> (..., 55, 3), in the dtype and on the device of ``poses``."""
    import torch

    from .rotation import axis_angle_to_matrix

    if trans is None:
        trans = torch.zeros(poses.shape[:-1] + (3,), dtype=poses.dtype, device=poses.device)
    _check(poses, trans)
    R = axis_angle_to_matrix(poses.reshape(poses.shape[:-1] + (N_JOINTS, 3)))
    off = torch.as_tensor(np.array(REST_OFFSETS), dtype=poses.dtype, device=poses.device)
    J, _ = _chain(R, trans, off, lambda xs, axis: torch.stack(xs, dim=axis))
    return J
