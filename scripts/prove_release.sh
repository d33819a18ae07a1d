#!/usr/bin/env bash
# Proves release archives from the archive alone (docs/install.md): scripts/prove_release.sh TARGET...
# (Rust triples whose archives scripts/release.sh wrote to target/dist/; `c-sdk` and `web` are skipped here.)
#
# For each: `sha256sum -c` against target/dist/SHA256SUMS; the archive extracted into an empty folder outside
# the repository; `--version` names the commit and the target; the musl binaries are static (`file`); then
# `generate` on a WAV (5.23 s of the bundle's reference speech, written into that folder) with no --bundle
# (the bundle is found next to the executable) and no environment from the project, natively, under qemu-user
# or under wine. The output must have ceil(duration x 30) frames, all finite, and equal the native x86-64 build
# (target/release/livegesture, tract, same seed): bit for bit for x86-64 (musl, gnu, Windows: the same kernels),
# within 1e-4 (scaled) with identical motion tokens on other instruction sets. Exit 0 only when all pass.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh >/dev/null
repo="$PWD"
dist="$repo/target/dist"
VERSION="$(sed -n 's/^version = "\(.*\)"/\1/p' runtime/Cargo.toml | head -n1)"
# the native reference build (x86-64 gnu, this checkout's target/release unless LIVEGESTURE_NATIVE_BIN names another)
native="${LIVEGESTURE_NATIVE_BIN:-$repo/target/release/livegesture}"
[ -x "$native" ] || { echo "prove_release.sh: $native is missing (cargo build --release -p livegesture)" >&2; exit 2; }
work="$(mktemp -d /tmp/livegesture-prove.XXXXXX)"
trap 'rm -rf "$work"' EXIT

# the WAV and the native reference output (x86-64 gnu build of this checkout, tract)
"$LIVEGESTURE_PY" - models/default/reference/clip.wav "$work/speech.wav" <<'PY'
import sys, wave
with wave.open(sys.argv[1], "rb") as r, wave.open(sys.argv[2], "wb") as w:
    w.setparams(r.getparams())
    w.writeframes(r.readframes(int(5.23 * r.getframerate())))
PY
"$native" generate "$work/speech.wav" -o "$work/native.npz" --backend tract --seed 3 \
  --bundle models/default 2>/dev/null

failed=()
for triple in "$@"; do
  case "$triple" in c-sdk|web) continue ;; esac
  name="livegesture-$VERSION-$triple"
  archive=""
  for a in "$name.tar.gz" "$name.zip"; do [ -f "$dist/$a" ] && archive="$a"; done
  echo "=== prove $triple"
  if [ -z "$archive" ]; then failed+=("$triple (no archive in target/dist)"); continue; fi
  (cd "$dist" && grep " $archive\$" SHA256SUMS | sha256sum -c --quiet) || { failed+=("$triple (checksum)"); continue; }
  d="$work/$triple"; mkdir -p "$d"
  case "$archive" in
    *.zip) (cd "$d" && "$LIVEGESTURE_PY" -m zipfile -e "$dist/$archive" .) ;;
    *) tar -C "$d" -xzf "$dist/$archive" ;;
  esac
  exe="$d/$name/bin/livegesture"; runner="$(scripts/cross.sh --runner "$triple")"
  if [[ $triple == *windows* ]]; then exe="$exe.exe"; export WINEDEBUG=-all; fi
  if [[ $triple == *musl* ]]; then
    file "$exe" | grep -q "statically linked" || { file "$exe"; failed+=("$triple (not static)"); continue; }
    echo "static: $(file -b "$exe" | cut -d, -f1-5)"
  fi
  # from the extracted folder only: no repository, no project environment, the bundle next to the exe
  clean=(env -i PATH=/usr/bin:/bin HOME="$work" WINEDEBUG=-all)
  v="$(cd "$work" && "${clean[@]}" $runner "$exe" --version 2>&1 | tr -d '\r')"
  echo "$v"
  [[ $v == *"$triple"* && $v == *"commit "* ]] || { failed+=("$triple (--version: $v)"); continue; }
  start=$SECONDS
  if ! (cd "$work" && "${clean[@]}" $runner "$exe" generate speech.wav -o "$triple.npz" --backend tract --seed 3); then
    failed+=("$triple (generate failed)"); continue
  fi
  echo "generate: $(( SECONDS - start )) s ($([ -n "$runner" ] && echo "under $runner" || echo native))"
  exact=0; [[ $triple == x86_64-* ]] && exact=1
  if ! "$LIVEGESTURE_PY" - "$work/speech.wav" "$work/$triple.npz" "$work/native.npz" "$exact" <<'PY'
import math, sys, wave
import numpy as np
wav, got_p, want_p, exact = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4] == "1"
with wave.open(wav) as w:
    frames = math.ceil(w.getnframes() / w.getframerate() * 30)
got, want = np.load(got_p), np.load(want_p)
for k in ("poses", "trans", "expressions"):
    g, r = got[k], want[k]
    assert g.shape[0] == frames, f"{k}: {g.shape[0]} frames, expected ceil(duration x 30) = {frames}"
    assert np.isfinite(g).all(), f"{k}: non-finite values"
    if exact:
        assert g.shape == r.shape and np.array_equal(g, r), \
            f"{k}: differs from the native x86-64 build (max |diff| {np.abs(g - r).max() if g.shape == r.shape else 'shape'})"
    else:
        err = float(np.abs(g - r).max() / max(1.0, float(np.abs(r).max())))
        assert err <= 1e-4, f"{k}: {err:.3e} (scaled) from the native x86-64 build, bound 1e-4"
print(f"{frames} frames = ceil(duration x 30), finite, " + ("bit-identical to" if exact else "within 1e-4 of") + " the native x86-64 tract output")
PY
  then failed+=("$triple (output)"); continue; fi
done
if [ ${#failed[@]} -gt 0 ]; then echo "prove_release.sh: FAILED: ${failed[*]}" >&2; exit 1; fi
echo "prove_release.sh: every archive proven: $*"
