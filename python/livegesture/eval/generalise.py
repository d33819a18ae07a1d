"""Generalisation check: does a model's motion follow REAL speech, not only the voices it was trained on?

    python -m livegesture.eval.generalise --synth CORPUS [--real-speech DIR]
        (--checkpoint CKPT | --generated-real DIR [--generated-synth DIR] ...) [--out report.json]

Two sets of audio, each evaluated with the same three measures:

- ``real``: the real-speech VALIDATION split (:data:`livegesture.data.real_speech.VALIDATION`, 8 recordings
  of real people, never trained on), read at any rate/channel count and resampled to 16 kHz mono
  (``scipy.signal.resample_poly`` through :func:`livegesture.data.beat2.load_audio`);
- ``synth``: the held-out split (``--synth-split``, default ``test``) of a synthetic corpus (``--synth``),
  i.e. synthetic voices and sentences the model was not trained on.

For every clip i, its motion is scored against its OWN audio and against ANOTHER clip's audio (a fixed
derangement: clip i of the sorted ids gets the audio of clip (i + 1) mod n), over their common length:

- ``bc``: Beat Constancy (:func:`livegesture.eval.metrics.beat_constancy`, upper-body joints, onsets from
  :func:`~livegesture.eval.metrics.detect_onsets`, the same settings as ``python -m livegesture.eval`` but
  a 0.5 s trim at each end instead of 2 s, ``BC_TRIM_S``: some recordings are only 4-5 s long);
- ``jaw_env``: Pearson correlation between the jaw opening (angle of the jaw joint's axis-angle, joint 22)
  and the speech envelope (:func:`speech_envelope`: log RMS energy per motion frame over a 2-frame window,
  50 dB range below the clip's 95th percentile, mapped to [0, 1]);
- ``speed_env``: Pearson correlation between the upper-body speed (mean speed of the upper-body joints,
  project skeleton, translation removed) and the envelope, both smoothed with a centred Gaussian
  (sigma ``SPEED_SMOOTH_S`` = 0.2 s) so that a stroke that peaks a few frames after its syllable counts.

Per measure and set: the mean over clips of own, other and their difference (``gap``), a 95 % bootstrap
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
(:func:`livegesture.data.synth.generate_motion`, speaker 2's style, seed 0) computes from the recording —
what a model trained on that corpus is asked to learn, i.e. what the check can show at most.

``--require-targets`` exits with status 1 unless the model's real-speech gaps reach the targets of issue 16
(speed_env gap >= 0.15, jaw_env gap >= 0.6, positive BC gap on more than half of the clips).
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
from ..regions import FPS, JAW_JOINT, SAMPLE_RATE, UPPER_JOINTS, frame_start_sample

SPEED_SMOOTH_S = 0.2
BC_TRIM_S = 0.5          # the recordings are 4-30 s: livegesture.eval's 2 s trim would leave nothing of some
ENV_RANGE_DB = 50.0
MEASURES = ("bc", "jaw_env", "speed_env")
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


def clip_measures(m: ClipMotion, a: ClipAudio, speed_ref=None) -> dict:
    """The three measures of one motion against one audio, over their common length (BC is NaN when the
    clip is too short for its trim)."""
    T = min(m.n, a.n)
    try:
        bc = M.beat_constancy(m.joints[:T], onset_times=a.onsets, fps=FPS, speed_ref=speed_ref, trim_s=BC_TRIM_S)
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


def evaluate_set(ids: list[str], motions: list[list[dict]], audios: list[np.ndarray], speed_ref=None,
                 n_boot: int = 2000, seed: int = 0) -> dict:
    """``motions[i]``: the realisations (>= 1) for clip ``ids[i]`` whose own audio is ``audios[i]`` (16 kHz).
    Returns the summary per measure and per-clip numbers (realisations averaged per clip)."""
    n = len(ids)
    if not (n == len(motions) == len(audios)):
        raise ValueError(f"evaluate_set: {n} ids, {len(motions)} motions, {len(audios)} audios")
    perm = derangement(n)
    aud = [ClipAudio(a) for a in audios]
    per_clip = []
    for i, cid in enumerate(ids):
        own, other = [], []
        for mo in motions[i]:
            cm = ClipMotion(mo)
            own.append(clip_measures(cm, aud[i], speed_ref))
            other.append(clip_measures(cm, aud[perm[i]], speed_ref))
        row = {"id": cid, "other_audio": ids[perm[i]], "realisations": len(motions[i]),
               "frames": own[0]["frames"]}
        for k in MEASURES:
            o = float(np.nanmean([r[k] for r in own])) if any(not math.isnan(r[k]) for r in own) else float("nan")
            x = float(np.nanmean([r[k] for r in other])) if any(not math.isnan(r[k]) for r in other) else float("nan")
            row[k] = {"own": o, "other": x, "gap": o - x}
        per_clip.append(row)
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
    return {"clips": n, "seconds": round(sum(len(a) for a in audios) / SAMPLE_RATE, 2), "summary": summary,
            "per_clip": per_clip}


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


def reference_real_motion(audio: np.ndarray, seed: int = 0) -> dict:
    """The synthetic corpus generator's motion for a real recording (speaker 2's style)."""
    from ..data import synth
    pcm = np.clip(np.round(np.asarray(audio, np.float64) * 32767.0), -32768, 32767) / 32768.0
    an = synth.analyse_audio(pcm)
    T = len(audio) * FPS // SAMPLE_RATE
    poses, trans, expr = synth.generate_motion(an, T, synth.STYLE_BY_SPEAKER[2], np.random.default_rng(seed))
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


def _generate(ckpt: str, ids, audios, n: int, seed: int, guidance) -> list[list[dict]]:
    from ..checkpoint import load as load_checkpoint
    from ..stream import generate_clip
    model = load_checkpoint(ckpt)
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


def format_table(report: dict) -> str:
    lines = []
    for set_name in ("real", "synth"):
        blocks = report.get(set_name)
        if not blocks:
            continue
        any_block = next(iter(blocks.values()))
        lines.append(f"== {set_name}: {report['sets'][set_name]} ({any_block['clips']} clips, "
                     f"{any_block['seconds']:.0f} s)")
        lines.append(f"{'motion':<10} {'measure':<10} {'own':>7} {'other':>7} {'gap':>7} {'gap 95% CI':>17} "
                     f"{'own>other':>9}")
        for src, b in blocks.items():
            for k in MEASURES:
                s = b["summary"][k]
                ci = f"[{_f(s['gap_ci95'][0], sign=True)}, {_f(s['gap_ci95'][1], sign=True)}]"
                wins = f"{round(s['wins'] * s['clips'])}/{s['clips']}" if not math.isnan(s["wins"]) else "nan"
                lines.append(f"{src:<10} {k:<10} {_f(s['own']):>7} {_f(s['other']):>7} {_f(s['gap'], sign=True):>7} "
                             f"{ci:>17} {wins:>9}")
        lines.append("per clip (gap = own - other):")
        lines.append(f"  {'id':<38} {'s':>5} " + " ".join(f"{src[:5] + ' ' + k:>18}" for src in blocks
                                                           for k in MEASURES))
        first = next(iter(blocks.values()))["per_clip"]
        for i, row in enumerate(first):
            vals = [_f(blocks[src]["per_clip"][i][k]["gap"], sign=True) for src in blocks for k in MEASURES]
            lines.append(f"  {row['id'][:38]:<38} {row['frames'] / FPS:>5.1f} " + " ".join(f"{v:>18}" for v in vals))
        lines.append("")
    if report.get("targets_real_model"):
        t = report["targets_real_model"]
        lines.append("issue-16 targets on real speech (model): speed_env gap >= 0.15: "
                     f"{t['speed_env_gap']}, jaw_env gap >= 0.6: {t['jaw_env_gap']}, BC gap > 0 on most clips: "
                     f"{t['bc_gap_positive_on_most_clips']}")
    return "\n".join(lines)


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.eval.generalise", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--synth", help="synthetic BEAT2-layout corpus for the held-out synthetic set (and the BC "
                                    "speed reference); without it only the real set is evaluated")
    ap.add_argument("--synth-split", default="test", help="held-out split of --synth (default test)")
    ap.add_argument("--real-speech", help="real-speech folder (default $LIVEGESTURE_REAL_SPEECH or "
                                          "shared/data/real-speech beside the repository)")
    ap.add_argument("--no-real", action="store_true", help="skip the real-speech set")
    ap.add_argument("--checkpoint", help="generate with this checkpoint (Python streaming reference)")
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
    report = {"settings": {"fps": FPS, "sample_rate": SAMPLE_RATE, "mismatch": "clip i gets the audio of clip "
                           "(i + 1) mod n (sorted ids)", "env_range_db": ENV_RANGE_DB,
                           "speed_smooth_s": SPEED_SMOOTH_S, "bc_trim_s": BC_TRIM_S, "bootstrap": a.bootstrap, "ci": 0.95,
                           "bc_speed_ref": "synth train split" if speed_ref is not None else "evaluated motion",
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
            model_m = _generate(a.checkpoint, ids, aud, a.n_realisations, a.seed, a.guidance)
        else:
            model_m = _load_generated(gen[name], ids, f"--generated-{name}")
        ref_m = [[m] for m in mot] if mot is not None else [[reference_real_motion(x)] for x in aud]
        report[name] = {"model": evaluate_set(ids, model_m, aud, speed_ref, a.bootstrap),
                        "reference": evaluate_set(ids, ref_m, aud, speed_ref, a.bootstrap)}
    if "real" in report:
        report["targets_real_model"] = targets_met(report["real"]["model"])
    report["seconds"] = round(time.time() - t0, 1)
    text = format_table(report)
    print(text)
    if a.out:
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(_jsonable(report), indent=1))
        tmp.replace(out)
        out.with_suffix(".txt").write_text(text + "\n")
    if a.require_targets and "real" in report and not report["targets_real_model"]["all"]:
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
