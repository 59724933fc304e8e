#!/usr/bin/env python3
"""An independent check of disk centres on the shared real photographs: each
disk's outline fitted to sub-pixel edge points (not a Hough vote, not
grainforce's search), then grainforce's and PeGS's centres compared with it.

usage: GRAINFORCE_TEST_DATA=/path/to/shared python3 benches/edge_fit.py \
           [--grainforce target/release/grainforce] [--only NAME]

Edge points: the colour distance from the background colour (the image's most
common colour, as `detect --channel auto` reads it), sampled along 360 rays
from PeGS's centre; on each ray the outline is where the distance falls, going
outward, half-way from the disk's level (its median over 0.75–0.9 R on that
ray) to the background's (its median over 1.15–1.3 R), interpolated between
samples. A ray counts only when the disk stands clear of the background (its level
at least twice the larger of 2.5 times the background's noise and 0.04), the
level outside is below 0.4 of the disk's, and nothing beyond 1.15 R rises
half-way back (no neighbour, wall or paint there). A circle is fitted to the points
by least squares (algebraic, then geometric), dropping points more than
3 median deviations off, twice; a disk is fitted only when at least 40 rays
spread over more than half its circumference remain. Needs numpy, scipy,
Pillow (pip, in a virtual environment).
"""
import csv
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image
from scipy.ndimage import map_coordinates

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from real_photos import PHOTOS  # noqa: E402


def colour_distance(path):
    im = np.asarray(Image.open(path).convert("RGB")).astype(np.float32) / 255.0
    q = np.minimum((im * 16).astype(int), 15)
    bins = (q[..., 0] * 16 + q[..., 1]) * 16 + q[..., 2]
    fullest = np.bincount(bins.ravel(), minlength=4096).argmax()
    background = im[bins == fullest].mean(0)
    d = np.sqrt(((im - background) ** 2).sum(-1))
    d /= np.percentile(d[::3, ::3], 99)
    return d, float(np.percentile(d[bins == fullest], 90))


def fit_circle(pts):
    """Least squares circle: algebraic (Kasa), then Gauss-Newton on the distances."""
    x, y = pts[:, 0], pts[:, 1]
    a = np.c_[2 * x, 2 * y, np.ones_like(x)]
    cx, cy, c = np.linalg.lstsq(a, x * x + y * y, rcond=None)[0]
    r = np.sqrt(c + cx * cx + cy * cy)
    for _ in range(20):
        dx, dy = x - cx, y - cy
        rho = np.hypot(dx, dy)
        j = np.c_[-dx / rho, -dy / rho, -np.ones_like(x)]
        step = np.linalg.lstsq(j, -(rho - r), rcond=None)[0]
        cx, cy, r = cx + step[0], cy + step[1], r + step[2]
        if np.abs(step).max() < 1e-6:
            break
    return cx, cy, r


def edge_fit(d, level, x0, y0, r0):
    empty = max(2.5 * level, 0.04)
    t = np.linspace(0, 2 * np.pi, 360, endpoint=False)
    rho = np.arange(0.6, 1.35, 0.25 / r0) * r0
    xs = x0 + np.outer(np.cos(t), rho)
    ys = y0 + np.outer(np.sin(t), rho)
    prof = map_coordinates(d, [ys.ravel(), xs.ravel()], order=1, mode="nearest").reshape(xs.shape)
    pts, angles = [], []
    for k in range(len(t)):
        p = prof[k]
        inside = np.median(p[(rho >= 0.75 * r0) & (rho <= 0.9 * r0)])
        outside = np.median(p[(rho >= 1.15 * r0) & (rho <= 1.3 * r0)])
        half = 0.5 * (inside + outside)
        beyond = p[(rho >= 1.15 * r0) & (rho <= 1.3 * r0)]
        if inside < 2 * empty or outside > 0.4 * inside or beyond.max() >= half:
            continue
        # The last sample at or above half-way before 1.15 R, then the crossing.
        idx = np.nonzero((p >= half) & (rho < 1.15 * r0))[0]
        if len(idx) == 0 or idx[-1] + 1 >= len(rho):
            continue
        i = idx[-1]
        f = (p[i] - half) / max(p[i] - p[i + 1], 1e-9)
        r = rho[i] + f * (rho[i + 1] - rho[i])
        pts.append((x0 + r * np.cos(t[k]), y0 + r * np.sin(t[k])))
        angles.append(t[k])
    pts, angles = np.array(pts), np.array(angles)
    for _ in range(3):
        if len(pts) < 40:
            return None
        cx, cy, r = fit_circle(pts)
        res = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
        mad = np.median(np.abs(res - np.median(res))) + 1e-9
        keep = np.abs(res - np.median(res)) <= 3 * 1.4826 * mad
        pts, angles = pts[keep], angles[keep]
    # Points spread over more than half the circumference: the largest empty arc < pi.
    a = np.sort(angles)
    gaps = np.diff(np.r_[a, a[0] + 2 * np.pi])
    if len(pts) < 40 or gaps.max() > np.pi:
        return None
    cx, cy, r = fit_circle(pts)
    res = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r
    # A fit that wandered off the disk it started on is no fit.
    if np.hypot(cx - x0, cy - y0) > 0.2 * r0 or abs(r / r0 - 1) > 0.15:
        return None
    return cx, cy, r, float(np.sqrt(np.mean(res**2)))


