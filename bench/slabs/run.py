#!/usr/bin/env python3
"""Issue 15's measurements: `spsr reconstruct --slabs K` against the same run in one piece.

For each input and depth: the run in one piece, then the slab runs, alternating run by run; wall
time and peak resident memory (the sum over the whole process tree, sampled every 0.1 s, so that a
Dask run counts its scheduler, nannies and workers too); the distance between each
slab mesh and the one-piece mesh (Hausdorff and mean, both directions, in finest cells: the
bounding cube's side / 2^depth) and each mesh's Chamfer distance to the ground truth (spsr eval,
relative to the truth's bounding-box diagonal).

    ~/.cache/spsr-bench-venv/bin/python bench/slabs/run.py [--inputs bunny_1m spot_1m] [--depth 10] [--slabs 1 2 4 8 16]
        [--big spot:4000000] [--name issue15-slabs] [--extra '--cycles 1 --iters 8'] [--workers 0 1 2]

`--workers 0` (the default) runs the slabs one after another with `spsr reconstruct --slabs K`;
`--workers W` (W ≥ 1) runs them as Dask tasks with `python -m spsr.distributed --workers W` (a
LocalCluster of W worker processes, each with 2 / W threads, so that every run uses the machine's 2
cores; the Python that runs this script must have spsr and dask[distributed] installed). With more
than one runner, a plot of time and peak memory against slabs goes beside the table.

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
import threading
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SPSR = os.path.join(ROOT, "target", "release", "spsr")
DATA = os.path.join(ROOT, "..", "shared", "data")
CACHE = os.path.expanduser("~/.cache/spsr-bench-inputs")
sys.path.insert(0, os.path.join(ROOT, "bench"))

from run import tree_rss_kib  # noqa: E402  (bench/run.py)


def timed(args):
    """Runs a command: (wall seconds, peak resident memory of its process tree in MiB)."""
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak, done = [0], threading.Event()

    def watch():
        while not done.wait(0.1):
            peak[0] = max(peak[0], tree_rss_kib(proc.pid))

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    _, err = proc.communicate()
    wall = time.perf_counter() - start
    done.set()
    watcher.join()
    if proc.returncode:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {err.decode()[-2000:]}")
    return wall, peak[0] / 1024


def runner_name(workers):
    return "spsr --slabs" if workers == 0 else f"Dask, {workers} worker{'s' if workers > 1 else ''}"


def slab_command(workers, path, out, depth, k, work, extra):
    """The command of one slab run: the command line's sequential slabs, or a LocalCluster."""
    if workers == 0:
        return [SPSR, "reconstruct", path, "-o", out, "--depth", str(depth), "--slabs", str(k),
                "--work-dir", work] + extra
    threads = max(1, (os.cpu_count() or 2) // workers)
    return [sys.executable, "-m", "spsr.distributed", "--workers", str(workers), path, "-o", out,
            "--depth", str(depth), "--slabs", str(k), "--work-dir", work, "--threads", str(threads)] + extra


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
    ap.add_argument("--workers", nargs="*", type=int, default=[0],
                    help="0: spsr --slabs (one process); W: a Dask LocalCluster of W workers")
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
            # Alternate: one piece, then five slab runs, one piece again, ...
            plan = [(k, workers) for k in a.slabs for workers in a.workers]
            for i, (k, workers) in enumerate(plan):
                out = os.path.join(tmp, f"{name}-{k}-{workers}.ply")
                if i % 5 == 0:
                    runs.setdefault("one", []).append(timed(base + ["-o", one, "--slabs", "auto"]))
                w, m = timed(slab_command(workers, path, out, a.depth, k, tmp, a.extra.split()))
                d = evaluate(out, one)
                c = evaluate(out, gt)
                rows.append(dict(input=name, depth=a.depth, slabs=k, runner=runner_name(workers), time_s=w, peak_mib=m,
                                 hausdorff_cells=d["hausdorff"] / cell, hausdorff=d["hausdorff"],
                                 mean_cells=max(d["mesh_to_reference_mean"], d["reference_to_mesh_mean"]) / cell,
                                 chamfer_rel=c["chamfer_rel"], pieces=c["components"], closed=c["closed"]))
                print(rows[-1], flush=True)
            c1 = evaluate(one, gt)
            w1 = sorted(r[0] for r in runs["one"])[len(runs["one"]) // 2]
            m1 = max(r[1] for r in runs["one"])
            rows.append(dict(input=name, depth=a.depth, slabs=0, runner="spsr, one piece", time_s=w1, peak_mib=m1,
                             hausdorff_cells=0.0, hausdorff=0.0, mean_cells=0.0, chamfer_rel=c1["chamfer_rel"],
                             chamfer=c1["chamfer"],
                             pieces=c1["components"], closed=c1["closed"]))
            print(rows[-1], flush=True)

    os.makedirs(os.path.join(ROOT, "bench", "results"), exist_ok=True)
    with open(os.path.join(ROOT, "bench", "results", a.name + ".json"), "w") as f:
        json.dump(rows, f, indent=1)
    load = os.getloadavg()
    lines = [f"# Slab runs against one piece (depth {a.depth})", "",
             f"`python3 bench/slabs/run.py {' '.join(sys.argv[1:])}`; load average at the end "
             f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; 2 cores. Distances are to the run in one piece, "
             "in finest cells; Chamfer is to the ground truth, relative to its diagonal; peak is the "
             "resident memory of the whole process tree. The Chamfer estimate samples each mesh, so "
             "two meshes that are one surface can differ by a percent or more in it; the *bound* is "
             "exact: the Hausdorff distance between a slab mesh and the one-piece mesh bounds how far "
             "their distances to any surface can differ (triangle inequality), given here relative to "
             "the one-piece mesh's Chamfer distance.", "",
             "| input | runner | slabs | time (s) | × one piece | peak (MiB) | × one piece | Hausdorff (cells) | mean (cells) | Chamfer | × one piece | bound | pieces | closed |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        one = next(x for x in rows if x["input"] == r["input"] and x["slabs"] == 0)
        lines.append(f"| {r['input']} | {r['runner']} | {r['slabs'] or '–'} | {r['time_s']:.1f} | {r['time_s'] / one['time_s']:.2f} "
                     f"| {r['peak_mib']:.0f} | {r['peak_mib'] / one['peak_mib']:.2f} | {r['hausdorff_cells']:.2g} "
                     f"| {r['mean_cells']:.2g} | {r['chamfer_rel']:.4g} | {r['chamfer_rel'] / one['chamfer_rel']:.4f} "
                     f"| ± {r['hausdorff'] / one['chamfer']:.1e} | {r['pieces']} | {'yes' if r['closed'] else 'no'} |")
    with open(os.path.join(ROOT, "bench", "results", a.name + ".md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))
    if len(a.workers) > 1:
        plot(rows, os.path.join(ROOT, "bench", "results", a.name + ".png"))


def plot(rows, path):
    """Time and peak memory against slabs, one line per runner, the run in one piece dashed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    inputs = sorted({r["input"] for r in rows})
    fig, axes = plt.subplots(len(inputs), 2, figsize=(10, 4 * len(inputs)), squeeze=False)
    for row_axes, name in zip(axes, inputs):
        mine = [r for r in rows if r["input"] == name]
        one = next(r for r in mine if r["slabs"] == 0)
        for ax, key, label in zip(row_axes, ("time_s", "peak_mib"), ("time (s)", "peak resident memory (MiB)")):
            for runner in sorted({r["runner"] for r in mine if r["slabs"]}):
                pts = sorted((r["slabs"], r[key]) for r in mine if r["runner"] == runner)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=runner)
            ax.axhline(one[key], color="k", ls="--", lw=1, label="one piece")
            ax.set_xscale("log", base=2)
            ax.set_xticks(sorted({r["slabs"] for r in mine if r["slabs"]}))
            ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
            ax.set_xlabel("slabs")
            ax.set_ylabel(label)
            ax.set_title(f"{name}, depth {one['depth']}")
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
