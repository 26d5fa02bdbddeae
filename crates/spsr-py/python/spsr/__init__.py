"""Screened Poisson surface reconstruction from Python.

spsr turns an oriented point cloud (points with outward normals) into a watertight triangle
mesh by the method of Kazhdan & Hoppe (ACM Transactions on Graphics, 2013), with the
parameters and defaults of the reference implementation, PoissonRecon 18. The work is done
by the Rust library of the same name; NumPy arrays go in and come out.

Examples
--------
>>> import numpy as np, spsr
>>> rng = np.random.default_rng(0)
>>> normals = rng.normal(size=(20000, 3))
>>> normals /= np.linalg.norm(normals, axis=1, keepdims=True)
>>> mesh = spsr.reconstruct(normals, normals, depth=6)   # unit sphere: points == normals
>>> mesh.vertices.shape[1], mesh.faces.dtype
(3, dtype('int32'))

Functions
---------
reconstruct
    Oriented points to a watertight mesh.
trim
    Remove the surface invented where there were no samples (needs a density).
estimate_normals
    Normals for points that have none, oriented outward or towards the sensor.
eval
    Score a mesh against a reference mesh or sphere.
render
    A shaded picture of a mesh (an RGBA array), on the CPU.
read_points, read_mesh, write_mesh, write_points
    Files: PLY, text, LAS/LAZ, E57 and PCD point clouds in; PLY, OBJ, STL and GLB meshes out.

Errors are raised as ``ValueError`` (bad arrays or parameters), ``OSError`` (files),
``FileFormatError`` (malformed files; both of those) and ``MemoryError`` (a run that would
exceed ``max_memory``). Their messages name the keyword at fault, its value and what is
allowed (``invalid parameter depth=0: expected an integer from 1 to 18``). The GIL is released
while the library works, and Ctrl-C stops a reconstruction (``KeyboardInterrupt``).
"""

from __future__ import annotations

import os
import warnings
from typing import TYPE_CHECKING, Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _spsr

if TYPE_CHECKING:  # pragma: no cover
    import numpy.typing as npt

    ArrayLike = npt.ArrayLike
else:
    ArrayLike = Any

__all__ = [
    "MAX_DEPTH",
    "FileFormatError",
    "Grid",
    "Mesh",
    "PointCloud",
    "estimate_normals",
    "eval",
    "read_mesh",
    "read_points",
    "reconstruct",
    "render",
    "trim",
    "write_mesh",
    "write_points",
]

__version__: str = _spsr.__version__

#: Deepest octree depth accepted by :func:`reconstruct`.
MAX_DEPTH: int = _spsr.MAX_DEPTH

PathLike = Union[str, "os.PathLike[str]"]


class FileFormatError(OSError, ValueError):
    """A file's content is malformed (bad header, truncated body, unparsable number), or a
    point file has no normals where they are needed.

    Both an ``OSError`` (a problem with a file) and a ``ValueError`` (bad data), like
    ``io.UnsupportedOperation``.
    """


# --------------------------------------------------------------------------------------
# Array helpers

_FLOATS = (np.dtype(np.float32), np.dtype(np.float64))
_COLUMN_TYPES = tuple(
    np.dtype(t)
    for t in (np.uint8, np.int8, np.uint16, np.int16, np.uint32, np.int32, np.float32, np.float64)
)
_COLOR_FAMILIES = (
    ("red", "green", "blue", "alpha"),
    ("r", "g", "b", "a"),
    ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"),
)


def _native(a: np.ndarray) -> np.ndarray:
    """`a` in native byte order and aligned (a copy only when it is not)."""
    if a.dtype.isnative and a.flags.aligned:
        return a
    return np.require(a, a.dtype.newbyteorder("="), ["A"])


def _real_array(x: ArrayLike, what: str) -> np.ndarray:
    try:
        a = np.asarray(x)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be an array of numbers: {e}") from None
    if a.dtype.kind not in "biuf":
        raise ValueError(f"{what} must hold real numbers, got dtype {a.dtype}")
    return _native(a)


def _rows3(x: ArrayLike, what: str, count: Optional[int] = None, count_of: str = "") -> np.ndarray:
    """An (N, 3) float32 or float64 array; float32 and float64 input is used as it is."""
    a = _real_array(x, what)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{what} must be an array of shape (N, 3), got shape {a.shape}")
    if a.dtype not in _FLOATS:
        a = a.astype(np.float64)
    if count is not None and a.shape[0] != count:
        raise ValueError(f"{what} has {a.shape[0]} rows but there are {count} {count_of}")
    return a


def _column(x: ArrayLike, what: str, count: int, count_of: str) -> np.ndarray:
    """A 1-D array in one of the library's attribute types."""
    a = _real_array(x, what)
    if a.ndim != 1:
        raise ValueError(f"{what} must be a 1-D array, got shape {a.shape}")
    if a.shape[0] != count:
        raise ValueError(f"{what} has {a.shape[0]} values but there are {count} {count_of}")
    if a.dtype not in _COLUMN_TYPES:
        if a.dtype.kind == "b":
            a = a.astype(np.uint8)
        elif a.dtype.kind == "f":
            a = a.astype(np.float32 if a.dtype.itemsize < 4 else np.float64)
        elif a.size == 0 or (a.min() >= np.iinfo(np.int32).min and a.max() <= np.iinfo(np.int32).max):
            a = a.astype(np.int32)
        else:
            a = a.astype(np.float64)
    return a


def _color_columns(colors: ArrayLike, count: int, count_of: str) -> List[Tuple[str, np.ndarray]]:
    """(N, 3) or (N, 4) colours as `red green blue [alpha]` columns of one type: integers in
    the full range of their type (uint8: 0-255), floats in [0, 1]."""
    a = _real_array(colors, "colors")
    if a.ndim != 2 or a.shape[1] not in (3, 4):
        raise ValueError(f"colors must be an array of shape (N, 3) or (N, 4), got shape {a.shape}")
    if a.shape[0] != count:
        raise ValueError(f"colors has {a.shape[0]} rows but there are {count} {count_of}")
    if a.dtype not in (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.float32), np.dtype(np.float64)):
        if a.dtype.kind == "f":
            a = a.astype(np.float32)
        elif a.size and (a.min() < 0 or a.max() > 65535):
            raise ValueError("colors: integer colours must lie in 0-255 (uint8) or 0-65535 (uint16)")
        else:
            a = a.astype(np.uint8 if a.size == 0 or a.max() <= 255 else np.uint16)
    names = _COLOR_FAMILIES[0][: a.shape[1]]
    return [(name, np.ascontiguousarray(a[:, k])) for k, name in enumerate(names)]


