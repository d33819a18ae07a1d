"""BEAT2-style evaluation metrics (docs/evaluation.md; LiveGesture paper, supplementary C).

Everything here is numpy/scipy, deterministic, and works on any clip length. Conventions:

- Motion is 30 fps SMPL-X-layout: ``poses`` (T, 165) axis-angle, ``trans`` (T, 3). Joint positions come from
  the project skeleton (``livegesture.skeleton.forward_kinematics``), never from the licensed SMPL-X model.
- Times are in seconds. Frame k of a clip sits at time ``k / fps``.

Beat Constancy (BC), paper eq. 3
    ``BC = 1/|g_mot| * sum_{b_g in g_mot} exp(-min_{b_a in a_aud} |b_g - b_a|^2 / (2 sigma^2))``, sigma = 0.3 s.

    *Motion beats* are local minima of joint speed, detected **per upper-body joint** as in EMAGE/BEAT2
    (joints [3,6,9,12,13,14,15,16,17,18,19,20,21]): speed is the norm of the central-difference velocity
    of the joint position (forward/backward difference at the ends); a frame is a beat of that joint when
    it is a strict minimum of the speed over +-``order`` (7) frames (``scipy.signal.argrelextrema``, as
    EMAGE). BC is computed per joint and averaged over the 13 joints; a joint without any beat in the
    window counts 0 (EMAGE does the same). Minima are filtered so that noise in still segments does not
    count as beats. Two rules are available (``BC_RULE`` is the default):

    - ``rule="emage"`` (default, ``BC_RULE``): EMAGE's rule, below; the paper's BC is EMAGE's metric, so its
      figures compare with this one.
    - ``rule="prominence"`` (the project's rule, an option: ``--bc-rule prominence``): keep a minimum when the joint's speed rises above it by at least
      ``threshold * ref`` somewhere within +-``order`` frames (``ref`` = the joint's reference mean speed).
      This keeps the stroke ends of real beat gestures (where the speed can drop to ~0) and drops the
      wobble of a joint at rest.
    - ``rule="emage"``: keep a minimum when the speed itself is above ``threshold * ref``
      (EMAGE divides the speed by the dataset mean joint speed ``mean_vel_smplxflame_30.npy`` and keeps
      minima above 0.1). It drops stroke ends that come to a full stop.

    ``ref`` is the per-joint mean speed of a reference set (``mean_joint_speed`` over the training split,
    like EMAGE's file); when none is given the clip's own per-joint mean speed is used.

    *Audio beats* are onsets from :func:`detect_onsets` (spectral flux on a log-mel STFT with
    librosa-style peak picking: the project's one onset detector, ``livegesture.onsets``; no librosa).

    The first and last ``trim_s`` = 2 s of a clip are excluded (EMAGE's ``align_mask`` of 60 frames):
    motion beats are searched in frames ``[2 s * fps, T - 2 s * fps)`` and only onsets inside the same time
    window are used. Onsets are detected on the whole audio (then cropped) rather than on the cropped
    audio, so that a boundary does not create a spurious onset. A clip's BC is weighted by its trimmed
    length when averaging over a set (EMAGE does the same), see :func:`weighted_mean`.

    Global translation is removed before computing speeds (EMAGE zeroes ``transl`` in its SMPL-X call).

L1 diversity
    - :func:`l1_diversity_realisations`: paper eq. 2 over N realisations of the SAME audio,
      ``1/(2 N (N-1) T) sum_i sum_{j != i} sum_t ||p_t^(i) - p_t^(j)||_1`` (p = all joint positions of a
      frame, global translation removed, L1 summed over joints and xyz).
    - :func:`l1_diversity_beat2`: the BEAT2/EMAGE code's ``L1div``: over all frames of all clips of a test
      set, the mean over frames of ``sum |p_t - mean_frame|_1`` (distance of each frame's pose to the mean
      pose of the set).
    - :func:`l1_diversity_across_clips`: mean pairwise eq.-2-style L1 between DIFFERENT clips' motions
      (frame by frame over their common length); a per-frame distance, like eq. 2 without the 1/2.

FGD, paper eq. 1
    :func:`frechet_distance` on two feature sets (features from ``livegesture.eval.fgd_encoder``).

Face error
    :func:`face_param_mse`: MSE of jaw rotation (axis-angle of joint 22) and of the 100 expression
    parameters. :func:`face_vertex_mse` is paper eq. 4 on face vertices; it needs a user-supplied SMPL-X
    model (a callable), since the SMPL-X model files are licensed and do not ship with the project.
"""
from __future__ import annotations

