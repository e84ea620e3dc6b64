"""A small client for the semdepth HTTP and WebSocket service.

REST calls use the Python standard library only (``urllib.request``,
``json``; multipart bodies are built by hand), so a lab script needs nothing
from PyPI to upload pairs and read results. Streaming over the WebSocket uses
the ``websockets`` package (``pip install 'websockets>=12'``), imported only
when :func:`stream_pairs` runs.

The contract this follows is ``docs/api.md`` of the project (endpoints,
FrameResult, the ``SDP1`` binary pair format). Python 3.9 or newer.

Example::

    from semdepth_client import SemdepthClient
    api = SemdepthClient("http://127.0.0.1:8080", token="secret")
    session = api.create_session(name="grain 7", calibration_id="c_...")
    result = api.upload_pair(session["id"], "0000_left.png", "0000_right.png")
    print(result["status"], result["disparity_axis_px"], result["z_um"])
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import struct
import urllib.error
import urllib.parse
import urllib.request
import uuid
from pathlib import Path
from typing import Any, AsyncIterator, Dict, Iterable, List, Optional, Sequence, Tuple, Union

__all__ = [
    "SemdepthClient",
    "SemdepthError",
    "ImageInput",
    "IMAGE_EXTENSIONS",
    "encode_pair",
    "encoding_for",
    "find_pairs",
    "stream_pairs",
]

#: A path to an image file, or the file's bytes.
ImageInput = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview]

#: File extensions the service decodes, and the ``encoding`` of the stream
#: header for each.
IMAGE_EXTENSIONS: Dict[str, str] = {
    ".png": "png",
    ".tif": "tiff",
    ".tiff": "tiff",
    ".jpg": "jpeg",
    ".jpeg": "jpeg",
    ".bmp": "bmp",
}

_CONTENT_TYPES = {
    "png": "image/png",
    "tiff": "image/tiff",
    "jpeg": "image/jpeg",
    "bmp": "image/bmp",
}

MAGIC = b"SDP1"


class SemdepthError(Exception):
    """An error answered by the service (or met on the way to it).

    ``status`` is the HTTP status (0 when the server could not be reached),
    ``code`` the snake_case code of the server's error body and ``message``
    its text, which says what was wrong and what was expected.
    """

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(f"{status} {code}: {message}" if status else f"{code}: {message}")
        self.status = status
        self.code = code
        self.message = message


def _error_from_body(status: int, body: bytes, reason: str = "") -> SemdepthError:
    """Builds a SemdepthError from a ``{"error": {"code", "message"}}`` body."""
    try:
        detail = json.loads(body.decode("utf-8"))["error"]
        return SemdepthError(status, str(detail["code"]), str(detail["message"]))
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        text = body.decode("utf-8", "replace").strip()
        return SemdepthError(status, "http_error", text or reason or "no error body")


def _read_image(image: ImageInput) -> Tuple[bytes, str, Optional[str]]:
    """Returns (bytes, file name, encoding or None) of a path or bytes."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        data = bytes(image)
        encoding = _sniff_encoding(data)
        return data, f"image.{encoding or 'bin'}", encoding
    path = Path(image)
    return path.read_bytes(), path.name, IMAGE_EXTENSIONS.get(path.suffix.lower())


def _sniff_encoding(data: bytes) -> Optional[str]:
    """Guesses the encoding of image bytes from their signature."""
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff"
    if data.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if data.startswith(b"BM"):
        return "bmp"
    return None


def encoding_for(image: ImageInput) -> str:
    """The stream header ``encoding`` of a file path (by extension) or of
    image bytes (by signature): ``png``, ``tiff``, ``jpeg`` or ``bmp``."""
    if isinstance(image, (bytes, bytearray, memoryview)):
        found = _sniff_encoding(bytes(image[:8]))
    else:
        found = IMAGE_EXTENSIONS.get(Path(image).suffix.lower())
    if found is None:
        what = "these bytes" if isinstance(image, (bytes, bytearray, memoryview)) else str(image)
        raise ValueError(f"cannot tell the image encoding of {what} (expected a file ending in "
                         f"{', '.join(IMAGE_EXTENSIONS)} or PNG/TIFF/JPEG/BMP bytes)")
    return found


def _natural_key(name: str) -> List[Any]:
    """Sort key that orders ``img_9`` before ``img_10``."""
    return [(0, int(part), "") if part.isdigit() else (1, 0, part) for part in re.split(r"(\d+)", name)]


