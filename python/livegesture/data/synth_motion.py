"""Motion of the synthetic corpus (:mod:`livegesture.data.synth`): the analysis of a clip's 16 kHz audio
(:func:`analyse_audio`, :func:`onset_times`) and the SMPL-X motion model driven by it (:func:`generate_motion`:
upper body, hands, head, face, and the lower body by two-bone IK).

Motion, 30 fps, computed from an analysis of the final 16 kHz audio (:func:`analyse_audio`: RMS energy
envelope, spectral-flux onsets picked like ``librosa.onset.onset_detect``: the project's onset detector
:func:`livegesture.onsets.detect_onsets` with :data:`~livegesture.onsets.SYNTH_ONSETS`, autocorrelation pitch).
Everything audio-driven is causal: an onset at time t only changes frames at or after t.

- arm strokes at stressed onsets: shoulder/elbow/wrist kernels ``(u^2) exp(2 (1 - u))``, ``u = (t - t0)
  / tau``, that start at the onset and peak ``tau`` (0.13-0.24 s) later (stroke types beat, sweep, push,
  point), dominant hand per speaker style, sometimes both hands. Which onsets are stressed, the stroke
  probability and the amplitude read each onset's *drive* (:data:`STROKE_DRIVES`):

  - ``flux`` (the original corpus): the spectral-flux onset strength;
  - ``loudness``: the energy envelope at the onset's frame, a feature every speech has (on real, almost
    continuous speech the flux strength follows the envelope far less than on espeak-ng speech: r 0.50
    against 0.84, docs/experiments.md, the coupling diagnostic);
  - ``syllable``: the envelope's mean over the first 60 ms, the onset's events starting 60 ms later;
  - ``syllable-body``: ``syllable`` for strokes, nods and flicks, the brows on the flux strength (the
    original corpus's face target);
- finger curl changes with the strokes, and a hand shape per phrase; small wrist flicks at every onset;
- gesture space: arms rise while the speaker talks (causally smoothed speech activity) and return to the
  speaker's rest posture in pauses;
- head nods at stressed onsets; head pitch follows the voice pitch; head turns at phrase starts;
- idle sway (sums of slow sinusoids with random phases) and breathing on spine and neck;
- jaw opening follows the energy envelope; expressions 0-9 from energy, pitch and onsets (the others 0);
- lower body: weight shifts (often at phrase starts) and occasional steps; pelvis translation follows the
  weight, the legs are solved by two-bone IK on :mod:`livegesture.skeleton` so planted feet do not slide
  (foot contact is exact);
- five speaker styles (amplitude, handedness, gesture rate, timing, rest posture, sway, jaw, expressions),
  with speaker 2 ("scott") holding about 60 % of the clips and all of train/val/test;
- per clip random choices (which onsets gesture, hand, stroke type, phases, hand shapes, weight shifts),
  so one audio has many plausible motions (:func:`generate_motion` with different generators).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..onsets import SYNTH_ONSETS, detect_onsets
from ..regions import FPS, N_EXPRESSIONS, N_JOINTS, SAMPLE_RATE
from ..skeleton import REST_OFFSETS, axis_angle_to_matrix_np
from .synth_speech import Style


# ----------------------------------------------------------------------------- audio analysis

HOP = SYNTH_ONSETS.hop   # 10 ms analysis hop (160 samples), the onset detector's
ANALYSIS_RATE = SAMPLE_RATE / HOP


@dataclass
class AudioAnalysis:
    """Per 10 ms analysis frame i (its time is ``times[i]``, the centre of its window)."""
    times: np.ndarray          # (n,) seconds
    env: np.ndarray            # (n,) energy envelope in [0, 1]
    active: np.ndarray         # (n,) bool, speech activity
    onset_env: np.ndarray      # (n,) normalised spectral flux in [0, 1]
    f0: np.ndarray             # (n,) Hz, 0 where unvoiced
    onsets: np.ndarray         # (k,) onset times, seconds
    onset_strength: np.ndarray  # (k,) onset envelope value at the onset, [0, 1]
    phrase_start: np.ndarray   # (k,) bool, onset preceded by >= 0.3 s without speech


def _frames(x: np.ndarray, win: int, hop: int) -> np.ndarray:
    n = max(1, 1 + (len(x) - 1) // hop)
    pad = np.concatenate([np.zeros(win // 2), x, np.zeros(win + hop)])
    idx = np.arange(n)[:, None] * hop + np.arange(win)[None, :]
    return pad[idx]


def analyse_audio(audio: np.ndarray, sr: int = SAMPLE_RATE) -> AudioAnalysis:
    """Energy envelope, speech activity, spectral-flux onsets and autocorrelation pitch of a clip."""
    x = np.asarray(audio, dtype=np.float64)
    if sr != SAMPLE_RATE:
        raise ValueError("analyse_audio expects 16 kHz audio")
    fr = _frames(x, SYNTH_ONSETS.win_length, HOP)
    n = len(fr)
    times = np.arange(n) * HOP / sr
    rms = np.sqrt((fr ** 2).mean(1) + 1e-12)
    db = 20 * np.log10(rms + 1e-9)
    ref = np.percentile(db, 95)
    env = np.clip((db - (ref - 40.0)) / 40.0, 0.0, 1.0)
    # speech activity with a 150 ms hangover
    act_raw = db > ref - 28.0
    active = act_raw.copy()
    last = -10 ** 9
    for i in range(n):
        if act_raw[i]:
            last = i
        active[i] = i - last <= 15
    # onsets: the project's onset detector with the corpus settings, only where speech is active
    on = detect_onsets(x, sr, SYNTH_ONSETS, gate=active)
    oe, onsets = on.envelope, on.frames
    # pitch: normalised autocorrelation over 40 ms on active frames
    f0 = np.zeros(n)
    pw, nfft_p = 640, 1024
    lag_lo, lag_hi = sr // 400, sr // 70
    idx = np.nonzero(active & (env > 0.3))[0]
    if len(idx):
        pad = np.concatenate([np.zeros(pw // 2), x, np.zeros(pw)])
        hw = np.hanning(pw)
        wac = np.fft.irfft(np.abs(np.fft.rfft(hw, nfft_p)) ** 2)[:lag_hi + 1]
        for c0 in range(0, len(idx), 2000):
            ii = idx[c0:c0 + 2000]
            seg = pad[ii[:, None] * HOP + np.arange(pw)[None, :]]
            seg = (seg - seg.mean(1, keepdims=True)) * hw
            r = np.fft.irfft(np.abs(np.fft.rfft(seg, nfft_p, axis=1)) ** 2, axis=1)[:, :lag_hi + 1]
            r = r / np.maximum(r[:, :1], 1e-12) / (wac / wac[0])
            lag = lag_lo + np.argmax(r[:, lag_lo:lag_hi], axis=1)
            peak = r[np.arange(len(ii)), lag]
            f0[ii] = np.where(peak > 0.45, sr / lag, 0.0)
    on_t = times[onsets] if len(onsets) else np.zeros(0)
    strength = oe[onsets] if len(onsets) else np.zeros(0)
    ps = np.zeros(len(onsets), dtype=bool)
    for k, i in enumerate(onsets):
        j0 = max(0, i - 30)
        ps[k] = not act_raw[j0:max(j0, i - 2)].any()
    return AudioAnalysis(times=times, env=env, active=active, onset_env=oe, f0=f0, onsets=on_t,
                         onset_strength=strength, phrase_start=ps)


def onset_times(audio: np.ndarray, sr: int = SAMPLE_RATE) -> np.ndarray:
    """Audio onset times in seconds (the onsets the synthetic motion follows)."""
    return analyse_audio(audio, sr).onsets


# ----------------------------------------------------------------------------- motion helpers

def _rot(axes: str, *angles) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of intrinsic rotations about ``axes`` (upper case, e.g. ``"XYZ"``:
    ``Rx(a) @ Ry(b) @ Rz(c)``) by the broadcast angle arrays, via scipy's ``Rotation.from_euler``."""
    ang = np.stack(np.broadcast_arrays(*[np.asarray(x, dtype=np.float64) for x in angles]), -1)
    flat = ang.reshape(-1, len(axes))
    return Rotation.from_euler(axes, flat).as_matrix().reshape(ang.shape[:-1] + (3, 3))


