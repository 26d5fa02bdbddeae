"""Every bad argument gets a Python exception with a clear message (the CLI's, where it has one)."""

import errno

import numpy as np
import pytest

import spsr
from conftest import fibonacci_sphere

POINTS, NORMALS = fibonacci_sphere(2_000)


def rec(**kw):
    return spsr.reconstruct(POINTS, NORMALS, **{"depth": 4, **kw})


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"depth": 0}, "invalid parameter --depth: 0 is outside 1..=18"),
        ({"depth": 19}, "invalid parameter --depth: 19 is outside 1..=18"),
        ({"depth": -1}, "invalid parameter --depth: -1 is outside 1..=18"),
        ({"full_depth": 5}, "invalid parameter --full-depth: 5 is deeper than --depth 4"),
        ({"full_depth": -2}, "invalid parameter --full-depth"),
        ({"samples_per_node": 0.0}, "invalid parameter --samples-per-node: 0 must be a positive number"),
        ({"samples_per_node": float("nan")}, "invalid parameter --samples-per-node"),
        ({"point_weight": -1.0}, "invalid parameter --point-weight: -1 must be zero or a positive number"),
        ({"degree": 3}, "invalid parameter --degree: 3 is not supported; use 1 or 2"),
        ({"degree": -1}, "invalid parameter --degree: -1 is not supported"),
        ({"boundary": "periodic"}, "invalid parameter --boundary: 'periodic' is not one of neumann, dirichlet, free"),
        ({"scale": 0.5}, "invalid parameter --scale: 0.5 must be at least 1"),
        ({"iters": 0}, "invalid parameter --iters: 0 is outside 1..=10000"),
        ({"iters": -3}, "invalid parameter --iters: -3 is outside 1..=10000"),
        ({"max_memory": 0}, "invalid parameter --max-memory: 0 bytes cannot hold any reconstruction"),
        ({"max_memory": -5}, "invalid parameter --max-memory: must be a positive size"),
        ({"max_memory": "lots"}, "invalid parameter --max-memory: 'lots' is not a size such as 512M or 8G"),
        ({"max_memory": "-1G"}, "invalid parameter --max-memory: must be a positive size"),
        ({"data_pull": 0.0}, "invalid parameter --data-pull: 0 must be a positive number"),
        ({"confidence_property": ""}, "invalid parameter --confidence-property: the property name is empty"),
        ({"confidence_property": "quality"}, "the points have no property 'quality'"),
        ({"trim": "sometimes"}, "invalid parameter --trim: 'sometimes' is neither a density value"),
        ({"trim": float("inf")}, "invalid parameter --trim: must be a finite density value"),
        ({"trim": "auto", "min_island_area": 1.5}, "invalid parameter --min-island-area"),
        ({"trim": "auto", "hole_area": -0.1}, "invalid parameter --hole-area"),
        ({"threads": 0}, "invalid parameter threads: must be at least 1, got 0"),
    ],
)
def test_bad_parameters(kw, message):
    with pytest.raises(ValueError) as info:
        rec(**kw)
    assert message in str(info.value)


@pytest.mark.parametrize(
    "kw",
    [{"depth": "8"}, {"depth": 8.5}, {"density": 1}, {"boundary": 3}, {"scale": "big"}, {"max_memory": True}],
)
def test_wrong_types(kw):
    with pytest.raises(TypeError):
        rec(**kw)


def test_memory_limit():
    with pytest.raises(MemoryError, match="--depth"):
        spsr.reconstruct(POINTS, NORMALS, depth=12, max_memory="1M")


@pytest.mark.parametrize(
    "points, normals, message",
    [
        (POINTS[:, :2], NORMALS, r"points must be an array of shape \(N, 3\), got shape \(2000, 2\)"),
        (POINTS.ravel(), NORMALS, r"points must be an array of shape \(N, 3\)"),
        (POINTS[None], NORMALS, r"points must be an array of shape \(N, 3\)"),
        (POINTS.astype(complex), NORMALS, "points must hold real numbers, got dtype complex128"),
        (np.array([["a", "b", "c"]]), NORMALS[:1], "points must hold real numbers"),
        ([[1, 2, 3], [4, 5]], NORMALS[:2], "points must be an array of numbers"),
        (POINTS, None, "the points have no normals"),
        (POINTS, NORMALS[:-1], "length mismatch: 2000 positions but 1999 normals"),
        (POINTS, NORMALS[:, :1], r"normals must be an array of shape \(N, 3\)"),
        (POINTS[:3], NORMALS[:3], "too few usable points: 3 usable, 0 dropped"),
        (np.full((4, 3), np.nan), NORMALS[:4], "too few usable points: 0 usable, 4 dropped"),
        (POINTS[:3], np.zeros((3, 3)), "too few usable points"),
        (np.ones((10, 3)), NORMALS[:10], "degenerate input"),
        (np.zeros((0, 3)), np.zeros((0, 3)), "too few usable points"),
    ],
)
def test_bad_arrays(points, normals, message):
    with pytest.raises(ValueError, match=message):
        spsr.reconstruct(points, normals, depth=4)


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"colors": np.zeros((2000, 2))}, r"colors must be an array of shape \(N, 3\) or \(N, 4\)"),
        ({"colors": np.zeros((10, 3))}, "colors has 10 rows but there are 2000 points"),
        ({"colors": np.full((2000, 3), 70000)}, "integer colours must lie in"),
        ({"weights": np.ones(5)}, "has 5 values but there are 2000 points"),
        ({"weights": np.ones((2000, 2))}, "must be a 1-D array"),
        ({"weights": np.ones(2000), "confidence_property": "x"}, "cannot be used together"),
        ({"point_attributes": {"t": np.ones(3)}}, "attribute 't' has 3 values but there are 2000 points"),
        ({"point_attributes": {"": np.ones(2000)}}, "attribute names must be non-empty strings"),
        ({"point_attributes": {"t": np.array(["x"] * 2000)}}, "attribute 't' must hold real numbers"),
        ({"colors": np.zeros((2000, 3)), "point_attributes": {"Red": np.ones(2000)}}, "given twice"),
    ],
)
def test_bad_per_point_data(kw, message):
    with pytest.raises(ValueError, match=message):
        rec(**kw)


