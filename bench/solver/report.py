#!/usr/bin/env python3
"""Issue 18: bench/results/issue18-solver.{md,png} from the JSON that run.py (residual, work,
Chamfer; degree 1 in issue18-solver.json, degree 2 in issue18-solver-degree2.json), timing.py
(issue18-timing.json) and score.py (issue18-score.json) wrote."""
import json, os, statistics

R = "bench/results"
REF = {  # PoissonRecon 18.74 at its defaults, bench/results/issue3-grid.md (Chamfer rel., wall s)
    ("sphere_200k", 8): (1.45e-05, 13.18), ("sphere_200k", 9): (1.64e-05, 21.72), ("sphere_200k", 10): (2.08e-05, 42.65),
    ("spot_1m", 8): (4.29e-05, 9.62), ("spot_1m", 9): (1.59e-05, 30.58), ("spot_1m", 10): (8.59e-06, 120.44),
}


def load(name):
    p = os.path.join(R, name)
    return json.load(open(p)) if os.path.exists(p) else None


def main():
    md = ["# Issue 18: the solver's cycles", "",
          "Configurations are written solver/cycles/sweeps per relaxation; cascadic/1/8 is today's default. "
          "What the figures say and the default chosen: `docs/solver.md`. Commands: "
          "`python3 bench/solver/run.py --spsr target/release/spsr` (degree 1), "
          "`... run.py --short --degrees 2 --clouds sphere_200k --name issue18-solver-degree2`, "
          "`python3 bench/solver/score.py`, `python3 bench/solver/timing.py --reps 2 --depths 8 9 10`, then "
          "`python3 bench/solver/report.py` (matplotlib for the figure).", ""]
    sweeps = [(1, load("issue18-solver.json")), (2, load("issue18-solver-degree2.json"))]
    md += ["## Residual against work, Chamfer (`bench/solver/run.py`)", "",
           "One `spsr reconstruct -v` per configuration (solver/cycles/sweeps per relaxation); the whole "
           "hierarchical system's relative residual `‖b − M x‖/‖b‖` after the last cycle, the work "
           "(Gauss–Seidel sweeps × nodes over the depths above the base), the solve's time from the report "
           "(without the residuals' measurement; divergence constraints included), and `spsr eval` Chamfer against "
           "the shared ground-truth mesh (gt/sphere.ply, gt/spot.ply; absolute units). One run each; "
           "the machine was shared and loaded (load average given), so times are indicative only; "
           "residual, work and Chamfer are deterministic.", ""]
    for degree, d in sweeps:
        if not d:
            continue
        md += [f"Degree {degree}; load average at the end {d['load_average'][0]:.1f} / {d['load_average'][1]:.1f} / {d['load_average'][2]:.1f} (2 cores).", "",
               "| cloud | depth | solver | cycles | sweeps | residual per cycle | work | solve (s) | Chamfer | vs cascadic/1/8 |",
               "|---|---|---|---|---|---|---|---|---|---|"]
        base = {}
        for r in d["rows"]:
            if (r["solver"], r["cycles"], r["iters"]) == ("cascadic", 1, 8):
                base[(r["cloud"], r["depth"])] = r["eval"]["chamfer"]
        for r in d["rows"]:
            b = base.get((r["cloud"], r["depth"]))
            rel = f"{100 * (r['eval']['chamfer'] / b - 1):+.1f} %" if b else ""
            md.append(f"| {r['cloud']} | {r['depth']} | {r['solver']} | {r['cycles']} | {r['iters']} | "
                      f"{' → '.join(f'{x:.4f}' for x in r['residual'])} | {r['work'][-1]:.3g} | {r['solve_seconds_median']:.1f} | "
                      f"{r['eval']['chamfer']:.4e} | {rel} |")
        md.append("")
    s = load("issue18-score.json")
    if s:
        md += ["## Against PoissonRecon 18.74 (`bench/solver/score.py`)", "",
               "Chamfer relative to the ground truth's diagonal, scored as `bench/run.py` scores (analytic sphere for "
               "sphere_200k, gt/spot.ply for spot_1m), against PoissonRecon 18.74 at its defaults from "
               "`bench/results/issue3-grid.md` (same scoring, same machine, loaded). Every mesh below is closed "
               "and manifold, one piece, unless marked.", "",
               "| cloud | depth | configuration | Chamfer (rel.) | / PoissonRecon | topology |", "|---|---|---|---|---|---|"]
        for r in s:
            ref = REF[(r["cloud"], r["depth"])][0]
            topo = "closed, manifold" if r["closed"] and r["edge_manifold"] and r["vertex_manifold"] else "NOT closed/manifold"
            if r["components"] != 1:
                topo += f", {r['components']} pieces"
            md.append(f"| {r['cloud']} | {r['depth']} | {r['config']} | {r['chamfer_rel']:.3e} | {r['chamfer_rel'] / ref:.3f} | {topo} |")
        md.append("")
    t = load("issue18-timing.json")
    if t:
        loads = t["load_average_per_run"]
        md += ["## Whole runs' time (`bench/solver/timing.py`)", "",
               f"`spsr reconstruct` without `-v`, 2 threads, configurations alternating run by run, median of {len(t['rows'][0]['walls'])} "
               f"(the runs' 1-minute load average ranged {min(loads):.1f}–{max(loads):.1f} on 2 cores: other engineers' builds "
               "and this session's own scoring ran alongside). Wall times scatter by up to 3× under that load; the CPU time "
               "(user + system of the run) is the steadier measure of the work and the ratio to quote. These runs used the "
               "binary before the base solve of later cycles was warm-started (commit 39c811c; on sphere_200k at depth 8 that "
               "changed the Chamfer in the sixth digit and the CPU time by about 2 %). The second repetition was cut short "
               "for time, so most rows are one run.", "",
               "| run | walls (s) | CPU (s) | median CPU | CPU / cascadic/1/8 | wall / cascadic/1/8 | Chamfer (abs.) |",
               "|---|---|---|---|---|---|---|"]
        med = {r["config"]: r for r in t["rows"]}
        for r in t["rows"]:
            r0 = med.get(r["config"].rsplit(" ", 1)[0] + " cascadic/1/8")
            cr = r["median_cpu"] / r0["median_cpu"] if r0 else float("nan")
            wr = r["median_wall"] / r0["median_wall"] if r0 else float("nan")
            md.append(f"| {r['config']} | {', '.join(f'{w:.1f}' for w in r['walls'])} | {', '.join(f'{w:.1f}' for w in r['cpu'])} | "
                      f"{r['median_cpu']:.1f} | {cr:.2f} | {wr:.2f} | {r['chamfer']:.4e} |")
        md.append("")
    open(os.path.join(R, "issue18-solver.md"), "w").write("\n".join(md) + "\n")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    marks = {"cascadic": "o", "vcycle": "s", "wcycle": "^"}
    for degree, d in sweeps:
        if not d:
            continue
        for r in d["rows"]:
            lab = f"{r['cloud']} deg{degree}"
            col = {"sphere_200k": "C0", "spot_1m": "C1"}[r["cloud"]] if degree == 1 else "C2"
            axes[0].plot(r["work"], r["residual"], marks[r["solver"]] + "-", color=col, alpha=0.6, ms=4)
            b = [x["eval"]["chamfer"] for x in d["rows"] if x["cloud"] == r["cloud"] and (x["solver"], x["cycles"], x["iters"]) == ("cascadic", 1, 8)][0]
            axes[1].plot(r["work"][-1] / [x for x in d["rows"] if x["cloud"] == r["cloud"]][0]["work"][-1], r["eval"]["chamfer"] / b,
                         marks[r["solver"]], color=col, ms=6, label=lab if r["solver"] == "cascadic" and r["cycles"] == 1 and r["iters"] == 8 else None)
    axes[0].set_xscale("log"); axes[0].set_yscale("log")
    axes[0].set_xlabel("work (sweeps × nodes)"); axes[0].set_ylabel("whole system's relative residual")
    axes[0].set_title("residual after each cycle (o cascadic, □ V, △ W)")
    axes[1].set_xlabel("work / cascadic 8 sweeps"); axes[1].set_ylabel("Chamfer / cascadic 8 sweeps")
    axes[1].set_title("Chamfer to the ground truth against work (depth 8)")
    axes[1].axhline(1.0, color="grey", lw=0.5); axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(R, "issue18-solver.png"), dpi=110)


if __name__ == "__main__":
    main()
