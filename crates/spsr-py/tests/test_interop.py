"""The Open3D and trimesh examples of docs/python.md, the command line the wheel installs, the stubs."""

import inspect
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import spsr
from conftest import CENTER, RADIUS

SPHERE_VOLUME = 4.0 / 3.0 * np.pi * RADIUS**3


def test_trimesh(sphere_mesh):
    trimesh = pytest.importorskip("trimesh")
    mesh = sphere_mesh
    # As in docs/python.md: the arrays go straight in.
    tm = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    assert tm.is_watertight and tm.is_winding_consistent
    assert tm.volume == pytest.approx(SPHERE_VOLUME, rel=0.02)  # positive: outward faces
    np.testing.assert_allclose(tm.center_mass, CENTER, atol=1e-3)
    # The convenience method carries normals.
    tm2 = mesh.to_trimesh()
    np.testing.assert_array_equal(tm2.faces, tm.faces)
    np.testing.assert_allclose(tm2.vertex_normals, mesh.normals, atol=1e-5)
    # And back: a trimesh sampled with normals, reconstructed.
    points, face = trimesh.sample.sample_surface(tm, 5000, seed=1)
    again = spsr.reconstruct(points, tm.face_normals[face], depth=5)
    assert trimesh.Trimesh(again.vertices, again.faces).is_watertight


def test_open3d(sphere, sphere_mesh):
    o3d = pytest.importorskip("open3d")
    mesh = sphere_mesh
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.faces)
    )
    assert m.is_watertight() and m.is_orientable()
    assert m.get_volume() == pytest.approx(SPHERE_VOLUME, rel=0.02)
    assert len(mesh.to_open3d().triangles) == len(mesh.faces)
    # From an Open3D point cloud.
    points, normals = sphere
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(normals)
    again = spsr.reconstruct(np.asarray(pcd.points), np.asarray(pcd.normals), depth=6)
    np.testing.assert_array_equal(again.faces, spsr.reconstruct(points, normals, depth=6).faces)


def spsr_command():
    exe = Path(sys.executable).parent / ("spsr.exe" if os.name == "nt" else "spsr")
    if not exe.exists():
        pytest.skip("the spsr console script is not installed next to this Python")
    return str(exe)


def test_command_line(tmp_path, sphere):
    exe = spsr_command()
    out = subprocess.run([exe, "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("spsr ")
    points, normals = sphere
    cloud = tmp_path / "cloud.ply"
    spsr.write_points(cloud, points, normals)
    mesh = tmp_path / "mesh.ply"
    out = subprocess.run(
        [exe, "reconstruct", str(cloud), "-o", str(mesh), "--depth", "5", "--density"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert f"spsr: wrote {mesh}" in out.stdout
    # The same mesh as the Python call.
    ref = spsr.reconstruct(points, normals, depth=5)
    np.testing.assert_array_equal(spsr.read_mesh(mesh).faces, ref.faces)
    # Errors: the CLI's message and exit codes.
    out = subprocess.run([exe, "reconstruct", str(cloud), "-o", str(mesh), "--depth", "0"], capture_output=True, text=True)
    assert out.returncode == 2
    assert "spsr: error: invalid parameter --depth 0: expected an integer from 1 to 18" in out.stderr
    out = subprocess.run([exe, "reconstruct", "--no-such-flag"], capture_output=True, text=True)
    assert out.returncode == 2 and "--no-such-flag" in out.stderr
    out = subprocess.run([exe, "reconstruct", str(tmp_path / "missing.ply"), "-o", str(mesh)], capture_output=True, text=True)
    assert out.returncode == 1 and "missing.ply" in out.stderr
    # python -m spsr is the same program.
    out = subprocess.run([sys.executable, "-m", "spsr", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "reconstruct" in out.stdout


def test_documented_and_typed():
    import spsr._spsr as native

    for name in spsr.__all__:
        obj = getattr(spsr, name)
        if callable(obj):
            assert inspect.getdoc(obj), name
    assert (Path(spsr.__file__).parent / "py.typed").exists()
    stub = (Path(spsr.__file__).parent / "_spsr.pyi").read_text()
    functions = [n for n in dir(native) if callable(getattr(native, n)) and not n.startswith("_")]
    assert functions
    for name in functions:
        # Functions, and classes (the kept implicit function).
        assert f"def {name}(" in stub or f"class {name}:" in stub, name
    # Every keyword of reconstruct is a field of spsr::Params or a documented extra.
    doc = inspect.getdoc(spsr.reconstruct)
    for p in inspect.signature(spsr.reconstruct).parameters:
        assert f"{p} :" in doc or f"{p}," in doc, p
