# The compiled half of grainforce; use the functions of `grainforce` instead.
from typing import Any, Callable, Optional

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
def infer_flags() -> list[tuple[str, bool, Optional[str], list[str], str]]: ...
def infer(
    scene: Scene, argv: list[str], progress: Optional[Callable[[int, int], Any]] = None
) -> tuple[Columns, str]: ...
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
