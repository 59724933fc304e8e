"""The Python package against the CLI, the DEM's exact forces and bad input.

The CLI binary comes from GRAINFORCE_BIN (python/ci.sh sets it), else from
PATH; without it the comparison with the CLI fails rather than skips.
"""

import json
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import grainforce as gf

REPO = Path(__file__).resolve().parents[2]
OEDOMETER = REPO / "fixtures" / "oedometer"
IDS = {"id": str, "a": str, "b": str, "wall": str, "contact": str}


def cli():
    binary = os.environ.get("GRAINFORCE_BIN") or shutil.which("grainforce")
    if not binary:
        pytest.fail("set GRAINFORCE_BIN to the grainforce binary (python/ci.sh does)")
    return binary


def run_cli(scene_dir, tmp_path, *flags):
    out, report = tmp_path / "forces.csv", tmp_path / "report.json"
    subprocess.run(
        [cli(), "infer", str(scene_dir), "-o", str(out), "--report", str(report), "--quiet", *flags],
        check=True,
    )
    return pd.read_csv(out, dtype=IDS), json.loads(report.read_text())


def oedometer_tables():
    grains = pd.read_csv(OEDOMETER / "grains.csv", dtype=IDS)
    contacts = pd.read_csv(OEDOMETER / "contacts.csv", dtype=IDS)
    walls = pd.read_csv(OEDOMETER / "walls.csv", dtype=IDS)
    meta = json.loads((OEDOMETER / "scene.json").read_text())
    return grains, contacts, walls, meta


def assert_same_forces(got, expected, tolerance=1e-12):
    assert list(got.columns) == list(expected.columns)
    assert list(got["contact"]) == list(expected["contact"])
    components = [c for c in expected.columns if c.startswith("f_")]
    scale = np.abs(expected[components].to_numpy()).max()
    gap = np.abs(got[components].to_numpy() - expected[components].to_numpy()).max()
    assert gap <= tolerance * scale, f"largest gap {gap:.3e} (scale {scale:.3e})"


@pytest.mark.parametrize(
    "method, options, flags",
    [
        ("qs", {}, []),
        ("tikhonov", {"lambda_": 2e-4, "mu": 0.4}, ["--lambda", "2e-4", "--mu", "0.4"]),
        ("tikhonov", {"lambda_precision": "fine"}, ["--lambda-precision", "fine"]),
        ("ls", {}, []),
        ("scaled", {"solver": "interior_point"}, ["--solver", "interior-point"]),
        ("qs", {"ordering": "nested_dissection", "cone": "exact"}, ["--ordering", "nested-dissection"]),
    ],
)
def test_dataframes_in_and_out_match_the_cli(tmp_path, method, options, flags):
    grains, contacts, walls, meta = oedometer_tables()
    scene = gf.Scene.from_frames(grains, contacts, walls, **meta)
    assert (scene.dim, scene.n_grains, scene.n_contacts) == (2, len(grains), len(contacts))
    result = gf.infer(scene, method=method, **options)
    expected, report = run_cli(OEDOMETER, tmp_path, "--method", method, *flags)
    assert isinstance(result.forces, pd.DataFrame)
    assert_same_forces(result.forces, expected)
    assert result.report["time_fit"] is None and result.report["uncertainty"] is None
    (frame,) = result.report["frames"]
    assert frame.keys() == report.keys()
    timings = {"time", "solver_time"}
    for key in report.keys() - timings:
        assert_close(frame[key], report[key], key)


def assert_close(got, expected, where):
    """Same structure, text and flags; numbers to 1e-12."""
    if isinstance(expected, float) and not isinstance(expected, bool):
        assert got == pytest.approx(expected, rel=1e-12, abs=1e-300), where
    elif isinstance(expected, dict):
        assert got.keys() == expected.keys(), where
        for k in expected:
            assert_close(got[k], expected[k], f"{where}.{k}")
    elif isinstance(expected, list):
        assert len(got) == len(expected), where
        for k, (g, e) in enumerate(zip(got, expected)):
            assert_close(g, e, f"{where}[{k}]")
    else:
        assert got == expected, where


