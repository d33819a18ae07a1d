#!/usr/bin/env bash
# Training throughput on one GPU, both families, default and paper configs, before/after (a few minutes).
#
#   bash scripts/bench_train_gpu.sh prepare        # here (needs espeak-ng): the corpus, target/bench-train-corpus
#   bash scripts/bench_train_gpu.sh run [OUT_DIR]  # on the GPU machine (python3 with torch, numpy, scipy, tqdm)
#   bash scripts/bench_train_gpu.sh smoke          # here, CPU, tiny config: checks the script itself
#
# `run` writes OUT_DIR/bench_train.json (one row per family, config, stage and variant: steps/s, samples/s,
# GPU utilisation from nvidia-smi, peak GPU memory) and bench_train.md (the table), plus nvidia-smi's and
# torch's description of the machine. Variants: before = --amp off --prefetch 0; after = the CUDA defaults
# (bf16 autocast, prefetched pinned batches). The corpus is synthetic (livegesture.data.synth, 5 minutes):
# the device machine has no espeak-ng, so it is made here and travels (carry target/bench-train-corpus).
set -euo pipefail
cd "$(dirname "$0")/.."
CORPUS="${BENCH_TRAIN_CORPUS:-target/bench-train-corpus}"
PY="${LIVEGESTURE_PY:-python3}"
case "${1:-run}" in
  prepare)
    source scripts/env.sh
    "$LIVEGESTURE_PY" -m livegesture.data.synth --out "$CORPUS" --minutes "${BENCH_TRAIN_MINUTES:-5}" --seed 0 \
      --jobs 2 --clip-seconds 20 40 --overwrite --no-progress
    du -sh "$CORPUS" ;;
  run)
    OUT_DIR="${2:-${OUT:-target/bench-train}}"
    mkdir -p "$OUT_DIR"
    [ -d "$CORPUS" ] || { echo "no corpus at $CORPUS: run '$0 prepare' first (and carry it)" >&2; exit 2; }
    (nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv || true) > "$OUT_DIR/machine.txt" 2>&1
    PYTHONPATH=python PYTHONUNBUFFERED=1 "$PY" -c 'import torch, sys; print(sys.version); print("torch", torch.__version__, "cuda", torch.version.cuda)' >> "$OUT_DIR/machine.txt"
    PYTHONPATH=python PYTHONUNBUFFERED=1 "$PY" -m livegesture.bench_train --data "$CORPUS" --device cuda \
      --configs "${BENCH_TRAIN_CONFIGS:-default,paper}" --variants "${BENCH_TRAIN_VARIANTS:-before,after}" \
      --warmup "${BENCH_TRAIN_WARMUP:-5}" --steps "${BENCH_TRAIN_STEPS:-20}" --out "$OUT_DIR/bench_train.json" \
      2>&1 | grep -v 'it/s' | tee "$OUT_DIR/bench_train.log" ;;
  smoke)
    source scripts/env.sh
    dir="$(mktemp -d)"
    trap 'rm -rf "$dir"' EXIT
    "$LIVEGESTURE_PY" -m livegesture.data.synth --out "$dir/corpus" --minutes 0.6 --seed 3 --jobs 1 \
      --clip-seconds 10 14 --no-progress
    "$LIVEGESTURE_PY" -m livegesture.bench_train --data "$dir/corpus" --device cpu --configs tiny --warmup 1 \
      --steps 3 --threads 1 2>&1 | grep -v 'it/s' ;;
  *) echo "usage: $0 prepare|run [OUT_DIR]|smoke" >&2; exit 2 ;;
esac
