"""The README's Python example runs as written (on the repository's example scan)."""

import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def python_blocks():
    readme = ROOT / "README.md"
    if not readme.exists():
        pytest.skip("not in the repository")
    text = readme.read_text(encoding="utf-8")
    section = text[text.index("## Python") :]
    section = section[: section.index("\n## ", 1)]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_readme_example(tmp_path, monkeypatch):
    example = python_blocks()[0]
    assert len(example.strip().splitlines()) == 5
    if not (ROOT / "examples" / "bunny.ply").exists():
        pytest.skip("examples/bunny.ply is missing")
    monkeypatch.chdir(tmp_path)
    os.symlink(ROOT / "examples", tmp_path / "examples")
    exec(compile(example, "README.md", "exec"), {})
    import spsr

    mesh = spsr.read_mesh(tmp_path / "bunny-mesh.ply")
    assert len(mesh.faces) > 10_000 and mesh.density is not None
