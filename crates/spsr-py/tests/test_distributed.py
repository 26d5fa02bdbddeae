"""spsr.distributed: the slabs as Dask tasks give the command line's bytes, survive a killed
worker, and fail cleanly (clear error, no output, no job folder left)."""

import os
import subprocess
import sys

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import spsr  # noqa: E402
import spsr.distributed  # noqa: E402
from spsr import _spsr  # noqa: E402

from conftest import fibonacci_sphere  # noqa: E402

DEPTH = "7"


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=3, threads_per_worker=1, processes=True, dashboard_address=None
    )
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    """A cloud of two tiles in two formats: a sphere and an ellipsoid beside it, so that the
    slabs cut through two pieces of different sizes."""
    d = tmp_path_factory.mktemp("tiles")
    p1, n1 = fibonacci_sphere(12_000, center=np.array([0.0, 0.0, 0.0]), radius=1.0)
    q, m = fibonacci_sphere(8_000, center=np.zeros(3), radius=1.0)
    axes = np.array([1.4, 0.6, 0.8])
    p2 = q * axes + np.array([3.0, 0.3, -0.1])
    n2 = m / axes
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    a, b = str(d / "a.ply"), str(d / "b.xyz")
    spsr.write_points(a, p1, normals=n1)
    spsr.write_points(b, p2, normals=n2)
    return [a, b]


def command_line(tiles, out, *flags):
    code = _spsr.cli_main(["spsr", "reconstruct", *tiles, "-o", str(out), "--depth", DEPTH, *flags])
    assert code == 0
    return open(out, "rb").read()


def job_folders(path):
    return [n for n in os.listdir(path) if n.startswith("spsr-slabs-")]


def test_the_cluster_writes_the_command_lines_bytes(client, tiles, tmp_path):
    expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3")
    out = tmp_path / "dask.ply"
    stats = spsr.distributed.reconstruct(tiles, out, client=client, slabs=3, depth=int(DEPTH))
    assert out.read_bytes() == expected
    assert stats["slabs"] == 3 and stats["closed"] and stats["pieces"] == 2
    assert stats["points"] == 20_000 and stats["dropped"] == 0
    mesh = spsr.read_mesh(out)
    assert len(mesh.vertices) == stats["vertices"] and len(mesh.faces) == stats["faces"]
    assert job_folders(tmp_path) == []
    # Each step's time, in the order the steps ran: the default's noise and two solver cycles.
    steps = [step for step, _ in stats["timings"]]
    assert steps == ["prepare", "noise", "smoothing", "coarse", "solve_coarse", "solve", "cycle",
                     "solve", "iso", "extract", "finish"]
    assert all(seconds >= 0 for _, seconds in stats["timings"])


def test_colours_in_the_tiles_reach_the_mesh(client, tmp_path):
    """Colours and other properties stored in the tiles are carried in slabs, as in one
    piece: the cluster writes the command line's bytes, with the in-core mesh's properties."""
    p1, n1 = fibonacci_sphere(10_000, center=np.array([0.0, 0.0, 0.0]), radius=1.0)
    p2, n2 = fibonacci_sphere(6_000, center=np.array([2.5, 0.0, 0.0]), radius=0.8)
    tiles = []
    for name, p, n in (("a.ply", p1, n1), ("b.ply", p2, n2)):
        colors = np.clip((p - p.min()) / np.ptp(p) * 255, 0, 255).astype(np.uint8)
        path = str(tmp_path / name)
        spsr.write_points(path, p, normals=n, colors=colors,
                          attributes={"height": p[:, 2].astype(np.float32)})
        tiles.append(path)
    expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3")
    out = tmp_path / "dask.ply"
    stats = spsr.distributed.reconstruct(tiles, out, client=client, slabs=3, depth=int(DEPTH))
    assert out.read_bytes() == expected
    assert stats["closed"] and stats["pieces"] == 2
    slabs_mesh = spsr.read_mesh(out)
    one = tmp_path / "one.ply"
    command_line(tiles, one)
    in_core = spsr.read_mesh(str(one))
    assert slabs_mesh.colors is not None and slabs_mesh.colors.dtype == np.uint8
    assert set(slabs_mesh.attributes) == set(in_core.attributes)
    assert slabs_mesh.attributes["height"].dtype == np.float32
    # Each vertex's colour is the in-core one at its place (the same vertices, to 1e-4 cells).
    order_s = np.lexsort(np.round(slabs_mesh.vertices, 4).T)
    order_c = np.lexsort(np.round(in_core.vertices, 4).T)
    assert len(order_s) == len(order_c)
    diff = np.abs(slabs_mesh.colors[order_s].astype(int) - in_core.colors[order_c].astype(int))
    assert np.mean(diff <= 1) > 0.99, diff.max()


