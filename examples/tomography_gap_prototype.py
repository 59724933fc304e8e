"""The numpy prototype behind docs/tomography.md "The grey gap at 15 voxels
per diameter" (round 12): the neck's two blurred balls fitted to the grey
of a volume `tomography_accuracy` wrote with TOMO_DUMP, with the true or
estimated geometry, levels and blur, a wider window without third grains,
and each grain's whole sphere fitted to the grey.

    TOMO_ONLY="fit, grey gap" TOMO_DUMP=/tmp/dump/s1 cargo run --release \
        --example tomography_accuracy -- fixtures/regression/box3d_gated 15 spheres
    python examples/tomography_gap_prototype.py /tmp/dump/s1 truth 1.038
    python examples/tomography_gap_prototype.py /tmp/dump/s1 neck 1.038 [--reach 9 --mask]
        [--true-radii] [--true-geometry] [--calibrate]
    python examples/tomography_gap_prototype.py /tmp/dump/s1 whole 1.038

σ = √(blur² + 15/192) (the blur of a voxel sub-sampled 4³); 0.754 for
TOMO_BLUR=0.7. Needs numpy and scipy. Prints the contacts' error and
the near misses' bias by band of true separation, and recall / precision
with the import's rule (median + 3 robust sd, the neck grey ≥ 0.9).
"""
import argparse
import csv

import numpy as np
from scipy.ndimage import binary_dilation, binary_erosion, find_objects
from scipy.optimize import least_squares
from scipy.special import erf


def ball(r, radius, sigma):
    """A ball blurred by a Gaussian, at distance r from its centre."""
    phi = lambda x: np.exp(-0.5 * x * x) / np.sqrt(2 * np.pi)
    cdf = lambda x: 0.5 * (1 + erf(x / np.sqrt(2)))
    r = np.maximum(r, 1e-9)
    return (cdf((radius - r) / sigma) - cdf((-radius - r) / sigma)
            + sigma / r * (phi((radius + r) / sigma) - phi((radius - r) / sigma)))


def load(d, name):
    grey = np.load(f"{d}/{name}_grey.npy")
    labels = np.load(f"{d}/{name}_labels.npy")
    zones = list(csv.DictReader(open(f"{d}/{name}_zones.csv")))
    spheres = np.array([[float(v) for v in r.values()]
                        for r in csv.DictReader(open(f"{d}/{name}_spheres.csv"))])
    return grey, labels, zones, spheres


def window(p, n, rr, grey, labels, pair, reach_k, mask):
    """The neck's voxels (as neck.rs: radius √(k r* σ) + 1, σ = 1), without
    those within two voxels of a third label when `mask`."""
    depth = 3.0 if reach_k <= 4 else 4.0
    reach = min(np.sqrt(reach_k * rr) + 1, 16)
    half = min(max(reach, depth + reach ** 2 / (2 * rr)), 16)
    nz, ny, nx = grey.shape
    lo = np.maximum(np.ceil(p - half), 0).astype(int)
    hi = np.minimum(np.floor(p + half), [nx - 1, ny - 1, nz - 1]).astype(int)
    box = tuple(slice(lo[k], hi[k] + 1) for k in (2, 1, 0))
    z, y, x = np.meshgrid(*[np.arange(lo[k], hi[k] + 1) for k in (2, 1, 0)], indexing="ij")
    P = np.stack([x.ravel(), y.ravel(), z.ravel()], 1).astype(float)
    d = P - p
    t = d @ n
    rho2 = (d * d).sum(1) - t * t
    keep = (rho2 <= reach ** 2) & (np.abs(t) <= depth + rho2 / (2 * rr))
    if mask:
        lab = labels[box]
        third = binary_dilation((lab != 0) & (lab != pair[0]) & (lab != pair[1]), iterations=2)
        keep &= ~third.ravel()
    return P[keep], grey[box].ravel()[keep].astype(float)


def fit_neck(P, G, p, n, ra, rb, sigma, void, solid):
    def residual(x):
        ca = p + (x[0] - x[1] / 2 - ra) * n
        cb = p + (x[0] + x[1] / 2 + rb) * n
        f = ball(np.linalg.norm(P - ca, axis=1), ra, sigma) + ball(np.linalg.norm(P - cb, axis=1), rb, sigma)
        return void + (solid - void) * f - G
    r = least_squares(residual, [0.0, 0.0], x_scale=0.1)
    cov = np.linalg.pinv(r.jac.T @ r.jac) * (r.fun @ r.fun / max(len(r.fun) - 2, 1))
    return r.x[1], np.sqrt(cov[1, 1])


