#!/usr/bin/env python3
"""How much of the backlight each circle `grainforce detect` finds passes,
against the packing's median disk: the margin behind the opaque-object rule
of docs/image.md ("Opaque objects are no disks"), on every real photograph
at hand. Prints one Markdown row per photo: the field (bright: the
background's level above the disks' median in the signal channel), the
darkest circle that matches a reference disk, and the circles that match
none, each as its inner 0.8 R's median over the circles' median.

usage: GRAINFORCE_TEST_DATA=/path/to/shared [GRAINFORCE_EXTRA_PHOTOS=/path/to/photos] \\
           python3 benches/photos_false_circles.py [--grainforce BIN] [NAME ...]

The current binary drops the opaque circles, so they no longer show here;
give `--grainforce` a binary from before the rule (round 7) to see them.
Needs numpy and Pillow.
"""
import csv
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import extra_photos  # noqa: E402
import real_photos  # noqa: E402


def photos(shared, extra):
    """(name, image, reference centres, radius range) of every photo at hand."""
    out = []
    for name, (image, centres, _, radii) in real_photos.PHOTOS.items():
        folder = os.path.join(shared, "real-photos", name)
        out.append((name, os.path.join(folder, image), os.path.join(folder, centres), radii))
    if extra:
        for name, (_, radii) in extra_photos.PHOTOS.items():
            folder = os.path.join(extra, name)
            images = glob.glob(os.path.join(folder, "image.*"))
            if images:
                out.append((name, images[0], os.path.join(folder, "centers.txt"), radii))
    return out


def circles(scene):
    """Detected circles in pixels (x right, y down) and the search record."""
    frame = json.load(open(os.path.join(scene, "image-frame.json")))
    height = frame["height"]
    rows = csv.DictReader(open(os.path.join(scene, "grains.csv")))
    found = np.array([[float(r["x"]) - 0.5, height - 0.5 - float(r["y"]), float(r["radius"])] for r in rows])
    return found, frame.get("search", {})


def matched(found, centres):
    """Which circles match a reference disk (nearest first, one to one, within half its radius)."""
    ref = np.array([[float(v) for v in line.split(",")[:3]] for line in open(centres) if line.strip()])
    ref[:, :2] -= 1.0  # MATLAB's 1-based pixel centres
    pairs = sorted((np.hypot(*(found[j, :2] - ref[i, :2])), i, j)
                   for i in range(len(ref)) for j in range(len(found))
                   if np.hypot(*(found[j, :2] - ref[i, :2])) < 0.5 * ref[i, 2])
    taken_ref, hit = set(), set()
    for _, i, j in pairs:
        if i not in taken_ref and j not in hit:
            taken_ref.add(i)
            hit.add(j)
    return hit


def interior_median(picture, x, y, r):
    """The median over a grid of about 500 points within r of (x, y), as detect samples it."""
    step = max(1.0, r / 12.0)
    n = int(r / step)
    offsets = np.arange(-n, n + 1) * step
    dx, dy = np.meshgrid(offsets, offsets)
    inside = np.hypot(dx, dy) <= r
    px, py = np.round(x + dx[inside]).astype(int), np.round(y + dy[inside]).astype(int)
    h, w = picture.shape
    ok = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    return float(np.median(picture[py[ok], px[ok]]))


def signal_picture(image, search):
    """The picture G² is read in and the background's level in it; None when not read from the image."""
    if search.get("channel") == "gray-distance":
        return np.asarray(Image.open(image).convert("L"), dtype=float) / 255.0, search["background"][0]
    if search.get("channel") != "colour-distance":
        return None
    channel = {"red": 0, "green": 1, "blue": 2}[search.get("signal", "green")]
    rgb = np.asarray(Image.open(image).convert("RGB"), dtype=float) / 255.0
    return rgb[:, :, channel], search["background"][channel]


def main(argv):
    shared = os.environ.get("GRAINFORCE_TEST_DATA")
    if not shared:
        print("set GRAINFORCE_TEST_DATA (and GRAINFORCE_EXTRA_PHOTOS for more photographs); skipping")
        return 0
    grainforce = "target/release/grainforce"
    if "--grainforce" in argv:
        grainforce = argv[argv.index("--grainforce") + 1]
        argv = [a for a in argv if a not in ("--grainforce", grainforce)]
    print("| photo | field | darkest real disk | circles on no disk |")
    print("|---|---|---|---|")
    for name, image, centres, (lo, hi) in photos(shared, os.environ.get("GRAINFORCE_EXTRA_PHOTOS")):
        if argv and name not in argv:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([grainforce, "detect", image, "-o", tmp, "--radius", "%d..%d" % (lo, hi)],
                           check=True, capture_output=True)
            found, search = circles(tmp)
        signal = signal_picture(image, search)
        if signal is None:
            print("| `%s` | searched in %s: not applied | | |" % (name, search.get("channel")))
            continue
        picture, background = signal
        levels = np.array([interior_median(picture, x, y, 0.8 * r) for x, y, r in found])
        typical = float(np.median(levels))
        ratio = levels / typical
        hit = matched(found, centres)
        real = [ratio[j] for j in hit]
        other = sorted(ratio[j] for j in range(len(found)) if j not in hit)
        print("| `%s` | %s | %.3f | %s |" % (
            name, "bright" if background > typical else "dark", min(real) if real else float("nan"),
            ", ".join("%.3f" % v for v in other) or "none"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
