#!/usr/bin/env python3
"""Know the floor (issue 20): each stage's time against the machine's memory bandwidth.

Runs the bandwidth probe (`cargo run --release --example bandwidth`, a STREAM-style triad on 1
thread and on all threads), then `spsr reconstruct -v` over a grid of inputs, depths, degrees
and thread counts, and reads the `-v` profile: per stage its time, the bytes it must move at the
least and the flops it does (`spsr::work`, the floor model). Writes a table per run case:

    time, bytes, flops, achieved GB/s, floor time (bytes / probe bandwidth of that thread
    count), time / floor, share of the total, and the 1 -> 2 thread speed-up of the stage

to `bench/results/<name>.md` and `.json`, with `uptime` before and after (the load average says
how far the timings can be trusted on a shared machine).

    python3 bench/floor/run.py                      # bunny_1m, spot_1m; depths 10 11; degrees 1 2; threads 1 2
    python3 bench/floor/run.py --depths 10          # what the committed table ran
    python3 bench/floor/run.py --help

Standard library only.
"""

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SPSR = ROOT / "target" / "release" / "spsr"
PROBE = ROOT / "target" / "release" / "examples" / "bandwidth"

# "  name   1.234 s   peak   120 MiB   0.104 GB   0.016 Gflop   1.01 GB/s"; the peak and the
# work columns are optional (reading and writing have no peak, some stages no model).
LINE = re.compile(
    r"^  (?P<indent>\s*)(?P<name>\S.*?)\s+(?P<secs>[\d.]+) s"
    r"(?:\s+peak\s+(?P<mib>\d+) MiB)?"
    r"(?:\s+(?P<gb>[\d.]+) GB\s+(?P<gflop>[\d.]+) Gflop\s+(?P<rate>[\d.]+) GB/s)?\s*$"
)


def sh(cmd, **kw):
    return subprocess.run(cmd, check=True, text=True, capture_output=True, **kw).stdout


def uptime():
    try:
        return sh(["uptime"]).strip()
    except (OSError, subprocess.CalledProcessError):
        return "uptime unavailable"


def load_average():
    return list(os.getloadavg())


def cpu_model():
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def build():
    env = dict(os.environ, CARGO_TARGET_DIR=str(ROOT / "target"))
    for args in (["-p", "spsr-cli"], ["-p", "spsr", "--example", "bandwidth"]):
        subprocess.run(["cargo", "build", "--release", *args], cwd=ROOT, check=True, env=env)


def probe(repeats):
    out = sh([str(PROBE), "--json", "--repeats", str(repeats)])
    return json.loads(out)


def parse_profile(stderr):
    """The `timings:` block of `-v`: a list of stages (parts of "solving" with `part` set)."""
    stages, inside, total = [], False, None
    for line in stderr.splitlines():
        if line.startswith("timings:"):
            inside = True
            continue
        if not inside:
            continue
        m = LINE.match(line)
        if not m:
            break
        name, secs = m["name"], float(m["secs"])
        if name == "total":
            total = secs
            break
        stages.append(
            {
                "stage": name,
                "part": bool(m["indent"]),
                "seconds": secs,
                "peak_mib": int(m["mib"]) if m["mib"] else None,
                "gb": float(m["gb"]) if m["gb"] is not None else None,
                "gflop": float(m["gflop"]) if m["gflop"] is not None else None,
            }
        )
    return stages, total


def run_case(inp, depth, degree, threads, timeout):
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "mesh.ply"
        cmd = [
            str(SPSR), "reconstruct", str(inp), "-o", str(out), "--depth", str(depth),
            "--degree", str(degree), "--threads", str(threads), "-v",
        ]
        env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
        t = time.time()
        try:
            p = subprocess.run(cmd, text=True, capture_output=True, timeout=timeout, env=env)
        except subprocess.TimeoutExpired:
            return {"failed": f"over {timeout} s", "command": " ".join(cmd)}
        wall = time.time() - t
    if p.returncode != 0:
        return {"failed": p.stderr.strip().splitlines()[-1][-300:], "command": " ".join(cmd)}
    stages, total = parse_profile(p.stderr)
    mesh = re.search(r"^mesh\s+(\d+) vertices, (\d+) faces", p.stderr, re.M)
    nodes = re.search(r"^octree\s+(\d+) nodes", p.stderr, re.M)
    samples = re.search(r"^samples\s+(\d+)", p.stderr, re.M)
    return {
        "command": " ".join(cmd),
        "wall_s": wall,
        "total_s": total,
        "stages": stages,
        "vertices": int(mesh[1]) if mesh else None,
        "faces": int(mesh[2]) if mesh else None,
        "nodes": int(nodes[1]) if nodes else None,
        "samples": int(samples[1]) if samples else None,
    }