def necks(args, grey, labels, zones, spheres):
    counts = np.bincount(labels.ravel())
    equivalent = (3 * counts / (4 * np.pi)) ** (1 / 3)
    rows = []
    for z in zones:
        a, b = int(z["a"]), int(z["b"])
        p = np.array([float(z[k]) for k in ("px", "py", "pz")])
        n = np.array([float(z[k]) for k in ("nx", "ny", "nz")])
        if args.true_geometry:
            ca, cb = spheres[a - 1, :3], spheres[b - 1, :3]
            n = (cb - ca) / np.linalg.norm(cb - ca)
            p = ca + n * (spheres[a - 1, 3] + 0.5 * (np.linalg.norm(cb - ca) - spheres[a - 1, 3] - spheres[b - 1, 3]))
        if args.true_radii or args.true_geometry:
            ra, rb = spheres[a - 1, 3], spheres[b - 1, 3]
        else:
            ra, rb = equivalent[a], equivalent[b]
        P, G = window(p, n, ra * rb / (ra + rb), grey, labels, (a, b), args.reach, args.mask)
        rows.append(dict(apart=float(z["apart"]), grey=float(z["grey"]), P=P, G=G, p=p, n=n, ra=ra, rb=rb))
    sigma, void, solid = args.sigma, 0.0, 1.0
    if args.calibrate:
        sigma, void, solid = calibrate(rows, grey, labels)
        print(f"calibrated: sigma {sigma:.2f}, void {void:.3f}, solid {solid:.3f}")
    out = []
    for r in rows:
        gap, sd = fit_neck(r["P"], r["G"], r["p"], r["n"], r["ra"], r["rb"], sigma, void, solid)
        out.append((r["apart"], gap, sd, r["grey"]))
    return np.array(out)


