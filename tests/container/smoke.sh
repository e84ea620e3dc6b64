#!/usr/bin/env bash
# Container smoke test (issue #5), run by .ci/run: builds the image FROM
# scratch (docker/build.sh), starts it with a named volume on the host
# network, creates a calibration and a session over HTTP, uploads a
# synthetic pair, replaces the container with a new one on the same volume
# and checks that both are still there; checks the health status turns
# healthy and that the server does not run as root. Cleans up its
# containers, volume and image.
#
# Needs docker (the daemon installed from Debian and started here when
# missing, also where only a docker client is installed), curl
# and python3; the host binary $SEMDEPTH_BIN (default target/release/semdepth,
# built if missing) makes the synthetic pair.
set -euo pipefail
cd "$(dirname "$0")/../.."

tag="semdepth-smoke:$$"
volume="semdepth-smoke-data-$$"
name="semdepth-smoke-$$"
token="smoke-$(date +%s%N)"
port="$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
base="http://127.0.0.1:$port"
work="$(mktemp -d)"

log() { printf '\n== container smoke: %s\n' "$*"; }
fail() { echo "container smoke test FAILED: $*" >&2; docker logs "$name" 2>&1 | tail -30 >&2 || true; exit 1; }

cleanup() {
    docker rm -f "$name" >/dev/null 2>&1 || true
    docker volume rm -f "$volume" >/dev/null 2>&1 || true
    docker image rm -f "$tag" >/dev/null 2>&1 || true
    rm -rf "$work"
}
trap cleanup EXIT

log "docker/up.sh refuses the example's placeholder token before starting anything"
mkdir -p "$work/up"
cp -r docker "$work/up/docker"
cp docker/semdepth.env.example "$work/up/docker/semdepth.env"
if out=$("$work/up/docker/up.sh" 2>&1); then
    fail "docker/up.sh went ahead with the placeholder token: $out"
fi
grep -q "placeholder" <<<"$out" || fail "docker/up.sh refused the placeholder token without naming it: $out"
echo "$out"

log "docker"
# The daemon, not only a client: a machine may ship a docker CLI alone.
if ! command -v docker >/dev/null 2>&1 || { ! docker info >/dev/null 2>&1 && ! command -v dockerd >/dev/null 2>&1; }; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq docker.io >/dev/null
fi
if ! docker info >/dev/null 2>&1; then
    # A daemon that died (the machine restarted) leaves its containerd's pid
    # file behind; once another process has that pid, a new dockerd takes
    # containerd for running, waits on it and gives up ("containerd is still
    # running ... timeout waiting for containerd to start").
    for pidfile in /var/run/docker/containerd/containerd.pid /var/run/docker.pid; do
        name=$(basename "$pidfile" .pid)
        if [ -f "$pidfile" ] && [ "$(ps -p "$(cat "$pidfile")" -o comm= 2>/dev/null)" != "$name" ]; then
            echo "removing the stale $pidfile (no $name has its pid)"
            rm -f "$pidfile"
        fi
    done
    # No bridge: containers use the host network and talk over loopback.
    (dockerd --bridge=none --iptables=false >/tmp/semdepth-dockerd.log 2>&1 &)
    for _ in $(seq 1 60); do docker info >/dev/null 2>&1 && break; sleep 1; done
    docker info >/dev/null 2>&1 || { cat /tmp/semdepth-dockerd.log >&2; fail "dockerd did not start"; }
fi

log "image"
docker/build.sh "$tag"
size=$(docker image inspect "$tag" --format '{{.Size}}')
echo "image size: $size bytes ($((size / 1024 / 1024)) MiB)"
[ "$size" -lt $((20 * 1024 * 1024)) ] || fail "image is $size bytes (target under 20 MiB)"

start() {
    docker run -d --name "$name" --network host \
        -v "$volume:/data" --read-only --tmpfs /tmp \
        -e SEMDEPTH_LISTEN="127.0.0.1:$port" -e SEMDEPTH_TOKEN="$token" \
        "$tag" >/dev/null
}
wait_healthy() {
    for _ in $(seq 1 60); do
        state=$(docker inspect -f '{{.State.Health.Status}}' "$name")
        [ "$state" = healthy ] && return 0
        [ "$(docker inspect -f '{{.State.Running}}' "$name")" = true ] || fail "container exited"
        sleep 1
    done
    fail "health status is '$state' after 60 s (expected healthy)"
}
api() { # METHOD PATH [curl args...]: prints the body, fails on non-2xx
    local method=$1 path=$2; shift 2
    curl -sS --fail-with-body -X "$method" -H "Authorization: Bearer $token" "$@" "$base$path"
}
field() { python3 -c "import json,sys; print(json.load(sys.stdin)$1)"; }

log "first container"
start
wait_healthy
echo "health: healthy"
pid=$(docker inspect -f '{{.State.Pid}}' "$name")
uid=$(awk '/^Uid:/ {print $2}' "/proc/$pid/status")
echo "server process $pid runs as uid $uid"
[ "$uid" != 0 ] || fail "the server runs as root"
code=$(curl -s -o /dev/null -w '%{http_code}' "$base/v1/sessions")
[ "$code" = 401 ] || fail "a request without the token got $code (expected 401)"

cal=$(api POST /v1/calibrations -H 'Content-Type: application/json' \
    -d '{"name": "smoke", "model": "fit", "samples": [{"disparity_px": 3, "z_um": 0}, {"disparity_px": 4, "z_um": 100}]}' | field "['id']")
session=$(api POST /v1/sessions -H 'Content-Type: application/json' \
    -d "{\"name\": \"smoke\", \"calibration_id\": \"$cal\"}" | field "['id']")
echo "calibration $cal, session $session"

bin="${SEMDEPTH_BIN:-target/release/semdepth}"
[ -x "$bin" ] || { cargo build --release --locked --bin semdepth; bin=target/release/semdepth; }
"$bin" synth "$work/seq" --preset clean --shape blob --seed 3 --frames 2 >/dev/null
result=$(api POST "/v1/sessions/$session/frames" -F "left=@$work/seq/0000_left.png" -F "right=@$work/seq/0000_right.png")
status=$(echo "$result" | field "['status']")
z=$(echo "$result" | field "['z_um']")
echo "first pair: $status, z = $z um"
[ "$status" = initialised ] || fail "first pair status $status"

log "replace the container, same volume"
docker stop -t 30 "$name" >/dev/null
docker rm "$name" >/dev/null
start
wait_healthy
api GET "/v1/calibrations/$cal" | field "['name']" | grep -qx smoke || fail "calibration lost"
frames=$(api GET "/v1/sessions/$session" | field "['frames']")
[ "$frames" = 1 ] || fail "session has $frames frames after the restart (expected 1)"
n=$(api GET "/v1/sessions/$session/results" | field "['results'].__len__()")
[ "$n" = 1 ] || fail "$n results after the restart (expected 1)"
result=$(api POST "/v1/sessions/$session/frames" -F "left=@$work/seq/0001_left.png" -F "right=@$work/seq/0001_right.png")
status=$(echo "$result" | field "['status']")
[ "$status" = tracked ] || fail "second pair after the restart: $status (expected tracked)"
echo "calibration and session survived; the session continued tracking"

log "passed"