def test_dicts_of_arrays_in_dataframes_out():
    grains, contacts, walls, meta = oedometer_tables()
    expected = gf.infer(gf.read_scene(OEDOMETER)).forces
    as_dict = lambda df: {c: df[c].to_numpy() for c in df.columns}
    scene = gf.Scene.from_frames(as_dict(grains), as_dict(contacts), as_dict(walls), **meta)
    forces = gf.infer(scene).forces
    assert isinstance(forces, pd.DataFrame) and list(forces) == ["contact", "f_x", "f_y"]
    assert_same_forces(forces, expected, tolerance=0.0)
    back, _, _ = scene.to_frames()
    assert isinstance(back, pd.DataFrame)
    assert np.array_equal(back["s_xx"].to_numpy(), grains["s_xx"].to_numpy())


def test_scene_round_trips_through_frames(tmp_path):
    scene = gf.read_scene(OEDOMETER)
    grains, contacts, walls = scene.to_frames()
    original, _, _, _ = oedometer_tables()
    assert list(grains["id"]) == list(original["id"])
    assert np.array_equal(grains["x"].to_numpy(), original["x"].to_numpy())
    scene.save(tmp_path / "copy")
    # Not bit for bit: the reader normalises the normals it then writes.
    assert_same_forces(gf.infer(gf.read_scene(tmp_path / "copy")).forces, gf.infer(scene).forces)


def test_dem_forces_are_recovered():
    run = gf.dem("oedometer", seed=3)
    assert run.report["passed"] and run.report["grains"] == run.scene.n_grains
    result = gf.infer(run.scene, method="qs")
    assert_same_forces(result.forces, run.forces, tolerance=1e-6)


def test_packing_forces_are_recovered():
    scene, truth = gf.packing(dim=3, grains=200, seed=2)
    assert scene.dim == 3
    assert_same_forces(gf.infer(scene, method="ls").forces, truth, tolerance=1e-8)


def test_sequence_with_progress_recovers_the_dem_forces():
    run = gf.dem("impact", duration=0.004)
    assert len(run.scene) > 10 and run.scene.frames[0] == 0
    calls = []
    result = gf.infer(run.scene, method="dynamic", progress=lambda done, total: calls.append((done, total)))
    assert sorted(calls) == [(k, len(run.scene)) for k in range(1, len(run.scene) + 1)]
    assert list(result.forces.columns) == ["frame", "contact", "f_x", "f_y"]
    assert len(result.report["frames"]) == len(run.scene)
    truth = run.forces
    assert list(result.forces["frame"]) == list(truth["frame"])
    assert_same_forces(result.forces, truth, tolerance=1e-6)
    # A frame range picks frames as --frames does.
    part = gf.infer(run.scene, method="dynamic", frames=(2, 4))
    assert sorted(set(part.forces["frame"])) == [2, 3, 4]


def test_progress_callback_errors_propagate():
    run = gf.dem("impact", duration=0.002)

    def broken(done, total):
        raise KeyError("from the callback")

    with pytest.raises(KeyError, match="from the callback"):
        gf.infer(run.scene, method="dynamic", progress=broken)


