#!/usr/bin/env bash
# usage: eval.sh NAME CKPT [BUNDLE]  -> stage 1 of README.md for one model:
#   real-speech VALIDATION split, Python reference, seeds 25-27 and 28-30 (SEEDS="31 34" for stage 2's fresh seeds);
#   then (unless SEEDS is set) the export to /tmp/seeds16/bundle_NAME (or the given BUNDLE) and the in-distribution
#   synthetic seeds 7-12 (Rust tract, /tmp/corpus_default's test split).
set -euo pipefail
name=$1 ck=$2
here=$(cd "$(dirname "$0")" && pwd)
cd "$here/../../../.."
source scripts/env.sh >/dev/null 2>&1
E=docs/eval/realspeech_eval.sh
bash $E real "$here/../real" "$name" "$ck" ${SEEDS:-25 28}
[ -n "${SEEDS:-}" ] && exit 0
mkdir -p /tmp/seeds16
b=${3:-/tmp/seeds16/bundle_$name}
if [ ! -f "$b/manifest.json" ]; then
  t0=$(date +%s)
  nice -n 10 $LIVEGESTURE_PY export/export.py --checkpoint "$ck" --out "$b" \
    --reference-wav models/default/reference/clip.wav --reference-seconds 60 > /tmp/seeds16/export_$name.log 2>&1
  echo "export: $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
fi
WORK=/tmp/seeds16 bash $E synth "$here/../synth" "$name" "$b" 7 8 9 10 11 12
echo EVALDONE
