#!/usr/bin/env bash
# Property-based API test: runs schemathesis (PyPI, 4.x) against the committed
# OpenAPI document (openapi/openapi.yaml) and a real `semdepth serve`, and
# fails when any response is a server error or does not match the spec
# (status code, content type, headers, body schema).
#
# Usage: tools/schemathesis_run.sh
#
# Environment (all optional):
#   SEMDEPTH_BIN                 server binary (default: target/debug/semdepth,
#                                built with `cargo build --locked`: after
#                                `cargo test` that is a quick build, and the
#                                dev profile keeps overflow checks on)
#   SCHEMATHESIS_MAX_EXAMPLES    test cases per operation and phase (default 200)
#   SCHEMATHESIS_SEED            random seed (default: 1 under CI=true so CI
#                                runs are reproducible, else a random one)
#   SCHEMATHESIS_WORKERS         concurrent schemathesis workers (default 2)
#   SCHEMATHESIS_PHASES          phases (default examples,coverage,fuzzing,stateful)
#   SCHEMATHESIS_EXTRA_ARGS      further arguments for `schemathesis run`
#   SCHEMATHESIS_REPORT_DIR      keep the JUnit report there (default: none)
#
# Authentication: the server is started without --token, so /v1 needs no
# token. The spec declares the bearer scheme as optional ("either the token or
# nothing"), which is what such a server accepts; a bearer header that
# schemathesis may generate is ignored by a server without a token.
#
# Excluded: GET /v1/sessions/{id}/stream is the WebSocket upgrade. Plain HTTP
# requests (which is all schemathesis sends) can only get its error answers
# (400 "websocket_upgrade_required", 404), never the documented 101, and the
# pair messages are binary WebSocket frames that an OpenAPI document cannot
# describe; tests/app/ws.rs covers this route. GET
# /v1/sessions/{id}/events is an endless server-sent event stream: a client
# that reads the whole body (as schemathesis does) waits until its timeout;
# tests/app/live.rs covers it.
set -euo pipefail
if [ -n "${SEMDEPTH_BIN:-}" ] && [[ $SEMDEPTH_BIN != /* ]]; then
    SEMDEPTH_BIN=$PWD/$SEMDEPTH_BIN
fi
cd "$(dirname "$0")/.."
root=$(pwd)

max_examples=${SCHEMATHESIS_MAX_EXAMPLES:-200}
workers=${SCHEMATHESIS_WORKERS:-2}
phases=${SCHEMATHESIS_PHASES:-examples,coverage,fuzzing,stateful}
if [ -n "${SCHEMATHESIS_SEED:-}" ]; then
    seed=$SCHEMATHESIS_SEED
elif [ "${CI:-}" = "true" ]; then
    seed=1
else
    seed=$(( (RANDOM << 15) | RANDOM ))
fi

log() { printf '\n== %s\n' "$*"; }

# -- schemathesis ------------------------------------------------------------
if ! command -v schemathesis >/dev/null 2>&1 \
    || ! schemathesis --version 2>/dev/null | grep -Eq 'version 4\.'; then
    log "installing schemathesis 4.x from PyPI"
    python3 -m pip install --quiet --disable-pip-version-check 'schemathesis>=4,<5'
    hash -r
fi
if command -v schemathesis >/dev/null 2>&1 \
    && schemathesis --version 2>/dev/null | grep -Eq 'version 4\.'; then
    st=(schemathesis)
else
    # Installed where PATH does not look (a user site, another pyenv shim).
    st=(python3 -m schemathesis.cli)
fi
"${st[@]}" --version

# -- the server --------------------------------------------------------------
if [ -n "${SEMDEPTH_BIN:-}" ]; then
    bin=$SEMDEPTH_BIN
else
    log "cargo build --locked"
    cargo build --locked
    bin=$root/target/debug/semdepth
fi
if [ ! -x "$bin" ]; then
    echo "semdepth binary not found or not executable: $bin" >&2
    exit 1
fi

work=$(mktemp -d)
server_pid=
server_log=$work/server.log
stop_server() {
    if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
        kill -TERM "$server_pid" 2>/dev/null || true
        for _ in $(seq 50); do
            kill -0 "$server_pid" 2>/dev/null || break
            sleep 0.1
        done
        kill -KILL "$server_pid" 2>/dev/null || true
        wait "$server_pid" 2>/dev/null || true
    fi
    server_pid=
}
cleanup() {
    stop_server
    rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

print_server_log() {
    log "server log (last 200 lines of $server_log)"
    tail -n 200 "$server_log" || true
}

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1]); s.close()')
base=http://127.0.0.1:$port
log "starting $bin serve on $base"
# Many sessions: schemathesis creates one per POST /v1/sessions test case.
"$bin" serve --listen "127.0.0.1:$port" --db "$work/db.sqlite3" \
    --max-sessions 100000 --request-timeout-s 30 >"$server_log" 2>&1 &
server_pid=$!

ready=
for _ in $(seq 300); do
    if ! kill -0 "$server_pid" 2>/dev/null; then
        echo "the server exited before it was ready" >&2
        print_server_log
        exit 1
    fi
    if curl -fsS -o /dev/null "$base/readyz" 2>/dev/null; then
        ready=1
        break
    fi
    sleep 0.1
done
if [ -z "$ready" ]; then
    echo "the server did not answer /readyz within 30 s" >&2
    print_server_log
    exit 1
fi

# -- real data for the unit phases ------------------------------------------
# schemathesis cannot invent images the tracker accepts, nor the ids of
# sessions and calibrations that exist: tools/schemathesis_hooks.py offers
# small synthetic pairs (written here with `semdepth synth`) and creates
# fixture sessions and calibrations on the server under test.
"$bin" synth --shape blob --frames 3 --width 96 --height 80 "$work/pairs/a" >/dev/null
"$bin" synth --shape rod --preset cluttered --seed 5 --frames 1 --width 96 --height 80 "$work/pairs/c" >/dev/null
"$bin" synth --shape tip --preset noisy --seed 3 --frames 1 --width 72 --height 64 "$work/pairs/b" >/dev/null

# -- the run -----------------------------------------------------------------
# Checks: no 5xx; every status, content type, header and body as documented;
# schema-violating requests rejected with a 4xx (negative_data_rejection);
# undeclared methods answered 405 with an Allow header; deleted resources
# gone and created ones available (stateful).
# Not run:
# - positive_data_acceptance (schema-valid requests must succeed): the
#   server rightly refuses some schema-valid requests for reasons a JSON
#   Schema cannot state: random bytes are no image, a fit needs degree + 1
#   *distinct* disparities, low_threshold <= high_threshold, an unknown
#   calibration id is a 404. Those answers are documented 4xx statuses,
#   which status_code_conformance checks.
# - ignored_auth: the server runs without a token here (see above).
# - object_level_authorization: the API has no users.
checks=not_a_server_error,status_code_conformance,content_type_conformance
checks+=,response_headers_conformance,response_schema_conformance
checks+=,negative_data_rejection,missing_required_header,unsupported_method
checks+=,allow_header_conformance,use_after_free,ensure_resource_availability
report_args=()
if [ -n "${SCHEMATHESIS_REPORT_DIR:-}" ]; then
    mkdir -p "$SCHEMATHESIS_REPORT_DIR"
    report_args=(--report junit --report-dir "$SCHEMATHESIS_REPORT_DIR")
fi
# shellcheck disable=SC2206  # word splitting of the extra arguments is intended
extra=(${SCHEMATHESIS_EXTRA_ARGS:-})

log "schemathesis run (seed $seed, $max_examples examples per operation, phases $phases)"
start=$(date +%s)
set +e
# Run from the work directory so nothing (caches, reports) lands in the tree.
(
    cd "$work"
    # Fuzzing: no values captured from responses (the ids of fixtures would
    # change the strategies hypothesis replays). Stateful: the document's
    # own links only (links inferred from field names tie a session's name
    # to an object's), and scenarios long enough to go from a session to its
    # objects, pairs and samples.
    cat >schemathesis.toml <<'TOML'
[phases.fuzzing.extra-data-sources]
responses = false
[phases.stateful]
max-steps = 40
[phases.stateful.inference]
algorithms = []
TOML
    export SCHEMATHESIS_HOOKS=$root/tools/schemathesis_hooks.py SEMDEPTH_ST_PAIRS=$work/pairs SEMDEPTH_ST_BASE=$base
    "${st[@]}" run "$root/openapi/openapi.yaml" \
        --url "$base" \
        --checks "$checks" \
        --exclude-path '/v1/sessions/{id}/stream' \
        --exclude-path '/v1/sessions/{id}/events' \
        --phases "$phases" \
        --max-examples "$max_examples" \
        --seed "$seed" \
        --workers "$workers" \
        --request-timeout 60 \
        --generation-database none \
        --no-color \
        "${report_args[@]}" "${extra[@]}"
)
status=$?
set -e
echo "schemathesis finished in $(( $(date +%s) - start )) s with exit code $status"

if ! kill -0 "$server_pid" 2>/dev/null; then
    echo "the server died during the run" >&2
    status=1
fi
# A panic on a task whose answer schemathesis never sees must fail too.
if grep -q 'panicked' "$server_log"; then
    echo "the server panicked during the run" >&2
    status=1
fi
if [ "$status" -ne 0 ]; then
    print_server_log
fi
exit "$status"
