"""Markdown table of generalise's motion-swap design (main after the bcmetric merge, a43975a) per guidance x jumps.
   python table_motion_swap.py DIR   reads DIR/GxU_real_12345.json: clip i's own audio vs its own motion / vs the
   motion made for every other clip j != i (averaged over j); gap [95 % CI over clips], clips own > other"""
import json, sys
from pathlib import Path

out = Path(sys.argv[1])
files = {p.name.split("_")[0]: p for p in out.glob("*x*_real_12345.json")}
print("| guidance x jumps | upper-body speed vs envelope | jaw vs envelope | Beat Constancy |")
print("|---|---|---|---|")
ref = None
for s in sorted(files, key=lambda s: (-int(s.split("x")[1]), float(s.split("x")[0]))):
    d = json.loads(files[s].read_text())["real"]["motion_swap"]
    ref = d["reference"]["summary"]
    cells = []
    for m in ("speed_env", "jaw_env", "bc"):
        x = d["model"]["summary"][m]; lo, hi = x["gap_ci95"]
        cells.append(f"{x['gap']:+.3f} [{lo:+.3f}, {hi:+.3f}], {round(x['wins'] * x['clips'])}/{x['clips']}")
    print(f"| {s} | " + " | ".join(cells) + " |")
cells = []
for m in ("speed_env", "jaw_env", "bc"):
    x = ref[m]; lo, hi = x["gap_ci95"]
    cells.append(f"{x['gap']:+.3f} [{lo:+.3f}, {hi:+.3f}], {round(x['wins'] * x['clips'])}/{x['clips']}")
print("| corpus motion model | " + " | ".join(cells) + " |")