import warnings
from typing import Callable, Iterable, Sequence

import numpy as np
from scipy import linalg
from scipy.signal import argrelextrema

from ..onsets import detect_onsets as _detect_onsets
from ..onsets import eval_onset_params, peak_pick, spectral_flux
from ..regions import FPS, JAW_JOINT, UPPER_JOINTS

SIGMA_S = 0.3             # BC temporal tolerance (seconds)
TRIM_S = 2.0              # seconds excluded at each end of a clip for BC
BEAT_ORDER = 7            # argrelextrema order (frames), EMAGE
BEAT_THRESHOLD = 0.1      # fraction of the reference joint speed, EMAGE
BC_RULE = "emage"         # the default motion-beat rule: EMAGE's (the project's "prominence" is an option)


# ============================================================================ joints

def joints_from_motion(poses: np.ndarray, trans: np.ndarray | None = None,
                       remove_translation: bool = True) -> np.ndarray:
    """(T,165) axis-angle poses (+ (T,3) trans) -> (T,55,3) joint positions from the project skeleton.

    With ``remove_translation`` (the default, as every metric here wants) the global translation is zeroed.
    """
    try:
        from ..skeleton import forward_kinematics
    except ImportError as e:  # pragma: no cover - only before the skeleton module exists
        raise ImportError("livegesture.skeleton.forward_kinematics is needed to turn poses into joint "
                          f"positions ({e})") from e
    poses = np.asarray(poses, dtype=np.float64).reshape(len(poses), -1)
    if trans is None or remove_translation:
        trans = np.zeros((len(poses), 3), dtype=np.float64)
    return np.asarray(forward_kinematics(poses, np.asarray(trans, dtype=np.float64)), dtype=np.float64)


def joint_speed(joints: np.ndarray, fps: float = FPS) -> np.ndarray:
    """(T,J,3) positions -> (T,J) speed (m/s): central differences inside, one-sided at the two ends (EMAGE)."""
    x = np.asarray(joints, dtype=np.float64)
    if x.ndim == 2:
        x = x.reshape(len(x), -1, 3)
    T = len(x)
    if T < 2:
        return np.zeros(x.shape[:2])
    v = np.empty_like(x)
    v[0] = (x[1] - x[0]) * fps
    v[-1] = (x[-1] - x[-2]) * fps
    if T > 2:
        v[1:-1] = (x[2:] - x[:-2]) * (fps / 2.0)
    return np.linalg.norm(v, axis=-1)


def mean_joint_speed(joint_sets: Iterable[np.ndarray], fps: float = FPS) -> np.ndarray:
    """Per-joint mean speed (J,) over all frames of a set of (T,J,3) clips (EMAGE's ``mean_vel`` file)."""
    total, n = None, 0
    for j in joint_sets:
        s = joint_speed(j, fps)
        total = s.sum(0) if total is None else total + s.sum(0)
        n += len(s)
    if total is None or n == 0:
        raise ValueError("mean_joint_speed: empty set")
    return total / n


# ============================================================================ motion beats

def _beat_frames(speed: np.ndarray, start: int, stop: int, order: int, threshold: float, ref: float,
                 rule: str) -> np.ndarray:
    """Absolute frame indices of filtered speed minima of ONE joint inside [start, stop)."""
    seg = speed[start:stop]
    if len(seg) < 3:
        return np.zeros(0, dtype=np.int64)
    idx = argrelextrema(seg, np.less, order=order)[0]
    if len(idx) == 0:
        return idx.astype(np.int64)
    floor = threshold * ref
    if rule == "emage":
        keep = seg[idx] > floor
    elif rule == "prominence":
        keep = np.zeros(len(idx), dtype=bool)
        for n, i in enumerate(idx):
            lo, hi = max(0, i - order), min(len(seg), i + order + 1)
            keep[n] = seg[lo:hi].max() - seg[i] > floor
    else:
        raise ValueError(f"unknown motion-beat rule {rule!r} (prominence or emage)")
    return (idx[keep] + start).astype(np.int64)


