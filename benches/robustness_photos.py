#!/usr/bin/env python3
"""Robustness sweep: `grainforce detect` (only --radius) on transformed copies
of every real photograph with a reference, imitating photographs nobody here
has seen (another camera, light of another colour, another scale, a crop).

usage: GRAINFORCE_TEST_DATA=/path/to/shared [GRAINFORCE_EXTRA_PHOTOS=/path/to/photos] \\
           python3 benches/robustness_photos.py [--grainforce target/release/grainforce]
           [--only NAME,NAME] [--transforms T,T] [--big] [--keep DIR]

Photographs: the shared five (benches/real_photos.py) and, when
GRAINFORCE_EXTRA_PHOTOS is set, those of benches/extra_photos.py. Each is
run as it is ("original") and after each transform below; the reference
centres (and PeGS's force-bearing contacts, shared photos only) are mapped
through the same transform and scored by the shared scorer (match.py: nearest
centre within half a radius, one to one). Radius ranges are scaled with the
picture. For a crop, the disks cut by the new border whose centre lies less
than half a radius inside it (or outside) are passed to match.py as --drop:
finding them is neither a hit nor a false disk. --big adds the 21-megapixel
copies (each photo up-sampled to 21 MP, plain and under red light) with wall
time, CPU time (user + system) and peak memory (GNU time's maximum
resident set size).

Needs numpy and opencv-python-headless. Transformed pictures are PNG (the
JPEG one decoded again), written to a temporary folder. Prints one Markdown
row per photo and transform, then the rows below target: recall or
precision < 0.98, or centres / contacts worse than on the photograph itself
and than the targets (0.035 / 0.075 R, 0.9). The `png` transform is the
control: the same pixels as OpenCV decodes the file (decoders differ by a
grey level here and there). docs/image.md, "Robustness sweep", has the
results.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import extra_photos  # noqa: E402
import real_photos  # noqa: E402

# Illuminants (B, G, R factors, OpenCV's channel order): a coloured light
# multiplies each channel of a white-light photograph.
ILLUMINANTS = {"red": (0.12, 0.22, 1.0), "orange": (0.15, 0.55, 1.0), "green": (0.25, 1.0, 0.3)}
TARGET_MEGAPIXELS = 21.0
SEED = 39


def photos():
    """(name, image, centres, contacts or None, (rmin, rmax))"""
    shared = os.path.join(os.environ["GRAINFORCE_TEST_DATA"], "real-photos")
    for name, (image, centres, contacts, radii) in real_photos.PHOTOS.items():
        folder = os.path.join(shared, name)
        yield name, os.path.join(folder, image), os.path.join(folder, centres), os.path.join(folder, contacts), radii
    extra = os.environ.get("GRAINFORCE_EXTRA_PHOTOS")
    if extra:
        for name, (_, radii) in extra_photos.PHOTOS.items():
            folder = os.path.join(extra, name)
            image = [f for f in os.listdir(folder) if f.startswith("image.")][0]
            yield name, os.path.join(folder, image), os.path.join(folder, "centers.txt"), None, radii


def resize(img, factor):
    import cv2

    h, w = img.shape[:2]
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    interp = cv2.INTER_AREA if factor < 1 else cv2.INTER_CUBIC
    out = cv2.resize(img, size, interpolation=interp)
    return out, (size[0] / w, size[1] / h)


def to_uint8(a):
    return np.clip(np.rint(a), 0, 255).astype(np.uint8)


def colour(img, fn):
    """fn on a colour picture; None (transform skipped) for a grey one."""
    return None if img.ndim == 2 else fn(img)


def jpeg(img, quality):
    import cv2

    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)


def crop_box(w, h):
    # a window off-centre, so each border cuts disks at a different phase
    return int(0.13 * w), int(0.09 * h), int(0.91 * w), int(0.95 * h)


def transform(img, kind):
    """(picture, map of (x, y, r) arrays in 0-based pixel centres, radius factor,
    crop box or None); None when the transform does not apply."""
    h, w = img.shape[:2]
    same = lambda x, y, r: (x, y, r)
    if kind == "png":  # the control: the same pixels as OpenCV decodes them, lossless
        return img, same, 1.0, None
    if kind == "rot90":  # clockwise
        return np.ascontiguousarray(np.rot90(img, -1)), lambda x, y, r: (h - 1 - y, x, r), 1.0, None
    if kind == "mirror":
        return np.ascontiguousarray(img[:, ::-1]), lambda x, y, r: (w - 1 - x, y, r), 1.0, None
    if kind.startswith("scale"):
        f = float(kind[5:])
        out, (sx, sy) = resize(img, f)
        return out, lambda x, y, r: ((x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5, r * sx), f, None
    if kind.startswith("gamma"):
        g = float(kind[5:])
        return to_uint8(255.0 * (img / 255.0) ** g), same, 1.0, None
    if kind == "swap-rb":
        return colour(img, lambda c: np.ascontiguousarray(c[:, :, ::-1])), same, 1.0, None
    if kind == "rotate-rgb":
        return colour(img, lambda c: np.ascontiguousarray(c[:, :, [1, 2, 0]])), same, 1.0, None
    if kind.startswith("light-"):
        tint = np.array(ILLUMINANTS[kind[6:]])
        return colour(img, lambda c: to_uint8(c * tint)), same, 1.0, None
    if kind == "jpeg40":
        return jpeg(img, 40), same, 1.0, None
    if kind == "noise3":
        rng = np.random.default_rng(SEED)
        return to_uint8(img + rng.normal(0.0, 0.03 * 255.0, img.shape)), same, 1.0, None
    if kind == "crop":
        x0, y0, x1, y1 = crop_box(w, h)
        return img[y0:y1, x0:x1].copy(), lambda x, y, r: (x - x0, y - y0, r), 1.0, (x1 - x0, y1 - y0)
    if kind.startswith("21mp"):
        f = float(np.sqrt(TARGET_MEGAPIXELS * 1e6 / (w * h)))
        out, (sx, sy) = resize(img, f)
        if kind == "21mp-red":
            out = colour(out, lambda c: to_uint8(c * np.array(ILLUMINANTS["red"])))
        return out, lambda x, y, r: ((x + 0.5) * sx - 0.5, (y + 0.5) * sy - 0.5, r * sx), f, None
    raise ValueError(kind)


TRANSFORMS = ["png", "rot90", "mirror", "scale0.5", "scale1.7", "gamma0.6", "gamma1.6", "swap-rb", "rotate-rgb",
              "light-red", "light-orange", "light-green", "jpeg40", "noise3", "crop"]
BIG = ["21mp", "21mp-red"]


def write_reference(tmp, centres, mapping, window):
    """The reference mapped through the transform, in MATLAB pixels (as
    match.py reads it), and the 1-based lines to drop (cut by a crop)."""
    a = np.loadtxt(centres, delimiter=",", ndmin=2)
    x, y, r = mapping(a[:, 0] - 1.0, a[:, 1] - 1.0, a[:, 2])
    path = os.path.join(tmp, "centres.txt")
    with open(path, "w") as f:
        for i in range(len(x)):
            f.write("%.4f,%.4f,%.4f,%g\n" % (x[i] + 1.0, y[i] + 1.0, r[i], a[i, 3] if a.shape[1] > 3 else 0))
    drop = []
    if window is not None:
        w, h = window
        inside = np.minimum.reduce([x + 0.5, y + 0.5, w - 0.5 - x, h - 0.5 - y])
        drop = [i + 1 for i in np.nonzero(inside < 0.5 * r)[0]]
    return path, drop


def score(match, scene, centres, contacts, drop, tmp):
    args = [sys.executable, match, scene, centres, "--json"]
    if contacts:
        args += ["--contacts", contacts]
    if drop:
        path = os.path.join(tmp, "drop.txt")
        with open(path, "w") as f:
            f.write("".join("%d\n" % i for i in drop))
        args += ["--drop", path]
    out = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def kept_contacts(contacts, drop, tmp):
    """PeGS's contacts between disks that stay whole in the picture."""
    if not contacts:
        return None
    dropped = set(drop)
    path = os.path.join(tmp, "contacts.csv")
    with open(contacts) as f, open(path, "w") as out:
        out.write(f.readline())
        for line in f:
            a, b = (int(v) for v in line.strip().split(",")[:2])
            if a not in dropped and b not in dropped:
                out.write(line)
    return path


