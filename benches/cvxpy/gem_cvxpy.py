#!/usr/bin/env python3
"""What a researcher would write instead of grainforce: the GEM problem (eq. 2.13)

    minimise ||K_st f - b_st||^2  s.t.  K_eq f = 0,  f_n >= 0,  |f_t| <= mu f_n

built with numpy/scipy from a grainforce scene folder and solved by cvxpy with
the Clarabel solver. Forces are unknown in global components (d per contact);
frictionless contacts (mu = 0) have no tangential force. The objective rows are
xx, yy[, zz], 2xy[, 2xz, 2yz] of V sigma = sum sym(r x f), as in grainforce, so
the minimiser is the same. Quasi-static scenes without gravity or accelerations
only (the benchmark's scenes).

Usage:
    python3 gem_cvxpy.py --setup            create .venv here, pip install cvxpy clarabel
    python3 gem_cvxpy.py SCENE_DIR -o forces.csv

Run with the venv's python for timing (grainforce bench --cvxpy does). Prints one
JSON line: read, build and solve times, total, status.
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, ".venv")
VENV_PY = os.path.join(VENV, "bin", "python")


def setup():
    check = [VENV_PY, "-c", "import cvxpy; assert 'CLARABEL' in cvxpy.installed_solvers()"]
    if os.path.exists(VENV_PY) and subprocess.call(check, stderr=subprocess.DEVNULL) == 0:
        return
    if not os.path.exists(VENV_PY):
        subprocess.check_call([sys.executable, "-m", "venv", VENV])
    subprocess.check_call([VENV_PY, "-m", "pip", "install", "--quiet", "--upgrade", "pip"])
    subprocess.check_call(
        [VENV_PY, "-m", "pip", "install", "--quiet", "cvxpy", "clarabel", "numpy", "scipy"]
    )
    subprocess.check_call(check)


def main():
    args = sys.argv[1:]
    if "--setup" in args:
        setup()
        return
    try:
        import cvxpy  # noqa: F401
    except ImportError:
        setup()
        os.execv(VENV_PY, [VENV_PY, os.path.abspath(__file__)] + args)
    if len(args) != 3 or args[1] not in ("-o", "--output"):
        sys.exit("usage: gem_cvxpy.py SCENE_DIR -o forces.csv")
    solve(args[0], args[2])


def solve(scene_dir, out_path):
    import csv

    import cvxpy as cp
    import numpy as np
    import scipy.sparse as sp

    t0 = time.perf_counter()
    with open(os.path.join(scene_dir, "grains.csv"), newline="") as fh:
        grains = list(csv.DictReader(fh))
    with open(os.path.join(scene_dir, "contacts.csv"), newline="") as fh:
        contacts = list(csv.DictReader(fh))
    settings = {}
    sj = os.path.join(scene_dir, "scene.json")
    if os.path.exists(sj):
        with open(sj) as fh:
            settings = json.load(fh)
    t_read = time.perf_counter() - t0

    t_build0 = time.perf_counter()
    dim = 3 if "z" in grains[0] else 2
    axes = ["x", "y", "z"][:dim]
    index = {g["id"]: i for i, g in enumerate(grains)}
    pos = np.array([[float(g[a]) for a in axes] for g in grains])
    vol = np.array([float(g["volume"]) for g in grains])
    if dim == 2:
        comps = ["s_xx", "s_yy", "s_xy"]
        pairs = [(0, 0), (1, 1), (0, 1)]
    else:
        comps = ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]
        pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    sig = np.array([[float(g.get(c) or 0.0) for c in comps] for g in grains])
    nc = len(contacts)
    a = np.array([index[c["a"]] for c in contacts])
    b = np.array([index.get(c["b"], -1) for c in contacts])
    point = np.array([[float(c[k]) for k in axes] for c in contacts])
    normal = np.array([[float(c["n_" + k]) for k in axes] for c in contacts])
    default_mu = settings.get("mu")
    mu = np.array(
        [float(c["mu"]) if c.get("mu") not in (None, "") else (default_mu if default_mu is not None else np.inf)
         for c in contacts]
    )
    ng = len(grains)
    ns = len(pairs)
    nm = 3 if dim == 2 else 6

    # Sparse K_st (ns rows per grain) and K_eq (nm rows per grain) over f (dim per contact).
    st_r, st_c, st_v, eq_r, eq_c, eq_v = [], [], [], [], [], []
    grain_b = b >= 0
    for grain, sign, mask in [(a, 1.0, np.ones(nc, bool)), (b, -1.0, grain_b)]:
        idx = np.nonzero(mask)[0]
        p = grain[idx]
        r = point[idx] - pos[p]
        for k in range(dim):  # unknown component k of contact idx
            col = dim * idx + k
            for m, (i, j) in enumerate(pairs):
                # diagonal rows: r_i f_i; off-diagonal rows: r_i f_j + r_j f_i (= 2 sym)
                val = np.zeros(len(idx))
                if j == k:
                    val += r[:, i]
                if i == k:
                    val += r[:, j]
                if i == j:
                    val *= 0.5
                st_r.append(ns * p + m); st_c.append(col); st_v.append(sign * val)
            # force rows
            eq_r.append(nm * p + k); eq_c.append(col); eq_v.append(np.full(len(idx), sign))
            # moment rows: r x e_k
            if dim == 2:
                val = r[:, 0] if k == 1 else -r[:, 1]
                eq_r.append(nm * p + 2); eq_c.append(col); eq_v.append(sign * val)
            else:
                e = np.zeros(3); e[k] = 1.0
                mom = np.cross(r, e)
                for j in range(3):
                    eq_r.append(nm * p + 3 + j); eq_c.append(col); eq_v.append(sign * mom[:, j])
    n = dim * nc
    K_st = sp.csr_matrix((np.concatenate(st_v), (np.concatenate(st_r), np.concatenate(st_c))), shape=(ns * ng, n))
    K_eq = sp.csr_matrix((np.concatenate(eq_v), (np.concatenate(eq_r), np.concatenate(eq_c))), shape=(nm * ng, n))
    rhs = vol[:, None] * sig
    rhs[:, dim:] *= 2.0  # 2 V sigma_xy etc.
    rhs = rhs.reshape(-1)

    # Only grains that have contacts carry equations.
    has = np.zeros(ng, bool)
    has[a] = True
    has[b[grain_b]] = True
    keep_st = np.repeat(has, ns)
    keep_eq = np.repeat(has, nm)
    K_st, rhs, K_eq = K_st[keep_st], rhs[keep_st], K_eq[keep_eq]

    f = cp.Variable(n)
    F = cp.reshape(f, (nc, dim), order="C")
    fn = -cp.sum(cp.multiply(F, normal), axis=1)  # compressive normal force
    cons = [K_eq @ f == 0, fn >= 0]
    # Tangential basis (2D: n rotated by +90 degrees; 3D: any orthonormal pair).
    if dim == 2:
        t1 = np.stack([-normal[:, 1], normal[:, 0]], axis=1)
        ft1 = cp.sum(cp.multiply(F, t1), axis=1)
        fr = np.isfinite(mu) & (mu == 0)
        co = np.isfinite(mu) & (mu > 0)
        if fr.any():
            cons.append(ft1[np.nonzero(fr)[0]] == 0)
        if co.any():
            ic = np.nonzero(co)[0]
            cons += [ft1[ic] <= cp.multiply(mu[ic], fn[ic]), -ft1[ic] <= cp.multiply(mu[ic], fn[ic])]
    else:
        helper = np.where(np.abs(normal[:, [0]]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        t1 = np.cross(normal, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(normal, t1)
        ft1 = cp.sum(cp.multiply(F, t1), axis=1)
        ft2 = cp.sum(cp.multiply(F, t2), axis=1)
        fr = np.isfinite(mu) & (mu == 0)
        co = np.isfinite(mu) & (mu > 0)
        if fr.any():
            i = np.nonzero(fr)[0]
            cons += [ft1[i] == 0, ft2[i] == 0]
        if co.any():
            i = np.nonzero(co)[0]
            cons.append(cp.SOC(cp.multiply(mu[i], fn[i]), cp.vstack([ft1[i], ft2[i]]), axis=0))
    prob = cp.Problem(cp.Minimize(cp.sum_squares(K_st @ f - rhs)), cons)
    t_build = time.perf_counter() - t_build0

    t_solve0 = time.perf_counter()
    prob.solve(solver=cp.CLARABEL)
    t_solve = time.perf_counter() - t_solve0
    if f.value is None:
        print(json.dumps({"status": prob.status}))
        sys.exit(f"cvxpy: {prob.status}")

    t3 = time.perf_counter()
    vals = f.value.reshape(nc, dim)
    with open(out_path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["contact"] + ["f_" + k for k in axes])
        for c, v in zip(contacts, vals):
            w.writerow([c["id"]] + [repr(float(x)) for x in v])
    t_write = time.perf_counter() - t3
    report = {
        "status": str(prob.status),
        "read_time": t_read,
        "build_time": t_build,
        "solve_time": t_solve,
        "write_time": t_write,
        "total": time.perf_counter() - t0,
        "solver_time_clarabel": float(prob.solver_stats.solve_time or 0.0),
        "iterations": int(prob.solver_stats.num_iters or 0),
    }
    print(json.dumps({k: (v if isinstance(v, str) else float(v)) for k, v in report.items()}))


if __name__ == "__main__":
    main()
