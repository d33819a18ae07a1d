#!/usr/bin/env bash
# usage: train.sh NAME  -> NAME = flux1 | flux2 (the original flux-driven corpora, training seed 1 | 2) or
# sylb1 .. sylb4 (the syllable-body corpora, seed 1 .. 4). The recipe of ../realspeech-loudness-2026-11-25 ("loud",
# "flux", "sylb" there were seed 0), run by its train.sh: svq1/svq2 from the shipped checkpoint, experts 3000 and
# fuse 1600 steps, the clean corpus counted twice + the real-like corpus (the real-speech TRAIN split x 8, espeak-ng
# and flite voices). Run folder /work/runs-seeds16/NAME.
set -euo pipefail
name=$1
case $name in
  flux1|flux2|sylb1|sylb2|sylb3|sylb4) ;;
  *) echo "usage: train.sh flux1|flux2|sylb1|sylb2|sylb3|sylb4" >&2; exit 2 ;;
esac
here=$(cd "$(dirname "$0")" && pwd)
SEED=${name: -1} OUT=/work/runs-seeds16/$name LOG=$here/${name}_train_log.jsonl \
  exec bash "$here/../../realspeech-loudness-2026-11-25/train/train.sh" "${name%?}"
