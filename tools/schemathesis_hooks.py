"""schemathesis hooks of tools/schemathesis_run.sh: real data for the unit phases.

The stateful phase follows the OpenAPI links from the operations that create
sessions, objects and calibrations to those that take their ids. The unit
phases (examples, coverage, fuzzing) generate every operation on its own: a
random session id only ever reaches the 404 branch, random bytes are never an
image. So that those phases reach each operation's logic too, these hooks

- offer real stereo pairs (`semdepth synth`, written by the run script) in
  place of the generated multipart body of positive upload cases (besides
  it, for the documented examples);
- give positive cases real ids: three of every four cases that name a
  session or a calibration (path or body) name one created here, the fourth
  keeps its generated id for the 404 branch. Every operation but a GET gets a
  fresh fixture, so that no case changes what a later one finds;
- check that a PNG response is a PNG of the size its headers state.

Negative cases are never touched: they must stay invalid in whatever
component made them so.
"""

import copy
import itertools
import json
import os
import pathlib
import struct
import urllib.error
import urllib.request
import uuid
import zlib
from collections import defaultdict

import schemathesis
from hypothesis import strategies as st

_DIR = pathlib.Path(os.environ["SEMDEPTH_ST_PAIRS"])
_BASE = os.environ["SEMDEPTH_ST_BASE"]


def _pair(left, right):
    return {"left": (_DIR / left).read_bytes(), "right": (_DIR / right).read_bytes()}


def _flat_png(width, height, grey):
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + bytes([grey]) * width for _ in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


FLAT = _flat_png(96, 80, 128)
# A 3-pair sequence (initialised, tracked), another object of the same size
# and a featureless pair (lost, re-initialised), a pair of another size (400
# pair_size_changed inside a session) and a pair of mismatched sizes (400).
PAIRS = [_pair(f"a/{i:04}_left.png", f"a/{i:04}_right.png") for i in range(3)] + [
    _pair("c/0000_left.png", "c/0000_right.png"),
    {"left": FLAT, "right": FLAT},
    _pair("b/0000_left.png", "b/0000_right.png"),
    _pair("a/0000_left.png", "b/0000_right.png"),
]
UPLOADS = {("POST", "/v1/sessions/{id}/frames"), ("POST", "/v1/depth")}


# -- talking to the server under test ----------------------------------------
def _call(method, path, body=None, pair=None):
    """One request to the server; the JSON answer (2xx only)."""
    headers = {}
    data = None
    if body is not None:
        data = json.dumps(body).encode()
        headers["Content-Type"] = "application/json"
    if pair is not None:
        boundary = uuid.uuid4().hex
        parts = []
        for name in ("left", "right"):
            parts.append(
                f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{name}.png"\r\n'
                "Content-Type: image/png\r\n\r\n".encode()
                + pair[name]
                + b"\r\n"
            )
        data = b"".join(parts) + f"--{boundary}--\r\n".encode()
        headers["Content-Type"] = f"multipart/form-data; boundary={boundary}"
    request = urllib.request.Request(_BASE + path, data=data, method=method, headers=headers)
    with urllib.request.urlopen(request, timeout=60) as response:
        text = response.read()
    return json.loads(text) if text else None


def _new_session(objects):
    session = _call("POST", "/v1/sessions", {"name": "schemathesis fixture", "objects": objects})
    return session["id"]


# Not a name the documented examples use ("needle"), which would clash.
_OBJECT = "st-fixture"


def _tracked_session():
    """A session whose one object was initialised on a real pair."""
    sid = _new_session([{"name": _OBJECT}])
    _call("POST", f"/v1/sessions/{sid}/frames", pair=PAIRS[0])
    return sid, _OBJECT


def _two_object_session():
    """A session with two objects and no pair yet (one can be deleted)."""
    return _new_session([{"name": _OBJECT}, {"name": f"{_OBJECT}-2"}]), f"{_OBJECT}-2"


def _geometric_calibration():
    body = {"model": "geometric", "name": "schemathesis fixture", "pixel_size_um": 0.05, "vergence_deg": 5.0}
    return _call("POST", "/v1/calibrations", body)["id"]


def _fitted_calibration():
    samples = [{"disparity_px": 1.0, "z_um": 0.0}, {"disparity_px": 3.0, "z_um": 10.0}]
    body = {"model": "fit", "name": "schemathesis fixture", "degree": 1, "samples": samples}
    return _call("POST", "/v1/calibrations", body)["id"]


_shared = {}


def _shared_fixture(key, make):
    if key not in _shared:
        _shared[key] = make()
    return _shared[key]


# -- which cases are changed ---------------------------------------------------
def _is_positive(case):
    """Positive in every component (a coverage case can be positive as a
    whole and negative in one component)."""
    meta = case.meta
    if meta is None:
        return True
    components = getattr(meta, "components", None) or {}
    return meta.generation.mode.is_positive and not any(c.mode.is_negative for c in components.values())


def _op(case):
    """The case's operation: (METHOD, path template)."""
    return (case.method.upper(), case.path)


def _phase(case):
    """The phase that generated the case (None for the cases made here)."""
    if case.meta is None:
        return None
    name = case.meta.phase.name
    return getattr(name, "value", name)


_counters = defaultdict(itertools.count)


