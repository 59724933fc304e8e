# The compiled half of grainforce; use the functions of `grainforce` instead.
from typing import Any, Callable, Optional, Union

import numpy as np
import numpy.typing as npt

class InfeasibleError(ValueError): ...
class SolverError(RuntimeError): ...

class Scene:
    @property
    def dim(self) -> int: ...
    @property
    def frames(self) -> list[Optional[int]]: ...
    @property
    def n_grains(self) -> int: ...
    @property
    def n_contacts(self) -> int: ...
    def save(self, path: str) -> None: ...
    def __len__(self) -> int: ...

Columns = dict[str, Any]

def read_scene(path: str) -> Scene: ...
class Run:
    def forces(self) -> Columns: ...
    def report(self) -> str: ...
    def failed_frames(self) -> list[tuple[int, str]]: ...
    def impulse_csv(self) -> Optional[str]: ...
    def pareto_csv(self) -> Optional[str]: ...
    def save(
        self,
        forces: Optional[str] = None,
        report: Optional[str] = None,
        impulse: Optional[str] = None,
        pareto: Optional[str] = None,
    ) -> None: ...

def infer_defaults() -> str: ...
def infer(
    scene: Union[Scene, str], options: str, progress: Optional[Callable[[int, int], Any]] = None
) -> Run: ...
def dem(
    preset: str,
    dim: int = 2,
    seed: int = 1,
    grains: Optional[int] = None,
    gate: Optional[float] = None,
    duration: Optional[float] = None,
    frames_every: Optional[int] = None,
    max_steps: Optional[int] = None,
    verbose: bool = False,
) -> tuple[Scene, Columns, str]: ...
def packing(dim: int = 2, grains: int = 1000, seed: int = 1) -> tuple[Scene, Columns]: ...
def detect(
    image: npt.NDArray[np.float64],
    radius_min: float,
    radius_max: float,
    polarity: str = "bright",
    smoothing: Optional[float] = None,
) -> Columns: ...
def write_table(path: str, names: list[str], columns: list[Any]) -> None: ...

class LabelImport:
    def scene(self) -> Scene: ...
    def quality_csv(self) -> str: ...
    @property
    def rattlers(self) -> list[str]: ...
    @property
    def cut(self) -> list[str]: ...
    @property
    def warnings(self) -> list[str]: ...
    def stress_match(self) -> Optional[tuple[str, str]]: ...
    def save(self, path: str) -> None: ...

def import_labels(
    volume: npt.NDArray[Any],
    voxel_size: float,
    origin: Optional[list[float]] = None,
    grey: Optional[npt.NDArray[np.float32]] = None,
    walls: list[str] = ...,
    container: Optional[int] = None,
    density: Optional[float] = None,
    normals: str = "fit",
    max_gap: Optional[float] = None,
    min_grey: float = 0.9,
    stresses: Optional[str] = None,
    match_distance: Optional[float] = None,
    match_transform: str = "rigid",
) -> LabelImport: ...
def import_imaged11(
    path: str,
    cell: list[float],
    stiffness: str,
    grain_volume: Optional[float] = None,
    contacts: Optional[str] = None,
    phase: Optional[str] = None,
) -> Scene: ...

class Photoelastic:
    def forces(self) -> Columns: ...
    def report(self) -> str: ...
    def overlay(self) -> npt.NDArray[np.float32]: ...
    def save(
        self,
        forces: Optional[str] = None,
        report: Optional[str] = None,
        overlay: Optional[str] = None,
    ) -> None: ...

def photoelastic(
    image: str,
    scene: str,
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
) -> Photoelastic: ...
