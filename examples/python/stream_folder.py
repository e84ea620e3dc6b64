#!/usr/bin/env python3
"""Stream a folder of SEM stereo pairs to semdepth over its WebSocket.

Same folder layout as upload_folder.py (NAME_left.EXT / NAME_right.EXT, sent
in NAME order). Each pair goes as one binary SDP1 message carrying the files
as they are (encoding png, tiff, jpeg or bmp from the extension), and one line
is printed per reply:

    seq  pair  frame  status  disparity_axis_px  z_um

Needs the websockets package (pip install 'websockets>=12'). Exit code 0
when every pair got a result, 1 on a refused connection or an error reply
(the server's message is printed), 2 for a bad folder or arguments.

    python3 stream_folder.py DATA --server http://127.0.0.1:8080 --token T \\
        --calibration-id c_... --policy all
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import sys
from pathlib import Path
from typing import List, Optional

sys.path.insert(0, str(Path(__file__).resolve().parent))

from semdepth_client import SemdepthClient, SemdepthError, encode_pair, stream_pairs  # noqa: E402
from upload_folder import calibration_args, fmt, folder_pairs, folder_parser, resolve_calibration  # noqa: E402


async def run(args: argparse.Namespace, pairs: list) -> int:
    api = SemdepthClient(args.server, token=args.token)
    name = args.name or args.folder.resolve().name
    if args.session_id:
        sid = args.session_id
        if args.calibration_id or args.geometric:
            api.update_session(sid, calibration_id=resolve_calibration(api, args, name))
    else:
        calibration_id = resolve_calibration(api, args, name)
        sid = api.create_session(name=name, calibration_id=calibration_id)["id"]
    print(f"session {sid} ({len(pairs)} pairs, policy {args.policy})")
    print(f"{'seq':>4} {'pair':<16} {'frame':>5}  {'status':<11} {'disparity_axis_px':>17} {'z_um':>10}")
    messages = (encode_pair(seq, left, right) for seq, (_, left, right) in enumerate(pairs))
    counts = {}
    errors = 0
    async for r in stream_pairs(args.server, sid, messages, token=args.token, policy=args.policy):
        seq = r.get("seq")
        pair_name = pairs[seq][0] if isinstance(seq, int) and 0 <= seq < len(pairs) else "?"
        if "error" in r:
            errors += 1
            e = r["error"]
            print(f"{seq if seq is not None else '-':>4} {pair_name:<16} error: {e.get('code')}: {e.get('message')}",
                  flush=True)
            continue
        status = r.get("status", "?")
        counts[status] = counts.get(status, 0) + 1
        if status == "skipped":
            print(f"{seq:>4} {pair_name:<16} {'-':>5}  skipped", flush=True)
            continue
        line = (f"{seq:>4} {pair_name:<16} {r['frame']:>5}  {status:<11} "
                f"{fmt(r.get('disparity_axis_px'), 3):>17} {fmt(r.get('z_um'), 2):>10}")
        if r.get("reason"):
            line += f"  ({r['reason']})"
        print(line, flush=True)
    summary = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    print(f"{sum(counts.values()) + errors} replies: {summary or 'none'}" + (f", {errors} errors" if errors else ""))
    return 1 if errors else 0


def main(argv: Optional[List[str]] = None) -> int:
    parser = folder_parser(__doc__)
    parser.add_argument("--session-id", default=None, metavar="ID",
                        help="stream into this existing session instead of creating one")
    parser.add_argument("--policy", choices=["all", "latest"], default="all",
                        help="all: every pair is processed; latest: pairs that wait are skipped (default %(default)s)")
    calibration_args(parser)
    args = parser.parse_args(argv)

    pairs = folder_pairs(args.folder)
    if pairs is None:
        return 2
    # Before anything is created on the server.
    if importlib.util.find_spec("websockets") is None:
        print("error: streaming needs the websockets package: pip install 'websockets>=12'", file=sys.stderr)
        return 2
    try:
        return asyncio.run(run(args, pairs))
    except SemdepthError as e:
        print(f"error: server {args.server}: {e}", file=sys.stderr)
        return 1
    except ImportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
