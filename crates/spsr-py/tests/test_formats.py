"""Meshes and clouds through the formats spsr writes and reads back: OFF, OBJ, text."""

import numpy as np
import pytest

import spsr


def tetrahedron():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)
    normals = (vertices - 0.25) / np.linalg.norm(vertices - 0.25, axis=1)[:, None]
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 99, 199]], dtype=np.uint8)
    return spsr.Mesh(vertices, faces, normals=normals, colors=colors, density=np.arange(4.0))


@pytest.mark.parametrize("ext", ["off", "obj"])
def test_off_and_obj_round_trip(tmp_path, ext):
    mesh = tetrahedron()
    path = tmp_path / f"tet.{ext}"
    spsr.write_mesh(path, mesh)
    back = spsr.read_mesh(path)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-6)
    np.testing.assert_allclose(back.normals, mesh.normals, atol=1e-6)
    # OFF stores colour bytes; OBJ values in [0, 1].
    scale = 1.0 if back.colors.dtype == np.uint8 else 255.0
    np.testing.assert_allclose(back.colors * scale, mesh.colors, atol=0.5)
    assert back.density is None  # neither format holds it
    # The vertices as a point cloud, with their normals.
    cloud = spsr.read_points(path)
    np.testing.assert_allclose(cloud.points, mesh.vertices, atol=1e-6)
    np.testing.assert_allclose(cloud.normals, mesh.normals, atol=1e-6)


def test_unknown_extensions_are_refused(tmp_path):
    with pytest.raises(OSError, match=r"\.ply, \.obj, \.stl, \.off, \.glb"):
        spsr.write_mesh(tmp_path / "tet.xyz", tetrahedron())
    points = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    with pytest.raises(OSError, match=r"\.ply, \.xyz, \.txt"):
        spsr.write_points(tmp_path / "c.las", points)
    assert list(tmp_path.iterdir()) == []


def test_text_clouds_round_trip(tmp_path):
    points = np.array([[0.1, 1e-7, 500000.123456789], [-3.5, 2.0, 1.0 / 3.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    path = tmp_path / "c.xyz"
    spsr.write_points(path, points, normals)
    cloud = spsr.read_points(path)
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.normals, normals)


def test_tiles_are_read_as_one_cloud(tmp_path):
    rng = np.random.default_rng(3)
    points = rng.normal(size=(300, 3))
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    a, b, c = tmp_path / "a.ply", tmp_path / "b.xyz", tmp_path / "c.ply"
    spsr.write_points(a, points[:100], normals=normals[:100])
    spsr.write_points(b, points[100:], normals=normals[100:])
    cloud = spsr.read_points([a, str(b)])
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.normals, normals)
    # A tile without normals among tiles with normals: an error naming it.
    spsr.write_points(c, points[:10])
    with pytest.raises(spsr.FileFormatError, match="c.ply"):
        spsr.read_points([a, c])
    with pytest.raises(ValueError, match="no files"):
        spsr.read_points([])
