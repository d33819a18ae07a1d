#!/usr/bin/env bash
# Proves release archives from the archive alone (docs/install.md): scripts/prove_release.sh TARGET...
# (Rust triples whose archives scripts/release.sh wrote to target/dist/; `c-sdk` and `web` are skipped here.)
#
# For each: `sha256sum -c` against target/dist/SHA256SUMS; the archive extracted into an empty folder outside
# the repository; `--version` names the commit and the target; the musl binaries are static (`file`, `ldd`); then
# `generate` on a WAV (5.23 s of the bundle's reference speech, written into that folder) with no --bundle
# (the bundle is found next to the executable) and no environment from the project, natively, under qemu-user
# or under wine. The output must have ceil(duration x 30) frames, all finite, and equal the native x86-64 build
# (target/release/livegesture, tract, same seed): the same bytes (cmp of the .npz) for x86-64 Linux (musl, gnu);
# within 1e-4 (scaled), i.e. the same motion tokens, for Windows (bit-identity reported) and other instruction
# sets. Every archive carries LICENSES/livegesture-LICENSE and crates.txt. Exit 0 only when all pass.
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
# wine's prefix lives in the cache folder beside the venv: its first start (wineboot, ~700 MB) is paid once per
# machine or CI run, not once per archive
export WINEPREFIX="${WINEPREFIX:-$(dirname "$LIVEGESTURE_VENV")/wine}"

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
  if [[ $triple == *windows* ]]; then
    exe="$exe.exe"; export WINEDEBUG=-all
    if [ ! -f "$WINEPREFIX/system.reg" ]; then   # wine's first start on this machine, measured
      ws=$SECONDS; wineboot -i >/dev/null 2>&1; wineserver -w
      echo "wine: prefix $WINEPREFIX created (wineboot) in $(( SECONDS - ws )) s"
    fi
  fi
  [ -s "$d/$name/LICENSES/livegesture-LICENSE" ] && [ -s "$d/$name/LICENSES/crates.txt" ] \
    || { failed+=("$triple (LICENSES/livegesture-LICENSE or crates.txt missing)"); continue; }
  if [[ $triple == *musl* ]]; then
    file "$exe" | grep -qE "statically linked|static-pie linked" || { file "$exe"; failed+=("$triple (not static)"); continue; }
    l="$(ldd "$exe" 2>&1 || true)"
    [[ $l == *"not a dynamic executable"* || $l == *"statically linked"* ]] || { echo "$l"; failed+=("$triple (ldd: dynamic)"); continue; }
    echo "static: $(file -b "$exe" | cut -d, -f1-5); ldd: $l"
  fi
  # from the extracted folder only: no repository, no project environment, the bundle next to the exe
  clean=(env -i PATH=/usr/bin:/bin HOME="$work" WINEDEBUG=-all WINEPREFIX="$WINEPREFIX")
  v="$(cd "$work" && "${clean[@]}" $runner "$exe" --version 2>&1 | tr -d '\r')"
  echo "$v"
  [[ $v == *"$triple"* && $v == *"commit "* ]] || { failed+=("$triple (--version: $v)"); continue; }
  start=$SECONDS
  if ! (cd "$work" && "${clean[@]}" $runner "$exe" generate speech.wav -o "$triple.npz" --backend tract --seed 3); then
    failed+=("$triple (generate failed)"); continue
  fi
  echo "generate: $(( SECONDS - start )) s ($([ -n "$runner" ] && echo "under $runner" || echo native))"
  # x86-64 Linux (musl, gnu): the same code and kernels as the native build, so the same bytes: the whole .npz
  # (its members carry a fixed timestamp) must equal the native one. Windows: its C runtime's libm is not
  # glibc's, so bit-identity is reported, not required: frames within 1e-4 (scaled), which a different motion
  # token (another codebook entry, O(1) apart) cannot meet. Other instruction sets: within 1e-4 likewise.
  exact=0
  if [[ $triple == x86_64-unknown-linux-* ]]; then
    exact=1
    cmp "$work/$triple.npz" "$work/native.npz" || { failed+=("$triple (.npz differs from the native build's)"); continue; }
    echo "cmp: $triple.npz is byte-identical to the native x86-64 gnu build's tract output"
  fi
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
        assert g.shape == r.shape, f"{k}: shape {g.shape}, the native x86-64 build's {r.shape}"
        err = float(np.abs(g - r).max() / max(1.0, float(np.abs(r).max())))
        assert err <= 1e-4, f"{k}: {err:.3e} (scaled) from the native x86-64 build, bound 1e-4"
same = all(np.array_equal(got[k], want[k]) for k in ("poses", "trans", "expressions"))
print(f"{frames} frames = ceil(duration x 30), finite, " + ("bit-identical to" if same else "within 1e-4 (scaled) of")
      + " the native x86-64 tract output")
PY
  then failed+=("$triple (output)"); continue; fi
done
if [ ${#failed[@]} -gt 0 ]; then echo "prove_release.sh: FAILED: ${failed[*]}" >&2; exit 1; fi
echo "prove_release.sh: every archive proven: $*"
