#!/usr/bin/env python3
"""Trace a reference outline of one object in a real image, independently of semdepth.

A person draws a coarse outline of the object by hand (a polygon, a few vertices,
within some pixels of the edge). This tool moves it onto the edge: the outline is
resampled every 6 px, and each point is moved along the outline's normal, within
--search px, to where the image (Gaussian-smoothed, sigma 2 px) changes most steeply
in the expected direction (brighter inside, or darker inside with --dark); the moves
are median-filtered along the outline (5 points) so a lone texture edge cannot pull
one point away. Points on the image border stay there. The result must be checked by
eye on its overlay (--overlay) before it is committed as a fixture; it uses no code
of semdepth.

usage: trace_reference.py IMAGE GUESS_JSON [--dark] [--search PX] [--overlay OUT.png]
GUESS_JSON: [[x, y], ...] in pixels, in order around the object. Prints the polygon.
"""
import argparse
import json

import numpy as np
from PIL import Image, ImageDraw
from scipy import ndimage


def resample(poly, spacing):
    pts = []
    n = len(poly)
    for i in range(n):
        a, b = np.array(poly[i], float), np.array(poly[(i + 1) % n], float)
        length = np.hypot(*(b - a))
        steps = max(1, int(round(length / spacing)))
        for k in range(steps):
            pts.append(a + (b - a) * k / steps)
    return np.array(pts)


def snap(image, guess, search, dark=False, sigma=2.0, spacing=6.0):
    grey = ndimage.gaussian_filter(np.asarray(image, dtype=np.float64), sigma)
    gy, gx = np.gradient(grey)
    h, w = grey.shape
    pts = resample(guess, spacing)
    n = len(pts)
    area = 0.5 * sum(pts[i, 0] * pts[(i + 1) % n, 1] - pts[(i + 1) % n, 0] * pts[i, 1] for i in range(n))
    orient = 1.0 if area > 0 else -1.0
    moves = np.zeros(n)
    fixed = np.zeros(n, bool)
    for i in range(n):
        p = pts[i]
        if p[0] <= 0.5 or p[1] <= 0.5 or p[0] >= w - 1.5 or p[1] >= h - 1.5:
            fixed[i] = True
            continue
        t = pts[(i + 1) % n] - pts[i - 1]
        t /= np.hypot(*t)
        # Outward normal for a polygon whose signed area has sign `orient`
        # (y downwards): rotate the tangent.
        normal = orient * np.array([t[1], -t[0]])
        best, best_s = -np.inf, 0.0
        for s in np.arange(-search, search + 0.25, 0.5):
            q = p + s * normal
            if not (0 <= q[0] < w - 1 and 0 <= q[1] < h - 1):
                continue
            gxs = ndimage.map_coordinates(gx, [[q[1]], [q[0]]], order=1)[0]
            gys = ndimage.map_coordinates(gy, [[q[1]], [q[0]]], order=1)[0]
            along = gxs * normal[0] + gys * normal[1]
            score = along if dark else -along
            if score > best:
                best, best_s = score, s
        moves[i] = best_s
    free = ~fixed
    idx = np.where(free)[0]
    smoothed = moves.copy()
    for j, i in enumerate(idx):
        window = idx[max(0, j - 2): j + 3]
        smoothed[i] = np.median(moves[window])
    out = []
    for i in range(n):
        t = pts[(i + 1) % n] - pts[i - 1]
        t /= np.hypot(*t)
        normal = orient * np.array([t[1], -t[0]])
        q = pts[i] + (0 if fixed[i] else smoothed[i]) * normal
        out.append([round(float(np.clip(q[0], 0, w - 1)), 1), round(float(np.clip(q[1], 0, h - 1)), 1)])
    return out


def overlay(image, polygons, out, crop=None):
    rgb = image.convert("RGB")
    draw = ImageDraw.Draw(rgb)
    for pts, colour in polygons:
        draw.line([tuple(p) for p in pts] + [tuple(pts[0])], fill=colour, width=1)
    if crop:
        rgb = rgb.crop(crop)
    rgb.save(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("image")
    ap.add_argument("guess")
    ap.add_argument("--dark", action="store_true")
    ap.add_argument("--search", type=float, default=20.0)
    ap.add_argument("--overlay")
    a = ap.parse_args()
    image = Image.open(a.image).convert("L")
    guess = json.loads(a.guess)
    pts = snap(image, guess, a.search, a.dark)
    if a.overlay:
        overlay(image, [(guess, (255, 200, 0)), (pts, (0, 255, 0))], a.overlay)
    print(json.dumps(pts))


if __name__ == "__main__":
    main()
