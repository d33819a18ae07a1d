#!/usr/bin/env bash
# Parity on every target (docs/targets.md, docs/targets.md): one bundle, the torch references made at export,
# judged on each named target.
#
#   scripts/targets.sh [--bundle DIR] [--checks LIST] [--out DIR] TARGET...
#
# TARGET: x86-64-v4 (this machine, native), x86-64-v3 (`qemu-x86_64 -cpu Haswell`: AVX2+FMA, no AVX-512),
# x86-64-v2 (`qemu-x86_64 -cpu Nehalem`: SSE4.2, no AVX), aarch64 (the aarch64 gnu build under qemu-aarch64,
# tract and ONNX Runtime from PyPI's aarch64 wheel), aarch64-musl (the static aarch64 build, tract), armv7 (tract,
# qemu-arm: tract's VFP kernels), armv7-neon (the same under an armv7 /proc/cpuinfo and `-cpu cortex-a7`: tract's
# NEON kernels), windows (the x86-64 Windows build under wine, tract), aarch64-neon and aarch64-musl-neon (aarch64 and
# aarch64-musl under `qemu-aarch64 -cpu cortex-a72`: NEON, no SVE), or all (x86-64-v4 x86-64-v3 x86-64-v2 aarch64 armv7).
# openvino, webgpu, wasm-tract and wasm-ort-web run through scripts/targets_providers.sh (same report, same exit).
#
# Each target runs `livegesture parity --target-name TARGET --json OUT/TARGET.json` (default OUT: target/targets):
# ONNX Runtime within 1e-5 and tract within 1e-4 (scaled) of the torch references, the seeded rollout with
# identical tokens up to a first divergence that must be a near-tie, frames before it within 1e-4. The JSON is
# the parity report (rows, passed, tokens, divergences) plus a `target` object: the instruction set and kernels
# tract chose, the CPU features ONNX Runtime dispatches on, and the runner. Exit 0 only when every target passes;
# 1 when one fails (the failing graph and output are printed); 2 on bad arguments.
#
# --checks: the parity checks (default: all on x86-64-v4; graph,rollout,logmel under emulation, where the chunk and
# batch invariance checks, which do not depend on the instruction set, would take many times longer).
# x86-64 targets run target/release/livegesture (build it first: cargo build --release -p livegesture); the
# others build once with scripts/cross.sh (profile dist; TARGETS_NO_BUILD=1: use the binary already built).
# Add a target: a function `target_NAME` setting BIN, RUNNER, BACKENDS (and ORT_LIB for ort) like those below.
set -euo pipefail
cd "$(dirname "$0")/.."

ALL="x86-64-v4 x86-64-v3 x86-64-v2 aarch64 armv7"
bundle=models/default
checks=""
out=target/targets
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --bundle) bundle="${2:?--bundle needs a folder}"; shift 2 ;;
    --checks) checks="${2:?--checks needs a list}"; shift 2 ;;
    --out) out="${2:?--out needs a folder}"; shift 2 ;;
    -h|--help) sed -n '2,26p' "$0"; exit 0 ;;
    all) targets+=($ALL); shift ;;
    -*) echo "targets.sh: unknown option $1" >&2; exit 2 ;;
    *) targets+=("$1"); shift ;;
  esac
