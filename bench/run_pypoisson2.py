#!/usr/bin/env python3
"""Runs PoissonRecon 18.74 through the `pypoisson2` binding on one PLY point cloud and writes
the mesh as binary PLY. Used by compare_reference.py, each run in its own process so that its
peak memory can be measured. Reads binary little-endian PLY with float x y z nx ny nz (the
format of ../shared/data)."""
import sys
import time

import numpy as np


def read_points(path):
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        count = next(int(l.split()[2]) for l in header if l.startswith("element vertex"))
        props = [l.split()[2] for l in header if l.startswith("property")]
        assert "format binary_little_endian" in " ".join(header), "binary little endian only"
        data = np.fromfile(f, dtype="<f4", count=count * len(props)).reshape(count, len(props))
    idx = [props.index(n) for n in ("x", "y", "z", "nx", "ny", "nz")]
    return data[:, idx[:3]].astype(np.float64), data[:, idx[3:]].astype(np.float64)


def write_mesh(path, vertices, faces):
    vertices = np.asarray(vertices, dtype="<f4")
    faces = np.asarray(faces, dtype="<i4")
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


def main():
    src, dst, depth, degree = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    from poisson import poisson_reconstruction

    points, normals = read_points(src)
    t0 = time.perf_counter()
    out = poisson_reconstruction(
        points,
        normals,
        depth=depth,
        degree=degree,
        point_weight=2.0 * degree,
        samples_per_node=1.5,
        full_depth=5,
        boundary="neumann",
    )
    vertices, faces = out[0], out[1]
    t1 = time.perf_counter()
    write_mesh(dst, vertices, faces)
    print(f"compute_seconds {t1 - t0:.3f}", file=sys.stderr)


if __name__ == "__main__":
    main()
