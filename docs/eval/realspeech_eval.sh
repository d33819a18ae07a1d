#!/usr/bin/env bash
# The issue-16 evaluations of the pre-registered sittings (docs/eval/realspeech-*), one script for all of them.
#
#   realspeech_eval.sh real  OUTDIR NAME CKPT  FIRST_SEED...   real-speech VALIDATION split, Python reference:
#       python -m livegesture.eval.generalise --checkpoint CKPT --n-realisations 3 --seed S for each FIRST_SEED S
#       -> OUTDIR/NAME_real_seedsS-(S+2).json
#   realspeech_eval.sh synth OUTDIR NAME BUNDLE SEED...         synthetic test split of /tmp/corpus_default (the
#       original, flux-driven motion), Rust runtime (tract), each seed generated and scored alone
#       -> OUTDIR/NAME_sSEED.json; generated motion under $WORK/ev_NAME/generated_seedSEED
#
# Environment: WORK (default /tmp/realspeech-eval) for generated files; LIVEGESTURE_BIN (default
# $WORK/livegesture, else target/release/livegesture); CORPUS (default /tmp/corpus_default).
set -euo pipefail
kind=$1 out=$2 name=$3 model=$4
shift 4
cd "$(dirname "$0")/../.."
source scripts/env.sh >/dev/null 2>&1
export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
WORK=${WORK:-/tmp/realspeech-eval}
CORPUS=${CORPUS:-/tmp/corpus_default}
mkdir -p "$out"
out=$(cd "$out" && pwd)
case $kind in
  real)
    for s in "$@"; do
      t0=$(date +%s)
      nice -n 10 $LIVEGESTURE_PY -m livegesture.eval.generalise --checkpoint "$model" --n-realisations 3 --seed $s \
        --out "$out/${name}_real_seeds$s-$((s + 2)).json" > /dev/null
      echo "$name real seed $s: $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
    done ;;
  synth)
    BIN=${LIVEGESTURE_BIN:-$WORK/livegesture}
    [ -x "$BIN" ] || BIN=$PWD/target/release/livegesture
    for s in "$@"; do
      t0=$(date +%s)
      d=$WORK/ev_$name/generated_seed$s; mkdir -p "$d"
      for id in $(awk -F, '$2=="test"{print $1}' "$CORPUS/train_test_split.csv"); do
        nice -n 10 "$BIN" generate "$CORPUS/wave16k/$id.wav" -o "$d/$id.npz" --bundle "$model" \
          --backend tract --seed $s 2>/dev/null
      done
      t1=$(date +%s)
      (cd python && nice -n 10 $LIVEGESTURE_PY -m livegesture.eval --data "$CORPUS" --split test --generated "$d" \
        --fgd-encoder "$CORPUS/fgd_encoder.pt" --out "$out/${name}_s$s.json" > /dev/null)
      echo "$name synth seed $s: generate $((t1 - t0)) s, score $(( $(date +%s) - t1 )) s ($(date -u +%H:%M:%S))"
    done ;;
  *) echo "usage: realspeech_eval.sh real|synth OUTDIR NAME CKPT|BUNDLE SEED..." >&2; exit 2 ;;
esac
