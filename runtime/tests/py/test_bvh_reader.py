"""`generate -o motion.bvh` read back with an independent BVH reader (the `bvh` package from PyPI):
the hierarchy is the project's skeleton (python/livegesture/skeleton.py: names, parents, rest offsets),
and every joint's rotation equals the npz's axis-angle."""
import subprocess

import numpy as np
import pytest
from bvh import Bvh

from livegesture import skeleton
from livegesture.compare import diff

BOUND = 1e-5  # max abs difference of rotation matrix entries (angles are written with 6 decimals in degrees)


def euler_zxy(z, x, y):
    z, x, y = np.radians([z, x, y])
    rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(x), -np.sin(x)], [0, np.sin(x), np.cos(x)]])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    return rz @ rx @ ry


def rotation_error(mocap, poses):
    """Max abs difference between the BVH's joint rotations (as the reader parses them, per the
    channel order each joint declares) and the npz axis-angle as matrices."""
    want = skeleton.axis_angle_to_matrix_np(poses.reshape(len(poses), 55, 3))
    got_all = np.full_like(want, np.nan)
    for j, name in enumerate(skeleton.JOINT_NAMES):
        chans = [c for c in mocap.joint_channels(name) if c.endswith("rotation")]
        vals = np.array(mocap.frames_joint_channels(name, chans), dtype=np.float64)
        for t in range(len(poses)):
            ang = dict(zip((c[0] for c in chans), vals[t]))
            got = euler_zxy(ang["Z"], ang["X"], ang["Y"]) if [c[0] for c in chans] == ["Z", "X", "Y"] else None
            if got is None:  # a reader-side fallback for any other order: compose in the declared order
                got = np.eye(3)
                for c, a in zip(chans, vals[t]):
                    got = got @ {"X": euler_zxy(0, a, 0), "Y": euler_zxy(0, 0, a), "Z": euler_zxy(a, 0, 0)}[c[0]]
            got_all[t, j] = got
    # the shared comparison: a NaN on either side (or a joint never read) is an infinite error, where
    # `max(worst, nan)` kept `worst`; entries of rotation matrices are <= 1, so the scale is 1
    return diff(got_all, want).max_abs


@pytest.fixture(scope="module")
def outputs(binary, bundle, speech_wav, tmp_path_factory):
    wav, _, _ = speech_wav
    d = tmp_path_factory.mktemp("bvh")
    for out in ("m.bvh", "m.npz"):
        r = subprocess.run([str(binary), "generate", str(wav), "-o", str(d / out), "--seed", "11",
                            "--backend", "tract", "--bundle", str(bundle)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    return (d / "m.bvh").read_text(), np.load(d / "m.npz")


def test_hierarchy_is_the_project_skeleton(outputs):
    text, npz = outputs
    mocap = Bvh(text)
    names = mocap.get_joints_names()
    assert sorted(names) == sorted(skeleton.JOINT_NAMES) and len(names) == 55
    for j, name in enumerate(skeleton.JOINT_NAMES):
        parent = mocap.joint_parent(name)
        p = skeleton.PARENTS[j]
        assert (parent.name if parent is not None else None) == (skeleton.JOINT_NAMES[p] if p >= 0 else None)
        if p >= 0:  # offsets in centimetres
            np.testing.assert_allclose(mocap.joint_offset(name), skeleton.REST_OFFSETS[j] * 100, atol=1e-5)
    assert mocap.nframes == len(npz["poses"])
    assert abs(mocap.frame_time - 1 / 30) < 1e-6


def test_rotations_and_root_translation_equal_the_npz(outputs):
    text, npz = outputs
    mocap = Bvh(text)
    poses = npz["poses"].astype(np.float64)
    err = rotation_error(mocap, poses)
    assert err <= BOUND, err
    pos = np.array(mocap.frames_joint_channels("pelvis", ["Xposition", "Yposition", "Zposition"]), dtype=np.float64)
    # not assert_allclose (equal_nan=True by default): the shared comparison, absolute 1e-3 cm
    d = diff(pos, (npz["trans"] + skeleton.REST_OFFSETS[0]) * 100)
    assert d.max_abs <= 1e-3 and d.within(1e-3), d
    # the check fails on a broken file: one joint's channels declared in another order
    broken = text
    i = broken.index("JOINT left_elbow")
    j = broken.index("CHANNELS 3 Zrotation Xrotation Yrotation", i)
    broken = broken[:j] + "CHANNELS 3 Xrotation Yrotation Zrotation" + broken[j + 40:]
    assert rotation_error(Bvh(broken), poses) > 1e-2


def test_a_nan_rotation_fails_the_check(outputs):
    """issue 38 item 5: one joint's rotation written as nan in one frame. The old fold
    (`max(worst, nan)` keeps `worst`) passed it; the shared comparison fails it."""
    text, npz = outputs
    poses = npz["poses"].astype(np.float64)
    lines = text.split("\n")
    k = lines.index("MOTION") + 4  # a frame line in the middle of the motion
    vals = lines[k].split()
    vals[10] = "nan"
    lines[k] = " ".join(vals)
    broken = Bvh("\n".join(lines))
    worst = 0.0
    for v in [0.0, float("nan"), 0.0]:
        worst = max(worst, v)
    assert worst == 0.0, "premise: max() skips a NaN that comes second"
    assert rotation_error(broken, poses) == float("inf")
