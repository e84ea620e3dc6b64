#!/usr/bin/env bash
# The live view (issue #19) in a real browser: headless Chromium from
# Debian's packages, driven by Playwright for Python (which uses that
# Chromium; it downloads no browser), against a real `semdepth serve` on
# loopback. Called by .ci/run; runs alone too:
#
#     bash tests/browser.sh
#
# Installs what is missing: chromium (apt, as root), and from PyPI
# playwright, pillow (to compose a two-object scene) and websockets (the
# example client's streaming). Screenshots go to $SEMDEPTH_SCREENSHOTS
# (default target/ci-artifacts/browser), which CI keeps; look at them.
# Set SEMDEPTH_BIN to test another binary (default: the release build).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
export PYTHONDONTWRITEBYTECODE=1

CHROMIUM=${CHROMIUM:-$(command -v chromium || true)}
if [ -z "$CHROMIUM" ]; then
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
        echo "installing chromium (apt)"
        apt-get update -qq
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    fi
    CHROMIUM=$(command -v chromium) || {
        echo "chromium not found: the browser test needs Debian's chromium (apt-get install chromium)" >&2
        exit 1
    }
fi
export CHROMIUM

for module in playwright:'playwright>=1.40,<2' PIL:'pillow>=9' websockets:'websockets>=12'; do
    if ! "$PYTHON" -c "import ${module%%:*}" >/dev/null 2>&1; then
        echo "installing ${module#*:} (PyPI)"
        "$PYTHON" -m pip install --quiet --disable-pip-version-check "${module#*:}"
    fi
done

if [ -n "${SEMDEPTH_BIN:-}" ]; then
    BIN=$SEMDEPTH_BIN
else
    cargo build --release --locked --quiet --bin semdepth
    BIN=$PWD/target/release/semdepth
fi
SHOTS=${SEMDEPTH_SCREENSHOTS:-$PWD/target/ci-artifacts/browser}
"$PYTHON" tests/browser/viewer_test.py "$BIN" "$SHOTS"
