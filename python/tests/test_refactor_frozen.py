"""The merged onset detector, forward kinematics and scipy rotations give the results of the code they
replaced (``eval/metrics.py`` and ``data/synth.py`` each had an onset detector, ``skeleton.py`` two FK
walks, ``skeleton.py`` and ``data/synth.py`` hand-written Rodrigues and Euler matrices).

``data/frozen_onsets_skeleton.npz`` holds that code's outputs on the fixed inputs of ``frozen_inputs.py``,
written by ``python/tools/make_frozen_refactor_outputs.py`` at commit 2f21d8d, before the merge. Onset times
and the synthetic corpus' analysis must match bit for bit; the envelope of ``metrics.onset_strength``
(now ``|X|^2`` instead of ``re^2 + im^2``) to 1e-12, the forward kinematics to 1e-9 and the synthetic
motion (float32, through the scipy rotations) to 1e-6 (it is bit-identical on this input).

The synthetic analysis' continuous values (the energy envelope, the onset envelope and onset strengths) are
compared to 1e-12, not bit for bit: numpy's SIMD reductions round differently on other CPUs (an AVX-512 AMD
EPYC, CPU family 26, gives 1 ulp, 1.1e-16, on the onset envelope and strengths; an AVX2-only AMD EPYC 3.9e-16 on
the energy envelope), while everything discrete (onset times, activity, phrase starts) and f0 stay exact.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frozen_inputs import fixed_audio, fixed_poses
from livegesture import onsets, skeleton
from livegesture.data import synth_motion, synth_speech
from livegesture.eval import metrics as M

FROZEN = Path(__file__).parent / "data" / "frozen_onsets_skeleton.npz"


@pytest.fixture(scope="module")
def frozen():
    return dict(np.load(FROZEN))


@pytest.fixture(scope="module")
def audio16():
    return fixed_audio(16000)


def _exact(got, want, name):
    got = np.asarray(got)
    assert got.shape == want.shape, f"{name}: shape {got.shape} != {want.shape}"
    assert got.dtype == want.dtype, f"{name}: dtype {got.dtype} != {want.dtype}"
    assert np.array_equal(got, want), f"{name}: differs, max |d| {np.abs(got - want).max()}"


def test_eval_onsets_are_the_old_ones(frozen, audio16):
    assert len(frozen["metrics_onsets_16k"]) > 10
    _exact(M.detect_onsets(audio16, 16000), frozen["metrics_onsets_16k"], "16 kHz")
    _exact(M.detect_onsets(fixed_audio(22050), 22050), frozen["metrics_onsets_22k"], "22.05 kHz")
    _exact(M.detect_onsets(audio16, 16000, log_gain=None), frozen["metrics_onsets_16k_db"], "dB")
    env, times = M.onset_strength(audio16, 16000)
    _exact(times, frozen["metrics_env_times_16k"], "envelope times")
    np.testing.assert_allclose(env, frozen["metrics_env_16k"], rtol=0, atol=1e-12)


def test_synth_analysis_is_the_old_one(frozen, audio16):
    an = synth_motion.analyse_audio(audio16)
    for k in ("times", "active", "f0", "onsets", "phrase_start"):
        _exact(getattr(an, k), frozen["synth_" + k], k)
    for k in ("env", "onset_env", "onset_strength"):   # float reductions: CPU-dependent rounding (docstring)
        got, want = np.asarray(getattr(an, k)), frozen["synth_" + k]
        assert got.shape == want.shape and got.dtype == want.dtype, k
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12, err_msg=k)
    _exact(synth_motion.onset_times(audio16), frozen["synth_onset_times"], "onset_times")
    # the fixture exercises the phrase logic and the speech gate
    assert frozen["synth_phrase_start"].any() and not frozen["synth_active"].all()


def test_synth_motion_is_the_old_one(frozen, audio16):
    an = synth_motion.analyse_audio(audio16)
    poses, trans, _ = synth_motion.generate_motion(an, 150, synth_speech.STYLE_BY_SPEAKER[2],
                                                   np.random.default_rng(7))
    np.testing.assert_allclose(poses, frozen["synth_poses"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(trans, frozen["synth_trans"], rtol=0, atol=1e-6)


def test_forward_kinematics_is_the_old_one(frozen):
    p, tr = fixed_poses()
    J, G = skeleton.forward_kinematics(p, tr, return_rotations=True)
    np.testing.assert_allclose(J, frozen["fk_joints"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(G, frozen["fk_rots"], rtol=0, atol=1e-9)
    _exact(skeleton.rest_joints(), frozen["rest_joints"], "rest joints")
    torch = pytest.importorskip("torch")
    Jt = skeleton.forward_kinematics_torch(torch.tensor(p), torch.tensor(tr)).numpy()
    np.testing.assert_allclose(Jt, frozen["fk_joints"], rtol=0, atol=1e-9)


def test_rotation_conventions():
    a = np.array([0.3, -1.2, 2.9])
    c, s = np.cos(a), np.sin(a)
    rx = np.zeros((3, 3, 3))
    rx[:, 0, 0] = 1
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2] = c, -s, s, c
    np.testing.assert_allclose(synth_motion._rx(a), rx, atol=1e-12)
    x, y, z = np.array([0.1, 2.0]), np.array([-0.7, 0.4]), 1.3  # scalars broadcast
    np.testing.assert_allclose(synth_motion._euler(x, y, z),
                               synth_motion._rx(x) @ synth_motion._ry(y) @ synth_motion._rz(np.full(2, z)), atol=1e-12)
    # Rodrigues: a quarter turn about z, and the series branch near 0
    R = skeleton.axis_angle_to_matrix_np(np.array([[0.0, 0.0, np.pi / 2], [1e-9, 0.0, 0.0]]))
    np.testing.assert_allclose(R[0], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(R[1], np.eye(3) + np.array([[0, 0, 0], [0, 0, -1e-9], [0, 1e-9, 0]]), atol=1e-15)
    assert skeleton.axis_angle_to_matrix_np(np.zeros((0, 4, 3))).shape == (0, 4, 3, 3)


def test_onset_gate():
    x = fixed_audio(16000, 4.0)
    p = onsets.SYNTH_ONSETS
    free = onsets.detect_onsets(x, 16000, p)
    assert len(free.frames) > 5
    closed = onsets.detect_onsets(x, 16000, p, gate=np.zeros(len(free.envelope), dtype=bool))
    assert len(closed.frames) == 0
    np.testing.assert_array_equal(closed.envelope, free.envelope)
    # a gate that closes over one onset: the refractory wait restarts from the last onset kept
    gate = np.ones(len(free.envelope), dtype=bool)
    gate[free.frames[2]] = False
    half = onsets.detect_onsets(x, 16000, p, gate=gate).frames
    assert free.frames[2] not in half and set(free.frames) - {free.frames[2]} <= set(half)
    with pytest.raises(ValueError, match="gate"):
        onsets.detect_onsets(x, 16000, p, gate=np.ones(3, dtype=bool))
