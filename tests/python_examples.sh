#!/usr/bin/env bash
# Runs the Python examples (examples/python/) against a real semdepth server
# and checks what they print. Called by .ci/run; runs alone too:
#
#     bash tests/python_examples.sh
#
# Steps: build the release binary (cargo does nothing when it is fresh; set
# SEMDEPTH_BIN to use another binary and skip the build), install the
# `websockets` package if it is missing, write a synthetic clean blob sequence
# of 6 pairs with its truth (`semdepth synth`), start `semdepth serve` with a
# token on a free loopback port, create a fitted calibration from the
# generator's disparity geometry (truth.json: disparity = offset_px +
# px_per_um * z), then run upload_folder.py (REST) and stream_folder.py
# (WebSocket, policy all and latest) and check their output:
#   - one line per pair, frame 0 `initialised` and the others `tracked`, each
#     with a numeric disparity_axis_px and z_um;
#   - measured disparity vs truth.json disparity_px[0], after removing the
#     constant offset: RMS <= 0.2 px (DISPARITY_RMS_PX);
#   - z_um vs the true z: RMS <= the z of 0.3 px of disparity (Z_RMS_PX), and
#     z_um is the calibration applied to the printed disparity;
#   - the results CSV has one row per pair with the same z_um;
#   - policy latest answers every seq once and measures the last pair;
#   - a wrong token makes both scripts exit 1 with the server's message;
#   - the client's other calls, among them reinit() with a box around the
#     object (answered 200, the next pair `initialised` on it as frame 6) and
#     depth() with hints.
# Exits non-zero if anything is off; ends with "python examples: N passed, M failed".
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
EXAMPLES=$REPO/examples/python

PYTHON=${PYTHON:-python3}
export PYTHONDONTWRITEBYTECODE=1  # leave no __pycache__ in examples/python
command -v "$PYTHON" >/dev/null || { echo "python3 not found: the Python examples need Python 3.9+" >&2; exit 1; }
"$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 9))' || { echo "Python 3.9+ needed" >&2; exit 1; }

if ! "$PYTHON" -c 'import websockets' >/dev/null 2>&1; then
    echo "installing websockets (PyPI)"
    "$PYTHON" -m pip install --quiet 'websockets>=12'
fi

if [ -n "${SEMDEPTH_BIN:-}" ]; then
    BIN=$SEMDEPTH_BIN
else
    cargo build --release --locked --quiet --bin semdepth
    BIN=$REPO/target/release/semdepth
fi
[ -x "$BIN" ] || { echo "no semdepth binary at $BIN" >&2; exit 1; }

TMP=$(mktemp -d)
SERVER_PID=
cleanup() {
    if [ -n "$SERVER_PID" ]; then
        kill "$SERVER_PID" 2>/dev/null || true
        wait "$SERVER_PID" 2>/dev/null || true
    fi
    rm -rf "$TMP"
}
trap cleanup EXIT

started=$(date +%s)
"$BIN" synth "$TMP/pairs" --preset clean --shape blob --seed 5 --frames 6 >"$TMP/synth.out"

PORT=$("$PYTHON" -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1]); s.close()')
SERVER=http://127.0.0.1:$PORT
TOKEN=python-examples-token
"$BIN" serve --listen "127.0.0.1:$PORT" --db "$TMP/db.sqlite3" --token "$TOKEN" >"$TMP/server.log" 2>&1 &
SERVER_PID=$!

# Wait for /readyz (at most 20 s), then create the calibration.
CAL_ID=$(cd "$EXAMPLES" && "$PYTHON" - "$SERVER" "$TOKEN" "$TMP/pairs/truth.json" <<'EOF'
import json, sys, time
from semdepth_client import SemdepthClient, SemdepthError
server, token, truth_path = sys.argv[1:]
api = SemdepthClient(server, token=token, timeout=5)
deadline = time.monotonic() + 20
while True:
    try:
        api.readyz()
        break
    except SemdepthError as e:
        if time.monotonic() > deadline:
            sys.exit(f"server not ready after 20 s: {e}")
        time.sleep(0.1)
d = json.load(open(truth_path))["config"]["disparity"]
at = lambda z: d["offset_px"] + d["px_per_um"] * z
cal = api.create_calibration(name="synth stage steps", model="fit", degree=1,
                             samples=[{"disparity_px": at(0.0), "z_um": 0.0},
                                      {"disparity_px": at(100.0), "z_um": 100.0}])
print(cal["id"])
EOF
) || { echo "server start or calibration failed; server log:" >&2; tail -20 "$TMP/server.log" >&2; exit 1; }

