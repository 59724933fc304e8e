"""import_labels and import_imaged11 against the CLI, ImageD11's own stresses
and bad input."""

import subprocess

import numpy as np
import pandas as pd
import pytest

import grainforce as gf
from test_grainforce import REPO, cli

IMAGED11 = REPO / "fixtures" / "import" / "imaged11"


def packed_balls(seed=3, n=4, spacing=16.0, jitter=2.0):
    """n³ balls on a jittered cubic lattice, radius a little over half the
    spacing so that neighbours touch; labels 1 … n³ (uint16, z, y, x)."""
    rng = np.random.default_rng(seed)
    size = int(spacing * n + 8)
    z, y, x = np.mgrid[0:size, 0:size, 0:size].astype(np.float64)
    labels = np.zeros((size, size, size), dtype=np.uint16)
    best = np.full(labels.shape, np.inf)
    centres = []
    for k in range(n):
        for j in range(n):
            for i in range(n):
                c = 4 + spacing * (np.array([i, j, k]) + 0.5) + rng.uniform(-jitter, jitter, 3)
                centres.append(c)
    for label, c in enumerate(centres, start=1):
        d = np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / (0.5 * spacing + 1.0)
        inside = (d <= 1.0) & (d < best)
        labels[inside] = label
        best[inside] = d[inside]
    return labels, np.array(centres)


def test_a_volume_gives_the_scene_the_cli_writes(tmp_path):
    labels, _ = packed_balls()
    voxel = 1e-5
    got = gf.import_labels(labels, voxel, origin=(0.001, 0.0, -0.002), walls={"floor": ("z", -0.002)})
    assert got.scene.dim == 3
    assert got.scene.n_grains == 64
    assert got.scene.n_contacts > 64
    assert {"contact", "a", "b", "kept", "gap", "pca_n_x"} <= set(got.quality.columns)
    np.save(tmp_path / "labels.npy", labels)
    subprocess.run(
        [
            cli(), "import", "labels", str(tmp_path / "labels.npy"), "-o", str(tmp_path / "cli"),
            "--voxel-size", "1e-5", "--origin", "0.001,0,-0.002", "--walls", "floor:z=-0.002",
            "--quiet",
        ],
        check=True,
    )
    got.save(tmp_path / "py")
    for name in ["grains.csv", "contacts.csv", "contacts_quality.csv"]:
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    # Every integer type a segmentation writes gives the same scene.
    for dtype in [np.uint8, np.int32, np.int64, np.uint32]:
        other = gf.import_labels(labels.astype(dtype), voxel, origin=(0.001, 0.0, -0.002),
                                 walls=["floor:z=-0.002"])
        pd.testing.assert_frame_equal(other.quality, got.quality)
    # A view that is not contiguous is copied, not refused.
    flipped = gf.import_labels(np.ascontiguousarray(labels[::-1])[::-1], voxel)
    assert flipped.scene.n_grains == 64


def test_stresses_from_another_frame_are_attached(tmp_path):
    labels, centres = packed_balls()
    voxel = 1e-5
    # A diffraction frame turned 90° about z and shifted: x' = y, y' = -x.
    positions = centres * voxel
    turned = np.column_stack([positions[:, 1], -positions[:, 0], positions[:, 2]]) + 0.003
    keep = np.arange(2, 64)
    table = pd.DataFrame(
        {
            "id": [f"g{i + 1}" for i in keep],
            "x": turned[keep, 0],
            "y": turned[keep, 1],
            "z": turned[keep, 2],
            # σ'_xx (diffraction frame) = σ_yy (CT frame): a uniaxial stress
            # along the CT's y is along the diffraction frame's x.
            "s_xx": -1e6 * (keep + 1),
            "s_yy": np.zeros(len(keep)),
            "s_zz": np.zeros(len(keep)),
            "s_xy": np.zeros(len(keep)),
            "s_xz": np.zeros(len(keep)),
            "s_yz": np.zeros(len(keep)),
        }
    )
    got = gf.import_labels(labels, voxel, stresses=table)
    assert got.transform["matched"] == 62
    assert abs(got.transform["rotation_angle_degrees"] - 90.0) < 1.0
    assert got.transform["unmatched_scene_grains"] == ["1", "2"]
    matched = got.stress_match.dropna(subset=["grain", "source"])
    assert (matched["source"] == "g" + matched["grain"]).all()
    grains, _, _ = got.scene.to_frames()
    g = grains.set_index("id")
    for label in [3, 30, 64]:
        assert g.loc[str(label), "s_yy"] == pytest.approx(-1e6 * label, rel=1e-3)
        assert abs(g.loc[str(label), "s_xx"]) < 1e-2 * 1e6 * label
    assert g.loc["1", "s_yy"] == 0.0
    assert any("matched no stressed grain" in w for w in got.warnings)
    # The same through a file and through a Scene, and written as the CLI does.
    table.to_csv(tmp_path / "xrd.csv", index=False)
    by_path = gf.import_labels(labels, voxel, stresses=tmp_path / "xrd.csv")
    pd.testing.assert_frame_equal(by_path.stress_match, got.stress_match)
    got.save(tmp_path / "out")
    assert (tmp_path / "out" / "stress_match.json").exists()