def motion_beats(joints: np.ndarray, fps: float = FPS, joint_ids: Sequence[int] = UPPER_JOINTS,
                 start: int = 0, stop: int | None = None, order: int = BEAT_ORDER,
                 threshold: float = BEAT_THRESHOLD, speed_ref: np.ndarray | None = None,
                 rule: str = BC_RULE, mode: str = "per_joint") -> list[np.ndarray]:
    """Motion beats as absolute frame indices, one array per joint of ``joint_ids`` (``mode="per_joint"``)
    or a single array for the minima of the mean speed over those joints (``mode="mean_speed"``)."""
    speed = joint_speed(joints, fps)
    T = len(speed)
    stop = T if stop is None else min(stop, T)
    ids = list(joint_ids)
    if speed_ref is None:
        ref = speed.mean(0)
    else:
        ref = np.asarray(speed_ref, dtype=np.float64)
        if ref.ndim == 0:
            ref = np.full(speed.shape[1], float(ref))
    if mode == "per_joint":
        return [_beat_frames(speed[:, j], start, stop, order, threshold, ref[j], rule) for j in ids]
    if mode == "mean_speed":
        s = speed[:, ids].mean(1)
        return [_beat_frames(s, start, stop, order, threshold, float(ref[ids].mean()), rule)]
    raise ValueError(f"unknown motion-beat mode {mode!r} (per_joint or mean_speed)")


# ============================================================================ audio onsets

def onset_strength(audio: np.ndarray, sample_rate: int, hop_s: float = 0.01, win_s: float = 0.032,
                   n_mels: int = 64, log_gain: float | None = 1000.0,
                   top_db: float = 80.0) -> tuple[np.ndarray, np.ndarray]:
    """Spectral-flux onset envelope (not normalised) of :func:`detect_onsets`. Returns (envelope (F,), frame
    times (F,) in seconds); the settings are :func:`livegesture.onsets.eval_onset_params`'s.

    Centred STFT (zero padding of half a window at both ends), periodic Hann window of ``win_s`` (rounded
    to a power of two in samples), hop ``hop_s``; power spectrum -> mel -> log compression
    ``log(1 + log_gain * mel / max(mel))`` (about 30 dB of range for the default gain: quieter detail,
    background noise included, adds little flux, and the half-window early bias of a dB scale on sharp
    attacks shrinks); with ``log_gain=None``, librosa's dB scale clipped ``top_db`` below the peak instead.
    Flux = mean over mel bands of the half-wave rectified first difference (lag 1 frame).
    Frame n's flux is the change between frames n-1 and n, stamped at the midpoint of their centres.
    """
    if len(audio) == 0:
        return np.zeros(0), np.zeros(0)
    p = eval_onset_params(sample_rate, hop_s=hop_s, win_s=win_s, log_gain=log_gain, n_mels=n_mels,
                          top_db=top_db)
    flux = spectral_flux(audio, sample_rate, p)
    return flux, _flux_times(len(flux), p.hop, sample_rate)


def _flux_times(n: int, hop: int, sample_rate: int) -> np.ndarray:
    """Frame n's flux stamped between the centres of frames n-1 and n (frame 0 at 0 s)."""
    times = (np.arange(n) - 0.5) * hop / int(sample_rate)
    times[0] = 0.0
    return times


def detect_onsets(audio: np.ndarray, sample_rate: int, hop_s: float = 0.01, win_s: float = 0.032,
                  delta: float = 0.07, wait_s: float = 0.1, pre_max_s: float = 0.03,
                  post_max_s: float = 0.03, pre_avg_s: float = 0.1, post_avg_s: float = 0.1,
                  log_gain: float | None = 1000.0) -> np.ndarray:
    """Audio beats: onset times in seconds (sorted), the project's one onset detector
    (:func:`livegesture.onsets.detect_onsets`) with the Beat Constancy settings
    (:func:`livegesture.onsets.eval_onset_params`).

    The envelope of :func:`onset_strength` is normalised to [0, 1] (minus min, over max, as librosa's
    ``onset_detect``), then peak-picked with :func:`peak_pick` (librosa's defaults, a 30 ms max window on
    both sides, and a 100 ms refractory ``wait`` so that one syllable onset is one beat).
    """
    if len(audio) == 0:
        return np.zeros(0)
    p = eval_onset_params(sample_rate, hop_s=hop_s, win_s=win_s, delta=delta, wait_s=wait_s,
                          pre_max_s=pre_max_s, post_max_s=post_max_s, pre_avg_s=pre_avg_s,
                          post_avg_s=post_avg_s, log_gain=log_gain)
    on = _detect_onsets(audio, sample_rate, p)
    return _flux_times(len(on.envelope), p.hop, sample_rate)[on.frames]


