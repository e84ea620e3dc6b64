#!/usr/bin/env bash
# Starts semdepth with docker/compose.yaml, after checking what would
# otherwise only show in `docker logs` of a container that restarts in a
# loop: docker/semdepth.env with a real token, the Docker daemon, a compose
# tool, the image. Then waits until the container reports healthy, and
# prints its last log lines if it does not.
#
#   docker/up.sh            (after docker/build.sh)
set -euo pipefail
cd "$(dirname "$0")/.."

env_file=docker/semdepth.env
placeholder=change-me-to-a-long-random-string
die() {
    echo "docker/up.sh: $*" >&2
    exit 1
}

[ -f "$env_file" ] || die "$env_file is missing: cp docker/semdepth.env.example $env_file, then set SEMDEPTH_TOKEN in it"
token=$(sed -n 's/^SEMDEPTH_TOKEN=//p' "$env_file" | tail -n 1)
suggest="python3 -c 'import secrets; print(secrets.token_urlsafe(32))'"
[ -n "$token" ] || die "$env_file sets no SEMDEPTH_TOKEN (expected SEMDEPTH_TOKEN=<a long random string>, e.g. from $suggest)"
[ "$token" != "$placeholder" ] || die "SEMDEPTH_TOKEN in $env_file is still the example's placeholder; the server refuses it (set a long random one, e.g. from $suggest)"

docker info >/dev/null 2>&1 || die "the Docker daemon is not running or not installed (Debian/Ubuntu: sudo apt-get install docker.io docker-compose, then sudo systemctl start docker)"
if docker compose version >/dev/null 2>&1; then
    compose=(docker compose -f docker/compose.yaml)
elif command -v docker-compose >/dev/null 2>&1; then
    compose=(docker-compose -f docker/compose.yaml)
else
    die "no compose tool: install Docker's docker-compose-plugin or Debian's docker-compose (or run the container with the plain docker run of README.md)"
fi
docker image inspect semdepth:latest >/dev/null 2>&1 || die "no image semdepth:latest: build it with docker/build.sh"

"${compose[@]}" up -d
container=$("${compose[@]}" ps -q semdepth)
[ -n "$container" ] || die "compose started no semdepth container"
for _ in $(seq 60); do
    health=$(docker inspect -f '{{if .State.Health}}{{.State.Health.Status}}{{end}}' "$container")
    restarts=$(docker inspect -f '{{.RestartCount}}' "$container")
    if [ "$health" = healthy ]; then
        echo "semdepth is up and healthy on http://127.0.0.1:8080 (bearer token: SEMDEPTH_TOKEN of $env_file)"
        exit 0
    fi
    if [ "$health" = unhealthy ] || [ "$restarts" -gt 0 ]; then
        break
    fi
    sleep 1
done
echo "docker/up.sh: semdepth did not become healthy (health: ${health:-none}, restarts: $restarts); its last log lines:" >&2
docker logs --tail 30 "$container" >&2
exit 1
