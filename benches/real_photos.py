#!/usr/bin/env python3
"""Disk detection on the shared real photographs: grainforce against what a
user would pick instead (OpenCV's HoughCircles and scikit-image's Hough
transform, one parameter set each for every photo), scored against the
experimenters' PeGS answers with the shared scorer (match.py).

usage: GRAINFORCE_TEST_DATA=/path/to/shared python3 benches/real_photos.py \
           [--grainforce target/release/grainforce] [--only NAME] [--keep DIR]

Needs numpy, opencv-python-headless and scikit-image (pip, in a virtual
environment). The photographs are not part of grainforce: they are read from
$GRAINFORCE_TEST_DATA/real-photos. Prints one Markdown table row per photo and
method: disks recall / precision, centre offset median / p90 (in radii),
the share of PeGS's force-bearing contacts found (for the Hough circles: the
pairs whose circles come within CONTACT_GAP of the smaller radius, the
fixed-gap rule a user would write; they give no other evidence), the number
of disk-disk contacts written and wall time.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

# name: (image, reference centres, reference contacts, radius range the user gives)
# The ranges are the experimenters' radii widened by ~10 % (what one would type).
PHOTOS = {
    "pegs2-step09": ("Step09-0001.tif", "Step09-0001_centers.txt", "Step09-0001_contacts_ref.csv", (45, 80)),
    "jlin-fixed48": ("image2.jpg", "image2_centers.txt", "image2_contacts_ref.csv", (28, 42)),
    "jlin-narrow21": ("image.jpg", "image_centers.txt", "image_contacts_ref.csv", (59, 78)),
    "jlin-step83": ("image3.jpg", "image3_centers.txt", "image3_contacts_ref.csv", (27, 39)),
    "jlin-iphone83": ("image4.jpg", "image4_centers.txt", "image4_contacts_ref.csv", (66, 90)),
}


# Circles closer than this fraction of the smaller radius touch (Hough only).
CONTACT_GAP = 0.1


def write_scene(folder, circles, height):
    """A scene folder as `detect` writes it (pixels, y up), for match.py,
    with the pairs closer than CONTACT_GAP as contacts."""
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, "grains.csv"), "w") as f:
        f.write("id,x,y,volume,radius\n")
        for i, (x, y, r) in enumerate(circles):
            f.write("%d,%.4f,%.4f,%.4f,%.4f\n" % (i, x + 0.5, height - 0.5 - y, np.pi * r * r, r))
    with open(os.path.join(folder, "image-frame.json"), "w") as f:
        json.dump({"px_per_m": 1.0, "origin": [0.0, 0.0], "width": 0, "height": height}, f)
    with open(os.path.join(folder, "contacts.csv"), "w") as f:
        f.write("id,a,b\n")
        k = 0
        for i, (xa, ya, ra) in enumerate(circles):
            for j in range(i + 1, len(circles)):
                xb, yb, rb = circles[j]
                if np.hypot(xb - xa, yb - ya) - ra - rb <= CONTACT_GAP * min(ra, rb):
                    f.write("%d,%d,%d\n" % (k, i, j))
                    k += 1


def opencv(path, rmin, rmax):
    import cv2

    img = cv2.imread(path, cv2.IMREAD_COLOR)
    red = cv2.GaussianBlur(img[:, :, 2], (0, 0), 1.0)
    c = cv2.HoughCircles(red, cv2.HOUGH_GRADIENT, dp=1, minDist=1.5 * rmin,
                         param1=20, param2=30, minRadius=rmin, maxRadius=rmax)
    return img.shape[0], [] if c is None else [tuple(map(float, v)) for v in c[0]]


def skimage_hough(path, rmin, rmax):
    from skimage import feature, io, transform

    img = io.imread(path)
    red = img[:, :, 0].astype(float) / 255.0
    edges = feature.canny(red, sigma=2.0)
    radii = np.arange(rmin, rmax + 1)
    acc = transform.hough_circle(edges, radii)
    _, cx, cy, r = transform.hough_circle_peaks(acc, radii, min_xdistance=int(1.5 * rmin),
                                                min_ydistance=int(1.5 * rmin), threshold=0.35)
    return img.shape[0], list(zip(cx.astype(float), cy.astype(float), r.astype(float)))


def score(match, scene, folder, name):
    _, centres, refc, _ = PHOTOS[name]
    args = [sys.executable, match, scene, os.path.join(folder, centres), "--json",
            "--contacts", os.path.join(folder, refc)]
    out = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv):
    root = os.environ.get("GRAINFORCE_TEST_DATA")
    if not root:
        sys.exit("GRAINFORCE_TEST_DATA is not set: it names the folder holding real-photos/")
    photos = os.path.join(root, "real-photos")
    match = os.path.join(photos, "match.py")
    binary = argv[argv.index("--grainforce") + 1] if "--grainforce" in argv else "target/release/grainforce"
    only = argv[argv.index("--only") + 1] if "--only" in argv else None
    keep = argv[argv.index("--keep") + 1] if "--keep" in argv else tempfile.mkdtemp()
    print("| photo | method | recall | precision | centre median / p90 [R] | PeGS contacts found | contacts | time [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (image, _, _, (rmin, rmax)) in PHOTOS.items():
        if only and name != only:
            continue
        folder = os.path.join(photos, name)
        path = os.path.join(folder, image)
        scene = os.path.join(keep, name, "grainforce")
        t = time.time()
        subprocess.run([binary, "-q", "detect", path, "-o", scene, "--radius", "%d..%d" % (rmin, rmax)],
                       check=True)
        rows = [("grainforce", score(match, scene, folder, name), time.time() - t)]
        for method, find in (("OpenCV HoughCircles", opencv), ("scikit-image hough_circle", skimage_hough)):
            t = time.time()
            height, circles = find(path, rmin, rmax)
            elapsed = time.time() - t
            out = os.path.join(keep, name, method.split()[0])
            write_scene(out, circles, height)
            rows.append((method, score(match, out, folder, name), elapsed))
        for method, m, elapsed in rows:
            print("| %s | %s | %.2f (%d/%d) | %.2f (%d false) | %.3f / %.3f | %.2f | %d | %.2f |" % (
                name, method, m["recall"], m["matched"], m["ref"], m["precision"], m["det"] - m["matched"],
                m["centre_med_R"], m["centre_p90_R"], m["contact_recall"], m["det_contacts"], elapsed),
                flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
