"""The corpus generator's own upper-body coupling (no model) per stroke drive, on the real-speech TRAIN split
(never the validation split) and the synthetic test split: the issue-16 speed gap (audio swap) of
``synth.generate_motion`` with speaker 2's style, seed 0 (as ``generalise``'s reference motion), plus its mean
upper-body speed. Run from the repository root with $LIVEGESTURE_PY:

  python docs/eval/realspeech-loudness-2026-11-25/drive_probe.py --synth /tmp/corpus_default --out OUT.json
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np

from livegesture.data import real_speech, synth
from livegesture.data.beat2 import load_audio
from livegesture.eval import generalise as G
from livegesture.regions import FPS, SAMPLE_RATE


def sets(synth_dir):
    paths = sorted(real_speech.split_paths("train"), key=lambda p: p.stem)
    yield "real_train", [p.stem for p in paths], [load_audio(p, SAMPLE_RATE).astype(np.float64) for p in paths]
    ids, aud, _ = G.synth_set(synth_dir, "test")
    yield "synth_test", ids, aud


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--synth", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    rep = {}
    for name, ids, aud in sets(a.synth):
        ca = [G.ClipAudio(x) for x in aud]
        rep[name] = {}
        for drive in synth.STROKE_DRIVES:
            ms = [[G.ClipMotion(G.reference_real_motion(x, drive=drive))] for x in aud]
            s = G.evaluate_set(ids, ms, ca, None, design="audio_swap")["summary"]["speed_env"]
            rep[name][drive] = {"speed_env": s, "mean_upper_speed_m_s": float(np.mean([m[0].speed.mean() for m in ms]))}
            print(f"{name:<11} {drive:<9} speed gap {s['gap']:+.3f} [{s['gap_ci95'][0]:+.3f}, {s['gap_ci95'][1]:+.3f}] "
                  f"wins {round(s['wins'] * s['clips'])}/{s['clips']}, own {s['own']:.3f} other {s['other']:.3f}, "
                  f"mean upper speed {rep[name][drive]['mean_upper_speed_m_s']:.4f} m/s", flush=True)
    Path(a.out).write_text(json.dumps(rep, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
