#!/usr/bin/env bash
# usage: eval_synth.sh NAME BUNDLE  -> synthetic test split of the ORIGINAL corpus (/tmp/corpus_default, flux-driven
# motion: the yardstick of today's figures), Rust tract, seeds 7-12, each seed scored alone
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
WORK=/tmp/loud16 bash "$here/../../realspeech_eval.sh" synth "$here/../synth" "$1" "$2" ${SEEDS:-7 8 9 10 11 12}
