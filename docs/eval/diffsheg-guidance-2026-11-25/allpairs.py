"""Own audio vs EVERY other clip's audio (not only the fixed derangement of livegesture.eval.generalise).

    python allpairs.py OUT_DIR SEEDS [SETTING ...]      e.g. python allpairs.py /tmp/dsguide 12345 1.25x2 3.0x2
reads OUT_DIR/SETTING/seedS/{id}.npz (sweep_real.sh) and the real-speech validation split, and prints per
setting, for upper-body speed vs envelope and jaw vs envelope: own, mean over the 7 other clips' audio, the
gap with a 95 % bootstrap CI over the 8 clips (livegesture.eval.generalise.bootstrap_ci, same seed), and the
clips whose own value beats the mean other value. Same measures and settings as generalise (clip_measures);
each clip's motion is scored against audio j over their common length; realisations averaged per clip."""
import re
import sys
from pathlib import Path

import numpy as np

from livegesture.eval import corpus as C
from livegesture.eval.generalise import ClipAudio, ClipMotion, bootstrap_ci, clip_measures, real_set

out, seeds = Path(sys.argv[1]), list(sys.argv[2])
settings = sys.argv[3:] or sorted(p.name for p in out.glob("*x*") if p.is_dir() and re.fullmatch(r"[0-9.]+x[0-9]+", p.name))
ids, audios = real_set()
aud = [ClipAudio(a) for a in audios]
n = len(ids)
print("| guidance x jumps | speed own | speed other (all) | speed gap [95 % CI] | clips | jaw gap [95 % CI] | clips |")
print("|---|---|---|---|---|---|---|")
for s in sorted(settings, key=lambda s: (-int(s.split("x")[1]), float(s.split("x")[0]))):
    res = {k: np.zeros((n, 2)) for k in ("speed_env", "jaw_env")}
    for i, cid in enumerate(ids):
        vals = {k: ([], []) for k in res}
        for seed in seeds:
            cm = ClipMotion(C.load_motion(out / s / f"seed{seed}" / f"{cid}.npz"))
            for j in range(n):
                m = {k: v for k, v in clip_measures(cm, aud[j]).items() if k in res}
                for k in res:
                    vals[k][0 if j == i else 1].append(m[k])
        for k in res:
            res[k][i] = [np.mean(vals[k][0]), np.mean(vals[k][1])]
    cells = []
    for k in ("speed_env", "jaw_env"):
        gap = res[k][:, 0] - res[k][:, 1]
        lo, hi = bootstrap_ci(gap)
        if k == "speed_env":
            cells += [f"{res[k][:, 0].mean():.3f}", f"{res[k][:, 1].mean():+.3f}"]
        cells += [f"{gap.mean():+.3f} [{lo:+.3f}, {hi:+.3f}]", f"{int((gap > 0).sum())}/{n}"]
    print(f"| {s} | " + " | ".join(cells) + " |", flush=True)
