"""BEAT2 L1div of each corpus's own train-split motion, split by the speech source of the clip."""
import csv, collections, sys
from pathlib import Path
import numpy as np
from livegesture.eval import corpus
from livegesture.eval import metrics as M
for root in ("/tmp/corpus_default", "/tmp/corpus_rs"):
    data = Path(root)
    rows = [r for r in csv.reader(open(data / "train_test_split.csv")) if len(r) > 1 and r[1] == "train"]
    groups = collections.defaultdict(list)
    allj = []
    for r in rows:
        c = r[0]
        m = corpus.load_motion(corpus.motion_path(data, c))
        J = M.joints_from_motion(m["poses"], m["trans"])
        allj.append(J)
        groups[c.split("_")[1]].append(J)
    print(root, "train clips", len(allj), "L1div BEAT2 %.3f" % M.l1_diversity_beat2(allj))
    for g, js in sorted(groups.items()):
        print("  speaker", g, len(js), "clips, L1div %.3f" % M.l1_diversity_beat2(js))
