"""Evaluation metrics on hand-made inputs with known answers (livegesture.eval)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.io.wavfile

from livegesture.eval import metrics as M
from livegesture.regions import UPPER_JOINTS

FPS = 30
SR = 16000


# ----------------------------------------------------------------------------- helpers

def beat_motion(beat_times, duration, fps=FPS, amp=0.2, drift=0.05, seed=0):
    """(T,55,3) joints whose upper-body speed minima sit exactly on ``beat_times`` (on the frame grid).

    Each upper-body joint swings ``amp * cos(pi * phase)`` along its own direction, with ``phase`` piecewise
    linear in time and integer at the beats (so the swing reverses exactly at each beat), plus a constant
    drift of ``drift`` m/s along a perpendicular direction so the speed minimum is not zero.
    """
    rng = np.random.default_rng(seed)
    T = int(round(duration * fps))
    t = np.arange(T) / fps
    gap = beat_times[1] - beat_times[0]   # evenly spaced beats: the swing is symmetric about each beat
    knots = np.concatenate([[beat_times[0] - gap], beat_times, [beat_times[-1] + gap]])
    phase = np.interp(t, knots, np.arange(len(knots)))
    J = np.zeros((T, 55, 3))
    for j in UPPER_JOINTS:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        e = np.cross(d, rng.normal(size=3))
        e /= np.linalg.norm(e)
        J[:, j] = amp * np.cos(np.pi * phase)[:, None] * d + drift * t[:, None] * e + rng.normal(size=3)
    return J


def clicks(times, duration, sr=SR, seed=0, noise=1e-3):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, noise, int(duration * sr))
    n = int(0.005 * sr)
    for t in times:
        i = int(round(t * sr))
        m = min(n, len(x) - i)
        x[i:i + m] += 0.8 * np.exp(-np.arange(m) / 40.0) * rng.choice([-1.0, 1.0], m)
    return x


BEATS = np.array([2.5, 5.0, 7.5, 10.0, 12.5, 15.0, 17.5])   # frames 75, 150, ... (on the 30 fps grid)
DUR = 20.0


# ----------------------------------------------------------------------------- Beat Constancy

def test_bc_score_formula():
    # one motion beat 0.3 s from the nearest audio beat: exp(-0.09 / 0.18) = exp(-0.5)
    assert M.bc_score([1.0], [0.0, 1.3, 5.0]) == pytest.approx(math.exp(-0.5))
    assert M.bc_score([1.0, 2.0], [1.0, 2.0]) == pytest.approx(1.0)
    assert M.bc_score([], [1.0]) == 0.0 and M.bc_score([1.0], []) == 0.0


def test_motion_beats_found_exactly():
    J = beat_motion(BEATS, DUR)
    for rule in ("prominence", "emage"):
        beats = M.motion_beats(J, FPS, start=60, stop=len(J) - 60, rule=rule)
        assert len(beats) == len(UPPER_JOINTS)
        for b in beats:
            np.testing.assert_array_equal(b, np.round(BEATS * FPS).astype(int))


@pytest.mark.parametrize("rule", ["prominence", "emage"])
@pytest.mark.parametrize("mode", ["per_joint", "mean_speed"])
def test_bc_aligned_is_one_and_shifted_is_low(rule, mode):
    J = beat_motion(BEATS, DUR)
    aligned = M.beat_constancy(J, onset_times=BEATS, fps=FPS, rule=rule, mode=mode)
    assert aligned == pytest.approx(1.0, abs=1e-9)
    # every onset 1 s after a motion beat (and 1.5 s before the next): nearest onset is 1 s away
    shifted = M.beat_constancy(J, onset_times=BEATS + 1.0, fps=FPS, rule=rule, mode=mode)
    assert shifted <= math.exp(-1.0 / (2 * 0.09)) + 1e-9


def test_bc_trims_two_seconds_each_end():
    J = beat_motion(BEATS, DUR)
    bc, d = M.beat_constancy(J, onset_times=BEATS, fps=FPS, return_details=True)
    assert (d["start"], d["stop"], d["weight"]) == (60, 540, 480)
    # a beat inside the first 2 s does not count, nor an onset there
    J2 = beat_motion(np.concatenate([[1.0], BEATS]), DUR)
    _, d2 = M.beat_constancy(J2, onset_times=np.concatenate([[1.0], BEATS]), fps=FPS, return_details=True)
    assert all(b.min() >= 60 for b in d2["motion_beats"]) and d2["audio_beats"].min() >= 2.0
    with pytest.raises(ValueError):
        M.beat_constancy(J[:100], onset_times=BEATS, fps=FPS)


def test_onset_detector_finds_clicks():
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.25, 0.9, 30)) + 0.3
    times = times[times < 19.5]
    x = clicks(times, 20.0)
    on = M.detect_onsets(x, SR)
    assert len(on) == len(times)
    err = np.abs(on - times)
    assert err.max() < 0.020, err.max()
    # any sample rate: the same clicks at 44.1 kHz
    x44 = clicks(times, 20.0, sr=44100)
    on44 = M.detect_onsets(x44, 44100)
    assert len(on44) == len(times) and np.abs(on44 - times).max() < 0.020


def test_bc_full_pipeline_matched_vs_mismatched_audio():
    """Motion + click track through the onset detector: matched audio passes a BC check that mismatched
    audio (another clip's beats) fails — the check catches motion that does not follow its audio."""
    J = beat_motion(BEATS, DUR)
    matched = M.beat_constancy(J, clicks(BEATS, DUR), SR, FPS)
    other = BEATS + np.array([0.9, -1.0, 1.1, -0.95, 1.0, -1.05, 0.9])
    mismatched = M.beat_constancy(J, clicks(other, DUR), SR, FPS)
    threshold = 0.9
    assert matched > threshold
    assert not mismatched > threshold   # the deliberately broken input fails the same check
    assert matched - mismatched > 0.8


def test_mean_joint_speed_and_speed_ref():
    J = beat_motion(BEATS, DUR)
    ref = M.mean_joint_speed([J, J])
    np.testing.assert_allclose(ref, M.joint_speed(J).mean(0))
    # a huge reference speed makes the prominence filter drop every beat -> BC 0
    assert M.beat_constancy(J, onset_times=BEATS, speed_ref=ref * 1e3) == 0.0


# ----------------------------------------------------------------------------- L1 diversity

def test_l1_diversity_realisations_eq2():
    rng = np.random.default_rng(0)
    base = rng.normal(size=(40, 2, 3))
    assert M.l1_diversity_realisations([base, base, base]) == 0.0
    # offsets 0, 1, 3 on all 6 numbers: sum_{i<j} |ci - cj| = 1 + 3 + 2 = 6 per number;
    # eq. 2 = 2 * T * 6 * 6 / (2 * N (N-1) T) = 36 / 6 = 6
    reals = [base + c for c in (0.0, 1.0, 3.0)]
    assert M.l1_diversity_realisations(reals) == pytest.approx(6.0)
    # different lengths are cut to the common length
    assert M.l1_diversity_realisations([base, base[:30] + 2.0]) == pytest.approx(2 * 30 * 12 / (2 * 2 * 30))
    with pytest.raises(ValueError):
        M.l1_diversity_realisations([base])


def test_l1_diversity_beat2_and_across_clips():
    a = np.zeros((10, 2, 3))
    b = np.full((20, 2, 3), 3.0)
    # pooled mean frame = 2 everywhere; |0-2|*6 for 10 frames, |3-2|*6 for 20 frames -> (120 + 120) / 30
    assert M.l1_diversity_beat2([a, b]) == pytest.approx(8.0)
    assert M.l1_diversity_across_clips([a, b]) == pytest.approx(18.0)
    assert M.l1_diversity_across_clips([a, a]) == 0.0


# ----------------------------------------------------------------------------- FGD

def _sqrtm_psd(S):
    w, V = np.linalg.eigh(S)
    return (V * np.sqrt(np.maximum(w, 0))) @ V.T


def _fd_closed_form(mu1, S1, mu2, S2):
    r = _sqrtm_psd(S1)
    return float(np.sum((mu1 - mu2) ** 2) + np.trace(S1 + S2 - 2 * _sqrtm_psd(r @ S2 @ r)))


def test_fgd_self_is_zero():
    f = np.random.default_rng(0).normal(size=(500, 16))
    assert M.frechet_distance(f, f) == pytest.approx(0.0, abs=1e-6)


def test_fgd_closed_form_gaussians():
    # diagonal: ||dmu||^2 + sum (sqrt(a) - sqrt(b))^2
    mu1, mu2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0])
    a, b = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 9.0])
    expect = 1 + 0 + 4 + (1 - 2) ** 2 + (2 - 1) ** 2 + 0
    assert M.frechet_distance_from_stats(mu1, np.diag(a), mu2, np.diag(b)) == pytest.approx(expect)
    # general (non-commuting) covariances against the symmetric closed form
    rng = np.random.default_rng(3)
    A, B = rng.normal(size=(4, 4)), rng.normal(size=(4, 4))
    S1, S2 = A @ A.T + 0.1 * np.eye(4), B @ B.T + 0.1 * np.eye(4)
    m1, m2 = rng.normal(size=4), rng.normal(size=4)
    assert M.frechet_distance_from_stats(m1, S1, m2, S2) == pytest.approx(_fd_closed_form(m1, S1, m2, S2),
                                                                          rel=1e-6)
    # from samples: converges to the closed form
    x = rng.multivariate_normal(m1, S1, size=100_000)
    y = rng.multivariate_normal(m2, S2, size=100_000)
    assert M.frechet_distance(x, y) == pytest.approx(_fd_closed_form(m1, S1, m2, S2), rel=0.03)