def default_data():
    """`../shared/data` beside the repository, or beside the main checkout for a worktree."""
    here = ROOT.parent / "shared" / "data"
    if here.is_dir():
        return here
    try:
        common = Path(sh(["git", "rev-parse", "--git-common-dir"], cwd=ROOT).strip())
        main = (ROOT / common).resolve().parent
        return main.parent / "shared" / "data"
    except (OSError, subprocess.CalledProcessError):
        return here


def bandwidth_of(bw, threads):
    """The probe's GB/s (STREAM count) for a thread count: the 1-thread figure for 1, the
    all-threads figure otherwise."""
    rows = sorted(bw["results"], key=lambda r: r["threads"])
    for r in rows:
        if r["threads"] == threads:
            return r["gbs"]
    return rows[-1]["gbs"] if threads > 1 else rows[0]["gbs"]


def derive(results, bw):
    """Adds floor time, time / floor, share and speed-up to every stage of every case."""
    by_key = {}
    for case in results:
        if "stages" in case:
            by_key[(case["input"], case["depth"], case["degree"], case["threads"])] = case
    for case in results:
        if "stages" not in case:
            continue
        gbs = bandwidth_of(bw, case["threads"])
        case["probe_gbs"] = gbs
        one = by_key.get((case["input"], case["depth"], case["degree"], 1))
        if case["threads"] == 1:
            one = None
        ones = {s["stage"]: s for s in one["stages"]} if one else {}
        for s in case["stages"]:
            s["achieved_gbs"] = s["gb"] / s["seconds"] if s["gb"] and s["seconds"] > 0 else None
            s["floor_s"] = s["gb"] / gbs if s["gb"] is not None else None
            s["over_floor"] = (
                s["seconds"] / s["floor_s"] if s["floor_s"] and s["floor_s"] > 0 else None
            )
            s["share"] = s["seconds"] / case["total_s"] if case["total_s"] else None
            o = ones.get(s["stage"])
            s["speedup"] = (
                o["seconds"] / s["seconds"] if o and s["seconds"] > 0 and o["seconds"] > 0 else None
            )
        # The issue's target: no top-level stage above 25 % of the total unless it runs
        # within 3 x of its bandwidth floor.
        case["over_target"] = [
            s["stage"]
            for s in case["stages"]
            if not s["part"]
            and s["share"] is not None
            and s["share"] > 0.25
            and (s["over_floor"] is None or s["over_floor"] > 3)
        ]


def fmt(x, spec):
    return "—" if x is None else format(x, spec)


def name_share(s):
    return f"{s['stage']} ({100 * s['share']:.0f} %)"


