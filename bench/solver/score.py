#!/usr/bin/env python3
"""Issue 18: Chamfer (relative to the ground truth's diagonal) of solver configurations, scored
as bench/run.py scores the reference (analytic sphere for sphere_200k, gt/spot.ply for
spot_1m), so that the figures compare with PoissonRecon 18.74's in bench/results/issue3-grid.md.
Writes bench/results/<name>.json.

    python3 bench/solver/score.py --spsr target/release/spsr --depths 8 9 10
"""
import argparse, json, os, subprocess, tempfile

DATA = "/work/shared/data"
GT = {"sphere_200k": ["--reference-sphere", "0.1,-0.2,0.3,1.0"], "spot_1m": ["--reference", f"{DATA}/gt/spot.ply"]}
CONFIGS = [("cascadic", 1, 8), ("cascadic", 2, 4), ("vcycle", 2, 4), ("cascadic", 2, 8)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spsr", default="target/release/spsr")
    ap.add_argument("--depths", nargs="+", type=int, default=[8, 9, 10])
    ap.add_argument("--name", default="issue18-score")
    a = ap.parse_args()
    out, rows = os.path.join(tempfile.mkdtemp(), "m.ply"), []
    for cloud, gt in GT.items():
        for depth in a.depths:
            for solver, cycles, iters in CONFIGS:
                subprocess.run([a.spsr, "reconstruct", f"{DATA}/points/{cloud}.ply", "-o", out, "--depth", str(depth),
                                "--solver", solver, "--cycles", str(cycles), "--iters", str(iters)], check=True, capture_output=True)
                e = json.loads(subprocess.run([a.spsr, "eval", out, "--json", *gt], check=True, capture_output=True, text=True).stdout)
                rows.append({"cloud": cloud, "depth": depth, "config": f"{solver}/{cycles}/{iters}", "chamfer_rel": e["chamfer_rel"],
                             "closed": e["closed"], "edge_manifold": e["edge_manifold"], "vertex_manifold": e["vertex_manifold"],
                             "components": e["components"]})
                print(rows[-1], flush=True)
                with open(f"bench/results/{a.name}.json", "w") as f:
                    json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