def test_bad_volumes_and_stresses_are_refused(tmp_path):
    labels, _ = packed_balls(n=2)
    with pytest.raises(ValueError, match="3D array"):
        gf.import_labels(labels[0], 1e-5)
    with pytest.raises(ValueError, match="integer label volume"):
        gf.import_labels(labels.astype(np.float32), 1e-5)
    bad = labels.astype(np.int16)
    bad[1, 2, 3] = -4
    with pytest.raises(ValueError, match="z=1 y=2 x=3"):
        gf.import_labels(bad, 1e-5)
    with pytest.raises(ValueError, match="voxel-size|voxel_size"):
        gf.import_labels(labels, -1.0)
    with pytest.raises(ValueError, match="normals"):
        gf.import_labels(labels, 1e-5, normals="best")
    with pytest.raises(ValueError, match="grey has shape"):
        gf.import_labels(labels, 1e-5, grey=np.zeros((2, 2, 2)))
    broken = pd.DataFrame({"id": ["a", "b", "c"], "x": [0.0, 1.0, 2.0], "y": [0.0] * 3})
    with pytest.raises(ValueError, match="z"):
        gf.import_labels(labels, 1e-5, stresses=broken)


def test_imaged11_maps_give_imaged11s_stresses():
    truth = pd.read_csv(IMAGED11 / "quartz_stress.csv")
    scene = gf.import_imaged11(
        IMAGED11 / "quartz.map",
        cell=(4.9134, 4.9134, 5.4052, 90, 90, 120),
        stiffness="quartz",
        grain_volume=1e-12,
    )
    grains, _, _ = scene.to_frames()
    assert len(grains) == len(truth)
    for c in ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]:
        assert np.abs(grains[c].to_numpy() / 1e6 - truth[c].to_numpy()).max() < 1e-3
    assert np.allclose(grains["x"].to_numpy(), truth["x"].to_numpy() * 1e-6, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="grain-volume|grain_volume"):
        gf.import_imaged11(IMAGED11 / "quartz.map", cell=(4.9, 4.9, 5.4, 90, 90, 120), stiffness="quartz")
    with pytest.raises(ValueError, match="cell needs 6"):
        gf.import_imaged11(IMAGED11 / "quartz.map", cell=(4.9, 4.9), stiffness="quartz")


def test_imaged11_hdf5_grain_files_give_imaged11s_stresses():
    truth = pd.read_csv(IMAGED11 / "quartz_h5_stress.csv")
    cell = (4.9134, 4.9134, 5.4052, 90, 90, 120)
    scene = gf.import_imaged11(
        IMAGED11 / "quartz.h5", cell=cell, stiffness="quartz", grain_volume=1e-12, phase="quartz"
    )
    grains, _, _ = scene.to_frames()
    assert len(grains) == len(truth)
    for c in ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"]:
        assert np.abs(grains[c].to_numpy() / 1e6 - truth[c].to_numpy()).max() < 1e-8
    with pytest.raises(ValueError, match="no group `zircon`"):
        gf.import_imaged11(
            IMAGED11 / "quartz.h5", cell=cell, stiffness="quartz", grain_volume=1e-12, phase="zircon"
        )


def test_the_ct_example_gives_the_dem_forces(monkeypatch):
    # python/examples/ct_to_forces.py: the 3D oedometer voxelised at 30
    # voxels per diameter, its stresses as a quartz ImageD11 map in a turned
    # frame, infer. Measured: the map's stresses 1.7e-4 MPa from the DEM's
    # (9-digit UBIs; the target 1e-3 MPa), relerr 0.0088 (target 0.05).
    monkeypatch.syspath_prepend(str(REPO / "python" / "examples"))
    from ct_to_forces import ct_to_forces

    found = ct_to_forces(verbose=False)
    assert found["map_stress_off"] < 1e3  # Pa
    assert found["relerr"] < 0.02
