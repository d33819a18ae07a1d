#!/usr/bin/env bash
# f32 vs reduced-precision bundle of one config (issue 15 deliverable 3), one pinned core, interleaved rounds:
# every round runs `livegesture bench` on every (bundle, backend) once, bundles in alternating order, then the
# onnxruntime-from-Python peer on each bundle. Writes one JSON per run and a summary (medians over rounds,
# reduced / f32 ratios; load time and peak RSS of one stream, and the bundles' sizes on disk) to OUT/summary.json
# and OUT/summary.md.
#
#   scripts/bench_precision.sh F32_BUNDLE REDUCED_BUNDLE OUT_DIR
#   ROUNDS=3 BACKENDS="ort tract" STREAMS=32 BENCH_CPU=1 scripts/bench_precision.sh models/default /tmp/default-int8 \
#       bench/results/precision-default
# REDUCED_BUNDLE comes from `python export/quantize.py --bundle F32_BUNDLE --precision int8|f16 --out ...`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh >/dev/null 2>&1
[ $# -eq 3 ] || { echo "usage: scripts/bench_precision.sh F32_BUNDLE REDUCED_BUNDLE OUT_DIR" >&2; exit 2; }
A="$1"; B="$2"; OUT="$3"
BIN="${BIN:-$ROOT/target/release/livegesture}"
ROUNDS="${ROUNDS:-2}"; BACKENDS="${BACKENDS:-ort tract}"; STREAMS="${STREAMS:-32}"; CPU="${BENCH_CPU:-1}"
STEPS="${STEPS:-150}"; PEER_TOKENS="${PEER_TOKENS:-100}"
AUDIO="models/default/reference/clip.wav"
mkdir -p "$OUT"
export OMP_NUM_THREADS=1
"$LIVEGESTURE_PY" - "$OUT/env_start.json" <<'EOF'
import json, sys, time
json.dump({"time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
           "loadavg": open("/proc/loadavg").read().split()[:3]}, open(sys.argv[1], "w"))
EOF
for r in $(seq 1 "$ROUNDS"); do
  order=("$A" "$B"); (( r % 2 == 0 )) && order=("$B" "$A")
  for b in "${order[@]}"; do
    tag=$([ "$b" = "$A" ] && echo f32 || echo reduced)
    for be in $BACKENDS; do
      taskset -c "$CPU" "$BIN" bench --bundle "$b" --backend "$be" --threads 1 --audio "$AUDIO" --steps "$STEPS" \
        --warmup 10 --latency-trials 1 --streams "$STREAMS" --batch-steps 10 --batch-warmup 2 --batch-min-steps 3 \
        --batch-seconds 15 --json "$OUT/rust_${tag}_${be}_r$r.json" --quiet > /dev/null
      echo "[precision] round $r $tag $be done" >&2
    done
    taskset -c "$CPU" "$LIVEGESTURE_PY" bench/ort_python_peer.py --bundle "$b" --audio "$AUDIO" --tokens "$PEER_TOKENS" \
      --warmup 10 --check-tokens 40 --streams "" --json "$OUT/ort_python_${tag}_r$r.json" 2>/dev/null
  done
done
"$LIVEGESTURE_PY" - "$OUT" "$A" "$B" "$ROUNDS" "$BACKENDS" <<'EOF'
import json, statistics, sys, time
from pathlib import Path
out, a, b, rounds, backends = Path(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5].split()
med = statistics.median
summ = {"f32_bundle": a, "reduced_bundle": b, "rounds": rounds,
        "start": json.loads((out / "env_start.json").read_text()),
        "end": {"time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "loadavg": open("/proc/loadavg").read().split()[:3]},
        "precision": json.loads((Path(b) / "manifest.json").read_text())["precision"]["weights"], "backends": {}}
rows = []
for be in backends + ["ort_python"]:
    d = {}
    for tag in ("f32", "reduced"):
        chain, n32, graphs, load, rss = [], [], {}, [], []
        for r in range(1, rounds + 1):
            if be == "ort_python":
                j = json.loads((out / f"ort_python_{tag}_r{r}.json").read_text())
                chain.append(j["single"]["step_ms"]["median"])
                for g, v in j["single"]["graphs_ms_median"].items():
                    graphs.setdefault(g, []).append(v)
            else:
                j = json.loads((out / f"rust_{tag}_{be}_r{r}.json").read_text())
                chain.append(j["single"]["chain_ms"]["median"])
                for g in j["single"]["graphs"]:
                    graphs.setdefault(g["graph"], []).append(g["ms"]["median"])
                n32 += [x["step_ms"]["median"] for x in j["batched"]]
                load.append(j["load_seconds"])
                rss.append(j["peak_rss_single_bytes"])
        d[tag] = {"chain_ms_rounds": chain, "chain_ms": med(chain), "graphs_ms": {g: med(v) for g, v in graphs.items()},
                  "batched_ms_rounds": n32, "batched_ms": med(n32) if n32 else None,
                  "load_seconds": med(load) if load else None, "peak_rss_single_bytes": med(rss) if rss else None}
    d["chain_ratio"] = d["reduced"]["chain_ms"] / d["f32"]["chain_ms"]
    d["batched_ratio"] = (d["reduced"]["batched_ms"] / d["f32"]["batched_ms"]) if d["f32"]["batched_ms"] else None
    summ["backends"][be] = d
    fmt = lambda xs: ", ".join(f"{x:.2f}" for x in xs)  # noqa: E731
    rows.append(f"| {be} | {d['f32']['chain_ms']:.2f} ({fmt(d['f32']['chain_ms_rounds'])}) | "
                f"{d['reduced']['chain_ms']:.2f} ({fmt(d['reduced']['chain_ms_rounds'])}) | {d['chain_ratio']:.2f} | "
                + (f"{d['f32']['batched_ms']:.1f} ({fmt(d['f32']['batched_ms_rounds'])}) | "
                   f"{d['reduced']['batched_ms']:.1f} ({fmt(d['reduced']['batched_ms_rounds'])}) | {d['batched_ratio']:.2f} |"
                   if d["batched_ratio"] else "- | - | - |"))
md = ["| backend | f32 chain ms (rounds) | " + summ["precision"] + " chain ms (rounds) | ratio | f32 N=32 ms (rounds) | "
      + summ["precision"] + " N=32 ms (rounds) | ratio |", "|---|---|---|---|---|---|---|", *rows]
def du(folder):
    return sum(f.stat().st_size for f in Path(folder).rglob("*") if f.is_file())
def onnx_bytes(folder):
    return sum(f.stat().st_size for f in Path(folder).glob("*.onnx"))
summ["bytes_on_disk"] = {"f32": {"bundle": du(a), "graphs": onnx_bytes(a)},
                         "reduced": {"bundle": du(b), "graphs": onnx_bytes(b)}}
md += ["", "| backend | f32 load s | " + summ["precision"] + " load s | f32 peak RSS 1 stream MB | " + summ["precision"]
       + " peak RSS 1 stream MB |", "|---|---|---|---|---|"]
for be in backends:
    d = summ["backends"][be]
    md.append(f"| {be} | {d['f32']['load_seconds']:.2f} | {d['reduced']['load_seconds']:.2f} | "
              f"{d['f32']['peak_rss_single_bytes'] / 1e6:.0f} | {d['reduced']['peak_rss_single_bytes'] / 1e6:.0f} |")
bd = summ["bytes_on_disk"]
md += ["", f"on disk: f32 bundle {bd['f32']['bundle'] / 1e6:.1f} MB (graphs {bd['f32']['graphs'] / 1e6:.1f} MB), "
       f"{summ['precision']} bundle {bd['reduced']['bundle'] / 1e6:.1f} MB (graphs {bd['reduced']['graphs'] / 1e6:.1f} MB)"]
(out / "summary.json").write_text(json.dumps(summ, indent=1) + "\n")
(out / "summary.md").write_text("\n".join(md) + "\n")
print("\n".join(md))
EOF
