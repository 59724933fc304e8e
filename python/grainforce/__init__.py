"""grainforce: contact forces inside granular materials from measured grain
stresses (the Granular Element Method), 2D and 3D, static and dynamic.

>>> import grainforce as gf
>>> scene = gf.read_scene("fixtures/oedometer")
>>> result = gf.infer(scene, method="qs")
>>> result.forces.head()          # contact, f_x, f_y: as forces.csv
>>> result.report["stress_residual"]

Tables come and go as pandas DataFrames (dicts of NumPy arrays when pandas is
not installed) with the columns of the scene format (docs/scene-format.md).
The solves run in Rust with the GIL released, so Python threads and Dask
workers infer in parallel.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import tempfile
import warnings
from collections.abc import Mapping
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np

from . import _native
from ._native import InfeasibleError, SolverError

try:
    import pandas as _pd
except ImportError:  # pandas is optional: tables are then dicts of arrays
    _pd = None

__all__ = [
    "Scene",
    "Inference",
    "DemRun",
    "read_scene",
    "infer",
    "dem",
    "detect",
    "packing",
    "InfeasibleError",
    "SolverError",
    "FrameFailureWarning",
]



class FrameFailureWarning(UserWarning):
    """Some frames of a sequence failed; the result holds the others."""


Table = Any  # a pandas DataFrame, or a dict of column name -> array
Progress = Union[None, bool, Callable[[int, int], Any]]

# Columns holding ids or names: kept as text whatever they look like.
_TEXT_COLUMNS = {"id", "a", "b", "wall", "contact"}


def _table(columns: Mapping[str, Any]) -> Table:
    """A DataFrame when pandas is installed, else the dict of arrays."""
    columns = {k: np.asarray(v) for k, v in columns.items()}
    if _pd is not None:
        return _pd.DataFrame(columns)
    return columns


def _column(name: str, values: Any) -> Any:
    """A column as float64, int64 or text, the forms the native writer takes."""
    array = np.asarray(values)
    if array.ndim != 1:
        raise ValueError(f"column `{name}`: expected one value per row, got shape {array.shape}")
    if array.dtype.kind == "f":
        return np.ascontiguousarray(array, dtype=np.float64)
    if array.dtype.kind in "iub":
        return np.ascontiguousarray(array, dtype=np.int64)
    # Text, or mixed objects (e.g. grain ids and wall names in `b`).
    return ["" if _missing(v) else str(v) for v in array.tolist()]


def _missing(value: Any) -> bool:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return True
    return _pd is not None and value is _pd.NA


def _write_table(path: str, name: str, table: Table) -> None:
    if _pd is not None and isinstance(table, _pd.DataFrame):
        if table.index.name is not None and table.index.name not in table.columns:
            table = table.reset_index()  # e.g. grains indexed by id
        columns = {str(k): table[k].to_numpy() for k in table.columns}
    elif isinstance(table, Mapping):
        columns = {str(k): np.atleast_1d(np.asarray(v)) for k, v in table.items()}
    else:
        raise TypeError(
            f"{name}: expected a pandas DataFrame or a dict of arrays, got {type(table).__name__}"
        )
    lengths = {k: len(v) for k, v in columns.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{name}: columns of different lengths: {lengths}")
    _native.write_table(path, list(columns), [_column(k, v) for k, v in columns.items()])


def _read_table(path: str) -> Table:
    if _pd is not None:
        header = _pd.read_csv(path, nrows=0).columns
        return _pd.read_csv(path, dtype={c: str for c in header if c in _TEXT_COLUMNS})
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    columns = {}
    for k, name in enumerate(header):
        cells = [r[k] for r in body]
        if name in _TEXT_COLUMNS:
            columns[name] = np.array(cells, dtype=str)
        else:
            columns[name] = np.array([float(c) if c else math.nan for c in cells])
    return columns


class Scene:
    """A scene: one frame (static) or a sequence of frames (dynamic).

    Build one with :func:`read_scene`, :meth:`Scene.from_frames` or :func:`dem`.
    """

    __slots__ = ("_native",)

    def __init__(self, native: "_native.Scene"):
        self._native = native

    @classmethod
    def from_frames(
        cls,
        grains: Table,
        contacts: Table,
        walls: Optional[Table] = None,
        **meta: Any,
    ) -> "Scene":
        """A scene from tables with the scene format's columns.

        grains: id, x, y[, z], volume, s_xx, s_yy, s_xy (3D: s_zz, s_xz, s_yz),
        optional mass, a_x…, inertia, alpha…, radius, frame. contacts: id, a, b,
        x, y[, z], n_x, n_y[, n_z], optional mu, frame. walls: wall, f_x,
        f_y[, f_z], optional frame. Each a pandas DataFrame or a dict of
        arrays. ``meta`` holds scene.json's keys: gravity, mu, thickness,
        description.

        Checked exactly as a scene folder is: a bad value raises ValueError
        naming the table, line (the header is line 1) and column.
        """
        with tempfile.TemporaryDirectory(prefix="grainforce-") as folder:
            _write_table(os.path.join(folder, "grains.csv"), "grains", grains)
            _write_table(os.path.join(folder, "contacts.csv"), "contacts", contacts)
            if walls is not None:
                _write_table(os.path.join(folder, "walls.csv"), "walls", walls)
            if meta:
                settings = {
                    k: (np.asarray(v, dtype=float).tolist() if k == "gravity" else v)
                    for k, v in meta.items()
                }
                with open(os.path.join(folder, "scene.json"), "w") as f:
                    json.dump(settings, f)
            try:
                return cls(_native.read_scene(folder))
            except ValueError as e:
                # Name the tables, not the temporary folder they went through.
                message = str(e).replace(folder + os.sep, "").replace(folder, "tables")
                raise type(e)(message) from None

    @property
    def dim(self) -> int:
        """2 or 3."""
        return self._native.dim

    @property
    def frames(self) -> list:
        """Frame numbers (``[None]`` for a static scene)."""
        return self._native.frames

    @property
    def n_grains(self) -> int:
        """Grains of the first frame."""
        return self._native.n_grains

    @property
    def n_contacts(self) -> int:
        """Contacts of the first frame."""
        return self._native.n_contacts

    def __len__(self) -> int:
        return len(self._native)

    def __repr__(self) -> str:
        return repr(self._native)

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Writes the scene folder (grains.csv, contacts.csv, walls.csv, scene.json)."""
        self._native.save(os.fspath(path))

    def to_frames(self) -> Tuple[Table, Table, Optional[Table]]:
        """The tables (grains, contacts, walls or None), as the scene format writes them."""
        with tempfile.TemporaryDirectory(prefix="grainforce-") as folder:
            self._native.save(folder)
            walls = os.path.join(folder, "walls.csv")
            return (
                _read_table(os.path.join(folder, "grains.csv")),
                _read_table(os.path.join(folder, "contacts.csv")),
                _read_table(walls) if os.path.exists(walls) else None,
            )