run() { # NAME COMMAND...: runs a script, keeps stdout, stderr and exit code
    local name=$1; shift
    set +e
    (cd "$TMP" && "$@") >"$TMP/$name.out" 2>"$TMP/$name.err"
    echo $? >"$TMP/$name.rc"
    set -e
}
run upload "$PYTHON" "$EXAMPLES/upload_folder.py" "$TMP/pairs" --server "$SERVER" --token "$TOKEN" \
    --calibration-id "$CAL_ID" --csv "$TMP/results.csv"
run stream "$PYTHON" "$EXAMPLES/stream_folder.py" "$TMP/pairs" --server "$SERVER" --token "$TOKEN" \
    --calibration-id "$CAL_ID" --policy all
run latest "$PYTHON" "$EXAMPLES/stream_folder.py" "$TMP/pairs" --server "$SERVER" --token "$TOKEN" \
    --calibration-id "$CAL_ID" --policy latest
STREAM_SID=$(sed -n 's/^session \([^ ]*\) .*/\1/p' "$TMP/stream.out")
run ws_badtoken "$PYTHON" "$EXAMPLES/stream_folder.py" "$TMP/pairs" --server "$SERVER" --token wrong \
    --session-id "${STREAM_SID:-none}"
run upload_badtoken "$PYTHON" "$EXAMPLES/upload_folder.py" "$TMP/pairs" --server "$SERVER" --token wrong
# The token from the environment instead of the command line (issue #22).
run upload_envtoken env SEMDEPTH_TOKEN="$TOKEN" "$PYTHON" "$EXAMPLES/upload_folder.py" "$TMP/pairs" --server "$SERVER" \
    --calibration-id "$CAL_ID"
run stream_badtoken "$PYTHON" "$EXAMPLES/stream_folder.py" "$TMP/pairs" --server "$SERVER" --token wrong

for name in upload stream; do
    echo "--- $name output"
    cat "$TMP/$name.out"
done

set +e
"$PYTHON" - "$TMP" "$EXAMPLES" "$SERVER" "$TOKEN" "$CAL_ID" <<'EOF'
import asyncio, csv, json, math, sys
from pathlib import Path

DISPARITY_RMS_PX = 0.2  # measured vs true disparity, constant offset removed
Z_RMS_PX = 0.3          # z error allowed, as the z of this much disparity

tmp = Path(sys.argv[1])
examples, server, token, cal_id = sys.argv[2:6]
sys.path.insert(0, examples)
from semdepth_client import SemdepthClient, SemdepthError, encode_pair, reinit_message, stream_pairs  # noqa: E402
truth = json.loads((tmp / "pairs" / "truth.json").read_text())
geometry = truth["config"]["disparity"]
frames = truth["frames"]
um_per_px = 1.0 / geometry["px_per_um"]
passed, failed = [], []


def check(ok, what):
    (passed if ok else failed).append(what)
    print(("ok    " if ok else "FAIL  ") + what)


def out(name):
    return (tmp / f"{name}.out").read_text(), (tmp / f"{name}.err").read_text(), int((tmp / f"{name}.rc").read_text())


def number(text):
    try:
        value = float(text)
        return value if math.isfinite(value) else None
    except ValueError:
        return None


def rows(text, first_col):
    """Per-pair lines: (pair, frame, status, disparity, z) from the table."""
    found = []
    for line in text.splitlines():
        cols = line.split()
        if (len(cols) < first_col + 5 or not cols[first_col + 1].isdigit()
                or cols[first_col + 2] not in ("initialised", "tracked", "lost")):
            continue
        pair, frame, status, disparity, z = cols[first_col:first_col + 5]
        found.append((pair, int(frame), status, number(disparity), number(z)))
    return found


