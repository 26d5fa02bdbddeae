#!/usr/bin/env python3
"""The Python peers' side of one benchmark run: reads an oriented point cloud, reconstructs
with one peer, writes the mesh as binary PLY. Each run is its own process (started by
bench/run.py) so that its wall time and peak memory can be measured; the interpreter, NumPy
and the peer's module count against the peer.

    python python_peers.py TOOL IN.ply OUT.ply PARAMS_JSON

TOOL: pypoisson2 | open3d | pymeshlab. PARAMS_JSON: {"depth", "degree", "point_weight",
"samples_per_node", "full_depth", "scale", "iters", "threads", "boundary"}. Prints one line
`BENCH {json}` on stdout: compute_seconds (points in memory to mesh arrays in memory, without
file I/O and imports), the parameters the peer was given and those it fixes itself.

Input: binary little-endian PLY whose vertex element has float x y z nx ny nz (the format of
../shared/data and of the harness's generated inputs).
"""
import json
import sys
import time

import numpy as np


def read_points(path):
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: PLY header has no end_header")
            line = line.decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        if "format binary_little_endian 1.0" not in header:
            raise ValueError(f"{path}: only binary little-endian PLY is supported")
        count, props, in_vertex = None, [], False
        for line in header:
            words = line.split()
            if words[:1] == ["element"]:
                in_vertex = words[1] == "vertex"
                if in_vertex:
                    count = int(words[2])
            elif words[:1] == ["property"] and in_vertex:
                if words[1] != "float":
                    raise ValueError(f"{path}: vertex property {line!r} is not float")
                props.append(words[2])
        data = np.fromfile(f, dtype="<f4", count=count * len(props)).reshape(count, len(props))
    idx = [props.index(n) for n in ("x", "y", "z", "nx", "ny", "nz")]
    return (
        np.ascontiguousarray(data[:, idx[:3]], dtype=np.float64),
        np.ascontiguousarray(data[:, idx[3:]], dtype=np.float64),
    )


def write_mesh(path, vertices, faces):
    vertices = np.ascontiguousarray(vertices, dtype="<f4")
    faces = np.asarray(faces)
    with open(path, "wb") as f:
        f.write(
            (
                "ply\nformat binary_little_endian 1.0\n"
                f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
                f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
            ).encode("ascii")
        )
        rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        rec["n"] = 3
        rec["i"] = faces
        f.write(vertices.tobytes())
        f.write(rec.tobytes())


def pypoisson2(points, normals, p):
    """PoissonRecon 18.74 through its PyPI binding. Everything we set is settable."""
    from poisson import poisson_reconstruction

    given = dict(
        depth=p["depth"],
        degree=p["degree"],
        point_weight=p["point_weight"],
        samples_per_node=p["samples_per_node"],
        full_depth=p["full_depth"],
        scale=p["scale"],
        iters=p["iters"],
        boundary=p["boundary"],
    )
    kwargs = dict(given)
    # Threads: OpenMP (OMP_NUM_THREADS, set by the harness); newer bindings also take a
    # `threads` argument.
    try:
        import inspect

        if "threads" in inspect.signature(poisson_reconstruction).parameters:
            kwargs["threads"] = p["threads"]
            given["threads"] = p["threads"]
    except (TypeError, ValueError):
        pass
    t0 = time.perf_counter()
    out = poisson_reconstruction(points, normals, **kwargs)
    vertices, faces = out[0], out[1]
    seconds = time.perf_counter() - t0
    given.setdefault("threads", f"OMP_NUM_THREADS={p['threads']}")
    return vertices, faces, seconds, given, {}


def open3d(points, normals, p):
    """Open3D's TriangleMesh.create_from_point_cloud_poisson (its bundled PoissonRecon)."""
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    t0 = time.perf_counter()
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(points)
    pcd.normals = o3d.utility.Vector3dVector(normals)
    given = dict(depth=p["depth"], width=0, scale=p["scale"], linear_fit=False, n_threads=p["threads"])
    extra = dict(full_depth=p["full_depth"], samples_per_node=p["samples_per_node"], point_weight=p["point_weight"])
    # Open3D's source: FEM degree 1, Neumann boundary, 8 Gauss-Seidel iterations, float
    # precision, kernel depth = depth - 2, all fixed.
    fixed = dict(degree=1, boundary="neumann", iters=8, precision="float32")
    try:
        mesh, _density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, **given, **extra)
        given.update(extra)
    except TypeError:
        # Releases before full_depth, samples_per_node and point_weight became arguments fix
        # them inside the library.
        mesh, _density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, **given)
        fixed["full_depth / samples_per_node / point_weight"] = "fixed by this Open3D release"
    vertices = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.triangles)
    seconds = time.perf_counter() - t0
    return vertices, faces, seconds, given, fixed


def pymeshlab(points, normals, p):
    """MeshLab's filter generate_surface_reconstruction_screened_poisson."""
    import pymeshlab as ml

    t0 = time.perf_counter()
    ms = ml.MeshSet()
    ms.add_mesh(ml.Mesh(vertex_matrix=points, v_normals_matrix=normals))
    given = dict(
        depth=p["depth"],
        fulldepth=p["full_depth"],
        cgdepth=0,
        scale=p["scale"],
        samplespernode=p["samples_per_node"],
        pointweight=p["point_weight"],
        iters=p["iters"],
        confidence=False,
        preclean=False,
        threads=p["threads"],
    )
    ms.generate_surface_reconstruction_screened_poisson(**given)
    m = ms.current_mesh()
    vertices = m.vertex_matrix()
    faces = m.face_matrix()
    seconds = time.perf_counter() - t0
    # MeshLab's plugin instantiates its bundled PoissonRecon with degree 2 and Neumann
    # boundaries; neither is a filter parameter.
    fixed = dict(degree=2, boundary="neumann")
    return vertices, faces, seconds, given, fixed


PEERS = {"pypoisson2": pypoisson2, "open3d": open3d, "pymeshlab": pymeshlab}


def main():
    if len(sys.argv) != 5 or sys.argv[1] not in PEERS:
        sys.exit(f"usage: python_peers.py {{{'|'.join(PEERS)}}} IN.ply OUT.ply PARAMS_JSON")
    tool, src, dst, params = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
    points, normals = read_points(src)
    vertices, faces, seconds, given, fixed = PEERS[tool](points, normals, params)
    if len(faces) == 0:
        sys.exit(f"{tool} returned an empty mesh")
    write_mesh(dst, vertices, faces)
    print("BENCH " + json.dumps({"compute_seconds": seconds, "given": given, "fixed": fixed}), flush=True)


if __name__ == "__main__":
    main()
