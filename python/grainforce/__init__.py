"""grainforce: contact forces inside granular materials from measured grain
stresses (the Granular Element Method), 2D and 3D, static and dynamic.

>>> import grainforce as gf
>>> scene = gf.read_scene("fixtures/oedometer")
>>> result = gf.infer(scene, method="qs")
>>> result.forces.head()          # contact, f_x, f_y: as forces.csv
>>> result.report["frames"][0]["stress_residual"]

Tables come back as pandas DataFrames (and go in as DataFrames or dicts of
NumPy arrays) with the columns of the scene format (docs/scene-format.md).
The solves run in Rust with the GIL released, so Python threads and Dask
workers infer in parallel.
"""

from __future__ import annotations

import csv
import io
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

import pandas as _pd

__all__ = [
    "Scene",
    "Inference",
    "DemRun",
    "read_scene",
    "infer",
    "dem",
    "detect",
    "packing",
    "LabelImport",
    "import_labels",
    "import_imaged11",
    "Photoelastic",
    "photoelastic",
    "InfeasibleError",
    "SolverError",
    "FrameFailureWarning",
]



class FrameFailureWarning(UserWarning):
    """Some frames of a sequence failed; the result holds the others."""


Table = Any  # a pandas DataFrame (or, going in, a dict of column name -> array)
Progress = Union[None, bool, Callable[[int, int], Any]]

# Columns holding ids or names: kept as text whatever they look like.
_TEXT_COLUMNS = {"id", "a", "b", "wall", "contact"}


def _table(columns: Mapping[str, Any]) -> Table:
    """The columns as a DataFrame."""
    return _pd.DataFrame({k: np.asarray(v) for k, v in columns.items()})


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
    return value is _pd.NA


def _write_table(path: str, name: str, table: Table) -> None:
    if isinstance(table, _pd.DataFrame):
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
    header = _pd.read_csv(path, nrows=0).columns
    return _pd.read_csv(path, dtype={c: str for c in header if c in _TEXT_COLUMNS})


def _csv_table(text: Optional[str]) -> Optional[Table]:
    """A CSV text the library wrote, as a DataFrame (None stays None)."""
    if text is None:
        return None
    header = next(csv.reader(io.StringIO(text)))
    return _pd.read_csv(io.StringIO(text), dtype={c: str for c in header if c in {"grain"}})


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
    """What :func:`infer` found: one type for a scene or a sequence.

    forces: forces.csv as a DataFrame (frame for sequences, contact, f_x,
    f_y[, f_z]: force on grain ``a`` by ``b``; sd_x, sd_y[, sd_z] with
    ``uncertainty``).
    report: a dict of one shape for one frame or many: ``frames`` (a list,
    one report per frame; a failed frame's is ``{"frame": k, "error":
    message}``), ``time_fit``, ``uncertainty``, ``impulse`` and
    ``accelerations`` (what deriving them from the tracks found), each None
    when not run.
    failed_frames: ``(frame, error message)`` of each frame of a sequence
    whose inference failed (its forces are absent), in frame order.
    impulse: the impulse check (``impulse=True``) as a DataFrame, else None.
    pareto: the Pareto front (``pareto=True`` or the knee rule) as a
    DataFrame, else None.
    """

    __slots__ = ("forces", "report", "failed_frames", "impulse", "pareto", "_native")

    def __init__(self, native: "_native.Run"):
        self._native = native
        self.forces = _table(native.forces())
        self.report = json.loads(native.report())
        self.failed_frames = native.failed_frames()
        self.impulse = _csv_table(native.impulse_csv())
        self.pareto = _csv_table(native.pareto_csv())

    def save(
        self,
        forces: Union[None, str, os.PathLike] = None,
        *,
        report: Union[None, str, os.PathLike] = None,
        impulse: Union[None, str, os.PathLike] = None,
        pareto: Union[None, str, os.PathLike] = None,
    ) -> None:
        """Writes the files ``grainforce infer -o FORCES --report REPORT
        --impulse IMPULSE --pareto PARETO`` writes, byte for byte."""
        path = lambda p: None if p is None else os.fspath(p)
        self._native.save(path(forces), path(report), path(impulse), path(pareto))

    def __repr__(self) -> str:
        n = len(self.forces)
        failed = f", {len(self.failed_frames)} frames failed" if self.failed_frames else ""
        return f"Inference({n} forces{failed})"


