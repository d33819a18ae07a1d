"""Lip-sync measurement (issue 41, docs/face.md): on the real-speech VALIDATION split (never trained on),
pocketsphinx allphone labels (:mod:`.labels`) per 30 fps frame -> six mouth classes (silence; bilabial M B P;
open AA AE AH AO AW AY; round OW UW UH OY W; spread IY IH EY EH Y; other). Scored:

- the argmax viseme mapped to the same six classes (sil; PP; aa; oh ou; E ih; the rest) by macro-F1, beside
  an envelope-only baseline (log RMS per frame: above the recording's median -> open, else silence);
- ``jawOpen`` by the AUC of open-vowel frames against bilabial frames, beside the AUC of the log RMS itself.

Macro-F1 averages the F1 of every class present in the labels or the predictions (a class never predicted
scores 0). Predictions may lag the labels by 0..``max_lag`` frames (prediction at frame j + lag vs label j);
each method gets the one lag that maximises its mean over recordings (reported). Bounds (``--check``): mean
viseme macro-F1 >= envelope's + 0.10 and mean jawOpen AUC >= envelope's - 0.03.

  python -m livegesture.face.evaluate --checkpoint models/face/face.pt [--onnx face.onnx] [--npz-dir D]
      [--out report.json] [--check]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from .names import ARKIT_NAMES, MOUTH_CLASSES, VISEME_MOUTH, phone_mouth

F1_MARGIN = 0.10
AUC_TOLERANCE = 0.03
MAX_LAG = 6


def macro_f1(y: np.ndarray, p: np.ndarray, n_classes: int = 6) -> float:
    f1s = []
    for c in range(n_classes):
        tp = np.sum((p == c) & (y == c))
        n_p, n_y = np.sum(p == c), np.sum(y == c)
        if n_p == 0 and n_y == 0:
            continue
        f1s.append(2.0 * tp / (n_p + n_y))
    return float(np.mean(f1s))


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """P(score of a positive > score of a negative), ties counted half (Mann-Whitney)."""
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    allv = np.concatenate([pos, neg])
    order = np.argsort(allv, kind="mergesort")
    ranks = np.empty(len(allv))
    sv = allv[order]
    i = 0
    while i < len(sv):                       # average ranks of ties
        j = i
        while j + 1 < len(sv) and sv[j + 1] == sv[i]:
            j += 1
        ranks[order[i:j + 1]] = (i + j) / 2.0 + 1.0
        i = j + 1
    r_pos = ranks[:len(pos)].sum()
    return float((r_pos - len(pos) * (len(pos) + 1) / 2.0) / (len(pos) * len(neg)))


def envelope(audio: np.ndarray, n_frames: int) -> np.ndarray:
    """Log RMS of each 30 fps frame's samples [j * 16000 // 30, (j + 1) * 16000 // 30)."""
    x = np.asarray(audio, np.float64)
    out = np.empty(n_frames)
    for j in range(n_frames):
        s = x[j * 16000 // 30:(j + 1) * 16000 // 30]
        out[j] = np.log(np.sqrt(np.mean(s * s)) + 1e-8) if len(s) else np.log(1e-8)
    return out


def _lagged(y, s, lag):
    return (y[:len(y) - lag], s[lag:]) if lag else (y, s)


def score_recording(mouth_labels: np.ndarray, visemes: np.ndarray, jaw: np.ndarray, env: np.ndarray,
                    lag_model: int, lag_env: int) -> dict:
    y, p = _lagged(mouth_labels, VISEME_MOUTH[np.argmax(visemes, axis=1)], lag_model)
    _, j = _lagged(mouth_labels, jaw, lag_model)
    ye, e = _lagged(mouth_labels, env, lag_env)
    base = np.where(e > np.median(env), 2, 0)
    return {"frames": int(len(mouth_labels)),
            "viseme_macro_f1": macro_f1(y, p), "envelope_macro_f1": macro_f1(ye, base),
            "jawopen_auc": auc(j[y == 2], j[y == 1]), "envelope_auc": auc(e[ye == 2], e[ye == 1]),
            "open_frames": int(np.sum(mouth_labels == 2)), "bilabial_frames": int(np.sum(mouth_labels == 1))}


def evaluate(recs: list[dict], max_lag: int = MAX_LAG) -> dict:
    """recs: [{name, phones (n,), visemes (n, 15), arkit (n, 52), audio (16 kHz)}] -> the report."""
    jaw_i = ARKIT_NAMES.index("jawOpen")
    prepared = []
    for r in recs:
        n = len(r["phones"])
        if r["visemes"].shape != (n, 15) or r["arkit"].shape != (n, 52):
            raise ValueError(f"face evaluation: {r['name']}: visemes {r['visemes'].shape} / arkit "
                             f"{r['arkit'].shape}, expected ({n}, 15) / ({n}, 52) (one row per labelled frame)")
        if not (np.isfinite(r["visemes"]).all() and np.isfinite(r["arkit"]).all()):
            raise ValueError(f"face evaluation: {r['name']}: non-finite visemes or arkit")
        prepared.append((r["name"], np.array([phone_mouth(p) for p in r["phones"]]), r["visemes"],
                         r["arkit"][:, jaw_i], envelope(r["audio"], n)))

    def mean_of(key, lm, le):
        v = [score_recording(y, vi, ja, en, lm, le)[key] for _, y, vi, ja, en in prepared]
        return float(np.nanmean(v))

    lags = range(max_lag + 1)
    lag_f1 = max(lags, key=lambda L: mean_of("viseme_macro_f1", L, 0))
    lag_env_f1 = max(lags, key=lambda L: mean_of("envelope_macro_f1", 0, L))
    lag_auc = max(lags, key=lambda L: mean_of("jawopen_auc", L, 0))
    lag_env_auc = max(lags, key=lambda L: mean_of("envelope_auc", 0, L))
    per = []
    for name, y, vi, ja, en in prepared:
        a = score_recording(y, vi, ja, en, lag_f1, lag_env_f1)
        b = score_recording(y, vi, ja, en, lag_auc, lag_env_auc)
        per.append({"recording": name, "frames": a["frames"], "open_frames": a["open_frames"],
                    "bilabial_frames": a["bilabial_frames"],
                    "viseme_macro_f1": a["viseme_macro_f1"], "envelope_macro_f1": a["envelope_macro_f1"],
                    "jawopen_auc": b["jawopen_auc"], "envelope_auc": b["envelope_auc"]})
    mean = {k: float(np.nanmean([p[k] for p in per]))
            for k in ("viseme_macro_f1", "envelope_macro_f1", "jawopen_auc", "envelope_auc")}
    counts = np.bincount(np.concatenate([y for _, y, *_ in prepared]), minlength=6)
    return {"recordings": per, "mean": mean,
            "lags_frames": {"viseme_macro_f1": lag_f1, "envelope_macro_f1": lag_env_f1, "jawopen_auc": lag_auc,
                            "envelope_auc": lag_env_auc},
            "label_counts": dict(zip(MOUTH_CLASSES, counts.tolist())),
            "bounds": {"f1_margin": F1_MARGIN, "auc_tolerance": AUC_TOLERANCE}}


def failures(report: dict) -> list[str]:
    m = report["mean"]
    out = []
    if not m["viseme_macro_f1"] >= m["envelope_macro_f1"] + F1_MARGIN:
        out.append(f"mean viseme macro-F1 {m['viseme_macro_f1']:.3f} < envelope's {m['envelope_macro_f1']:.3f} "
                   f"+ {F1_MARGIN}")
    if not m["jawopen_auc"] >= m["envelope_auc"] - AUC_TOLERANCE:
        out.append(f"mean jawOpen AUC {m['jawopen_auc']:.3f} < envelope's {m['envelope_auc']:.3f} - "
                   f"{AUC_TOLERANCE}")
    return out


def format_report(report: dict) -> str:
    lines = [f"{'recording':40s} {'frames':>6s} {'F1 face':>8s} {'F1 env':>7s} {'AUC jaw':>8s} {'AUC env':>8s}"]
    for p in report["recordings"]:
        lines.append(f"{p['recording']:40s} {p['frames']:6d} {p['viseme_macro_f1']:8.3f} {p['envelope_macro_f1']:7.3f} "
                     f"{p['jawopen_auc']:8.3f} {p['envelope_auc']:8.3f}")
    m, L = report["mean"], report["lags_frames"]
    lines.append(f"{'mean':40s} {'':6s} {m['viseme_macro_f1']:8.3f} {m['envelope_macro_f1']:7.3f} "
                 f"{m['jawopen_auc']:8.3f} {m['envelope_auc']:8.3f}")
    lines.append(f"lags (frames of 33 ms): face F1 {L['viseme_macro_f1']}, envelope F1 {L['envelope_macro_f1']}, "
                 f"jawOpen AUC {L['jawopen_auc']}, envelope AUC {L['envelope_auc']}")
    lines.append("label frames: " + ", ".join(f"{k} {v}" for k, v in report["label_counts"].items()))
    return "\n".join(lines)


def head_outputs(head, mel: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    import torch

    with torch.no_grad():
        o = head.outputs(head(torch.from_numpy(mel)[None]))
    return o["visemes"][0, :n_frames].numpy(), o["arkit_mouth"][0, :n_frames].numpy()


def check_npz_face(path, z) -> None:
    """The face keys of a generated .npz (docs/face.md): names in order, finite values, arkit in [0, 1], visemes
    summing to 1 (1e-4), one row per frame of ``poses``. Raises naming the file and key."""
    from .names import VISEME_NAMES

    for k in ("arkit", "arkit_names", "visemes", "viseme_names", "poses"):
        if k not in z:
            raise KeyError(f"face evaluation: {path} has no '{k}' key")
    if [str(x) for x in z["arkit_names"]] != list(ARKIT_NAMES):
        raise ValueError(f"face evaluation: {path}: arkit_names are not Apple's 52 names in order")
    if [str(x) for x in z["viseme_names"]] != list(VISEME_NAMES):
        raise ValueError(f"face evaluation: {path}: viseme_names {list(z['viseme_names'])} != {list(VISEME_NAMES)}")
    T = z["poses"].shape[0]
    a, v = z["arkit"], z["visemes"]
    if a.shape != (T, 52) or v.shape != (T, 15) or a.dtype != np.float32 or v.dtype != np.float32:
        raise ValueError(f"face evaluation: {path}: arkit {a.shape} {a.dtype} / visemes {v.shape} {v.dtype}, "
                         f"expected ({T}, 52) / ({T}, 15) float32")
    if not (np.isfinite(a).all() and np.isfinite(v).all()):
        raise ValueError(f"face evaluation: {path}: non-finite arkit or visemes")
    if a.min() < 0 or a.max() > 1:
        raise ValueError(f"face evaluation: {path}: arkit outside [0, 1] ({a.min()} .. {a.max()})")
    err = np.abs(v.sum(1) - 1).max() if T else 0.0
    if err > 1e-4 or v.min() < 0:
        raise ValueError(f"face evaluation: {path}: visemes do not sum to 1 (worst {err:.2e}) or are negative")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m livegesture.face.evaluate", description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="the face head's torch checkpoint (face.pt)")
    src.add_argument("--npz-dir", help="`livegesture generate` outputs, one <recording>.npz per VALIDATION "
                                       "recording (keys visemes, arkit)")
    ap.add_argument("--real-speech", default=None, help="the real-speech folder (default: shared/data/real-speech)")
    ap.add_argument("--labels-cache", default="target/face-labels")
    ap.add_argument("--out", help="write the report as JSON here")
    ap.add_argument("--check", action="store_true", help="exit 1 when a bound fails")
    a = ap.parse_args(argv)
    from .data import real_clips

    clips = real_clips("validation", Path(a.labels_cache), a.real_speech)
    recs = []
    if a.checkpoint:
        from .train import load_head

        head = load_head(a.checkpoint)
    for c in clips:
        if a.checkpoint:
            vis, ark = head_outputs(head, c.mel, c.n_frames)
        else:
            f = Path(a.npz_dir) / f"{c.name}.npz"
            if not f.exists():
                raise FileNotFoundError(f"face evaluation: {f} missing (run livegesture generate on {c.name}.wav)")
            z = np.load(f)
            for k in ("visemes", "arkit"):
                if k not in z:
                    raise KeyError(f"face evaluation: {f} has no '{k}' key")
            check_npz_face(f, z)
            vis, ark = z["visemes"].astype(np.float64), z["arkit"].astype(np.float64)
        recs.append({"name": c.name, "phones": c.phones, "visemes": vis, "arkit": ark, "audio": c.audio})
    rep = evaluate(recs)
    print(format_report(rep))
    if a.out:
        Path(a.out).write_text(json.dumps(rep, indent=1))
    bad = failures(rep)
    for b in bad:
        print("FAIL:", b, file=sys.stderr)
    if not bad:
        print("face lip-sync bounds hold")
    return 1 if (bad and a.check) else 0


if __name__ == "__main__":
    sys.exit(main())
