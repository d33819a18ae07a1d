#!/usr/bin/env bash
# usage: chain_eval.sh NAME  -> real-speech rules 1-3 first, then export and the in-distribution seeds 7-12
set -euo pipefail
name=$1
cd "$(dirname "$0")/../../../.."
source scripts/env.sh >/dev/null 2>&1
T=docs/eval/realspeech-loudness-2026-11-25/train
CK=/work/runs-loud16/$name/final.pt
bash $T/eval_real.sh $name $CK
t0=$(date +%s)
nice -n 10 $LIVEGESTURE_PY export/export.py --checkpoint $CK --out /tmp/loud16/bundle_$name \
  --reference-wav models/default/reference/clip.wav --reference-seconds 60 > /tmp/loud16/export_$name.log 2>&1
echo "export: $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
bash $T/eval_synth.sh $name /tmp/loud16/bundle_$name
echo EVALDONE
