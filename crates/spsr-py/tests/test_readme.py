"""The Python examples of README.md and docs/python.md run as written (on the repository's
example scan)."""

import os
import re
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def python_blocks(relative, heading=None):
    path = ROOT / relative
    if not path.exists():
        pytest.skip("not in the repository")
    text = path.read_text(encoding="utf-8")
    if heading is not None:
        text = text[text.index(heading) :]
        text = text[: text.index("\n## ", 1)]
    return re.findall(r"```python\n(.*?)```", text, re.S)


def example_scan():
    scan = ROOT / "examples" / "bunny.ply"
    if not scan.exists():
        pytest.skip("examples/bunny.ply is missing")
    return scan


@pytest.mark.parametrize("normals", [True, False])
def test_readme_example(tmp_path, monkeypatch, normals):
    example = python_blocks("README.md", "## Python")[0]
    # The front page promises Python in ten lines.
    assert len(example.strip().splitlines()) <= 10
    scan = example_scan()
    import spsr

    if normals:
        shutil.copy(scan, tmp_path / "scan.ply")
    else:
        # A scan without normals takes the example's other branch.
        spsr.write_points(tmp_path / "scan.ply", spsr.read_points(scan).points)
        assert spsr.read_points(tmp_path / "scan.ply").normals is None
    monkeypatch.chdir(tmp_path)
    scope = {}
    exec(compile(example, "README.md", "exec"), scope)
    mesh = spsr.read_mesh(tmp_path / "mesh.ply")
    assert len(mesh.faces) > 10_000
    # The bunny is open at the bottom, and trim="auto" opens it.
    assert scope["mesh"].stats["diagnosis"]["closed"] is False
    assert scope["picture"].shape == (800, 800, 4)


def test_python_docs_example(tmp_path, monkeypatch):
    example = python_blocks("docs/python.md")[0]
    scan = example_scan()
    monkeypatch.chdir(tmp_path)
    os.symlink(scan.parent, tmp_path / "examples")
    exec(compile(example, "docs/python.md", "exec"), {})
    import spsr

    mesh = spsr.read_mesh(tmp_path / "bunny-mesh.ply")
    assert len(mesh.faces) > 10_000 and mesh.density is not None
