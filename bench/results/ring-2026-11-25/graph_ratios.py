#!/usr/bin/env python
# usage: python graph_ratios.py graph_ab_output.txt BASE
# For each (graph, backend, batch): the medians over rounds and the median of each round's ratio to BASE.
import collections, statistics, sys
d = collections.defaultdict(dict)
for line in open(sys.argv[1]):
    r, g, be, B, b, m = line.split()
    d[(g, be, B, r)][b] = float(m)
base = sys.argv[2]
for k in sorted({k[:3] for k in d}):
    rs = [v for kk, v in d.items() if kk[:3] == k]
    for b in sorted({b for x in rs for b in x} - {base}):
        rat = [x[b] / x[base] for x in rs]
        print(f"{k[0]:14s} {k[1]:5s} {k[2]:5s} {b:24s} base {statistics.median(x[base] for x in rs):7.3f} ms  "
              f"this {statistics.median(x[b] for x in rs):7.3f} ms  ratio {statistics.median(rat):.3f}  "
              + " ".join(f"{x:.2f}" for x in rat))
