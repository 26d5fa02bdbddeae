"""spsr.render: the picture's shape, its silhouette, colours and errors."""

import numpy as np
import pytest

import spsr
from conftest import CENTER, RADIUS


def covered(picture):
    """Pixels that are not the white background."""
    return np.any(picture[:, :, :3] != 255, axis=2)


def test_a_sphere_is_drawn_as_a_disc(sphere_mesh):
    picture = spsr.render(sphere_mesh, view="front", size=(300, 200))
    assert picture.shape == (200, 300, 4) and picture.dtype == np.uint8
    assert np.all(picture[:, :, 3] == 255)
    # Fitted to the height less 5 % margins: a disc of radius 90 around the centre.
    y, x = np.mgrid[0:200, 0:300] + 0.5
    inside = np.hypot(x - 150, y - 100) < 90
    mask = covered(picture)
    iou = np.sum(mask & inside) / np.sum(mask | inside)
    assert iou > 0.97, iou


def test_views_sizes_and_colours(sphere_mesh, tmp_path):
    all_views = spsr.render(sphere_mesh, view="all", size=101)
    assert all_views.shape == (101, 101, 4)
    # One disc per quadrant.
    for r, c in [(25, 25), (25, 75), (75, 25), (75, 75)]:
        assert covered(all_views)[r, c]
    by_density = spsr.render(sphere_mesh, color="density", size=64)
    plain = spsr.render(sphere_mesh, color="plain", size=64)
    assert not np.array_equal(by_density, plain)
    # The same mesh from a file, and from arrays.
    path = tmp_path / "sphere.ply"
    spsr.write_mesh(path, sphere_mesh)
    assert np.array_equal(spsr.render(path, size=64), spsr.render(str(path), size=64))
    from_arrays = spsr.render(sphere_mesh.vertices, sphere_mesh.faces, size=64, color="plain")
    assert np.array_equal(from_arrays, plain)
    assert np.array_equal(spsr.render(sphere_mesh, size=64, threads=1), spsr.render(sphere_mesh, size=64, threads=2))


def test_a_loose_piece_is_highlighted(sphere_mesh):
    v = np.asarray(sphere_mesh.vertices)
    f = np.asarray(sphere_mesh.faces)
    extra = CENTER + np.array([[2.0, 0, 0], [2.3, 0, 0], [2.0, 0.3, 0]]) * RADIUS
    vertices = np.concatenate([v, extra])
    faces = np.concatenate([f, [[len(v), len(v) + 1, len(v) + 2]]])
    picture = spsr.render(vertices, faces, view="front", size=(400, 200), highlight="pieces")
    magenta = (picture[:, :, 0] > 150) & (picture[:, :, 2] > 130) & (picture[:, :, 1] < 40)
    assert magenta.sum() > 50
    assert not magenta[:, :250].any()  # the sphere, on the left, is not highlighted


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"size": (0, 10)}, "invalid parameter size=0x10: expected a width and height from 1 to 16384 pixels"),
        ({"size": 20000}, "size=20000x20000"),
        ({"size": "big"}, "size must be an integer or (width, height)"),
        ({"view": "back"}, "view='back': expected one of 'front', 'side', 'top', 'iso', 'all'"),
        ({"color": "colour"}, "color='colour'"),
        ({"color": "attribute:intensity"}, "color (the attribute 'intensity'): expected a per-vertex attribute"),
        ({"highlight": "holes"}, "highlight='holes': expected None or 'pieces'"),
        ({"threads": 0}, "threads=0"),
    ],
)
def test_bad_arguments_are_value_errors(sphere_mesh, kw, message):
    with pytest.raises(ValueError) as e:
        spsr.render(sphere_mesh, **kw)
    assert message in str(e.value)


def test_a_mesh_without_triangles_or_density_is_refused():
    empty = spsr.Mesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int32))
    with pytest.raises(ValueError, match="no triangles"):
        spsr.render(empty)
    tri = spsr.Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(ValueError, match="density=True"):
        spsr.render(tri, color="density")
