"""Markdown tables of this folder's README from the reports (no computation beyond selecting numbers).

    python docs/eval/realspeech-metric-2026-11-25/tables.py checks NAME=generalise.json ...
    python docs/eval/realspeech-metric-2026-11-25/tables.py power generalise.json
    python docs/eval/realspeech-metric-2026-11-25/tables.py sweep SWEEP_DIR
"""
import json
import sys
from pathlib import Path

MEASURES = (("speed_env", "upper-body speed"), ("jaw_env", "jaw"), ("bc", "BC"))


def _cell(s):
    n = round(s["wins"] * s["clips"])
    return f"{s['gap']:+.3f} [{s['gap_ci95'][0]:+.2f}, {s['gap_ci95'][1]:+.2f}], {n}/{s['clips']}"


def _blocks(rep, set_name, design):
    sr = rep[set_name]
    return sr if design == "audio_swap" else sr["motion_swap"]


def checks(items):
    for set_name in ("real", "synth"):
        print(f"\n{set_name}: gap [95 % CI], clips own > other\n")
        print("| motion | design | " + " | ".join(t for _, t in MEASURES) + " |")
        print("|---|---|" + "---|" * len(MEASURES))
        for item in items:
            name, path = item.split("=", 1)
            rep = json.loads(Path(path).read_text())
            if set_name not in rep:
                continue
            for src in ("model", "reference"):
                if src == "reference" and name != items[0].split("=", 1)[0]:
                    continue                                   # the reference is the same for every model
                label = name if src == "model" else "reference"
                for design in ("audio_swap", "motion_swap"):
                    b = _blocks(rep, set_name, design)[src]["summary"]
                    print(f"| {label} | {design.replace('_', ' ')} | " + " | ".join(_cell(b[k]) for k, _ in MEASURES)
                          + " |")


def power(path):
    rep = json.loads(Path(path).read_text())
    for set_name in ("real", "synth"):
        if set_name not in rep:
            continue
        for src in ("model", "reference"):
            p = rep[set_name]["onset_power"][src]
            s = p["summary"]
            print(f"\n{set_name}, {src}: audio-swap BC gap vs chance gap r = {s['gap_vs_chance_gap_r']:+.3f} "
                  f"(r^2 {s['gap_vs_chance_gap_r2']:.3f}), slope {s['gap_vs_chance_gap_slope']:.3f}; "
                  f"own BC > shifted BC on {round(s['own_above_shifted'] * len(p['per_clip']))}/{len(p['per_clip'])}\n")
            print("| clip | window s | onsets/s | chance BC | shifted BC | own BC | audio-swap gap | chance gap | "
                  "audio-swap gap - chance gap | motion-swap gap |")
            print("|---|---|---|---|---|---|---|---|---|---|")
            for r in p["per_clip"] + [dict(s, id="**mean**", window_s=float("nan"))]:
                ws = "-" if r["window_s"] != r["window_s"] else f"{r['window_s']:.1f}"
                print(f"| {r['id']} | {ws} | {r['onsets_per_s']:.2f} | {r['chance_bc']:.3f} | "
                      f"{r['shifted_bc']:.3f} | {r['bc_own']:.3f} | {r['bc_gap_audio_swap']:+.3f} | "
                      f"{r['chance_gap']:+.3f} | {r['bc_gap_audio_swap_minus_chance_gap']:+.3f} | "
                      f"{r['bc_gap_motion_swap']:+.3f} |")


def sweep(d):
    dirs = sorted((p for p in Path(d).glob("T*_K*") if (p / "generalise.json").exists()),
                  key=lambda p: (-float(p.name.split("_")[0][1:]), -int(p.name.split("_K")[1])))
    w = lambda s: f"{round(s['wins'] * s['clips'])}/{s['clips']}"
    c = lambda s: f"{s['gap']:+.3f} [{s['gap_ci95'][0]:+.2f}, {s['gap_ci95'][1]:+.2f}] {w(s)}"
    print("\nreal-speech validation split, 3 seeds: gap [95 % CI] clips own > other\n")
    print("| T | top_k | design | upper-body speed | jaw | BC |")
    print("|---|---|---|---|---|---|")
    for sd in dirs:
        g = json.loads((sd / "generalise.json").read_text())
        t, k = sd.name.split("_K")
        for design, b in (("audio swap", g["real"]["model"]), ("motion swap", g["real"]["motion_swap"]["model"])):
            s = b["summary"]
            print(f"| {t[1:]} | {k} | {design} | {c(s['speed_env'])} | {c(s['jaw_env'])} | {c(s['bc'])} |")
    print("\nin distribution: synthetic test split, 2 seeds "
          "(scripts/eval_bundle.sh; check = generalise, motion swap)\n")
    print("| T | top_k | BC own / other (gap, clips) | FGD vs test / train | L1 div eq.2 / BEAT2 | face MSE | "
          "check speed / jaw / BC gap (BC clips) |")
    print("|---|---|---|---|---|---|---|")
    for sd in dirs:
        g = json.loads((sd / "generalise.json").read_text())
        e = json.loads((sd / "eval.json").read_text())["generated"]
        sm = g["synth"]["motion_swap"]["model"]["summary"]
        t, k = sd.name.split("_K")
        print(f"| {t[1:]} | {k} | {e['bc']:.3f} / {e['bc_mismatched_audio']:.3f} ({e['bc_gap']:+.3f}, "
              f"{round(e['bc_matched_wins'] * e['clips'])}/{e['clips']}) | {e['fgd']:.2f} / {e['fgd_vs_train']:.2f} | "
              f"{e['l1div_realisations']:.2f} / {e['l1div_beat2']:.2f} | {e['face']['face']:.4f} | "
              f"{sm['speed_env']['gap']:+.3f} / {sm['jaw_env']['gap']:+.3f} / {sm['bc']['gap']:+.3f} ({w(sm['bc'])}) |")


if __name__ == "__main__":
    cmd, rest = sys.argv[1], sys.argv[2:]
    {"checks": lambda: checks(rest), "power": lambda: power(rest[0]), "sweep": lambda: sweep(rest[0])}[cmd]()
