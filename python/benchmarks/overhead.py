"""Overhead of the Python path against the CLI on one scene (a benchmark, not a test).

    python benchmarks/overhead.py [GRAINS] [REPEATS]   # GRAINFORCE_BIN = the CLI

Generates a 2D packing of about GRAINS grains (default 10⁴), writes it as a
scene folder, then times, as the median of REPEATS runs:
- cli: `grainforce infer DIR -o forces.csv` (process start, CSV in and out);
- python: gf.read_scene(DIR) + gf.infer(...) into a DataFrame;
- frames: gf.Scene.from_frames(DataFrames) + gf.infer(...);
- solve: the library's own time for the inference (report["time"]).
Overhead = (python − solve) / solve: everything the binding adds around the solve.
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import grainforce as gf


def median_time(run, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        value = run()
        times.append(time.perf_counter() - start)
    return statistics.median(times), value


def main():
    grains = int(float(sys.argv[1])) if len(sys.argv) > 1 else 10_000
    repeats = int(sys.argv[2]) if len(sys.argv) > 2 else 5
    cli = os.environ["GRAINFORCE_BIN"]
    scene, _ = gf.packing(dim=2, grains=grains, seed=1)
    with tempfile.TemporaryDirectory() as folder:
        scene_dir = Path(folder) / "scene"
        scene.save(scene_dir)
        out = Path(folder) / "forces.csv"
        tables = gf.read_scene(scene_dir).to_frames()
        grains_df, contacts_df, walls_df = tables

        t_cli, _ = median_time(
            lambda: subprocess.run([cli, "infer", str(scene_dir), "-o", str(out), "--quiet"], check=True),
            repeats,
        )
        solve_times = []

        def python_path():
            result = gf.infer(gf.read_scene(scene_dir))
            solve_times.append(result.report["time"])
            return result

        t_py, _ = median_time(python_path, repeats)
        t_frames, _ = median_time(
            lambda: gf.infer(gf.Scene.from_frames(grains_df, contacts_df, walls_df)), repeats
        )
        t_read, loaded = median_time(lambda: gf.read_scene(scene_dir), repeats)
        t_build, _ = median_time(lambda: gf.Scene.from_frames(grains_df, contacts_df, walls_df), repeats)
        infer_times = []

        def infer_only():
            result = gf.infer(loaded)
            infer_times.append(result.report["time"])

        t_infer, _ = median_time(infer_only, repeats)
        t_solve = statistics.median(solve_times)
        t_solve_alone = statistics.median(infer_times)
    print(f"scene: {scene}")
    print(f"cli    {t_cli:8.3f} s  (process, CSV in and out)")
    print(f"python {t_py:8.3f} s  read_scene + infer -> DataFrame")
    print(f"frames {t_frames:8.3f} s  Scene.from_frames(DataFrames) + infer")
    print(f"solve  {t_solve:8.3f} s  the library's own time (report['time'])")
    print(f"read   {t_read:8.3f} s  read_scene (CSV parse, as the CLI does)")
    print(f"build  {t_build:8.3f} s  Scene.from_frames(DataFrames)")
    print(f"infer  {t_infer:8.3f} s  gf.infer alone; its solve {t_solve_alone:.3f} s: "
          f"binding overhead {100 * (t_infer - t_solve_alone) / t_solve_alone:.1f} %")
    print(f"overhead python vs solve: {100 * (t_py - t_solve) / t_solve:5.1f} %")
    print(f"overhead frames vs solve: {100 * (t_frames - t_solve) / t_solve:5.1f} %")
    print(f"python vs cli:            {100 * (t_py - t_cli) / t_cli:+5.1f} %")


if __name__ == "__main__":
    main()