def _take(case, generated):
    """True for three of every four cases. In the fuzzing phase the choice
    follows the generated value, so an input hypothesis replays (it does,
    looking for inputs that succeed more) keeps its outcome; one whose outcome
    changed between replays keeps it searching for minutes. The other phases
    run each case once, often with one value throughout: a count per
    operation."""
    if _phase(case) == "fuzzing":
        return zlib.crc32(repr(generated).encode()) % 4 != 3
    return next(_counters[_op(case)]) % 4 != 3


def _with_pair(case, index, query=None):
    # A new case (public API) rather than an edit of this one: an edited body
    # with bytes in it would be revalidated, and bytes never pass a JSON
    # Schema validation, so the case would turn "negative". It keeps the
    # generated case's (positive) metadata, by which schemathesis counts the
    # cases an operation accepted.
    return case.operation.Case(
        _meta=copy.deepcopy(case.meta),
        method=case.method,
        path_parameters=dict(case.path_parameters),
        headers=dict(case.headers),
        cookies=dict(case.cookies),
        query=dict(case.query if query is None else query),
        body=dict(PAIRS[index]),
        media_type=case.media_type,
    )


@schemathesis.hook
def flatmap_case(context, case):
    """Examples and fuzzing: a real pair or the generated body, at random."""
    if _op(case) not in UPLOADS or not _is_positive(case):
        return st.just(case)
    choices = st.sampled_from([None, *range(len(PAIRS))])
    return choices.map(lambda index: case if index is None else _with_pair(case, index))


@schemathesis.hook
def before_add_examples(context, examples):
    """Examples (the documented example of each field): also with a real
    pair, without the example hints (they lie outside its 96x80 images)."""
    more = [
        _with_pair(case, 0, {k: v for k, v in case.query.items() if k not in ("roi", "point", "outline", "exclude")})
        for case in examples
        if _op(case) in UPLOADS and _is_positive(case)
    ]
    examples.extend(more)


@schemathesis.hook
def map_case(context, case):
    """Coverage (no strategies there): every pair in turn, then the generated body."""
    op = _op(case)
    if op not in UPLOADS or not _is_positive(case) or _phase(case) != "coverage":
        return case
    index = next(_counters[("coverage pair", op)]) % (len(PAIRS) + 1)
    return case if index == len(PAIRS) else _with_pair(case, index)


@schemathesis.hook
def before_call(context, case, kwargs):
    """Real ids in positive cases.

    The stateful phase follows the links for the ids in paths, so only the
    other phases get fixtures there. A calibration named in a body or a query
    no link provides: drawn at random, its 404 `calibration_not_found` would
    read as "the session just created is gone" to the stateful check
    `ensure_resource_availability`, so in that phase a calibration id that is
    a string is always a real one, in negative cases too (they stay negative
    in whatever else made them so).
    """
    stateful = _phase(case) == "stateful"
    if not stateful and not _is_positive(case):
        return
    op = _op(case)
    params = case.path_parameters
    if not stateful and "id" in params and case.path.startswith("/v1/sessions/") and _take(case, params["id"]):
        if op == ("DELETE", "/v1/sessions/{id}/objects/{name}"):
            sid, name = _two_object_session()
        elif op[0] != "GET":
            sid, name = _tracked_session()
        else:
            sid, name = _shared_fixture(op, _tracked_session)
        params["id"] = sid
        if "name" in params:
            params["name"] = name
    if not stateful and "id" in params and case.path.startswith("/v1/calibrations/") and _take(case, params["id"]):
        if op[0] != "GET":
            params["id"] = _fitted_calibration()
        else:
            params["id"] = _shared_fixture(("calibration", op), _fitted_calibration)
        if "index" in params:
            params["index"] = 0
    query = case.query
    if isinstance(query, dict) and "calibration_id" in query and (stateful or _take(case, query["calibration_id"])):
        query["calibration_id"] = _shared_fixture("geometric", _geometric_calibration)
    body = case.body
    if (
        isinstance(body, dict)
        and isinstance(body.get("calibration_id"), str)
        and (stateful or _take(case, body["calibration_id"]))
    ):
        # A session's samples extend a fitted calibration; a session's z_um
        # comes from any.
        fitted = op == ("POST", "/v1/sessions/{id}/calibration-samples")
        body["calibration_id"] = _shared_fixture(
            "fitted" if fitted else "geometric", _fitted_calibration if fitted else _geometric_calibration
        )


# -- responses ------------------------------------------------------------------
@schemathesis.deserializer("image/png")
def png(ctx, response):
    """A PNG whose size agrees with the x-frame-* headers (frames/latest)."""
    content = response.content
    if content[:8] != b"\x89PNG\r\n\x1a\n" or content[12:16] != b"IHDR":
        raise ValueError("not a PNG file (no PNG signature and IHDR chunk)")
    width, height = struct.unpack(">II", content[16:24])
    headers = {k.lower(): v for k, v in response.headers.items()}

    def header(name):
        value = headers.get(name)
        return int(value[0] if isinstance(value, list) else value) if value is not None else None

    scale, frame_w, frame_h = header("x-frame-scale"), header("x-frame-width"), header("x-frame-height")
    if scale and frame_w and frame_h:
        expected = (-(-frame_w // scale), -(-frame_h // scale))  # rounded up: partial blocks count
        if (width, height) != expected:
            raise ValueError(
                f"PNG of {width}x{height} for a {frame_w}x{frame_h} frame shrunk by {scale} "
                f"(expected {expected[0]}x{expected[1]})"
            )
    return f"PNG {width}x{height}"
