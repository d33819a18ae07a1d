#!/usr/bin/env bash
# Builds the C library (bindings/c: target/release/liblivegesture_c.{a,so}) and the example
# examples/c/generate.c into target/c/generate, linked statically against the library:
#   scripts/build_c_example.sh              (--prebuilt: use the library a workspace build made)
#   target/c/generate BUNDLE IN.wav SEED [tract|ort] > poses.f32   # little-endian float32, frames x 165
# CC (default cc) and CFLAGS may be set.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" != "--prebuilt" ]; then
  cargo build --release -p livegesture-c
fi
mkdir -p target/c
# the system libraries the Rust standard library needs (rustc --print native-static-libs)
"${CC:-cc}" -std=c11 -Wall -Wextra -Werror -O2 ${CFLAGS:-} -I bindings/c/include \
  examples/c/generate.c target/release/liblivegesture_c.a \
  -lgcc_s -lutil -lrt -lpthread -lm -ldl -lc -Wl,-z,noexecstack -o target/c/generate
echo "built target/c/generate" >&2