def _split_colors(columns: Sequence[Tuple[str, np.ndarray]]) -> Tuple[Optional[np.ndarray], Dict[str, np.ndarray]]:
    """Colour channels found among `columns` (stacked as (N, 3) or (N, 4)), and the rest."""
    by_name = {name.lower(): (name, array) for name, array in columns}
    for family in _COLOR_FAMILIES:
        if all(n in by_name for n in family[:3]):
            names = [n for n in family if n in by_name]
            channels = [by_name[n][1] for n in names]
            if len({c.dtype for c in channels}) == 1:
                colors = np.stack(channels, axis=1)
            else:  # mixed types: floats in [0, 1]
                colors = np.stack([_unit(c) for c in channels], axis=1)
            taken = {by_name[n][0] for n in names}
            rest = {name: array for name, array in columns if name not in taken}
            return colors, rest
    return None, dict(columns)


def _unit(c: np.ndarray) -> np.ndarray:
    if c.dtype.kind in "iu":
        return np.clip(c / np.iinfo(c.dtype).max, 0.0, 1.0).astype(np.float32)
    return np.clip(c, 0.0, 1.0).astype(np.float32)


def _columns(
    colors: Optional[ArrayLike],
    attributes: Optional[Mapping[str, ArrayLike]],
    count: int,
    count_of: str,
) -> List[Tuple[str, np.ndarray]]:
    out: List[Tuple[str, np.ndarray]] = []
    if colors is not None:
        out.extend(_color_columns(colors, count, count_of))
    for name, values in (attributes or {}).items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"attribute names must be non-empty strings, got {name!r}")
        out.append((name, _column(values, f"attribute '{name}'", count, count_of)))
    seen = set()
    for name, _ in out:
        if name.lower() in seen:
            raise ValueError(f"attribute '{name}' is given twice (colors are named red, green, blue, alpha)")
        seen.add(name.lower())
    return out


# --------------------------------------------------------------------------------------
# Meshes and point clouds


