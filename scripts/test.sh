#!/usr/bin/env bash
# The project's test command (README "Test"; .ci/run calls it). Installs what it needs, then runs:
#   1. the Python test suite (PyTorch reference: step == offline, streaming contract, data, training,
#      metrics, export);
#   2. fresh exports of the tiny configs of both families (the exporter verifies every graph against torch);
#   3. the Rust build and the parity checks (torch vs ort vs tract) on that export and on models/default;
#   4. the Rust tests (runtime numerics, bundles, pipeline, CLI, parity suite incl. its must-fail cases).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh

t0=$SECONDS
stage() { echo; echo "=== $* ($(( SECONDS - t0 )) s elapsed)"; }

stage "python tests"
"$LIVEGESTURE_PY" -m pytest -q python/tests

stage "export the tiny config (random weights) -> target/test-bundles/tiny"
mkdir -p target/test-bundles
"$LIVEGESTURE_PY" export/export.py --config tiny --random-seed 0 --out target/test-bundles/tiny
# the Rust tests (runtime and parity suite) use this fresh export (parity-tests/src/lib.rs)
export LIVEGESTURE_TEST_BUNDLE="$PWD/target/test-bundles/tiny"

stage "export the DiffSHEG tiny config (random weights) -> target/test-bundles/diffsheg-tiny"
"$LIVEGESTURE_PY" export/export.py --family diffsheg --config tiny --random-seed 0 --out target/test-bundles/diffsheg-tiny
export LIVEGESTURE_DIFFSHEG_TINY_BUNDLE="$PWD/target/test-bundles/diffsheg-tiny"

stage "rust build (release)"
cargo build --release --workspace --all-targets

stage "parity: fresh tiny export, both backends"
./target/release/livegesture parity --bundle target/test-bundles/tiny --backends ort,tract
stage "parity: models/default, both backends"
./target/release/livegesture parity --bundle models/default --backends ort,tract
stage "parity: fresh DiffSHEG tiny export, both backends"
./target/release/livegesture parity --bundle target/test-bundles/diffsheg-tiny --backends ort,tract
stage "parity: models/diffsheg, both backends"
./target/release/livegesture parity --bundle models/diffsheg --backends ort,tract

stage "rust tests"
if command -v cargo-nextest >/dev/null 2>&1; then
  cargo nextest run --workspace --release --no-fail-fast
else
  cargo test --workspace --release --no-fail-fast
fi

stage "all tests passed"