def test_bad_meshes(sphere_mesh):
    with pytest.raises(ValueError, match="faces refer to vertex 4, but there are 4 vertices"):
        spsr.Mesh(np.zeros((4, 3)), [[0, 1, 4]])
    with pytest.raises(ValueError, match="faces refer to vertex -1"):
        spsr.Mesh(np.zeros((4, 3)), [[0, 1, -1]])
    with pytest.raises(ValueError, match="faces must hold integers"):
        spsr.Mesh(np.zeros((4, 3)), [[0.0, 1.0, 2.0]])
    with pytest.raises(ValueError, match=r"faces must be an integer array of shape \(M, 3\)"):
        spsr.Mesh(np.zeros((4, 3)), [[0, 1, 2, 3]])
    with pytest.raises(ValueError, match="density has 3 values but there are 4 vertices"):
        spsr.Mesh(np.zeros((4, 3)), [[0, 1, 2]], density=np.zeros(3))
    with pytest.raises(ValueError, match="normals has 2 rows but there are 4 vertices"):
        spsr.Mesh(np.zeros((4, 3)), [[0, 1, 2]], normals=np.zeros((2, 3)))
    no_density = spsr.Mesh(sphere_mesh.vertices, sphere_mesh.faces)
    with pytest.raises(ValueError, match="density"):
        spsr.trim(no_density)
    with pytest.raises(ValueError, match="invalid parameter --trim"):
        spsr.trim(sphere_mesh, "half")
    with pytest.raises(ValueError, match="invalid parameter --min-island-area"):
        spsr.trim(sphere_mesh, min_island_area=1.0)
    with pytest.raises(TypeError, match="spsr.Mesh or the path"):
        spsr.trim(42)
    with pytest.raises(TypeError, match="mesh must be an spsr.Mesh"):
        spsr.write_mesh("x.ply", "not a mesh")


def test_bad_eval(sphere_mesh):
    with pytest.raises(ValueError, match="no reference"):
        spsr.eval(sphere_mesh)
    with pytest.raises(ValueError, match="cannot be used together"):
        spsr.eval(sphere_mesh, sphere_mesh, sphere=(0, 0, 0, 1))
    with pytest.raises(ValueError, match="instead of 4"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 1))
    with pytest.raises(ValueError, match="positive radius"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, -1))
    with pytest.raises(ValueError, match="invalid parameter --samples: must be at least 1, got 0"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, 1), samples=0)
    with pytest.raises(ValueError, match="the mesh has no faces"):
        spsr.eval(spsr.Mesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=int)), sphere=(0, 0, 0, 1))
    with pytest.raises(ValueError, match="seed"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, 1), seed=-1)


def test_file_errors(tmp_path, sphere_mesh):
    missing = tmp_path / "missing.ply"
    with pytest.raises(OSError) as info:
        spsr.read_points(missing)
    assert isinstance(info.value, FileNotFoundError)
    assert info.value.errno == errno.ENOENT and str(info.value).startswith(f"{missing}: ")
    with pytest.raises(OSError, match="is a directory"):
        spsr.read_points(tmp_path)
    with pytest.raises(OSError):
        spsr.read_mesh(missing)
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\nfoo\n")
    with pytest.raises(spsr.FileFormatError) as info:
        spsr.read_points(bad)
    assert isinstance(info.value, OSError) and isinstance(info.value, ValueError)
    assert str(bad) in str(info.value)
    with pytest.raises(OSError, match="missing-dir"):
        spsr.write_mesh(tmp_path / "missing-dir" / "m.ply", sphere_mesh)
    with pytest.raises(OSError):
        spsr.write_mesh(tmp_path, sphere_mesh)
    assert not (tmp_path / "missing-dir").exists()