class Mesh:
    """A triangle mesh: vertices, faces and optional per-vertex data.

    Parameters
    ----------
    vertices : array_like, shape (V, 3)
        Vertex positions (kept as float32 or float64; other numbers become float64).
    faces : array_like of int, shape (M, 3)
        Triangles as vertex indices, counter-clockwise seen from outside.
    normals : array_like, shape (V, 3), optional
        Per-vertex normals.
    density : array_like, shape (V,), optional
        Per-vertex density (the estimated sampling depth) as computed by
        ``reconstruct(..., density=True)``; :func:`trim` needs it.
    colors : array_like, shape (V, 3) or (V, 4), optional
        Per-vertex colours: uint8 (0-255), uint16 (0-65535) or floats in [0, 1].
    attributes : mapping of str to array_like, shape (V,), optional
        Other per-vertex values, each kept in its own numeric type.

    Attributes
    ----------
    vertices : numpy.ndarray, shape (V, 3)
        float64 for meshes made by spsr.
    faces : numpy.ndarray of int32, shape (M, 3)
        For meshes made by spsr (Open3D's index type).
    normals : numpy.ndarray of float32, shape (V, 3), or None
        Unit normals (``reconstruct(..., vertex_normals=True)``).
    density : numpy.ndarray of float32, shape (V,), or None
        ``reconstruct(..., density=True)``.
    colors : numpy.ndarray, shape (V, 3) or (V, 4), or None
        Colours interpolated from the points' colours, in the points' colour type.
    attributes : dict of str to numpy.ndarray
        Other per-vertex values interpolated from the points (or read from a file).
    grid : Grid or None
        The implicit function on a grid, for ``reconstruct(..., grid_res=R)``.
    stats : dict or None
        For meshes returned by :func:`reconstruct`: ``points``, ``dropped``, ``samples``,
        ``depth`` (the depth used: the one given, or the one ``width`` or ``depth="auto"``
        chose), ``depth_choice`` (how ``width`` or ``depth="auto"`` chose it, in one
        sentence, or None), ``iso_value``, ``mean_sample_depth``, ``nodes_per_depth``, ``stages`` (name and
        seconds of each stage), ``peak_memory`` (bytes after each stage, or None),
        ``work`` (per stage, the bytes it must move at the least and the flops it does by
        the floor model of ``spsr::work``, as ``(bytes, flops)``, or None for a stage without
        a model), ``clusters_per_depth``, ``warnings``, ``diagnosis`` (the checks of the result: ``pieces``, ``closed``,
        ``boundary_edges``, ``on_cube``, the vertices on the bounding cube's faces, and
        ``contradicted_normals``, the share of the normals against the surface),
        ``noise`` (what the noise adaptation measured and changed: ``median``, the
        median noise in the input's units, ``median_cells``, the same in finest cells,
        ``measured``, the share of samples it was measured on, ``adapted``, the share
        whose splat depth was lowered, and ``mean_lowering``, by how many depths on
        average; None with ``noise="off"``)
        and ``trim`` (the trimming's figures, or None). For meshes returned by
        :func:`trim`: ``trim``.

    Examples
    --------
    >>> import numpy as np, spsr
    >>> tetra = spsr.Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
    ...                   [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> tetra
    Mesh(4 vertices, 4 faces)
    """

    __slots__ = (
        "vertices", "faces", "normals", "density", "colors", "attributes", "stats", "grid", "_implicit"
    )

    vertices: np.ndarray
    faces: np.ndarray
    normals: Optional[np.ndarray]
    density: Optional[np.ndarray]
    colors: Optional[np.ndarray]
    attributes: Dict[str, np.ndarray]
    stats: Optional[Dict[str, Any]]
    grid: Optional["Grid"]
    _implicit: Any

    def __init__(
        self,
        vertices: ArrayLike,
        faces: ArrayLike,
        *,
        normals: Optional[ArrayLike] = None,
        density: Optional[ArrayLike] = None,
        colors: Optional[ArrayLike] = None,
        attributes: Optional[Mapping[str, ArrayLike]] = None,
    ) -> None:
        self.vertices = _rows3(vertices, "vertices")
        n = self.vertices.shape[0]
        f = _real_array(faces, "faces")
        if f.size == 0 and f.ndim <= 2:
            f = f.reshape(0, 3)
        if f.ndim != 2 or f.shape[1] != 3:
            raise ValueError(f"faces must be an integer array of shape (M, 3), got shape {f.shape}")
        if f.dtype.kind not in "iu":
            raise ValueError(f"faces must hold integers, got dtype {f.dtype}")
        if f.size and (f.min() < 0 or f.max() >= n):
            bad = int(f.min()) if f.min() < 0 else int(f.max())
            raise ValueError(f"faces refer to vertex {bad}, but there are {n} vertices")
        self.faces = f
        self.normals = None if normals is None else _rows3(normals, "normals", n, "vertices")
        self.density = (
            None if density is None else _column(density, "density", n, "vertices").astype(np.float32, copy=False)
        )
        self.colors = None
        if colors is not None:
            _color_columns(colors, n, "vertices")  # checks
            self.colors = np.asarray(colors)
        self.attributes = {
            name: array for name, array in _columns(None, attributes, n, "vertices")
        }
        self.stats = None
        self.grid = None
        self._implicit = None

    @classmethod
    def _from_native(cls, d: Dict[str, Any]) -> "Mesh":
        mesh = cls.__new__(cls)
        mesh.vertices = d["vertices"]
        mesh.faces = d["faces"]
        mesh.normals = d["normals"]
        mesh.density = d["density"]
        mesh.colors, mesh.attributes = _split_colors(d["attributes"])
        mesh.stats = d.get("stats")
        grid = d.get("grid")
        mesh.grid = None if grid is None else Grid(grid["values"], grid["origin"], grid["spacing"])
        mesh._implicit = d.get("implicit")
        return mesh

    def implicit(
        self, points: ArrayLike, *, gradients: bool = False, threads: Optional[int] = None
    ) -> Union[np.ndarray, Tuple[np.ndarray, np.ndarray]]:
        """The implicit function minus the iso-value at any points, evaluated exactly on the
        reconstruction's octree (not interpolated from a grid); needs a mesh from
        ``reconstruct(..., keep_implicit=True)``.

        Negative inside, positive outside, zero on the surface (the sign convention of
        :class:`Grid` and of signed distances); the values agree with ``grid_res``'s grid at
        its sample points (to float32 rounding). The function is about 1 inside and 0
        outside, so its values are not distances.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            Query points in the input's units. Points outside the bounding cube take the
            value at the nearest point of the cube; points with a non-finite coordinate
            get NaN.
        gradients : bool, default False
            Also return the gradient, per input unit; it points outward (along the
            surface's normal).
        threads : int, optional
            Worker threads (default: all cores). The values do not depend on it.

        Returns
        -------
        numpy.ndarray of float64, shape (N,)
            The values; with ``gradients``, ``(values, gradients)``, gradients of shape
            (N, 3).

        Raises
        ------
        ValueError
            The mesh keeps no implicit function, or ``points`` is not an (N, 3) array.

        Examples
        --------
        >>> mesh = spsr.reconstruct(points, normals, keep_implicit=True)
        >>> inside = mesh.implicit(queries) < 0
        """
        if self._implicit is None:
            raise ValueError(
                "this mesh keeps no implicit function: reconstruct it with keep_implicit=True "
                "(the function holds the octree and its coefficients, so it is kept only when "
                "asked for)"
            )
        q = _rows3(points, "points")
        result: Union[np.ndarray, Tuple[np.ndarray, np.ndarray]] = self._implicit.evaluate(
            q, bool(gradients), threads
        )
        return result

    def _native(self) -> Tuple[Any, ...]:
        n = self.vertices.shape[0]
        columns = _columns(self.colors, self.attributes, n, "vertices")
        density = None if self.density is None else np.asarray(self.density, dtype=np.float32)
        return (self.vertices, self.faces, self.normals, density, columns)

    def __repr__(self) -> str:
        extra = [
            name
            for name in ("normals", "density", "colors", "grid")
            if getattr(self, name) is not None
        ] + sorted(self.attributes)
        if self._implicit is not None:
            extra.append("implicit")
        more = f"; {', '.join(extra)}" if extra else ""
        return f"Mesh({self.vertices.shape[0]} vertices, {self.faces.shape[0]} faces{more})"

    def to_open3d(self) -> Any:
        """The mesh as an ``open3d.geometry.TriangleMesh`` (needs the ``open3d`` package).

        Vertex normals and colours are copied when present (colours as floats in [0, 1]).
        """
        import open3d as o3d  # noqa: PLC0415 (optional dependency)

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(np.asarray(self.vertices, dtype=np.float64)),
            o3d.utility.Vector3iVector(np.asarray(self.faces, dtype=np.int32)),
        )
        if self.normals is not None:
            m.vertex_normals = o3d.utility.Vector3dVector(np.asarray(self.normals, dtype=np.float64))
        if self.colors is not None:
            rgb = np.stack([_unit(np.asarray(self.colors)[:, k]) for k in range(3)], axis=1)
            m.vertex_colors = o3d.utility.Vector3dVector(rgb.astype(np.float64))
        return m

    def to_trimesh(self) -> Any:
        """The mesh as a ``trimesh.Trimesh`` (needs the ``trimesh`` package), without
        processing (no vertex merging); normals and colours are passed on when present."""
        import trimesh  # noqa: PLC0415 (optional dependency)

        kwargs: Dict[str, Any] = {"process": False}
        if self.normals is not None:
            kwargs["vertex_normals"] = self.normals
        if self.colors is not None:
            c = np.asarray(self.colors)
            if c.dtype != np.uint8:
                c = np.stack([_unit(c[:, k]) for k in range(c.shape[1])], axis=1)
                c = np.round(c * 255).astype(np.uint8)
            kwargs["vertex_colors"] = c
        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, **kwargs)


