"""How much of the real-speech speed gap comes from the first/last seconds of each recording?

    python docs/eval/diffsheg-confirm-2026-11-25/headtail.py --generated DIR [--generated DIR ...] \
        [--audio-dir WAVS] [--trim 0 0.5 1.0] [--out report.json]

For each trim (seconds cut at EACH end) it recomputes `python -m livegesture.eval.generalise`'s
upper-body speed-vs-envelope and jaw-vs-envelope gaps, both designs (audio swap: clip i's motion vs clip
i+1's audio; motion swap: clip i's audio vs the motion of every other clip), with the same signals
(`upper_speed`, `speech_envelope`, Gaussian smoothing 0.2 s, over the common length), but the Pearson
correlation is taken only over frames [trim, T - trim) of the smoothed signals (the smoothing runs on the
whole clip first, so trimming adds no new edge). trim 0 reproduces generalise's numbers exactly (checked
by --check REPORT.json). Bootstrap: generalise's `bootstrap_ci` (2000 resamples, seed 0).

It also prints the speed/envelope profile: mean smoothed upper-body speed and envelope over the first
0.5 s, the rest of the first FOPPAS window (frames 15..77, the window sampled by plain DDIM), the middle
(frames 78 .. T-1-LAST), the last window's frames before its last 0.5 s, and the last 0.5 s.

--audio-dir: a folder of 16 kHz WAVs {id}.wav (default: the real-speech validation split as generalise
reads it). Motion folders hold {id}.npz (livegesture generate output).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from livegesture.eval import corpus as C
from livegesture.eval import generalise as G
from livegesture.diffsheg.foppas import plan_windows
from livegesture.regions import FPS, SAMPLE_RATE


def load_wavs(d: Path):
    from livegesture.data.beat2 import load_audio
    paths = sorted(Path(d).glob("*.wav"), key=lambda p: p.stem)
    if len(paths) < 2:
        raise SystemExit(f"{d}: needs at least 2 WAVs, found {len(paths)}")
    return [p.stem for p in paths], [load_audio(p, SAMPLE_RATE).astype(np.float64) for p in paths]


def corr_trim(sig: np.ndarray, env: np.ndarray, T: int, trim: int, smooth: bool) -> float:
    a = G._smooth(sig[:T]) if smooth else np.asarray(sig[:T], np.float64)
    b = G._smooth(env[:T]) if smooth else np.asarray(env[:T], np.float64)
    lo, hi = trim, T - trim
    if hi - lo < 10:
        return float("nan")
    return G.pearson(a[lo:hi], b[lo:hi])


def gaps(ids, mot, aud, trim_s: float, n_boot: int = 2000) -> dict:
    trim = int(round(trim_s * FPS))
    n = len(ids)
    perm = G.derangement(n)
    out = {}
    for design in G.DESIGNS:
        rows = []
        for i in range(n):
            row = {}
            for key, smooth in (("speed_env", True), ("jaw_env", False)):
                sig = (lambda cm: cm.speed) if key == "speed_env" else (lambda cm: cm.jaw)
                if design == "audio_swap":
                    o = np.nanmean([corr_trim(sig(cm), aud[i].env, min(cm.n, aud[i].n), trim, smooth) for cm in mot[i]])
                    x = np.nanmean([corr_trim(sig(cm), aud[perm[i]].env, min(cm.n, aud[perm[i]].n), trim, smooth)
                                    for cm in mot[i]])
                else:
                    os_, xs = [], []
                    for j in range(n):
                        if j == i:
                            continue
                        T = min([aud[i].n] + [cm.n for cm in mot[i]] + [cm.n for cm in mot[j]])
                        os_.append(np.nanmean([corr_trim(sig(cm), aud[i].env, T, trim, smooth) for cm in mot[i]]))
                        xs.append(np.nanmean([corr_trim(sig(cm), aud[i].env, T, trim, smooth) for cm in mot[j]]))
                    o, x = float(np.nanmean(os_)), float(np.nanmean(xs))
                row[key] = {"own": float(o), "other": float(x), "gap": float(o - x)}
            rows.append(row)
        summ = {}
        for key in ("speed_env", "jaw_env"):
            g = np.array([r[key]["gap"] for r in rows])
            lo, hi = G.bootstrap_ci(g, n_boot, 0)
            summ[key] = {"own": float(np.mean([r[key]["own"] for r in rows])),
                         "other": float(np.mean([r[key]["other"] for r in rows])),
                         "gap": float(np.mean(g)), "gap_ci95": [lo, hi], "wins": int((g > 0).sum()),
                         "clips": n, "per_clip_gap": [float(v) for v in g]}
        out[design] = summ
    return out


def profile(ids, mot, aud, window: int = 88, overlap: int = 10) -> dict:
    """Mean smoothed upper-body speed / envelope per segment, averaged over clips and realisations."""
    H = int(0.5 * FPS)
    seg_names = ("first 0.5 s", "rest of window 0", "middle", "last window before its last 0.5 s", "last 0.5 s")
    acc = {k: {"speed": [], "env": [], "jaw": []} for k in seg_names}
    for i in range(len(ids)):
        T = aud[i].n
        plan = plan_windows(T, window, overlap)
        w0_end = plan[0][0] + plan[0][1] - (overlap if len(plan) > 1 else 0)   # frames emitted by window 0
        last_start = plan[-1][0] + (overlap if len(plan) > 1 else 0)           # first frame emitted new by the last window
        env = G._smooth(aud[i].env[:T])
        for cm in mot[i]:
            Tm = min(T, cm.n)
            sp = G._smooth(cm.speed[:Tm])
            segs = {"first 0.5 s": (0, H), "rest of window 0": (H, min(w0_end, Tm - H)),
                    "middle": (w0_end, max(w0_end, last_start)),
                    "last window before its last 0.5 s": (max(last_start, w0_end, H), Tm - H),
                    "last 0.5 s": (Tm - H, Tm)}
            for k, (a, b) in segs.items():
                if b - a >= 1:
                    acc[k]["speed"].append(float(sp[a:b].mean()))
                    acc[k]["env"].append(float(env[a:b].mean()))
                    acc[k]["jaw"].append(float(cm.jaw[a:b].mean()))
    return {k: {m: (float(np.mean(v)) if v else float("nan")) for m, v in d.items()} | {"n": len(d["speed"])}
            for k, d in acc.items()}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--generated", action="append", default=[], help="folder of {id}.npz (repeat per seed)")
    p.add_argument("--reference", action="store_true",
                   help="score the corpus generator's motion model on the audio instead (generalise's reference)")
    p.add_argument("--audio-dir", help="folder of 16 kHz {id}.wav (default: the real-speech validation split)")
    p.add_argument("--trim", type=float, nargs="+", default=[0.0, 0.5])
    p.add_argument("--check", help="a generalise report of the same folders: trim 0 must reproduce it")
    p.add_argument("--out")
    a = p.parse_args(argv)
    ids, audios = load_wavs(Path(a.audio_dir)) if a.audio_dir else G.real_set()
    aud = [G.ClipAudio(x) for x in audios]
    if a.reference == bool(a.generated):
        raise SystemExit("give --generated folders or --reference (one of the two)")
    if a.reference:
        mot = [[G.ClipMotion(G.reference_real_motion(x))] for x in audios]
    else:
        mot = [[G.ClipMotion(C.load_motion(Path(d) / f"{cid}.npz")) for d in a.generated] for cid in ids]
    rep = {"ids": ids, "realisations": len(mot[0]), "trims": {}, "profile": profile(ids, mot, aud)}
    for t in a.trim:
        rep["trims"][str(t)] = gaps(ids, mot, aud, t)
    print(f"{len(ids)} clips, {len(mot[0])} realisation(s) each" + (" (corpus generator's motion)" if a.reference else ""))
    print(f"{'trim s':>6} {'design':<11} {'speed gap [95% CI]':<30} {'wins':>5}  {'jaw gap':>7} {'jaw>=0.6':>8}")
    for t, r in rep["trims"].items():
        for d in G.DESIGNS:
            s, j = r[d]["speed_env"], r[d]["jaw_env"]
            print(f"{t:>6} {d:<11} {s['gap']:+.3f} [{s['gap_ci95'][0]:+.3f}, {s['gap_ci95'][1]:+.3f}]"
                  f"{'':<9} {s['wins']}/{s['clips']}  {j['gap']:+.3f} {sum(g >= 0.6 for g in j['per_clip_gap'])}/{j['clips']}")
    print("profile (means over clips x realisations):  segment: upper-body speed (smoothed) / envelope / jaw angle")
    for k, v in rep["profile"].items():
        print(f"  {k:<36} {v['speed']:.3f} / {v['env']:.3f} / {v['jaw']:.3f}  (n {v['n']})")
    if a.check:
        ref = json.load(open(a.check))
        r0 = rep["trims"].get("0.0") or rep["trims"].get("0")
        if r0 is None:
            raise SystemExit("--check needs --trim 0 among the trims")
        src = "reference" if a.reference else "model"
        for d, blk in (("audio_swap", ref["real"][src]), ("motion_swap", ref["real"]["motion_swap"][src])):
            for k in ("speed_env", "jaw_env"):
                diff = abs(blk["summary"][k]["gap"] - r0[d][k]["gap"])
                print(f"check {d} {k}: generalise {blk['summary'][k]['gap']:+.6f} here {r0[d][k]['gap']:+.6f} "
                      f"(|diff| {diff:.1e})")
                if diff > 1e-9:
                    print("CHECK FAILED", file=sys.stderr)
                    return 1
    if a.out:
        Path(a.out).write_text(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
