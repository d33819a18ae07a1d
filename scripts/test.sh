#!/usr/bin/env bash
# The project's test command (README "Test"; .ci/run calls it). Installs what it needs, then runs:
#   1. the Python test suite (PyTorch reference: step == offline, streaming contract, data, training, metrics)
#   2. the Rust tests (runtime numerics, bundles, CLI, parity against torch reference vectors)
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh

t0=$SECONDS
stage() { echo; echo "=== $* ($(( SECONDS - t0 )) s elapsed)"; }

stage "python tests"
"$LIVEGESTURE_PY" -m pytest -q python/tests

stage "rust tests"
if command -v cargo-nextest >/dev/null 2>&1; then
  cargo nextest run --workspace --release --no-fail-fast
else
  cargo test --workspace --release
fi

stage "done"