done
[ ${#targets[@]} -gt 0 ] || { echo "targets.sh: name at least one target (or all): $ALL aarch64-musl aarch64-neon aarch64-musl-neon armv7-neon windows openvino webgpu wasm-tract wasm-ort-web" >&2; exit 2; }
[ -f "$bundle/manifest.json" ] || { echo "targets.sh: --bundle $bundle: no manifest.json there (expected a bundle folder)" >&2; exit 2; }
source scripts/env.sh >/dev/null
mkdir -p "$out"

host_bin() {
  BIN="$PWD/target/release/livegesture"
  [ -x "$BIN" ] || { echo "targets.sh: $BIN is missing (cargo build --release -p livegesture)" >&2; exit 2; }
}
# the cross build of a triple: built (once) by scripts/cross.sh, or with TARGETS_NO_BUILD=1 (or CROSS_NO_BUILD=1) the
# binary already there, so that a run does not wait on cargo's lock while another cross build holds it
cross_bin() {
  CROSS_NO_BUILD="${CROSS_NO_BUILD:-${TARGETS_NO_BUILD:-0}}" scripts/cross.sh "$1"
}
need_qemu() {
  command -v "$1" >/dev/null 2>&1 || DEBIAN_FRONTEND=noninteractive apt-get install -y -qq qemu-user >/dev/null
}

# --- one function per target: BIN, RUNNER (command prefix), BACKENDS, ORT_LIB, EMULATED -------------------------
target_x86_64_v4() {
  host_bin; RUNNER=""; BACKENDS=ort,tract; ORT_LIB="$ORT_DYLIB_PATH"; EMULATED=0
  grep -qw avx512f /proc/cpuinfo || { echo "targets.sh: x86-64-v4 runs natively and this CPU has no AVX-512" >&2; return 1; }
}
target_x86_64_v3() {
  host_bin; need_qemu qemu-x86_64; RUNNER="qemu-x86_64 -cpu Haswell"; BACKENDS=ort,tract; ORT_LIB="$ORT_DYLIB_PATH"; EMULATED=1
}
target_x86_64_v2() {
  host_bin; need_qemu qemu-x86_64; RUNNER="qemu-x86_64 -cpu Nehalem"; BACKENDS=ort,tract; ORT_LIB="$ORT_DYLIB_PATH"; EMULATED=1
}
target_aarch64() {
  BIN="$(cross_bin aarch64-unknown-linux-gnu)" || return 1; RUNNER="$(scripts/cross.sh --runner aarch64-unknown-linux-gnu)"
  ORT_LIB="$(scripts/cross.sh --ort-lib aarch64-unknown-linux-gnu)"; BACKENDS=ort,tract; EMULATED=1
}
target_aarch64_musl() {
  BIN="$(cross_bin aarch64-unknown-linux-musl)" || return 1; RUNNER="$(scripts/cross.sh --runner aarch64-unknown-linux-musl)"
  ORT_LIB=""; BACKENDS=tract; EMULATED=1
}
# NEON-only aarch64 (Graviton 2 / Neoverse N1, Raspberry Pi 4, Ampere Altra): qemu's default CPU model (`max`) offers
# SVE, so tract would take its SVE kernels; `-cpu cortex-a72` (ARMv8.0 + NEON, no SVE, no dotprod) makes both
# runtimes dispatch to their NEON paths (tract: the arm64simd kernels)
target_aarch64_neon() {
  target_aarch64; RUNNER="$RUNNER -cpu cortex-a72"
}
target_aarch64_musl_neon() {
  target_aarch64_musl; RUNNER="$RUNNER -cpu cortex-a72"
}
target_armv7() {
  BIN="$(cross_bin armv7-unknown-linux-gnueabihf)" || return 1; RUNNER="$(scripts/cross.sh --runner armv7-unknown-linux-gnueabihf)"
  ORT_LIB=""; BACKENDS=tract; EMULATED=1
}
# armv7 with NEON (Raspberry Pi 2, Cortex-A7): tract reads NEON from /proc/cpuinfo on 32-bit ARM, and qemu-arm shows it
# this x86-64 host's, so plain `armv7` runs tract's VFP-only kernels (armvfpv2); scripts/qemu_armv7_cpuinfo.sh gives
# it a Cortex-A7's, and tract takes its armv7neon kernels
target_armv7_neon() {
  target_armv7; RUNNER="$PWD/scripts/qemu_armv7_cpuinfo.sh -L /usr/arm-linux-gnueabihf -cpu cortex-a7"
}
target_windows() {
  BIN="$(cross_bin x86_64-pc-windows-gnu)" || return 1; RUNNER="wine"; ORT_LIB=""; BACKENDS=tract; EMULATED=1
  export WINEDEBUG=-all WINEPREFIX="${WINEPREFIX:-$(dirname "$LIVEGESTURE_VENV")/wine}"   # created once (wineboot)
}

failed=()
for t in "${targets[@]}"; do
  case "$t" in   # the execution-provider and browser targets: scripts/targets_providers.sh, same report and exit
    openvino|webgpu|wasm-tract|wasm-ort-web)
      scripts/targets_providers.sh --bundle "$bundle" --out "$out" "$t" || failed+=("$t"); continue ;;
  esac
  fn="target_${t//-/_}"
  if ! declare -F "$fn" >/dev/null; then
    echo "targets.sh: unknown target '$t'; expected: $ALL aarch64-musl aarch64-neon aarch64-musl-neon armv7-neon windows openvino webgpu wasm-tract wasm-ort-web all" >&2; exit 2
  fi
  echo "=== target $t on $bundle"
  if ! "$fn"; then failed+=("$t (could not start)"); continue; fi
  c="$checks"
  [ -n "$c" ] || { [ "$EMULATED" = 1 ] && c=graph,rollout,logmel || c=graph,rollout,logmel,chunks,batch; }
  json="$out/$t.json"
  rm -f "$json"
  start=$SECONDS
  set +e
  ORT_DYLIB_PATH="$ORT_LIB" $RUNNER "$BIN" parity --bundle "$bundle" --backends "$BACKENDS" --checks "$c" \
    --target-name "$t" --json "$json" --quiet 2>&1 | tee "$out/$t.txt"
  rc=${PIPESTATUS[0]}
  set -e
  secs=$(( SECONDS - start ))
  if [ ! -s "$json" ]; then
    echo "targets.sh: $t: no report written (exit $rc)" >&2; failed+=("$t (exit $rc, no report)"); continue
  fi
  # the runner and the wall time beside the report (emulated time is not a speed)
  "$LIVEGESTURE_PY" - "$json" "$RUNNER" "$BIN" "$secs" "$EMULATED" <<'PY'
import json, sys
path, runner, binary, secs, emulated = sys.argv[1:]
r = json.load(open(path))
t = r.setdefault("target", {})
t.update(runner=runner or "native", binary=binary, wall_seconds=int(secs), emulated=emulated == "1")
json.dump(r, open(path + ".tmp", "w"), indent=1)
import os; os.replace(path + ".tmp", path)
t = r["target"]
print(f"target {t['name']}: {'PASS' if r['passed'] else 'FAIL'}, {t['comparisons']} comparisons, "
      f"{t['failed']} failed, tract {t['cpu']['tract_rung']} ({t['cpu']['tract_isa']}), "
      f"cpu features {','.join(t['cpu']['cpu_features']) or '-'}, {secs} s ({'emulated' if t['emulated'] else 'native'})")
PY
  [ "$rc" = 0 ] || failed+=("$t (exit $rc)")
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "targets.sh: FAILED on $bundle: ${failed[*]}" >&2
  exit 1
fi
echo "targets.sh: every target passed on $bundle: ${targets[*]}"
