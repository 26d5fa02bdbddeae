"""The resolution and the implicit function (issue 18): width=, depth="auto", grid_res= and
Mesh.implicit, with the command line's rules and the library's conventions (negative
inside)."""

import warnings

import numpy as np
import pytest

import spsr
from conftest import CENTER, RADIUS, fibonacci_sphere

POINTS, NORMALS = fibonacci_sphere(2_000)


def cube_side(points, scale=1.1):
    """The side of the bounding cube the library puts around `points`."""
    return scale * np.ptp(points, axis=0).max()


def test_a_width_lands_on_the_depth_it_implies():
    """A width of the cube's side / 2**5 is depth 5, the same mesh; a little narrower is one
    depth deeper, a little wider the same depth in a widened cube."""
    side = cube_side(POINTS)
    fixed = spsr.reconstruct(POINTS, NORMALS, depth=5)
    # side / 32 * 32 is side exactly: the cube is not widened.
    m = spsr.reconstruct(POINTS, NORMALS, width=side / 32)
    assert m.stats["depth"] == 5 and fixed.stats["depth"] == 5
    assert m.stats["depth_choice"].startswith("width ")
    assert fixed.stats["depth_choice"] is None
    assert np.array_equal(m.faces, fixed.faces)
    # (The width's scale, 1.1 * cube / cube, may differ from 1.1 in the last bit.)
    assert np.allclose(m.vertices, fixed.vertices, rtol=0, atol=1e-6)
    assert spsr.reconstruct(POINTS, NORMALS, width=side / 32 * 0.99).stats["depth"] == 6
    wider = spsr.reconstruct(POINTS, NORMALS, width=side / 32 * 1.2)
    assert wider.stats["depth"] == 5
    # The cube is widened to 2**5 cells of exactly that width.
    wider = spsr.reconstruct(POINTS, NORMALS, width=side / 32 * 1.2, keep_implicit=True)
    _, widened = wider._implicit.cube
    assert widened == pytest.approx(side * 1.2, rel=1e-12)


def test_auto_depth_is_deeper_for_a_denser_sampling():
    sparse = spsr.reconstruct(POINTS, NORMALS, depth="auto")
    dense = spsr.reconstruct(*fibonacci_sphere(20_000), depth="AUTO")
    assert 2 <= sparse.stats["depth"] < dense.stats["depth"] <= 8
    assert sparse.stats["depth_choice"].startswith(f"depth auto chose depth {sparse.stats['depth']}: ")
    assert "median nearest-neighbour distance" in dense.stats["depth_choice"]


@pytest.fixture(scope="module")
def sphere_with_grid(sphere):
    points, normals = sphere
    return spsr.reconstruct(points, normals, depth=6, grid_res=24, keep_implicit=True)


def test_the_grid_of_a_sphere_changes_sign_at_the_radius(sphere_with_grid):
    g = sphere_with_grid.grid
    assert isinstance(g, spsr.Grid) and g.res == 24
    assert g.values.dtype == np.float32 and g.values.shape == (24, 24, 24)
    assert g.values.flags.c_contiguous
    assert g.origin.dtype == np.float64 and g.origin.shape == (3,)
    assert g.spacing * 24 == pytest.approx(cube_side(sphere_with_grid.vertices), rel=0.02)
    p = g.points()
    assert p.shape == (24, 24, 24, 3)
    assert np.array_equal(p[1, 2, 3], g.origin + g.spacing * np.array([1, 2, 3]))
    # Negative at the sample nearest the centre, positive at the corners.
    r = np.linalg.norm(p - CENTER, axis=-1)
    assert g.values[np.unravel_index(r.argmin(), r.shape)] < 0
    for i, j, k in np.ndindex(2, 2, 2):
        assert g.values[-i, -j, -k] > 0
    # Where neighbours along an axis change sign, the crossing lies within a step of the
    # sphere.
    crossings = 0
    for axis in range(3):
        a = np.moveaxis(g.values, axis, 0).astype(np.float64)
        pa = np.moveaxis(p, axis, 0)
        va, vb = a[:-1], a[1:]
        change = (va < 0) != (vb < 0)
        t = (va / (va - vb))[change][:, None]
        at = pa[:-1][change] + t * (pa[1:][change] - pa[:-1][change])
        err = np.abs(np.linalg.norm(at - CENTER, axis=1) - RADIUS)
        assert err.max() < g.spacing, err.max()
        crossings += len(err)
    assert crossings > 1000
    assert "grid" in repr(sphere_with_grid) and "implicit" in repr(sphere_with_grid)


def test_implicit_agrees_with_the_grid_and_its_gradient_points_out(sphere_with_grid):
    m = sphere_with_grid
    g = m.grid
    values = m.implicit(g.points().reshape(-1, 3))
    assert values.dtype == np.float64 and values.shape == (24**3,)
    assert np.array_equal(values.astype(np.float32).reshape(g.values.shape), g.values)
    # float32 queries read the same.
    v32 = m.implicit(g.points().reshape(-1, 3)[:100].astype(np.float32))
    assert np.allclose(v32, values[:100], atol=1e-6)
    # On the sphere: about zero, the gradient along the outward normal.
    _, dirs = fibonacci_sphere(50)
    on = CENTER + RADIUS * dirs
    v, grad = m.implicit(on, gradients=True)
    assert v.shape == (50,) and grad.shape == (50, 3) and grad.dtype == np.float64
    assert np.abs(v).max() < 0.05
    cos = np.einsum("ij,ij->i", grad, dirs) / np.linalg.norm(grad, axis=1)
    assert cos.min() > 0.95
    assert np.array_equal(v, m.implicit(on))
    # Inside negative, far outside positive; a non-finite point gets NaN.
    v = m.implicit([CENTER, CENTER + 10.0, [np.nan, 0.0, 0.0]])
    assert v[0] < 0 < v[1] and np.isnan(v[2])
    _, grad = m.implicit([[np.inf, 0.0, 0.0]], gradients=True)
    assert np.isnan(grad).all()
    assert m.implicit(np.zeros((0, 3))).shape == (0,)
    assert np.array_equal(m.implicit(on, threads=1), m.implicit(on))


