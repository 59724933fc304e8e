"""Long sequences split in blocks: CLI shards concatenate to one run's file
byte for byte, and Dask tasks (examples/dask_frames.py) give one run's forces."""

import subprocess
from pathlib import Path

import pandas as pd
import pytest

import grainforce as gf
from test_grainforce import IDS, cli

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    folder = tmp_path_factory.mktemp("impact") / "scene"
    run = gf.dem("impact", duration=0.006)
    run.scene.save(folder)
    return folder, run.scene.frames


def test_cli_shards_concatenate_to_one_run(tmp_path, sequence):
    folder, frames = sequence
    whole = tmp_path / "all.csv"
    subprocess.run([cli(), "infer", str(folder), "-o", str(whole), "-m", "dynamic", "--quiet"], check=True)
    cuts = [frames[0], frames[len(frames) // 3], frames[2 * len(frames) // 3], frames[-1] + 1]
    shards = tmp_path / "shards"
    shards.mkdir()
    for k, (a, b) in enumerate(zip(cuts, cuts[1:])):
        subprocess.run(
            [cli(), "infer", str(folder), "-o", str(shards / f"forces-{k:05d}.csv"), "-m", "dynamic",
             "--frames", f"{a}..{b - 1}", "--quiet"],
            check=True,
        )
    # docs/cluster.md's merge, as written there.
    merge = "grainforce merge forces.csv shards/forces-*.csv"
    assert merge in (Path(__file__).resolve().parents[2] / "docs" / "cluster.md").read_text()
    subprocess.run(["bash", "-c", merge.replace("grainforce", f"'{cli()}'", 1)], cwd=tmp_path, check=True)
    merged = (tmp_path / "forces.csv").read_bytes()
    assert merged == whole.read_bytes()


def test_dask_blocks_give_one_runs_forces(sequence, monkeypatch):
    distributed = pytest.importorskip("dask.distributed")
    folder, _ = sequence
    # The workers (other processes) import the example's tasks too.
    monkeypatch.setenv("PYTHONPATH", str(EXAMPLES))
    monkeypatch.syspath_prepend(str(EXAMPLES))
    from dask_frames import infer_in_blocks
    expected = gf.infer(gf.read_scene(folder), method="dynamic").forces
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            forces = infer_in_blocks(client, str(folder), block=7, method="dynamic")
            assert len(client.scheduler_info()["workers"]) == 2
    pd.testing.assert_frame_equal(forces, expected)


def test_a_folder_and_a_frame_range_read_only_the_block(sequence):
    folder, frames = sequence
    whole = gf.infer(gf.read_scene(folder), method="dynamic").forces
    a, b = frames[len(frames) // 3], frames[len(frames) // 2]
    block = gf.infer(folder, method="dynamic", frames=(a, b)).forces
    expected = whole[(whole["frame"] >= a) & (whole["frame"] <= b)].reset_index(drop=True)
    assert len(expected) > 0
    pd.testing.assert_frame_equal(block, expected)