def disks_image(centres, radius, shape=(120, 160), supersample=4):
    """Bright antialiased disks on a dark background (rows are y; pixel (j, i)
    is centred at x = j, y = i, as in scikit-image)."""
    h, w = shape
    ys = (np.arange(h * supersample) + 0.5) / supersample - 0.5
    xs = (np.arange(w * supersample) + 0.5) / supersample - 0.5
    inside = np.zeros((h * supersample, w * supersample), dtype=bool)
    for cx, cy in centres:
        inside |= (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2 <= radius**2
    fine = np.where(inside, 0.8, 0.2)
    return fine.reshape(h, supersample, w, supersample).mean(axis=(1, 3))


def test_detect_finds_disks_in_an_array():
    centres = [(40.3, 35.7), (110.6, 40.2), (60.1, 85.4)]
    found = gf.detect(disks_image(centres, 15.0), radius=(10, 20))
    assert len(found) == 3
    for cx, cy in centres:
        d = np.hypot(found["x"] - cx, found["y"] - cy)
        k = int(np.argmin(d))
        assert d[k] < 0.2, (cx, cy, d[k])
        assert abs(found["r"][k] - 15.0) < 0.2


def test_bad_input_raises_with_the_library_message(tmp_path):
    with pytest.raises(FileNotFoundError, match="no-such-scene"):
        gf.read_scene(tmp_path / "no-such-scene")
    grains, contacts, walls, meta = oedometer_tables()
    bad = grains.astype({"s_xx": object})
    bad.loc[3, "s_xx"] = "abc"
    with pytest.raises(ValueError, match=r"grains\.csv, line 5, column `s_xx`") as info:
        gf.Scene.from_frames(bad, contacts, walls, **meta)
    assert "grainforce-" not in str(info.value)  # no temporary folder in the message
    with pytest.raises(ValueError, match="unknown field"):
        gf.Scene.from_frames(grains, contacts, walls, friction=0.5)
    scene = gf.read_scene(OEDOMETER)
    with pytest.raises(ValueError, match=r"^tolerance must lie in \(0, 1\), got 2"):
        gf.infer(scene, tolerance=2.0)
    with pytest.raises(ValueError, match="unknown variant `fast`"):
        gf.infer(scene, method="fast")
    with pytest.raises(ValueError, match="unknown variant `active-set`"):
        gf.infer(scene, solver="active-set")  # values are snake_case
    with pytest.raises(ValueError, match="time_fit='joint' fits momentum over time: use it with method='dynamic'"):
        gf.infer(scene, time_fit="joint", fps=100.0)
    with pytest.raises(ValueError, match="impulse needs the frame rate: give fps"):
        gf.infer(scene, impulse=True)
    with pytest.raises(TypeError, match="unexpected keyword argument 'colour'"):
        gf.infer(scene, colour="red")
    with pytest.raises(TypeError, match="unexpected keyword argument 'output'"):
        gf.infer(scene, output="forces.csv")
    with pytest.raises(ValueError, match="2 or 3"):
        gf.dem("oedometer", dim=4)
    with pytest.raises(ValueError, match="unknown DEM preset"):
        gf.dem("sandpile")
    with pytest.raises(ValueError, match="radius range"):
        gf.detect(np.zeros((50, 50)), radius=(5, 3))
    with pytest.raises(ValueError, match="2D"):
        gf.detect(np.zeros(50), radius=(5, 8))
    # An explicit hard-balance method fails on data no force set balances
    # (the default would switch to soft equilibrium instead).
    with pytest.raises(gf.InfeasibleError, match="μ too small"):
        gf.infer(sideways_loaded_disk(), method="qs", mu=1e-3)
    # allow_infeasible: the least-violation answer, momentum left unbalanced.
    loose = gf.infer(sideways_loaded_disk(), method="qs", mu=1e-3, allow_infeasible=True)
    assert loose.report["frames"][0]["momentum_residual"] > 1


def sideways_loaded_disk():
    """A disk on two supports ±30° from the vertical under a nearly horizontal
    body force: only friction (μ ≳ 1.4) could hold it."""
    a, r = np.radians(30), np.sqrt(0.01 / np.pi)
    normals = np.array([[-np.sin(a), -np.cos(a)], [np.sin(a), -np.cos(a)]])
    grains = {"id": [1], "x": [0.0], "y": [0.0], "volume": [0.01], "s_xx": [0.0],
              "s_yy": [0.0], "s_xy": [0.0], "mass": [0.1]}
    contacts = {"id": ["c1", "c2"], "a": [1, 1], "b": ["left", "right"],
                "x": r * normals[:, 0], "y": r * normals[:, 1],
                "n_x": normals[:, 0], "n_y": normals[:, 1]}
    return gf.Scene.from_frames(grains, contacts, gravity=[-9.81, -1.0])


def sideways_loaded_disks(mus):
    """sideways_loaded_disk, one frame per μ: a small μ parses like the
    others, but only the solver finds that no force set balances it."""
    a, r = np.radians(30), np.sqrt(0.01 / np.pi)
    normals = np.array([[-np.sin(a), -np.cos(a)], [np.sin(a), -np.cos(a)]])
    n = len(mus)
    grains = {"frame": np.arange(n), "id": [1] * n, "x": np.zeros(n), "y": np.zeros(n),
              "volume": np.full(n, 0.01), "s_xx": np.zeros(n), "s_yy": np.zeros(n),
              "s_xy": np.zeros(n), "mass": np.full(n, 0.1)}
    contacts = {"frame": np.repeat(np.arange(n), 2), "id": ["c1", "c2"] * n, "a": [1] * (2 * n),
                "b": ["left", "right"] * n, "x": np.tile(r * normals[:, 0], n),
                "y": np.tile(r * normals[:, 1], n), "n_x": np.tile(normals[:, 0], n),
                "n_y": np.tile(normals[:, 1], n), "mu": np.repeat(np.asarray(mus, float), 2)}
    return gf.Scene.from_frames(grains, contacts, gravity=[-9.81, -1.0])


def test_a_failed_frame_warns_and_the_others_are_kept():
    scene = sideways_loaded_disks([2.0, 2.0, 1e-3, 2.0])
    calls = []
    with pytest.warns(gf.FrameFailureWarning, match="μ too small"):
        result = gf.infer(scene, method="qs", progress=lambda done, total: calls.append((done, total)))
    assert calls == [(k, 4) for k in range(1, 5)]
    assert [frame for frame, _ in result.failed_frames] == [2]
    assert "μ too small" in result.failed_frames[0][1]
    assert sorted(set(result.forces["frame"])) == [0, 1, 3]
    # Each kept frame balances its disk: Σ f = −m g.
    forces = result.forces.groupby("frame")[["f_x", "f_y"]].sum()
    np.testing.assert_allclose(forces.to_numpy(), [[0.981, 0.1]] * 3, atol=1e-6)
    frames = result.report["frames"]
    assert [entry["frame"] for entry in frames] == [0, 1, 2, 3]
    assert "μ too small" in frames[2]["error"] and "error" not in frames[0]
    with pytest.raises(gf.InfeasibleError, match="frame 2"):
        gf.infer(scene, method="qs", stop_on_failure=True)


def test_python_runs_while_a_sequence_solves():
    """The solves run with the GIL released: while a sequence is inferred in
    another thread, the main thread runs Python. A handshake, not a timing:
    the first frame's progress callback waits until the main thread has
    taken three turns, so the inference cannot end before they happen (with
    the GIL held by the solve, the callback, which takes the GIL from a
    solving thread, could not even start)."""
    run = gf.dem("impact", duration=0.004)
    turns = [0]
    main_turned = threading.Event()
    seen = []

    def progress(done, total):
        if done == 1:
            if not main_turned.wait(timeout=600):
                raise RuntimeError("the main thread never ran during the solve")
            seen.append(turns[0])

    results = []
    errors = []

    def solve():
        try:
            results.append(gf.infer(run.scene, method="dynamic", progress=progress))
        except Exception as e:  # reported below
            errors.append(e)

    worker = threading.Thread(target=solve)
    worker.start()
    while worker.is_alive():
        turns[0] += 1
        if turns[0] == 3:
            main_turned.set()
        time.sleep(0.001)
    worker.join()
    assert not errors, errors
    assert len(results) == 1 and len(results[0].report["frames"]) == len(run.scene)
    assert seen and seen[0] >= 3, seen


def test_missing_cells_and_an_id_index():
    grains, contacts, walls, meta = oedometer_tables()
    expected = gf.infer(gf.read_scene(OEDOMETER)).forces
    contacts.loc[[0, 5], "mu"] = np.nan  # empty cells: the scene's μ (0.5) applies
    assert meta["mu"] == 0.5
    scene = gf.Scene.from_frames(grains.set_index("id"), contacts, walls, **meta)
    assert_same_forces(gf.infer(scene).forces, expected)
    with pytest.raises(ValueError, match="`mu`"):
        gf.Scene.from_frames(grains, contacts.assign(mu=-1.0), walls)


def impact_scene(tmp_path):
    """The impact preset with 0.1 % of a diameter of position noise, saved."""
    run = gf.dem("impact", duration=0.01)
    folder = tmp_path / "impact"
    run.scene.save(folder)
    # The noise comes from the CLI's own perturb, so both sides read one folder.
    noisy = tmp_path / "noisy"
    subprocess.run(
        [cli(), "-q", "perturb", str(folder), "-o", str(noisy), "--position-noise", "4.445e-5", "--seed", "4"],
        check=True,
    )
    return noisy


@pytest.mark.parametrize(
    "options, flags",
    [
        ({"time_fit": "joint", "impulse": True}, ["--time-fit", "joint"]),
        ({"uncertainty": 4, "noise_level": 0.1, "impulse": True, "impulse_window": 11, "frames": (5, 45)},
         ["--uncertainty", "4", "--noise-level", "0.1", "--impulse-window", "11", "--frames", "5..45"]),
        ({"lambda_rule": "knee", "pareto": True, "sweep_points": 7, "frames": (20, 22)},
         ["--lambda-rule", "knee", "--sweep-points", "7", "--frames", "20..22"]),
    ],
)
def test_time_fit_uncertainty_impulse_and_pareto_match_the_cli_byte_for_byte(tmp_path, options, flags):
    scene = impact_scene(tmp_path)
    common = {"method": "dynamic", "fps": 5000.0, "derive_accelerations": True}
    result = gf.infer(scene, **common, **options)
    mine, theirs = tmp_path / "py", tmp_path / "cli"
    mine.mkdir(), theirs.mkdir()
    names = ["forces.csv"]
    kwargs = {}
    cli_flags = ["--method", "dynamic", "--fps", "5000", "--derive-accelerations", *flags]
    if options.get("impulse"):
        names.append("impulse.csv")
        kwargs["impulse"] = mine / "impulse.csv"
        cli_flags += ["--impulse", str(theirs / "impulse.csv")]
        assert list(result.impulse.columns)[:3] == ["grain", "first_frame", "last_frame"]
    if options.get("pareto"):
        names.append("pareto.csv")
        kwargs["pareto"] = mine / "pareto.csv"
        cli_flags += ["--pareto", str(theirs / "pareto.csv")]
        assert len(result.pareto) == 7 and result.pareto["knee"].sum() == 1
    result.save(mine / "forces.csv", **kwargs)
    subprocess.run([cli(), "-q", "infer", str(scene), "-o", str(theirs / "forces.csv"), *cli_flags], check=True)
    if "time_fit" in options:
        assert result.report["time_fit"]["frames"] == len(result.report["frames"])
        # The joint solve sums in parallel: equal to rounding, not byte for byte.
        got = pd.read_csv(mine / "forces.csv", dtype=IDS)
        expected = pd.read_csv(theirs / "forces.csv", dtype=IDS)
        assert_same_forces(got, expected, tolerance=1e-9)
        names.remove("forces.csv")
        names.remove("impulse.csv")
        a = pd.read_csv(mine / "impulse.csv", dtype={"grain": str})
        b = pd.read_csv(theirs / "impulse.csv", dtype={"grain": str})
        assert list(a["grain"]) == list(b["grain"])
        np.testing.assert_allclose(a["dv_x_inferred"], b["dv_x_inferred"], rtol=1e-7)
    if "uncertainty" in options:
        assert list(result.forces.columns) == ["frame", "contact", "f_x", "f_y", "sd_x", "sd_y"]
        assert len(result.report["uncertainty"]) == 41
        assert len(result.impulse) > 0
        assert (result.forces["sd_x"] >= 0).all() and result.forces["sd_x"].max() > 0
    for name in names:
        assert (mine / name).read_bytes() == (theirs / name).read_bytes(), name
