"""Per-clip link between the real clips' audio statistics and the speed gaps (reads results/*.json).

    python docs/eval/realspeech-coupling-2026-11-25/perclip.py
"""
import json
from pathlib import Path

import numpy as np

R = Path(__file__).parent / "results"
g = json.loads((R / "generator.json").read_text())["real_val"]
st = g["stats_per_clip"]
onr = np.array([s["onset_train_vs_env_r"] for s in st])
act = np.array([s["active_fraction"] for s in st])
ref = np.array(g["ablations"]["full"]["per_clip_gap"])
what = np.array(g["ablations"]["strength_from_env"]["per_clip_gap"])
print(f"target (generator) gap vs r(onset train, envelope) over the 8 clips: r = {np.corrcoef(ref, onr)[0, 1]:+.2f}")
gaps = {}
for m in ("shipped", "scratch"):
    r = json.loads((R / f"{m}_real.json").read_text())["modes"]["fuse_sample"]
    a = np.array([c["speed_env"]["gap"] for c in r["audio_swap"]["per_clip"]])
    ms = np.array([c["speed_env"]["gap"] for c in r["motion_swap"]["per_clip"]])
    gaps[m] = a
    print(f"{m} (seeds 13-18) gap, audio / motion swap, vs r(onset train, envelope): "
          f"{np.corrcoef(a, onr)[0, 1]:+.2f} / {np.corrcoef(ms, onr)[0, 1]:+.2f}; vs target gap: "
          f"{np.corrcoef(a, ref)[0, 1]:+.2f} / {np.corrcoef(ms, ref)[0, 1]:+.2f}")
print(f"{'clip':<36} {'onset-env r':>11} {'active':>6} {'target':>7} {'what-if':>7} {'shipped':>7} {'scratch':>7}")
for i, s in enumerate(st):
    print(f"{s['id'][:36]:<36} {onr[i]:>11.2f} {act[i]:>6.2f} {ref[i]:>+7.3f} {what[i]:>+7.3f} "
          f"{gaps['shipped'][i]:>+7.3f} {gaps['scratch'][i]:>+7.3f}")
