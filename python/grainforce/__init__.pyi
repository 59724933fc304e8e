# Type hints of the grainforce package; `infer`'s keywords are the CLI's flags
# (tests/test_stub.py checks they stay the same set).
import os
from typing import Any, Callable, Literal, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

try:
    import pandas as pd

    Table = Union[pd.DataFrame, Mapping[str, npt.ArrayLike]]
except ImportError:  # pragma: no cover
    Table = Mapping[str, npt.ArrayLike]  # type: ignore[misc]

PathLike = Union[str, os.PathLike[str]]
Progress = Union[None, bool, Callable[[int, int], Any]]

class InfeasibleError(ValueError):
    """The constraints admit no force field (e.g. μ too small for the stresses)."""

class SolverError(RuntimeError):
    """The solver failed; the message carries its diagnostics."""

class FrameFailureWarning(UserWarning):
    """Some frames of a sequence failed; the result holds the others."""

class Scene:
    """A scene: one frame (static) or a sequence of frames (dynamic)."""

    @classmethod
    def from_frames(
        cls,
        grains: Table,
        contacts: Table,
        walls: Optional[Table] = None,
        *,
        gravity: Optional[Sequence[float]] = None,
        mu: Optional[float] = None,
        thickness: Optional[float] = None,
        description: Optional[str] = None,
    ) -> Scene:
        """A scene from tables with the scene format's columns (see docs/scene-format.md)."""
    @property
    def dim(self) -> int: ...
    @property
    def frames(self) -> list[Optional[int]]: ...
    @property
    def n_grains(self) -> int: ...
    @property
    def n_contacts(self) -> int: ...
    def __len__(self) -> int: ...
    def save(self, path: PathLike) -> None:
        """Writes the scene folder (grains.csv, contacts.csv, walls.csv, scene.json)."""
    def to_frames(self) -> Tuple[Table, Table, Optional[Table]]:
        """The tables (grains, contacts, walls or None)."""

class Inference:
    """forces: forces.csv as a DataFrame; report: one dict shape for one frame
    or many (frames, time_fit, uncertainty, impulse, accelerations);
    failed_frames: (frame, error) of each failed frame; impulse and pareto:
    DataFrames when run."""

    forces: Table
    report: dict[str, Any]
    failed_frames: list[Tuple[int, str]]
    impulse: Optional[Table]
    pareto: Optional[Table]
    def save(
        self,
        forces: Optional[PathLike] = None,
        *,
        report: Optional[PathLike] = None,
        impulse: Optional[PathLike] = None,
        pareto: Optional[PathLike] = None,
    ) -> None:
        """Writes the files `grainforce infer` writes, byte for byte."""

class DemRun:
    """scene, its exact forces (forces.csv columns) and dem_report.json as a dict."""

    scene: Scene
    forces: Table
    report: dict[str, Any]

def read_scene(path: PathLike) -> Scene:
    """Reads a scene folder: one frame, or a sequence when the files carry `frame`."""

def infer(
    scene: Union[Scene, PathLike],
    method: Optional[Literal["qs", "tikhonov", "scaled", "ls", "dynamic", "soft"]] = None,
    *,
    progress: Progress = None,
    stress_noise: Optional[Literal["absolute", "relative", "columns"]] = None,
    accept_degenerate: bool = False,
    mu: Optional[float] = None,
    wall_mu: Optional[float] = None,
    lambda_: Optional[float] = None,
    lambda_range: Optional[Tuple[float, float]] = None,
    lambda_precision: Optional[Literal["fine", "coarse"]] = None,
    gravity: Optional[Sequence[float]] = None,
    grains: Optional[Sequence[Union[str, int]]] = None,
    region: Optional[Sequence[float]] = None,
    cone: Optional[Literal["exact", "pyramid4", "pyramid8", "pyramid16"]] = None,
    solver: Optional[Literal["active_set", "interior_point"]] = None,
    ordering: Optional[Literal["auto", "amd", "nested_dissection"]] = None,
    tolerance: Optional[float] = None,
    allow_infeasible: bool = False,
    uniqueness_limit: Optional[int] = None,
    wall_weight: Optional[float] = None,
    lambda_rule: Optional[Literal["weights", "knee", "hard", "fixed", "variance"]] = None,
    stress_sd: Optional[float] = None,
    accel_sd: Optional[float] = None,
    sweep: Optional[Tuple[float, float]] = None,
    sweep_points: Optional[int] = None,
    pareto: bool = False,
    frames: Optional[Tuple[int, int]] = None,
    stop_on_failure: bool = False,
    fps: Optional[float] = None,
    derive_accelerations: bool = False,
    smoother: Optional[Literal["fir", "savgol", "whittaker"]] = None,
    fir_order: Optional[int] = None,
    cutoff: Optional[float] = None,
    savgol_window: Optional[int] = None,
    savgol_degree: Optional[int] = None,
    time_fit: Optional[Literal["frames", "joint"]] = None,
    roughness: Optional[float] = None,
    impulse: bool = False,
    impulse_window: Optional[int] = None,
    position_sd: Optional[float] = None,
    uncertainty: Optional[int] = None,
    noise_level: Optional[float] = None,
    uncertainty_seed: Optional[int] = None,
) -> Inference:
    """Infers the contact forces of a scene (``grainforce infer``); options are the library's configuration."""