def check_measurements(label, table):
    check(len(table) == len(frames), f"{label}: {len(table)} result lines for {len(frames)} pairs")
    if len(table) != len(frames):
        return
    check([r[0] for r in table] == [f"{i:04d}" for i in range(len(frames))], f"{label}: pairs in name order")
    check([r[1] for r in table] == list(range(len(frames))), f"{label}: frames 0..{len(frames) - 1}")
    statuses = [r[2] for r in table]
    check(statuses == ["initialised"] + ["tracked"] * (len(frames) - 1),
          f"{label}: statuses initialised then tracked ({', '.join(statuses)})")
    numeric = all(r[3] is not None and r[4] is not None for r in table)
    check(numeric, f"{label}: every pair has a numeric disparity_axis_px and z_um")
    if not numeric:
        return
    diffs = [r[3] - f["disparity_px"][0] for r, f in zip(table, frames)]
    offset = sum(diffs) / len(diffs)
    rms = math.sqrt(sum((x - offset) ** 2 for x in diffs) / len(diffs))
    check(rms <= DISPARITY_RMS_PX,
          f"{label}: disparity RMS {rms:.3f} px after removing offset {offset:+.3f} px (limit {DISPARITY_RMS_PX} px)")
    z_err = [r[4] - f["z_um"] for r, f in zip(table, frames)]
    z_rms = math.sqrt(sum(e * e for e in z_err) / len(z_err))
    check(z_rms <= Z_RMS_PX * um_per_px,
          f"{label}: z RMS error {z_rms:.2f} um (limit {Z_RMS_PX * um_per_px:.1f} um = {Z_RMS_PX} px; 1 px = {um_per_px:.1f} um)")
    # The calibration maps the printed (3-decimal) disparity to the printed z.
    mapped = [(r[3] - geometry["offset_px"]) * um_per_px for r in table]
    worst = max(abs(m - r[4]) for m, r in zip(mapped, table))
    check(worst <= 0.0006 * um_per_px + 0.01, f"{label}: z_um is the calibration of disparity_axis_px (worst {worst:.3f} um)")
    return table


stdout, stderr, rc = out("upload")
check(rc == 0, f"upload_folder.py exits 0 (got {rc}{': ' + stderr.strip() if rc else ''})")
upload = check_measurements("upload_folder.py", rows(stdout, 0))
check("results CSV: " in stdout, "upload_folder.py names the results CSV")
csv_path = tmp / "results.csv"
if csv_path.exists() and upload:
    records = list(csv.DictReader(csv_path.open()))
    same = len(records) == len(frames) and all(
        abs(float(rec["z_um"]) - r[4]) < 0.006 for rec, r in zip(records, upload))
    check(same, f"results CSV: {len(records)} rows with the printed z_um")
else:
    check(False, "results CSV written")

stdout, stderr, rc = out("stream")
check(rc == 0, f"stream_folder.py --policy all exits 0 (got {rc}{': ' + stderr.strip() if rc else ''})")
check_measurements("stream_folder.py", rows(stdout, 1))

stdout, stderr, rc = out("latest")
check(rc == 0, f"stream_folder.py --policy latest exits 0 (got {rc}{': ' + stderr.strip() if rc else ''})")
seqs = {}
for line in stdout.splitlines():
    cols = line.split()
    if len(cols) >= 4 and cols[0].isdigit() and cols[1].isdigit():
        seqs[int(cols[0])] = "error" if cols[2] == "error:" else cols[3]
last = seqs.get(len(frames) - 1)
check(sorted(seqs) == list(range(len(frames))) and last in ("initialised", "tracked"),
      f"policy latest: every seq answered once, the last one measured ({sum(s == 'skipped' for s in seqs.values())} skipped)")

