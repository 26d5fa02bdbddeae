"""The checks of the result: clean points give one closed piece and no warning; likely
garbage gives one RuntimeWarning whose advice is spelled with Python's keywords."""

import warnings

import numpy as np
import pytest

import spsr
from conftest import fibonacci_sphere


def test_a_clean_sphere_is_one_closed_piece_without_warning(sphere):
    points, normals = sphere
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = spsr.reconstruct(points, normals, depth=6)
    d = m.stats["diagnosis"]
    assert (d["pieces"], d["closed"], d["boundary_edges"], d["on_cube"]) == (1, True, 0, 0)
    assert d["contradicted_normals"] < 0.01
    assert m.stats["warnings"] == []


def test_half_flipped_normals_warn_in_python_words():
    points, normals = fibonacci_sphere(20_000)
    normals = np.where(normals[:, 2:3] > 0.3, -normals, normals)
    with pytest.warns(RuntimeWarning, match="runs on to the bounding cube") as caught:
        m = spsr.reconstruct(points, normals, depth=7)
    (message,) = [str(w.message) for w in caught]
    assert m.stats["warnings"] == [message]
    assert 'spsr.estimate_normals(points, orient="global")' in message
    assert 'trim="auto"' in message and "--" not in message
    assert m.stats["diagnosis"]["on_cube"] > 0 and not m.stats["diagnosis"]["closed"]


def test_noise_warns_with_keywords_that_help():
    rng = np.random.default_rng(3)
    unit, _ = fibonacci_sphere(30_000, center=np.zeros(3), radius=1.0)
    points = unit * (1.0 + 0.04 * rng.standard_normal(len(unit)))[:, None]
    normals = unit + 0.2 * rng.standard_normal(unit.shape)
    # PoissonRecon's behaviour: the default noise adaptation leaves one piece here.
    with pytest.warns(RuntimeWarning, match="the points are likely noisy") as caught:
        spsr.reconstruct(points, normals, depth=7, noise="off")
    (message,) = [str(w.message) for w in caught]
    assert "samples_per_node=5 to 10" in message and "depth=6" in message