def find_pairs(folder: Union[str, "os.PathLike[str]"]) -> List[Tuple[str, Path, Path]]:
    """Finds the stereo pairs ``NAME_left.EXT`` / ``NAME_right.EXT`` of a folder.

    EXT is one of png, tif, tiff, jpg, jpeg, bmp (any case). Returns
    ``(NAME, left_path, right_path)`` sorted by NAME (numbers in names compare
    as numbers). Raises ValueError for a NAME with only one side or with two
    files on one side.
    """
    sides: Dict[str, Dict[str, Path]] = {}
    pattern = re.compile(r"^(?P<name>.+)_(?P<side>left|right)$", re.IGNORECASE)
    for entry in Path(folder).iterdir():
        if not entry.is_file() or entry.suffix.lower() not in IMAGE_EXTENSIONS:
            continue
        match = pattern.match(entry.stem)
        if not match:
            continue
        name, side = match.group("name"), match.group("side").lower()
        found = sides.setdefault(name, {})
        if side in found:
            raise ValueError(f"two {side} images for pair {name!r}: {found[side].name} and {entry.name}")
        found[side] = entry
    problems = [
        f"pair {name!r} has no {('right' if 'left' in found else 'left')} image"
        for name, found in sides.items()
        if len(found) != 2
    ]
    if problems:
        raise ValueError("; ".join(sorted(problems)) + " (expected NAME_left.EXT and NAME_right.EXT)")
    return [(name, sides[name]["left"], sides[name]["right"]) for name in sorted(sides, key=_natural_key)]