def read_scene(path: Union[str, os.PathLike]) -> Scene:
    """Reads a scene folder (grains.csv, contacts.csv, optional walls.csv and
    scene.json): one frame, or a sequence when the files carry ``frame``.

    Raises FileNotFoundError when the folder or a needed file is missing and
    ValueError naming the file, line and column of a bad value.
    """
    return Scene(_native.read_scene(os.fspath(path)))


class Inference:
    """What :func:`infer` found.

    forces: the columns of forces.csv (frame for sequences, contact, f_x, f_y
    [, f_z]; force on grain ``a`` by ``b``), a DataFrame or a dict of arrays.
    report: the CLI's JSON report as a dict (a list of dicts, one per frame,
    for a sequence; a failed frame's is ``{"frame": k, "error": message}``).
    failed_frames: ``(frame, error message)`` of each frame of a sequence
    whose inference failed (its forces are absent), in frame order.
    """

    __slots__ = ("forces", "report", "failed_frames")

    def __init__(self, forces: Table, report: Any, failed_frames: Sequence = ()):
        self.forces = forces
        self.report = report
        self.failed_frames = list(failed_frames)

    def __repr__(self) -> str:
        n = len(self.forces["contact"])
        failed = f", {len(self.failed_frames)} frames failed" if self.failed_frames else ""
        return f"Inference({n} forces{failed})"


