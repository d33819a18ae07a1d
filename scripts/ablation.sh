#!/usr/bin/env bash
# The LiveGesture ablation table of docs/evaluation.md ("Ablation table"): the `default` config trained once per
# variant (python/livegesture/variants.py) on the synthetic corpus with ONE reduced budget, the same for every row,
# then scored with the in-distribution report (python -m livegesture.eval) and the real-speech gaps
# on the real-speech validation set (python -m livegesture.eval.generalise, the motion swap's gaps), both through the
# Python streaming reference of the checkpoint (SEEDS seeds each).
#
#   scripts/ablation.sh [OUT]          (default target/ablation; checkpoints and reports stay there, out of the tree)
#   VARIANTS="full no-ugm ..."         rows to train, in order (default below; `full` must come first)
#   STEPS="500 135 250 135"            steps of svq1 svq2 experts fuse (default: a third of the `default` recipe's
#                                      svq1 and a sixth of its other stages, 1500 800 1500 800, docs/model.md; the
#                                      budget the shared machine allowed), the batches of the `default` recipe
#   SEEDS=2 EVAL_CLIPS=                seeds per clip in both reports; only the first N test clips in distribution
#                                      (the table in docs/evaluation.md: SEEDS=1 EVAL_CLIPS=3, what time allowed)
#   TABLE_ONLY=1                       only print the table of the rows already evaluated
#   TRAIN=0 / EVAL=0                   only evaluate (each row once its final.pt exists, waiting for it) / only
#                                      train: the two halves may run side by side, one training while the other
#                                      evaluates the rows already trained
#   LIVEGESTURE_REAL_SPEECH=DIR        the real-speech recordings (default: shared/data/real-speech beside the repo)
#
# A stage that a variant does not change (livegesture.train.first_changed_stage) computes exactly what `full`'s
# does (same seed, data, config and initial weights), so it is taken from the `full` run instead of being
# trained again: a training-only variant copies `full`'s stage checkpoints before its first changed stage; a
# variant that changes the fusion or the eXperts reuses `full`'s motion tokenizer (--svq-from). Every process
# runs at nice 15 with one torch thread (a shared machine); one run at a time.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=/dev/null
source scripts/env.sh >/dev/null
export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"
OUT="$(realpath -m "${1:-target/ablation}")"
read -r S1 S2 SE SF <<<"${STEPS:-500 135 250 135}"
VARIANTS="${VARIANTS:-full no-ugm no-region-mask no-pilor experts-only additive-audio full-body-svq no-temporal no-spatial}"
PY=(nice -n 15 "$LIVEGESTURE_PY")
mkdir -p "$OUT/runs" "$OUT/eval"
CORPUS="$OUT/corpus"

table() {   # the rows evaluated so far, as docs/evaluation.md's table; the reference row from `full`'s reports
  "$LIVEGESTURE_PY" - "$OUT/eval" $VARIANTS <<'PY'
import json, sys
from pathlib import Path
d = Path(sys.argv[1])
print("| variant | FGD | BC | BC gap, audio swap | BC gap, motion swap | L1 div. (eq. 2) | face MSE "
      "| real speech, speed gap [95% CI] | real speech, jaw gap [95% CI] |")
print("|---|---|---|---|---|---|---|---|---|")
def row(name, r, real):
    def gap(m):
        x = real["summary"][m]
        return f"{x['gap']:+.3f} [{x['gap_ci95'][0]:+.3f}, {x['gap_ci95'][1]:+.3f}]"
    div = r.get("l1div_realisations")
    print(f"| {name} | {r['fgd']:.2f} | {r['bc']:.3f} | {r['bc_gap']:+.3f} | {r['bc_gap_motion_swap']:+.3f} "
          f"| {'-' if div is None else f'{div:.3f}'} | {r['face']['face']:.4f} | {gap('speed_env')} | {gap('jaw_env')} |")
missing = []
for v in sys.argv[2:]:
    e, g = d / f"{v}.json", d / f"{v}.gen.json"
    if not (e.exists() and g.exists()):
        missing.append(v)
        continue
    row(f"`{v}`", json.loads(e.read_text())["generated"], json.loads(g.read_text())["real"]["motion_swap"]["model"])
if (d / "full.json").exists() and (d / "full.gen.json").exists():
    row("corpus motion (reference)", json.loads((d / "full.json").read_text())["ground_truth"],
        json.loads((d / "full.gen.json").read_text())["real"]["motion_swap"]["reference"])
if missing:
    print("\nnot evaluated: " + ", ".join(missing))
PY
}
[ -n "${TABLE_ONLY:-}" ] && { table; exit 0; }

