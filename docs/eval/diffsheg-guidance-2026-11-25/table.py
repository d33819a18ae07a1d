"""Markdown table of the guidance x jumps sweep (docs/eval/diffsheg-guidance-2026-11-25/README.md).
   python table.py DIR TAG [SET=real]   reads DIR/GxU/{SET}_TAG.json (the sweep's output folder) or
   DIR/GxU_{SET}_TAG.json (the copies committed here, e.g. DIR=real); python -m livegesture.eval.generalise reports"""
import json, sys
from pathlib import Path

out, tag = Path(sys.argv[1]), sys.argv[2]
which = sys.argv[3] if len(sys.argv) > 3 else "real"
files = {p.parent.name: p for p in out.glob(f"*x*/{which}_{tag}.json")}
files.update({p.name[: -len(f"_{which}_{tag}.json")]: p for p in out.glob(f"*x*_{which}_{tag}.json")})
print("| guidance x jumps | upper-body speed vs envelope | jaw vs envelope | Beat Constancy |")
print("|---|---|---|---|")
for name in sorted(files, key=lambda s: (-int(s.split("x")[1]), float(s.split("x")[0]))):
    d = json.loads(files[name].read_text())[which]["model"]["summary"]
    cells = []
    for m in ("speed_env", "jaw_env", "bc"):
        s = d[m]
        lo, hi = s["gap_ci95"]
        cells.append(f"{s['gap']:+.3f} [{lo:+.3f}, {hi:+.3f}], {round(s['wins'] * s['clips'])}/{s['clips']}")
    print(f"| {name} | " + " | ".join(cells) + " |")
