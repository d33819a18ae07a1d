"""Generalisation check: does a model's motion follow REAL speech, not only the voices it was trained on?

    python -m livegesture.eval.generalise --synth CORPUS [--real-speech DIR]
        (--checkpoint CKPT | --generated-real DIR [--generated-synth DIR] ...) [--out report.json]

Two sets of audio, each evaluated with the same three measures:

- ``real``: the real-speech VALIDATION split (:data:`livegesture.data.real_speech.VALIDATION`, 8 recordings
  of real people, never trained on), read at any rate/channel count and resampled to 16 kHz mono
  (``scipy.signal.resample_poly`` through :func:`livegesture.data.beat2.load_audio`);
- ``synth``: the held-out split (``--synth-split``, default ``test``) of a synthetic corpus (``--synth``),
  i.e. synthetic voices and sentences the model was not trained on.

For every clip i, its motion is scored against its OWN audio and against a mismatched pair, in two designs
reported side by side (:func:`evaluate_set`):

- ``audio swap`` (docs/evaluation.md's "BC with the audio of another clip"; the report's ``model``/``reference``
  blocks): clip i's motion against ANOTHER clip's audio (a fixed derangement: clip i of the sorted ids
  gets the audio of clip (i + 1) mod n), over their common length;
- ``motion swap`` (the ``motion_swap`` blocks): clip i's OWN audio against the motion made for every
  OTHER clip j != i (each pair over the common length of audio i, motion i and motion j, then averaged
  over j). The onsets and envelope are the same on both sides, only the motion changes.

The audio swap's BC gap mostly measures the difference in onset density between a clip and its partner:
BC's chance level (:func:`chance_bc`, the BC of randomly placed motion beats) rises with the onset rate,
and real speech (4-6 onsets/s in BC's window) puts it at ~0.93 with sigma 0.3 s. Every report holds an
``onset_power`` block per set and motion source: onsets per second, chance BC, BC of the motion's own
beats circularly shifted (:func:`shifted_bc`), and the regression of the per-clip audio-swap BC gap on the
per-clip chance gap.

The three measures:

- ``bc``: Beat Constancy (:func:`livegesture.eval.metrics.beat_constancy`, upper-body joints, onsets from
  :func:`~livegesture.eval.metrics.detect_onsets`, the same settings as ``python -m livegesture.eval`` but
  a 0.5 s trim at each end instead of 2 s, ``BC_TRIM_S``: some recordings are only 4-5 s long);
- ``jaw_env``: Pearson correlation between the jaw opening (angle of the jaw joint's axis-angle, joint 22)
  and the speech envelope (:func:`speech_envelope`: log RMS energy per motion frame over a 2-frame window,
  50 dB range below the clip's 95th percentile, mapped to [0, 1]);
- ``speed_env``: Pearson correlation between the upper-body speed (mean speed of the upper-body joints,
  project skeleton, translation removed) and the envelope, both smoothed with a centred Gaussian
  (sigma ``SPEED_SMOOTH_S`` = 0.2 s) so that a stroke that peaks a few frames after its syllable counts.

Per measure, set and design: the mean over clips of own, other and their difference (``gap``), a 95 % bootstrap
confidence interval of the mean gap (resampling clips, ``--bootstrap`` resamples, fixed seed), the fraction
of clips whose own-audio value beats the other-audio value, and every clip's numbers. A motion that ignores
its audio has gaps near zero (tests: another clip's motion, time-reversed motion); a motion that follows
it, positive gaps.

Motion sources (one of):

- ``--checkpoint CKPT``: the Python streaming reference (``livegesture.stream.generate_clip``), any
  checkpoint :func:`livegesture.checkpoint.load` reads, ``--n-realisations`` seeds per clip;
- ``--generated-real DIR`` / ``--generated-synth DIR``: folders of ``{id}.npz`` in the BEAT2 output layout
  (``poses``, ``trans``, ``expressions``), e.g. from the Rust CLI ``livegesture generate`` with any bundle or
  model family; repeat the option for several realisations (metrics are averaged over them per clip). The
  16 kHz WAVs to feed the CLI are written by ``--write-audio DIR`` (``DIR/real/{id}.wav``,
  ``DIR/synth/{id}.wav``); ``scripts/generalise_bundle.sh`` does all of this for a bundle.

Every report also holds a ``reference`` block per set: for ``synth``, the corpus's own motion of the split;
for ``real``, the motion the synthetic corpus generator's motion model
(:func:`livegesture.data.synth_motion.generate_motion`, speaker 2's style, seed 0) computes from the recording —
what a model trained on that corpus is asked to learn, i.e. what the check can show at most.

``--require-targets`` exits with status 1 unless the model's real-speech gaps reach the targets of issue 16
(speed_env gap >= 0.15, jaw_env gap >= 0.6, positive BC gap on more than half of the clips) in the audio
swap design (``--targets-design motion_swap`` reads the motion swap instead); both verdicts are reported.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from . import corpus as C
from . import metrics as M
from .report import jsonable
from ..regions import FPS, JAW_JOINT, SAMPLE_RATE, UPPER_JOINTS, frame_start_sample
from ..data.synth_motion import STROKE_DRIVES

SPEED_SMOOTH_S = 0.2
BC_TRIM_S = 0.5          # the recordings are 4-30 s: livegesture.eval's 2 s trim would leave nothing of some
# the project's motion-beat rule, as every real-speech figure so far: this is the project's own measure (0.5 s trim),
# not the papers' BC (livegesture.eval, whose default is EMAGE's rule)
BC_RULE = "prominence"
ENV_RANGE_DB = 50.0
MEASURES = ("bc", "jaw_env", "speed_env")
DESIGNS = ("audio_swap", "motion_swap")
TARGETS = {"speed_env_gap": 0.15, "jaw_env_gap": 0.6, "bc_wins": 0.5}


def _log(*a):
    print(*a, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- signals

def speech_envelope(audio: np.ndarray, n_frames: int | None = None, sample_rate: int = SAMPLE_RATE,
                    fps: int = FPS, range_db: float = ENV_RANGE_DB) -> np.ndarray:
    """Speech envelope per motion frame, in [0, 1]: RMS over frame k's samples and half a frame either side
    (``frame_start_sample`` alignment), in dB, mapped linearly from (95th percentile - ``range_db``) -> 0 to
    the 95th percentile -> 1, clipped. ``n_frames`` defaults to the audio's whole frames."""
    x = np.asarray(audio, dtype=np.float64).reshape(-1)
    if n_frames is None:
        n_frames = int(len(x) * fps // sample_rate)
    if n_frames <= 0:
        return np.zeros(0)
    starts = np.array([frame_start_sample(k, sample_rate, fps) for k in range(n_frames + 1)])
    half = (sample_rate // fps) // 2
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    lo = np.clip(starts[:-1] - half, 0, len(x))
    hi = np.clip(starts[1:] + half, 0, len(x))
    n = np.maximum(hi - lo, 1)
    rms = np.sqrt((c[hi] - c[lo]) / n + 1e-12)
    db = 20.0 * np.log10(rms + 1e-9)
    ref = np.percentile(db, 95)
    return np.clip((db - (ref - range_db)) / range_db, 0.0, 1.0)


def jaw_opening(poses: np.ndarray) -> np.ndarray:
    """(T,165) axis-angle poses -> (T,) jaw rotation angle (radians) of joint 22."""
    p = np.asarray(poses, dtype=np.float64).reshape(len(poses), -1)
    return np.linalg.norm(p[:, 3 * JAW_JOINT:3 * JAW_JOINT + 3], axis=1)


def upper_speed(joints: np.ndarray, fps: int = FPS) -> np.ndarray:
    """(T,55,3) joint positions -> (T,) mean speed (m/s) of the upper-body joints (frame 0 repeats frame 1)."""
    s = M.joint_speed(joints, fps)[:, list(UPPER_JOINTS)].mean(1)
    return np.concatenate([s[:1], s]) if len(s) else np.zeros(len(joints))


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation; 0 when either signal is constant (a constant motion follows nothing)."""
    a = np.asarray(a, np.float64) - np.mean(a)
    b = np.asarray(b, np.float64) - np.mean(b)
    d = math.sqrt(float((a * a).sum()) * float((b * b).sum()))
    return float((a * b).sum() / d) if d > 1e-12 else 0.0


def _smooth(x: np.ndarray, fps: int = FPS, sigma_s: float = SPEED_SMOOTH_S) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d
    return gaussian_filter1d(np.asarray(x, np.float64), sigma_s * fps, mode="nearest")


# ----------------------------------------------------------------------------- one clip, one audio

class ClipMotion:
    """What the measures need from one motion: joints, jaw opening, upper-body speed."""

    def __init__(self, motion: dict):
        poses = np.asarray(motion["poses"], np.float64).reshape(len(motion["poses"]), -1)
        self.joints = M.joints_from_motion(poses, motion.get("trans"))
        self.jaw = jaw_opening(poses)
        self.speed = upper_speed(self.joints)
        self.n = len(poses)


class ClipAudio:
    def __init__(self, audio: np.ndarray):
        self.audio = np.asarray(audio, np.float64)
        self.onsets = M.detect_onsets(self.audio, SAMPLE_RATE)
        self.n = int(len(self.audio) * FPS // SAMPLE_RATE)
        self.env = speech_envelope(self.audio, self.n)


def clip_measures(m: ClipMotion, a: ClipAudio, speed_ref=None, n_frames: int | None = None) -> dict:
    """The three measures of one motion against one audio, over their common length, or its first
    ``n_frames`` when shorter (BC is NaN when the clip is too short for its trim)."""
    T = min(m.n, a.n) if n_frames is None else min(m.n, a.n, n_frames)
    try:
        bc = M.beat_constancy(m.joints[:T], onset_times=a.onsets, fps=FPS, speed_ref=speed_ref, trim_s=BC_TRIM_S,
                              rule=BC_RULE)
    except ValueError:
        bc = float("nan")
    env = a.env[:T]
    return {"bc": float(bc), "jaw_env": pearson(m.jaw[:T], env),
            "speed_env": pearson(_smooth(m.speed[:T]), _smooth(env)), "frames": int(T)}


# ----------------------------------------------------------------------------- a set

def derangement(n: int) -> list[int]:
    """The fixed mismatch: clip i gets the audio of clip (i + 1) mod n."""
    if n < 2:
        raise ValueError("the mismatched-audio check needs at least 2 clips")
    return [(i + 1) % n for i in range(n)]


def bootstrap_ci(values, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap CI of the mean (resampling the values with replacement)."""
    v = np.asarray([x for x in values if not math.isnan(x)], np.float64)
    if len(v) == 0:
        return float("nan"), float("nan")
    if len(v) == 1:
        return float(v[0]), float(v[0])
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, len(v), size=(n_boot, len(v)))].mean(1)
    a = (1 - level) / 2
    return float(np.quantile(means, a)), float(np.quantile(means, 1 - a))