def calibrate(rows, grey, labels):
    """σ on a grid and the levels refitted with each neck's gap free, as
    neck.rs does (the source of the gap's absolute offset)."""
    sample = rows[:: max(1, len(rows) // 40)]
    best = None
    for sigma in (0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3):
        void, solid = grey[labels == 0].mean(), grey[labels > 0].mean()
        for _ in range(2):
            F, G = [], []
            for r in sample:
                gap, _ = fit_neck(r["P"], r["G"], r["p"], r["n"], r["ra"], r["rb"], sigma, void, solid)
                ca = r["p"] + (-gap / 2 - r["ra"]) * r["n"]
                cb = r["p"] + (gap / 2 + r["rb"]) * r["n"]
                F.append(ball(np.linalg.norm(r["P"] - ca, axis=1), r["ra"], sigma)
                         + ball(np.linalg.norm(r["P"] - cb, axis=1), r["rb"], sigma))
                G.append(r["G"])
            F, G = np.concatenate(F), np.concatenate(G)
            c = np.linalg.lstsq(np.vstack([np.ones_like(F), F]).T, G, rcond=None)[0]
            void, solid = c[0], c[0] + c[1]
        sse = np.sum((void + (solid - void) * F - G) ** 2)
        if best is None or sse < best[0]:
            best = (sse, sigma, void, solid)
    return best[1:]


def whole(args, grey, labels, zones):
    """Each grain's sphere (centre, radius) fitted to the grey of the voxels
    within 3 of its label surface and none within 2 of another label; the
    zone's gap from the two spheres, then combined with the neck's."""
    fits = {}
    for i, box in enumerate(find_objects(labels)):
        if box is None:
            continue
        lab = i + 1
        box = tuple(slice(max(s.start - 6, 0), min(s.stop + 6, labels.shape[k])) for k, s in enumerate(box))
        L = labels[box]
        me = L == lab
        shell = binary_dilation(me, iterations=3) & ~binary_erosion(me, iterations=3)
        shell &= ~binary_dilation((L != 0) & ~me, iterations=2)
        offset = np.array([s.start for s in box])
        P = (np.argwhere(shell) + offset)[:, ::-1].astype(float)
        G = grey[box][shell].astype(float)
        start = np.r_[(np.argwhere(me).mean(0) + offset)[::-1], (3 * me.sum() / (4 * np.pi)) ** (1 / 3)]
        r = least_squares(lambda x: ball(np.linalg.norm(P - x[:3], axis=1), x[3], args.sigma) - G, start, x_scale=0.1)
        fits[lab] = (r.x, np.linalg.pinv(r.jac.T @ r.jac) * (r.fun @ r.fun / max(len(r.fun) - 4, 1)))
    out = []
    for z in zones:
        (xa, ca), (xb, cb) = fits[int(z["a"])], fits[int(z["b"])]
        u = (xb[:3] - xa[:3]) / np.linalg.norm(xb[:3] - xa[:3])
        ja, jb = np.r_[-u, -1], np.r_[u, -1]
        out.append((float(z["apart"]), np.linalg.norm(xb[:3] - xa[:3]) - xa[3] - xb[3],
                    np.sqrt(ja @ ca @ ja + jb @ cb @ jb), float(z["grey"])))
    return np.array(out)


def report(o, label):
    contact = o[:, 0] < 0
    e = o[:, 1]
    med = np.median(e[contact])
    line = [f"{label}: contacts' gap {med:+.3f}, rms {np.std(e[contact]):.4f}, sd {np.median(o[:, 2]):.4f}"]
    for lo, hi in ((0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.5)):
        m = ~contact & (o[:, 0] >= lo) & (o[:, 0] < hi)
        if m.any():
            line.append(f"[{lo}, {hi}) n {m.sum()} bias {np.mean(e[m] - med - o[m, 0]):+.3f}")
    m = o[:, 0] < 0.5
    line.append(f"slope {np.polyfit(np.where(contact, 0, o[:, 0])[m], e[m], 1)[0]:.3f}")
    centre = np.median(e)
    spread = 1.4826 * np.median(np.abs(e - centre))
    keep = (o[:, 3] >= 0.9) & (e <= centre + 3 * np.maximum(spread, o[:, 2]))
    line.append(f"recall {keep[contact].mean():.3f} precision {contact[keep].mean():.3f}")
    print(" | ".join(line))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dump")
    ap.add_argument("what", choices=["truth", "neck", "whole"])
    ap.add_argument("sigma", type=float)
    ap.add_argument("--name", default="spheres15")
    ap.add_argument("--reach", type=float, default=4.0)
    ap.add_argument("--mask", action="store_true")
    ap.add_argument("--true-radii", action="store_true")
    ap.add_argument("--true-geometry", action="store_true")
    ap.add_argument("--calibrate", action="store_true")
    args = ap.parse_args()
    grey, labels, zones, spheres = load(args.dump, args.name)
    if args.what == "truth":
        # The model with the true spheres against the grey of the contacts' necks.
        res = []
        for z in zones:
            a, b = int(z["a"]), int(z["b"])
            if float(z["apart"]) >= 0:
                continue
            ca, cb = spheres[a - 1, :3], spheres[b - 1, :3]
            ra, rb = spheres[a - 1, 3], spheres[b - 1, 3]
            n = (cb - ca) / np.linalg.norm(cb - ca)
            P, G = window(ca + n * ra, n, ra * rb / (ra + rb), grey, labels, (a, b), 4.0, False)
            f = ball(np.linalg.norm(P - ca, axis=1), ra, args.sigma) + ball(np.linalg.norm(P - cb, axis=1), rb, args.sigma)
            res.append(G - f)
        res = np.concatenate(res)
        print(f"levels 0 / 1, sigma {args.sigma}: residual mean {res.mean():+.4f}, rms {res.std():.4f}")
        return
    o = necks(args, grey, labels, zones, spheres) if args.what == "neck" else whole(args, grey, labels, zones)
    report(o, f"{args.what}")
    if args.what == "whole":
        args.calibrate = False
        n = necks(args, grey, labels, zones, spheres)
        c = o[:, 0] < 0
        wa, wb = 1 / n[:, 2] ** 2, 1 / o[:, 2] ** 2
        gap = (wa * (n[:, 1] - np.median(n[:, 1])) + wb * (o[:, 1] - np.median(o[:, 1]))) / (wa + wb)
        report(np.c_[o[:, 0], gap, 1 / np.sqrt(wa + wb), o[:, 3]], "neck + whole")
        print(f"their errors' correlation on the contacts: {np.corrcoef(n[c, 1], o[c, 1])[0, 1]:+.2f}")


if __name__ == "__main__":
    main()
