"""Print the in-distribution figures of livegesture.eval reports side by side (numpy-free; run from this folder).
usage: python lr5e5/table.py NAME=REPORT.json ..."""
import json
import sys

for arg in sys.argv[1:]:
    name, path = arg.split("=", 1)
    g = json.load(open(path))["generated"]
    print(f"{name:22s} BC gap {g['bc_gap']:+.3f} ({round(g['bc_matched_wins'] * g['clips'])}/{g['clips']})  "
          f"BEAT2 L1div {g['l1div_beat2']:.2f}  FGD {g['fgd']:.2f}  FGD train {g['fgd_vs_train']:.2f}  "
          f"face MSE {g['face']['face']:.4f}")