def test_fgd_singular_covariance_is_finite():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(200, 2))
    f1 = np.concatenate([z, z, np.zeros((200, 4))], axis=1)     # rank 2 in 8 dims
    f2 = f1 + 0.5
    d = M.frechet_distance(f1, f2)
    assert np.isfinite(d) and d == pytest.approx(8 * 0.25, rel=1e-3)


# ----------------------------------------------------------------------------- face

def test_face_param_mse():
    T = 12
    gp, ge = np.zeros((T, 165)), np.zeros((T, 100))
    pp, pe = gp.copy(), ge + 0.2
    pp[:, 66:69] = 0.1                       # jaw = joint 22
    pp[:, :66] = 5.0                         # body joints do not count
    f = M.face_param_mse(gp, ge, pp, pe)
    assert f["jaw"] == pytest.approx(0.01) and f["expressions"] == pytest.approx(0.04)
    assert f["face"] == pytest.approx((3 * 0.01 + 100 * 0.04) / 103) and f["frames"] == T


def test_face_vertex_mse_needs_a_model():
    m = {"poses": np.zeros((5, 165)), "trans": np.zeros((5, 3)), "expressions": np.zeros((5, 100))}
    with pytest.raises(NotImplementedError, match="SMPL-X model"):
        M.face_vertex_mse(m, m)
    # a user-supplied model (here a toy linear one): eq. 4 = mean over vertices of squared L2 distance
    W = np.random.default_rng(0).normal(size=(100, 7 * 3))
    model = lambda poses, trans, expr: (expr @ W).reshape(len(expr), 7, 3)  # noqa: E731
    p = dict(m, expressions=np.full((5, 100), 0.1))
    expect = (((0.1 * np.ones(100)) @ W).reshape(7, 3) ** 2).sum(-1).mean()
    assert M.face_vertex_mse(m, p, model) == pytest.approx(expect)


