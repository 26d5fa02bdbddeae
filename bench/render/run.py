#!/usr/bin/env python3
"""`spsr render`, timed: the time to draw meshes of 1 and 10 million faces at 1024 x 1024.

Each mesh is a bumpy sphere (a latitude-longitude grid, radius modulated by a product of
sines, so that faces overlap in depth and the headlight shading varies), written once as
binary PLY to ~/.cache/spsr-bench-inputs. `spsr render -v` reports the drawing time apart
from reading the PLY and writing the PNG; the median of --reps runs is kept.

    ~/.cache/spsr-bench-venv/bin/python bench/render/run.py                 # 1M and 10M faces
    ~/.cache/spsr-bench-venv/bin/python bench/render/run.py --faces 1000000 --reps 1

Writes bench/render/results.md and bench/render/results.json. Needs numpy (the venv made by
bench/setup_venv.sh has it) and builds spsr in release mode unless --no-build.
"""
import argparse
import datetime
import json
import math
import os
import re
import statistics
import subprocess
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SPSR = os.path.join(ROOT, "target", "release", "spsr")
CACHE = os.path.join(os.path.expanduser("~/.cache"), "spsr-bench-inputs")


def bumpy_sphere(faces, path):
    """A closed latitude-longitude sphere of about `faces` triangles, as binary PLY."""
    n = max(4, round(math.sqrt(faces / 4)))  # n latitude bands, 2n longitudes: 4n² faces
    theta = np.linspace(0, np.pi, n + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, 2 * n, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    r = 1 + 0.08 * np.sin(12 * t) * np.sin(9 * p)
    ring = np.stack([r * np.sin(t) * np.cos(p), r * np.cos(t), r * np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    vertices = np.concatenate([[[0, 1, 0]], ring, [[0, -1, 0]]]).astype(np.float32)
    m = 2 * n
    idx = 1 + np.arange((n - 1) * m).reshape(n - 1, m)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    quads = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)])
    south = len(vertices) - 1
    caps = np.concatenate([
        np.stack([np.zeros(m, int), nxt[0], idx[0]], -1),
        np.stack([np.full(m, south), idx[-1], nxt[-1]], -1),
    ])
    tris = np.concatenate([quads, caps]).astype(np.int32)
    face_dtype = np.dtype([("n", "u1"), ("v", "<i4", 3)])
    rows = np.empty(len(tris), face_dtype)
    rows["n"] = 3
    rows["v"] = tris
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(tris)}\nproperty list uchar int vertex_indices\nend_header\n")
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(header.encode())
        f.write(vertices.astype("<f4").tobytes())
        f.write(rows.tobytes())
    os.replace(tmp, path)
    return len(tris)


def run(mesh, view, size, threads, out):
    cmd = [SPSR, "render", mesh, "-o", out, "--view", view, "--size", size, "--threads", str(threads), "-v"]
    r = subprocess.run(cmd, capture_output=True, text=True, check=True)
    m = re.search(r"drawn in ([\d.]+) s, written in ([\d.]+) s", r.stderr)
    read = re.search(r"\(([\d.]+) s to read\)", r.stderr)
    return dict(draw_s=float(m.group(1)), png_s=float(m.group(2)), read_s=float(read.group(1)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--faces", nargs="+", type=int, default=[1_000_000, 10_000_000])
    ap.add_argument("--views", nargs="+", default=["iso", "all"])
    ap.add_argument("--size", default="1024x1024")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--no-build", action="store_true")
    args = ap.parse_args()
    if not args.no_build:
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "spsr-cli"], cwd=ROOT, check=True)
    os.makedirs(CACHE, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for faces in args.faces:
            path = os.path.join(CACHE, f"bumpy_sphere_{faces}.ply")
            if not os.path.exists(path):
                bumpy_sphere(faces, path)
            with open(path, "rb") as f:
                head = f.read(400).decode("latin-1")
            actual = int(re.search(r"element face (\d+)", head).group(1))
            for view in args.views:
                runs = [run(path, view, args.size, args.threads, os.path.join(work, "p.png")) for _ in range(args.reps)]
                row = dict(faces=actual, view=view, size=args.size, threads=args.threads, runs=runs,
                           draw_s=statistics.median(r["draw_s"] for r in runs),
                           png_s=statistics.median(r["png_s"] for r in runs),
                           read_s=statistics.median(r["read_s"] for r in runs))
                rows.append(row)
                print(f"{actual:>11,} faces {view:4s} {args.size}: draw {row['draw_s']:.3f} s, PNG {row['png_s']:.3f} s, "
                      f"reading the PLY {row['read_s']:.2f} s", flush=True)
    version = subprocess.run([SPSR, "--version"], capture_output=True, text=True).stdout.strip()
    git = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    res = dict(date=datetime.datetime.now().isoformat(timespec="seconds"), spsr=f"{version} (git {git})",
               cpu_count=os.cpu_count(), load_average=os.getloadavg(), rows=rows)
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "results.json"), "w") as f:
        json.dump(res, f, indent=1)
    lines = [
        "# `spsr render` timings",
        "",
        f"- {res['date']}, {res['spsr']}, {res['cpu_count']} cores (load average "
        f"{' / '.join(f'{x:.2f}' for x in res['load_average'])} at the end; other jobs may have shared the machine)",
        f"- Meshes: bumpy latitude-longitude spheres written by `bench/render/run.py`; median of {args.reps} runs of "
        f"`spsr render MESH -o P.png --size {args.size} --threads {args.threads} -v`",
        "- draw: `spsr::render::render` (projection, binning, rasterising, shading, 2 x 2 samples per pixel); "
        "PNG: encoding and writing; read: reading the binary PLY (not part of drawing)",
        "",
        "| faces | view | draw (s) | PNG (s) | read PLY (s) |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {r['faces']:,} | {r['view']} | {r['draw_s']:.3f} | {r['png_s']:.3f} | {r['read_s']:.2f} |" for r in rows]
    with open(os.path.join(here, "results.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("wrote bench/render/results.md and results.json")


if __name__ == "__main__":
    main()
