"""Shipped vs continued DiffSHEG, side by side, and the decision rule of this folder's README (section 1).

    python docs/eval/diffsheg-confirm-2026-11-25/compare.py SHIPPED_DIR CONTINUED_DIR

Each DIR holds eval.json (python -m livegesture.eval, synthetic test split, seeds 1-2), synth_12.json
(generalise --synth, seeds 1-2) and real_789101112.json (generalise, real-speech validation split, seeds 7-12),
as written by eval_bundle.sh. Prints markdown tables and the verdict.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def ci(s: dict) -> str:
    return f"{s['gap']:+.3f} [{s['gap_ci95'][0]:+.3f}, {s['gap_ci95'][1]:+.3f}], {round(s['wins'] * s['clips'])}/{s['clips']}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        raise SystemExit(__doc__)
    dirs = {"shipped": Path(argv[0]), "continued": Path(argv[1])}
    ev = {k: json.loads((d / "eval.json").read_text()) for k, d in dirs.items()}
    sy = {k: json.loads((d / "synth_12.json").read_text()) for k, d in dirs.items()}
    re = {k: json.loads((d / "real_789101112.json").read_text()) for k, d in dirs.items()}
    gt = ev["shipped"]["ground_truth"]
    print("| synthetic test split (15 clips, seeds 1-2) | shipped | continued | corpus motion |")
    print("|---|---|---|---|")
    g = {k: v["generated"] for k, v in ev.items()}
    rows = [("BC own / other, gap", lambda x: f"{x['bc']:.3f} / {x['bc_mismatched_audio']:.3f}, {x['bc_gap']:+.3f}"),
            ("clips with own > other", lambda x: f"{round(x['bc_matched_wins'] * 15)}/15"),
            ("L1 div eq. 2 / BEAT2", lambda x: f"{x.get('l1div_realisations', float('nan')):.2f} / {x['l1div_beat2']:.2f}"),
            ("FGD vs test motion", lambda x: f"{x['fgd']:.2f}"),
            ("FGD vs train motion", lambda x: f"{x['fgd_vs_train']:.2f}"),
            ("face MSE (jaw + expressions)", lambda x: f"{x['face']['face']:.4f}"),
            ("jaw MSE / expression MSE", lambda x: f"{x['face']['jaw']:.5f} / {x['face']['expressions']:.4f}")]
    for name, f in rows:
        try:
            t = f(gt)
        except (KeyError, TypeError, ValueError):
            t = "-"
        print(f"| {name} | {f(g['shipped'])} | {f(g['continued'])} | {t} |")
    for k in ("speed_env", "jaw_env", "bc"):
        for des, blk in (("audio swap", lambda r, w: r["synth"][w]), ("motion swap", lambda r, w: r["synth"]["motion_swap"][w])):
            print(f"| synth {k} gap, {des} | {ci(blk(sy['shipped'], 'model')['summary'][k])} | "
                  f"{ci(blk(sy['continued'], 'model')['summary'][k])} | {ci(blk(sy['shipped'], 'reference')['summary'][k])} |")
    print()
    print("| real speech (8 clips, seeds 7-12) | shipped | continued |")
    print("|---|---|---|")
    for des, path in (("motion swap", lambda r: r["real"]["motion_swap"]["model"]), ("audio swap", lambda r: r["real"]["model"])):
        for k in ("speed_env", "jaw_env", "bc"):
            print(f"| {k}, {des} | {ci(path(re['shipped'])['summary'][k])} | {ci(path(re['continued'])['summary'][k])} |")
    for name in dirs:
        pc = re[name]["real"]["motion_swap"]["model"]["per_clip"]
        print(f"{name}: jaw gap >= 0.6 (motion swap) on {sum(r['jaw_env']['gap'] >= 0.6 for r in pc)}/8 clips")
    # the decision rule (README section 1)
    fs, fc = g["shipped"]["fgd"], g["continued"]["fgd"]
    ms, mc = g["shipped"]["face"]["face"], g["continued"]["face"]["face"]
    rs = re["shipped"]["real"]["motion_swap"]["model"]["summary"]
    rc = re["continued"]["real"]["motion_swap"]["model"]["summary"]
    checks = {
        f"FGD {fc:.2f} <= 0.9 x {fs:.2f} = {0.9 * fs:.2f}": fc <= 0.9 * fs,
        f"face MSE {mc:.4f} <= 1.1 x {ms:.4f} = {1.1 * ms:.4f}": mc <= 1.1 * ms,
        f"real speed gap {rc['speed_env']['gap']:+.3f} >= {rs['speed_env']['gap']:+.3f} - 0.02": rc["speed_env"]["gap"] >= rs["speed_env"]["gap"] - 0.02,
        f"real speed wins {round(rc['speed_env']['wins'] * 8)} >= {round(rs['speed_env']['wins'] * 8)} - 1":
            round(rc["speed_env"]["wins"] * 8) >= round(rs["speed_env"]["wins"] * 8) - 1,
        f"real jaw gap {rc['jaw_env']['gap']:+.3f} >= {rs['jaw_env']['gap']:+.3f} - 0.02": rc["jaw_env"]["gap"] >= rs["jaw_env"]["gap"] - 0.02,
    }
    print()
    for k, v in checks.items():
        print(f"- {k}: {'yes' if v else 'NO'}")
    print(f"decision: {'REPLACE models/diffsheg' if all(checks.values()) else 'keep models/diffsheg'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
