"""Markdown table of the guidance x jumps sweep (docs/eval/diffsheg-guidance-2026-11-25/README.md).
   python table.py OUT_DIR TAG [SET=real]   reads OUT_DIR/GxU/{SET}_TAG.json (python -m livegesture.eval.generalise)"""
import json, sys
from pathlib import Path

out, tag = Path(sys.argv[1]), sys.argv[2]
which = sys.argv[3] if len(sys.argv) > 3 else "real"
print(f"| guidance x jumps | upper-body speed vs envelope | jaw vs envelope | Beat Constancy |")
print("|---|---|---|---|")
def key(p):
    g, u = p.parent.name.split("x")
    return (-int(u), float(g))
for p in sorted(out.glob(f"*x*/{which}_{tag}.json"), key=key):
    d = json.loads(p.read_text())[which]["model"]["summary"]
    cells = []
    for m in ("speed_env", "jaw_env", "bc"):
        s = d[m]
        lo, hi = s["gap_ci95"]
        cells.append(f"{s['gap']:+.3f} [{lo:+.3f}, {hi:+.3f}], {round(s['wins'] * s['clips'])}/{s['clips']}")
    print(f"| {p.parent.name} | " + " | ".join(cells) + " |")
