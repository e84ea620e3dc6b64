#!/usr/bin/env python3
"""Draw the reference outlines of crates/core/tests/accuracy/fixtures/real_outlines.json
over their real images (../shared/data/real) into docs/real/, so a reader can check them:
the outline in green, the coarse hand-drawn outline it was traced from in yellow.

usage: python3 tools/render_references.py   (from the repository root; needs numpy, Pillow)
"""
import json
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data" / "real"
FIXTURE = ROOT / "crates/core/tests/accuracy/fixtures/real_outlines.json"
OUT = ROOT / "docs" / "real"


def load(key):
    if key.endswith("mean_of_scans_0_to_45"):
        scans = [np.asarray(Image.open(SHARED / f"autoliftout/static_scans/scan_{k}_eb.png"), float) for k in range(0, 50, 5)]
        return Image.fromarray(np.mean(scans, axis=0).clip(0, 255).astype("uint8"))
    return Image.open(SHARED / key).convert("L")


def main():
    outlines = json.loads(FIXTURE.read_text())["outlines"]
    OUT.mkdir(parents=True, exist_ok=True)
    for key, objects in outlines.items():
        image = load(key).convert("RGB")
        draw = ImageDraw.Draw(image)
        for entry in objects.values():
            guess = entry.get("guess")
            if isinstance(guess, list):
                draw.line([tuple(p) for p in guess] + [tuple(guess[0])], fill=(255, 200, 0), width=1)
            poly = entry["polygon"]
            draw.line([tuple(p) for p in poly] + [tuple(poly[0])], fill=(0, 255, 0), width=2)
        scale = 768 / max(image.size)
        if scale < 1:
            image = image.resize((int(image.width * scale), int(image.height * scale)), Image.LANCZOS)
        name = key.replace("autoliftout/", "").replace("/", "_").replace(".png", "").replace(".tif", "") + ".jpg"
        image.save(OUT / name, quality=70)
        print(OUT / name)


if __name__ == "__main__":
    main()
