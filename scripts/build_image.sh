#!/usr/bin/env bash
# Builds the `livegesture serve` image from the Containerfile with podman (docs/deploy.md#container-image).
#
#   scripts/build_image.sh [--tag NAME] [--registry | --local] [--no-check]
#
# --registry: `podman build -f Containerfile .` as it stands: the binary built in the image
#   (docker.io/library/rust:1.92-bookworm) and the runtime on docker.io/library/debian:bookworm-slim.
# --local: for a machine that cannot reach docker.io (as this project's), the same Containerfile with
#   - the build argument BASE: a Debian bookworm root filesystem made here from Debian's packages
#     (mmdebstrap --variant=essential: dpkg's essential set and libgcc-s1; /usr merged by mmdebstrap's
#     hook rather than the usrmerge package, which brings perl; no documentation or locales),
#     imported with `podman import` as localhost/livegesture-base:bookworm (kept for the next build;
#     LIVEGESTURE_REFRESH_BASE=1 makes it again);
#   - the `build` stage replaced (--build-context build=docker-image://...) by an image holding the
#     binary built on this host (`cargo build --release --locked -p livegesture`, or $LIVEGESTURE_BIN;
#     stripped): the builder image (rust:1.92) comes from docker.io, Debian's rustc (1.63) is older
#     than the crate's 1.92, and a RUN step needs a container runtime. Allowed only when the binary
#     fits the base: the newest GLIBC_x.y symbol version it needs must be at most the base's glibc
#     (checked).
# Default: --registry when both docker.io images can be pulled (60 s each), else --local.
# Then (unless --no-check) a smoke check of the image's files: the image is mounted and its binary
# started with chroot as the image's user (not a container: no namespaces or limits): /healthz 200,
# /metrics, SIGTERM -> exit 0. Prints the image's size.
set -euo pipefail
cd "$(dirname "$0")/.."

tag=livegesture-serve mode=auto check=1
while [ $# -gt 0 ]; do
  case "$1" in
    --tag) tag="$2"; shift 2 ;;
    --registry) mode=registry; shift ;;
    --local) mode=local; shift ;;
    --no-check) check=0; shift ;;
    *) echo "build_image.sh: unknown argument $1 (see the header of scripts/build_image.sh)" >&2; exit 2 ;;
  esac
done

