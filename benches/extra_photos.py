#!/usr/bin/env python3
"""Disk detection at the defaults (only --radius) on real photoelastic
photographs from other public repositories, against OpenCV's HoughCircles
with the issue's one parameter set, scored by the shared scorer (match.py).
Reproduces the "More real photographs" table of docs/image.md.

usage: GRAINFORCE_EXTRA_PHOTOS=/path/to/photos GRAINFORCE_TEST_DATA=/path/to/shared \\
           python3 benches/extra_photos.py [--grainforce target/release/grainforce] [NAME ...]

The photographs are not part of grainforce (nor is any reference made from
them): each is read from $GRAINFORCE_EXTRA_PHOTOS/NAME/image.* (the file at
SOURCE below, unchanged) with its reference centres in
$GRAINFORCE_EXTRA_PHOTOS/NAME/centers.txt (x,y,r,flag a line, MATLAB pixels,
as PeGS writes them): PeGS's own `particle` x, y, r from the repository's
`*_preprocessing.mat` where there is one, otherwise circles checked by eye
on an overlay (OpenCV's and grainforce's, corrected by hand). Needs numpy
and opencv-python-headless. Prints one Markdown row per photo and method.

To write a PeGS reference (needs scipy):
    python3 benches/extra_photos.py --centres-from-mat IMAGE_preprocessing.mat centers.txt
"""
import glob
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

# name: (source: repository @ commit : path, radius range a user gives)
# (the experimenters' radii widened by ~10 %, or measured on the photo).
JLIN = "github.com/Joe-Lin2002/Gsq_Method@f0065c8b"
WCHEN = "github.com/WilliamChennn/Photoelastic-Centroid-Aware-YOLOv8L@5173c035"
PHOTOS = {
    "jl-video181": (JLIN + ":DATA/video_trial/frame_181.jpg", (73, 96)),
    "jl-multi58": (JLIN + ":DATA/multi-points-compress/Image.jpg", (32, 45)),
    "jl-multi2": (JLIN + ":DATA/multi-points-compress/Image2.jpg", (35, 52)),
    "jl-frame197": (JLIN + ":DATA/image_calibration_test/frame_197.jpg", (27, 45)),
    "jl-colorcomp2": (JLIN + ":DATA/image_calibration_test/color_comp2.jpg", (113, 143)),
    "jl-forcecmp4": (JLIN + ":DATA/force_compare/image4.jpg", (42, 65)),
    "jl-static0765": (JLIN + ":DATA/static_verification/IMG_0765.jpg", (67, 110)),
    "wc-slope-a": (WCHEN + ":referimages/Rawimg.jpg", (15, 29)),
    "wc-slope-b": (WCHEN + ":referimages/baselineimage.png", (12, 24)),
}


# The same OpenCV parameter set and scene writer as the shared photographs' bench.
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from real_photos import opencv, write_scene  # noqa: E402


def score(match, scene, centres):
    import json

    out = subprocess.run([sys.executable, match, scene, centres, "--json"],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def row(name, method, s, seconds):
    false = s["det"] - s["matched"]
    return "| `%s` | %s | %d/%d (%d) | %.3f / %.3f R | %s |" % (
        name, method, s["matched"], s["ref"], false, s["centre_med_R"], s["centre_p90_R"],
        "%.2f s" % seconds if seconds is not None else "")


def centres_from_mat(mat, out):
    """PeGS 1.x `particle` struct array: x, y, r (MATLAB pixels) a line."""
    import scipy.io

    particles = scipy.io.loadmat(mat, squeeze_me=True, struct_as_record=False)["particle"]
    with open(out, "w") as f:
        for p in np.atleast_1d(particles):
            f.write("%.7f,%.7f,%g,0\n" % (p.x, p.y, p.r))


def main(argv):
    if argv[:1] == ["--centres-from-mat"]:
        centres_from_mat(argv[1], argv[2])
        return 0
    photos_dir = os.environ.get("GRAINFORCE_EXTRA_PHOTOS")
    shared = os.environ.get("GRAINFORCE_TEST_DATA")
    if not photos_dir or not shared:
        print("set GRAINFORCE_EXTRA_PHOTOS (the photographs) and GRAINFORCE_TEST_DATA "
              "(for real-photos/match.py); skipping")
        return 0
    match = os.path.join(shared, "real-photos", "match.py")
    grainforce = "target/release/grainforce"
    if "--grainforce" in argv:
        grainforce = argv[argv.index("--grainforce") + 1]
        argv = [a for a in argv if a not in ("--grainforce", grainforce)]
    names = argv or list(PHOTOS)
    print("| photo | method | disks found (false) | centre offset median / p90 | time |")
    print("|---|---|---|---|---|")
    for name in names:
        _, (lo, hi) = PHOTOS[name]
        folder = os.path.join(photos_dir, name)
        image = glob.glob(os.path.join(folder, "image.*"))[0]
        centres = os.path.join(folder, "centers.txt")
        with tempfile.TemporaryDirectory() as tmp:
            scene = os.path.join(tmp, "ours")
            t = time.time()
            run = subprocess.run([grainforce, "detect", image, "-o", scene, "--radius", "%d..%d" % (lo, hi)],
                                 capture_output=True, text=True)
            seconds = time.time() - t
            if run.returncode != 0:
                print("| `%s` | grainforce | failed: %s | | |" % (name, run.stderr.strip().splitlines()[-1]))
            else:
                print(row(name, "grainforce", score(match, scene, centres), seconds))
            t = time.time()
            height, circles = opencv(image, lo, hi)
            seconds = time.time() - t
            write_scene(os.path.join(tmp, "cv"), circles, height)
            print(row(name, "OpenCV", score(match, os.path.join(tmp, "cv"), centres), seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
