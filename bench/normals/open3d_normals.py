#!/usr/bin/env python3
"""Open3D's normal estimation and orientation on one point file, for bench/normals/run.py.

    open3d_normals.py POINTS.ply [--knn 30] [--orient-k 10] [--out ORIENTED.ply]

Reads the points, keeps their normals as the reference and throws them away, then times
`estimate_normals(KDTreeSearchParamKNN(knn))` followed by
`orient_normals_consistent_tangent_plane(orient_k)` (Hoppe's Riemannian-graph MST
propagation). Prints one JSON line: times, peak resident memory of this process (rusage,
includes the Python interpreter and libraries, reported separately as `baseline_rss_mib`),
the percentage of normals oriented like the reference and the mean angle between the normal
lines. With --out, writes the oriented points as x y z nx ny nz (binary PLY, float32) so that
the reconstruction from them can be scored by the same tool as spsr's.
"""
import argparse
import json
import resource
import sys
import time

import numpy as np
import open3d as o3d


def rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def read_ply_xyzn(path):
    """Binary little-endian PLY with float x y z nx ny nz (the shared data's format)."""
    with open(path, "rb") as f:
        header = b""
        while not header.endswith(b"end_header\n"):
            line = f.readline()
            if not line:
                raise ValueError(f"{path}: no end_header")
            header += line
        text = header.decode("ascii", "replace")
        if "binary_little_endian" not in text:
            raise ValueError(f"{path}: expected binary_little_endian")
        count = next(int(l.split()[2]) for l in text.splitlines() if l.startswith("element vertex"))
        props = [l.split()[2] for l in text.splitlines() if l.startswith("property float")]
        data = np.frombuffer(f.read(count * 4 * len(props)), dtype="<f4").reshape(count, len(props))
    cols = {p: i for i, p in enumerate(props)}
    xyz = data[:, [cols["x"], cols["y"], cols["z"]]].astype(np.float64)
    nrm = data[:, [cols["nx"], cols["ny"], cols["nz"]]].astype(np.float64)
    return xyz, nrm


def write_ply_xyzn(path, xyz, nrm):
    body = np.hstack([xyz, nrm]).astype("<f4")
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(body)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\nend_header\n"
    )
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(body.tobytes())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("points")
    ap.add_argument("--knn", type=int, default=30, help="neighbours of the plane fits (Open3D's examples use 30)")
    ap.add_argument("--orient-k", type=int, default=10, help="neighbours of the orientation graph")
    ap.add_argument("--out")
    args = ap.parse_args()
    baseline = rss_mib()
    xyz, ref = read_ply_xyzn(args.points)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    t0 = time.perf_counter()
    pcd.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamKNN(knn=args.knn))
    t1 = time.perf_counter()
    pcd.orient_normals_consistent_tangent_plane(args.orient_k)
    t2 = time.perf_counter()
    est = np.asarray(pcd.normals)
    ln = np.linalg.norm(est, axis=1) * np.linalg.norm(ref, axis=1)
    ok = ln > 0
    cos = np.clip(np.sum(est * ref, axis=1)[ok] / ln[ok], -1.0, 1.0)
    out = {
        "input": args.points,
        "points": len(xyz),
        "mode": "open3d",
        "knn": args.knn,
        "orient_k": args.orient_k,
        "estimate_s": round(t1 - t0, 3),
        "orient_s": round(t2 - t1, 3),
        "normals_s": round(t2 - t0, 3),
        "peak_rss_mib": round(rss_mib(), 1),
        "baseline_rss_mib": round(baseline, 1),
        "oriented_pct": round(100.0 * float(np.mean(cos >= 0.0)), 4),
        "mean_angle_deg": round(float(np.degrees(np.arccos(np.abs(cos))).mean()), 3),
        "open3d": o3d.__version__,
    }
    if args.out:
        write_ply_xyzn(args.out, xyz, est)
    print(json.dumps(out))


if __name__ == "__main__":
    sys.exit(main())