# ----------------------------------------------------------------------------- FGD encoder + CLI

def _write_corpus(root, n_test=3, n_train=2, dur=8.0, seed=0):
    """A tiny BEAT2-layout corpus: arm swings that reverse at click times (speed minima on onsets)."""
    rng = np.random.default_rng(seed)
    (root / "smplxflame_30").mkdir(parents=True)
    (root / "wave16k").mkdir()
    rows = []
    for k in range(n_test + n_train):
        cid = f"2_test_0_{k}_{k}"
        beats = np.cumsum(rng.uniform(0.5, 1.0, 30)) + 0.3
        beats = np.round(beats[beats < dur - 0.3] * FPS) / FPS
        T = int(dur * FPS)
        t = np.arange(T) / FPS
        phase = np.interp(t, np.concatenate([[-1.0], beats, [dur + 1]]), np.arange(len(beats) + 2))
        poses = 0.02 * rng.normal(size=(1, 165)) + np.zeros((T, 165))
        for j, amp in ((0, 0.1), (3, 0.1), (6, 0.1), (9, 0.1), (12, 0.2), (13, 0.4), (14, 0.4), (16, 0.4),
                       (17, 0.4), (18, 0.4), (19, 0.4)):
            poses[:, 3 * j:3 * j + 3] += np.outer(amp * np.cos(np.pi * phase) + 0.1 * amp * t, rng.normal(size=3))
        expr = np.outer(np.sin(2 * t), rng.normal(size=100)) * 0.1
        np.savez(root / "smplxflame_30" / f"{cid}.npz", poses=poses.astype(np.float32),
                 trans=np.zeros((T, 3), np.float32), expressions=expr.astype(np.float32),
                 betas=np.zeros(300, np.float32), model="smplx2020", gender="neutral", mocap_frame_rate=30)
        x = clicks(beats, dur, seed=k)
        scipy.io.wavfile.write(root / "wave16k" / f"{cid}.wav", SR, (x * 32767).astype(np.int16))
        rows.append(f"{cid},{'test' if k < n_test else 'train'}")
    (root / "train_test_split.csv").write_text("id,type\n" + "\n".join(rows) + "\n")


