#!/usr/bin/env python3
"""Upload a folder of SEM stereo pairs to semdepth over REST, one pair at a time.

The folder holds NAME_left.EXT / NAME_right.EXT (png, tif, tiff, jpg, jpeg,
bmp); pairs go in NAME order (numbers in names compare as numbers). A new
session is created, each pair is uploaded to it, and one line is printed per
pair:

    pair  frame  status  disparity_axis_px  z_um

then the session's results are written as CSV (or printed with --print-csv).
Standard library only. Exit code 0 when every pair was measured, 1 when the
server refused something (its message is printed), 2 for a bad folder or
arguments.

    python3 upload_folder.py DATA --server http://127.0.0.1:8080 --token T \\
        --geometric 0.5 6.0
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import List, Optional, Tuple

sys.path.insert(0, str(Path(__file__).resolve().parent))

from semdepth_client import SemdepthClient, SemdepthError, find_pairs  # noqa: E402


def folder_pairs(folder: Path) -> Optional[List[Tuple[str, Path, Path]]]:
    """The folder's pairs, or None after printing why there are none."""
    try:
        pairs = find_pairs(folder)
    except (OSError, ValueError) as e:
        print(f"error: {folder}: {e}", file=sys.stderr)
        return None
    if not pairs:
        print(f"error: no NAME_left.EXT / NAME_right.EXT pairs in {folder}", file=sys.stderr)
        return None
    return pairs


def folder_parser(doc: str) -> argparse.ArgumentParser:
    """The arguments both scripts take: the folder, the server, its token and
    the session name; the description is the first paragraph of `doc`."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="folder of NAME_left.EXT / NAME_right.EXT pairs")
    parser.add_argument("--server", default="http://127.0.0.1:8080", help="server address (default %(default)s)")
    parser.add_argument("--token", default=os.environ.get("SEMDEPTH_TOKEN") or None,
                        help="bearer token, when the server has one (default: $SEMDEPTH_TOKEN, which keeps it out of ps)")
    parser.add_argument("--name", default=None, help="session name (default: the folder's name)")
    return parser


def calibration_args(parser: argparse.ArgumentParser) -> None:
    """Adds --calibration-id / --geometric (shared with stream_folder.py)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--calibration-id", metavar="ID", help="attach this existing calibration to the session")
    group.add_argument("--geometric", nargs=2, type=float, metavar=("PIXEL_UM", "VERGENCE_DEG"),
                       help="create a geometric calibration: pixel size in um and vergence (tilt difference) in degrees")
    parser.add_argument("--reference-disparity", type=float, default=0.0, metavar="PX",
                        help="with --geometric: disparity of z = 0, pixels (default 0)")
    parser.add_argument("--tilt-axis-deg", type=float, default=None, metavar="DEG",
                        help="with --geometric: direction of the tilt axis in the image, degrees (server default 90)")


def resolve_calibration(api: SemdepthClient, args: argparse.Namespace, name: str) -> Optional[str]:
    """The calibration id to attach: the given one, a new geometric one, or None."""
    if args.calibration_id:
        return args.calibration_id
    if args.geometric:
        body = {"name": name, "model": "geometric", "pixel_size_um": args.geometric[0],
                "vergence_deg": args.geometric[1], "reference_disparity_px": args.reference_disparity}
        if args.tilt_axis_deg is not None:
            body["tilt_axis_deg"] = args.tilt_axis_deg
        return api.create_calibration(**body)["id"]
    return None


def fmt(value: Optional[float], digits: int) -> str:
    """A number with fixed decimals, or '-' for null."""
    return "-" if value is None else f"{value:.{digits}f}"


def main(argv: Optional[List[str]] = None) -> int:
    parser = folder_parser(__doc__)
    calibration_args(parser)
    parser.add_argument("--csv", type=Path, default=None, metavar="PATH",
                        help="where to write the results CSV (default: ./semdepth_<session id>.csv)")
    parser.add_argument("--print-csv", action="store_true", help="print the results CSV instead of writing a file")
    parser.add_argument("--timeout", type=float, default=60, help="seconds per request (default %(default)s)")
    args = parser.parse_args(argv)

    pairs = folder_pairs(args.folder)
    if pairs is None:
        return 2

    api = SemdepthClient(args.server, token=args.token, timeout=args.timeout)
    name = args.name or args.folder.resolve().name
    try:
        calibration_id = resolve_calibration(api, args, name)
        session = api.create_session(name=name, calibration_id=calibration_id)
        sid = session["id"]
        print(f"session {sid} ({len(pairs)} pairs, calibration {calibration_id or 'none'})")
        print(f"{'pair':<16} {'frame':>5}  {'status':<11} {'disparity_axis_px':>17} {'z_um':>10}")
        lost = 0
        for pair_name, left, right in pairs:
            r = api.upload_pair(sid, left, right)
            lost += r["status"] == "lost"
            line = (f"{pair_name:<16} {r['frame']:>5}  {r['status']:<11} "
                    f"{fmt(r.get('disparity_axis_px'), 3):>17} {fmt(r.get('z_um'), 2):>10}")
            if r.get("reason"):
                line += f"  ({r['reason']})"
            print(line, flush=True)
        csv_text = api.results(sid, format="csv")
    except SemdepthError as e:
        print(f"error: server {args.server}: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1

    if args.print_csv:
        sys.stdout.write(csv_text)
    else:
        path = args.csv or Path(f"semdepth_{sid}.csv")
        path.write_text(csv_text, encoding="utf-8")
        print(f"results CSV: {path}")
    if lost:
        print(f"{lost} of {len(pairs)} pairs lost", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
