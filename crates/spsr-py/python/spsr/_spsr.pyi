# Type stubs of the native module `spsr._spsr` (src/). Private: use the functions of
# the `spsr` package, which check and convert their arguments before calling these.
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

__version__: str
MAX_DEPTH: int

_Columns = Sequence[Tuple[str, np.ndarray]]
# (vertices, faces, normals, density, columns)
_MeshArgs = Tuple[np.ndarray, np.ndarray, Optional[np.ndarray], Optional[np.ndarray], _Columns]

# `params`: the method's keywords of spsr.reconstruct (depth (an int, "auto" or None),
# width, grid_res, full_depth, samples_per_node, point_weight, degree, boundary, scale,
# iters, confidence, density, linear_fit, max_memory in bytes, two_level_splat, attributes,
# data_pull, vertex_normals, confidence_property, noise, keep_outliers, keep_normals, solver,
# cycles, gpu (False, True or "auto")), every one given. The result's "grid" is None or a dict (values, origin, spacing);
# its "implicit" is None or an ImplicitFunction (with keep_implicit).
def reconstruct(
    points: np.ndarray,
    normals: np.ndarray,
    columns: _Columns,
    *,
    params: Dict[str, Any],
    threads: Optional[int],
    trim: Optional[object],
    min_island_area: float,
    hole_area: float,
    keep_implicit: bool,
) -> Dict[str, Any]: ...

# The solved implicit function a reconstruction kept (Mesh.implicit).
class ImplicitFunction:
    @property
    def iso_value(self) -> float: ...
    @property
    def cube(self) -> Tuple[Tuple[float, float, float], float]: ...
    # Values (N,), or (values, gradients (N, 3)) with `gradients`.
    def evaluate(
        self, points: np.ndarray, gradients: bool, threads: Optional[int] = None
    ) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]: ...

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
def read_cloud(paths: List[str]) -> Dict[str, Any]: ...
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

# The steps of a slab run on a cluster (spsr.distributed).
def slab_params(params: Dict[str, Any]) -> str: ...
def slab_args(argv: List[str]) -> Union[int, Dict[str, Any]]: ...
def slab_trim(
    trim: Union[float, str, None], min_island_area: float, hole_area: float
) -> Optional[str]: ...
def slab_prepare(
    inputs: List[str],
    work_dir: str,
    slabs: int,
    params: str,
    threads: Optional[int] = None,
    trim: Optional[str] = None,
) -> Tuple[str, int, bool, int]: ...
def slab_step(
    step: str, dir: str, slab: Optional[int] = None, threads: Optional[int] = None
) -> None: ...
def slab_finish(dir: str, output: str) -> Dict[str, Any]: ...
def slab_remove(dir: str) -> None: ...