class Grid:
    """The implicit function minus the iso-value, sampled on a regular grid over the bounding
    cube: ``reconstruct(..., grid_res=R).grid``, the arrays that ``spsr reconstruct --grid
    FILE.npz --grid-res R`` writes.

    The grid divides the bounding cube into R x R x R cells and samples the centre of each:
    sample ``(i, j, k)`` lies at ``origin + spacing * (i, j, k)``. Each value is the
    function evaluated on the octree, not interpolated. Negative inside, positive outside.

    Attributes
    ----------
    values : numpy.ndarray of float32, shape (R, R, R)
        Indexed ``[x, y, z]`` (C order: z varies fastest).
    origin : numpy.ndarray of float64, shape (3,)
        The centre of cell (0, 0, 0), in the input's units.
    spacing : float
        The distance between neighbouring samples (the cube's side / R), in the input's
        units.

    Examples
    --------
    >>> g = spsr.reconstruct(points, normals, grid_res=64).grid
    >>> inside = g.values < 0                          # occupancy, (64, 64, 64) booleans
    >>> np.savez("grid.npz", values=g.values, origin=g.origin, spacing=g.spacing)  # as --grid
    """

    __slots__ = ("values", "origin", "spacing")

    values: np.ndarray
    origin: np.ndarray
    spacing: float

    def __init__(self, values: np.ndarray, origin: ArrayLike, spacing: float) -> None:
        self.values = values
        self.origin = np.asarray(origin, dtype=np.float64)
        self.spacing = float(spacing)

    @property
    def res(self) -> int:
        """R, the samples along each axis."""
        return int(self.values.shape[0])

    def points(self) -> np.ndarray:
        """The positions of the samples: float64, shape (R, R, R, 3), indexed as ``values``."""
        axis = np.arange(self.res, dtype=np.float64) * self.spacing
        x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
        return np.stack([x, y, z], axis=-1) + self.origin

    def __repr__(self) -> str:
        r = self.res
        o = ", ".join(f"{v:.6g}" for v in self.origin)
        return f"Grid({r}x{r}x{r}, origin ({o}), spacing {self.spacing:.6g})"


class PointCloud:
    """Points read from a file by :func:`read_points`.

    Attributes
    ----------
    points : numpy.ndarray of float64, shape (N, 3)
        Positions, in the file's frame and units.
    normals : numpy.ndarray of float64, shape (N, 3), or None
        Normals, when the file has them.
    colors : numpy.ndarray, shape (N, 3) or (N, 4), or None
        Colours, in the file's type (uint8 0-255, uint16 0-65535, floats in [0, 1]).
    attributes : dict of str to numpy.ndarray
        Every other numeric per-point property, in its own type (intensity, confidence, ...).
    scan_origins : list of (int, tuple of float)
        For files that record where the scanner stood (E57 poses, PCD viewpoints): the
        first point of each scan and the sensor position.

    Notes
    -----
    ``spsr.reconstruct(cloud)`` takes the normals, colours and attributes from the cloud.
    Invalid points (non-finite values, zero normals) are kept, so that the cloud matches
    the file point for point; the reconstruction drops them with a warning.
    """

    __slots__ = ("points", "normals", "colors", "attributes", "scan_origins")

    points: np.ndarray
    normals: Optional[np.ndarray]
    colors: Optional[np.ndarray]
    attributes: Dict[str, np.ndarray]
    scan_origins: List[Tuple[int, Tuple[float, float, float]]]

    def __init__(
        self,
        points: ArrayLike,
        normals: Optional[ArrayLike] = None,
        *,
        colors: Optional[ArrayLike] = None,
        attributes: Optional[Mapping[str, ArrayLike]] = None,
    ) -> None:
        self.points = _rows3(points, "points")
        n = self.points.shape[0]
        self.normals = None if normals is None else _rows3(normals, "normals", n, "points")
        self.colors = None
        if colors is not None:
            _color_columns(colors, n, "points")
            self.colors = np.asarray(colors)
        self.attributes = dict(_columns(None, attributes, n, "points"))
        self.scan_origins = []

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __repr__(self) -> str:
        extra = [n for n in ("normals", "colors") if getattr(self, n) is not None] + sorted(self.attributes)
        more = f"; {', '.join(extra)}" if extra else ""
        return f"PointCloud({len(self)} points{more})"


# --------------------------------------------------------------------------------------
# Functions


def _parse_size(size: Union[int, str, None]) -> Optional[int]:
    """`max_memory`: bytes, or a size such as '512M' or '8G' (binary units, as the CLI)."""
    if size is None:
        return None
    if isinstance(size, bool):
        raise TypeError("max_memory must be a number of bytes or a size such as '8G'")
    if isinstance(size, str):
        t = size.strip()
        body = t.upper()
        if body.endswith("IB"):
            body = body[:-2]
        body = body.rstrip("B")
        mul = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}.get(body[-1:], 1)
        if mul != 1:
            body = body[:-1]
        try:
            v = float(body.strip())
        except ValueError:
            v = float("nan")
        if not (np.isfinite(v) and v > 0):
            raise ValueError(
                f"invalid parameter max_memory={size!r}: expected a positive number of bytes or a "
                "size such as '512M' or '8G'"
            )
        return int(v * mul)
    try:
        return int(size.__index__())  # type: ignore[union-attr]
    except AttributeError:
        raise TypeError("max_memory must be a number of bytes or a size such as '8G'") from None


def _method_keywords(**params: Any) -> Dict[str, Any]:
    """The method's keywords of :func:`reconstruct` (its parameters, as opposed to the
    data, the trimming and the threads) as the native side takes them: one dict, with
    ``max_memory`` in bytes. :mod:`spsr.distributed` passes the same."""
    params["max_memory"] = _parse_size(params.get("max_memory"))
    return params