_DEFAULTS: Optional[dict] = None


def _defaults() -> dict:
    """The library's configuration fields and their defaults."""
    global _DEFAULTS
    if _DEFAULTS is None:
        _DEFAULTS = json.loads(_native.infer_defaults())
    return _DEFAULTS


def _plain(key: str, value: Any) -> Any:
    """A keyword's value as JSON takes it (tuples and arrays as lists)."""
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, (str, int, float)):
        return value
    if isinstance(value, (Sequence, np.ndarray)):
        items = [_plain(key, v) for v in list(value)]
        if key == "grains":
            return [str(v) for v in items]
        return items
    raise TypeError(f"{key}: unsupported value {value!r}")


def _config(options: Mapping[str, Any]) -> str:
    """The keywords as the library's configuration (JSON); the library checks it."""
    fields = _defaults()
    config = {}
    for key, value in options.items():
        name = key[:-1] if key.endswith("_") else key  # lambda_ -> lambda
        if name not in fields:
            raise TypeError(
                f"infer() got an unexpected keyword argument '{key}'; "
                f"options: {', '.join(sorted(fields))}"
            )
        if value is not None:
            config[name] = _plain(key, value)
    return json.dumps(config)


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
    option is a field of the library's configuration (``grainforce infer``'s
    flag with ``_`` for ``-``; ``lambda`` is ``lambda_``), its values in
    snake_case: stress_noise, mu, lambda_, lambda_range=(min, max),
    lambda_precision, gravity=(gx, gy), grains=[ids], region=(xmin, xmax,
    ymin, ymax), cone, solver ('active_set', 'interior_point'), ordering,
    tolerance, allow_infeasible, accept_degenerate, uniqueness_limit, wall_weight,
    lambda_rule, stress_sd, accel_sd, sweep, sweep_points, pareto=True,
    frames=(a, b), fps, derive_accelerations, smoother, fir_order, cutoff,
    savgol_window, savgol_degree, time_fit ('frames', 'joint'), roughness,
    impulse=True, impulse_window, position_sd, uncertainty=draws,
    noise_level, uncertainty_seed, stop_on_failure. Defaults are the CLI's;
    the library checks every value (ValueError naming the option).

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
    config = _config({"method": method, **options})
    callback, bar = _progress_callback(progress, frames)
    try:
        result = Inference(_native.infer(source, config, callback))
    finally:
        if bar is not None:
            bar.close()
    failed = result.failed_frames
    if failed:
        listed = "; ".join(message for _, message in failed[:3])
        more = f" (and {len(failed) - 3} more)" if len(failed) > 3 else ""
        warnings.warn(
            f"{len(failed)} frames failed and have no forces "
            f"(result.failed_frames): {listed}{more}",
            FrameFailureWarning,
            stacklevel=2,
        )
    return result


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


