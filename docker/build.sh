#!/usr/bin/env bash
# Builds the semdepth container image without pulling any base image:
# compiles a statically linked binary on the host (glibc, +crt-static),
# then copies it into an image FROM scratch (docker/Dockerfile).
#
#   docker/build.sh [IMAGE_TAG]     (default semdepth:latest)
#
# Environment: SEMDEPTH_BIN names a static binary already built (as .ci/run
# builds it); without it the binary is compiled here. CARGO_TARGET_DIR is
# honoured; the static build lives in its own target triple folder, so it
# does not disturb the normal build.
set -euo pipefail
cd "$(dirname "$0")/.."
tag="${1:-semdepth:latest}"
triple=x86_64-unknown-linux-gnu
target_dir="${CARGO_TARGET_DIR:-target}"

if [ -n "${SEMDEPTH_BIN:-}" ]; then
    binary="$SEMDEPTH_BIN"
    echo "== static binary: $binary (SEMDEPTH_BIN; not compiled again)"
else
    echo "== static binary ($triple, +crt-static)"
    RUSTFLAGS="-C target-feature=+crt-static" CARGO_PROFILE_RELEASE_STRIP=symbols \
        cargo build --release --locked --bin semdepth --target "$triple"
    binary="$target_dir/$triple/release/semdepth"
fi
if [ ! -x "$binary" ]; then
    echo "error: no executable at $binary" >&2
    exit 1
fi
if ldd "$binary" 2>&1 | grep -q '=>'; then
    echo "error: $binary is dynamically linked:" >&2
    ldd "$binary" >&2
    exit 1
fi

context="$(mktemp -d)"
trap 'rm -rf "$context"' EXIT
mkdir -p "$context/rootfs/data" "$context/rootfs/tmp" "$context/rootfs/etc"
printf 'semdepth:x:10001:10001:semdepth:/data:/sbin/nologin\n' > "$context/rootfs/etc/passwd"
cp "$binary" "$context/semdepth"
cp docker/Dockerfile "$context/Dockerfile"

echo "== image $tag"
docker build --quiet -t "$tag" "$context"
size=$(docker image inspect "$tag" --format '{{.Size}}')
echo "image $tag: $size bytes ($(( (size + 524288) / 1048576 )) MiB)"