def reconstruct(
    points: Union[ArrayLike, PointCloud],
    normals: Optional[ArrayLike] = None,
    *,
    depth: Union[int, str, None] = None,
    width: Optional[float] = None,
    full_depth: Optional[int] = None,
    samples_per_node: Optional[float] = None,
    point_weight: Optional[float] = None,
    degree: int = 1,
    boundary: str = "neumann",
    scale: float = 1.1,
    iters: Optional[int] = None,
    confidence: bool = False,
    density: bool = False,
    linear_fit: bool = False,
    max_memory: Union[int, str, None] = None,
    two_level_splat: bool = False,
    attributes: bool = True,
    data_pull: float = 32.0,
    vertex_normals: bool = False,
    confidence_property: Optional[str] = None,
    colors: Optional[ArrayLike] = None,
    weights: Optional[ArrayLike] = None,
    point_attributes: Optional[Mapping[str, ArrayLike]] = None,
    trim: Union[float, str, None] = None,
    min_island_area: float = 0.001,
    hole_area: float = 0.001,
    noise: Optional[str] = None,
    keep_outliers: bool = False,
    keep_normals: bool = False,
    threads: Optional[int] = None,
    solver: str = "cascadic",
    cycles: Optional[int] = None,
    gpu: Union[bool, str] = False,
    grid_res: Optional[int] = None,
    keep_implicit: bool = False,
) -> Mesh:
    """Reconstruct a watertight triangle mesh from oriented points.

    The keywords mirror the fields of the Rust ``spsr::Params`` (and the flags of
    ``spsr reconstruct``), with the same defaults: ``degree`` is ``Params::degree``,
    ``confidence`` and ``confidence_property`` together are ``Params::weights``,
    ``vertex_normals`` is ``Params::normals``; ``trim``, ``min_island_area`` and
    ``hole_area`` are ``spsr::trim::TrimParams``. An error names the keyword at fault.

    Parameters
    ----------
    points : array_like, shape (N, 3), or PointCloud
        Point positions. float32 and float64 arrays (any strides) are read in place, other
        numbers are converted to float64. A :class:`PointCloud` (from :func:`read_points`)
        brings its normals, colours and attributes, unless given here.
    normals : array_like, shape (N, 3)
        Outward normals, one per point; need not be unit length (with ``confidence`` their
        length is the point's weight). Points with non-finite values or zero normals are
        dropped with a ``RuntimeWarning``.
    depth : int or "auto", optional
        Maximum octree depth; the finest cells are 1/2**depth of the bounding cube. At most
        :data:`MAX_DEPTH` (18). Default 8, as PoissonRecon 6 and 18. ``"auto"`` chooses
        it from the data: the shallowest depth whose finest cells are no wider than the
        points' typical spacing (the median nearest-neighbour distance of 4096 of them), or
        on a clean cloud whose cells' face diagonals are no longer, fewer on a smooth
        surface, lowered until the run fits ``max_memory`` (or the memory available).
        ``stats["depth"]`` is the depth used and ``stats["depth_choice"]`` says why.
    width : float, optional
        The finest cells' width in the input's units, instead of ``depth`` (giving both is
        an error): the depth is the smallest whose cells are no wider, and the bounding cube
        is widened about its centre so that they are exactly this wide, as PoissonRecon's
        ``--width`` (so that runs at one width share one cell size).
    full_depth : int, optional
        The octree is complete down to this depth, where the coarse solve happens.
        Default 5, or ``depth`` when that is smaller.
    samples_per_node : float, optional
        Target samples per octree node (PoissonRecon 18; version 6 used 1.0). Default 1.5.
        Giving it turns the noise adaptation off unless ``noise="adaptive"`` is given too.
    point_weight : float, optional
        Screening weight alpha; 0 gives the unscreened 2006 method. Default 2 * degree.
        Giving it turns the noise adaptation off unless ``noise="adaptive"`` is given too.
    noise : {"adaptive", "off"}, optional
        ``"adaptive"`` measures the noise around every point, splats noisy regions
        coarser and lowers their points' screening weight (clean ones keep full detail),
        and removes pieces under 0.1 % of the mesh's
        area (bubbles left by noise); ``"off"`` is exactly PoissonRecon's behaviour.
        Default adaptive, or off when ``samples_per_node`` or ``point_weight`` is given.
    keep_outliers : bool, default False
        Keep the far outliers (a few points far outside the box that holds the rest)
        instead of leaving them out with a warning.
    keep_normals : bool, default False
        Keep the normals as given even when many point against their neighbours' (by
        default such normals are made consistent, with a warning).
    degree : {1, 2}, default 1
        B-spline degree (PoissonRecon 18; the 2013 paper uses 2).
    boundary : {"neumann", "dirichlet", "free"}, default "neumann"
        Boundary condition on the bounding cube.
    scale : float, default 1.1
        Bounding cube side = largest side of the points' bounding box * scale.
    iters : int, optional
        Gauss-Seidel sweeps per depth in each solver cycle. Default 8 with one cycle (as
        PoissonRecon and the 2013 paper), 4 with more. With more than one cycle the
        deepest depth's first relaxation makes half as many (rounded up): the last cycle
        relaxes it again.
    solver : {"cascadic", "vcycle", "wcycle"}, default "cascadic"
        Shape of the solver's cycles over the depths: coarse to fine (PoissonRecon's
        cascade), V-cycles (each depth also relaxed going down, its residual passed to the
        coarser depths) or W-cycles (the coarser depths visited twice).
    cycles : int, optional
        Solver cycles; the first is the cascade, each further one passes the finer depths'
        solution back to the coarser ones and relaxes every depth again. Default 2 at
        degree 1 (at least as accurate as PoissonRecon at its defaults), 1 at degree 2
        (PoissonRecon's cascade, already as accurate); ``cycles=1, iters=8`` is
        PoissonRecon's solve.
    gpu : bool or "auto", default False
        Solve the depths above the base (right-hand sides and relaxations) on an NVIDIA
        GPU; the mesh is the same bit for bit. True
        raises ``RuntimeError`` where no GPU can be used (a wheel built without the cargo
        feature ``gpu``, no driver, no NVRTC); ``"auto"`` falls back to the CPU with a
        ``RuntimeWarning``.
    confidence : bool, default False
        Use each normal's length as the point's weight.
    density : bool, default False
        Compute the per-vertex density (estimated sampling depth; one unit more means 4
        times more samples per area) into ``Mesh.density``.
    linear_fit : bool, default False
        Place vertices by linear interpolation along cell edges (PoissonRecon's
        ``--linearFit``) instead of the quadratic fit.
    max_memory : int or str, optional
        Refuse (``MemoryError``), before building the octree, a run whose estimated peak
        memory exceeds this many bytes (or a size such as ``"512M"``, ``"8G"``). Default:
        the memory the machine has available.
    two_level_splat : bool, default False
        Split each sample between the two depths around its estimated depth (2006 paper,
        PoissonRecon 6) instead of splatting it whole at the depth above (PoissonRecon 18).
    attributes : bool, default True
        Interpolate the points' colours and other attributes onto the mesh vertices
        (``False`` is the command line's ``--no-attributes``).
    data_pull : float, default 32
        Pull factor of the attribute interpolation (PoissonRecon 18's ``--dataX``).
    vertex_normals : bool, default False
        Compute unit per-vertex normals from the implicit function's gradient into
        ``Mesh.normals`` (``spsr::Params::normals``, the command line's ``--normals``).
    confidence_property : str, optional
        Use this per-point attribute (from ``point_attributes`` or the cloud) as each
        point's weight, instead of ``confidence``. Points whose value is not a positive
        finite number are dropped.
    colors : array_like, shape (N, 3) or (N, 4), optional
        Per-point colours: uint8 (0-255), uint16 (0-65535) or floats in [0, 1]; the mesh's
        colours come back in the same type.
    weights : array_like, shape (N,), optional
        Per-point weights (confidence values); the same as an attribute named
        ``confidence`` together with ``confidence_property="confidence"``.
    point_attributes : mapping of str to array_like, shape (N,), optional
        Other per-point values to interpolate onto the mesh, each in its own numeric type;
        they come back in ``Mesh.attributes``.
    trim : float or "auto", optional
        Trim the mesh where the density is below this value (see :func:`trim`). The
        density is computed for it; ``Mesh.density`` is set only with ``density=True``.
    min_island_area, hole_area : float, default 0.001
        With ``trim``: see :func:`trim`.
    grid_res : int, optional
        Also sample the implicit function minus the iso-value at the cell centres of an
        R x R x R grid over the bounding cube, into ``Mesh.grid`` (a :class:`Grid`: negative
        inside, positive outside), as ``spsr reconstruct --grid FILE.npz --grid-res R``. At
        least 2; refused when R**3 float32 values exceed ``max_memory`` (or the memory
        available).
    keep_implicit : bool, default False
        Keep the solved implicit function with the mesh, so that :meth:`Mesh.implicit`
        evaluates it at any points afterwards. It holds the octree and its coefficients
        (about the run's peak memory, less the points), freed with the mesh, so it is
        kept only when asked for.
    threads : int, optional
        Worker threads (default: all cores). The result does not depend on it.

    Returns
    -------
    Mesh
        ``vertices`` (float64, (V, 3)), ``faces`` (int32, (M, 3)), ``density``,
        ``normals``, ``colors`` and ``attributes`` as requested, ``grid`` with
        ``grid_res``, and ``stats``.

    Raises
    ------
    ValueError
        Bad arrays or parameter values (``depth`` and ``width`` together, a ``grid_res``
        under 2 or too large for the memory), too few usable points (at least 4), points
        that span no volume.
    MemoryError
        The estimated memory of the run exceeds ``max_memory``.
    KeyboardInterrupt
        Ctrl-C; the reconstruction stops at its next stage or solver depth.

    Examples
    --------
    >>> mesh = spsr.reconstruct(points, normals, depth=9, density=True)
    >>> mesh.vertices.shape, mesh.faces.shape, mesh.density.shape
    """
    cloud: Optional[PointCloud] = points if isinstance(points, PointCloud) else None
    if cloud is not None:
        positions: np.ndarray = cloud.points
        if normals is None:
            normals = cloud.normals
        if colors is None:
            colors = cloud.colors
        if point_attributes is None:
            point_attributes = cloud.attributes
    else:
        positions = _rows3(points, "points")
    n = positions.shape[0]
    if normals is None:
        raise ValueError(
            "the points have no normals (nx, ny, nz); spsr needs oriented points: pass normals= "
            "(an (N, 3) array of outward normals), e.g. from spsr.estimate_normals(points)"
        )
    normal_rows = _rows3(normals, "normals")
    if normal_rows.shape[0] != n:
        # The library's own message.
        raise ValueError(f"length mismatch: {n} positions but {normal_rows.shape[0]} normals")
    point_attributes = dict(point_attributes or {})
    weight_name = None
    if weights is not None:
        weight_name = "confidence"
        if any(k.lower() == weight_name for k in point_attributes):
            raise ValueError("weights= and an attribute named 'confidence' cannot be used together")
        if confidence_property is not None:
            raise ValueError("weights= and confidence_property= cannot be used together; give one")
        point_attributes[weight_name] = weights
        confidence_property = weight_name
    columns = _columns(colors, point_attributes, n, "points")
    out = _spsr.reconstruct(
        positions,
        normal_rows,
        columns,
        params=_method_keywords(
            depth=depth,
            width=width,
            grid_res=grid_res,
            full_depth=full_depth,
            samples_per_node=samples_per_node,
            point_weight=point_weight,
            noise=noise,
            keep_outliers=keep_outliers,
            keep_normals=keep_normals,
            degree=degree,
            boundary=boundary,
            scale=scale,
            iters=iters,
            confidence=confidence,
            density=density,
            linear_fit=linear_fit,
            max_memory=max_memory,
            two_level_splat=two_level_splat,
            attributes=attributes,
            data_pull=data_pull,
            vertex_normals=vertex_normals,
            confidence_property=confidence_property,
            solver=solver,
            cycles=cycles,
            gpu=gpu,
        ),
        threads=threads,
        trim=trim,
        min_island_area=min_island_area,
        hole_area=hole_area,
        keep_implicit=bool(keep_implicit),
    )
    if weight_name is not None:
        out["attributes"] = [(k, v) for k, v in out["attributes"] if k != weight_name]
    mesh = Mesh._from_native(out)
    stats = mesh.stats or {}
    # Dropped points and far outliers, in Python's words (depth=, not --depth).
    for w in stats.get("warnings", []):
        warnings.warn(w, RuntimeWarning, stacklevel=2)
    return mesh


