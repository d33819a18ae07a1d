"""Markdown tables of the synthetic test split per guidance x jumps (indist.sh's output).
   python table_indist.py DIR    reads DIR/GxU/eval.json and DIR/GxU/synth_123.json, or the committed copies
   DIR/GxU_eval.json and DIR/GxU_synth_123.json (DIR=synth)"""
import json, sys
from pathlib import Path

out = Path(sys.argv[1])
def find(name):
    return {**{p.parent.name: p for p in out.glob(f"*x*/{name}")},
            **{p.name[: -len(name) - 1]: p for p in out.glob(f"*x*_{name}")}}
ev, ge = find("eval.json"), find("synth_123.json")
order = lambda s: (-int(s.split("x")[1]), float(s.split("x")[0]))
print("| guidance x jumps | BC own / other, gap | clips own > other | L1 div eq. 2 / BEAT2 | FGD | FGD vs train | face MSE |")
print("|---|---|---|---|---|---|---|")
for s in sorted(ev, key=order):
    g = json.loads(ev[s].read_text())["generated"]
    print(f"| {s} | {g['bc']:.3f} / {g['bc_mismatched_audio']:.3f}, {g['bc_gap']:+.3f} | "
          f"{round(g['bc_matched_wins'] * g['clips'])}/{g['clips']} | {g['l1div_realisations']:.2f} / {g['l1div_beat2']:.2f} | "
          f"{g['fgd']:.2f} | {g['fgd_vs_train']:.2f} | {g['face']['face']:.4f} |")
print()
print("| guidance x jumps | upper-body speed vs envelope | jaw vs envelope | Beat Constancy |")
print("|---|---|---|---|")
for s in sorted(ge, key=order):
    d = json.loads(ge[s].read_text())["synth"]["model"]["summary"]
    cells = []
    for m in ("speed_env", "jaw_env", "bc"):
        x = d[m]; lo, hi = x["gap_ci95"]
        cells.append(f"{x['gap']:+.3f} [{lo:+.3f}, {hi:+.3f}], {round(x['wins'] * x['clips'])}/{x['clips']}")
    print(f"| {s} | " + " | ".join(cells) + " |")