class SemdepthClient:
    """REST client of the semdepth service (standard library only).

    ``base_url`` is the server's address, e.g. ``http://127.0.0.1:8080``;
    ``token`` is sent as ``Authorization: Bearer <token>`` when given;
    ``timeout`` is the socket timeout of one request in seconds. Every method
    returns the decoded JSON answer and raises :class:`SemdepthError` when the
    server answers with an error.
    """

    def __init__(self, base_url: str, token: Optional[str] = None, timeout: float = 60) -> None:
        self.base_url = base_url.rstrip("/")
        self.token = token
        self.timeout = timeout

    # -- plumbing -----------------------------------------------------------

    def request(
        self,
        method: str,
        path: str,
        body: Any = None,
        query: Optional[Dict[str, Any]] = None,
        data: Optional[bytes] = None,
        content_type: Optional[str] = None,
        raw: bool = False,
    ) -> Any:
        """Sends one request; returns the decoded JSON (or the text when
        ``raw``). ``body`` is sent as JSON, ``data`` as is."""
        url = self.base_url + path
        if query:
            url += "?" + urllib.parse.urlencode({k: v for k, v in query.items() if v is not None})
        headers = {"Accept": "application/json"}
        if self.token is not None:
            headers["Authorization"] = f"Bearer {self.token}"
        if body is not None:
            data = json.dumps(body).encode("utf-8")
            content_type = "application/json"
        if content_type:
            headers["Content-Type"] = content_type
        req = urllib.request.Request(url, data=data, headers=headers, method=method)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as response:
                payload = response.read()
        except urllib.error.HTTPError as e:
            raise _error_from_body(e.code, e.read(), str(e.reason)) from None
        except urllib.error.URLError as e:
            raise SemdepthError(0, "unreachable", f"cannot reach {self.base_url}: {e.reason}") from None
        except OSError as e:  # timeouts, resets
            raise SemdepthError(0, "unreachable", f"{method} {url}: {e}") from None
        if raw:
            return payload.decode("utf-8")
        return json.loads(payload.decode("utf-8")) if payload else None

    def _multipart(self, method: str, path: str, left: ImageInput, right: ImageInput,
                   query: Optional[Dict[str, Any]] = None,
                   fields: Optional[Dict[str, str]] = None) -> Dict[str, Any]:
        boundary = "semdepth-" + uuid.uuid4().hex
        chunks: List[bytes] = []
        for name, value in (fields or {}).items():
            chunks.append(
                (f"--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n"
                 f"{value}\r\n").encode("utf-8")
            )
        for field, image in (("left", left), ("right", right)):
            content, filename, encoding = _read_image(image)
            ctype = _CONTENT_TYPES.get(encoding or "", "application/octet-stream")
            chunks.append(
                (
                    f"--{boundary}\r\n"
                    f'Content-Disposition: form-data; name="{field}"; filename="{filename.replace(chr(34), "_")}"\r\n'
                    f"Content-Type: {ctype}\r\n\r\n"
                ).encode("utf-8")
            )
            chunks.append(content)
            chunks.append(b"\r\n")
        chunks.append(f"--{boundary}--\r\n".encode("ascii"))
        return self.request(method, path, data=b"".join(chunks), query=query,
                            content_type=f"multipart/form-data; boundary={boundary}")

    @staticmethod
    def _id(value: str) -> str:
        return urllib.parse.quote(value, safe="")

    # -- operations ---------------------------------------------------------

    def healthz(self) -> Dict[str, Any]:
        """``GET /healthz``: the server is alive."""
        return self.request("GET", "/healthz")

    def readyz(self) -> Dict[str, Any]:
        """``GET /readyz``: the server's storage is reachable."""
        return self.request("GET", "/readyz")

    # calibrations

    def create_calibration(self, **body: Any) -> Dict[str, Any]:
        """``POST /v1/calibrations``. Geometric: ``model="geometric",
        pixel_size_um=.., vergence_deg=..``; fitted: ``model="fit", degree=1,
        samples=[{"disparity_px": d, "z_um": z}, ...]``."""
        return self.request("POST", "/v1/calibrations", body)

    def list_calibrations(self) -> List[Dict[str, Any]]:
        """``GET /v1/calibrations``: the calibrations, oldest first."""
        answer = self.request("GET", "/v1/calibrations")
        return answer["calibrations"] if isinstance(answer, dict) else answer

    def get_calibration(self, calibration_id: str) -> Dict[str, Any]:
        """``GET /v1/calibrations/{id}``."""
        return self.request("GET", f"/v1/calibrations/{self._id(calibration_id)}")

    def delete_calibration(self, calibration_id: str) -> Any:
        """``DELETE /v1/calibrations/{id}``."""
        return self.request("DELETE", f"/v1/calibrations/{self._id(calibration_id)}")

    def add_calibration_sample(self, calibration_id: str, disparity_px: float, z_um: float) -> Dict[str, Any]:
        """``POST /v1/calibrations/{id}/samples``: appends a sample, refits."""
        return self.request("POST", f"/v1/calibrations/{self._id(calibration_id)}/samples",
                            {"disparity_px": disparity_px, "z_um": z_um})

    def remove_calibration_sample(self, calibration_id: str, index: int) -> Dict[str, Any]:
        """``DELETE /v1/calibrations/{id}/samples/{index}``: removes sample
        ``index`` (its position in ``samples``, from 0; ``residuals_um`` shows
        which one is off), refits; returns the calibration."""
        return self.request("DELETE", f"/v1/calibrations/{self._id(calibration_id)}/samples/{int(index)}")

    def edit_calibration_sample(self, calibration_id: str, index: int, disparity_px: Optional[float] = None,
                                z_um: Optional[float] = None) -> Dict[str, Any]:
        """``PATCH /v1/calibrations/{id}/samples/{index}``: changes a sample's
        disparity and/or height, refits; returns the calibration."""
        body = {k: v for k, v in (("disparity_px", disparity_px), ("z_um", z_um)) if v is not None}
        return self.request("PATCH", f"/v1/calibrations/{self._id(calibration_id)}/samples/{int(index)}", body)

    # sessions

    def create_session(self, name: Optional[str] = None, calibration_id: Optional[str] = None,
                       roi: Optional[Sequence[int]] = None, point: Optional[Sequence[float]] = None,
                       polarity: Optional[str] = None, outline: Optional[Sequence[Sequence[float]]] = None,
                       exclude: Optional[Sequence[Sequence[float]]] = None, **params: Any) -> Dict[str, Any]:
        """``POST /v1/sessions``; ``params`` may hold ``init`` and ``tracker``.

        ``roi`` ``[x, y, width, height]`` (the box the object lies in, pixels,
        clipped to the image), ``point`` ``[x, y]`` (a point on the object),
        ``outline`` ``[[x, y], ...]`` (the object's outline as drawn round it,
        at least 3 vertices), ``exclude`` ``[[x, y], ...]`` (points on what is
        not the object) and ``polarity`` (``"brighter"``, ``"darker"`` or
        ``"any"``) name the object the first pair initialises on; they go into
        ``init``."""
        body: Dict[str, Any] = dict(params)
        hints = _hints(roi=roi, point=point, polarity=polarity, outline=outline, exclude=exclude)
        if hints:
            body["init"] = {**body.get("init", {}), **hints}
        if name is not None:
            body["name"] = name
        if calibration_id is not None:
            body["calibration_id"] = calibration_id
        return self.request("POST", "/v1/sessions", body)

    def list_sessions(self) -> List[Dict[str, Any]]:
        """``GET /v1/sessions``: the sessions, oldest first."""
        answer = self.request("GET", "/v1/sessions")
        return answer["sessions"] if isinstance(answer, dict) else answer

    def get_session(self, session_id: str) -> Dict[str, Any]:
        """``GET /v1/sessions/{id}``."""
        return self.request("GET", f"/v1/sessions/{self._id(session_id)}")

    def update_session(self, session_id: str, **fields: Any) -> Dict[str, Any]:
        """``PATCH /v1/sessions/{id}``, e.g. ``calibration_id="c_..."``."""
        return self.request("PATCH", f"/v1/sessions/{self._id(session_id)}", fields)

    def delete_session(self, session_id: str) -> Any:
        """``DELETE /v1/sessions/{id}``."""
        return self.request("DELETE", f"/v1/sessions/{self._id(session_id)}")

    def delete_sessions(self, name_prefix: Optional[str] = None, idle_for_s: Optional[float] = None,
                        include_kept: bool = False) -> List[str]:
        """``DELETE /v1/sessions``: deletes the sessions named with
        ``name_prefix`` and/or idle for ``idle_for_s`` seconds (those created
        with ``keep=True`` only with ``include_kept``); returns their ids."""
        query: Dict[str, Any] = {"name_prefix": name_prefix, "idle_for_s": idle_for_s}
        if include_kept:
            query["include_kept"] = "true"
        return self.request("DELETE", "/v1/sessions", query=query)["deleted"]

    def reset(self, session_id: str) -> Dict[str, Any]:
        """``POST /v1/sessions/{id}/reset``: the next pair initialises again."""
        return self.request("POST", f"/v1/sessions/{self._id(session_id)}/reset")

    def reinit(self, session_id: str, roi: Optional[Sequence[int]] = None,
               point: Optional[Sequence[float]] = None, polarity: Optional[str] = None,
               min_area_px: Optional[float] = None, max_area_px: Optional[float] = None,
               outline: Optional[Sequence[Sequence[float]]] = None,
               exclude: Optional[Sequence[Sequence[float]]] = None, **init: Any) -> Dict[str, Any]:
        """``POST /v1/sessions/{id}/reinit``: the next pair initialises on the
        object these hints name; earlier results stay and frames keep counting.

        The hints (``roi``, ``point``, ``outline``, ``exclude``, ``polarity``,
        ``min_area_px``, ``max_area_px``) replace the session's as a set: those
        left as None are cleared. Other ``init`` parameters given as keywords
        (e.g. ``working_max_side=1024``) replace the session's. Returns the
        session."""
        body = {**init, **_hints(roi=roi, point=point, polarity=polarity, outline=outline, exclude=exclude,
                                 min_area_px=min_area_px, max_area_px=max_area_px)}
        return self.request("POST", f"/v1/sessions/{self._id(session_id)}/reinit", {"init": body})

    def upload_pair(self, session_id: str, left: ImageInput, right: ImageInput,
                    label: Optional[str] = None, timestamp: Optional[str] = None) -> Dict[str, Any]:
        """``POST /v1/sessions/{id}/frames``: uploads one pair (paths or
        bytes of PNG, TIFF, JPEG or BMP files); returns its FrameResult.
        ``label`` names the pair (the CSV's ``name``; default: the left file
        name) and ``timestamp`` (RFC 3339) is when it was acquired."""
        fields = {k: v for k, v in (("label", label), ("timestamp", timestamp)) if v is not None}
        return self._multipart("POST", f"/v1/sessions/{self._id(session_id)}/frames", left, right,
                               fields=fields)

    def results(self, session_id: str, since: int = 0, format: str = "json",
                limit: Optional[int] = None) -> Any:
        """``GET /v1/sessions/{id}/results``: with ``format="json"`` a page
        ``{"results": [...], "next_since": n|null}``; with ``format="csv"``
        the CSV text (header line first)."""
        if format not in ("json", "csv"):
            raise ValueError(f"format {format!r} (expected 'json' or 'csv')")
        return self.request("GET", f"/v1/sessions/{self._id(session_id)}/results",
                            query={"since": since, "format": format, "limit": limit},
                            raw=(format == "csv"))

    def all_results(self, session_id: str, since: int = 0) -> List[Dict[str, Any]]:
        """Every FrameResult from frame ``since`` on, following the pages."""
        out: List[Dict[str, Any]] = []
        next_since: Optional[int] = since
        while next_since is not None:
            page = self.results(session_id, since=next_since)
            out.extend(page["results"])
            next_since = page.get("next_since")
        return out

    def add_session_calibration_sample(self, session_id: str, calibration_id: str, z_um: float) -> Dict[str, Any]:
        """``POST /v1/sessions/{id}/calibration-samples``: pairs the session's
        latest disparity with the known height ``z_um`` and refits that
        calibration; returns the calibration."""
        return self.request("POST", f"/v1/sessions/{self._id(session_id)}/calibration-samples",
                            {"calibration_id": calibration_id, "z_um": z_um})

    def depth(self, left: ImageInput, right: ImageInput, calibration_id: Optional[str] = None,
              roi: Optional[Sequence[int]] = None, point: Optional[Sequence[float]] = None,
              polarity: Optional[str] = None, outline: Optional[Sequence[Sequence[float]]] = None,
              exclude: Optional[Sequence[Sequence[float]]] = None) -> Dict[str, Any]:
        """``POST /v1/depth``: measures one pair without a session; ``roi``,
        ``point``, ``outline``, ``exclude`` and ``polarity`` are hints as in
        :meth:`create_session`."""
        query: Dict[str, Any] = {"calibration_id": calibration_id, "polarity": polarity}
        if roi is not None:
            query["roi"] = ",".join(str(int(v)) for v in roi)
        if point is not None:
            query["point"] = ",".join(repr(float(v)) for v in point)
        for key, points in (("outline", outline), ("exclude", exclude)):
            if points is not None:
                query[key] = ",".join(repr(float(v)) for p in points for v in p)
        return self._multipart("POST", "/v1/depth", left, right, query=query)