[ -f "$CORPUS/train_test_split.csv" ] || \
  "${PY[@]}" -m livegesture.data.synth --out "$CORPUS" --minutes 64 --seed 1 --jobs 1
for v in $VARIANTS; do
  run="$OUT/runs/$v" t=$SECONDS
  if [ "${TRAIN:-1}" = 0 ]; then
    while [ ! -f "$run/final.pt" ]; do sleep 20; done
  elif [ ! -f "$run/final.pt" ]; then
    mkdir -p "$run"
    # how the stages before the variant's first changed stage are taken from `full`
    read -r first graphs <<<"$("$LIVEGESTURE_PY" -c "import sys
from livegesture import train, variants
v = sys.argv[1]
print(train.first_changed_stage(v) or 'none', v != 'full' and variants.get('livegesture', v).changes_graphs)" "$v")"
    reuse=()
    if [ "$v" != full ] && [ "$first" != svq1 ]; then
      [ -f "$OUT/runs/full/final.pt" ] || { echo "ablation: $v reuses full's stages: train full first" >&2; exit 1; }
      if [ "$graphs" = True ]; then
        reuse=(--svq-from "$OUT/runs/full/final.pt")
      else
        for s in svq1 svq2 experts fuse; do
          [ "$s" = "$first" ] && break
          cp "$OUT/runs/full/$s.pt" "$run/$s.pt"
        done
      fi
    fi
    "${PY[@]}" -m livegesture.train --config default --variant "$v" --data "$CORPUS" --out "$run" --speakers all \
      --threads 1 --device cpu --steps-svq1 "$S1" --steps-svq2 "$S2" --steps-experts "$SE" --steps-fuse "$SF" \
      "${reuse[@]}" >"$run.train.log" 2>&1 || { tail -20 "$run.train.log" >&2; exit 1; }
    echo "ablation: $v trained ($(( SECONDS - t )) s; first changed stage: $first; reused: ${reuse[*]:-${first}})"
  fi
  [ "${EVAL:-1}" = 0 ] && continue
  t=$SECONDS
  if [ ! -f "$OUT/eval/$v.json" ]; then
    "${PY[@]}" -m livegesture.eval --data "$CORPUS" --checkpoint "$run/final.pt" --n-realisations "${SEEDS:-2}" --seed 1 \
      ${EVAL_CLIPS:+--max-clips "$EVAL_CLIPS"} \
      --fgd-encoder "$OUT/fgd_encoder.pt" --no-per-clip --out "$OUT/eval/$v.json" >"$OUT/eval/$v.log" 2>&1 \
      || { tail -20 "$OUT/eval/$v.log" >&2; exit 1; }
  fi
  if [ ! -f "$OUT/eval/$v.gen.json" ]; then
    # the real-speech set only (its gaps; the synthetic set's held-out split is the in-distribution report's)
    "${PY[@]}" -m livegesture.eval.generalise --checkpoint "$run/final.pt" --n-realisations "${SEEDS:-2}" \
      --seed 1 --out "$OUT/eval/$v.gen.json" >"$OUT/eval/$v.gen.log" 2>&1 \
      || { tail -20 "$OUT/eval/$v.gen.log" >&2; exit 1; }
  fi
  echo "ablation: $v evaluated ($(( SECONDS - t )) s)"
done
table
