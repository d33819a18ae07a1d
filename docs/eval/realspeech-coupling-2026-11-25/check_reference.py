import numpy as np, torch
torch.set_num_threads(1)
from livegesture.checkpoint import load
from livegesture.eval import generalise as G
from livegesture.stream import generate_clip
m = load("models/default.train/checkpoint.pt")
ids, aud = G.real_set()
g = generate_clip(m, np.asarray(aud[0], np.float32), seed=13)
z = np.load(f"/tmp/couple16/shipped_real/fuse_sample_s13_{ids[0]}.npz")
print(ids[0], "max abs diff poses", np.abs(g["poses"] - z["poses"]).max(), len(g["poses"]), len(z["poses"]))