def test_fgd_encoder_train_save_load(tmp_path):
    from livegesture.eval.fgd_encoder import (WINDOW, load_fgd_encoder, motion_frame_features, motion_windows,
                                              train_fgd_encoder)
    _write_corpus(tmp_path / "c", n_test=1, n_train=2, dur=4.0)
    enc = train_fgd_encoder(tmp_path / "c", tmp_path / "enc.pt", steps=5, seed=0, batch=4, log=None)
    m = np.load(tmp_path / "c" / "smplxflame_30" / "2_test_0_1_1.npz")
    fr = motion_frame_features(m["poses"], m["trans"])
    assert fr.shape == (120, 495)
    w = motion_windows(fr, WINDOW, 16)
    assert w.shape == (4, WINDOW, 495)
    f = enc.features(w)
    assert f.shape == (4, enc.feature_dim) and np.isfinite(f).all()
    enc2 = load_fgd_encoder(tmp_path / "enc.pt")
    np.testing.assert_allclose(enc2.features(w), f, rtol=1e-6, atol=1e-6)
    assert enc2.provenance["steps"] == 5
    with pytest.raises(ValueError):
        enc.features(w[:, :, :10])


def test_cli_report(tmp_path, capsys):
    from livegesture.eval.__main__ import main
    _write_corpus(tmp_path / "c")
    gen = tmp_path / "gen"
    gen.mkdir()
    ids = [f"2_test_0_{k}_{k}" for k in range(3)]
    for k, cid in enumerate(ids):   # "generated" = the real motion of the NEXT clip: must not follow the audio
        src = np.load(tmp_path / "c" / "smplxflame_30" / f"{ids[(k + 1) % 3]}.npz")
        np.savez(gen / f"{cid}.npz", **{key: src[key] for key in src.files})
    out = tmp_path / "report.json"
    # the project's rule (an option; EMAGE's is the default, test_bc_default_rule_is_emages): on this synthetic
    # motion the strokes stop dead at the beat, which EMAGE's rule drops as "no motion"
    assert main(["--data", str(tmp_path / "c"), "--generated", str(gen), "--fgd-encoder",
                 str(tmp_path / "enc.pt"), "--fgd-steps", "5", "--out", str(out), "--bc-rule", "prominence"]) == 0
    r = json.loads(out.read_text())
    assert r["settings"]["bc_rule"] == "prominence"
    gt, g = r["ground_truth"], r["generated"]
    printed = capsys.readouterr().out
    assert "BC (matched audio)" in printed and "BC gap, motion swap" in printed
    assert gt["bc"] > 0.9 and gt["bc_gap"] > 0.1 and r["checks"]["ground_truth_follows_audio"]
    # the broken "generated" set (motion of another clip) fails the follows-the-audio check
    assert g["bc"] < gt["bc"] - 0.1 and g["bc_gap"] < 0 and not r["checks"]["generated_follows_audio"]
    # motion swap (clip i's own audio, clip i+1's motion): the corpus motion beats it on every clip; the broken
    # set's own motion (clip i+1's) follows clip i's clicks no better than its swap (clip i+2's)
    assert gt["bc_gap_motion_swap"] > 0.1 and gt["bc_motion_swap_wins"] == 1.0
    assert g["bc_gap_motion_swap"] < 0.05
    assert gt["face"]["face"] == 0.0 and g["face"]["face"] > 0
    assert g["fgd"] >= 0 and gt["fgd"] >= 0 and g["l1div_realisations"] is None
    assert (tmp_path / "enc.pt").exists()


def test_bc_default_rule_is_emages(capsys):
    """Beat Constancy's default motion-beat rule is EMAGE's (the papers' BC), in the function and the CLI; the
    project's prominence rule is an option, and the two differ on a stroke that stops dead at its beat."""
    import inspect
    from livegesture.eval.__main__ import main
    assert M.BC_RULE == "emage"
    assert inspect.signature(M.beat_constancy).parameters["rule"].default == "emage"
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "emage (default" in " ".join(capsys.readouterr().out.split())
    speed = np.abs(np.sin(np.linspace(0, 6 * np.pi, 180)))     # comes to a full stop six times
    emage = M._beat_frames(speed, 0, 180, 7, 0.1, float(speed.mean()), "emage")
    prominence = M._beat_frames(speed, 0, 180, 7, 0.1, float(speed.mean()), "prominence")
    assert len(emage) == 0 and len(prominence) >= 4