def _clip_motion(m) -> "ClipMotion":
    return m if isinstance(m, ClipMotion) else ClipMotion(m)


def _clip_audio(a) -> "ClipAudio":
    return a if isinstance(a, ClipAudio) else ClipAudio(a)


def _nanmean(values) -> float:
    v = [x for x in values if not math.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


def _summarise(per_clip: list[dict], n_boot: int, seed: int) -> dict:
    summary = {}
    for k in MEASURES:
        own = np.array([r[k]["own"] for r in per_clip])
        oth = np.array([r[k]["other"] for r in per_clip])
        gap = own - oth
        ok = ~np.isnan(gap)
        lo, hi = bootstrap_ci(gap[ok], n_boot, seed)
        summary[k] = {"own": float(np.mean(own[ok])) if ok.any() else float("nan"),
                      "other": float(np.mean(oth[ok])) if ok.any() else float("nan"),
                      "gap": float(np.mean(gap[ok])) if ok.any() else float("nan"),
                      "gap_ci95": [lo, hi], "wins": float(np.mean(gap[ok] > 0)) if ok.any() else float("nan"),
                      "clips": int(ok.sum())}
    return summary


def evaluate_set(ids: list[str], motions: list[list[dict]], audios: list[np.ndarray], speed_ref=None,
                 n_boot: int = 2000, seed: int = 0, design: str = "audio_swap") -> dict:
    """``motions[i]``: the realisations (>= 1) for clip ``ids[i]`` whose own audio is ``audios[i]`` (16 kHz).
    Returns the summary per measure and per-clip numbers (realisations averaged per clip).

    ``design`` picks the mismatched side of the gap (the own side is the same in both):

    - ``"audio_swap"``: clip i's motion against the audio of clip :func:`derangement` (i) (docs/evaluation.md: "BC with
      the audio of another clip"). The two sides use different onset tracks and envelopes, so a clip whose
      partner's onsets are sparser than its own shows a BC gap whatever its motion (see :func:`chance_bc`);
    - ``"motion_swap"``: clip i's OWN audio against the motion made for every OTHER clip j != i: for each
      pair, own motion i and motion j (realisations averaged) are both scored against the same first T_ij
      frames of audio i (T_ij the common length of audio i, motion i and motion j), and own, other and gap
      are the means over j. The onset track and the envelope are the same on both sides of every pair and
      only the motion changes, so onset density (and clip length) cancels.

    ``motions`` / ``audios`` items may also be prepared :class:`ClipMotion` / :class:`ClipAudio`.
    """
    n = len(ids)
    if not (n == len(motions) == len(audios)):
        raise ValueError(f"evaluate_set: {n} ids, {len(motions)} motions, {len(audios)} audios")
    if design not in DESIGNS:
        raise ValueError(f"evaluate_set: unknown design {design!r} (one of {', '.join(DESIGNS)})")
    perm = derangement(n)
    aud = [_clip_audio(a) for a in audios]
    mot = [[_clip_motion(m) for m in reals] for reals in motions]
    if any(len(r) == 0 for r in mot):
        raise ValueError("evaluate_set: every clip needs at least one realisation")
    per_clip = []
    for i, cid in enumerate(ids):
        own = [clip_measures(cm, aud[i], speed_ref) for cm in mot[i]]
        row = {"id": cid, "realisations": len(mot[i]), "frames": own[0]["frames"]}
        if design == "audio_swap":
            other = [clip_measures(cm, aud[perm[i]], speed_ref) for cm in mot[i]]
            row["other_audio"] = ids[perm[i]]
            for k in MEASURES:
                o, x = _nanmean([r[k] for r in own]), _nanmean([r[k] for r in other])
                row[k] = {"own": o, "other": x, "gap": o - x}
        else:
            # pair (i, j): own and other over the SAME frames of audio i (the common length of audio i, motion
            # i and motion j), so that both sides see the same onsets and envelope; then the mean over j
            row["other_motions"] = n - 1
            pairs = {k: ([], []) for k in MEASURES}
            for j in range(n):
                if j == i:
                    continue
                T = min([aud[i].n] + [cm.n for cm in mot[i]] + [cm.n for cm in mot[j]])
                o_ij = [clip_measures(cm, aud[i], speed_ref, T) for cm in mot[i]]
                x_ij = [clip_measures(cm, aud[i], speed_ref, T) for cm in mot[j]]
                for k in MEASURES:
                    pairs[k][0].append(_nanmean([r[k] for r in o_ij]))
                    pairs[k][1].append(_nanmean([r[k] for r in x_ij]))
            for k in MEASURES:
                ok = [not (math.isnan(o) or math.isnan(x)) for o, x in zip(*pairs[k])]
                o = _nanmean([v for v, g in zip(pairs[k][0], ok) if g])
                x = _nanmean([v for v, g in zip(pairs[k][1], ok) if g])
                row[k] = {"own": o, "other": x, "gap": o - x, "pairs": int(sum(ok))}
        per_clip.append(row)
    return {"design": design, "clips": n, "seconds": round(sum(len(a.audio) for a in aud) / SAMPLE_RATE, 2),
            "summary": _summarise(per_clip, n_boot, seed), "per_clip": per_clip}


# ----------------------------------------------------------------------------- power of the BC gap

def bc_window(n_frames: int, fps: int = FPS, trim_s: float = BC_TRIM_S) -> tuple[int, int]:
    """BC's trimmed window [start, stop) in frames (as :func:`livegesture.eval.metrics.beat_constancy`)."""
    trim = int(round(trim_s * fps))
    return trim, n_frames - trim


def chance_bc(onsets: np.ndarray, n_frames: int, fps: int = FPS, sigma: float = M.SIGMA_S,
              trim_s: float = BC_TRIM_S) -> float:
    """Chance level of Beat Constancy for one onset track: the expected BC of motion beats placed uniformly
    at random on the frames of BC's window (exactly the mean over every window frame of
    exp(-d^2 / 2 sigma^2), d the distance to the nearest onset inside the window). It grows with the onset
    density: with onsets every ``2 sigma`` (0.6 s) or closer, any motion scores about 0.8 or more."""
    start, stop = bc_window(n_frames, fps, trim_s)
    if stop - start < 3:
        return float("nan")
    a = np.asarray(onsets, np.float64)
    a = a[(a >= start / fps) & (a < stop / fps)]
    return M.bc_score(np.arange(start, stop) / fps, a, sigma)


def shifted_bc(m: "ClipMotion", a: "ClipAudio", speed_ref=None, min_shift_s: float = 1.0,
               sigma: float = M.SIGMA_S) -> float:
    """Chance level of Beat Constancy for one motion and one onset track: the mean BC of the motion's own
    beats circularly shifted inside BC's window by every shift of at least ``min_shift_s`` (either way),
    against the same onsets. Keeps the motion's beat count and rhythm and the audio's onsets; only their
    alignment is destroyed."""
    T = min(m.n, a.n)
    try:
        _, det = M.beat_constancy(m.joints[:T], onset_times=a.onsets, fps=FPS, speed_ref=speed_ref,
                                  trim_s=BC_TRIM_S, return_details=True, rule=BC_RULE)
    except ValueError:
        return float("nan")
    start, W = det["start"], det["stop"] - det["start"]
    k = int(math.ceil(min_shift_s * FPS))
    shifts = np.arange(k, W - k + 1)
    onsets = np.sort(np.asarray(det["audio_beats"], np.float64))
    if len(shifts) == 0:
        return float("nan")
    per_joint = []
    for b in det["motion_beats"]:
        if len(b) == 0 or len(onsets) == 0:
            per_joint.append(0.0)
            continue
        t = (((np.asarray(b)[None, :] - start + shifts[:, None]) % W) + start) / FPS   # (shifts, beats)
        pos = np.searchsorted(onsets, t)
        left = onsets[np.clip(pos - 1, 0, len(onsets) - 1)]
        right = onsets[np.clip(pos, 0, len(onsets) - 1)]
        d = np.minimum(np.abs(t - left), np.abs(t - right))
        per_joint.append(float(np.exp(-d * d / (2.0 * sigma * sigma)).mean()))
    return float(np.mean(per_joint))


def onset_power(ids: list[str], motions: list[list], audios: list, audio_swap: dict, motion_swap: dict | None = None,
                speed_ref=None) -> dict:
    """How much power the BC gap has on one set: per clip the onset rate inside BC's window, the chance BC
    of its onset track (:func:`chance_bc`), the motion's BC at chance alignment (:func:`shifted_bc`,
    realisations averaged), and how much of the audio-swap BC gap the difference in chance level between
    the clip's own onset track and its partner's explains (Pearson r, r^2 and least-squares slope of the
    per-clip BC gap on the per-clip chance gap; a gap that is only onset density has slope ~1)."""
    n = len(ids)
    aud = [_clip_audio(a) for a in audios]
    mot = [[_clip_motion(m) for m in reals] for reals in motions]
    perm = derangement(n)
    rows = []
    for i, cid in enumerate(ids):
        T_own = min(mot[i][0].n, aud[i].n)
        T_oth = min(mot[i][0].n, aud[perm[i]].n)
        start, stop = bc_window(T_own)
        a = aud[i].onsets
        n_on = int(((a >= start / FPS) & (a < stop / FPS)).sum())
        c_own, c_oth = chance_bc(aud[i].onsets, T_own), chance_bc(aud[perm[i]].onsets, T_oth)
        row = {"id": cid, "window_s": max(stop - start, 0) / FPS, "onsets": n_on,
               "onsets_per_s": n_on / max((stop - start) / FPS, 1e-9),
               "chance_bc": c_own, "chance_bc_other_audio": c_oth, "chance_gap": c_own - c_oth,
               "shifted_bc": _nanmean([shifted_bc(cm, aud[i], speed_ref) for cm in mot[i]]),
               "bc_own": audio_swap["per_clip"][i]["bc"]["own"],
               "bc_gap_audio_swap": audio_swap["per_clip"][i]["bc"]["gap"]}
        row["bc_gap_audio_swap_minus_chance_gap"] = row["bc_gap_audio_swap"] - row["chance_gap"]
        if motion_swap is not None:
            row["bc_gap_motion_swap"] = motion_swap["per_clip"][i]["bc"]["gap"]
        rows.append(row)
    g = np.array([r["bc_gap_audio_swap"] for r in rows])
    c = np.array([r["chance_gap"] for r in rows])
    ok = ~(np.isnan(g) | np.isnan(c))
    r = pearson(g[ok], c[ok]) if ok.sum() > 2 else float("nan")
    slope = float(np.polyfit(c[ok], g[ok], 1)[0]) if ok.sum() > 2 and np.std(c[ok]) > 0 else float("nan")
    col = lambda k: _nanmean([row[k] for row in rows])
    summary = {"onsets_per_s": col("onsets_per_s"), "chance_bc": col("chance_bc"), "shifted_bc": col("shifted_bc"),
               "bc_own": col("bc_own"),
               "own_above_shifted": float(np.mean([row["bc_own"] > row["shifted_bc"] for row in rows
                                                   if not math.isnan(row["shifted_bc"])])),
               "gap_vs_chance_gap_r": r, "gap_vs_chance_gap_r2": r * r if not math.isnan(r) else float("nan"),
               "gap_vs_chance_gap_slope": slope,
               "bc_gap_audio_swap": col("bc_gap_audio_swap"), "chance_gap": col("chance_gap"),
               "bc_gap_audio_swap_minus_chance_gap": col("bc_gap_audio_swap_minus_chance_gap"),
               "wins_audio_swap_minus_chance_gap": float(np.mean([row["bc_gap_audio_swap_minus_chance_gap"] > 0
                                                                  for row in rows]))}
    if motion_swap is not None:
        summary["bc_gap_motion_swap"] = col("bc_gap_motion_swap")
    return {"summary": summary, "per_clip": rows}


def targets_met(block: dict) -> dict:
    """Issue 16's done-when targets for one set's block (meant for the model on the real split)."""
    s = block["summary"]
    res = {"speed_env_gap": s["speed_env"]["gap"] >= TARGETS["speed_env_gap"],
           "jaw_env_gap": s["jaw_env"]["gap"] >= TARGETS["jaw_env_gap"],
           "bc_gap_positive_on_most_clips": s["bc"]["wins"] > TARGETS["bc_wins"]}
    res["all"] = all(res.values())
    return res


# ----------------------------------------------------------------------------- data of the two sets

def real_set(real_dir=None) -> tuple[list[str], list[np.ndarray]]:
    """The real-speech VALIDATION split: (sorted ids, 16 kHz mono audio)."""
    from ..data import real_speech
    from ..data.beat2 import load_audio
    paths = sorted(real_speech.split_paths("validation", real_dir), key=lambda p: p.stem)
    return [p.stem for p in paths], [load_audio(p, SAMPLE_RATE).astype(np.float64) for p in paths]


def synth_set(data, split: str, max_clips: int | None = None):
    """(sorted ids, audio, corpus motion) of a corpus split."""
    ids = C.read_split(data, split)
    if max_clips:
        ids = ids[:max_clips]
    if len(ids) < 2:
        raise SystemExit(f"{data}: split {split!r} has {len(ids)} clip(s); the check needs at least 2")
    audio = [C.load_audio(C.audio_path(data, c))[0] for c in ids]
    motion = [C.load_motion(C.motion_path(data, c)) for c in ids]
    return ids, audio, motion


def reference_real_motion(audio: np.ndarray, seed: int = 0, drive: str = "flux") -> dict:
    """The synthetic corpus generator's motion for a real recording (speaker 2's style), with the stroke
    ``drive`` of the corpus the model was trained on (``synth --stroke-drive``)."""
    from ..data import synth_motion, synth_speech
    pcm = np.clip(np.round(np.asarray(audio, np.float64) * 32767.0), -32768, 32767) / 32768.0
    an = synth_motion.analyse_audio(pcm)
    T = len(audio) * FPS // SAMPLE_RATE
    poses, trans, expr = synth_motion.generate_motion(an, T, synth_speech.STYLE_BY_SPEAKER[2],
                                                      np.random.default_rng(seed), drive)
    return {"poses": poses, "trans": trans, "expressions": expr}


def train_speed_ref(data) -> np.ndarray | None:
    """Mean joint speed of the corpus's train split (BC's motion-beat reference, as livegesture.eval)."""
    ids = C.read_split(data, "train")
    tot, n = 0.0, 0
    for c in ids:
        m = C.load_motion(C.motion_path(data, c))
        s = M.joint_speed(M.joints_from_motion(m["poses"], m["trans"]), FPS)
        tot, n = tot + s.sum(0), n + len(s)
    return tot / n if n else None


def _load_generated(dirs: list[str], ids: list[str], what: str) -> list[list[dict]]:
    out, missing = [], []
    for cid in ids:
        paths = [Path(d) / f"{cid}.npz" for d in dirs]
        miss = [str(p) for p in paths if not p.exists()]
        if miss:
            missing += miss
            continue
        out.append([C.load_motion(p) for p in paths])
    if missing:
        raise SystemExit(f"{what}: missing generated motion for {len(missing)} clip(s): {', '.join(missing[:6])}"
                         + (" ..." if len(missing) > 6 else ""))
    return out


def _generate(ckpt: str, ids, audios, n: int, seed: int, guidance, device: str = "cpu") -> list[list[dict]]:
    from ..checkpoint import load as load_checkpoint
    from ..stream import generate_clip
    model = load_checkpoint(ckpt).to(device)     # the streaming loop runs where the model is
    out = []
    for k, (cid, x) in enumerate(zip(ids, audios)):
        reals = []
        for r in range(n):
            t0 = time.time()
            g = generate_clip(model, np.asarray(x, np.float32), seed=seed + r, guidance=guidance)
            reals.append({"poses": np.asarray(g["poses"], np.float64), "trans": np.asarray(g["trans"], np.float64),
                          "expressions": np.asarray(g["expressions"], np.float64)})
            _log(f"generated {cid} seed {seed + r}: {len(g['poses'])} frames in {time.time() - t0:.1f} s "
                 f"({k + 1}/{len(ids)})")
        out.append(reals)
    return out


def write_audio(out_dir: Path, ids, audios):
    from scipy.io import wavfile
    out_dir.mkdir(parents=True, exist_ok=True)
    for cid, x in zip(ids, audios):
        pcm = np.clip(np.round(np.asarray(x, np.float64) * 32767.0), -32768, 32767).astype(np.int16)
        tmp = out_dir / f"{cid}.wav.tmp"
        wavfile.write(tmp, SAMPLE_RATE, pcm)
        tmp.replace(out_dir / f"{cid}.wav")


# ----------------------------------------------------------------------------- report

def _f(v, nd=3, sign=False):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "nan"
    return f"{v:+.{nd}f}" if sign else f"{v:.{nd}f}"


SOURCES = ("model", "reference")
DESIGN_TITLES = {"audio_swap": "audio swap: clip i's motion vs its own audio / vs clip i+1's audio",
                 "motion_swap": "motion swap: clip i's own audio vs its own motion / vs the motion of every "
                                "other clip j != i"}


def design_blocks(set_report: dict, design: str) -> dict:
    """{source: block} of one set's report for one design (audio swap: the set's ``model``/``reference``
    blocks; motion swap: those under ``motion_swap``)."""
    src = set_report if design == "audio_swap" else set_report.get("motion_swap", {})
    return {k: src[k] for k in SOURCES if k in src}


def _summary_lines(blocks: dict) -> list[str]:
    lines = [f"{'motion':<10} {'measure':<10} {'own':>7} {'other':>7} {'gap':>7} {'gap 95% CI':>17} {'own>other':>9}"]
    for src, b in blocks.items():
        for k in MEASURES:
            s = b["summary"][k]
            ci = f"[{_f(s['gap_ci95'][0], sign=True)}, {_f(s['gap_ci95'][1], sign=True)}]"
            wins = f"{round(s['wins'] * s['clips'])}/{s['clips']}" if not math.isnan(s["wins"]) else "nan"
            lines.append(f"{src:<10} {k:<10} {_f(s['own']):>7} {_f(s['other']):>7} {_f(s['gap'], sign=True):>7} "
                         f"{ci:>17} {wins:>9}")
    return lines


def _targets_line(t: dict, design: str) -> str:
    return (f"issue-16 targets on real speech (model, {design.replace('_', ' ')}): speed_env gap >= 0.15: "
            f"{t['speed_env_gap']}, jaw_env gap >= 0.6: {t['jaw_env_gap']}, BC gap > 0 on most clips: "
            f"{t['bc_gap_positive_on_most_clips']}")


def format_table(report: dict) -> str:
    lines = []
    for set_name in ("real", "synth"):
        sr = report.get(set_name)
        if not sr:
            continue
        any_block = next(iter(design_blocks(sr, "audio_swap").values()))
        lines.append(f"== {set_name}: {report['sets'][set_name]} ({any_block['clips']} clips, "
                     f"{any_block['seconds']:.0f} s)")
        for design in DESIGNS:
            blocks = design_blocks(sr, design)
            if not blocks:
                continue
            lines.append(f"-- {DESIGN_TITLES[design]}")
            lines += _summary_lines(blocks)
        lines.append("per clip (gap = own - other; a = audio swap, m = motion swap):")
        cols = [(d, src, k) for d in DESIGNS for src in design_blocks(sr, d) for k in MEASURES]
        lines.append(f"  {'id':<38} {'s':>5} "
                     + " ".join(f"{d[0] + ' ' + src[:3] + ' ' + k:>15}" for d, src, k in cols))
        first = any_block["per_clip"]
        for i, row in enumerate(first):
            vals = [_f(design_blocks(sr, d)[src]["per_clip"][i][k]["gap"], sign=True) for d, src, k in cols]
            lines.append(f"  {row['id'][:38]:<38} {row['frames'] / FPS:>5.1f} "
                         + " ".join(f"{v:>15}" for v in vals))
        for src, pw in sr.get("onset_power", {}).items():
            s = pw["summary"]
            lines.append(f"onset density and chance level of BC ({src}; window = BC's, {BC_TRIM_S} s trimmed):")
            lines.append(f"  {'id':<38} {'on/s':>5} {'chance':>7} {'shifted':>7} {'BC own':>7} {'a gap':>7} "
                         f"{'chance gap':>10} {'a-chance':>8} {'m gap':>7}")
            for r in pw["per_clip"]:
                lines.append(f"  {r['id'][:38]:<38} {r['onsets_per_s']:>5.2f} {_f(r['chance_bc']):>7} "
                             f"{_f(r['shifted_bc']):>7} {_f(r['bc_own']):>7} "
                             f"{_f(r['bc_gap_audio_swap'], sign=True):>7} "
                             f"{_f(r['chance_gap'], sign=True):>10} "
                             f"{_f(r['bc_gap_audio_swap_minus_chance_gap'], sign=True):>8} "
                             f"{_f(r.get('bc_gap_motion_swap', float('nan')), sign=True):>7}")
            lines.append(f"  {'mean':<38} {s['onsets_per_s']:>5.2f} {_f(s['chance_bc']):>7} {_f(s['shifted_bc']):>7} "
                         f"{_f(s['bc_own']):>7} {_f(s['bc_gap_audio_swap'], sign=True):>7} "
                         f"{_f(s['chance_gap'], sign=True):>10} "
                         f"{_f(s['bc_gap_audio_swap_minus_chance_gap'], sign=True):>8} "
                         f"{_f(s.get('bc_gap_motion_swap', float('nan')), sign=True):>7}")
            lines.append("  audio-swap BC gap vs chance gap over clips: "
                         f"r = {_f(s['gap_vs_chance_gap_r'], sign=True)}, "
                         f"r^2 = {_f(s['gap_vs_chance_gap_r2'])}, slope = {_f(s['gap_vs_chance_gap_slope'])}; "
                         f"own BC above shifted on {s['own_above_shifted'] * len(pw['per_clip']):.0f}/"
                         f"{len(pw['per_clip'])} clips")
        lines.append("")
    for design in DESIGNS:
        key = "targets_real_model" + ("" if design == "audio_swap" else "_" + design)
        if report.get(key):
            lines.append(_targets_line(report[key], design))
    if report.get("targets_design"):
        lines.append(f"--require-targets reads the {report['targets_design'].replace('_', ' ')} design")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.eval.generalise", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--synth", help="synthetic BEAT2-layout corpus for the held-out synthetic set (and the BC "
                                    "speed reference); without it only the real set is evaluated")
    ap.add_argument("--synth-split", default="test", help="held-out split of --synth (default test)")
    ap.add_argument("--real-speech", help="real-speech folder (default $LIVEGESTURE_REAL_SPEECH or "
                                          "shared/data/real-speech beside the repository)")
    ap.add_argument("--no-real", action="store_true", help="skip the real-speech set")
    ap.add_argument("--reference-drive", default="flux", choices=STROKE_DRIVES,
                    help="the corpus generator's stroke drive for the real set's reference motion: the one the "
                    "model's training corpus used (synth --stroke-drive; default flux, the original corpus)")
    ap.add_argument("--checkpoint", help="generate with this checkpoint (Python streaming reference)")
    ap.add_argument("--device", default="cpu", help="with --checkpoint: run the model here (cpu, cuda)")
    ap.add_argument("--generated-real", action="append", default=[], help="folder of {id}.npz for the real set "
                    "(repeat for several realisations)")
    ap.add_argument("--generated-synth", action="append", default=[], help="folder of {id}.npz for the synth set")
    ap.add_argument("--n-realisations", type=int, default=1, help="seeds per clip with --checkpoint (default 1)")
    ap.add_argument("--seed", type=int, default=1, help="first seed with --checkpoint (default 1)")
    ap.add_argument("--guidance", type=float, default=None, help="CFG scale with --checkpoint (model default)")
    ap.add_argument("--max-clips", type=int, default=None, help="only the first N clips of the synth split")
    ap.add_argument("--bootstrap", type=int, default=2000, help="bootstrap resamples for the CIs")
    ap.add_argument("--write-audio", help="write the sets' 16 kHz mono WAVs to DIR/real and DIR/synth and exit "
                                          "(input for the Rust CLI)")
    ap.add_argument("--out", help="write the report as JSON here (a .txt table beside it)")
    ap.add_argument("--require-targets", action="store_true",
                    help="exit 1 unless the model reaches issue 16's targets on the real set")
    ap.add_argument("--targets-design", choices=DESIGNS, default="audio_swap",
                    help="which mismatch design --require-targets reads (default audio_swap, docs/evaluation.md's \"audio "
                         "of another clip\"); both are always reported")
    a = ap.parse_args(argv)

    sets = {}
    if not a.no_real:
        ids, aud = real_set(a.real_speech)
        sets["real"] = (ids, aud, None)
    if a.synth:
        ids, aud, mot = synth_set(a.synth, a.synth_split, a.max_clips)
        sets["synth"] = (ids, aud, mot)
    if not sets:
        raise SystemExit("nothing to evaluate: give --synth and/or leave the real set on")
    if a.write_audio:
        for name, (ids, aud, _) in sets.items():
            write_audio(Path(a.write_audio) / name, ids, aud)
            _log(f"wrote {len(ids)} WAVs to {Path(a.write_audio) / name}")
        return 0
    gen = {"real": a.generated_real, "synth": a.generated_synth}
    if a.checkpoint and (a.generated_real or a.generated_synth):
        raise SystemExit("give either --checkpoint or --generated-real/--generated-synth, not both")
    if not a.checkpoint:
        for name in sets:
            if not gen[name]:
                raise SystemExit(f"no motion for the {name} set: give --checkpoint or --generated-{name} DIR "
                                 f"(or drop the set: {'--no-real' if name == 'real' else 'leave out --synth'})")
    speed_ref = train_speed_ref(a.synth) if a.synth else None
    report = {"settings": {"fps": FPS, "sample_rate": SAMPLE_RATE,
                           "mismatch": "audio swap: clip i gets the audio of clip (i + 1) mod n (sorted ids); motion "
                                       "swap: clip i's audio gets the motion of every clip j != i",
                           "env_range_db": ENV_RANGE_DB, "speed_smooth_s": SPEED_SMOOTH_S, "bc_trim_s": BC_TRIM_S,
                           "bootstrap": a.bootstrap, "ci": 0.95, "reference_drive": a.reference_drive,
                           "bc_rule": BC_RULE, "bc_speed_ref": "synth train split" if speed_ref is not None else "evaluated motion",
                           "motion": a.checkpoint or gen},
              "sets": {}}
    if "real" in sets:
        from ..data import real_speech
        report["sets"]["real"] = f"real-speech validation split ({', '.join(real_speech.VALIDATION)})"
    if "synth" in sets:
        report["sets"]["synth"] = f"{a.synth} split {a.synth_split}"
    t0 = time.time()
    for name, (ids, aud, mot) in sets.items():
        if a.checkpoint:
            model_m = _generate(a.checkpoint, ids, aud, a.n_realisations, a.seed, a.guidance, device=a.device)
        else:
            model_m = _load_generated(gen[name], ids, f"--generated-{name}")
        ref_m = ([[m] for m in mot] if mot is not None
                 else [[reference_real_motion(x, drive=a.reference_drive)] for x in aud])
        ca = [ClipAudio(x) for x in aud]
        report[name] = {"motion_swap": {}, "onset_power": {}}
        for src, mm in (("model", model_m), ("reference", ref_m)):
            cm = [[ClipMotion(m) for m in reals] for reals in mm]
            report[name][src] = evaluate_set(ids, cm, ca, speed_ref, a.bootstrap, design="audio_swap")
            report[name]["motion_swap"][src] = evaluate_set(ids, cm, ca, speed_ref, a.bootstrap, design="motion_swap")
            report[name]["onset_power"][src] = onset_power(ids, cm, ca, report[name][src],
                                                           report[name]["motion_swap"][src], speed_ref)
    if "real" in report:
        report["targets_real_model"] = targets_met(report["real"]["model"])
        report["targets_real_model_motion_swap"] = targets_met(report["real"]["motion_swap"]["model"])
        report["targets_design"] = a.targets_design
    report["seconds"] = round(time.time() - t0, 1)
    text = format_table(report)
    print(text)
    if a.out:
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(jsonable(report), indent=1))
        tmp.replace(out)
        out.with_suffix(".txt").write_text(text + "\n")
    if a.require_targets and "real" in report:
        key = "targets_real_model" + ("" if a.targets_design == "audio_swap" else "_" + a.targets_design)
        if not report[key]["all"]:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