def reinit_message(object: Optional[str] = None, **hints: Any) -> Dict[str, Any]:
    """New hints to send among the pairs of :func:`stream_pairs` (the
    stream's text message ``{"reinit": {"init": {...}}}``): keywords as in
    :meth:`Client.reinit`, replacing the session's hints as a set; ``object``
    names one object of a session of several."""
    body: Dict[str, Any] = {"init": _hints(**hints)}
    if object is not None:
        body["object"] = object
    return {"reinit": body}


def _hints(**hints: Any) -> Dict[str, Any]:
    """The hints given (not None) as ``init`` fields, lists for sequences."""
    def plain(v: Any) -> Any:
        return [plain(x) for x in v] if isinstance(v, (tuple, list)) else v
    return {k: plain(v) for k, v in hints.items() if v is not None}


# -- streaming ----------------------------------------------------------------


def encode_pair(seq: int, left: ImageInput, right: ImageInput, encoding: Optional[str] = None,
                width: Optional[int] = None, height: Optional[int] = None,
                bit_depth: Optional[int] = None) -> bytes:
    """Builds one binary pair message of the stream.

    ``b"SDP1"`` + u32 little-endian header length + UTF-8 JSON header + left
    bytes + right bytes. ``encoding`` is ``png``, ``tiff``, ``jpeg``, ``bmp``
    (guessed from the left image when None) or ``raw``, which needs
    ``width``, ``height`` and ``bit_depth`` (8 or 16; samples little-endian,
    row-major).
    """
    left_bytes = left if isinstance(left, (bytes, bytearray, memoryview)) else Path(left).read_bytes()
    right_bytes = right if isinstance(right, (bytes, bytearray, memoryview)) else Path(right).read_bytes()
    if encoding is None:
        encoding = encoding_for(left)
    header: Dict[str, Any] = {"seq": int(seq), "encoding": encoding}
    if encoding == "raw":
        if width is None or height is None or bit_depth is None:
            raise ValueError("raw encoding needs width, height and bit_depth")
        header.update(width=int(width), height=int(height), bit_depth=int(bit_depth))
    header["left_len"] = len(left_bytes)
    header["right_len"] = len(right_bytes)
    head = json.dumps(header, separators=(",", ":")).encode("utf-8")
    return b"".join([MAGIC, struct.pack("<I", len(head)), head, bytes(left_bytes), bytes(right_bytes)])