class LabelImport:
    """A label volume's import (``grainforce import labels``).

    ``scene`` (grains and contacts; stresses zero unless attached),
    ``quality`` (contacts_quality.csv: every touching zone, kept or not, with
    its area, fitted gap, grey evidence and the standard PCA normal),
    ``rattlers`` and ``cut`` (grain ids), ``warnings``, and with stresses
    attached ``stress_match`` (stress_match.csv: grain, source, distance) and
    ``transform`` (stress_match.json: rotation, translation, residual).
    ``save(path)`` writes the folder the CLI writes.
    """

    __slots__ = ("_native", "scene", "quality", "stress_match", "transform")

    def __init__(self, native: "_native.LabelImport"):
        self._native = native
        self.scene = Scene(native.scene())
        self.quality = _pd.read_csv(
            io.StringIO(native.quality_csv()), dtype={"contact": str, "a": str, "b": str}
        )
        matched = native.stress_match()
        if matched is None:
            self.stress_match = None
            self.transform = None
        else:
            header = ("grain", "source")
            self.stress_match = _pd.read_csv(
                io.StringIO(matched[0]), dtype={c: str for c in header}
            )
            self.transform = json.loads(matched[1])

    @property
    def rattlers(self) -> list:
        return self._native.rattlers

    @property
    def cut(self) -> list:
        return self._native.cut

    @property
    def warnings(self) -> list:
        return self._native.warnings

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Writes the scene folder, contacts_quality.csv and (with stresses) stress_match.*."""
        self._native.save(os.fspath(path))

    def __repr__(self) -> str:
        extra = ""
        if self.transform is not None:
            extra = f", {self.transform['matched']} stresses attached"
        return f"LabelImport({self.scene!r}, {len(self.rattlers)} rattlers{extra})"


def _wall_specs(walls: Any) -> list:
    if walls is None:
        return []
    if isinstance(walls, Mapping):
        out = []
        for name, spec in walls.items():
            try:
                axis, position = spec
            except (TypeError, ValueError):
                raise ValueError(
                    f"walls[{name!r}]: expected (axis, position), e.g. ('z', 0.0), got {spec!r}"
                ) from None
            out.append(f"{name}:{axis}={float(position)!r}")
        return out
    if isinstance(walls, str):
        return [walls]
    return [str(w) for w in walls]


def import_labels(
    volume: Any,
    voxel_size: float,
    *,
    origin: Optional[Sequence[float]] = None,
    grey: Any = None,
    walls: Any = None,
    container: Optional[int] = None,
    density: Optional[float] = None,
    normals: str = "fit",
    max_gap: Optional[float] = None,
    min_grey: float = 0.9,
    stresses: Any = None,
    match_distance: Optional[float] = None,
    match_transform: str = "rigid",
) -> LabelImport:
    """Grains and contacts from a labelled CT volume (``grainforce import labels``).

    volume: a 3D integer array indexed (z, y, x), each voxel its grain's
    label, 0 = void. Voxel [z, y, x] is centred at origin + voxel_size·(x, y, z)
    (metres). grey: the CT it was segmented from (same shape): grey-level
    evidence and a sub-voxel gap per contact (``grey_gap``, ``grey_gap_sd``,
    the neck fit's ``grey_fit_misfit``); necks darker than ``min_grey`` and
    zones whose grey gap lies more than 3 robust deviations above the median
    (where the neck model fits them) are dropped. walls:
    plane walls, ``{"bottom": ("z", 0.0)}`` or ``["bottom:z=0"]``.
    container: the label that is the container. density: kg/m³, gives masses
    and inertia tensors. normals: ``"fit"`` (local surface fits) or ``"pca"``
    (the field's standard). max_gap: drop zones whose fitted gap exceeds the
    median by this many voxels.

    stresses: per-grain stresses to attach by position (a Scene, e.g. from
    :func:`import_imaged11`, a scene folder or CSV path, or a table with id,
    x, y, z, s_xx … s_yz in SI); the rigid transform between the two frames
    is fitted (``match_transform="none"``: the same frame) and stresses are
    rotated into the CT frame. Runs with the GIL released.
    """
    array = np.asarray(volume)
    if array.ndim != 3:
        raise ValueError(f"import_labels() needs a 3D array (z, y, x), got shape {array.shape}")
    if array.dtype.kind == "b":
        array = array.astype(np.uint8)
    if array.dtype.kind not in "iu":
        raise ValueError(
            f"import_labels() needs an integer label volume, got dtype {array.dtype} "
            "(convert whole-valued floats with .astype(np.uint32))"
        )
    array = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("="))
    grey_array = None
    if grey is not None:
        grey_array = np.ascontiguousarray(np.asarray(grey), dtype=np.float32)
        if grey_array.shape != array.shape:
            raise ValueError(
                f"grey has shape {grey_array.shape}, the volume {array.shape}"
            )
    if origin is not None:
        origin = [float(x) for x in origin]
        if len(origin) != 3:
            raise ValueError(f"origin needs 3 numbers (x, y, z), got {len(origin)}")

    def run(stress_path: Optional[str]) -> LabelImport:
        return LabelImport(
            _native.import_labels(
                array,
                float(voxel_size),
                origin,
                grey_array,
                _wall_specs(walls),
                container,
                density,
                normals,
                max_gap,
                float(min_grey),
                stress_path,
                match_distance,
                match_transform,
            )
        )

    if stresses is None:
        return run(None)
    if isinstance(stresses, (str, os.PathLike)):
        return run(os.fspath(stresses))
    with tempfile.TemporaryDirectory(prefix="grainforce-") as folder:
        if isinstance(stresses, Scene):
            stresses.save(folder)
            path = folder
        else:
            path = os.path.join(folder, "stresses.csv")
            _write_table(path, "stresses", stresses)
        try:
            return run(path)
        except ValueError as e:
            message = str(e).replace(folder + os.sep, "").replace(folder, "stresses")
            raise type(e)(message) from None


def import_imaged11(
    path: Union[str, os.PathLike],
    *,
    cell: Sequence[float],
    stiffness: str,
    grain_volume: Optional[float] = None,
    contacts: Optional[Union[str, os.PathLike]] = None,
    phase: Optional[str] = None,
) -> Scene:
    """A 3D scene from an ImageD11 grain map (``.map``/``.ubi``, or an HDF5
    grain file as ``ImageD11.grain.write_grain_file_h5`` writes it;
    ``grainforce import imaged11``): positions from ``#translation`` (µm →
    m), sample-frame stresses from the UBIs (Biot strain of the polar
    decomposition, Hooke's law in the x ∥ a* crystal frame, docs/field.md).

    cell: a, b, c (Å), α, β, γ (degrees) of the unstrained crystal.
    stiffness: a preset (quartz, zirconium, …) or constants as the CLI takes
    them. grain_volume: m³, given to every grain (a map has none; any value
    will do when the stresses go to :func:`import_labels`). contacts: a
    contact list CSV (as ``import gff`` reads it). phase: the group of an
    HDF5 grain file that holds several.
    """
    cell = [float(x) for x in cell]
    if len(cell) != 6:
        raise ValueError(f"cell needs 6 numbers (a, b, c, alpha, beta, gamma), got {len(cell)}")
    return Scene(
        _native.import_imaged11(
            os.fspath(path),
            cell,
            stiffness,
            grain_volume,
            None if contacts is None else os.fspath(contacts),
            phase,
        )
    )


class Photoelastic:
    """A photoelastic fit (``grainforce photoelastic``).

    forces: forces.csv as a DataFrame (contact, f_x, f_y: N/m per unit
    thickness; zero for a contact left out). report: the fit report as a
    dict (per-disk residuals, balance, ``left_out``, f_σ when fitted to the
    walls). ``overlay()`` gives the photograph and the fitted fringes side
    by side as an array; ``save()`` writes the CLI's files.
    """

    __slots__ = ("_native", "forces", "report")

    def __init__(self, native: "_native.Photoelastic"):
        self._native = native
        self.forces = _table(native.forces())
        self.report = json.loads(native.report())

    def overlay(self) -> np.ndarray:
        """The photograph (left half) and the fitted fringes (right half),
        rows = y down, intensities in [0, 1] (float32)."""
        return self._native.overlay()

    def save(
        self,
        forces: Union[None, str, os.PathLike] = None,
        *,
        report: Union[None, str, os.PathLike] = None,
        overlay: Union[None, str, os.PathLike] = None,
    ) -> None:
        """Writes the files ``grainforce photoelastic -o FORCES --report
        REPORT --overlay OVERLAY`` writes."""
        path = lambda p: None if p is None else os.fspath(p)
        self._native.save(path(forces), path(report), path(overlay))

    def __repr__(self) -> str:
        r = self.report
        return (
            f"Photoelastic({len(self.forces)} forces, {len(r['disks'])} disks, "
            f"{len(r['flagged'])} flagged)"
        )


def photoelastic(
    image: Union[str, os.PathLike],
    scene: Union[str, os.PathLike],
    *,
    fsigma: Optional[float] = None,
    thickness: Optional[float] = None,
    scale: Optional[float] = None,
    channel: Optional[str] = None,
    mu: Optional[float] = None,
    balance_weight: Optional[float] = None,
    blur: Optional[float] = None,
    edge: Optional[float] = None,
    iterations: Optional[int] = None,
    per_disk: bool = False,
    contacts: Optional[str] = None,
    candidates: Optional[float] = None,
    sparsity: Optional[float] = None,
    wall_mu: Optional[float] = None,
    polariscope: Optional[str] = None,
    lighting: bool = False,
    penalty_start: Optional[float] = None,
    narrow_start: Optional[float] = None,
    local_starts: Optional[int] = None,
) -> Photoelastic:
    """Contact forces fitted to a photoelastic photograph's fringes, all
    disks at once under balance and friction (``grainforce photoelastic``,
    docs/photoelastic.md).

    image: the photograph (circular polariscope). scene: the scene
    folder from ``grainforce detect`` or ``import pegs`` (disks, contacts,
    image-frame.json). fsigma: the fringe constant f_σ [N/m]; without it f_σ
    is fitted to the walls' load cells (walls.csv). thickness [m] and scale
    [px/m] default to the scene's. Every keyword left None keeps the CLI's
    default: channel green, mu 1 (where the scene gives none), exact balance (balance_weight makes it a
    penalty), blur 1 px, edge 6 px, 60 iterations, contacts "all" (or "evidence": only those
    ``detect`` judged force-bearing), candidates 0.2 on a scene from
    ``detect`` and off on others (near-miss pairs with a gap below this
    share of the smaller radius fitted too, and on a ``detect`` scene disks
    that near a wall as closely, listed in the report; 0: off);
    off: sparsity (weight of the term that fits unsupported
    contacts to zero; measured in docs/photoelastic.md, not yet better).
    wall_mu: the friction coefficient of contacts with walls (default mu;
    0 for smooth walls). polariscope: "dark" (bright fringes on dark disks),
    "bright" (dark fringes on bright disks) or "auto" (the default: read from
    the photograph; ``report["bright_field"]`` says which). lighting: fit
    each disk's background as a plane (light falling off across it).
    narrow_start (0.3) and penalty_start (10): where the fit leaves disks
    flagged, it is fitted again from a fit with every wedge at this μ, then,
    where disks are still flagged, from one with balance as a penalty of
    this weight, and the lower residual kept (``report["second_starts"]``;
    0 turns one off). local_starts (0,
    off): each disk still flagged is fitted again from up to this many
    starts with its and its neighbours' contacts free, kept where the whole
    residual falls (``report["local_restarts"]``).
    """
    opt = lambda v: None if v is None else float(v)
    return Photoelastic(
        _native.photoelastic(
            os.fspath(image),
            os.fspath(scene),
            opt(fsigma),
            opt(thickness),
            opt(scale),
            channel,
            opt(mu),
            opt(balance_weight),
            opt(blur),
            opt(edge),
            None if iterations is None else int(iterations),
            bool(per_disk),
            contacts,
            opt(candidates),
            opt(sparsity),
            opt(wall_mu),
            polariscope,
            bool(lighting),
            opt(penalty_start),
            opt(narrow_start),
            None if local_starts is None else int(local_starts),
        )
    )