def _rx(a):
    return _rot("X", a)


def _ry(a):
    return _rot("Y", a)


def _rz(a):
    return _rot("Z", a)


def _euler(x, y, z):
    return _rot("XYZ", x, y, z)


_MIRROR = np.outer([-1.0, 1.0, 1.0], [-1.0, 1.0, 1.0])  # M R M for the mirror x -> -x


def _kernel(t: np.ndarray, t0: float, tau: float) -> np.ndarray:
    u = np.maximum(t - t0, 0.0) / tau
    return np.where(t >= t0, u * u * np.exp(2.0 * (1.0 - u)), 0.0)


def _add_kernel(ch: np.ndarray, t0: float, tau: float, amp: float):
    """ch[k] += amp * kernel(k / FPS - t0) over the kernel's support (causal: frames k/FPS >= t0)."""
    k0 = int(np.ceil(t0 * FPS - 1e-9))
    k1 = min(len(ch), int(t0 * FPS + 7 * tau * FPS) + 1)
    if k0 >= k1:
        return
    t = np.arange(k0, k1) / FPS
    ch[k0:k1] += amp * _kernel(t, t0, tau)


def _smooth_noise(T: int, rng, amp: float, fmin: float = 0.03, fmax: float = 0.18, n: int = 3) -> np.ndarray:
    t = np.arange(T) / FPS
    out = np.zeros(T)
    for _ in range(n):
        f = rng.uniform(fmin, fmax)
        out += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) * rng.uniform(0.5, 1.0)
    return amp * out / np.sqrt(n)


