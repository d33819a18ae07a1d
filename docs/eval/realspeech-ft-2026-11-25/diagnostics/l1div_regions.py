"""BEAT2 L1div per joint group (joint POSITIONS, so a hand moves with its arm) of generated motion and of the
corpus test motion. usage: l1div_regions.py CORPUS NAME=DIR [NAME=DIR ...] (DIR: {id}.npz of the test split)"""
import csv
import sys
from pathlib import Path

import numpy as np

from livegesture.eval import corpus
from livegesture.eval import metrics as M
from livegesture.regions import HANDS_JOINTS, LOWER_JOINTS, UPPER_JOINTS

GROUPS = {"upper": UPPER_JOINTS, "hands": HANDS_JOINTS, "lower": LOWER_JOINTS, "jaw": (22,), "all": tuple(range(55))}
data = Path(sys.argv[1])
ids = sorted(r[0] for r in csv.reader(open(data / "train_test_split.csv")) if len(r) > 1 and r[1] == "test")
sets = {"corpus test": [corpus.load_motion(corpus.motion_path(data, c)) for c in ids]}
for arg in sys.argv[2:]:
    name, d = arg.split("=", 1)
    sets[name] = [dict(np.load(Path(d) / f"{c}.npz")) for c in ids]
print(f"{'motion':14s}" + "".join(f"{g:>9s}" for g in GROUPS))
for name, motions in sets.items():
    J = [M.joints_from_motion(m["poses"], m["trans"]) for m in motions]
    print(f"{name:14s}" + "".join(f"{M.l1_diversity_beat2([j[:, list(g)] for j in J]):9.3f}" for g in GROUPS.values()))
