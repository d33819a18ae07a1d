"""Check that coupling.py's ``fuse_sample`` mode is the shipped decoding: the cached rollout of the first real
validation clip, seed 13, against ``livegesture.stream.generate_clip`` (the generator behind
``python -m livegesture.eval.generalise --checkpoint``). Run from the repository root after the ``decode`` command
for the real set (cache folder as argument, default /tmp/couple16/shipped_real).

    python docs/eval/realspeech-coupling-2026-11-25/check_reference.py [CACHE_DIR] [CHECKPOINT]
"""
import sys

import numpy as np
import torch

from livegesture.checkpoint import load
from livegesture.eval import generalise as G
from livegesture.stream import generate_clip

cache = sys.argv[1] if len(sys.argv) > 1 else "/tmp/couple16/shipped_real"
ckpt = sys.argv[2] if len(sys.argv) > 2 else "models/default.train/checkpoint.pt"
torch.set_num_threads(1)
m = load(ckpt)
ids, aud = G.real_set()
g = generate_clip(m, np.asarray(aud[0], np.float32), seed=13)
z = np.load(f"{cache}/fuse_sample_s13_{ids[0]}.npz")
d = float(np.abs(g["poses"] - z["poses"]).max())
print(ids[0], "max abs diff poses", d, len(g["poses"]), len(z["poses"]))
sys.exit(0 if d == 0.0 and len(g["poses"]) == len(z["poses"]) else 1)
