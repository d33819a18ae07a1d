#!/usr/bin/env bash
# Runs the whole benchmark matrix (BENCHMARKS.md, issue 7) on one core and writes BENCHMARKS.md's inputs:
#   bench/results/*.json      raw results (livegesture bench, PyTorch eager loop, FLOPs, roofline; not committed)
#   bench/results/summary.md  the tables (also written into BENCHMARKS.md between its results markers)
#   docs/bench/*.png          latency distribution, real-time streams per core against N
#
#   scripts/bench.sh                       # default bundle + a paper-config bundle with random weights
#   PAPER_BUNDLE=target/paper-bundle scripts/bench.sh   # reuse an exported paper bundle
#   QUICK=1 scripts/bench.sh               # fewer steps (smoke run; not for quoting)
#
# Everything is pinned to one CPU (taskset) and single-threaded (ort: 1 intra-op and 1 inter-op thread;
# tract is single-threaded; torch.set_num_threads(1)). Run on a quiet machine: the load average is recorded.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
set +u

RES="${RESULTS:-bench/results}"
PLOTS="${PLOTS:-docs/bench}"
PAPER_BUNDLE="${PAPER_BUNDLE:-target/paper-bundle}"
CPU="${BENCH_CPU:-0}"
AUDIO="models/default/reference/clip.wav"   # 42.5 s of speech; the paper bundle's own clip is 3 s
mkdir -p "$RES" "$PLOTS"

if [ -n "${QUICK:-}" ]; then
  STEPS=60; TORCH_TOKENS=60; BATCH_SECONDS=3
else
  STEPS=300; TORCH_TOKENS=300; BATCH_SECONDS=20
fi
PIN=(taskset -c "$CPU")
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1

echo "[bench] building (release)" >&2
cargo build --release -q -p livegesture
BIN="$ROOT/target/release/livegesture"

if [ ! -f "$PAPER_BUNDLE/manifest.json" ]; then
  echo "[bench] exporting a paper-config bundle with random weights to $PAPER_BUNDLE (a few minutes)" >&2
  "$LIVEGESTURE_PY" export/export.py --config paper --random-seed 0 --out "$PAPER_BUNDLE" \
    --rollout-tokens 16 --reference-seconds 3
fi

start=$(date -u +%FT%TZ)
load_start="$(cut -d' ' -f1-3 /proc/loadavg)"

echo "[bench] roofline" >&2
"${PIN[@]}" "$LIVEGESTURE_PY" -m livegesture.bench roofline --json "$RES/roofline.json" >/dev/null
# one token's roofline over the default bundle's real weight bytes, per backend form (issue 42 item 1)
for be in ort tract; do
  "${PIN[@]}" "$LIVEGESTURE_PY" -m livegesture.bench weights --bundle models/default --backend "$be" \
    --json "$RES/roofline_weights_$be.json" >/dev/null
done

declare -A BUNDLE=([default]=models/default [paper]="$PAPER_BUNDLE")
for cfg in default paper; do
  b="${BUNDLE[$cfg]}"
  "$LIVEGESTURE_PY" export/flops.py --bundle "$b" --json "$RES/flops_$cfg.json" >/dev/null
  for be in tract ort; do
    echo "[bench] livegesture bench: $cfg on $be" >&2
    # N=128 on the paper config takes seconds per batched step: every N is capped at
    # $BATCH_SECONDS s of timed steps (at least 5 steps) after 3 warm-up steps.
    "${PIN[@]}" "$BIN" bench --bundle "$b" --backend "$be" --threads 1 --audio "$AUDIO" \
      --steps "$STEPS" --warmup 20 --latency-trials 5 --streams 1,8,32,128 \
      --batch-steps 100 --batch-warmup 3 --batch-min-steps 5 --batch-seconds "$BATCH_SECONDS" \
      --json "$RES/rust_${cfg}_${be}.json" --quiet > "$RES/rust_${cfg}_${be}.txt"
    cat "$RES/rust_${cfg}_${be}.txt" >&2
  done
done

echo "[bench] PyTorch eager streaming loop" >&2
"${PIN[@]}" "$LIVEGESTURE_PY" -m livegesture.bench torch --checkpoint models/default.train/checkpoint.pt \
  --tokens "$TORCH_TOKENS" --json "$RES/torch_default.json" >/dev/null
"${PIN[@]}" "$LIVEGESTURE_PY" -m livegesture.bench torch --config paper \
  --tokens "$TORCH_TOKENS" --json "$RES/torch_paper.json" >/dev/null

echo "[bench] onnxruntime from Python (the second peer; reproduces the reference rollout's tokens first)" >&2
for cfg in default paper; do
  "${PIN[@]}" "$LIVEGESTURE_PY" bench/ort_python_peer.py --bundle "${BUNDLE[$cfg]}" --audio "$AUDIO" \
    --tokens "$TORCH_TOKENS" --warmup 20 --streams 1,32 --batch-steps 100 --batch-warmup 3 --batch-min-steps 5 \
    --batch-seconds "$BATCH_SECONDS" --json "$RES/ort_python_$cfg.json"
done

echo "[bench] roofline again (the tables use the best of both measurements)" >&2
"${PIN[@]}" "$LIVEGESTURE_PY" -m livegesture.bench roofline --json "$RES/roofline_end.json" >/dev/null

end=$(date -u +%FT%TZ)
"$LIVEGESTURE_PY" - "$RES/env.json" "$start" "$end" "$load_start" "$(cut -d' ' -f1-3 /proc/loadavg)" \
  "$(git rev-parse --short HEAD)" "$STEPS" "$BATCH_SECONDS" <<'EOF'
import json, os, platform, sys
out, start, end, l0, l1, commit, steps, bsec = sys.argv[1:]
cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
mem = next((l.split()[1] for l in open("/proc/meminfo") if l.startswith("MemTotal")), "0")
json.dump({"start": start, "end": end, "loadavg_start": l0, "loadavg_end": l1, "cpu": cpu,
           "cores": os.cpu_count(), "mem_gib": round(int(mem) / 2**20, 1), "kernel": platform.release(),
           "commit": commit, "steps": int(steps), "batch_seconds": float(bsec)},
          open(out, "w"), indent=1)
EOF

# the tables also go into BENCHMARKS.md between its results markers (the prose there is written by hand)
"$LIVEGESTURE_PY" bench/plot.py --results "$RES" --plots "$PLOTS" --doc BENCHMARKS.md
