#!/usr/bin/env python3
"""Side-by-side runs of spsr and PoissonRecon 18.74 (the PyPI binding `pypoisson2`) on the
shared data, with the same parameters, each run as its own process. Reports wall time, peak
resident memory (from the child's rusage), mesh size, closedness and distances to the ground
truth (area-uniform samples, exact point-to-triangle distances).

    python3 bench/compare_reference.py --inputs bunny_100k sphere_200k spot_1m --depths 8 10

The reference runs in the virtual environment given by --venv (default
~/.cache/spsr-bench-venv, made by bench/setup_venv.sh). Results go to bench/results/.
"""
import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data")

GROUND_TRUTH = {
    "bunny": "gt/bunny.ply",
    "spot": "gt/spot.ply",
    "sphere": "sphere:0.1,-0.2,0.3,1",
    "torus": "gt/torus.ply",
    "fandisk": "gt/fandisk.ply",
    "rocker_arm": "gt/rocker_arm.ply",
    "bunny_small": "gt/bunny_small.ply",
}


def ground_truth(name):
    for key in sorted(GROUND_TRUTH, key=len, reverse=True):
        if name.startswith(key):
            gt = GROUND_TRUTH[key]
            return gt if gt.startswith("sphere:") else os.path.join(DATA, gt)
    return None


def measured(cmd, env=None):
    """Runs `cmd`; returns (exit status, wall seconds, peak RSS in MiB, stderr tail)."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        err.seek(0)
        tail = err.read().decode(errors="replace")[-400:]
    code = os.waitstatus_to_exitcode(status)
    return code, wall, usage.ru_maxrss / 1024.0, tail


def score(mesh, gt, tool):
    out = subprocess.run([tool, mesh, gt, "200000"], capture_output=True, text=True)
    if out.returncode != 0:
        return {"error": out.stderr.strip()[-200:]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--inputs", nargs="+", default=["bunny_100k", "sphere_200k", "spot_1m"])
    ap.add_argument("--depths", nargs="+", type=int, default=[8, 10])
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--venv", default=os.path.expanduser("~/.cache/spsr-bench-venv"))
    ap.add_argument("--timeout", type=int, default=1800)
    args = ap.parse_args()

    subprocess.run(["cargo", "build", "--release", "-q", "-p", "spsr-cli", "-p", "spsr", "--example", "mesh_distance"], cwd=ROOT, check=True)
    subprocess.run(["cargo", "build", "--release", "-q", "-p", "spsr-cli"], cwd=ROOT, check=True)
    spsr = os.path.join(ROOT, "target", "release", "spsr")
    scorer = os.path.join(ROOT, "target", "release", "examples", "mesh_distance")
    py = os.path.join(args.venv, "bin", "python")
    runner = os.path.join(ROOT, "bench", "run_pypoisson2.py")
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads))
    work = tempfile.mkdtemp(prefix="spsr-bench-")
    rows = []
    for name in args.inputs:
        src = os.path.join(DATA, "points", name + ".ply")
        gt = ground_truth(name)
        for depth in args.depths:
            runs = {"spsr": [], "PoissonRecon 18.74": []}
            for rep in range(args.reps):
                order = ["spsr", "PoissonRecon 18.74"] if rep % 2 == 0 else ["PoissonRecon 18.74", "spsr"]
                for tool in order:
                    out = os.path.join(work, f"{name}-{depth}-{tool[:4]}.ply")
                    if tool == "spsr":
                        cmd = [spsr, "reconstruct", src, "-o", out, "--depth", str(depth), "--degree", str(args.degree), "--threads", str(args.threads)]
                    else:
                        cmd = [py, runner, src, out, str(depth), str(args.degree)]
                    code, wall, rss, tail = measured(cmd, env)
                    runs[tool].append((code, wall, rss, tail, out))
            for tool, rs in runs.items():
                ok = [r for r in rs if r[0] == 0]
                row = {"input": name, "depth": depth, "tool": tool, "degree": args.degree, "threads": args.threads}
                if not ok:
                    row["failed"] = rs[-1][3].strip().splitlines()[-1] if rs[-1][3].strip() else f"exit {rs[-1][0]}"
                else:
                    row["wall_s"] = statistics.median(r[1] for r in ok)
                    row["peak_rss_mib"] = statistics.median(r[2] for r in ok)
                    if gt:
                        row.update(score(ok[-1][4], gt, scorer))
                rows.append(row)
                print(json.dumps(row), flush=True)
    stamp = datetime.datetime.now().strftime("%Y-%m-%d-%H%M")
    os.makedirs(os.path.join(ROOT, "bench", "results"), exist_ok=True)
    meta = {
        "date": stamp,
        "machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.platform()}",
        "spsr": subprocess.run([spsr, "--version"], capture_output=True, text=True).stdout.strip(),
        "reference": "pypoisson2 (PoissonRecon 18.74)",
        "parameters": {"degree": args.degree, "point_weight": 2 * args.degree, "samples_per_node": 1.5, "full_depth": 5, "boundary": "neumann", "threads": args.threads, "reps": args.reps},
        "rows": rows,
    }
    with open(os.path.join(ROOT, "bench", "results", f"reference-{stamp}.json"), "w") as f:
        json.dump(meta, f, indent=1)
    lines = [
        f"Run {stamp} on {meta['machine']}; degree {args.degree}, α = {2 * args.degree}, samples per node 1.5, {args.threads} threads, median of {args.reps}.",
        "",
        "| input | depth | tool | vertices | mean dist. mesh→GT | mean dist. GT→mesh | closed | wall (s) | peak RSS (MiB) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "failed" in r:
            lines.append(f"| {r['input']} | {r['depth']} | {r['tool']} | failed: {r['failed']} | | | | | |")
            continue
        lines.append(
            f"| {r['input']} | {r['depth']} | {r['tool']} | {r.get('vertices', '')} | {r.get('mesh_to_gt_mean', float('nan')):.3e} | "
            f"{r.get('gt_to_mesh_mean', float('nan')):.3e} | {r.get('closed', '')} | {r['wall_s']:.2f} | {r['peak_rss_mib']:.0f} |"
        )
    table = "\n".join(lines)
    with open(os.path.join(ROOT, "bench", "results", f"reference-{stamp}.md"), "w") as f:
        f.write(table + "\n")
    print(table)


if __name__ == "__main__":
    sys.exit(main())
