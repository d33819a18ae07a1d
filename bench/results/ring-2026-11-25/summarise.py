#!/usr/bin/env python
# usage: python summarise.py bench_ab_output.txt [BASE]
# Medians over rounds of scripts/bench_ab.sh's lines per (bundle, backend), and the median over rounds of each
# round's ratio to the BASE bundle (default: the first bundle listed) measured in the same round.
import collections, statistics, sys
rows = [l.split() for l in open(sys.argv[1]) if l.strip() and l.split()[0].isdigit()]
bundles = list(dict.fromkeys(r[1] for r in rows))
base = sys.argv[2] if len(sys.argv) > 2 else bundles[0]
val = {(r[0], r[1], r[3]): (float(r[4]), float(r[5])) for r in rows}
rounds = sorted({r[0] for r in rows}, key=int)
print(f"{'bundle':28s} {'backend':6s} {'chain ms':>9s} {'ratio':>6s} {'N=32 ms':>9s} {'ratio':>6s}   per-round ratios chain | N=32")
for be in ("ort", "tract"):
    for b in bundles:
        if (rounds[0], b, be) not in val:
            continue
        ch = [val[(r, b, be)][0] for r in rounds]; ba = [val[(r, b, be)][1] for r in rounds]
        rc = [val[(r, b, be)][0] / val[(r, base, be)][0] for r in rounds]
        rb = [val[(r, b, be)][1] / val[(r, base, be)][1] for r in rounds]
        print(f"{b:28s} {be:6s} {statistics.median(ch):9.3f} {statistics.median(rc):6.3f} {statistics.median(ba):9.2f} "
              f"{statistics.median(rb):6.3f}   {' '.join(f'{x:.2f}' for x in rc)} | {' '.join(f'{x:.2f}' for x in rb)}")