def run_detect(binary, image, scene, radii, big):
    cmd = [binary, "-q", "detect", image, "-o", scene, "--radius", "%d..%d" % radii]
    if big:
        cmd = ["/usr/bin/time", "-f", "MAXRSS %M %U %S"] + cmd
    t = time.time()
    run = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.time() - t
    rss = cpu = None
    for line in run.stderr.splitlines():
        if line.startswith("MAXRSS"):
            rss = int(line.split()[1]) / 1024.0
            cpu = float(line.split()[2]) + float(line.split()[3])
    error = None if run.returncode == 0 else (run.stderr.strip().splitlines() or ["exit %d" % run.returncode])[-1]
    return seconds, cpu, rss, error


def row(name, kind, s, seconds, cpu, rss, failed, original):
    """The table row and what in it is below target: recall or precision
    < 0.98, or centres / contacts worse than on the untransformed photo
    (some references are off by more than the targets themselves: PeGS's
    own centre error, pairs PeGS lists with background between them)."""
    flags = []
    if failed:
        return "| `%s` | %s | failed: %s | | | | | |" % (name, kind, failed[:120]), ["failed"]
    if s["recall"] < 0.98:
        flags.append("recall %.3f" % s["recall"])
    if s["precision"] < 0.98:
        flags.append("precision %.3f" % s["precision"])
    base = original or s
    if (s["centre_med_R"] > max(0.035, base["centre_med_R"] + 0.01)
            or s["centre_p90_R"] > max(0.075, base["centre_p90_R"] + 0.02)):
        flags.append("centres %.3f / %.3f R" % (s["centre_med_R"], s["centre_p90_R"]))
    contacts = s.get("contact_recall")
    if contacts is not None and contacts < min(0.9, base["contact_recall"] - 0.05):
        flags.append("contacts %.2f" % contacts)
    text = "| `%s` | %s | %.3f (%d/%d) | %.3f (%d false) | %.3f / %.3f | %s | %s | %s |" % (
        name, kind, s["recall"], s["matched"], s["ref"], s["precision"], s["det"] - s["matched"],
        s["centre_med_R"], s["centre_p90_R"], "%.2f" % contacts if contacts is not None else "",
        "%.2f" % seconds + (" (CPU %.2f)" % cpu if cpu is not None else ""), "%.0f" % rss if rss is not None else "")
    return text, flags


