"""Pick DiffSHEG's guidance scale on a held-out SYNTHETIC split (never the real-speech validation recordings).

    python python/tools/diffsheg_guidance_sweep.py --checkpoint runs/diffsheg/final.pt --data CORPUS \
        [--split val] [--scales 1.0,1.25,2,3] [--max-clips 6] [--out sweep.json]

For every scale, every clip of the split is generated (batched FOPPAS, seed 1) and scored with
``livegesture.eval.generalise.evaluate_set``: BC, jaw-envelope and upper-body-speed-envelope correlations with
the clip's own audio vs another clip's audio (gap = own - other).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch


def main(argv=None):
    from livegesture import checkpoint as ckpt
    from livegesture.diffsheg.foppas import generate_clips
    from livegesture.eval.generalise import evaluate_set, synth_set
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="val")
    ap.add_argument("--scales", default="1.0,1.25,2,3")
    ap.add_argument("--max-clips", type=int, default=6)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    model = ckpt.load(a.checkpoint)
    if getattr(model, "family", "livegesture") != "diffsheg":
        raise SystemExit(f"{a.checkpoint}: not a DiffSHEG checkpoint")
    ids, audio, _ = synth_set(a.data, a.split, a.max_clips)
    res = {}
    for g in [float(x) for x in a.scales.split(",")]:
        t0 = time.time()
        gens = generate_clips(model, [x.astype(np.float32) for x in audio], [a.seed] * len(ids), guidance=g)
        rep = evaluate_set(ids, [[m] for m in gens], audio)
        res[str(g)] = {k: {kk: rep["summary"][k][kk] for kk in ("own", "other", "gap", "wins")} for k in rep["summary"]}
        s = rep["summary"]
        print(f"guidance {g:5.2f}: bc gap {s['bc']['gap']:+.3f}  jaw_env gap {s['jaw_env']['gap']:+.3f} "
              f"(own {s['jaw_env']['own']:.3f})  speed_env gap {s['speed_env']['gap']:+.3f} "
              f"(own {s['speed_env']['own']:.3f})  [{time.time() - t0:.0f} s]", flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"checkpoint": a.checkpoint, "data": a.data, "split": a.split, "ids": ids, "results": res}, f,
                      indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