def stream_url(base_url: str, session_id: str, policy: str = "all") -> str:
    """The ``ws://``/``wss://`` address of a session's stream."""
    parts = urllib.parse.urlsplit(base_url.rstrip("/"))
    scheme = {"http": "ws", "https": "wss"}.get(parts.scheme, parts.scheme)
    path = f"{parts.path}/v1/sessions/{urllib.parse.quote(session_id, safe='')}/stream"
    return urllib.parse.urlunsplit((scheme, parts.netloc, path, urllib.parse.urlencode({"policy": policy}), ""))


def _handshake_error(e: Exception) -> Optional[SemdepthError]:
    """Turns a refused WebSocket upgrade into a SemdepthError."""
    response = getattr(e, "response", None)  # websockets >= 13: InvalidStatus
    if response is not None and hasattr(response, "status_code"):
        return _error_from_body(response.status_code, bytes(getattr(response, "body", b"") or b""))
    status = getattr(e, "status_code", None)  # websockets 12: InvalidStatusCode
    if isinstance(status, int):
        return SemdepthError(status, "websocket_refused",
                             f"{e} (the server refused the WebSocket upgrade: check the token and the session id)")
    return None


async def stream_pairs(
    url: str,
    session_id: str,
    pairs: Iterable[Any],
    token: Optional[str] = None,
    policy: str = "all",
    reply_timeout: float = 120,
) -> AsyncIterator[Dict[str, Any]]:
    """Streams pairs to a session over its WebSocket; yields the replies.

    ``url`` is the server's base address (``http://host:port``; ``ws://``
    works too). Each item of ``pairs`` is ``(left, right)`` (paths or bytes of
    encoded files; the encoding is taken from the left one), ready-made
    message bytes from :func:`encode_pair`, or new hints as a dict from
    :func:`reinit_message` (the next pair tracked initialises with them);
    sequence numbers count from 0 over the pairs in the order given. Yields
    one JSON reply per message: the FrameResult plus ``seq``, ``{"seq": n,
    "status": "skipped"}`` under ``policy="latest"``, ``{"seq": null,
    "reinit": <the session>}`` for new hints, or ``{"seq": n|null, "error":
    {...}}``. Sending runs alongside receiving, so
    ``policy="all"`` slows the sender down without stalling. Needs the
    ``websockets`` package (12 or newer).
    """
    try:
        from websockets.asyncio.client import connect  # websockets >= 13
        header_arg = "additional_headers"
    except ImportError:
        try:
            from websockets.client import connect  # type: ignore[no-redef]  # websockets 12
            header_arg = "extra_headers"
        except ImportError:
            raise ImportError("streaming needs the websockets package: pip install 'websockets>=12'") from None

    address = stream_url(url, session_id, policy)
    kwargs: Dict[str, Any] = {"max_size": None}
    if token is not None:
        kwargs[header_arg] = {"Authorization": f"Bearer {token}"}
    try:
        ws = await connect(address, **kwargs)
    except Exception as e:  # refused upgrade (401, 404, ...), unreachable server
        error = _handshake_error(e)
        if error is not None:
            raise error from None
        raise SemdepthError(0, "unreachable", f"cannot open {address}: {e}") from None

    async def sender() -> int:
        count, seq = 0, 0
        for item in pairs:
            if isinstance(item, dict):
                await ws.send(json.dumps(item))
                count += 1
                continue
            if isinstance(item, (bytes, bytearray, memoryview)):
                message = bytes(item)
            else:
                left, right = item
                message = encode_pair(seq, left, right)
            await ws.send(message)
            count += 1
            seq += 1
        return count

    task = asyncio.ensure_future(sender())
    recv: Optional["asyncio.Future[Any]"] = None
    received = 0
    try:
        while True:
            if task.done():
                failure = task.exception()
                if failure is not None:
                    if isinstance(failure, (ValueError, OSError, SemdepthError)):
                        raise failure
                    raise SemdepthError(0, "connection_closed", f"sending a pair: {failure}") from failure
                if received >= task.result():
                    break
            if recv is None:
                recv = asyncio.ensure_future(ws.recv())
            waiting = {recv} if task.done() else {recv, task}
            done, _ = await asyncio.wait(waiting, timeout=reply_timeout, return_when=asyncio.FIRST_COMPLETED)
            if not done:
                raise SemdepthError(0, "timeout", f"no reply within {reply_timeout} s")
            if recv in done:
                try:
                    message = recv.result()
                except Exception as e:  # the server closed the socket
                    raise SemdepthError(0, "connection_closed", f"receiving a reply: {e}") from None
                recv = None
                if isinstance(message, bytes):
                    message = message.decode("utf-8")
                received += 1
                yield json.loads(message)
    finally:
        pending = [f for f in (recv, task) if f is not None]
        for future in pending:
            future.cancel()
        await asyncio.gather(*pending, return_exceptions=True)
        await ws.close()
