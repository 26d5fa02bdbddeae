#!/usr/bin/env python3
"""Issue 18: the solver's cycles measured. For each cloud, depth, degree and solver
configuration, one `spsr reconstruct -v` run gives the whole system's relative residual and the
work (Gauss-Seidel sweeps x nodes) after each cycle and the solve's wall time (from the
report, without the residuals' own measurement); `spsr eval --json` scores the mesh (Chamfer
to the ground truth). Configurations alternate run by run; with --reps > 1 the median time is
kept. Writes bench/results/<name>.{json,md} (and .png when matplotlib is there).

    python3 bench/solver/run.py --spsr target/release/spsr --reps 1 --name issue18-solver
"""
import argparse, json, os, re, statistics, subprocess, tempfile, time

DATA = "/work/shared/data"
CLOUDS = {"sphere_200k": "sphere", "spot_1m": "spot"}
CONFIGS = [
    ("cascadic", 1, 8), ("cascadic", 1, 16), ("cascadic", 1, 32),
    ("cascadic", 2, 8), ("cascadic", 3, 8),
    ("vcycle", 2, 8), ("vcycle", 3, 8), ("vcycle", 4, 8), ("vcycle", 2, 4),
    ("wcycle", 2, 8), ("wcycle", 3, 8),
]

SHORT = [("cascadic", 1, 8), ("cascadic", 1, 16), ("cascadic", 2, 8), ("vcycle", 2, 8), ("vcycle", 2, 4), ("wcycle", 2, 8)]


def run_one(spsr, cloud, depth, degree, solver, cycles, iters, out):
    cmd = [spsr, "reconstruct", f"{DATA}/points/{cloud}.ply", "-o", out, "--depth", str(depth),
           "--degree", str(degree), "--solver", solver, "--cycles", str(cycles), "--iters", str(iters), "-v",
           "--residuals"]
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    err = p.stderr
    res = [float(m) for m in re.findall(r"whole system after cycle \d+: ([0-9.e+-]+)", err)]
    work = [float(m) for m in re.findall(r"work ([0-9.e+-]+) sweeps", err)]
    secs = [float(m) for m in re.findall(r"sweeps x nodes, ([0-9.]+) s\)", err)]
    cons = float(re.search(r"divergence constraints\s+([0-9.]+) s", err).group(1))
    ev = subprocess.run([spsr, "eval", out, "--json", "--reference", f"{DATA}/gt/{CLOUDS[cloud]}.ply"],
                        capture_output=True, text=True, check=True)
    e = json.loads(ev.stdout)
    return {"residual": res, "work": work, "solve_seconds": secs[-1] + cons, "wall_with_report": wall, "eval": e}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spsr", default="target/release/spsr")
    ap.add_argument("--clouds", nargs="+", default=list(CLOUDS))
    ap.add_argument("--depths", nargs="+", type=int, default=[8])
    ap.add_argument("--degrees", nargs="+", type=int, default=[1])
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--name", default="issue18-solver")
    ap.add_argument("--short", action="store_true", help="six configurations instead of eleven")
    a = ap.parse_args()
    rows = {}
    tmp = tempfile.mkdtemp()
    for rep in range(a.reps):
        for cloud in a.clouds:
            for depth in a.depths:
                for degree in a.degrees:
                    for (solver, cycles, iters) in (SHORT if a.short else CONFIGS):
                        key = (cloud, depth, degree, solver, cycles, iters)
                        r = run_one(a.spsr, cloud, depth, degree, solver, cycles, iters, os.path.join(tmp, "m.ply"))
                        rows.setdefault(key, []).append(r)
                        print(key, r["residual"][-1], r["solve_seconds"], flush=True)
    out = []
    for key, rs in rows.items():
        r = rs[0]
        e = r["eval"]
        out.append({"cloud": key[0], "depth": key[1], "degree": key[2], "solver": key[3], "cycles": key[4],
                    "iters": key[5], "residual": r["residual"], "work": r["work"],
                    "solve_seconds_median": statistics.median(x["solve_seconds"] for x in rs),
                    "eval": e})
    load = os.getloadavg()
    res = {"load_average": load, "reps": a.reps, "rows": out}
    os.makedirs("bench/results", exist_ok=True)
    with open(f"bench/results/{a.name}.json", "w") as f:
        json.dump(res, f, indent=1)
    print(json.dumps(res)[:2000])


if __name__ == "__main__":
    main()