stdout, stderr, rc = out("upload_envtoken")
check(rc == 0 and len(rows(stdout, 0)) == len(frames),
      f"upload_folder.py with the token in SEMDEPTH_TOKEN: exit {rc}, {len(rows(stdout, 0))} rows"
      f"{': ' + stderr.strip() if rc else ''}")

for name, label in (("upload_badtoken", "upload_folder.py"), ("stream_badtoken", "stream_folder.py"),
                    ("ws_badtoken", "stream_folder.py --session-id (WebSocket upgrade)")):
    stdout, stderr, rc = out(name)
    # websockets 12 does not expose the refused upgrade's body: status only there.
    clean = "401 unauthorized" in stderr and "bearer token" in stderr or name == "ws_badtoken" and "401" in stderr
    check(rc == 1 and clean and "Traceback" not in stderr,
          f"{label} with a wrong token: exit {rc}, {stderr.strip().splitlines()[-1] if stderr.strip() else 'no message'}")

# The client module's other calls, straight.
api = SemdepthClient(server, token=token)
pairs = tmp / "pairs"
upload_sid = next(line.split()[1] for line in out("upload")[0].splitlines() if line.startswith("session "))
try:
    check(any(c["id"] == cal_id for c in api.list_calibrations()), "client: list_calibrations has the calibration")
    one = api.depth(pairs / "0000_left.png", (pairs / "0000_right.png").read_bytes(), calibration_id=cal_id)
    check(one["status"] == "initialised" and upload and abs(one["z_um"] - upload[0][4]) < 0.01,
          f"client: depth() one-shot z_um {one['z_um']:.2f} as the session's first pair")
    page = api.results(upload_sid, since=2)
    check([r["frame"] for r in page["results"]] == [2, 3, 4, 5] and len(api.all_results(upload_sid)) == 6,
          "client: results(since=2) and all_results()")
    at = lambda z: geometry["offset_px"] + geometry["px_per_um"] * z  # noqa: E731
    fit = api.create_calibration(name="steps", model="fit", degree=1,
                                 samples=[{"disparity_px": at(0.0), "z_um": 0.0}, {"disparity_px": at(50.0), "z_um": 50.0}])
    fit = api.add_session_calibration_sample(upload_sid, fit["id"], frames[-1]["z_um"])
    check(len(fit["samples"]) == 3 and abs(fit["samples"][-1]["disparity_px"] - upload[-1][3]) < 0.001,
          f"client: add_session_calibration_sample paired disparity {fit['samples'][-1]['disparity_px']:.3f} px with z")
    # New hints: a box around the object of pair 0000 (its true outline, 40 px
    # margin); the next pair initialises on it and the frames count on.
    outline = frames[0]["left"]["polygon"]
    xs, ys = [p[0] for p in outline], [p[1] for p in outline]
    roi = [int(min(xs)) - 40, int(min(ys)) - 40, int(max(xs) - min(xs)) + 80, int(max(ys) - min(ys)) + 80]
    session = api.reinit(upload_sid, roi=roi, polarity="any")
    check(session["state"] == "awaiting_first_pair" and session["init"]["roi"] == roi and session["frames"] == 6,
          f"client: reinit(roi={roi}) answers the session awaiting its next first pair")
    again = api.upload_pair(upload_sid, pairs / "0000_left.png", pairs / "0000_right.png")
    cx, cy = frames[0]["left"]["centroid"]
    off = math.hypot(again["left"]["centroid"][0] - cx, again["left"]["centroid"][1] - cy)
    check(again["frame"] == 6 and again["status"] == "initialised" and off < 1.5,
          f"client: after reinit() frame {again['frame']} is {again['status']}, {off:.2f} px from the true centroid")
    hinted = api.depth(pairs / "0000_left.png", pairs / "0000_right.png", roi=roi, point=[cx, cy], polarity="brighter")
    off = math.hypot(hinted["left"]["centroid"][0] - cx, hinted["left"]["centroid"][1] - cy)
    check(hinted["status"] == "initialised" and off < 1.5, f"client: depth() with hints, {off:.2f} px from the true centroid")
    # A lasso: the true outline at 16 vertices, 4 px outside it.
    step = max(1, len(outline) // 16)
    lasso = [[x + 4 * (x - cx) / max(1e-9, math.hypot(x - cx, y - cy)), y + 4 * (y - cy) / max(1e-9, math.hypot(x - cx, y - cy))]
             for x, y in outline[::step]]
    session = api.reinit(upload_sid, outline=lasso)
    check(session["init"]["outline"] is not None and len(session["init"]["outline"]) == len(lasso) and session["init"]["roi"] is None,
          f"client: reinit(outline=...) sets a lasso of {len(lasso)} vertices and clears the box")
    again = api.upload_pair(upload_sid, pairs / "0000_left.png", pairs / "0000_right.png")
    off = math.hypot(again["left"]["centroid"][0] - cx, again["left"]["centroid"][1] - cy)
    check(again["status"] == "initialised" and off < 1.5, f"client: after reinit(outline=...) {again['status']}, {off:.2f} px from the true centroid")
    lassoed = api.depth(pairs / "0000_left.png", pairs / "0000_right.png", outline=lasso)
    off = math.hypot(lassoed["left"]["centroid"][0] - cx, lassoed["left"]["centroid"][1] - cy)
    check(lassoed["status"] == "initialised" and off < 1.5, f"client: depth(outline=...), {off:.2f} px from the true centroid")
    check(api.reset(upload_sid)["state"] == "awaiting_first_pair", "client: reset()")
    api.delete_session(upload_sid)
    try:
        api.get_session(upload_sid)
        check(False, "client: a deleted session is gone")
    except SemdepthError as e:
        check(e.status == 404 and e.code and e.message, f"client: deleted session gives SemdepthError {e.status} {e.code}")
    try:
        api.create_session(nmae="typo")
        check(False, "client: unknown field refused")
    except SemdepthError as e:
        check(e.status == 400 and "nmae" in e.message, f"client: unknown field gives SemdepthError {e.status} {e.code}")

    # Raw encoding: a synthetic disc shifted by 5.5 px between left and right.
    def disc(cx, w=200, h=160):
        return bytes(int(60 + 120 / (1 + math.exp(min(50.0, math.hypot(x - cx, y - 80) - 35)))) for y in range(h) for x in range(w))

    async def raw_stream():
        sid = api.create_session(name="raw")["id"]
        left, right = disc(90.0), disc(95.5)
        msgs = [encode_pair(i, left, right, encoding="raw", width=200, height=160, bit_depth=8) for i in range(2)]
        # New hints among the pairs: a square round the disc, 5 px outside it.
        msgs.append(reinit_message(outline=[[50, 40], [130, 40], [130, 120], [50, 120]]))
        msgs.append(encode_pair(2, left, right, encoding="raw", width=200, height=160, bit_depth=8))
        return [r async for r in stream_pairs(server, sid, msgs, token=token)]

    replies = asyncio.run(raw_stream())
    measured = [r for r in replies if "reinit" not in r]
    check(len(measured) == 3 and all(abs(r.get("disparity_axis_px", 0) - 5.5) < 0.1 for r in measured),
          f"client: raw SDP1 pairs measure {[r.get('disparity_axis_px') for r in measured]} px for a 5.5 px shift")
    # The next pair tracked after the hints arrive initialises: pair 1 if it
    # was still waiting, else pair 2.
    reinit_reply = [r for r in replies if "reinit" in r]
    check(len(replies) == 4 and len(reinit_reply) == 1 and reinit_reply[0]["seq"] is None
          and len(reinit_reply[0]["reinit"]["init"]["outline"]) == 4
          and [r["status"] for r in measured[1:]].count("initialised") == 1,
          f"client: reinit_message() among streamed pairs names the object anew ({[r.get('status', 'reinit') for r in replies]})")
except (SemdepthError, KeyError, TypeError) as e:
    check(False, f"client calls: {type(e).__name__}: {e}")

print(f"python examples: {len(passed)} passed, {len(failed)} failed")
sys.exit(1 if failed else 0)
EOF
status=$?
echo "python examples took $(( $(date +%s) - started )) s"
exit $status