def dem(
    preset: Literal["oedometer", "box", "impact", "bed_impact"],
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
    """Runs a DEM preset (``grainforce dem``): synthetic ground truth."""

def packing(dim: int = 2, grains: int = 1000, *, seed: int = 1) -> Tuple[Scene, Table]:
    """A synthetic packing with exact forces: (scene, forces)."""

def detect(
    image: npt.ArrayLike,
    radius: Tuple[float, float],
    *,
    polarity: Literal["bright", "dark", "either"] = "bright",
    smoothing: Optional[float] = None,
) -> Table:
    """Finds disks in a grey image: columns x, y, r, support, visible, contrast, rms."""

class LabelImport:
    """A label volume's import: scene, quality (contacts_quality.csv),
    rattlers, cut, warnings, and with stresses attached stress_match
    (stress_match.csv) and transform (stress_match.json)."""

    scene: Scene
    quality: Table
    stress_match: Optional[Table]
    transform: Optional[dict[str, Any]]
    @property
    def rattlers(self) -> list[str]: ...
    @property
    def cut(self) -> list[str]: ...
    @property
    def warnings(self) -> list[str]: ...
    def save(self, path: PathLike) -> None:
        """Writes the folder `grainforce import labels` writes."""

def import_labels(
    volume: npt.ArrayLike,
    voxel_size: float,
    *,
    origin: Optional[Sequence[float]] = None,
    grey: Optional[npt.ArrayLike] = None,
    walls: Union[None, Mapping[str, Tuple[str, float]], Sequence[str]] = None,
    container: Optional[int] = None,
    density: Optional[float] = None,
    normals: Literal["fit", "pca"] = "fit",
    max_gap: Optional[float] = None,
    min_grey: float = 0.9,
    stresses: Union[None, Scene, PathLike, Table] = None,
    match_distance: Optional[float] = None,
    match_transform: Literal["rigid", "none"] = "rigid",
) -> LabelImport:
    """Grains and contacts from a labelled CT volume (z, y, x), optionally with
    per-grain stresses attached by position (`grainforce import labels`)."""

def import_imaged11(
    path: PathLike,
    *,
    cell: Sequence[float],
    stiffness: str,
    grain_volume: Optional[float] = None,
    contacts: Optional[PathLike] = None,
    phase: Optional[str] = None,
) -> Scene:
    """A 3D scene from an ImageD11 grain map, text or HDF5 (`grainforce import imaged11`)."""

class Photoelastic:
    """A photoelastic fit: forces (forces.csv), report (the fit report)."""

    forces: Table
    report: dict[str, Any]
    def overlay(self) -> npt.NDArray[np.float32]:
        """The photograph and the fitted fringes side by side."""
    def save(
        self,
        forces: Optional[PathLike] = None,
        *,
        report: Optional[PathLike] = None,
        overlay: Optional[PathLike] = None,
    ) -> None:
        """Writes the files `grainforce photoelastic` writes."""

def photoelastic(
    image: PathLike,
    scene: PathLike,
    *,
    fsigma: Optional[float] = None,
    thickness: Optional[float] = None,
    scale: Optional[float] = None,
    channel: Optional[Literal["green", "red", "blue", "luma", "auto"]] = None,
    mu: Optional[float] = None,
    balance_weight: Optional[float] = None,
    blur: Optional[float] = None,
    edge: Optional[float] = None,
    iterations: Optional[int] = None,
    per_disk: bool = False,
    contacts: Optional[Literal["all", "evidence"]] = None,
    candidates: Optional[float] = None,
    sparsity: Optional[float] = None,
    wall_mu: Optional[float] = None,
    polariscope: Optional[Literal["dark", "bright", "auto"]] = None,
    lighting: bool = False,
    penalty_start: Optional[float] = None,
    narrow_start: Optional[float] = None,
) -> Photoelastic:
    """Contact forces fitted to a photoelastic photograph's fringes (`grainforce photoelastic`).

    `None` keeps the CLI's default: `mu` 1 where the scene gives none; where
    disks are left flagged, second starts (`penalty_start` 10, `narrow_start`
    0.3; 0 turns one off), the lower residual kept (report `second_starts`).
    """
