"""Every bad argument gets a Python exception with a clear message (the CLI's, where it has one)."""

import errno
import re

import numpy as np
import pytest

import spsr
from conftest import fibonacci_sphere

POINTS, NORMALS = fibonacci_sphere(2_000)


def rec(**kw):
    return spsr.reconstruct(POINTS, NORMALS, **{"depth": 4, **kw})


AREA = "a fraction of the total area in [0, 1), such as 0.001"
THRESHOLD = "a density value (a finite number such as 6.5) or 'auto'"
MAX_MEMORY = "a positive number of bytes or a size such as '512M' or '8G'"


# The whole message: the keyword as the user typed it, the value given and what is allowed.
@pytest.mark.parametrize(
    "kw, message",
    [
        ({"depth": 0}, "depth=0: expected an integer from 1 to 18"),
        ({"depth": 19}, "depth=19: expected an integer from 1 to 18"),
        ({"depth": -1}, "depth=-1: expected an integer from 1 to 18"),
        ({"full_depth": 5}, "full_depth=5: expected at most the depth, 4"),
        ({"full_depth": -2}, "full_depth=-2: expected at most the depth, 4"),
        ({"samples_per_node": 0.0}, "samples_per_node=0: expected a positive number"),
        ({"samples_per_node": float("nan")}, "samples_per_node=NaN: expected a positive number"),
        ({"point_weight": -1.0}, "point_weight=-1: expected zero or a positive number"),
        ({"degree": 3}, "degree=3: expected 1 or 2"),
        ({"degree": -1}, "degree=-1: expected 1 or 2"),
        ({"boundary": "periodic"}, "boundary='periodic': expected one of 'neumann', 'dirichlet', 'free'"),
        ({"scale": 0.5}, "scale=0.5: expected a number from 1 to 1000 (the points must lie inside the cube)"),
        ({"iters": 0}, "iters=0: expected an integer from 1 to 10000"),
        ({"iters": -3}, "iters=-3: expected an integer from 1 to 10000"),
        ({"max_memory": 0}, "max_memory=0: expected a positive number of bytes"),
        ({"max_memory": -5}, "max_memory=-5: expected a positive number of bytes"),
        ({"max_memory": "lots"}, f"max_memory='lots': expected {MAX_MEMORY}"),
        ({"max_memory": "-1G"}, f"max_memory='-1G': expected {MAX_MEMORY}"),
        ({"data_pull": 0.0}, "data_pull=0: expected a positive number"),
        (
            {"confidence_property": ""},
            "confidence_property (an empty property name): expected the name of a per-point property",
        ),
        (
            {"confidence_property": "quality"},
            "confidence_property (the property 'quality'): expected a property the points have (they have: none)",
        ),
        ({"trim": "sometimes"}, f"trim='sometimes': expected {THRESHOLD}"),
        ({"trim": float("inf")}, "trim=inf: expected a finite density value, or auto"),
        ({"trim": "auto", "min_island_area": 1.5}, f"min_island_area=1.5: expected {AREA}"),
        ({"trim": "auto", "hole_area": -0.1}, f"hole_area=-0.1: expected {AREA}"),
        ({"threads": 0}, "threads=0: expected an integer of at least 1"),
    ],
)
def test_bad_parameters(kw, message):
    with pytest.raises(ValueError) as info:
        rec(**kw)
    assert str(info.value) == f"invalid parameter {message}"


def test_messages_name_keywords_not_flags(sphere_mesh):
    """The library's field `weights` is `confidence_property=` here; a property the points
    have is named in the message, and no command-line flag appears."""
    with pytest.raises(ValueError) as info:
        rec(point_attributes={"quality": np.ones(2000)}, confidence_property="confidence")
    assert str(info.value).startswith("invalid parameter confidence_property (the property 'confidence')")
    assert "(they have: quality)" in str(info.value)
    # The trimming's threshold is `threshold=` in spsr.trim (`trim=` in reconstruct).
    with pytest.raises(ValueError) as info:
        spsr.trim(sphere_mesh, float("nan"))
    assert str(info.value) == "invalid parameter threshold=NaN: expected a finite density value, or auto"
    with pytest.raises(ValueError, match=r"^invalid parameter threshold \(1000, which removes the whole mesh\)"):
        spsr.trim(sphere_mesh, 1000.0)


@pytest.mark.parametrize(
    "kw",
    [{"depth": 8.5}, {"density": 1}, {"boundary": 3}, {"scale": "big"}, {"max_memory": True}],
)
def test_wrong_types(kw):
    with pytest.raises(TypeError):
        rec(**kw)


def test_memory_limit():
    with pytest.raises(MemoryError) as info:
        spsr.reconstruct(POINTS, NORMALS, depth=12, max_memory="1M")
    message = str(info.value)
    assert message.startswith("this reconstruction needs about ")
    assert "octree nodes at depth=12), more than the max_memory limit (0.00 GiB); " in message
    assert "--" not in message
    assert re.search(r"use depth=\d+ or less, a larger samples_per_node, or raise max_memory$", message) or message.endswith(
        "even the coarsest depth does not fit: raise max_memory or use fewer points"
    )


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
    with pytest.raises(ValueError) as info:
        spsr.trim(no_density)
    assert str(info.value) == "the mesh has no per-vertex density; reconstruct it with density=True to get one"
    with pytest.raises(ValueError) as info:
        spsr.trim(sphere_mesh, "half")
    assert str(info.value) == f"invalid parameter threshold='half': expected {THRESHOLD}"
    with pytest.raises(ValueError) as info:
        spsr.trim(sphere_mesh, None)
    assert str(info.value) == f"invalid parameter threshold=None: expected {THRESHOLD}"
    with pytest.raises(ValueError) as info:
        spsr.trim(sphere_mesh, min_island_area=1.0)
    assert str(info.value) == f"invalid parameter min_island_area=1: expected {AREA}"
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
    with pytest.raises(ValueError, match=r"^invalid parameter sphere \(centre .*radius -1\): expected a finite centre and a positive radius$"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, -1))
    with pytest.raises(ValueError, match="^invalid parameter samples=0: expected at least 1$"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, 1), samples=0)
    with pytest.raises(ValueError, match="^invalid parameter samples=-4: expected at least 1$"):
        spsr.eval(sphere_mesh, sphere=(0, 0, 0, 1), samples=-4)
    with pytest.raises(ValueError, match="the mesh has no triangles"):
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
