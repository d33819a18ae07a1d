#!/usr/bin/env bash
# Source this file: it installs what the project needs on a fresh machine (idempotent, cached) and exports
#   LIVEGESTURE_PY    the Python interpreter of the project's virtual environment
#   ORT_DYLIB_PATH    ONNX Runtime's shared library (from the venv's onnxruntime wheel) for the ort backend
# The venv lives in ${LIVEGESTURE_VENV:-~/.cache/livegesture/venv-<hash of python/requirements.txt>}, so it
# is built once per machine (torch brings ~5 GiB of CUDA libraries; ~3 minutes) and reused afterwards.
set -euo pipefail
_lg_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
_lg_req="$_lg_root/python/requirements.txt"
_lg_hash="$(sha256sum "$_lg_req" | cut -c1-12)"
LIVEGESTURE_VENV="${LIVEGESTURE_VENV:-$HOME/.cache/livegesture/venv-$_lg_hash}"

# Distribution packages: espeak-ng and flite speak the synthetic corpus.
if ! command -v espeak-ng >/dev/null 2>&1 || ! command -v flite >/dev/null 2>&1; then
  echo "[env] installing espeak-ng and flite (Debian packages)" >&2
  if [ "$(id -u)" = 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq espeak-ng flite >/dev/null
  else
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq espeak-ng flite >/dev/null
  fi
fi

# One installer at a time: scripts that source this file at the same moment (parallel evaluations) would
# otherwise race in pip (the editable reinstall below) and one of them fail.
mkdir -p "$(dirname "$LIVEGESTURE_VENV")"
exec {_lg_lock}>"$LIVEGESTURE_VENV.lock"
flock "$_lg_lock"
if [ ! -f "$LIVEGESTURE_VENV/.complete" ]; then
  echo "[env] creating Python venv at $LIVEGESTURE_VENV (first run on this machine: a few minutes)" >&2
  rm -rf "$LIVEGESTURE_VENV"
  python3 -m venv "$LIVEGESTURE_VENV"
  "$LIVEGESTURE_VENV/bin/pip" install -q --upgrade pip >/dev/null
  "$LIVEGESTURE_VENV/bin/pip" install -q -r "$_lg_req"
  touch "$LIVEGESTURE_VENV/.complete"
fi
# The package's pyproject needs setuptools >= 77 to build (its licence field); a venv's own setuptools is older,
# so install a new one once: then the editable install below builds offline, without an isolated build env.
if ! "$LIVEGESTURE_VENV/bin/python" -c 'import sys, setuptools; sys.exit(int(setuptools.__version__.split(".")[0]) < 77)' 2>/dev/null; then
  "$LIVEGESTURE_VENV/bin/pip" install -q "setuptools>=77" >/dev/null
fi
# The package itself is used from the checkout (editable, no copy): cheap, so redone every time.
"$LIVEGESTURE_VENV/bin/pip" install -q --no-deps --no-build-isolation -e "$_lg_root/python" >/dev/null 2>&1 || \
  "$LIVEGESTURE_VENV/bin/pip" install -q --no-deps -e "$_lg_root/python" >/dev/null
flock -u "$_lg_lock"
exec {_lg_lock}>&-

export LIVEGESTURE_VENV
export LIVEGESTURE_PY="$LIVEGESTURE_VENV/bin/python"
ORT_DYLIB_PATH="${ORT_DYLIB_PATH:-$(ls "$LIVEGESTURE_VENV"/lib/python3*/site-packages/onnxruntime/capi/libonnxruntime.so.1* 2>/dev/null | head -n1)}"
export ORT_DYLIB_PATH
