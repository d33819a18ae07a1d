"""Helpers behind the tables of README.md (numpy only; run with $LIVEGESTURE_PY).

  compare.py real  SHIPPED_real3.json CAND_real3.json   paired: per-clip gap (own - other) of the candidate minus
                                                         the shipped model's, mean and 95 % bootstrap CI over clips
  compare.py synth SHIPPED_eval.json  CAND_eval.json     the same for the BC gap of a livegesture.eval report
  compare.py pool  A_real3.json B_real3.json ...         several generalise reports of ONE model with different
                                                         seeds (e.g. --seed 1 and --seed 4, 3 realisations each):
                                                         per-clip gap averaged over the reports, then mean, CI, wins
Bootstrap: 2000 resamples of the clips, numpy default_rng(0)."""
import json
import sys

import numpy as np

MEASURES = ("speed_env", "jaw_env", "bc")


def boot(d, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    m = d[rng.integers(0, len(d), (n, len(d)))].mean(1)
    return d.mean(), np.percentile(m, 2.5), np.percentile(m, 97.5)


def real_gaps(path, measure):
    per = json.load(open(path))["real"]["model"]["per_clip"]
    return {c["id"]: c[measure]["gap"] for c in per}


def main(kind, *paths):
    if kind == "real":
        a, b = paths
        for m in MEASURES:
            ga, gb = real_gaps(a, m), real_gaps(b, m)
            d = np.array([gb[i] - ga[i] for i in sorted(ga)])
            mu, lo, hi = boot(d)
            print(f"real {m:10s} candidate - shipped {mu:+.3f} [{lo:+.3f}, {hi:+.3f}], clips better {int((d > 0).sum())}/{len(d)}")
    elif kind == "synth":
        a, b = (json.load(open(p))["generated"]["per_clip"] for p in paths)
        ga = {c["id"]: c["bc"] - c["bc_mismatched_audio"] for c in a}
        gb = {c["id"]: c["bc"] - c["bc_mismatched_audio"] for c in b}
        d = np.array([gb[i] - ga[i] for i in sorted(ga)])
        mu, lo, hi = boot(d)
        print(f"synth BC gap candidate - shipped {mu:+.4f} [{lo:+.4f}, {hi:+.4f}], clips better {int((d > 0).sum())}/{len(d)}")
    elif kind == "pool":
        for m in MEASURES:
            gs = [real_gaps(p, m) for p in paths]
            ids = sorted(gs[0])
            if any(sorted(g) != ids for g in gs):
                raise SystemExit("pool: the reports cover different clips")
            d = np.array([np.mean([g[i] for g in gs]) for i in ids])
            mu, lo, hi = boot(d)
            print(f"pooled {m:10s} gap {mu:+.3f} [{lo:+.3f}, {hi:+.3f}] {int((d > 0).sum())}/{len(d)}")
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    main(sys.argv[1], *sys.argv[2:])
