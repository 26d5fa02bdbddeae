"""spsr.estimate_normals: clouds without normals, oriented by each mode; bad arguments."""

import numpy as np
import pytest

import spsr
from conftest import CENTER, RADIUS, fibonacci_sphere

POINTS, TRUE_NORMALS = fibonacci_sphere(10_000)


def agreement(normals):
    return np.einsum("ij,ij->i", normals, TRUE_NORMALS)


def test_estimated_normals_reconstruct_the_sphere():
    normals, info = spsr.estimate_normals(POINTS, return_info=True)
    assert normals.shape == POINTS.shape and normals.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    assert agreement(normals).min() > 0.99  # outward and accurate
    assert info["orientation"] == "mst" and info["neighbours"] >= 3 and info["degenerate"] == 0
    mesh = spsr.reconstruct(POINTS, normals, depth=6)
    d = np.abs(np.linalg.norm(mesh.vertices - CENTER, axis=1) - RADIUS)
    assert d.mean() < 2e-3 * RADIUS


def test_orientation_modes():
    inward = spsr.estimate_normals(POINTS, viewpoint=CENTER)  # orient="viewpoint" implied
    assert agreement(inward).max() < -0.99
    sensor = CENTER + [2.0, 0.5, -1.0]
    scans = spsr.estimate_normals(POINTS, orient="viewpoint", scan_origins=[(0, sensor)])
    # Every normal points towards the sensor's side: outward on the cap the sensor sees.
    facing = np.einsum("ij,ij->i", sensor - POINTS, TRUE_NORMALS) > 0
    assert ((agreement(scans) > 0) == facing).mean() > 0.999
    unoriented = spsr.estimate_normals(POINTS, orient="none", neighbours=12)
    assert np.abs(agreement(unoriented)).min() > 0.99
    globally = spsr.estimate_normals(POINTS[::4], orient="global")
    assert agreement_subset(globally, 4).min() > 0.99
    # A PointCloud brings its points; the same normals as the arrays.
    cloud = spsr.PointCloud(POINTS)
    np.testing.assert_array_equal(spsr.estimate_normals(cloud), spsr.estimate_normals(POINTS))


def agreement_subset(normals, step):
    return np.einsum("ij,ij->i", normals, TRUE_NORMALS[::step])


def test_deterministic_across_threads():
    a = spsr.estimate_normals(POINTS, threads=1)
    b = spsr.estimate_normals(POINTS, threads=2)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "args, kw, message",
    [
        ((POINTS,), {"neighbours": 2}, r"^invalid parameter neighbours=2: expected at least 3 \(a plane needs"),
        (
            (POINTS,),
            {"orient": "outward"},
            "^invalid parameter orient='outward': expected one of 'mst', 'viewpoint', 'global', 'none'$",
        ),
        ((POINTS,), {"orient": "mst", "viewpoint": (0, 0, 0)}, "viewpoint= is only used by"),
        ((POINTS,), {"orient": "viewpoint"}, "needs viewpoint="),
        ((POINTS,), {"viewpoint": (0, 0)}, r"viewpoint must be \(x, y, z\)"),
        ((POINTS,), {"viewpoint": (0, 0, np.nan)}, "finite"),
        ((POINTS,), {"threads": 0}, "^invalid parameter threads=0: expected an integer of at least 1$"),
        ((POINTS,), {"scan_origins": [(0, (0, 0, 0)), (0, (1, 1, 1))]}, r"^invalid parameter scan_origins \(a scan"),
        ((POINTS[:2],), {}, "too few usable points"),
        ((np.outer(np.arange(10.0), [1.0, 2.0, 3.0]),), {}, "degenerate input"),
        ((POINTS[:, :2],), {}, r"points must be an array of shape \(N, 3\)"),
    ],
)
def test_bad_arguments(args, kw, message):
    with pytest.raises(ValueError, match=message):
        spsr.estimate_normals(*args, **kw)
