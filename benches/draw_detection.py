#!/usr/bin/env python3
"""Draws what `grainforce detect` found, without the photograph's pixels:
outlines, centres and contacts on a plain background (force-bearing contacts
red and thick, other touching pairs grey), for documentation pictures of
photographs that are not ours to ship.

usage: python3 benches/draw_detection.py SCENE_DIR OUT.png [--scale 0.6]
Needs numpy and opencv-python-headless.
"""
import csv
import json
import os
import sys

import cv2
import numpy as np


def main(argv):
    scene, out = argv[0], argv[1]
    scale = float(argv[argv.index("--scale") + 1]) if "--scale" in argv else 1.0
    frame = json.load(open(os.path.join(scene, "image-frame.json")))
    s, (x0, y0), w, h = frame["px_per_m"], frame["origin"], frame["width"], frame["height"]
    px = lambda x, y: ((x - x0) * s - 0.5, h - 0.5 - (y - y0) * s)
    grains = {}
    for r in csv.DictReader(open(os.path.join(scene, "grains.csv"))):
        grains[r["id"]] = (*px(float(r["x"]), float(r["y"])), float(r["radius"]) * s)
    canvas = np.full((int(h * scale), int(w * scale), 3), 255, np.uint8)
    sub = 4  # sub-pixel drawing
    p = lambda x, y: (int(round(x * scale * (1 << sub))), int(round(y * scale * (1 << sub))))
    for x, y, r in grains.values():
        cv2.circle(canvas, p(x, y), int(round(r * scale * (1 << sub))), (90, 90, 90), 1, cv2.LINE_AA, sub)
        cv2.circle(canvas, p(x, y), 2 << sub, (0, 0, 0), -1, cv2.LINE_AA, sub)
    for r in csv.DictReader(open(os.path.join(scene, "contacts-evidence.csv"))):
        if r["contact"] == "" or r["b"] not in grains:
            continue
        (xa, ya, _), (xb, yb, _) = grains[r["a"]], grains[r["b"]]
        bearing = r.get("force_bearing") == "yes"
        colour, width = ((40, 40, 220), 3) if bearing else ((170, 170, 170), 1)
        cv2.line(canvas, p(xa, ya), p(xb, yb), colour, width, cv2.LINE_AA, sub)
    cv2.imwrite(out, canvas, [cv2.IMWRITE_PNG_COMPRESSION, 9])


if __name__ == "__main__":
    main(sys.argv[1:])