_FLAGS: Optional[dict] = None


def _flags() -> dict:
    global _FLAGS
    if _FLAGS is None:
        _FLAGS = {
            flag.replace("-", "_"): (flag, takes_value, value_name, choices)
            for flag, takes_value, value_name, choices, _help in _native.infer_flags()
        }
    return _FLAGS


def _number(value: Any) -> str:
    if isinstance(value, (bool, np.bool_)):
        raise TypeError("expected a number, got a bool")
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def _flag_value(key: str, value: Any, value_name: Optional[str], choices: list) -> str:
    if isinstance(value, str):
        return value.replace("_", "-") if choices else value
    if isinstance(value, (Sequence, np.ndarray)):
        items = list(value)
        if value_name and ".." in value_name:
            if len(items) != 2:
                raise ValueError(f"{key}: expected (min, max), got {value!r}")
            return f"{_number(items[0])}..{_number(items[1])}"
        if key == "grains":
            return ",".join(str(v) for v in items)
        return ",".join(_number(v) for v in items)
    try:
        return _number(value)
    except (TypeError, ValueError):
        raise TypeError(f"{key}: unsupported value {value!r}") from None


def _argv(options: Mapping[str, Any]) -> list:
    flags = _flags()
    argv = []
    for key, value in options.items():
        if value is None:
            continue
        name = key[:-1] if key.endswith("_") else key  # lambda_ -> lambda
        if name not in flags:
            raise TypeError(
                f"infer() got an unexpected keyword argument '{key}'; "
                f"options: {', '.join(sorted(flags))}"
            )
        flag, takes_value, value_name, choices = flags[name]
        if not takes_value:
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"{key} is a switch: pass True or False")
            if value:
                argv.append(f"--{flag}")
            continue
        argv.append(f"--{flag}={_flag_value(key, value, value_name, choices)}")
    return argv


def _progress_callback(progress: Progress, total: Optional[int]):
    if progress is None or progress is False:
        return None, None
    if callable(progress):
        return progress, None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        def report(done, total):
            print(f"\r{done}/{total} frames", end="\n" if done == total else "", file=sys.stderr)

        return report, None
    bar = tqdm(total=total, unit="frame")

    def advance(done, total):
        # The frames inferred (a range of the scene's) set the length.
        if bar.total != total:
            bar.total = total
        bar.update(done - bar.n)

    return advance, bar


