#!/usr/bin/env python3
"""Issue 15's measurements: `spsr reconstruct --slabs K` against the same run in one piece.

For each input and depth: the run in one piece, then the slab runs, alternating run by run; wall
time and peak resident memory of the whole process (/usr/bin/time); the distance between each
slab mesh and the one-piece mesh (Hausdorff and mean, both directions, in finest cells: the
bounding cube's side / 2^depth) and each mesh's Chamfer distance to the ground truth (spsr eval,
relative to the truth's bounding-box diagonal).

    ~/.cache/spsr-bench-venv/bin/python bench/slabs/run.py [--inputs bunny_1m spot_1m] [--depth 10] [--slabs 1 2 4 8 16]
        [--big spot:4000000] [--name issue15-slabs] [--extra '--cycles 1 --iters 8']

Inputs are the shared data's points (../shared/data/points); `--big NAME:COUNT` samples COUNT
points from the shared ground-truth mesh gt/NAME.ply (cached in ~/.cache/spsr-bench-inputs, as
bench/run.py does). Results go to bench/results/NAME.{md,json}.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SPSR = os.path.join(ROOT, "target", "release", "spsr")
DATA = os.path.join(ROOT, "..", "shared", "data")
CACHE = os.path.expanduser("~/.cache/spsr-bench-inputs")
sys.path.insert(0, os.path.join(ROOT, "bench"))


def timed(args):
    """Runs a command under /usr/bin/time: (wall seconds, peak RSS in MiB)."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as t:
        subprocess.run(["/usr/bin/time", "-f", "%e %M", "-o", t.name] + args, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall, kb = t.read().split()[-2:]
    return float(wall), int(kb) / 1024


def evaluate(mesh, reference):
    out = subprocess.run([SPSR, "eval", mesh, "--reference", reference, "--json"], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out)


def cube_cell(path, depth):
    """The finest cell of a run at `depth`: 1.1 × the points' largest bounding-box side / 2^depth."""
    from run import read_mesh_ply  # bench/run.py; a cloud is a mesh without faces
    p = read_mesh_ply(path)[0]
    side = float((p.max(axis=0) - p.min(axis=0)).max())
    return 1.1 * side / 2 ** depth


def resolve(name):
    path = os.path.join(DATA, "points", name + ".ply")
    meta = json.load(open(path[:-4] + ".json"))
    gt = meta.get("ground_truth") or f"gt/{meta.get('shape')}.ply"
    return path, os.path.join(DATA, gt)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--inputs", nargs="*", default=["bunny_1m", "spot_1m"])
    ap.add_argument("--big", nargs="*", default=[], help="NAME:COUNT sampled from gt/NAME.ply")
    ap.add_argument("--depth", type=int, default=10)
    ap.add_argument("--slabs", nargs="*", type=int, default=[1, 2, 4, 8, 16])
    ap.add_argument("--name", default="issue15-slabs")
    ap.add_argument("--extra", default="", help="flags for every run, e.g. '--cycles 1 --iters 8'")
    a = ap.parse_args()

    cases = [(n,) + resolve(n) for n in a.inputs]
    for spec in a.big:
        from run import sample_gt  # bench/run.py
        shape, count = spec.split(":")
        gt = os.path.join(DATA, "gt", shape + ".ply")
        name = f"{shape}_{int(count) // 1_000_000}m"
        cases.append((name, sample_gt(name, gt, int(count), CACHE), gt))

    rows = []
    with tempfile.TemporaryDirectory(dir=os.path.expanduser("~/.cache")) as tmp:
        for name, path, gt in cases:
            cell = cube_cell(path, a.depth)
            one = os.path.join(tmp, f"{name}-one.ply")
            base = [SPSR, "reconstruct", path, "--depth", str(a.depth)] + a.extra.split()
            runs = {}
            # Alternate: one piece, a slab count, one piece again, ...
            for k in a.slabs:
                out = os.path.join(tmp, f"{name}-{k}.ply")
                if "one" not in runs or len(runs) % 2 == 0:
                    runs.setdefault("one", []).append(timed(base + ["-o", one, "--slabs", "auto"]))
                runs[k] = [timed(base + ["-o", out, "--slabs", str(k), "--work-dir", tmp])]
                d = evaluate(out, one)
                c = evaluate(out, gt)
                w, m = runs[k][0]
                rows.append(dict(input=name, depth=a.depth, slabs=k, time_s=w, peak_mib=m,
                                 hausdorff_cells=d["hausdorff"] / cell,
                                 mean_cells=max(d["mesh_to_reference_mean"], d["reference_to_mesh_mean"]) / cell,
                                 chamfer_rel=c["chamfer_rel"], pieces=c["components"], closed=c["closed"]))
                print(rows[-1], flush=True)
            c1 = evaluate(one, gt)
            w1 = sorted(r[0] for r in runs["one"])[len(runs["one"]) // 2]
            m1 = max(r[1] for r in runs["one"])
            rows.append(dict(input=name, depth=a.depth, slabs=0, time_s=w1, peak_mib=m1,
                             hausdorff_cells=0.0, mean_cells=0.0, chamfer_rel=c1["chamfer_rel"],
                             pieces=c1["components"], closed=c1["closed"]))
            print(rows[-1], flush=True)

    os.makedirs(os.path.join(ROOT, "bench", "results"), exist_ok=True)
    with open(os.path.join(ROOT, "bench", "results", a.name + ".json"), "w") as f:
        json.dump(rows, f, indent=1)
    load = os.getloadavg()
    lines = [f"# Slab runs against one piece (depth {a.depth})", "",
             f"`python3 bench/slabs/run.py {' '.join(sys.argv[1:])}`; load average at the end "
             f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; 2 threads. Slabs 0 is the run in one piece; "
             "distances are to it, in finest cells; Chamfer is to the ground truth, relative to its diagonal.", "",
             "| input | slabs | time (s) | × one piece | peak (MiB) | × one piece | Hausdorff (cells) | mean (cells) | Chamfer | × one piece | pieces | closed |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        one = next(x for x in rows if x["input"] == r["input"] and x["slabs"] == 0)
        lines.append(f"| {r['input']} | {r['slabs'] or 'one piece'} | {r['time_s']:.1f} | {r['time_s'] / one['time_s']:.2f} "
                     f"| {r['peak_mib']:.0f} | {r['peak_mib'] / one['peak_mib']:.2f} | {r['hausdorff_cells']:.2g} "
                     f"| {r['mean_cells']:.2g} | {r['chamfer_rel']:.4g} | {r['chamfer_rel'] / one['chamfer_rel']:.4f} "
                     f"| {r['pieces']} | {'yes' if r['closed'] else 'no'} |")
    with open(os.path.join(ROOT, "bench", "results", a.name + ".md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