# ============================================================================ Beat Constancy

def bc_score(motion_beat_times: np.ndarray, audio_beat_times: np.ndarray, sigma: float = SIGMA_S) -> float:
    """Paper eq. 3 for one set of motion beats: mean over motion beats of exp(-d^2 / (2 sigma^2)), d the
    distance to the nearest audio beat. 0 when there are no motion beats or no audio beats."""
    m = np.asarray(motion_beat_times, dtype=np.float64).reshape(-1)
    a = np.sort(np.asarray(audio_beat_times, dtype=np.float64).reshape(-1))
    if len(m) == 0 or len(a) == 0:
        return 0.0
    pos = np.searchsorted(a, m)
    left = a[np.clip(pos - 1, 0, len(a) - 1)]
    right = a[np.clip(pos, 0, len(a) - 1)]
    d = np.minimum(np.abs(m - left), np.abs(m - right))
    return float(np.mean(np.exp(-d * d / (2.0 * sigma * sigma))))


def beat_constancy(joints: np.ndarray, audio: np.ndarray | None = None, sample_rate: int = 16000,
                   fps: float = FPS, *, onset_times: np.ndarray | None = None, sigma: float = SIGMA_S,
                   trim_s: float = TRIM_S, joint_ids: Sequence[int] = UPPER_JOINTS, order: int = BEAT_ORDER,
                   threshold: float = BEAT_THRESHOLD, speed_ref: np.ndarray | None = None,
                   rule: str = BC_RULE, mode: str = "per_joint", return_details: bool = False):
    """Beat Constancy of one clip.

    ``joints``: (T,55,3) joint positions (global translation removed; see :func:`joints_from_motion`).
    Audio beats come from ``onset_times`` (seconds) when given, else from :func:`detect_onsets` on
    ``audio`` at ``sample_rate``. Clip length is the motion length, or the audio length if shorter.
    Returns the BC (float), or ``(bc, details)`` with ``return_details``: details has the trimmed window
    (frames), the number of frames it weighs (``weight``), motion beats per joint (frames) and audio beats
    (seconds).
    """
    joints = np.asarray(joints, dtype=np.float64)
    T = len(joints)
    if onset_times is None:
        if audio is None:
            raise ValueError("beat_constancy: give audio or onset_times")
        audio = np.asarray(audio)
        T = min(T, int(len(audio) * fps // sample_rate))
        onset_times = detect_onsets(audio, sample_rate)
    trim = int(round(trim_s * fps))
    start, stop = trim, T - trim
    if stop - start < 3:
        raise ValueError(f"beat_constancy: clip of {T} frames is too short for a {trim_s} s trim at each end")
    beats = motion_beats(joints[:T], fps, joint_ids, start, stop, order, threshold, speed_ref, rule, mode)
    t0, t1 = start / fps, stop / fps
    a = np.asarray(onset_times, dtype=np.float64)
    a = a[(a >= t0) & (a < t1)]
    per_joint = [bc_score(b / fps, a, sigma) for b in beats]
    bc = float(np.mean(per_joint))
    if return_details:
        return bc, dict(start=start, stop=stop, weight=stop - start, motion_beats=beats, audio_beats=a,
                        per_joint=per_joint)
    return bc


def beat_constancy_from_motion(poses: np.ndarray, trans: np.ndarray | None, audio: np.ndarray,
                               sample_rate: int = 16000, fps: float = FPS, **kw):
    """:func:`beat_constancy` on SMPL-X-layout motion (FK through the project skeleton, translation removed)."""
    return beat_constancy(joints_from_motion(poses, trans), audio, sample_rate, fps, **kw)


def weighted_mean(values: Sequence[float], weights: Sequence[float]) -> float:
    """Weighted mean (BC over a set: each clip weighted by its trimmed length, as EMAGE)."""
    v = np.asarray(values, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    if len(v) == 0 or w.sum() <= 0:
        return float("nan")
    return float((v * w).sum() / w.sum())


# ============================================================================ L1 diversity

def _flat_frames(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return x.reshape(x.shape[0], -1)


def l1_diversity_realisations(realisations: Sequence[np.ndarray] | np.ndarray) -> float:
    """Paper eq. 2. ``realisations``: N arrays (T,J,3) (or (T,D)) of joint positions for the same audio,
    global translation removed. Clips are cut to their common length T.

    ``Div = 1/(2 N (N-1) T) * sum_i sum_{j != i} sum_t ||p_t^(i) - p_t^(j)||_1``.
    """
    reals = [_flat_frames(r) for r in realisations]
    N = len(reals)
    if N < 2:
        raise ValueError("l1_diversity_realisations needs at least 2 realisations")
    T = min(len(r) for r in reals)
    if T == 0:
        raise ValueError("l1_diversity_realisations: empty clips")
    P = np.stack([r[:T] for r in reals])  # (N,T,D)
    total = 0.0
    for i in range(N):
        for j in range(i + 1, N):
            total += 2.0 * np.abs(P[i] - P[j]).sum()  # (i, j) and (j, i)
    return float(total / (2.0 * N * (N - 1) * T))


def l1_diversity_beat2(clips: Sequence[np.ndarray]) -> float:
    """BEAT2/EMAGE ``L1div``: frames of all clips pooled, mean over frames of the L1 distance (summed over
    joints and xyz) between the frame and the mean frame of the pool."""
    X = np.concatenate([_flat_frames(c) for c in clips], axis=0)
    if len(X) == 0:
        raise ValueError("l1_diversity_beat2: no frames")
    return float(np.abs(X - X.mean(0, keepdims=True)).sum() / len(X))


def l1_diversity_across_clips(clips: Sequence[np.ndarray]) -> float:
    """Mean over pairs of DIFFERENT clips of the per-frame L1 distance (summed over joints and xyz) over
    their common length: ``mean_{i<j} 1/T_ij sum_t ||p_t^(i) - p_t^(j)||_1``."""
    C = [_flat_frames(c) for c in clips]
    if len(C) < 2:
        raise ValueError("l1_diversity_across_clips needs at least 2 clips")
    vals = []
    for i in range(len(C)):
        for j in range(i + 1, len(C)):
            T = min(len(C[i]), len(C[j]))
            if T > 0:
                vals.append(np.abs(C[i][:T] - C[j][:T]).sum() / T)
    return float(np.mean(vals))


# ============================================================================ FGD

def frechet_distance_from_stats(mu1: np.ndarray, sigma1: np.ndarray, mu2: np.ndarray, sigma2: np.ndarray,
                                eps: float = 1e-6) -> float:
    """Paper eq. 1: ``||mu1 - mu2||^2 + Tr(S1 + S2 - 2 (S1 S2)^(1/2))``.

    ``scipy.linalg.sqrtm`` of the product; if it is not finite (singular covariances), ``eps * I`` is added
    to both covariances and the root recomputed. A negligible imaginary part from round-off is dropped;
    a large one raises. The result is clamped at 0 (it can dip a hair below through round-off).
    """
    mu1, mu2 = np.atleast_1d(np.asarray(mu1, np.float64)), np.atleast_1d(np.asarray(mu2, np.float64))
    s1, s2 = np.atleast_2d(np.asarray(sigma1, np.float64)), np.atleast_2d(np.asarray(sigma2, np.float64))
    if mu1.shape != mu2.shape or s1.shape != s2.shape or s1.shape != (len(mu1), len(mu1)):
        raise ValueError(f"frechet_distance: shape mismatch {mu1.shape} {mu2.shape} {s1.shape} {s2.shape}")
    diff = mu1 - mu2

    def _sqrt(a, b):
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", linalg.LinAlgWarning)
            out = linalg.sqrtm(a @ b)
        if isinstance(out, tuple):  # older scipy with disp=False
            out = out[0]
        return out

    covmean = _sqrt(s1, s2)
    if not np.isfinite(covmean).all():
        off = np.eye(len(mu1)) * eps
        covmean = _sqrt(s1 + off, s2 + off)
    if np.iscomplexobj(covmean):
        if not np.allclose(np.diagonal(covmean).imag, 0, atol=1e-3 * max(1.0, np.abs(covmean).max())):
            raise ValueError(f"frechet_distance: sqrtm has a large imaginary part "
                             f"{np.abs(np.diagonal(covmean).imag).max():.3g}")
        covmean = covmean.real
    fd = float(diff @ diff + np.trace(s1) + np.trace(s2) - 2.0 * np.trace(covmean))
    return max(fd, 0.0)


def feature_stats(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2 or len(f) < 2:
        raise ValueError(f"feature_stats: need (N>=2, F) features, got {f.shape}")
    return f.mean(0), np.cov(f, rowvar=False).reshape(f.shape[1], f.shape[1])


def frechet_distance(features_a: np.ndarray, features_b: np.ndarray, eps: float = 1e-6) -> float:
    """FGD between two (N, F) feature sets (paper eq. 1, sample means and covariances)."""
    return frechet_distance_from_stats(*feature_stats(features_a), *feature_stats(features_b), eps=eps)


# ============================================================================ face

def face_param_mse(gt_poses: np.ndarray, gt_expressions: np.ndarray, pred_poses: np.ndarray,
                   pred_expressions: np.ndarray) -> dict:
    """MSE of the jaw rotation (axis-angle of joint 22, 3 numbers) and of the expression parameters.
    Clips are cut to their common length. Returns ``jaw``, ``expressions`` (each the mean over its own
    numbers), ``face`` (mean over all 3 + E numbers) and ``frames``."""
    gp = np.asarray(gt_poses, np.float64).reshape(len(gt_poses), -1)
    pp = np.asarray(pred_poses, np.float64).reshape(len(pred_poses), -1)
    ge = np.asarray(gt_expressions, np.float64).reshape(len(gt_expressions), -1)
    pe = np.asarray(pred_expressions, np.float64).reshape(len(pred_expressions), -1)
    T = min(len(gp), len(pp), len(ge), len(pe))
    E = min(ge.shape[1], pe.shape[1])
    if ge.shape[1] != pe.shape[1]:
        raise ValueError(f"face_param_mse: expression sizes differ ({ge.shape[1]} vs {pe.shape[1]})")
    j = slice(3 * JAW_JOINT, 3 * JAW_JOINT + 3)
    dj = (gp[:T, j] - pp[:T, j]) ** 2
    de = (ge[:T, :E] - pe[:T, :E]) ** 2
    return dict(jaw=float(dj.mean()) if T else float("nan"),
                expressions=float(de.mean()) if T else float("nan"),
                face=float((dj.sum() + de.sum()) / (T * (3 + E))) if T else float("nan"),
                frames=int(T))


FaceModel = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def face_vertex_mse(gt: dict, pred: dict, face_model: FaceModel | None = None,
                    vertex_ids: np.ndarray | None = None) -> float:
    """Paper eq. 4: mean over face vertices (and frames) of ``||v_i - v_hat_i||_2^2``.

    ``gt``/``pred``: dicts with ``poses`` (T,165), ``trans`` (T,3), ``expressions`` (T,100).
    ``face_model``: a user-supplied SMPL-X evaluation ``f(poses, trans, expressions) -> (T, V, 3)`` vertices
    (e.g. a wrapper around the ``smplx`` package with the user's licensed model files, betas zero),
    ``vertex_ids`` optionally selects the face vertices. The project ships no SMPL-X model and never fakes
    vertices: without a model this raises ``NotImplementedError``; use :func:`face_param_mse` instead.
    """
    if face_model is None:
        raise NotImplementedError(
            "face vertex MSE needs a user-supplied SMPL-X model (the SMPL-X model files are licensed and do "
            "not ship with LiveGesture): pass face_model=callable(poses, trans, expressions) -> (T, V, 3) "
            "vertices (CLI: --face-model module:function). Without one, use face_param_mse "
            "(jaw rotation + expression parameters).")
    T = min(len(gt["poses"]), len(pred["poses"]))
    # Translation is zeroed in both, as in the BEAT2 evaluation, so only the face deformation counts.
    z = np.zeros((T, 3))
    vg = np.asarray(face_model(np.asarray(gt["poses"])[:T], z, np.asarray(gt["expressions"])[:T]), np.float64)
    vp = np.asarray(face_model(np.asarray(pred["poses"])[:T], z, np.asarray(pred["expressions"])[:T]),
                    np.float64)
    if vertex_ids is not None:
        vg, vp = vg[:, vertex_ids], vp[:, vertex_ids]
    return float(((vg - vp) ** 2).sum(-1).mean())


__all__ = [
    "SIGMA_S", "TRIM_S", "BEAT_ORDER", "BEAT_THRESHOLD",
    "joints_from_motion", "joint_speed", "mean_joint_speed", "motion_beats",
    "onset_strength", "peak_pick", "detect_onsets",
    "bc_score", "beat_constancy", "beat_constancy_from_motion", "weighted_mean",
    "l1_diversity_realisations", "l1_diversity_beat2", "l1_diversity_across_clips",
    "frechet_distance_from_stats", "feature_stats", "frechet_distance",
    "face_param_mse", "face_vertex_mse",
]
