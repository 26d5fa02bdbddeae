#!/usr/bin/env python3
"""Issue 18: wall and CPU time (whole run, no -v; CPU time, user + system of the child, is
far less disturbed by other jobs on a shared machine) and Chamfer to the ground truth of a few solver
configurations against one cascadic cycle of 8 sweeps (PoissonRecon's solve). Configurations
alternate run by run; the median of --reps runs is kept; each mesh is scored once with
`spsr eval --json`. Writes bench/results/<name>.json.

    python3 bench/solver/timing.py --spsr target/release/spsr --reps 3 --depths 8 9 10
    python3 bench/solver/timing.py --reps 3 --depths 8 9 10 --configs cascadic/1/8 cascadic/2/4 \\
        --name issue18-timing-default
"""
import argparse, json, os, statistics, subprocess, tempfile, time

DATA = "/work/shared/data"
GT = {"sphere_200k": "sphere", "spot_1m": "spot"}
CONFIGS = [("cascadic", 1, 8), ("cascadic", 2, 4), ("vcycle", 2, 4)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spsr", default="target/release/spsr")
    ap.add_argument("--clouds", nargs="+", default=list(GT))
    ap.add_argument("--depths", nargs="+", type=int, default=[8])
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--name", default="issue18-timing")
    ap.add_argument("--configs", nargs="+", default=[f"{s}/{c}/{i}" for s, c, i in CONFIGS],
                    help="solver/cycles/sweeps, e.g. cascadic/1/8 cascadic/2/4")
    a = ap.parse_args()
    configs = [(s, int(c), int(i)) for s, c, i in (x.split("/") for x in a.configs)]
    tmp = tempfile.mkdtemp()
    walls, cpu, evals, loads = {}, {}, {}, []
    for rep in range(a.reps):
        for cloud in a.clouds:
            for depth in a.depths:
                for (solver, cycles, iters) in configs:
                    key = f"{cloud} d{depth} {solver}/{cycles}/{iters}"
                    out = os.path.join(tmp, "m.ply")
                    cmd = [a.spsr, "reconstruct", f"{DATA}/points/{cloud}.ply", "-o", out, "--depth", str(depth),
                           "--degree", str(a.degree), "--solver", solver, "--cycles", str(cycles), "--iters", str(iters)]
                    t = time.perf_counter()
                    before = os.times()
                    subprocess.run(cmd, capture_output=True, check=True)
                    after = os.times()
                    walls.setdefault(key, []).append(time.perf_counter() - t)
                    cpu.setdefault(key, []).append(after.children_user + after.children_system
                                                   - before.children_user - before.children_system)
                    loads.append(os.getloadavg()[0])
                    if key not in evals:
                        ev = subprocess.run([a.spsr, "eval", out, "--json", "--reference", f"{DATA}/gt/{GT[cloud]}.ply"],
                                            capture_output=True, text=True, check=True)
                        evals[key] = json.loads(ev.stdout)
                    print(key, f"{walls[key][-1]:.2f}", f"{cpu[key][-1]:.2f}", evals[key]["chamfer"], flush=True)
                    write(a, walls, cpu, evals, loads)


def write(a, walls, cpu, evals, loads):
    """The results so far (written after every run, so that a cut-short run keeps them)."""
    rows = [{"config": k, "walls": w, "median_wall": statistics.median(w), "cpu": cpu[k],
             "median_cpu": statistics.median(cpu[k]), "chamfer": evals[k]["chamfer"],
             "closed": evals[k]["closed"], "components": evals[k]["components"],
             "edge_manifold": evals[k]["edge_manifold"], "vertex_manifold": evals[k]["vertex_manifold"]} for k, w in walls.items()]
    res = {"degree": a.degree, "reps": a.reps, "load_average_per_run": loads, "rows": rows}
    with open(f"bench/results/{a.name}.json", "w") as f:
        json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
