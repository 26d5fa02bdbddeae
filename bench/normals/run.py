#!/usr/bin/env python3
"""Normal estimation and orientation: spsr's modes against Open3D, on the shared data with the
normals thrown away (each file's own normals are the reference).

    cargo build --release --example normals_bench
    python3 bench/normals/run.py                 # all inputs, writes bench/normals/results.md
    python3 bench/normals/run.py --inputs oni bunny_100k --no-open3d

Every measurement runs in its own process: `normals_bench` (crates/spsr/examples) for spsr,
`open3d_normals.py` in the venv of bench/setup_venv.sh for Open3D. Reported per run: the
percentage of normals oriented like the reference, the mean angle between the normal lines,
the time of estimation + orientation, the peak resident memory of the process at the end of
orientation (Open3D's includes the Python interpreter and libraries; their baseline is given
below the table), and the distance from a depth-8 spsr reconstruction to the ground truth,
next to the same reconstruction from the reference normals. The distance is the symmetric
Chamfer distance (mean of both directions, 200,000 area-uniform samples each), except for the
bunny, whose ground truth is open at the bottom: there it is ground truth → mesh.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DATA = os.path.normpath(os.path.join(ROOT, "..", "shared", "data"))
BENCH = os.path.join(ROOT, "target", "release", "examples", "normals_bench")
VENV = os.path.expanduser("~/.cache/spsr-bench-venv/bin/python")
CUBE = "box:-0.5,-0.371795,-0.371795,0.5,0.371795,0.371795"

# name: (input, ground truth or None, extra arguments of normals_bench)
INPUTS = {
    "bunny_100k": ("points/bunny_100k.ply", "gt/bunny.ply", []),
    "bunny_100k_noise0p25": ("points/bunny_100k_noise0p25.ply", "gt/bunny.ply", []),
    "bunny_100k_noise0p5": ("points/bunny_100k_noise0p5.ply", "gt/bunny.ply", []),
    "spot_100k_nonuniform": ("points/spot_100k_nonuniform.ply", "gt/spot.ply", []),
    "fandisk_100k": ("points/fandisk_100k.ply", "gt/fandisk.ply", []),
    "rocker_arm_100k": ("points/rocker_arm_100k.ply", "gt/rocker_arm.ply", []),
    "sphere_200k": ("points/sphere_200k.ply", "sphere:0.1,-0.2,0.3,1", []),
    "torus_200k": ("points/torus_200k.ply", "gt/torus.ply", []),
    "bunny_1m": ("points/bunny_1m.ply", "gt/bunny.ply", []),
    "kitten": ("real/kitten.ply", None, []),
    "oni": ("real/oni.ply", None, []),
    "cube": ("real/cube.ply", CUBE, []),
    # A hollow ball with a wall of 3 point spacings: nearby sheets facing opposite ways.
    "hollow_ball_100k": ("synth:shell:100000:0.05", None, []),
    # One raw range scan, no normals: the sensor-facing orientation is the reference.
    "bun000_raw": (
        "real/stanford_bunny_raw/bun000.ply",
        None,
        ["--reference-viewpoint", "0,0.1,1"],
    ),
}
VIEWPOINTS = {"bun000_raw": "0,0.1,1"}


def path_of(rel):
    return rel if rel.startswith("synth:") else os.path.join(DATA, rel)


def gt_arg(gt):
    if gt is None:
        return []
    if gt.startswith(("sphere:", "box:")):
        return ["--gt", gt]
    return ["--gt", os.path.join(DATA, gt)]


def run_json(cmd, timeout):
    start = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout} s"}
    wall = time.perf_counter() - start
    if out.returncode != 0:
        return {"error": (out.stderr or out.stdout)[-300:].strip()}
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["wall_s"] = round(wall, 3)
    return res


def measure(name, methods, timeout, log):
    rel, gt, extra = INPUTS[name]
    src = path_of(rel)
    rows = {}
    tmpdir = tempfile.TemporaryDirectory()
    o3d_src = src
    if rel.startswith("synth:") or "--reference-viewpoint" in extra:
        # Open3D reads the same points and reference normals from a file.
        o3d_src = os.path.join(tmpdir.name, "input.ply")
        subprocess.run([BENCH, src, "true", "--write-input", o3d_src] + extra, check=True,
                       capture_output=True)
    for m in methods:
        if m == "true" and gt is None:
            continue
        if m == "viewpoint":
            if name not in VIEWPOINTS:
                continue
            mode = "viewpoint:" + VIEWPOINTS[name]
        else:
            mode = m
        if m == "open3d":
            with tempfile.TemporaryDirectory() as tmp:
                oriented = os.path.join(tmp, "o3d.ply")
                r = run_json([VENV, os.path.join(ROOT, "bench", "normals", "open3d_normals.py"),
                              o3d_src, "--out", oriented], timeout)
                if "error" not in r and gt is not None:
                    d = run_json([BENCH, oriented, "true"] + gt_arg(gt), timeout)
                    for k in ("mesh_to_gt", "gt_to_mesh", "chamfer", "components_mesh"):
                        r[k] = d.get(k)
        else:
            r = run_json([BENCH, src, mode] + gt_arg(gt) + extra, timeout)
        r["name"], r["method"] = name, m
        rows[m] = r
        log.write(json.dumps(r) + "\n")
        log.flush()
        print(name, m, {k: r.get(k) for k in ("oriented_pct", "mean_angle_deg", "normals_s",
                                               "peak_rss_mib", "chamfer", "gt_to_mesh", "error")},
              flush=True)
    tmpdir.cleanup()
    return rows


def distance(name, r):
    if r is None or r.get("chamfer") is None:
        return None
    return r["gt_to_mesh"] if name.startswith("bunny") else r["chamfer"]


def fmt(x, spec):
    return "—" if x is None else format(x, spec)


def table(results):
    lines = [
        "| input | method | oriented like reference (%) | mean angle (°) | distance to GT | × true normals | normals time (s) | peak RSS (MiB) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, rows in results.items():
        truth = distance(name, rows.get("true"))
        for m in ("true", "viewpoint", "mst", "global", "open3d"):
            r = rows.get(m)
            if r is None:
                continue
            if "error" in r:
                lines.append(f"| {name} | {m} | failed: {r['error'][:80]} | | | | | |")
                continue
            d = distance(name, r)
            ratio = d / truth if d is not None and truth else None
            label = "reference normals" if m == "true" else m
            lines.append(
                f"| {name} | {label} | {fmt(r.get('oriented_pct'), '.3f')} | "
                f"{fmt(r.get('mean_angle_deg'), '.2f')} | {fmt(d, '.3e')} | "
                f"{fmt(ratio, '.3f')} | {fmt(r.get('normals_s'), '.2f')} | "
                f"{fmt(r.get('peak_rss_mib'), '.0f')} |"
            )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--inputs", nargs="*", default=list(INPUTS))
    ap.add_argument("--methods", nargs="*", default=["true", "viewpoint", "mst", "global", "open3d"])
    ap.add_argument("--no-open3d", action="store_true")
    ap.add_argument("--timeout", type=int, default=1800)
    ap.add_argument("--log", default=os.path.join(ROOT, "bench", "normals", "results.jsonl"))
    ap.add_argument("--table", action="store_true",
                    help="only print the table of the log's latest row per input and method")
    args = ap.parse_args()
    if args.table:
        results = {}
        with open(args.log) as log:
            for line in log:
                r = json.loads(line)
                results.setdefault(r["name"], {})[r["method"]] = r
        order = [n for n in INPUTS if n in results]
        print(table({n: results[n] for n in order}))
        return
    methods = [m for m in args.methods if not (args.no_open3d and m == "open3d")]
    if not os.path.exists(BENCH):
        sys.exit("build first: cargo build --release --example normals_bench")
    results = {}
    with open(args.log, "a") as log:
        for name in args.inputs:
            results[name] = measure(name, methods, args.timeout, log)
    print(table(results))


if __name__ == "__main__":
    main()
