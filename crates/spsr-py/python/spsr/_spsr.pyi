# Type stubs of the native module `spsr._spsr` (src/). Private: use the functions of
# the `spsr` package, which check and convert their arguments before calling these.
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

__version__: str
MAX_DEPTH: int

_Columns = Sequence[Tuple[str, np.ndarray]]
# (vertices, faces, normals, density, columns)
_MeshArgs = Tuple[np.ndarray, np.ndarray, Optional[np.ndarray], Optional[np.ndarray], _Columns]

def reconstruct(
    points: np.ndarray,
    normals: np.ndarray,
    columns: _Columns,
    *,
    depth: int,
    full_depth: Optional[int],
    samples_per_node: Optional[float],
    point_weight: Optional[float],
    degree: int,
    boundary: str,
    scale: float,
    iters: int,
    confidence: bool,
    density: bool,
    linear_fit: bool,
    max_memory: Optional[int],
    two_level_splat: bool,
    attributes: bool,
    data_pull: float,
    vertex_normals: bool,
    confidence_property: Optional[str],
    threads: Optional[int],
    trim: Optional[object],
    min_island_area: float,
    hole_area: float,
    noise: Optional[str],
    keep_outliers: bool,
    keep_normals: bool,
    solver: str,
    cycles: int,
) -> Dict[str, Any]: ...
def trim(
    mesh: _MeshArgs,
    threshold: object,
    min_island_area: float,
    hole_area: float,
    threads: Optional[int],
) -> Dict[str, Any]: ...
def evaluate(
    mesh: _MeshArgs,
    reference: Optional[_MeshArgs],
    sphere: Optional[Tuple[Tuple[float, float, float], float]],
    samples: int,
    seed: int,
    threads: Optional[int],
) -> str: ...
def read_cloud(path: str) -> Dict[str, Any]: ...
def read_mesh(path: str) -> Dict[str, Any]: ...
def write_mesh(path: str, mesh: _MeshArgs, ascii: bool) -> None: ...
def write_points(
    path: str,
    points: np.ndarray,
    normals: Optional[np.ndarray],
    attributes: _Columns,
    ascii: bool,
) -> None: ...
def estimate_normals(
    points: np.ndarray,
    *,
    neighbours: Optional[int],
    orient: Optional[str],
    viewpoint: Optional[Tuple[float, float, float]],
    scan_origins: Optional[Sequence[Tuple[int, Tuple[float, float, float]]]],
    threads: Optional[int],
) -> Dict[str, Any]: ...
def render(
    mesh: _MeshArgs,
    view: str,
    width: int,
    height: int,
    highlight: Optional[str],
    color: Optional[str],
    threads: Optional[int],
) -> np.ndarray: ...
def cli_main(argv: List[str]) -> int: ...

# The library's defaults by function and keyword (tests/test_defaults.py checks the
# signatures of the `spsr` functions against them).
def _defaults() -> Dict[str, Dict[str, Any]]: ...
