#!/usr/bin/env bash
# per-graph A/B with runtime/examples/graph_time (median of its timed loop), interleaved over ROUNDS rounds
# (bundle order reversed on even rounds), pinned to CPU 1, nice 10.
#   ROUNDS=5 BATCHES=2 BUNDLES="/tmp/ring/base /tmp/ring/masktab /tmp/ring/ring2" \
#     SPECS="expert_upper:tract fusion:tract expert_upper:ort experts_fused:ort fusion:ort" \
#     bench/results/ring-2026-11-25/graph_ab.sh   (from the repository root; GT=path of graph_time)
ROUNDS=${ROUNDS:-3}; BATCHES=${BATCHES:-"2 64"}; BUNDLES=${BUNDLES:-"base masktab ring"}
SPECS=${SPECS:-"expert_upper:tract fusion:tract experts_fused:ort fusion:ort"}; GT=${GT:-target/release/examples/graph_time}
for r in $(seq 1 $ROUNDS); do
  order=($BUNDLES); if (( r % 2 == 0 )); then order=($(echo $BUNDLES | tr ' ' '\n' | tac)); fi
  for spec in $SPECS; do
    g=${spec%%:*}; be=${spec##*:}
    for B in $BATCHES; do
      for b in "${order[@]}"; do
        m=$(taskset -c 1 nice -n 10 $GT $b $g $B $be 2>&1 | awk '/median/ {print $(NF-1)}')
        echo "$r $g $be B=$B $b $m"
      done
    done
  done
done