def table(case):
    rows = [
        "| stage | time s | share | GB | Gflop | GB/s | floor s | time ÷ floor | speed-up 1→2 |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in case["stages"]:
        name = ("&nbsp;&nbsp;" + s["stage"]) if s["part"] else s["stage"]
        rows.append(
            f"| {name} | {s['seconds']:.3f} | {fmt(s['share'] and 100 * s['share'], '.1f')} % "
            f"| {fmt(s['gb'], '.3f')} | {fmt(s['gflop'], '.3f')} | {fmt(s['achieved_gbs'], '.2f')} "
            f"| {fmt(s['floor_s'], '.4f')} | {fmt(s['over_floor'], '.0f')} | {fmt(s['speedup'], '.2f')} |"
        )
    rows.append(f"| total | {case['total_s']:.3f} | 100 % | | | | | | |")
    return "\n".join(rows)


def report(meta, bw, results):
    lines = [
        f"# {meta['name']}: each stage against the bandwidth floor (issue 20)",
        "",
        f"Machine: {meta['cpu']}, {meta['cores']} cores. spsr {meta['commit']}.",
        "",
        f"**Timings taken under load** (the machine was shared): load average "
        f"{' / '.join(f'{x:.2f}' for x in meta['load_before'])} (1 / 5 / 15 min) before, "
        f"{' / '.join(f'{x:.2f}' for x in meta['load_after'])} after. "
        "To be rerun on a quiet machine.",
        "",
        f"- `uptime` before: `{meta['uptime_before']}`",
        f"- `uptime` after: `{meta['uptime_after']}`",
        "",
        "Bandwidth probe (`cargo run --release --example bandwidth -- --json`, triad "
        f"a = b + s·c over 3 × {bw['array_mib']} MiB, best of {bw['repeats']}, STREAM's count of "
        "24 bytes an element, write-allocate not counted):",
        "",
    ]
    for r in bw["results"]:
        lines.append(
            f"- {r['threads']} thread(s): {r['gbs']:.2f} GB/s ({r['gbs_write_allocate']:.2f} GB/s "
            "counting the write-allocate read)"
        )
    lines += [
        "",
        "How to read the tables: *GB* and *Gflop* are the floor model of `spsr::work` "
        "(`crates/spsr/src/pipeline/work.rs`: every array read or written once at its stored "
        "size; flops counted from the loops), *GB/s* that traffic over the stage's time, *floor "
        "s* the traffic over the probe's bandwidth for the run's thread count, *time ÷ floor* how "
        "far the stage is from that floor, *share* the stage's part of the total (the indented "
        "rows are the parts of \"solving\"), *speed-up 1→2* the stage's 1-thread time over its "
        "2-thread time. The runs are plain `-v` runs, without `--residuals` (whose measurement "
        "would add the solver's *fixed right-hand side* and *residual* parts). *noise* has no model (the "
        "noise adaptation is being reworked elsewhere). The run's command is under each table.",
        "",
        "Target (issue 20): no stage above 25 % of the total unless it runs within 3 × of its "
        "bandwidth floor.",
        "",
        "## Summary",
        "",
        "| input | depth | degree | threads | total s | stages over 25 % | their time ÷ floor | target |",
        "|---|---:|---:|---:|---:|---|---|---|",
    ]
    for c in results:
        if "stages" not in c:
            lines.append(
                f"| {c['input']} | {c['depth']} | {c['degree']} | {c['threads']} | failed | "
                f"{c['failed'][:80]} | | |"
            )
            continue
        big = [s for s in c["stages"] if not s["part"] and s["share"] and s["share"] > 0.25]
        lines.append(
            f"| {c['input']} | {c['depth']} | {c['degree']} | {c['threads']} | {c['total_s']:.1f} "
            f"| {', '.join(name_share(s) for s in big)} "
            f"| {', '.join(fmt(s['over_floor'], '.0f') for s in big)} "
            f"| {'missed' if c['over_target'] else 'met'} |"
        )
    for c in results:
        if "stages" not in c:
            continue
        lines += [
            "",
            f"## {c['input']}, depth {c['depth']}, degree {c['degree']}, {c['threads']} thread(s)",
            "",
            f"{c['samples']} samples, {c['nodes']} nodes, {c['vertices']} vertices, {c['faces']} "
            f"faces; floor at {c['probe_gbs']:.2f} GB/s.",
            "",
            table(c),
            "",
            f"`{c['command']}`",
        ]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--inputs", nargs="+", default=["bunny_1m", "spot_1m"])
    ap.add_argument("--depths", nargs="+", type=int, default=[10, 11])
    ap.add_argument("--degrees", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--data", default=os.environ.get("SPSR_BENCH_DATA") or str(default_data()),
                    help="folder with points/<input>.ply (default ../shared/data beside the repository)")
    ap.add_argument("--name", default="issue20-floor")
    ap.add_argument("--timeout", type=int, default=3600, help="seconds per run")
    ap.add_argument("--repeats", type=int, default=10, help="the probe's repetitions")
    ap.add_argument("--no-build", action="store_true", help="use the binaries in target/release")
    a = ap.parse_args()

    if not a.no_build:
        build()
    results_dir = ROOT / "bench" / "results"
    results_dir.mkdir(parents=True, exist_ok=True)
    md_path, json_path = results_dir / f"{a.name}.md", results_dir / f"{a.name}.json"
    try:
        commit = sh(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT).strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    meta = {
        "name": a.name,
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "commit": commit,
        "uptime_before": uptime(),
        "load_before": load_average(),
    }
    print(f"uptime: {meta['uptime_before']}", file=sys.stderr)
    bw = probe(a.repeats)
    print(f"bandwidth: {json.dumps(bw['results'])}", file=sys.stderr)
    results = []
    for inp in a.inputs:
        path = Path(a.data) / "points" / f"{inp}.ply"
        for depth in a.depths:
            for degree in a.degrees:
                for threads in a.threads:
                    print(f"{inp} depth {depth} degree {degree} threads {threads} ...", file=sys.stderr, flush=True)
                    case = run_case(path, depth, degree, threads, a.timeout)
                    case.update(input=inp, depth=depth, degree=degree, threads=threads)
                    print(f"  {case.get('total_s', case.get('failed'))}", file=sys.stderr, flush=True)
                    results.append(case)
                    # Written after every run, so an interrupted grid keeps what it measured.
                    json_path.write_text(json.dumps({"meta": meta, "bandwidth": bw, "runs": results}, indent=1))
    meta["uptime_after"] = uptime()
    meta["load_after"] = load_average()
    derive(results, bw)
    json_path.write_text(json.dumps({"meta": meta, "bandwidth": bw, "runs": results}, indent=1))
    md_path.write_text(report(meta, bw, results))
    print(f"wrote {md_path} and {json_path}", file=sys.stderr)


if __name__ == "__main__":
    main()
