#!/usr/bin/env python3
"""How much the substrate's texture moves a real needle's disparity when
the substrate lies at another height (docs/real/README.md).

The real sequences' right views are their left images moved as a whole, so
the substrate moves with the needle and its texture cannot move the
disparity. Here the right view is composited instead: the needle (inside
its hand-checked reference outline, grown by GROW pixels so that its edge's
blur and halo go with it) moved by the known disparity d, the rest of the
frame by d - LAG. The tracker (`semdepth process`, the object named by a
lasso along the reference, no standard-error limit) then reports each
pair's disparity error against d and its standard error. The grown band is
substrate carried with the needle, so a small GROW splits the needle's halo
(too much error) and a large one keeps the substrate next to the edge with
the needle (too little): read the errors over several GROW values.

usage: python3 tools/substrate_lag.py [--image REL] [--grow 3 6 10] [--lag 0 1 2 4]
       (run from the repository root with target/debug/semdepth built)
"""
import argparse
import json
import pathlib
import subprocess
import tempfile

import numpy as np
from PIL import Image, ImageDraw
from scipy import ndimage

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "real"
FIXTURE = ROOT / "crates/core/tests/accuracy/fixtures/real_outlines.json"


def mask_of(polygon, shape, supersample=4):
    """The polygon's area share per pixel."""
    h, w = shape
    im = Image.new("L", (w * supersample, h * supersample), 0)
    ImageDraw.Draw(im).polygon([(x * supersample, y * supersample) for x, y in polygon], fill=255)
    return np.asarray(im.resize((w, h), Image.BOX)).astype(float) / 255.0


def disparity(k):
    """The known disparity of pair k, as the real suite gives it."""
    return 3.0 + 0.45 * k


def write_pairs(left, mask, grow, lag, pairs, out):
    yy, xx = np.mgrid[-grow : grow + 1, -grow : grow + 1]
    grown = ndimage.grey_dilation(mask, footprint=(xx**2 + yy**2) <= grow * grow) if grow > 0 else mask
    for k in range(pairs):
        d = disparity(k)
        needle = ndimage.shift(left, (0, d), order=3, mode="nearest")
        substrate = ndimage.shift(left, (0, d - lag), order=3, mode="nearest")
        alpha = ndimage.shift(grown, (0, d), order=1, mode="nearest")
        right = substrate * (1 - alpha) + needle * alpha
        Image.fromarray(left.clip(0, 255).round().astype(np.uint8)).save(out / f"p{k:02d}_left.png")
        Image.fromarray(right.clip(0, 255).round().astype(np.uint8)).save(out / f"p{k:02d}_right.png")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--image", default="autoliftout/landing/ref_liftout_needle_eb.png")
    parser.add_argument("--object", default="needle")
    parser.add_argument("--grow", type=int, nargs="+", default=[3, 6, 10])
    parser.add_argument("--lag", type=float, nargs="+", default=[0.0, 1.0, 2.0, 4.0])
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--semdepth", default=str(ROOT / "target/debug/semdepth"))
    args = parser.parse_args()
    polygon = json.loads(FIXTURE.read_text())["outlines"][args.image][args.object]["polygon"]
    left = np.asarray(Image.open(DATA / args.image).convert("L")).astype(float)
    mask = mask_of(polygon, left.shape)
    lasso = ",".join(f"{x:.1f},{y:.1f}" for x, y in polygon[:: max(1, len(polygon) // 24)])
    with tempfile.TemporaryDirectory() as tmp:
        params = pathlib.Path(tmp) / "params.json"
        params.write_text(json.dumps({"max_disparity_std_px": 50.0}))
        print("| grow px | lag px | pair | status | error px | std px |")
        print("|---|---|---|---|---|---|")
        for grow in args.grow:
            for lag in args.lag:
                out = pathlib.Path(tmp) / f"g{grow}_l{lag}"
                out.mkdir()
                write_pairs(left, mask, grow, lag, args.pairs, out)
                run = subprocess.run(
                    [args.semdepth, "process", str(out), f"--outline={lasso}", "--no-contour", "--params", str(params)],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                for k, line in enumerate(run.stdout.splitlines()):
                    r = json.loads(line)
                    d, s = r.get("disparity_px"), r.get("disparity_std_px")
                    error = f"{d[0] - disparity(k):+.3f}" if d else "-"
                    std = f"{s:.3f}" if s else "-"
                    print(f"| {grow} | {lag} | {k} | {r.get('status')} | {error} | {std} |")


if __name__ == "__main__":
    main()
