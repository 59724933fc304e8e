"""photoelastic() on the bundled photograph (fixtures/photoelastic: the DEM
oedometer drawn with known forces) against the truth, the CLI and bad input."""

import json
import subprocess

import numpy as np
import pandas as pd
import pytest

import grainforce as gf
from test_grainforce import REPO, cli

PHOTO = REPO / "fixtures" / "photoelastic" / "photo.jpg"
SCENE = REPO / "fixtures" / "photoelastic" / "scene"
TRUTH = REPO / "fixtures" / "oedometer" / "forces.csv"
# What fixtures/photoelastic was drawn with (examples/photoelastic_fixture.rs).
FSIGMA = 200.0
BLUR = 0.8


def relerr(forces: pd.DataFrame) -> float:
    truth = pd.read_csv(TRUTH, dtype={"contact": str}).set_index("contact")
    fit = forces.set_index("contact").loc[truth.index]
    diff = fit[["f_x", "f_y"]].to_numpy() - truth[["f_x", "f_y"]].to_numpy()
    return float(np.linalg.norm(diff) / np.linalg.norm(truth[["f_x", "f_y"]].to_numpy()))


@pytest.fixture(scope="module")
def fitted():
    return gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, blur=BLUR)


def test_the_fit_recovers_the_drawn_forces(fitted):
    # Measured 0.0010 (docs/photoelastic.md); the per-disk fit gives ~0.4.
    assert relerr(fitted.forces) < 0.005
    assert fitted.report["median_imbalance"] < 1e-6
    assert not fitted.report["flagged"]
    # On the DEM's geometry every disk with contacts can balance (the six
    # rattlers have none, so nothing of theirs is left out).
    assert fitted.report["balance_left_out"] == []
    assert len(fitted.report["disks"]) == 58


def test_files_match_the_cli(fitted, tmp_path):
    fitted.save(tmp_path / "py.csv", report=tmp_path / "py.json", overlay=tmp_path / "py.png")
    subprocess.run(
        [cli(), "photoelastic", str(PHOTO), "--scene", str(SCENE), "-o", str(tmp_path / "cli.csv"),
         "--fsigma", str(FSIGMA), "--blur", str(BLUR), "--report", str(tmp_path / "cli.json"),
         "--overlay", str(tmp_path / "cli.png")],
        check=True, capture_output=True,
    )
    assert (tmp_path / "py.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
    assert (tmp_path / "py.png").read_bytes() == (tmp_path / "cli.png").read_bytes()
    clock = lambda r: {k: v for k, v in r.items() if k not in ("seconds", "timing")}
    ours = json.loads((tmp_path / "py.json").read_text())
    assert clock(ours) == clock(json.loads((tmp_path / "cli.json").read_text()))
    assert clock(ours) == clock(fitted.report)


def test_overlay_is_the_photograph_beside_the_fit(fitted):
    both = fitted.overlay()
    frame = json.loads((SCENE / "image-frame.json").read_text())
    assert both.shape == (frame["height"], 2 * frame["width"])
    assert both.dtype == np.float32
    assert 0.0 <= both.min() and both.max() <= 1.0
    left, right = both[:, : frame["width"]], both[:, frame["width"]:]
    # The fitted fringes explain the photograph: close, not equal (noise, JPEG).
    assert np.corrcoef(left.ravel(), right.ravel())[0, 1] > 0.9


def test_without_fsigma_it_is_fitted_to_the_walls():
    fit = gf.photoelastic(PHOTO, SCENE, blur=BLUR)
    assert abs(fit.report["fsigma_fitted_to_walls"] / FSIGMA - 1) < 0.02
    assert relerr(fit.forces) < 0.005


def test_bad_input_raises(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.jpg"):
        gf.photoelastic(tmp_path / "nowhere.jpg", SCENE, fsigma=FSIGMA)
    with pytest.raises(ValueError, match="channel"):
        gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, channel="purple")
    with pytest.raises(ValueError, match="contacts"):
        gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, contacts="some")
    with pytest.raises(ValueError, match="fsigma"):
        gf.photoelastic(PHOTO, SCENE, fsigma=-1.0)
    with pytest.raises(ValueError, match="penalty_start"):
        gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, penalty_start=-1.0)
    with pytest.raises(ValueError, match="narrow_start"):
        gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, narrow_start=float("nan"))


def test_the_experimental_switches_match_the_cli(tmp_path):
    fit = gf.photoelastic(PHOTO, SCENE, fsigma=FSIGMA, blur=BLUR, candidates=0.2, sparsity=300)
    fit.save(tmp_path / "py.csv")
    subprocess.run(
        [cli(), "photoelastic", str(PHOTO), "--scene", str(SCENE), "-o", str(tmp_path / "cli.csv"),
         "--fsigma", str(FSIGMA), "--blur", str(BLUR), "--candidates", "0.2", "--sparsity", "300"],
        check=True, capture_output=True,
    )
    assert (tmp_path / "py.csv").read_bytes() == (tmp_path / "cli.csv").read_bytes()
    assert len(fit.forces) == 93  # candidates are reported, not written
    assert isinstance(fit.report["candidates"], list)