def test_implicit_needs_keep_implicit(sphere_mesh):
    with pytest.raises(ValueError, match=r"keeps no implicit function: reconstruct it with keep_implicit=True"):
        sphere_mesh.implicit([[0.0, 0.0, 0.0]])
    assert sphere_mesh.grid is None
    m = spsr.reconstruct(POINTS, NORMALS, depth=4, keep_implicit=True)
    with pytest.raises(ValueError, match=r"points must be an array of shape \(N, 3\)"):
        m.implicit([0.0, 0.0, 0.0])


def test_trimming_keeps_the_function():
    kept = spsr.reconstruct(POINTS, NORMALS, depth=5, keep_implicit=True, grid_res=4)
    q = [CENTER, CENTER + RADIUS * 0.5]
    trimmed = spsr.reconstruct(POINTS, NORMALS, depth=5, keep_implicit=True, trim="auto", grid_res=4)
    assert trimmed.stats["trim"] is not None and trimmed.density is None
    assert np.array_equal(trimmed.implicit(q), kept.implicit(q))
    assert np.array_equal(trimmed.grid.values, kept.grid.values)
    # spsr.trim hands the function on, too.
    dense = spsr.reconstruct(POINTS, NORMALS, depth=5, keep_implicit=True, density=True)
    assert np.array_equal(spsr.trim(dense).implicit(q), kept.implicit(q))


@pytest.mark.parametrize(
    "kw, message",
    [
        (
            {"depth": 6, "width": 0.1},
            "depth=6 and width=0.1 cannot be used together: a width sets the depth (the smallest "
            "whose cells are no wider); give one",
        ),
        ({"depth": "auto", "width": 0.1}, "depth='auto' and width=0.1 cannot be used together"),
        ({"depth": "deep"}, "invalid parameter depth='deep': expected an integer from 1 to 18, or 'auto'"),
        # A string is a value of depth= now; a number in a string is not one it takes.
        ({"depth": "8"}, "invalid parameter depth='8': expected an integer from 1 to 18, or 'auto'"),
        ({"width": float("nan")}, "invalid parameter width=NaN: expected a positive cell width in the input's units"),
        ({"width": -0.5}, "invalid parameter width=-0.5: expected a positive cell width in the input's units"),
        ({"width": 0.0}, "invalid parameter width=0: expected a positive cell width in the input's units"),
        ({"width": 1e-9}, "invalid parameter width=0.000000001: expected at least "),
        ({"grid_res": 1}, "invalid parameter grid_res=1: expected at least 2 samples along each axis"),
        ({"grid_res": 0}, "invalid parameter grid_res=0: expected at least 2 samples along each axis"),
        ({"grid_res": -3}, "invalid parameter grid_res=-3: expected at least 2 samples along each axis"),
        ({"grid_res": 100_000}, "invalid parameter grid_res=100000: expected at most "),
        (
            {"grid_res": 1000, "max_memory": "1G"},
            "invalid parameter grid_res=1000: expected at most 645: 1000³ float32 values need",
        ),
        ({"grid_res": 10**12}, "invalid parameter grid_res=1000000000000: expected a grid that fits in memory"),
    ],
)
def test_bad_controls(kw, message):
    kw = {"depth": 4, **kw} if "width" not in kw and "depth" not in kw else kw
    with pytest.raises(ValueError) as info:
        spsr.reconstruct(POINTS, NORMALS, **kw)
    assert str(info.value).startswith(message), str(info.value)


def test_a_depth_of_another_type_is_a_type_error():
    with pytest.raises(TypeError, match=r"^depth must be an integer or 'auto', got float$"):
        spsr.reconstruct(POINTS, NORMALS, depth=6.5)


# --- gpu= (issue 17) -------------------------------------------------------------------------


def _gpu_usable():
    try:
        spsr.reconstruct(*fibonacci_sphere(2000), depth=4, gpu=True)
        return True
    except RuntimeError:
        return False


def test_gpu_true_without_a_usable_gpu_is_a_clear_runtime_error():
    if _gpu_usable():
        pytest.skip("a GPU is usable here")
    with pytest.raises(RuntimeError, match="no usable GPU"):
        spsr.reconstruct(*fibonacci_sphere(2000), depth=5, gpu=True)


def test_gpu_auto_gives_the_cpu_mesh_and_says_when_it_fell_back():
    pts, nrm = fibonacci_sphere(3000)
    cpu = spsr.reconstruct(pts, nrm, depth=5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        auto = spsr.reconstruct(pts, nrm, depth=5, gpu="auto")
    fell_back = any("GPU was not used" in str(w.message) for w in caught)
    assert fell_back != _gpu_usable()
    assert np.array_equal(cpu.vertices, auto.vertices)
    assert np.array_equal(cpu.faces, auto.faces)


@pytest.mark.parametrize("bad, error", [("sometimes", ValueError), (3, TypeError), (1.0, TypeError)])
def test_bad_gpu_values_are_refused(bad, error):
    with pytest.raises(error, match="gpu"):
        spsr.reconstruct(*fibonacci_sphere(500), depth=4, gpu=bad)
