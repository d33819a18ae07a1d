#!/usr/bin/env bash
# after training: fw11 and soup checkpoints, then two chains: real speech (C) and in-distribution (D)
set -euo pipefail
cd /work/runs-ft16
until grep -q TRAINDONE train_s11.log; do sleep 15; done
cd /work/wt-ft16; source scripts/env.sh >/dev/null 2>&1; export PYTHONPATH=$PWD/python OMP_NUM_THREADS=1
mkdir -p /work/runs-ft16/soup
t0=$(date +%s)
nice -n 10 $LIVEGESTURE_PY -m livegesture.interpolate --base /work/runs-ft16/lr5e5all_s11/final.pt \
  --tuned /work/runs-ft16/lr5e5_s11/final.pt --alpha 0.5 --out /work/runs-ft16/soup/fusewise_s11_0.5.pt
nice -n 10 $LIVEGESTURE_PY -m livegesture.interpolate --base models/default.train/checkpoint.pt \
  --tuned /work/runs-ftlr/soup/fusewise_0.5.pt --tuned /work/runs-ft16/soup/fusewise_s11_0.5.pt --alpha 1 \
  --out /work/runs-ft16/soup/soup_fw7_fw11.pt
echo "interpolate $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
cd /work/runs-ft16
( ./eval_real.sh soup /work/runs-ft16/soup/soup_fw7_fw11.pt; ./eval_real.sh fw11 /work/runs-ft16/soup/fusewise_s11_0.5.pt ) > chain_c.log 2>&1 &
(
  cd /work/wt-ft16
  for n in soup:soup/soup_fw7_fw11.pt fw11:soup/fusewise_s11_0.5.pt; do
    name=${n%%:*} ck=/work/runs-ft16/${n#*:}; t0=$(date +%s)
    nice -n 10 $LIVEGESTURE_PY export/export.py --checkpoint $ck --out /tmp/ft16/bundle_$name \
      --reference-wav models/default/reference/clip.wav --reference-seconds 60 > /tmp/ft16/export_$name.log 2>&1
    echo "export $name $(( $(date +%s) - t0 )) s ($(date -u +%H:%M:%S))"
    /work/runs-ft16/eval_synth.sh $name /tmp/ft16/bundle_$name
  done
) > chain_d.log 2>&1 &
wait
echo POSTDONE
