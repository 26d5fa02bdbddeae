"""Synthetic inputs shared by the tests (no data files are read)."""

import numpy as np
import pytest

CENTER = np.array([0.1, -0.2, 0.3])
RADIUS = 1.5


def fibonacci_sphere(n, center=CENTER, radius=RADIUS):
    """`n` evenly spread points on a sphere and their outward unit normals (float64)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    normals = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return center + radius * normals, normals


@pytest.fixture(scope="session")
def sphere():
    """A sphere of 20,000 points whose coordinates are exact in float32 too."""
    points, normals = fibonacci_sphere(20_000)
    return points.astype(np.float32).astype(np.float64), normals.astype(np.float32).astype(np.float64)


@pytest.fixture(scope="session")
def sphere_mesh(sphere):
    import spsr

    points, normals = sphere
    return spsr.reconstruct(points, normals, depth=6, density=True, vertex_normals=True)
