#!/usr/bin/env bash
# models/README.md, DiffSHEG "sampler's jumps": the shipped bundle on the real-speech validation split per
# steps x jumps through the Rust CLI (ort), 3 seeds. O=OUT_DIR; needs source scripts/env.sh, PYTHONPATH=python.
set -e
cd "$(dirname "$0")/../../.."
O=${O:-/tmp/dsheg/rj}
$LIVEGESTURE_PY -m livegesture.eval.generalise --no-real --synth ${CORPUS:-/tmp/dsheg/corpus_default} --write-audio $O/audio >/dev/null 2>&1 || true
$LIVEGESTURE_PY -m livegesture.eval.generalise --write-audio $O/audio > /dev/null 2>&1 || true
ls $O/audio
for sj in 25x2 25x1 10x1; do
  s=${sj%x*}; j=${sj#*x}; args=()
  for seed in 1 2 3; do
    d=$O/$sj/seed$seed; mkdir -p $d
    for wav in $O/audio/real/*.wav; do
      id=$(basename $wav .wav)
      ./target/release/livegesture generate $wav -o $d/$id.npz --bundle models/diffsheg --backend ort --seed $seed --ddim-steps $s --jumps $j 2>/dev/null
    done
    args+=(--generated-real $d)
  done
  OMP_NUM_THREADS=1 $LIVEGESTURE_PY -m livegesture.eval.generalise "${args[@]}" --out $O/$sj/real3.json > $O/$sj/real3.log 2>&1
  echo "$sj done"
done