def test_parameters_reach_the_tasks(client, tiles, tmp_path):
    flags = ["--slabs", "2", "--degree", "2", "--noise", "off", "--samples-per-node", "3"]
    expected = command_line(tiles, tmp_path / "cli.ply", *flags)
    out = tmp_path / "dask.ply"
    work = tmp_path / "work"
    work.mkdir()
    spsr.distributed.reconstruct(
        tiles, out, client=client, slabs=2, depth=int(DEPTH), degree=2, noise="off",
        samples_per_node=3.0, work_dir=work,
    )
    assert out.read_bytes() == expected
    assert os.listdir(work) == []


def test_density_and_trimming_give_the_command_lines_bytes(client, tiles, tmp_path):
    # The density of every vertex, and the whole mesh trimmed with one threshold, in the last
    # task (issue 15): the same bytes as the command line's --slabs 3.
    for flags, keywords in [
        (["--density"], {"density": True}),
        (["--trim", "auto"], {"trim": "auto"}),
        (["--trim", "5.9", "--density"], {"trim": 5.9, "density": True}),
    ]:
        expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3", *flags)
        out = tmp_path / "dask.ply"
        stats = spsr.distributed.reconstruct(
            tiles, out, client=client, slabs=3, depth=int(DEPTH), **keywords
        )
        assert out.read_bytes() == expected, flags
        mesh = spsr.read_mesh(out)
        assert len(mesh.vertices) == stats["vertices"] and len(mesh.faces) == stats["faces"]
        assert (mesh.density is not None) == ("--density" in flags), flags
        assert job_folders(tmp_path) == []


def test_a_killed_worker_changes_nothing(client, tiles, tmp_path):
    expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3")
    marker = tmp_path / "died"
    out = tmp_path / "dask.ply"
    spsr.distributed.reconstruct(
        tiles, out, client=client, slabs=3, depth=int(DEPTH), _fault=("solve", 1, str(marker))
    )
    assert marker.exists(), "the worker was not killed"
    assert out.read_bytes() == expected
    assert job_folders(tmp_path) == []


def test_a_lone_worker_killed_runs_nothing_twice(tiles, tmp_path):
    # With one worker, the worker killed mid-task also held the results of the steps before:
    # the run must not want them back (Dask would run the preparation again, into a second
    # job folder that nothing removes).
    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None
    )
    try:
        with distributed.Client(cluster) as lone:
            expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "2")
            marker = tmp_path / "died"
            out = tmp_path / "dask.ply"
            spsr.distributed.reconstruct(
                tiles, out, client=lone, slabs=2, depth=int(DEPTH), _fault=("solve", 0, str(marker))
            )
            assert marker.exists(), "the worker was not killed"
            assert out.read_bytes() == expected
            assert job_folders(tmp_path) == []
    finally:
        cluster.close()