def option(argv, name, default=None):
    return argv[argv.index(name) + 1] if name in argv else default


def main(argv):
    import cv2

    if not os.environ.get("GRAINFORCE_TEST_DATA"):
        print("GRAINFORCE_TEST_DATA is not set (the folder holding real-photos/): skipping")
        return 0
    match = os.path.join(os.environ["GRAINFORCE_TEST_DATA"], "real-photos", "match.py")
    binary = option(argv, "--grainforce", "target/release/grainforce")
    only = option(argv, "--only")
    kinds = ["original"] + TRANSFORMS + (BIG if "--big" in argv else [])
    if option(argv, "--transforms"):
        kinds = option(argv, "--transforms").split(",")
    keep = option(argv, "--keep")
    print("| photo | transform | recall | precision | centre median / p90 [R] | PeGS contacts | time [s] | peak MB |")
    print("|---|---|---|---|---|---|---|---|")
    below = []
    for name, image, centres, contacts, (rmin, rmax) in photos():
        if only and name not in only.split(","):
            continue
        img = cv2.imread(image, cv2.IMREAD_UNCHANGED)
        if img.ndim == 3 and img.shape[2] == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        original = None
        for kind in kinds:
            with tempfile.TemporaryDirectory(dir=keep) as tmp:
                if kind == "original":
                    path, mapping, factor, window = image, (lambda x, y, r: (x, y, r)), 1.0, None
                else:
                    out = transform(img, kind)
                    if out[0] is None:
                        continue
                    picture, mapping, factor, window = out
                    path = os.path.join(tmp, "image.png")
                    cv2.imwrite(path, picture, [cv2.IMWRITE_PNG_COMPRESSION, 1])
                ref, drop = write_reference(tmp, centres, mapping, window)
                radii = (int(np.floor(rmin * factor)), int(np.ceil(rmax * factor)))
                scene = os.path.join(tmp, "scene")
                seconds, cpu, rss, failed = run_detect(binary, path, scene, radii, kind.startswith("21mp"))
                s = None if failed else score(match, scene, ref, kept_contacts(contacts, drop, tmp), drop, tmp)
                text, flags = row(name, kind, s, seconds, cpu, rss, failed, original)
                if kind == "original":
                    original = s
                print(text, flush=True)
                if flags:
                    below.append("%s %s: %s" % (name, kind, ", ".join(flags)))
    print("\nbelow target (%d rows):" % len(below))
    for line in below:
        print("-", line)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
