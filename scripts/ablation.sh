#!/usr/bin/env bash
# The ablation tables of docs/evaluation.md ("Ablation table"): the `default` config of each family trained once per
# variant (python/livegesture/variants.py) on the synthetic corpus with ONE reduced budget per family, the same for
# every row of that family,
# then scored with the in-distribution report (python -m livegesture.eval) and the real-speech gaps
# on the real-speech validation set (python -m livegesture.eval.generalise, the motion swap's gaps), both through the
# Python streaming reference of the checkpoint (SEEDS seeds each).
#
#   scripts/ablation.sh [OUT]          (default target/ablation; checkpoints and reports stay there, out of the tree)
#   VARIANTS="full no-ugm ..."         LiveGesture rows to train, in order (default below; `full` must come first)
#   DS_VARIANTS="full no-x0 ..."       DiffSHEG rows, after LiveGesture's (default: the five of docs/diffsheg.md;
#                                      "" for none); each row trained from scratch (one stage), run diffsheg-NAME
#   DS_STEPS=500                       DiffSHEG steps per row (the shipped models/diffsheg: 2801 steps, 28 min cap),
#                                      its recipe's batch and learning rate
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
VARIANTS="${VARIANTS-full no-ugm no-region-mask no-pilor experts-only additive-audio full-body-svq no-temporal no-spatial}"
DS_VARIANTS="${DS_VARIANTS-full naive-concat no-detach no-x0 reverse}"
DS_STEPS="${DS_STEPS:-500}"
# the rows as FAMILY:VARIANT; a row's files are named by its run name (LiveGesture: NAME; DiffSHEG: diffsheg-NAME)
ROWS=""
for v in $VARIANTS; do ROWS+=" livegesture:$v"; done
for v in $DS_VARIANTS; do ROWS+=" diffsheg:$v"; done
run_name() { case "$1" in livegesture:*) echo "${1#*:}" ;; *) echo "${1%%:*}-${1#*:}" ;; esac; }
PY=(nice -n 15 "$LIVEGESTURE_PY")
mkdir -p "$OUT/runs" "$OUT/eval"
CORPUS="$OUT/corpus"

table() {   # the rows evaluated so far, as docs/evaluation.md's tables (one per family); the reference row from
            # each family's `full` reports
  "$LIVEGESTURE_PY" - "$OUT/eval" $ROWS <<'PY'
import json, sys
from pathlib import Path
d = Path(sys.argv[1])
def head():
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
for family in ("livegesture", "diffsheg"):
    rows = [a.split(":", 1)[1] for a in sys.argv[2:] if a.split(":", 1)[0] == family]
    if not rows:
        continue
    run = (lambda v: v) if family == "livegesture" else (lambda v: f"{family}-{v}")
    print(f"\n{family}\n")
    head()
    for v in rows:
        e, g = d / f"{run(v)}.json", d / f"{run(v)}.gen.json"
        if not (e.exists() and g.exists()):
            missing.append(run(v))
            continue
        row(f"`{v}`", json.loads(e.read_text())["generated"], json.loads(g.read_text())["real"]["motion_swap"]["model"])
    e, g = d / f"{run('full')}.json", d / f"{run('full')}.gen.json"
    if e.exists() and g.exists():
        row("corpus motion (reference)", json.loads(e.read_text())["ground_truth"],
            json.loads(g.read_text())["real"]["motion_swap"]["reference"])
if missing:
    print("\nnot evaluated: " + ", ".join(missing))
PY
}
[ -n "${TABLE_ONLY:-}" ] && { table; exit 0; }

[ -f "$CORPUS/train_test_split.csv" ] || \
  "${PY[@]}" -m livegesture.data.synth --out "$CORPUS" --minutes 64 --seed 1 --jobs 1
for row in $ROWS; do
  family="${row%%:*}" v="${row#*:}" name="$(run_name "$row")"
  run="$OUT/runs/$name" t=$SECONDS
  if [ "${TRAIN:-1}" = 0 ]; then
    while [ ! -f "$run/final.pt" ]; do sleep 20; done
  elif [ ! -f "$run/final.pt" ] && [ "$family" = diffsheg ]; then
    mkdir -p "$run"
    "${PY[@]}" -m livegesture.train --family diffsheg --config default --variant "$v" --data "$CORPUS" --out "$run" \
      --speakers all --threads 1 --device cpu --steps "$DS_STEPS" >"$run.train.log" 2>&1 \
      || { tail -20 "$run.train.log" >&2; exit 1; }
    echo "ablation: $name trained ($(( SECONDS - t )) s)"
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
  if [ ! -f "$OUT/eval/$name.json" ]; then
    "${PY[@]}" -m livegesture.eval --data "$CORPUS" --checkpoint "$run/final.pt" --n-realisations "${SEEDS:-2}" --seed 1 \
      ${EVAL_CLIPS:+--max-clips "$EVAL_CLIPS"} \
      --fgd-encoder "$OUT/fgd_encoder.pt" --no-per-clip --out "$OUT/eval/$name.json" >"$OUT/eval/$name.log" 2>&1 \
      || { tail -20 "$OUT/eval/$name.log" >&2; exit 1; }
  fi
  if [ ! -f "$OUT/eval/$name.gen.json" ]; then
    # the real-speech set only (its gaps; the synthetic set's held-out split is the in-distribution report's)
    "${PY[@]}" -m livegesture.eval.generalise --checkpoint "$run/final.pt" --n-realisations "${SEEDS:-2}" \
      --seed 1 --out "$OUT/eval/$name.gen.json" >"$OUT/eval/$name.gen.log" 2>&1 \
      || { tail -20 "$OUT/eval/$name.gen.log" >&2; exit 1; }
  fi
  echo "ablation: $name evaluated ($(( SECONDS - t )) s)"
done
table