def _one_pole(x: np.ndarray, fs: float, tau_up: float, tau_down: float | None = None) -> np.ndarray:
    tau_down = tau_up if tau_down is None else tau_down
    au, ad = 1 - np.exp(-1 / (fs * tau_up)), 1 - np.exp(-1 / (fs * tau_down))
    y = np.empty_like(x, dtype=np.float64)
    acc = float(x[0]) if len(x) else 0.0
    for i, v in enumerate(x):
        acc += (au if v > acc else ad) * (v - acc)
        y[i] = acc
    return y


def _at_frames(a: AudioAnalysis, sig: np.ndarray, T: int) -> np.ndarray:
    """Sample an analysis-rate signal at motion frame k using only analysis frames up to frame k's end."""
    idx = np.minimum(((np.arange(T) + 1) * ANALYSIS_RATE / FPS).astype(int) - 1, len(sig) - 1)
    return sig[np.maximum(idx, 0)]


def _keys(T: int, keys: list[tuple[float, float, np.ndarray]], init) -> np.ndarray:
    """Piecewise smoothstep transitions: keys are (t_start, duration, target value)."""
    init = np.asarray(init, dtype=np.float64)
    out = np.empty((T,) + init.shape)
    t = np.arange(T) / FPS
    cur = init
    out[:] = cur
    for t0, dur, val in sorted(keys, key=lambda k: k[0]):
        val = np.asarray(val, dtype=np.float64)
        u = np.clip((t - t0) / max(dur, 1e-3), 0.0, 1.0)
        s = (u * u * (3 - 2 * u)).reshape((T,) + (1,) * init.ndim)
        m = t >= t0
        out[m] = (cur + (val - cur) * s)[m]
        cur = val
    return out


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrices taking unit vectors a to unit vectors b (..., 3)."""
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1, keepdims=True)
    c = (a * b).sum(-1, keepdims=True)
    ang = np.arctan2(s, c)
    aa = axis / np.maximum(s, 1e-12) * ang
    return axis_angle_to_matrix_np(aa)


# ----------------------------------------------------------------------------- motion

FINGERS = ("index", "middle", "pinky", "ring")
HAND_SHAPES = {  # curl (rad per finger: index, middle, pinky, ring), thumb curl
    "relaxed": (np.array([0.35, 0.45, 0.55, 0.5]), 0.3),
    "open": (np.array([0.06, 0.08, 0.12, 0.1]), 0.08),
    "fist": (np.array([0.9, 1.0, 1.1, 1.05]), 0.6),
    "point": (np.array([0.05, 1.0, 1.1, 1.05]), 0.6),
}
REST_POSTURES = {  # sh_fwd, sh_out, sh_abd, el_flex, pron, curl shape
    "hang": (0.05, 0.0, 0.12, 0.2, 0.0, "relaxed"),
    "clasp": (0.3, -0.45, 0.15, 1.1, 0.3, "relaxed"),
    "front": (0.15, -0.1, 0.15, 0.7, 0.2, "relaxed"),
}


STROKE_DRIVES = ("flux", "loudness", "syllable", "syllable-body")
SYLLABLE_WINDOW = 0.06   # s: the "syllable" drive's loudness window after the onset (and the events' delay)


def onset_loudness(a: AudioAnalysis) -> np.ndarray:
    """The energy envelope (``a.env``, [0, 1]) at each onset's analysis frame: causal, the onset's own frame."""
    if not len(a.onsets):
        return np.zeros(0)
    idx = np.clip(np.round(a.onsets / (a.times[1] - a.times[0])).astype(int), 0, len(a.env) - 1)
    return a.env[idx].astype(np.float64)


def syllable_loudness(a: AudioAnalysis, window: float = SYLLABLE_WINDOW) -> np.ndarray:
    """The mean energy envelope over ``[onset, onset + window]`` of each onset (the syllable's early loudness,
    a steadier reading than the onset's own frame). Known only at ``onset + window``: the ``syllable`` drive
    starts every onset event there, so the motion stays causal."""
    if not len(a.onsets):
        return np.zeros(0)
    hop = a.times[1] - a.times[0]
    i0 = np.clip(np.round(a.onsets / hop).astype(int), 0, len(a.env) - 1)
    n = max(1, int(round(window / hop)))
    c = np.concatenate([[0.0], np.cumsum(a.env, dtype=np.float64)])
    i1 = np.minimum(i0 + n, len(a.env))
    return (c[i1] - c[i0]) / np.maximum(i1 - i0, 1)


# long: one clip's motion built part by part (arms, torso and head, face, assembly, lower body), each a marked block
def generate_motion(analysis: AudioAnalysis, n_frames: int, style: Style, rng: np.random.Generator,
                    drive: str = "flux"):
    """SMPL-X motion for one clip driven by ``analysis`` -> (poses (T,165), trans (T,3), expressions (T,100))
    float32. Different generators give different plausible motions for the same audio. ``drive``: what the
    onset strength of the strokes, nods, flicks and brows is (:data:`STROKE_DRIVES`)."""
    T = n_frames
    t = np.arange(T) / FPS
    a = analysis
    face_a = a   # the brows' onsets and strengths: the drive's, or the flux ones for "syllable-body"
    if drive == "loudness":
        a = face_a = dataclasses.replace(a, onset_strength=onset_loudness(a))
    elif drive in ("syllable", "syllable-body"):
        a = dataclasses.replace(a, onset_strength=syllable_loudness(a), onsets=a.onsets + SYLLABLE_WINDOW)
        face_a = a if drive == "syllable" else face_a
    elif drive != "flux":
        raise ValueError(f"stroke drive {drive!r}: expected one of {', '.join(STROKE_DRIVES)}")
    env = _at_frames(a, a.env, T)
    active = _at_frames(a, a.active.astype(np.float64), T)
    act = _one_pole(_one_pole(active, FPS, 0.2, 0.8), FPS, 0.2, 0.6)  # engagement (gesture space), smooth onset
    env_s = _one_pole(_at_frames(a, _one_pole(a.env, ANALYSIS_RATE, 0.015, 0.06), T), FPS, 0.02, 0.05)
    f0 = a.f0
    voiced = f0 > 0
    med = np.median(f0[voiced]) if voiced.any() else 150.0
    st = np.where(voiced, 12 * np.log2(np.maximum(f0, 1.0) / med), 0.0)
    # hold the last voiced value through unvoiced gaps, then smooth causally
    held = st.copy()
    for i in range(1, len(held)):
        if not voiced[i]:
            held[i] = held[i - 1] * 0.97
    pitch = _one_pole(_at_frames(a, held, T), FPS, 0.12)

    ch: dict[str, np.ndarray] = {}

    def c(name):
        if name not in ch:
            ch[name] = np.zeros(T)
        return ch[name]

    rest = REST_POSTURES[style.rest]
    sides = ("L", "R")
    # gesture-space targets, re-chosen at phrase starts
    on_t, on_s, ps = a.onsets, a.onset_strength, a.phrase_start
    phrase_times = [0.0] + [float(x) for x in on_t[ps]]
    space_keys = {s: [] for s in sides}
    shape_keys = {s: [] for s in sides}
    head_keys, exp_keys = [], []
    for pt in phrase_times:
        for s in sides:
            space_keys[s].append((pt, 0.5, rng.normal(0, 1, 4) * [0.08, 0.12, 0.06, 0.2]))
            shape = rng.choice(["relaxed", "relaxed", "open", "fist"], p=[0.35, 0.25, 0.3, 0.1])
            shape_keys[s].append((pt, 0.35, np.concatenate([HAND_SHAPES[shape][0], [HAND_SHAPES[shape][1]]])))
        head_keys.append((pt, 0.6, rng.normal(0, 1, 2) * [0.12, 0.04]))
        exp_keys.append((pt, 0.8, rng.normal(0, 1, 4) * 0.4 * style.expr_gain))
    dominant_eng = {"R": 1.0 if style.right_prob >= 0.5 else 0.65, "L": 1.0 if style.right_prob < 0.5 else 0.65}

    for s in sides:
        sp = _keys(T, space_keys[s], np.zeros(4))
        hs = _keys(T, shape_keys[s], np.concatenate([HAND_SHAPES[rest[5]][0], [HAND_SHAPES[rest[5]][1]]]))
        eng = act * dominant_eng[s]
        c(f"{s}_sh_fwd")[:] = rest[0] + eng * (0.25 + sp[:, 0]) + _smooth_noise(T, rng, 0.03 * style.sway)
        c(f"{s}_sh_out")[:] = rest[1] * (1 - eng) + eng * (0.1 + sp[:, 1]) + _smooth_noise(T, rng, 0.04 * style.sway)
        c(f"{s}_sh_abd")[:] = rest[2] + eng * (0.08 + sp[:, 2]) + _smooth_noise(T, rng, 0.03 * style.sway)
        el_target = max(rest[3], 0.2 + style.raise_amount)
        c(f"{s}_el_flex")[:] = rest[3] + eng * (el_target - rest[3] + sp[:, 3]) + _smooth_noise(T, rng, 0.05 * style.sway)
        c(f"{s}_pron")[:] = rest[4] + eng * 0.3 + _smooth_noise(T, rng, 0.08 * style.sway)
        c(f"{s}_wr_flex")[:] = 0.1 + _smooth_noise(T, rng, 0.06 * style.sway)
        c(f"{s}_wr_dev")[:] = _smooth_noise(T, rng, 0.04 * style.sway)
        for fi, f in enumerate(FINGERS):
            c(f"{s}_curl_{f}")[:] = hs[:, fi] + _smooth_noise(T, rng, 0.04)
        c(f"{s}_curl_thumb")[:] = hs[:, 4] + _smooth_noise(T, rng, 0.03)
        c(f"{s}_spread")[:] = 0.1 + _smooth_noise(T, rng, 0.05)

    # ---- arm strokes at stressed onsets
    if len(on_s):
        q = np.quantile(on_s, 0.45)
    last_stroke = {"L": -10.0, "R": -10.0}
    last_nod = -10.0
    stroke_types = ("beat", "sweep", "push", "point")
    for t0, s0, phrase0 in zip(on_t, on_s, ps):
        t0 = float(t0)
        stressed = s0 >= q or phrase0
        # small wrist flicks on every onset (syllable rhythm)
        for s in sides:
            _add_kernel(c(f"{s}_wr_flex"), t0, 0.1, 0.05 * style.amp * (0.5 + s0) * rng.uniform(0.5, 1.2)
                        * (0.4 + 0.6 * float(np.interp(t0, t, act))))
        if not stressed:
            continue
        if rng.random() < style.nod_rate and t0 - last_nod > 0.35:
            amp = style.nod_amp * (0.5 + s0) * rng.uniform(0.6, 1.3)
            tau = rng.uniform(0.11, 0.16)
            _add_kernel(c("head_x"), t0, tau, amp)
            _add_kernel(c("neck_x"), t0, tau, 0.3 * amp)
            last_nod = t0
        if rng.random() > style.gesture_rate * (0.6 + 0.6 * s0):
            continue
        r = rng.random()
        if r < style.both_prob:
            hands = ("L", "R")
        else:
            hands = ("R",) if rng.random() < style.right_prob else ("L",)
        hands = tuple(h for h in hands if t0 - last_stroke[h] >= style.min_gap)
        if not hands:
            continue
        kind = stroke_types[rng.choice(4, p=np.asarray(style.stroke_weights) / sum(style.stroke_weights))]
        amp = style.amp * (0.55 + 0.9 * s0) * np.exp(rng.normal(0, 0.2))
        tau = rng.uniform(*style.tau)
        for h in hands:
            d = rng.uniform(0.0, 0.03) if len(hands) == 2 else 0.0   # both hands: slight lag, never early
            th, ah = t0 + d, amp * rng.uniform(0.85, 1.15)
            if kind == "beat":
                _add_kernel(c(f"{h}_el_flex"), th, tau, -0.38 * ah)
                _add_kernel(c(f"{h}_wr_flex"), th, 0.8 * tau, 0.28 * ah)
                _add_kernel(c(f"{h}_sh_fwd"), th, tau, 0.06 * ah)
                for f in FINGERS:
                    _add_kernel(c(f"{h}_curl_{f}"), th, tau, -0.15 * ah)
            elif kind == "sweep":
                _add_kernel(c(f"{h}_sh_out"), th, tau, 0.38 * ah)
                _add_kernel(c(f"{h}_pron"), th, tau, 0.45 * ah)
                _add_kernel(c(f"{h}_el_flex"), th, tau, -0.12 * ah)
                for f in FINGERS:
                    _add_kernel(c(f"{h}_curl_{f}"), th, tau, -0.35 * ah)
                _add_kernel(c(f"{h}_spread"), th, tau, 0.15 * ah)
            elif kind == "push":
                _add_kernel(c(f"{h}_sh_fwd"), th, tau, 0.3 * ah)
                _add_kernel(c(f"{h}_el_flex"), th, tau, -0.3 * ah)
                _add_kernel(c(f"{h}_wr_flex"), th, tau, -0.22 * ah)
                for f in FINGERS:
                    _add_kernel(c(f"{h}_curl_{f}"), th, tau, -0.3 * ah)
            else:  # point
                _add_kernel(c(f"{h}_sh_fwd"), th, tau, 0.15 * ah)
                _add_kernel(c(f"{h}_el_flex"), th, tau, -0.25 * ah)
                _add_kernel(c(f"{h}_wr_flex"), th, 0.8 * tau, 0.15 * ah)
                _add_kernel(c(f"{h}_curl_index"), th, tau, -0.4 * ah)
                for f in ("middle", "pinky", "ring"):
                    _add_kernel(c(f"{h}_curl_{f}"), th, tau, 0.35 * ah)
                _add_kernel(c(f"{h}_curl_thumb"), th, tau, 0.2 * ah)
            sign = 1.0 if h == "R" else -1.0
            _add_kernel(c("spine_y"), th, tau, 0.035 * sign * ah)
            _add_kernel(c("spine_x"), th, tau, 0.015 * ah)
            last_stroke[h] = th

    # ---- torso, head
    breath_f = rng.uniform(0.2, 0.3)
    breath = np.sin(2 * np.pi * breath_f * t + rng.uniform(0, 2 * np.pi))
    c("spine_x")[:] += 0.03 * act + _smooth_noise(T, rng, 0.015 * style.sway) + 0.012 * breath
    c("spine_y")[:] += _smooth_noise(T, rng, 0.03 * style.sway)
    c("spine_z")[:] += _smooth_noise(T, rng, 0.02 * style.sway)
    hk = _keys(T, head_keys, np.zeros(2))
    c("neck_x")[:] += 0.05 + _smooth_noise(T, rng, 0.02 * style.sway) - 0.008 * breath
    c("head_x")[:] += -0.02 * np.clip(pitch, -6, 8) / 3 * style.expr_gain + _smooth_noise(T, rng, 0.03 * style.sway)
    c("head_y")[:] += hk[:, 0] * act + _smooth_noise(T, rng, 0.06 * style.sway, 0.03, 0.2)
    c("head_z")[:] += hk[:, 1] + _smooth_noise(T, rng, 0.03 * style.sway)
    c("collar_z")[:] = 0.015 * breath

    # ---- face
    jaw = style.jaw_gain * np.power(np.clip(env_s, 0, 1), 1.2) + 0.01
    ek = _keys(T, exp_keys, np.zeros(4))
    expr = np.zeros((T, N_EXPRESSIONS))
    brow = np.zeros(T)
    fq = np.quantile(face_a.onset_strength, 0.45) if len(face_a.onsets) else 1.0
    for t0, s0 in zip(face_a.onsets, face_a.onset_strength):
        if s0 >= fq and rng.random() < 0.5:
            _add_kernel(brow, float(t0), 0.2, (0.6 + s0) * rng.uniform(0.5, 1.2))
    g = style.expr_gain
    expr[:, 0] = g * (2.2 * env_s - 0.3) + 0.15 * _smooth_noise(T, rng, 1.0)
    expr[:, 1] = g * 0.35 * np.clip(pitch, -8, 8)
    expr[:, 2] = g * 0.9 * brow + ek[:, 0]
    expr[:, 3] = g * (-0.8 * env_s) + rng.uniform(-0.5, 0.8) + ek[:, 1]
    expr[:, 4] = g * 0.6 * act + ek[:, 2]
    expr[:, 5] = g * 0.5 * brow - 0.2 * np.clip(pitch, -8, 8) * g
    expr[:, 6] = ek[:, 3] + _smooth_noise(T, rng, 0.3)
    expr[:, 7] = g * 0.8 * _one_pole(env, FPS, 0.3, 0.8) + _smooth_noise(T, rng, 0.2)
    expr[:, 8] = _smooth_noise(T, rng, 0.25, 0.02, 0.1)
    expr[:, 9] = _smooth_noise(T, rng, 0.25, 0.02, 0.1) + 0.3 * g * np.clip(pitch, -8, 8) / 4 * act

    # ---- assemble local rotations
    R = np.tile(np.eye(3), (T, N_JOINTS, 1, 1))
    R[:, 3] = _euler(c("spine_x") * 0.4, c("spine_y") * 0.35, c("spine_z") * 0.4)
    R[:, 6] = _euler(c("spine_x") * 0.3, c("spine_y") * 0.35, c("spine_z") * 0.3)
    R[:, 9] = _euler(c("spine_x") * 0.3, c("spine_y") * 0.3, c("spine_z") * 0.3)
    R[:, 12] = _euler(c("neck_x"), c("head_y") * 0.4, c("head_z") * 0.4)
    R[:, 15] = _euler(c("head_x") - 0.05, c("head_y") * 0.6, c("head_z") * 0.6)
    R[:, 22] = _euler(jaw, _smooth_noise(T, rng, 0.01), np.zeros(T))
    for s, (collar, sh, el, wr, hand0) in (("L", (13, 16, 18, 20, 25)), ("R", (14, 17, 19, 21, 40))):
        Rs = {}
        Rs[collar] = _rz(c("collar_z"))
        Rs[sh] = _rx(-c(f"{s}_sh_fwd")) @ _ry(c(f"{s}_sh_out")) @ _rz(-np.pi / 2 + 0.06 + c(f"{s}_sh_abd"))
        Rs[el] = _ry(-c(f"{s}_el_flex")) @ _rx(c(f"{s}_pron"))
        Rs[wr] = _rz(-c(f"{s}_wr_flex")) @ _ry(c(f"{s}_wr_dev"))
        spread = c(f"{s}_spread")
        for fi, f in enumerate(("index", "middle", "pinky", "ring", "thumb")):
            cu = c(f"{s}_curl_{f}")
            if f == "thumb":
                Rs[hand0 + 12] = _rx(-0.5 * cu) @ _rz(-0.3 * cu) @ _ry(0.2 * cu)
                Rs[hand0 + 13] = _rz(-0.6 * cu)
                Rs[hand0 + 14] = _rz(-0.5 * cu)
                continue
            spr = {"index": 0.12, "middle": 0.0, "ring": -0.08, "pinky": -0.16}[f] * spread
            Rs[hand0 + 3 * fi] = _ry(spr) @ _rz(-0.9 * cu)
            Rs[hand0 + 3 * fi + 1] = _rz(-1.1 * cu)
            Rs[hand0 + 3 * fi + 2] = _rz(-0.75 * cu)
        for j, Rj in Rs.items():
            R[:, j] = Rj if s == "L" else Rj * _MIRROR

    # ---- lower body: pelvis from the weight, legs by IK
    pelvis_R, trans = _lower_body(T, a, style, rng, act, breath, R)
    R[:, 0] = pelvis_R

    aa = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(T, N_JOINTS, 3)
    aa[:, 23:25] = 0.0
    poses = aa.reshape(T, 3 * N_JOINTS)
    return poses.astype(np.float32), trans.astype(np.float32), expr.astype(np.float32)


_O = np.asarray(REST_OFFSETS, dtype=np.float64)


def _knee_table(side: int):
    """Hip-to-ankle distance as a function of knee flexion phi, on its monotonic branch."""
    ok, oa = _O[4 + side], _O[7 + side]
    phi = np.linspace(-0.3, 2.4, 2701)
    v = ok[None, :] + (_rx(phi) @ oa)
    d = np.linalg.norm(v, axis=-1)
    i0 = int(np.argmax(d))
    return phi[i0:], d[i0:]


def _lower_body(T, a: AudioAnalysis, style: Style, rng, act, breath, R):
    """Weight shifts and steps -> pelvis global rotation (T,3,3), trans (T,3); fills leg rotations in R."""
    t = np.arange(T) / FPS
    nominal = {0: np.array([0.10, 0.0]), 1: np.array([-0.10, 0.0])}   # ankle x, z per foot (0 left, 1 right)
    feet = {f: nominal[f] + rng.normal(0, 0.015, 2) for f in (0, 1)}
    start_feet = {f: feet[f].copy() for f in (0, 1)}
    w_keys, foot_keys, lifts = [], {0: [], 1: []}, []
    w0 = 0.5 + rng.normal(0, 0.1)
    # event times: a Poisson process, with a tendency to move at phrase starts
    ev, tt = [], rng.exponential(1 / style.shift_rate) * 0.5
    phrase = [float(x) for x in a.onsets[a.phrase_start]]
    while tt < T / FPS - 1.5:
        near = [p for p in phrase if tt <= p < tt + 2.0]
        if near and rng.random() < 0.6:
            tt = near[0]
        ev.append(tt)
        tt += 1.8 + rng.exponential(1 / style.shift_rate)
    busy_until = 0.0
    for te in ev:
        if te < busy_until:
            continue
        if rng.random() < style.step_prob and te + 2.0 < T / FPS:
            f = int(rng.integers(2))
            w_keys.append((te, 0.5, 0.85 if f == 1 else 0.15))   # weight onto the other foot (w = 1: left)
            ts, dur = te + 0.45, rng.uniform(0.35, 0.5)
            for _ in range(20):   # a step of 6-15 cm that stays near the nominal stance
                new = feet[f] + rng.normal(0, 1, 2) * [0.08, 0.1]
                if 0.06 <= np.linalg.norm(new - feet[f]) <= 0.15 and np.linalg.norm(new - nominal[f]) <= 0.12:
                    break
            else:
                new = nominal[f] + 0.0
            foot_keys[f].append((ts, dur, new))
            lifts.append((f, ts, dur, rng.uniform(0.04, 0.08)))
            feet[f] = new
            w = float(np.clip(0.5 + rng.normal(0, 0.12), 0.3, 0.7))
            w_keys.append((ts + dur + 0.05, 0.6, w))
            busy_until = ts + dur + 0.7
        else:
            w = float(np.clip(rng.choice([0.25, 0.75]) + rng.normal(0, 0.08), 0.15, 0.85))
            dur = rng.uniform(0.6, 1.2)
            w_keys.append((te, dur, w))
            busy_until = te + dur
    W = _keys(T, w_keys, w0)
    F = {f: _keys(T, foot_keys[f], start_feet[f]) for f in (0, 1)}
    lift = {0: np.zeros(T), 1: np.zeros(T)}
    for f, ts, dur, h in lifts:
        u = np.clip((t - ts) / dur, 0, 1)
        lift[f] += h * np.sin(np.pi * u) * ((t >= ts) & (t <= ts + dur))
    # pelvis position: between the feet, towards the loaded one, plus sway and a small bob
    wl = 0.5 + (W - 0.5) * 0.7
    pel_xz = wl[:, None] * F[0] + (1 - wl[:, None]) * F[1]
    pel_xz += np.stack([_smooth_noise(T, rng, 0.006 * style.sway), _smooth_noise(T, rng, 0.008 * style.sway)], 1)
    ankle_y0 = _O[0, 1] + _O[1, 1] + _O[4, 1] + _O[7, 1]     # rest ankle height at trans = 0
    drop = rng.uniform(0.008, 0.018)
    pel_y = -drop - 0.006 * np.abs(W - 0.5) + 0.002 * breath
    trans = np.stack([pel_xz[:, 0], pel_y, pel_xz[:, 1] + 0.02], 1)
    roll = (W - 0.5) * 0.08 + _smooth_noise(T, rng, 0.01 * style.sway)   # the loaded hip is higher
    yaw = _smooth_noise(T, rng, 0.04 * style.sway, 0.02, 0.15)
    pitch = 0.02 * act + _smooth_noise(T, rng, 0.008)
    Rp = _euler(pitch, yaw, roll)
    R[:, 3] = _rz(-0.7 * roll) @ R[:, 3]                      # the spine keeps the torso upright
    legs = ((0, (1, 4, 7, 10)), (1, (2, 5, 8, 11)))
    targets = {side: np.stack([F[side][:, 0], ankle_y0 + lift[side], F[side][:, 1]], 1) for side, _ in legs}
    tables = {side: _knee_table(side) for side, _ in legs}
    # lower the pelvis where a leg could not reach its planted foot (keeps the feet exactly in place)
    need = np.zeros(T)
    for side, (hip, knee, ankle, foot) in legs:
        d = targets[side] - (trans + _O[0] + Rp @ _O[hip])
        reach = 0.99 * tables[side][1][0]
        horiz2 = d[:, 0] ** 2 + d[:, 2] ** 2
        vert = np.sqrt(np.maximum(reach ** 2 - horiz2, 0.0))
        need = np.maximum(need, -d[:, 1] - vert)
    if need.max() > 0:
        from scipy.ndimage import gaussian_filter1d, maximum_filter1d
        need = gaussian_filter1d(maximum_filter1d(need, 15), 3.0) * 1.05 + (need > 0) * 1e-4
        trans[:, 1] -= np.maximum(need, 0.0)
    p_pelvis = trans + _O[0]
    foot_yaw = {0: 0.12 + rng.normal(0, 0.04), 1: -0.12 + rng.normal(0, 0.04)}
    for side, (hip, knee, ankle, foot) in legs:
        hip_w = p_pelvis + (Rp @ _O[hip])
        d_loc = np.einsum("tji,tj->ti", Rp, targets[side] - hip_w)     # R^T d
        D = np.linalg.norm(d_loc, axis=-1)
        phi_tab, d_tab = tables[side]
        phi = np.interp(D, d_tab[::-1], phi_tab[::-1])
        v_rest = _O[knee][None, :] + (_rx(phi) @ _O[ankle])
        R_hip = _min_rotation(v_rest / np.linalg.norm(v_rest, axis=-1, keepdims=True),
                              d_loc / np.maximum(D[:, None], 1e-9))
        R_knee = _rx(phi)
        Ff = _ry(np.full(T, foot_yaw[side]))
        shin = Rp @ R_hip @ R_knee
        R[:, hip] = R_hip
        R[:, knee] = R_knee
        R[:, ankle] = np.swapaxes(shin, -1, -2) @ Ff
        R[:, foot] = np.eye(3)
    return Rp, trans