def estimate_normals(
    points: Union[ArrayLike, PointCloud],
    *,
    neighbours: Optional[int] = None,
    orient: Optional[str] = None,
    viewpoint: Optional[Sequence[float]] = None,
    scan_origins: Optional[Sequence[Tuple[int, Sequence[float]]]] = None,
    threads: Optional[int] = None,
    return_info: bool = False,
) -> Any:
    """Estimate outward normals for points that have none, as ``spsr normals``.

    A plane is fitted to each point's nearest neighbours (principal component analysis),
    which gives each point a normal line; then the signs are chosen so that the normals
    point outward, or towards the sensor (``spsr::normals``).

    Parameters
    ----------
    points : array_like, shape (N, 3), or PointCloud
        Positions. A :class:`PointCloud` read from a file that records where the scanner
        stood (E57 scan poses, PCD ``VIEWPOINT``) brings its ``scan_origins``.
    neighbours : int, optional
        Neighbours in each plane fit, at least 3. Default: chosen from the noise (16 on
        clean clouds, 24 to 192 on noisy ones).
    orient : {"mst", "viewpoint", "global", "none"}, optional
        How to choose the signs. ``"mst"``: propagation along a minimum spanning tree of the
        neighbour graph, each connected piece turned outward (Hoppe et al. 1992).
        ``"viewpoint"``: every normal towards ``viewpoint``, or towards its scan's sensor
        position (``scan_origins``). ``"global"``: ``"mst"`` corrected by the indicator
        function of Poisson reconstructions (right on thin parts and nearby sheets; slower).
        ``"none"``: arbitrary signs. Default: ``"viewpoint"`` when ``viewpoint`` is given or
        scan positions are known, else ``"mst"``.
    viewpoint : (x, y, z), optional
        The sensor position, for ``orient="viewpoint"``.
    scan_origins : sequence of (int, (x, y, z)), optional
        ``(first point, sensor position)`` per scan, in increasing order of first point.
    threads : int, optional
        Worker threads (default: all cores). The result does not depend on it.
    return_info : bool, default False
        Also return a dict: ``orientation``, ``neighbours`` (used in each fit), ``noisy``,
        ``degenerate`` and ``non_finite`` (point counts), and the orientation's ``flipped``,
        ``components``, ``skipped`` and ``corrections``.

    Returns
    -------
    numpy.ndarray of float64, shape (N, 3)
        Unit normals in input order (zero for points with a non-finite coordinate, which
        the reconstruction then drops); with ``return_info``, ``(normals, info)``.

    Raises
    ------
    ValueError
        Fewer than 3 finite points, all points on one line, or a bad parameter.

    Examples
    --------
    >>> normals = spsr.estimate_normals(points)
    >>> mesh = spsr.reconstruct(points, normals, depth=9)
    """
    if isinstance(points, PointCloud):
        if scan_origins is None and points.scan_origins:
            scan_origins = points.scan_origins
        positions = points.points
    else:
        positions = _rows3(points, "points")
    vp = None
    if viewpoint is not None:
        v = [float(x) for x in viewpoint]
        if len(v) != 3:
            raise ValueError(f"viewpoint must be (x, y, z), got {len(v)} values")
        if not all(np.isfinite(v)):
            raise ValueError(f"viewpoint must be three finite numbers, got {tuple(v)}")
        vp = (v[0], v[1], v[2])
    origins = None
    if scan_origins is not None:
        origins = []
        for first, origin in scan_origins:
            o = [float(x) for x in origin]
            if len(o) != 3:
                raise ValueError(f"scan_origins: each position must be (x, y, z), got {len(o)} values")
            origins.append((int(first), (o[0], o[1], o[2])))
    info = _spsr.estimate_normals(
        positions, neighbours=neighbours, orient=orient, viewpoint=vp, scan_origins=origins, threads=threads
    )
    normals = info.pop("normals")
    return (normals, info) if return_info else normals