def grainforce_centres(binary, path, rmin, rmax):
    out = tempfile.mkdtemp()
    subprocess.run([binary, "detect", "-q", path, "-o", out, "--radius", "%d..%d" % (rmin, rmax)], check=True)
    fr = json.load(open(os.path.join(out, "image-frame.json")))
    s, (x0, y0), h = float(fr.get("px_per_m", 1.0)), fr.get("origin", [0.0, 0.0]), float(fr["height"])
    return np.array([((float(r["x"]) - x0) * s - 0.5, h - 0.5 - (float(r["y"]) - y0) * s)
                     for r in csv.DictReader(open(os.path.join(out, "grains.csv")))])


def main(argv):
    root = os.environ.get("GRAINFORCE_TEST_DATA")
    if not root:
        sys.exit("GRAINFORCE_TEST_DATA is not set: it names the folder holding real-photos/")
    binary = argv[argv.index("--grainforce") + 1] if "--grainforce" in argv else "target/release/grainforce"
    only = argv[argv.index("--only") + 1] if "--only" in argv else None
    print("| photo | disks edge-fitted | edge-fit rms residual [px] | grainforce − edge fit: median / p90 [R] "
          "| PeGS − edge fit: median / p90 [R] |")
    print("(rms residual: the median over the disks)", file=sys.stderr)
    print("|---|---|---|---|---|")
    for name, (image, centres, _, (rmin, rmax)) in PHOTOS.items():
        if only and name != only:
            continue
        folder = os.path.join(root, "real-photos", name)
        path = os.path.join(folder, image)
        ref = np.array([[float(v) for v in l.split(",")[:3]] for l in open(os.path.join(folder, centres))
                        if l.strip()])
        ref[:, :2] -= 1.0  # MATLAB's 1-based pixel centres
        d, level = colour_distance(path)
        ours = grainforce_centres(binary, path, rmin, rmax)
        off_ours, off_pegs, rms = [], [], []
        for x, y, r in ref:
            fit = edge_fit(d, level, x, y, r)
            if fit is None:
                continue
            cx, cy, rf, res = fit
            rms.append(res)
            k = np.argmin(np.hypot(ours[:, 0] - cx, ours[:, 1] - cy))
            if np.hypot(ours[k, 0] - cx, ours[k, 1] - cy) < 0.5 * rf:
                off_ours.append(np.hypot(ours[k, 0] - cx, ours[k, 1] - cy) / rf)
            off_pegs.append(np.hypot(x - cx, y - cy) / rf)
        q = lambda v, p: float(np.percentile(v, p)) if len(v) else float("nan")
        print("| %s | %d of %d | %.2f | %.3f / %.3f | %.3f / %.3f |" % (
            name, len(off_pegs), len(ref), q(rms, 50), q(off_ours, 50), q(off_ours, 90), q(off_pegs, 50), q(off_pegs, 90)),
            flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