need() {
  local missing=()
  for p in "$@"; do command -v "${p%%:*}" >/dev/null 2>&1 || missing+=("${p#*:}"); done
  [ ${#missing[@]} -eq 0 ] && return
  if [ "$(id -u)" = 0 ]; then _sudo=""; else _sudo="sudo"; fi
  $_sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $_sudo apt-get install -y -qq "${missing[@]}" >/dev/null
}
need podman:podman

BUILDER=docker.io/library/rust:1.92-bookworm
BASE=docker.io/library/debian:bookworm-slim
if [ "$mode" = auto ]; then
  mode=registry
  for img in "$BASE" "$BUILDER"; do
    if ! timeout 60 podman pull -q "$img" >/dev/null 2>&1; then
      echo "build_image.sh: cannot pull $img: building with --local"
      mode=local
      break
    fi
  done
fi

t0=$SECONDS
if [ "$mode" = registry ]; then
  echo "+ podman build -t $tag -f Containerfile ."
  podman build -t "$tag" -f Containerfile .
else
  need mmdebstrap:mmdebstrap objdump:binutils curl:curl
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
  base=localhost/livegesture-base:bookworm
  if [ -n "${LIVEGESTURE_REFRESH_BASE:-}" ] || ! podman image exists "$base"; then
    echo "+ mmdebstrap --variant=essential bookworm | podman import - $base"
    # dates in the tarball from SOURCE_DATE_EPOCH: the same packages give the same base
    SOURCE_DATE_EPOCH="${SOURCE_DATE_EPOCH:-$(git log -1 --format=%ct)}" mmdebstrap --quiet --variant=essential \
      --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr --include=libgcc-s1 \
      --dpkgopt='path-exclude=/usr/share/doc/*' --dpkgopt='path-exclude=/usr/share/man/*' \
      --dpkgopt='path-exclude=/usr/share/info/*' --dpkgopt='path-exclude=/usr/share/locale/*' \
      --customize-hook='rm -rf "$1"/var/cache/apt/* "$1"/var/lib/apt/lists/* "$1"/var/log/*' \
      bookworm "$work/base.tar" http://deb.debian.org/debian
    podman import -q "$work/base.tar" "$base" >/dev/null
    rm -f "$work/base.tar"
  fi
  # the base's glibc (its dpkg status) and the newest glibc symbol version the binary needs
  mnt="$(podman image mount "$base")"
  base_glibc="$(awk '/^Package: libc6$/{p=1} p&&/^Version:/{print $2; exit}' "$mnt/var/lib/dpkg/status")"
  podman image unmount "$base" >/dev/null
  base_glibc="${base_glibc%%-*}"

  bin="${LIVEGESTURE_BIN:-}"
  if [ -z "$bin" ]; then
    echo "+ cargo build --release --locked -p livegesture"
    cargo build --release --locked -p livegesture
    bin="${CARGO_TARGET_DIR:-target}/release/livegesture"
  fi
  need_glibc="$(objdump -T "$bin" | grep -o 'GLIBC_[0-9.]*' | sed 's/GLIBC_//' | sort -uV | tail -n1)"
  if [ "$(printf '%s\n%s\n' "$need_glibc" "$base_glibc" | sort -V | tail -n1)" != "$base_glibc" ]; then
    echo "build_image.sh: $bin needs glibc $need_glibc, the base has $base_glibc: build it on Debian bookworm, or use --registry" >&2
    exit 1
  fi
  echo "binary: $bin (needs glibc >= $need_glibc; the base has $base_glibc)"
  mkdir -p "$work/bin/src/target/release"
  strip -o "$work/bin/src/target/release/livegesture" "$bin"
  tar -C "$work/bin" -cf "$work/bin.tar" src
  podman import -q "$work/bin.tar" localhost/livegesture-binary:build >/dev/null
  echo "+ podman build -t $tag -f Containerfile --build-arg BASE=$base --build-context build=docker-image://localhost/livegesture-binary:build ."
  podman build -t "$tag" -f Containerfile --build-arg BASE="$base" \
    --build-context build=docker-image://localhost/livegesture-binary:build .
  podman rmi -f localhost/livegesture-binary:build >/dev/null
fi
echo "built $tag in $(( SECONDS - t0 )) s ($mode): $(podman image inspect --format '{{.Size}}' "$tag" | awk '{printf "%.1f MB", $1/1e6}')"

[ "$check" = 1 ] || exit 0
# the smoke check: the image's own files, its binary on its base's glibc, as its user
need curl:curl
mnt="$(podman image mount "$tag")"
trap 'podman image unmount "$tag" >/dev/null 2>&1 || true; rm -rf "${work:-}"' EXIT
user="$(podman image inspect --format '{{.Config.User}}' "$tag")"
port=$(( 20000 + RANDOM % 20000 ))
log="$(mktemp)"
chroot --userspec="$user" "$mnt" /usr/local/bin/livegesture serve --addr "127.0.0.1:$port" --backend tract \
  --bundle /opt/livegesture/models/default 2>"$log" &
pid=$!
ok=0
for _ in $(seq 1 120); do
  if curl -fsS "http://127.0.0.1:$port/healthz" 2>/dev/null | grep -q '^ok: model'; then ok=1; break; fi
  kill -0 "$pid" 2>/dev/null || break
  sleep 0.5
done
if [ "$ok" = 1 ] && curl -fsS "http://127.0.0.1:$port/metrics" | grep -q '^livegesture_sessions_capacity '; then
  kill -TERM "$pid"
  if wait "$pid"; then
    echo "smoke check: the image's binary served /healthz and /metrics as user $user from the image's files (chroot) and exited 0 on SIGTERM"
    rm -f "$log"
    exit 0
  fi
fi
kill -KILL "$pid" 2>/dev/null || true
echo "build_image.sh: smoke check failed; the server said:" >&2
cat "$log" >&2
rm -f "$log"
exit 1