def _mesh_arg(mesh: Union[Mesh, PathLike], what: str) -> Mesh:
    if isinstance(mesh, Mesh):
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        return read_mesh(mesh)
    raise TypeError(f"{what} must be an spsr.Mesh or the path of a PLY mesh, got {type(mesh).__name__}")


def trim(
    mesh: Union[Mesh, PathLike],
    threshold: Union[float, str] = "auto",
    *,
    min_island_area: float = 0.001,
    hole_area: float = 0.001,
    threads: Optional[int] = None,
) -> Mesh:
    """Remove the surface that a reconstruction invented where there were no samples.

    The mesh is cut along the line where the density equals ``threshold`` (new vertices on
    the crossing edges, every per-vertex value interpolated) and the part below is removed;
    then kept pieces smaller than ``min_island_area`` of the total area are removed and
    removed regions inside kept surface smaller than ``hole_area`` are restored, as
    PoissonRecon's SurfaceTrimmer does.

    Parameters
    ----------
    mesh : Mesh or path
        A mesh with a density: ``reconstruct(..., density=True)``, or a PLY file with a
        vertex property ``density`` (``spsr reconstruct --density``).
    threshold : float or "auto", default "auto"
        The density level. ``"auto"`` takes median - max(1, 4 * MAD) of the area-weighted
        vertex densities.
    min_island_area : float, default 0.001
        Fraction of the total area, in [0, 1).
    hole_area : float, default 0.001
        Fraction of the total area, in [0, 1).
    threads : int, optional
        Worker threads (default: all cores).

    Returns
    -------
    Mesh
        The trimmed mesh, with the input's ``grid`` and implicit function (trimming
        changes the surface, not the function); ``stats["trim"]`` holds the threshold used (and the median and MAD
        for ``"auto"``), the areas and the counts of cut vertices, islands and holes.

    Raises
    ------
    ValueError
        The mesh has no density or no triangles, or a parameter is out of range.
    """
    m = _mesh_arg(mesh, "mesh")
    out = _spsr.trim(m._native(), threshold, min_island_area, hole_area, threads)
    stats = {"trim": out.pop("trim")}
    result = Mesh._from_native(out)
    result.stats = stats
    # Trimming changes the surface, not the function it was extracted from.
    result.grid = m.grid
    result._implicit = m._implicit
    return result


def eval(  # noqa: A001 (the command line's name)
    mesh: Union[Mesh, PathLike],
    reference: Union[Mesh, PathLike, None] = None,
    *,
    sphere: Optional[Sequence[float]] = None,
    samples: int = 1_000_000,
    seed: int = 1,
    threads: Optional[int] = None,
) -> Dict[str, Any]:
    """Score a mesh against a reference surface, as ``spsr eval --json``.

    Both surfaces are sampled area-uniformly (``samples`` points each, fixed seed) and
    exact point-to-triangle distances are measured.

    Parameters
    ----------
    mesh : Mesh or path
        The mesh to score (a PLY file when a path).
    reference : Mesh or path, optional
        The ground-truth mesh.
    sphere : (cx, cy, cz, r), optional
        An analytic sphere as the reference instead (give one of ``reference`` and
        ``sphere``).
    samples : int, default 1000000
        Samples per surface.
    seed : int, default 1
        Seed of the sampling.
    threads : int, optional
        Worker threads (default: all cores). The result does not depend on it.

    Returns
    -------
    dict
        The fields of ``spsr eval --json``: ``chamfer`` and ``hausdorff`` (and ``*_rel``,
        relative to the reference's bounding-box diagonal), ``mesh_to_reference_mean`` /
        ``_max``, ``reference_to_mesh_mean`` / ``_max``, F-scores at 0.5 % and 1 % of the
        diagonal (``fscore_0_5``, ``precision_0_5``, ``recall_0_5``, ``fscore_1``, ...),
        normal consistency, areas, and the mesh's topology (``closed``,
        ``edge_manifold``, ``vertex_manifold``, ``components``, ``euler``, ...).
    """
    import json

    m = _mesh_arg(mesh, "mesh")
    ref = None if reference is None else _mesh_arg(reference, "reference")._native()
    sph = None
    if sphere is not None:
        s = [float(v) for v in sphere]
        if len(s) != 4:
            raise ValueError(f"sphere must be (cx, cy, cz, r), got {len(s)} values instead of 4")
        sph = ((s[0], s[1], s[2]), s[3])
    if seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed}")
    result: Dict[str, Any] = json.loads(_spsr.evaluate(m._native(), ref, sph, samples, seed, threads))
    return result