def test_a_malformed_tile_is_an_error_and_leaves_nothing(client, tiles, tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\n")
    out = tmp_path / "out.ply"
    with pytest.raises(spsr.FileFormatError, match="bad.ply"):
        spsr.distributed.reconstruct([tiles[0], bad], out, client=client, slabs=3, depth=6)
    assert not out.exists()
    assert job_folders(tmp_path) == []


def test_a_missing_tile_is_an_error(client, tiles, tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere.ply"):
        spsr.distributed.reconstruct(
            [tiles[0], tmp_path / "nowhere.ply"], tmp_path / "out.ply", client=client, depth=6
        )
    assert os.listdir(tmp_path) == []


def test_an_unusable_work_folder_is_an_error(client, tiles, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    out = tmp_path / "out.ply"
    with pytest.raises(OSError, match="a-file"):
        spsr.distributed.reconstruct(
            tiles, out, client=client, slabs=2, depth=6, work_dir=blocker / "work"
        )
    assert not out.exists()
    assert blocker.read_text() == "not a folder"


def test_an_unwritable_output_removes_the_job(client, tiles, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    out = tmp_path / "missing-folder" / "out.ply"
    with pytest.raises(OSError, match="missing-folder"):
        spsr.distributed.reconstruct(tiles, out, client=client, slabs=2, depth=6, work_dir=work)
    assert not out.exists()
    assert os.listdir(work) == []


def test_keywords_are_checked_before_anything_runs(tiles, tmp_path):
    # No client given: a check that failed after starting a cluster would be slow.
    out = tmp_path / "out.ply"
    with pytest.raises(ValueError, match="depth=0"):
        spsr.distributed.reconstruct(tiles, out, depth=0)
    with pytest.raises(ValueError, match="trim"):
        spsr.distributed.reconstruct(tiles, out, trim="often")
    with pytest.raises(ValueError, match="hole_area"):
        spsr.distributed.reconstruct(tiles, out, trim="auto", hole_area=2.0)
    with pytest.raises(ValueError, match="colors="):
        spsr.distributed.reconstruct(tiles, out, colors=np.zeros((3, 3)))
    with pytest.raises(TypeError, match="unexpected keyword argument 'dpeth'"):
        spsr.distributed.reconstruct(tiles, out, dpeth=6)
    with pytest.raises(ValueError, match="slabs=0"):
        spsr.distributed.reconstruct(tiles, out, slabs=0)
    with pytest.raises(ValueError, match="max_memory"):
        spsr.distributed.reconstruct(tiles, out, max_memory="lots")
    # A slab run takes a plain depth and makes no grid (issue 18).
    with pytest.raises(ValueError, match=r"^width= is not supported on a cluster: the depth is then chosen"):
        spsr.distributed.reconstruct(tiles, out, width=0.05)
    with pytest.raises(ValueError, match=r"^depth='auto' is not supported on a cluster: .* give depth="):
        spsr.distributed.reconstruct(tiles, out, depth="auto")
    with pytest.raises(ValueError, match=r"^grid_res= is not supported on a cluster"):
        spsr.distributed.reconstruct(tiles, out, grid_res=16)
    with pytest.raises(ValueError, match=r"^keep_implicit= is not supported on a cluster"):
        spsr.distributed.reconstruct(tiles, out, keep_implicit=True)
    with pytest.raises(ValueError, match="depth='deep'"):
        spsr.distributed.reconstruct(tiles, out, depth="deep")
    assert os.listdir(tmp_path) == []


def module(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "spsr.distributed", *args],
        capture_output=True, text=True, cwd=cwd, timeout=300,
    )


def test_the_module_runs_reconstructs_flags_on_a_local_cluster(tiles, tmp_path):
    expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3")
    out = tmp_path / "dask.ply"
    r = module("--workers", "2", *tiles, "-o", str(out), "--depth", DEPTH, "--slabs", "3", "-v")
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == expected
    assert "in 3 slabs on 2 workers" in r.stdout
    assert "samples" in r.stderr and "solve_coarse" in r.stderr
    # The command line's trimming too.
    expected = command_line(tiles, tmp_path / "cli.ply", "--slabs", "3", "--trim", "auto")
    r = module("--workers", "2", *tiles, "-o", str(out), "--depth", DEPTH, "--slabs", "3",
               "--trim", "auto")
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == expected


def test_the_module_refuses_what_a_cluster_cannot_do(tiles, tmp_path):
    r = module(*tiles, "-o", str(tmp_path / "out.obj"))
    assert r.returncode == 2 and "binary PLY" in r.stderr
    r = module(*tiles, "-o", str(tmp_path / "out.ply"), "--trim", "often")
    assert r.returncode == 2 and "--trim" in r.stderr
    r = module(*tiles, "-o", str(tmp_path / "out.ply"), "--depth", "0")
    assert r.returncode == 2 and "--depth" in r.stderr
    for flags, name in [
        (["--width", "0.05"], "--width"),
        (["--depth", "auto"], "--depth auto"),
        (["--grid", str(tmp_path / "g.npz"), "--grid-res", "8"], "--grid"),
    ]:
        r = module(*tiles, "-o", str(tmp_path / "out.ply"), *flags)
        assert r.returncode == 2 and f"{name} is not supported on a cluster" in r.stderr, r.stderr
    r = module("--workers", "none", *tiles, "-o", str(tmp_path / "out.ply"))
    assert r.returncode == 2 and "--workers" in r.stderr
    r = module("--help")
    assert r.returncode == 0 and "--scheduler" in r.stdout and "--depth" in r.stdout
    assert os.listdir(tmp_path) == []