def infer(
    scene: Union[Scene, str, os.PathLike],
    method: Optional[str] = None,
    *,
    progress: Progress = None,
    **options: Any,
) -> Inference:
    """Infers the contact forces of a scene (``grainforce infer``).

    scene: a Scene, or the path of a scene folder, of which only the frames
    the options need are read (``frames=(a, b)`` plus the filter's margin
    when accelerations are derived from the tracks), as the CLI reads it.

    method: None (the CLI's default: qs, switching to soft and saying so in
    the report when the data do not balance), qs (least squares on the
    stresses, hard equilibrium, friction), tikhonov, scaled, ls, dynamic or
    soft (momentum as a weighted penalty). An explicit hard-balance method
    raises on collapsed forces unless accept_degenerate=True. Every other
    option of ``grainforce infer`` is a keyword with its flag's name (``-``
    becomes ``_``, and ``lambda`` is ``lambda_``): stress_noise, mu, lambda_,
    lambda_range=(min, max), lambda_precision, gravity=(gx, gy), grains=[ids],
    region=(xmin, xmax, ymin, ymax), cone, solver, ordering, tolerance,
    allow_infeasible=True, accept_degenerate=True, wall_weight, lambda_rule,
    stress_sd, accel_sd, sweep, sweep_points, frames=(a, b), fps,
    derive_accelerations, smoother, fir_order, cutoff, savgol_window,
    savgol_degree, position_sd, stop_on_failure. Defaults are the CLI's.

    progress: for sequences, True for a tqdm bar (a line on stderr without
    tqdm) or a callable ``progress(done, total)`` called after each frame.

    A frame of a sequence whose inference fails does not stop the others:
    the result lists it in ``failed_frames`` and a FrameFailureWarning is
    issued; with stop_on_failure=True the first failure raises instead, as
    it does for a single scene or when every frame fails.

    The solve runs with the GIL released. Bad options or data raise
    ValueError with the library's message; infeasible data InfeasibleError
    (a ValueError); a failed solve SolverError (a RuntimeError).
    """
    if isinstance(scene, (str, os.PathLike)):
        source, frames = os.fspath(scene), None
    elif isinstance(scene, Scene):
        source, frames = scene._native, len(scene)
    else:
        raise TypeError(
            f"infer() needs a grainforce.Scene or a folder path, got {type(scene).__name__}"
        )
    argv = _argv({"method": method, **options})
    callback, bar = _progress_callback(progress, frames)
    try:
        columns, report, failed = _native.infer(source, argv, callback)
    finally:
        if bar is not None:
            bar.close()
    if failed:
        listed = "; ".join(message for _, message in failed[:3])
        more = f" (and {len(failed) - 3} more)" if len(failed) > 3 else ""
        warnings.warn(
            f"{len(failed)} frames failed and have no forces "
            f"(result.failed_frames): {listed}{more}",
            FrameFailureWarning,
            stacklevel=2,
        )
    return Inference(_table(columns), json.loads(report), failed)


class DemRun:
    """A DEM run: ``scene`` (its frames), ``forces`` (the exact contact forces,
    forces.csv columns) and ``report`` (dem_report.json as a dict)."""

    __slots__ = ("scene", "forces", "report")

    def __init__(self, scene: Scene, forces: Table, report: dict):
        self.scene = scene
        self.forces = forces
        self.report = report

    def __repr__(self) -> str:
        return f"DemRun({self.scene!r}, gate passed: {self.report.get('passed')})"


def dem(
    preset: str,
    dim: int = 2,
    *,
    seed: int = 1,
    grains: Optional[int] = None,
    gate: Optional[float] = None,
    duration: Optional[float] = None,
    frames_every: Optional[int] = None,
    max_steps: Optional[int] = None,
    verbose: bool = False,
) -> DemRun:
    """Runs a DEM preset (``grainforce dem``): synthetic ground truth.

    preset: oedometer, box, impact or bed_impact (impact presets give a
    sequence with accelerations). Other arguments default to the preset's.
    Runs with the GIL released.
    """
    native, forces, report = _native.dem(
        preset, dim, seed, grains, gate, duration, frames_every, max_steps, verbose
    )
    return DemRun(Scene(native), _table(forces), json.loads(report))


def packing(dim: int = 2, grains: int = 1000, *, seed: int = 1) -> Tuple[Scene, Table]:
    """A synthetic jittered packing with exact, balanced forces (the
    generator of ``grainforce bench``): ``(scene, forces)``, the forces as
    forces.csv columns. About ``grains`` grains; quick even at 10⁵."""
    native, forces = _native.packing(dim, grains, seed)
    return Scene(native), _table(forces)


def detect(
    image: Any,
    radius: Tuple[float, float],
    *,
    polarity: str = "bright",
    smoothing: Optional[float] = None,
) -> Table:
    """Finds disks in a grey image (a 2D array, intensities in [0, 1]).

    Pixel coordinates as in scikit-image: x along a row, y down the
    columns, pixel (row i, column j) centred at (x, y) = (j, i).
    radius: (min, max) in pixels. polarity: bright, dark or either.
    Returns the columns x, y, r (pixels), support, visible, contrast and rms,
    one row per disk, sorted by row then column.
    """
    array = np.asarray(image, dtype=np.float64)
    if array.ndim != 2:
        raise ValueError(f"detect() needs a 2D grey image, got an array of shape {array.shape}")
    lo, hi = radius
    return _table(
        _native.detect(np.ascontiguousarray(array), float(lo), float(hi), polarity, smoothing)
    )
