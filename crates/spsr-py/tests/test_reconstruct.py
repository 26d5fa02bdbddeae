"""Reconstruction from arrays: results, accuracy, array handling, files, threads, Ctrl-C."""

import os
import signal
import threading
import time
import traceback

import numpy as np
import pytest

import spsr
from conftest import CENTER, RADIUS, fibonacci_sphere


def edges_shared_twice(faces):
    """True when every undirected edge is used by exactly two triangles (a closed mesh)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e.sort(axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def test_result_arrays(sphere_mesh):
    m = sphere_mesh
    assert m.vertices.dtype == np.float64 and m.vertices.ndim == 2 and m.vertices.shape[1] == 3
    assert m.faces.dtype == np.int32 and m.faces.shape[1] == 3
    assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    assert m.density.dtype == np.float32 and m.density.shape == (len(m.vertices),)
    assert m.normals.dtype == np.float32 and m.normals.shape == m.vertices.shape
    assert np.allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-4)
    assert m.colors is None and m.attributes == {}
    assert edges_shared_twice(m.faces)
    s = m.stats
    assert s["points"] == 20_000 and s["dropped"] == 0 and s["samples"] > 0
    assert len(s["nodes_per_depth"]) >= 7 and min(s["nodes_per_depth"]) > 0
    assert [name for name, _ in s["stages"]][0] == "preparing points"
    assert s["trim"] is None
    assert "20,000" not in repr(m) and repr(m).startswith("Mesh(")


def test_sphere_accuracy():
    """Vertices lie on the analytic sphere: mean distance below 0.1 % of the radius."""
    points, normals = fibonacci_sphere(50_000)
    m = spsr.reconstruct(points, normals, depth=7)
    d = np.abs(np.linalg.norm(m.vertices - CENTER, axis=1) - RADIUS)
    assert d.mean() < 1e-3 * RADIUS, d.mean()
    assert d.max() < 1e-2 * RADIUS, d.max()
    # The outward normals point away from the centre.
    m = spsr.reconstruct(points, normals, depth=7, vertex_normals=True)
    radial = (m.vertices - CENTER) / np.linalg.norm(m.vertices - CENTER, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", radial, m.normals).min() > 0.95


def test_metrics_of_sphere(sphere_mesh):
    e = spsr.eval(sphere_mesh, sphere=(*CENTER, RADIUS), samples=20_000)
    assert e["chamfer_rel"] < 1e-3
    assert e["closed"] and e["components"] == 1 and e["euler"] == 2
    # Against itself, the distance is zero.
    e = spsr.eval(sphere_mesh, sphere_mesh, samples=5_000)
    assert e["chamfer"] < 1e-12


def test_float32_float64_and_strides_give_the_same_mesh(sphere):
    points, normals = sphere
    ref = spsr.reconstruct(points, normals, depth=5)
    variants = [
        (points.astype(np.float32), normals.astype(np.float32)),
        (np.asfortranarray(points), np.asfortranarray(normals)),
        (np.repeat(points, 2, axis=0)[::2], normals.T.copy().T),
        (points.tolist(), normals.tolist()),
        (points.astype(">f8"), normals.astype(">f4")),
    ]
    for p, n in variants:
        m = spsr.reconstruct(p, n, depth=5)
        np.testing.assert_array_equal(m.vertices, ref.vertices)
        np.testing.assert_array_equal(m.faces, ref.faces)


def test_inputs_are_not_modified(sphere):
    points, normals = sphere
    p, n = points.copy(), normals.copy()
    p.flags.writeable = False
    spsr.reconstruct(p, n, depth=5)
    np.testing.assert_array_equal(p, points)
    np.testing.assert_array_equal(n, normals)


def test_deterministic_across_thread_counts(sphere):
    points, normals = sphere
    a = spsr.reconstruct(points, normals, depth=6, threads=1)
    b = spsr.reconstruct(points, normals, depth=6, threads=2)
    c = spsr.reconstruct(points, normals, depth=6)
    for m in (b, c):
        np.testing.assert_array_equal(a.vertices, m.vertices)
        np.testing.assert_array_equal(a.faces, m.faces)


def test_colours_and_attributes_carried(sphere):
    points, normals = sphere
    rgb = np.clip((normals + 1) * 127.5, 0, 255).astype(np.uint8)
    temperature = (points[:, 2] * 10).astype(np.float32)
    m = spsr.reconstruct(points, normals, depth=5, colors=rgb, point_attributes={"temperature": temperature})
    assert m.colors.dtype == np.uint8 and m.colors.shape == (len(m.vertices), 3)
    assert m.attributes["temperature"].dtype == np.float32
    # Colours follow the normals' direction: red grows with x.
    x = m.vertices[:, 0] - CENTER[0]
    assert np.corrcoef(x, m.colors[:, 0].astype(float))[0, 1] > 0.95
    np.testing.assert_allclose(m.attributes["temperature"], m.vertices[:, 2] * 10, atol=1.0)
    assert np.corrcoef(m.attributes["temperature"], m.vertices[:, 2])[0, 1] > 0.99
    # Float colours stay float; RGBA keeps alpha.
    rgba = np.concatenate([rgb / 255.0, np.ones((len(rgb), 1))], axis=1)
    m = spsr.reconstruct(points, normals, depth=5, colors=rgba)
    assert m.colors.dtype == np.float64 and m.colors.shape[1] == 4
    # attributes=False drops them.
    m = spsr.reconstruct(points, normals, depth=5, colors=rgb, attributes=False)
    assert m.colors is None


def test_weights_and_confidence(sphere):
    points, normals = sphere
    w = np.ones(len(points))
    w[:10] = 0.0  # dropped: not a positive weight
    with pytest.warns(RuntimeWarning, match="10 of 20000 points dropped"):
        m = spsr.reconstruct(points, normals, depth=5, weights=w)
    assert m.stats["dropped"] == 10 and "confidence" not in m.attributes
    m = spsr.reconstruct(points, normals * 2.0, depth=5, confidence=True)
    assert len(m.faces) > 0


def test_dropped_points_warn(sphere):
    points, normals = sphere
    p = points.copy()
    p[:3] = np.nan
    with pytest.warns(RuntimeWarning, match="3 of 20000 points dropped") as caught:
        m = spsr.reconstruct(p, normals, depth=5)
    assert m.stats["dropped"] == 3
    assert len(caught) == 1 and m.stats["warnings"] == [str(caught[0].message)]


def test_far_outliers_warn_in_python_words():
    points, normals = fibonacci_sphere(2_000)
    points = np.concatenate([points, [[100.0, 0.0, 0.0]]])
    normals = np.concatenate([normals, [[1.0, 0.0, 0.0]]])
    with pytest.warns(RuntimeWarning, match="lie far outside the box") as caught:
        m = spsr.reconstruct(points, normals, depth=4, keep_outliers=True)
    (message,) = [str(w.message) for w in caught]
    assert m.stats["warnings"] == [message]
    assert message.startswith("1 of 2001 points")
    assert "(depth=4 resolves the surface like depth=0)" in message
    assert message.endswith("; remove those points (crop the input to that box), or use depth=9")
    assert "--" not in message


def test_trim_and_density():
    """An open hemisphere: the closure over the opening has low density and is trimmed."""
    points, normals = fibonacci_sphere(40_000)
    keep = points[:, 2] - CENTER[2] > -0.5 * RADIUS
    points, normals = points[keep], normals[keep]
    # The surface closing the opening runs on to the bounding cube: trimming is advised.
    with pytest.warns(RuntimeWarning, match='trim the invented surface with trim="auto"'):
        full = spsr.reconstruct(points, normals, depth=6, density=True)
    trimmed = spsr.trim(full, "auto")
    assert len(trimmed.faces) < len(full.faces)
    assert not edges_shared_twice(trimmed.faces)
    t = trimmed.stats["trim"]
    assert t["auto"] is not None and t["threshold"] == pytest.approx(t["auto"]["threshold"])
    # The part left is the sampled part: nothing below the cut.
    assert (trimmed.vertices[:, 2] - CENTER[2]).min() > -0.6 * RADIUS
    # trim= in reconstruct does the same in one step; density only when asked.
    one = spsr.reconstruct(points, normals, depth=6, trim="auto")
    assert one.density is None and one.stats["trim"]["triangles_out"] == len(one.faces)
    np.testing.assert_array_equal(one.faces, trimmed.faces)
    # A numeric threshold.
    low = spsr.trim(full, float(t["threshold"]) - 100.0)
    assert len(low.faces) == len(full.faces)


def test_mesh_file_round_trip(tmp_path, sphere_mesh):
    m = sphere_mesh
    for name, ascii in (("m.ply", False), ("a.ply", True)):
        path = tmp_path / name
        spsr.write_mesh(path, m, ascii=ascii)
        r = spsr.read_mesh(str(path))
        np.testing.assert_allclose(r.vertices, m.vertices, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(r.faces, m.faces)
        np.testing.assert_allclose(r.density, m.density, rtol=1e-6)
        np.testing.assert_allclose(r.normals, m.normals, atol=1e-6)
    for ext in ("obj", "stl", "glb"):
        spsr.write_mesh(tmp_path / f"m.{ext}", m)
        assert (tmp_path / f"m.{ext}").stat().st_size > 1000
    # A mesh built from arrays.
    tetra = spsr.Mesh(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
        np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.uint64),
        colors=np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], dtype=np.uint8),
        attributes={"label": np.arange(4, dtype=np.int16)},
    )
    spsr.write_mesh(tmp_path / "t.ply", tetra)
    r = spsr.read_mesh(tmp_path / "t.ply")
    np.testing.assert_array_equal(r.faces, tetra.faces)
    np.testing.assert_array_equal(r.colors, tetra.colors)
    assert r.attributes["label"].dtype == np.int16
    np.testing.assert_array_equal(r.attributes["label"], np.arange(4))


def test_point_file_round_trip(tmp_path, sphere):
    points, normals = sphere
    rgb = (np.abs(normals) * 255).astype(np.uint8)
    intensity = np.arange(len(points), dtype=np.uint16)
    path = tmp_path / "cloud.ply"
    spsr.write_points(path, points, normals, colors=rgb, attributes={"intensity": intensity})
    c = spsr.read_points(path)
    assert len(c) == len(points) and "intensity" in repr(c)
    np.testing.assert_array_equal(c.points, points)
    np.testing.assert_array_equal(c.normals, normals)
    np.testing.assert_array_equal(c.colors, rgb)
    assert c.attributes["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(c.attributes["intensity"], intensity)
    # A cloud goes straight into reconstruct, with its normals and colours.
    m = spsr.reconstruct(c, depth=5)
    ref = spsr.reconstruct(points, normals, depth=5)
    np.testing.assert_array_equal(m.faces, ref.faces)
    assert m.colors.dtype == np.uint8 and m.attributes["intensity"].dtype == np.uint16
    # A text file without normals reads with normals None.
    xyz = tmp_path / "cloud.xyz"
    np.savetxt(xyz, points[:100])
    c = spsr.read_points(xyz)
    assert c.normals is None and c.points.shape == (100, 3)
    with pytest.raises(ValueError, match="no normals"):
        spsr.reconstruct(c)
    # The PointCloud constructor, and writing one back.
    spsr.write_points(tmp_path / "again.ply", spsr.PointCloud(points[:10], normals[:10]))
    assert len(spsr.read_points(tmp_path / "again.ply")) == 10


def test_gil_released_during_reconstruction(sphere):
    points, normals = sphere
    done = []
    worker = threading.Thread(target=lambda: done.append(spsr.reconstruct(points, normals, depth=8)))
    worker.start()
    ticks = 0
    while worker.is_alive():
        ticks += 1
        time.sleep(0.001)
    worker.join()
    assert done and len(done[0].faces) > 0
    # Had the call held the GIL, this thread could not have run until it returned.
    assert ticks >= 20, ticks


def test_ctrl_c_stops_the_reconstruction():
    points, normals = fibonacci_sphere(300_000)
    timer = threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt) as info:
            spsr.reconstruct(points, normals, depth=10)
            time.sleep(30)  # not reached unless the run beat the signal
    finally:
        timer.cancel()
    frames = [f.name for f in traceback.extract_tb(info.value.__traceback__)]
    assert "reconstruct" in frames, frames
    # The library is usable afterwards.
    m = spsr.reconstruct(points[::30], normals[::30], depth=5)
    assert len(m.faces) > 0


def test_far_outliers_are_left_out_by_default():
    points, normals = fibonacci_sphere(2_000)
    with_outlier = np.concatenate([points, [[100.0, 0.0, 0.0]]])
    normals_too = np.concatenate([normals, [[1.0, 0.0, 0.0]]])
    with pytest.warns(RuntimeWarning, match="left out 1 far outlier"):
        m = spsr.reconstruct(with_outlier, normals_too, depth=5)
    clean = spsr.reconstruct(points, normals, depth=5)
    assert np.array_equal(m.vertices, clean.vertices)


def test_noise_keyword_and_hand_tuning():
    # Noise of about one point spacing, which the samples resolve (docs/noise.md).
    points, normals = fibonacci_sphere(20_000)
    rng = np.random.default_rng(3)
    noisy = points + rng.normal(scale=0.04, size=points.shape)
    adaptive = spsr.reconstruct(noisy, normals, depth=7)
    off = spsr.reconstruct(noisy, normals, depth=7, noise="off")
    tuned = spsr.reconstruct(noisy, normals, depth=7, samples_per_node=1.5)
    assert np.array_equal(off.vertices, tuned.vertices)
    assert len(adaptive.faces) < len(off.faces)
    # The noise measured is the noise put in, in the input's units.
    noise = adaptive.stats["noise"]
    assert 0.028 < noise["median"] < 0.048, noise
    assert noise["adapted"] > 0.5 and noise["mean_lowering"] > 0
    assert off.stats["noise"] is None
    with pytest.raises(ValueError, match="noise"):
        spsr.reconstruct(points, normals, noise="sometimes")
    # Noise well under the point spacing cannot be told from the shape between the points:
    # it is left alone, as PoissonRecon does.
    sparse, sparse_normals = fibonacci_sphere(5_000)
    faint = sparse + rng.normal(scale=0.02, size=sparse.shape)
    left = spsr.reconstruct(faint, sparse_normals, depth=7)
    assert left.stats["noise"]["adapted"] == 0
    assert np.array_equal(left.vertices, spsr.reconstruct(faint, sparse_normals, depth=7, noise="off").vertices)
