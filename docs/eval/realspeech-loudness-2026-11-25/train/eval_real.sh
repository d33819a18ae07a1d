#!/usr/bin/env bash
# usage: eval_real.sh NAME CKPT  -> real-speech validation split, Python reference, seeds 19-21 and 22-24
# (SEEDS="25 28" for the next sitting's fresh seeds 25-30)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
bash "$here/../../realspeech_eval.sh" real "$here/../real" "$1" "$2" ${SEEDS:-19 22}