def render(
    mesh: Union[Mesh, PathLike, ArrayLike],
    faces: Optional[ArrayLike] = None,
    *,
    view: str = "iso",
    size: Union[int, Tuple[int, int]] = (800, 800),
    color: Optional[str] = None,
    highlight: Optional[str] = None,
    threads: Optional[int] = None,
) -> np.ndarray:
    """A shaded picture of a mesh, drawn on the CPU, as ``spsr render``.

    The camera is orthographic and fitted to the mesh, assuming y is up. Faces are shaded
    flat with a light at the camera; faces seen from behind are terracotta, so flipped or
    inside-out surface shows.

    Parameters
    ----------
    mesh : Mesh, path, or array_like of shape (V, 3)
        The mesh, the path of a PLY mesh, or vertex positions (then give ``faces``).
    faces : array_like of int, shape (M, 3), optional
        Triangles, when ``mesh`` is an array of vertices.
    view : str, default "iso"
        ``"front"`` (looking along -z), ``"side"`` (along -x), ``"top"`` (along -y, the
        front at the bottom), ``"iso"`` (along -(1, 1, 1)), or ``"all"``: the four in a
        2 x 2 grid.
    size : int or (width, height), optional
        Picture size in pixels, each from 1 to 16384; one number for a square. Default
        (800, 800).
    color : str, optional
        ``"density"`` or ``"attribute:NAME"``: that per-vertex value through the viridis
        colour map, between its 2nd and 98th percentiles; ``"plain"``: one colour. Default:
        the mesh's vertex colours when it has them, else plain.
    highlight : str, optional
        ``"pieces"``: every connected piece except the largest in magenta.
    threads : int, optional
        Worker threads (default: all cores). The picture does not depend on it.

    Returns
    -------
    numpy.ndarray of uint8, shape (height, width, 4)
        RGBA, rows from the top, on an opaque white background.

    Examples
    --------
    >>> picture = spsr.render(mesh, view="all", size=(1024, 1024))
    >>> import matplotlib.pyplot as plt; plt.imshow(picture)      # doctest: +SKIP
    """
    if faces is not None:
        m = Mesh(mesh, faces)
    else:
        m = _mesh_arg(mesh, "mesh")  # type: ignore[arg-type]
    if isinstance(size, (int, np.integer)):
        width = height = int(size)
    else:
        try:
            width, height = (int(v) for v in size)
        except (TypeError, ValueError):
            raise ValueError(f"size must be an integer or (width, height), got {size!r}") from None
    if not isinstance(view, str):
        raise TypeError(f"view must be a string, got {type(view).__name__}")
    return _spsr.render(m._native(), view, width, height, highlight, color, threads)


def read_points(path: Union[PathLike, Sequence[PathLike]]) -> PointCloud:
    """Read a point cloud: PLY, text (``.xyz``, ``.txt``, ``.csv``, ...), LAS/LAZ, E57 or PCD,
    or the vertices of a mesh file (OBJ, OFF, STL, GLB; with their normals where the file
    has one per vertex). A list of paths is read as one cloud (the tiles of a survey, as
    ``spsr reconstruct`` reads several inputs): their points one after another; the tiles
    must all have normals or none, and the same attributes.

    The format is recognised by the file's first bytes, else by its extension; anything
    else is read as text.

    Returns
    -------
    PointCloud
        ``normals`` is None when the file has none.

    Raises
    ------
    OSError
        The file cannot be opened or read.
    FileFormatError
        The file is malformed (the message names what is wrong and where).
    """
    if isinstance(path, (str, bytes, os.PathLike)):
        paths = [os.fspath(path)]
    else:
        paths = [os.fspath(p) for p in path]
        if not paths:
            raise ValueError("read_points: no files given")
    d = _spsr.read_cloud(paths)
    cloud = PointCloud.__new__(PointCloud)
    cloud.points = d["positions"]
    cloud.normals = d["normals"]
    cloud.colors, cloud.attributes = _split_colors(d["attributes"])
    cloud.scan_origins = [(int(i), tuple(o)) for i, o in d["scan_origins"]]
    return cloud


def read_mesh(path: PathLike) -> Mesh:
    """Read a triangle mesh: PLY, OBJ, STL, OFF or GLB (polygons are fan-triangulated).

    The format is recognised by the file's first bytes, else by its extension. PLY: a
    vertex property ``density`` fills ``Mesh.density``, ``nx ny nz`` fill ``Mesh.normals``,
    colour properties ``Mesh.colors`` and every other scalar vertex property
    ``Mesh.attributes``. GLB keeps normals, colours and spsr's density; OBJ and OFF normals
    and colours; STL positions only (corners at the same position become one vertex).
    """
    return Mesh._from_native(_spsr.read_mesh(os.fspath(path)))


def write_mesh(path: PathLike, mesh: Mesh, *, ascii: bool = False) -> None:
    """Write a mesh, in the format its extension names.

    ``.ply`` (binary little endian, or ASCII) with normals, colours, attributes and density;
    ``.obj`` (Wavefront OBJ with vertex colours and normals), ``.off`` (OFF with normals and
    colours), ``.stl`` (binary, or ASCII), ``.glb`` (glTF 2.0 binary with normals, colours
    and density). The file appears only when complete (written to a temporary file in the
    same folder, then renamed).

    Raises
    ------
    OSError
        The extension is none of these, the folder does not exist or is not writable, or
        the path is a folder.
    """
    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be an spsr.Mesh, got {type(mesh).__name__}")
    _spsr.write_mesh(os.fspath(path), mesh._native(), bool(ascii))


def write_points(
    path: PathLike,
    points: Union[ArrayLike, PointCloud],
    normals: Optional[ArrayLike] = None,
    *,
    colors: Optional[ArrayLike] = None,
    attributes: Optional[Mapping[str, ArrayLike]] = None,
    ascii: bool = False,
) -> None:
    """Write a point cloud, in the format its extension names.

    ``.ply``: normals, colours and attributes in their own types. ``.xyz`` or ``.txt``:
    text, ``x y z``, then ``nx ny nz`` with normals, then ``r g b`` with normals and
    colours. Any other extension raises ``OSError``. Written atomically, like
    :func:`write_mesh`. ``points`` may be a :class:`PointCloud`.
    """
    if isinstance(points, PointCloud):
        cloud = points
        normals = cloud.normals if normals is None else normals
        colors = cloud.colors if colors is None else colors
        attributes = cloud.attributes if attributes is None else attributes
        positions = cloud.points
    else:
        positions = _rows3(points, "points")
    n = positions.shape[0]
    normal_rows = None if normals is None else _rows3(normals, "normals", n, "points")
    _spsr.write_points(os.fspath(path), positions, normal_rows, _columns(colors, attributes, n, "points"), bool(ascii))
