#!/usr/bin/env python3
"""Side-by-side benchmark of spsr and other Poisson reconstructors: speed, peak memory and
accuracy on the same inputs, on the same machine, in one run.

Usually started through bench/run.sh, which first makes the Python environment (numpy,
matplotlib and the Python peers; see setup_venv.sh) and then runs this file in it:

    bash bench/run.sh                                     # the full default run
    bash bench/run.sh --inputs bunny_20k --depths 6 7 --reps 1 --name smoke

Tools (--tools): spsr (target/release/spsr, built here), pypoisson2 (PoissonRecon 18.74),
open3d, pymeshlab (MeshLab's filter) and poisson_reconstruction (the crates.io crate, through
bench/peers/poisson_reconstruction_runner, built here). Each run of each tool is its own
process, started with the same parameters and thread count; the harness records its wall time
and peak resident memory (rusage of the child) and scores its mesh with `spsr eval` against the
input's ground truth. Repetitions run the whole grid again, with the tools in reverse order on
every other repetition (so spsr and PoissonRecon alternate), and the median is reported.

Inputs come from ../shared/data (or --data / $SPSR_BENCH_DATA). Without that folder the harness
runs on inputs it makes itself (analytic sphere and torus with exact normals, fixed seeds) and
on the repository's own example/bunny.ply. Names like sphere_300k or torus_50k are generated
on demand in either case.

Results: bench/results/<name>.json (everything, including every single run), <name>.md (the
table, and a thumbnail of every scored mesh drawn by `spsr render`, in <name>-thumbs/) and
<name>-*.png (plots). `--plot-only RESULTS.json` redraws the plots and the table.
"""
import argparse
import datetime
import json
import math
import os
import platform
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BENCH = os.path.join(ROOT, "bench")
RUNNER_DIR = os.path.join(BENCH, "peers", "poisson_reconstruction_runner")
RUNNER = os.path.join(RUNNER_DIR, "target", "release", "poisson_reconstruction_runner")
PY_PEERS = os.path.join(BENCH, "peers", "python_peers.py")

TOOLS = ["spsr", "pypoisson2", "open3d", "pymeshlab", "poisson_reconstruction"]
LABELS = {
    "spsr": "spsr",
    "pypoisson2": "PoissonRecon 18.74",
    "open3d": "Open3D",
    "pymeshlab": "PyMeshLab",
    "poisson_reconstruction": "poisson_reconstruction",
}
PY_MODULES = {"pypoisson2": "poisson", "open3d": "open3d", "pymeshlab": "pymeshlab"}

SHARED_DEFAULT = dict(
    inputs=["bunny_100k", "sphere_200k", "spot_1m"],
    depths=[8, 9, 10],
    # The point-count family, run at --scaling-depth only (bunny_100k comes from the grid).
    scaling=["bunny_20k", "bunny_1m"],
    # A small case that every tool finishes, poisson_reconstruction included (it needs minutes
    # where the others need a second; its time here also lets the harness skip its hopeless
    # runs instead of waiting for the time limit).
    cases=["sphere_10k:5"],
)
FALLBACK_DEFAULT = dict(
    inputs=["bunny_20k", "sphere_100k", "torus_100k"],
    depths=[7, 8, 9],
    scaling=["sphere_20k", "sphere_500k"],
    cases=["sphere_10k:5"],
)

SPHERE = dict(center=(0.1, -0.2, 0.3), radius=1.0)
TORUS = dict(major=1.0, minor=0.35)


# ---------------------------------------------------------------------------------------------
# Inputs


def parse_count(text):
    m = re.fullmatch(r"(\d+(?:\.\d+)?)([km]?)", text)
    if not m:
        return None
    return int(float(m.group(1)) * {"": 1, "k": 1000, "m": 1000000}[m.group(2)])


def ply_vertex_count(path):
    with open(path, "rb") as f:
        for _ in range(64):
            line = f.readline().decode("ascii", "replace").split()
            if line[:2] == ["element", "vertex"]:
                return int(line[2])
            if line == ["end_header"]:
                break
    return None


def write_points_ply(path, points, normals, comment):
    import numpy as np

    data = np.hstack([points, normals]).astype("<f4")
    with open(path + ".tmp", "wb") as f:
        f.write(
            (
                f"ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {len(data)}\n"
                + "".join(f"property float {n}\n" for n in ("x", "y", "z", "nx", "ny", "nz"))
                + "end_header\n"
            ).encode("ascii")
        )
        f.write(data.tobytes())
    os.replace(path + ".tmp", path)


def write_mesh_ply(path, vertices, faces):
    import numpy as np

    with open(path + ".tmp", "wb") as f:
        f.write(
            (
                "ply\nformat binary_little_endian 1.0\n"
                f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
                f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
            ).encode("ascii")
        )
        rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        rec["n"] = 3
        rec["i"] = faces
        f.write(np.asarray(vertices, dtype="<f4").tobytes())
        f.write(rec.tobytes())
    os.replace(path + ".tmp", path)


def generate(name, shape, count, cache):
    """Oriented samples on an analytic shape (fixed seed from the name); returns the input path
    and the ground truth."""
    import numpy as np
    import zlib

    os.makedirs(cache, exist_ok=True)
    path = os.path.join(cache, f"{name}.ply")
    rng = np.random.default_rng([20261122, zlib.crc32(name.encode())])
    if shape == "sphere":
        c, r = np.array(SPHERE["center"]), SPHERE["radius"]
        gt = dict(kind="sphere", spec=f"{c[0]},{c[1]},{c[2]},{r}", about="analytic sphere (exact)")
        if not os.path.exists(path):
            u = rng.standard_normal((count, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            write_points_ply(path, c + r * u, u, f"generated {name}: uniform on sphere c={tuple(c)} r={r}")
        return path, gt
    # Torus around z: area-uniform by rejection on the tube angle (area element ~ R + r cos v).
    big, small = TORUS["major"], TORUS["minor"]
    gt_path = os.path.join(cache, "torus_gt.ply")
    gt = dict(
        kind="mesh",
        path=gt_path,
        about="torus R=1 r=0.35, triangulated 1024x384 with vertices on the exact surface",
    )
    if not os.path.exists(gt_path):
        nu, nv = 1024, 384
        uu, vv = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nv) * 2 * np.pi / nv, indexing="ij")
        ring = big + small * np.cos(vv)
        verts = np.stack([ring * np.cos(uu), ring * np.sin(uu), small * np.sin(vv)], axis=-1).reshape(-1, 3)
        i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        a = i * nv + j
        b = ((i + 1) % nu) * nv + j
        c = ((i + 1) % nu) * nv + (j + 1) % nv
        d = i * nv + (j + 1) % nv
        faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
        write_mesh_ply(gt_path, verts, faces)
    if not os.path.exists(path):
        us, vs = [], []
        while sum(len(x) for x in us) < count:
            u = rng.uniform(0, 2 * np.pi, 2 * count)
            v = rng.uniform(0, 2 * np.pi, 2 * count)
            keep = rng.uniform(0, big + small, 2 * count) < big + small * np.cos(v)
            us.append(u[keep])
            vs.append(v[keep])
        u, v = np.concatenate(us)[:count], np.concatenate(vs)[:count]
        n = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], axis=-1)
        p = np.stack([(big + small * np.cos(v)) * np.cos(u), (big + small * np.cos(v)) * np.sin(u), small * np.sin(v)], -1)
        write_points_ply(path, p, n, f"generated {name}: area-uniform on torus R={big} r={small}")
    return path, gt


def read_mesh_ply(path):
    """Vertices and triangles of a binary little-endian PLY with float x y z first and a
    `list uchar int` face element (the layout of ../shared/data/gt)."""
    import numpy as np

    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        body = f.read()
    nv = nf = 0
    vprops = 0
    current = None
    for line in header:
        w = line.split()
        if w[:1] == ["format"] and w[1] != "binary_little_endian":
            raise ValueError(f"{path}: only binary little-endian PLY is read here")
        if w[:1] == ["element"]:
            current = w[1]
            if current == "vertex":
                nv = int(w[2])
            elif current == "face":
                nf = int(w[2])
        elif w[:1] == ["property"] and current == "vertex":
            if w[1] != "float":
                raise ValueError(f"{path}: vertex properties must be float")
            vprops += 1
    verts = np.frombuffer(body, dtype="<f4", count=nv * vprops).reshape(nv, vprops)[:, :3].astype(np.float64)
    rec = np.frombuffer(body, dtype=[("n", "u1"), ("i", "<i4", (3,))], count=nf, offset=nv * vprops * 4)
    if nf and not (rec["n"] == 3).all():
        raise ValueError(f"{path}: only triangles are read here")
    return verts, rec["i"].astype(np.int64)


def sample_gt(name, gt_path, count, cache):
    """`count` oriented points area-uniform on a ground-truth mesh (fixed seed from the name),
    each with its triangle's unit normal, as the shared data's own samples were made."""
    import numpy as np
    import zlib

    os.makedirs(cache, exist_ok=True)
    path = os.path.join(cache, f"{name}.ply")
    if os.path.exists(path):
        return path
    rng = np.random.default_rng([20261124, zlib.crc32(name.encode())])
    pts, nrm = surface_samples(*read_mesh_ply(gt_path), count, rng)
    write_points_ply(path, pts, nrm, f"generated {name}: {count} points area-uniform on {os.path.basename(gt_path)}, triangle normals")
    return path


def surface_samples(v, f, count, rng):
    """`count` points area-uniform on the triangles `f` of the vertices `v`, each with its
    triangle's unit normal, drawn from `rng`."""
    import numpy as np

    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross = np.cross(b - a, c - a)
    area = np.linalg.norm(cross, axis=1)
    keep = area > 0
    a, b, c, cross, area = a[keep], b[keep], c[keep], cross[keep], area[keep]
    tri = rng.choice(len(area), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    u, w = 1 - s, s * r2
    pts = u[:, None] * a[tri] + (s * (1 - r2))[:, None] * b[tri] + w[:, None] * c[tri]
    return pts, cross[tri] / area[tri, None]


def resolve_input(name, data, cache):
    """Returns dict(name, path, points, gt, source) or raises ValueError."""
    if data:
        path = os.path.join(data, "points", name + ".ply")
        if os.path.exists(path):
            meta = {}
            if os.path.exists(path[:-4] + ".json"):
                with open(path[:-4] + ".json") as f:
                    meta = json.load(f)
            gt = None
            if meta.get("ground_truth"):
                gt = dict(kind="mesh", path=os.path.join(data, meta["ground_truth"]), about=meta["ground_truth"])
            elif meta.get("shape") == "sphere":
                c, r = meta["center"], meta["radius"]
                gt = dict(kind="sphere", spec=f"{c[0]},{c[1]},{c[2]},{r}", about="analytic sphere (exact)")
            elif meta.get("shape") and os.path.exists(os.path.join(data, "gt", meta["shape"] + ".ply")):
                gt = dict(kind="mesh", path=os.path.join(data, "gt", meta["shape"] + ".ply"), about=f"gt/{meta['shape']}.ply")
            return dict(name=name, path=path, points=ply_vertex_count(path), gt=gt, source=f"shared data: points/{name}.ply")
    if name == "bunny_20k":
        return dict(
            name=name,
            path=os.path.join(ROOT, "examples", "bunny.ply"),
            points=ply_vertex_count(os.path.join(ROOT, "examples", "bunny.ply")),
            gt=dict(kind="mesh", path=os.path.join(ROOT, "crates", "spsr", "tests", "data", "bunny_gt.ply"), about="crates/spsr/tests/data/bunny_gt.ply"),
            source="repository: examples/bunny.ply",
        )
    m = re.fullmatch(r"([a-z_]+?)_(\d+(?:\.\d+)?[km]?)", name)
    if data and m and m.group(1) not in ("sphere", "torus") and parse_count(m.group(2)):
        gt_path = os.path.join(data, "gt", m.group(1) + ".ply")
        if os.path.exists(gt_path):
            count = parse_count(m.group(2))
            path = sample_gt(name, gt_path, count, cache)
            return dict(
                name=name,
                path=path,
                points=count,
                gt=dict(kind="mesh", path=gt_path, about=f"gt/{m.group(1)}.ply"),
                source=f"sampled by the harness from gt/{m.group(1)}.ply (area-uniform, triangle normals, fixed seed)",
            )
    m = re.fullmatch(r"(sphere|torus)_(\w+)", name)
    count = parse_count(m.group(2)) if m else None
    if m and count:
        path, gt = generate(name, m.group(1), count, cache)
        return dict(name=name, path=path, points=count, gt=gt, source=f"generated by the harness ({m.group(1)}, fixed seed)")
    raise ValueError(f"input {name!r}: not in {data or '(no shared data)'} and not a generated name (sphere_N, torus_N)")


# ---------------------------------------------------------------------------------------------
# Running and measuring


GNU_TIME = "/usr/bin/time"


def rss_kib(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid):
    """The processes started by any thread of `pid` (none once it is gone)."""
    out = []
    try:
        for t in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{t}/children") as f:
                out.extend(int(x) for x in f.read().split())
    except (OSError, ValueError):
        pass
    return out


def tree_rss_kib(pid):
    """Resident memory of a process and all its descendants, in KiB (0 for those gone)."""
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        total += rss_kib(p)
        todo.extend(children(p))
    return total


def measured(cmd, env, timeout, max_rss_mib, log_prefix):
    """Runs cmd in its own session; returns dict(code, wall_s, peak_rss_mib, user_s, sys_s,
    killed, stdout, stderr). A watchdog kills the session past `timeout` seconds or
    `max_rss_mib` resident.

    Peak memory: a child's ru_maxrss counts the memory of the process that forked it (Linux
    folds the pre-exec address space into it), so forking straight from this Python process
    would add the harness's own 20-150 MiB. The command is therefore started by GNU time
    (about 1 MiB), whose report of its child's ru_maxrss is the number we keep."""
    out_path, err_path, time_path = log_prefix + ".out", log_prefix + ".err", log_prefix + ".time"
    use_time = os.access(GNU_TIME, os.X_OK)
    full = [GNU_TIME, "-o", time_path, "-f", "%e %M %U %S", "--"] + cmd if use_time else cmd
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        start = time.perf_counter()
        proc = subprocess.Popen(full, stdout=out, stderr=err, env=env, start_new_session=True)
        done = threading.Event()
        killed = {}

        def watch():
            while not done.wait(0.2):
                why = None
                rss = sum(rss_kib(p) for p in [proc.pid] + children(proc.pid)) / 1024.0
                if time.perf_counter() - start > timeout:
                    why = f"time limit ({timeout:.0f} s)"
                elif rss > max_rss_mib:
                    why = f"memory limit ({max_rss_mib / 1024:.0f} GiB resident)"
                if why and not done.is_set():
                    killed["reason"] = why
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except OSError:
                        pass
                    return

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        done.set()
        proc.returncode = os.waitstatus_to_exitcode(status)
        watcher.join()
    with open(out_path, errors="replace") as f:
        stdout = f.read()
    with open(err_path, errors="replace") as f:
        stderr = f.read()
    res = dict(code=proc.returncode, wall_s=wall, killed=killed.get("reason"), stdout=stdout, stderr=stderr,
               peak_rss_mib=usage.ru_maxrss / 1024.0, user_s=usage.ru_utime, sys_s=usage.ru_stime,
               rss_method="ru_maxrss of the child (includes the harness's fork)")
    if use_time:
        report = open(time_path).read().splitlines() if os.path.exists(time_path) else []
        sig = next((int(l.split()[-1]) for l in report if l.startswith("Command terminated by signal")), None)
        if sig is not None and res["code"] >= 0:
            res["code"] = -sig
        try:
            _, maxrss, user, system = report[-1].split()
            res.update(peak_rss_mib=int(maxrss) / 1024.0, user_s=float(user), sys_s=float(system),
                       rss_method="GNU time (ru_maxrss of its child)")
        except (IndexError, ValueError):
            pass
    return res


def failure_reason(r, output):
    if r["killed"]:
        return r["killed"]
    if r["code"] < 0:
        sig = -r["code"]
        name = signal.Signals(sig).name if sig in signal.Signals._value2member_map_ else str(sig)
        hint = " (likely the kernel's out-of-memory killer)" if sig == signal.SIGKILL else ""
        return f"killed by {name}{hint}"
    if r["code"] != 0:
        lines = [l.strip() for l in r["stderr"].splitlines() if l.strip()]
        return f"exit {r['code']}: " + (lines[-1][:300] if lines else "no message")
    if not os.path.exists(output) or os.path.getsize(output) == 0:
        return "no output mesh"
    return None


def spsr_compute_seconds(stderr):
    times = dict(re.findall(r"^\s+(reading|writing|total)\s+([\d.]+) s\s*$", stderr, re.M))
    if "total" in times:
        return float(times["total"]) - float(times.get("reading", 0)) - float(times.get("writing", 0))
    return None


def spsr_profile(stderr):
    """spsr's own report under -v: octree nodes and each stage's seconds (the per-stage
    profile kept with every run)."""
    m = re.search(r"^octree\s+(\d+) nodes", stderr, re.M)
    stages = {k.strip(): float(v) for k, v in re.findall(r"^\s{2,}([a-z][\w :-]*?)\s{2,}([\d.]+) s", stderr, re.M)}
    return dict(octree_nodes=int(m.group(1)) if m else None, stages=stages)


def command(tool, inp, out, depth, args, py):
    p = params(args, depth)
    if tool == "spsr":
        return [
            os.path.join(ROOT, "target", "release", "spsr"), "reconstruct", inp, "-o", out,
            "--depth", str(depth), "--degree", str(args.degree), "--point-weight", str(p["point_weight"]),
            "--samples-per-node", str(args.samples_per_node), "--boundary", args.boundary,
            "--full-depth", str(p["full_depth"]), "--scale", str(args.scale),
            "--threads", str(args.threads),
        ] + ([] if args.no_profile else ["-v"]) + (["--iters", str(args.iters)] if args.iters is not None else [])
    if tool == "poisson_reconstruction":
        return [RUNNER, inp, out, str(depth), str(p["point_weight"]), str(args.threads), str(max(depth - 2, 0)), "10"]
    return [py, PY_PEERS, tool, inp, out, json.dumps(p)]


def params(args, depth):
    return dict(
        depth=depth,
        degree=args.degree,
        point_weight=args.point_weight if args.point_weight is not None else 2.0 * args.degree,
        samples_per_node=args.samples_per_node,
        full_depth=min(args.full_depth, depth) if isinstance(depth, int) else args.full_depth,
        scale=args.scale,
        # The peers' sweeps per depth: as given, else PoissonRecon's 8 (spsr is then left at its
        # own default: two cycles of 4 sweeps at degree 1, one cascade of 8 at degree 2).
        iters=args.iters if args.iters is not None else 8,
        threads=args.threads,
        boundary=args.boundary,
    )


def static_params(tool, args):
    """What each tool is given and what it cannot match (the Python peers also report what they
    were given at run time; see the runs' `given`)."""
    p = params(args, "D")
    if tool == "spsr":
        if args.iters is None:
            p = dict(p, iters="default (two cycles of 4 sweeps at degree 1, one of 8 at degree 2)")
        return dict(given=p, cannot_match={})
    if tool == "pypoisson2":
        return dict(given=p, cannot_match={})
    if tool == "open3d":
        return dict(
            given=dict(depth="D", scale=p["scale"], full_depth=p["full_depth"], samples_per_node=p["samples_per_node"], point_weight=p["point_weight"], n_threads=p["threads"], linear_fit=False),
            cannot_match=dict(iters="8 Gauss-Seidel iterations (fixed; same as ours by default)", degree="1 (fixed; same as ours by default)", boundary="neumann (fixed)", precision="float32 (PoissonRecon 18.74 and spsr solve in double)"),
        )
    if tool == "pymeshlab":
        return dict(
            given=dict(depth="D", fulldepth=p["full_depth"], scale=p["scale"], samplespernode=p["samples_per_node"], pointweight=p["point_weight"], iters=p["iters"], threads=p["threads"], cgdepth=0),
            cannot_match=dict(degree="2 (fixed by MeshLab's plugin; ours: %d)" % args.degree, boundary="neumann (fixed)", version="MeshLab bundles an older PoissonRecon (version 9 era)"),
        )
    return dict(
        given=dict(max_depth="D", screening=p["point_weight"], density_estimation_depth="D-2", max_relaxation_iters=10, threads=p["threads"]),
        cannot_match=dict(
            degree="2 (triquadratic B-splines, fixed)",
            samples_per_node="no equivalent: one density-estimation depth (D-2, as PoissonRecon's kernel depth) and depth from density",
            boundary="none: the grid is the points' box widened by one finest cell (no bounding-cube scale)",
            full_depth="no equivalent (sparse layers from the root down)",
            solver="conjugate gradients per level, at most 10 iterations (the crate's recommendation), not Gauss-Seidel",
            extraction="plain marching cubes on the finest cells",
        ),
    )


def score(mesh, gt, args):
    spsr = os.path.join(ROOT, "target", "release", "spsr")
    cmd = [spsr, "eval", mesh, "--json", "--samples", str(args.samples), "--threads", str(args.threads)]
    cmd += ["--reference-sphere", gt["spec"]] if gt["kind"] == "sphere" else ["--reference", gt["path"]]
    start = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["spsr eval failed"])[-1][:300]}
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["eval_seconds"] = time.perf_counter() - start
    return result


# ---------------------------------------------------------------------------------------------
# Environment and versions


def thumbnail(mesh, png, args):
    """A small picture of a scored mesh (`spsr render`, iso view, loose pieces in magenta);
    None when it cannot be drawn, which does not stop the run."""
    spsr = os.path.join(ROOT, "target", "release", "spsr")
    os.makedirs(os.path.dirname(png), exist_ok=True)
    cmd = [spsr, "render", mesh, "-o", png, "--size", "192x192", "--highlight", "pieces", "--threads", str(args.threads)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired) as e:
        print(f"bench: no thumbnail of {os.path.basename(png)}: {e}", flush=True)
        return None
    if out.returncode != 0 or not os.path.exists(png):
        print(f"bench: no thumbnail of {os.path.basename(png)}: {(out.stderr.strip().splitlines() or ['?'])[-1][:200]}", flush=True)
        return None
    return png


def thumbnail_lines(res, path):
    """The thumbnails section of the report: one row per case, one column per tool; empty
    when no thumbnail exists next to the report."""
    here = os.path.dirname(path)
    shown = {(r["input"], r["depth"], r["tool"]): r["thumbnail"] for r in res["rows"]
             if r.get("thumbnail") and os.path.exists(os.path.join(here, r["thumbnail"]))}
    if not shown:
        return []
    tools = [t for t in TOOLS if any(k[2] == t for k in shown)]
    cases = sorted({(k[0], k[1]) for k in shown}, key=lambda c: (res["inputs"][c[0]]["points"] or 0, c[0], c[1]))
    lines = ["", "## Thumbnails", "",
             "Each tool's mesh of the first repetition, drawn by `spsr render` (iso view; faces seen from behind in "
             "terracotta, every piece but the largest in magenta).", "",
             "| input | D | " + " | ".join(LABELS[t] for t in tools) + " |",
             "|---|---|" + "---|" * len(tools)]
    for n, d in cases:
        cells = [f"![{t} {n} D{d}]({shown[(n, d, t)]})" if (n, d, t) in shown else "—" for t in tools]
        lines.append(f"| {n} | {d} | " + " | ".join(cells) + " |")
    return lines


def sh(cmd, cwd=ROOT):
    try:
        return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd).stdout.strip()
    except OSError:
        return ""


def machine():
    info = dict(arch=platform.machine(), cores=os.cpu_count(), os=platform.platform(), python=platform.python_version())
    try:
        with open("/proc/cpuinfo") as f:
            info["cpu"] = next((l.split(":", 1)[1].strip() for l in f if l.startswith("model name")), "")
        with open("/proc/meminfo") as f:
            mem = {l.split(":")[0]: int(l.split()[1]) for l in f}
        info["memory_gib"] = round(mem["MemTotal"] / 2**20, 1)
        info["memory_available_gib_at_start"] = round(mem.get("MemAvailable", 0) / 2**20, 1)
    except (OSError, StopIteration, KeyError, ValueError):
        pass
    info["load_average_at_start"] = os.getloadavg()
    info["rustc"] = sh(["rustc", "--version"])
    return info


def peer_versions(py):
    """Imports each Python peer in the venv; returns {tool: version or None}, {tool: error}."""
    code = r"""
import importlib, importlib.metadata as md, json
mods = {"pypoisson2": ("poisson", "pypoisson2"), "open3d": ("open3d", "open3d"), "pymeshlab": ("pymeshlab", "pymeshlab"),
        "numpy": ("numpy", "numpy"), "matplotlib": ("matplotlib", "matplotlib")}
out = {}
for tool, (mod, dist) in mods.items():
    try:
        importlib.import_module(mod)
        out[tool] = {"version": md.version(dist)}
    except Exception as e:
        out[tool] = {"error": (type(e).__name__ + ": " + str(e)).splitlines()[0][:300]}
print(json.dumps(out))
"""
    try:
        res = subprocess.run([py, "-c", code], capture_output=True, text=True, timeout=300)
        return json.loads(res.stdout.strip().splitlines()[-1])
    except Exception as e:  # no venv, broken interpreter, ...
        return {t: {"error": f"Python environment unusable: {e}"} for t in PY_MODULES}


def install_log_reason(venv, module):
    path = os.path.join(venv, "spsr-bench-install.log")
    if os.path.exists(path):
        with open(path) as f:
            for line in f:
                if line.startswith(module + ":"):
                    return line.strip()
    return None


def crate_version():
    lock = os.path.join(RUNNER_DIR, "Cargo.lock")
    if os.path.exists(lock):
        text = open(lock).read()
        m = re.search(r'name = "poisson_reconstruction"\nversion = "([^"]+)"', text)
        if m:
            return m.group(1)
    return None


# ---------------------------------------------------------------------------------------------
# Main loop


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.environ.get("SPSR_BENCH_DATA", os.path.join(ROOT, "..", "shared", "data")),
                    help="shared data folder (default ../shared/data or $SPSR_BENCH_DATA); without points/ in it, generated inputs are used")
    ap.add_argument("--inputs", nargs="+", help="inputs of the main grid (names in DATA/points, or sphere_N / torus_N)")
    ap.add_argument("--depths", nargs="+", type=int, help="depths of the main grid")
    ap.add_argument("--scaling", nargs="*", help="extra inputs of the point-count plot, run at --scaling-depth only")
    ap.add_argument("--scaling-depth", type=int, default=9)
    ap.add_argument("--cases", nargs="*", help="extra NAME:DEPTH cases [default: sphere_10k:5 unless --inputs is given]")
    ap.add_argument("--tools", nargs="+", default=TOOLS, choices=TOOLS)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--point-weight", type=float, default=None, help="screening weight alpha [default: 2 x degree]")
    ap.add_argument("--samples-per-node", type=float, default=1.5)
    ap.add_argument("--full-depth", type=int, default=5)
    ap.add_argument("--scale", type=float, default=1.1)
    ap.add_argument("--no-profile", action="store_true",
                    help="run spsr without -v: no per-stage profile and no compute time")
    ap.add_argument("--iters", type=int, default=None,
                    help="Gauss-Seidel sweeps per depth for every tool (default: each tool's own; "
                         "PoissonRecon's 8 for the peers)")
    ap.add_argument("--boundary", default="neumann", choices=["neumann", "dirichlet", "free"])
    ap.add_argument("--samples", type=int, default=1_000_000, help="spsr eval samples per surface")
    ap.add_argument("--timeout", type=float, default=900, help="per-run time limit in seconds")
    ap.add_argument("--max-rss-gib", type=float, default=16, help="per-run resident memory limit")
    ap.add_argument("--slow", type=float, default=300, help="a case whose first run takes longer than this many seconds is not repeated")
    ap.add_argument("--omp-wait-policy", default="PASSIVE", help="OMP_WAIT_POLICY for every run; 'unset' leaves the OpenMP default "
                    "(busy-waiting threads, which on a machine shared with other jobs made the OpenMP peers up to 10x slower)")
    ap.add_argument("--venv", default=os.environ.get("SPSR_BENCH_VENV", os.path.expanduser("~/.cache/spsr-bench-venv")))
    ap.add_argument("--out", default=os.path.join(BENCH, "results"))
    ap.add_argument("--name", default=None, help="results name [default: bench-DATE-TIME]")
    ap.add_argument("--keep-meshes", action="store_true")
    ap.add_argument("--no-thumbnails", action="store_true", help="do not draw a thumbnail of each scored mesh")
    ap.add_argument("--no-build", action="store_true", help="use the binaries as they are")
    ap.add_argument("--plot-only", metavar="RESULTS_JSON", help="redraw the table and plots of an earlier run")
    args = ap.parse_args()

    if args.plot_only:
        with open(args.plot_only) as f:
            res = json.load(f)
        stem = args.plot_only[:-5] if args.plot_only.endswith(".json") else args.plot_only
        for p in plots(res, stem):
            print("wrote", p)
        write_markdown(res, stem + ".md")
        return 0

    shared = os.path.isdir(os.path.join(args.data, "points"))
    defaults = SHARED_DEFAULT if shared else FALLBACK_DEFAULT
    if not shared:
        print(f"bench: no shared data at {args.data}; using generated inputs and the repository's bunny", flush=True)
    inputs = args.inputs or defaults["inputs"]
    depths = args.depths or defaults["depths"]
    scaling = defaults["scaling"] if args.scaling is None else args.scaling
    if args.inputs and args.scaling is None:
        scaling = []
    extra = args.cases if args.cases is not None else ([] if args.inputs else defaults["cases"])
    py = os.path.join(args.venv, "bin", "python")
    if not os.path.exists(py):
        print(f"bench: no Python environment at {args.venv} (run bench/setup_venv.sh); the Python peers will be recorded as failed", flush=True)
        py = sys.executable
    cache = os.path.join(os.path.expanduser("~/.cache"), "spsr-bench-inputs")
    work = tempfile.mkdtemp(prefix="spsr-bench-")

    # Tools: build, check, record why one is unavailable.
    unavailable = {}
    versions = {}
    if not args.no_build:
        b = subprocess.run(["cargo", "build", "--release", "-q", "-p", "spsr-cli"], cwd=ROOT)
        if b.returncode != 0:
            sys.exit("bench: cannot build spsr")
    versions["spsr"] = sh([os.path.join(ROOT, "target", "release", "spsr"), "--version"]) + " (git " + sh(["git", "describe", "--always", "--dirty"]) + ")"
    if "poisson_reconstruction" in args.tools:
        if not args.no_build:
            b = subprocess.run(["cargo", "build", "--release", "-q", "--locked"], cwd=RUNNER_DIR, capture_output=True, text=True)
            if b.returncode != 0:
                unavailable["poisson_reconstruction"] = "build failed: " + (b.stderr.strip().splitlines() or ["?"])[-1][:300]
        if "poisson_reconstruction" not in unavailable and not os.path.exists(RUNNER):
            unavailable["poisson_reconstruction"] = "runner not built"
        versions["poisson_reconstruction"] = crate_version()
    pv = peer_versions(py)
    for tool, module in PY_MODULES.items():
        info = pv.get(tool, {})
        versions[tool] = info.get("version")
        if tool in args.tools and "error" in info:
            unavailable[tool] = "not installed: " + (install_log_reason(args.venv, module) or info["error"])
    for tool in ("pypoisson2", "open3d", "pymeshlab"):
        if versions.get(tool):
            versions[tool] = f"{tool} {versions[tool]}"
    if versions.get("pypoisson2"):
        versions["pypoisson2"] += " (PoissonRecon 18.74)"
    if versions.get("poisson_reconstruction"):
        versions["poisson_reconstruction"] = "crate " + versions["poisson_reconstruction"]
    for lib in ("numpy", "matplotlib"):
        versions[lib] = pv.get(lib, {}).get("version")

    # Cases: main grid, point-count family, extras; smallest first so that the skip rules see
    # the cheap cases before the expensive ones.
    cases = [(n, d) for n in inputs for d in depths]
    cases += [(n, args.scaling_depth) for n in scaling if (n, args.scaling_depth) not in cases]
    for c in extra:
        n, d = c.rsplit(":", 1)
        if (n, int(d)) not in cases:
            cases.append((n, int(d)))
    resolved = {}
    for n in dict.fromkeys(n for n, _ in cases):
        try:
            resolved[n] = resolve_input(n, args.data if shared else None, cache)
        except ValueError as e:
            print("bench:", e, flush=True)
    cases = sorted((c for c in cases if c[0] in resolved), key=lambda c: (resolved[c[0]]["points"] or 0, c[1], c[0]))

    machine_info = machine()
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), RAYON_NUM_THREADS=str(args.threads), PYTHONDONTWRITEBYTECODE="1")
    env.pop("OMP_WAIT_POLICY", None)
    if args.omp_wait_policy.lower() != "unset":
        env["OMP_WAIT_POLICY"] = args.omp_wait_policy
    start_time = datetime.datetime.now()
    name = args.name or start_time.strftime("bench-%Y-%m-%d-%H%M")
    print(f"bench: {len(cases)} cases x {len(args.tools)} tools x {args.reps} repetitions; work dir {work}", flush=True)

    state = {(t, n, d): dict(runs=[], failed=None, score=None, given=None, fixed=None, thumbnail=None) for t in args.tools for n, d in cases}
    thumbs = os.path.join(args.out, name + "-thumbs")

    def skip_reason(tool, n, d):
        pts = resolved[n]["points"] or 0
        for (t2, n2, d2), s in state.items():
            if t2 != tool or not s["failed"] or (n2, d2) == (n, d):
                continue
            limit = s["failed"].startswith(("time limit", "memory limit", "killed"))
            if limit and d2 <= d and (resolved[n2]["points"] or 0) <= pts:
                return f"skipped: {s['failed']} on {n2} at depth {d2}"
        # A run that took over a minute on no more points at a lower depth predicts at least a
        # doubling per depth (fixed overheads make shorter runs poor predictors).
        for (t2, n2, d2), s in state.items():
            if t2 != tool or not s["runs"] or d2 >= d or (resolved[n2]["points"] or 0) > pts:
                continue
            w = statistics.median(r["wall_s"] for r in s["runs"])
            if w > 60 and w * 2 ** (d - d2) > args.timeout:
                return f"skipped: predicted over the time limit ({w:.0f} s on {n2} at depth {d2}; at least doubling per depth)"
        return None

    for rep in range(args.reps):
        order = list(args.tools) if rep % 2 == 0 else list(reversed(args.tools))
        for n, d in cases:
            inp = resolved[n]
            for tool in order:
                s = state[(tool, n, d)]
                if s["failed"]:
                    continue
                if tool in unavailable:
                    s["failed"] = unavailable[tool]
                    continue
                if rep > 0 and s["runs"] and s["runs"][0]["wall_s"] > args.slow:
                    continue
                if rep == 0:
                    why = skip_reason(tool, n, d)
                    if why:
                        s["failed"] = why
                        print(f"  {tool:24s} {n} d{d}: {why}", flush=True)
                        continue
                out = os.path.join(work, f"{tool}-{n}-{d}.ply")
                if os.path.exists(out):
                    os.remove(out)
                r = measured(command(tool, inp["path"], out, d, args, py), env, args.timeout, args.max_rss_gib * 1024, os.path.join(work, f"{tool}-{n}-{d}-{rep}"))
                why = failure_reason(r, out)
                if why:
                    s["failed"] = why
                    print(f"  {tool:24s} {n} d{d} rep {rep}: FAILED {why}", flush=True)
                    continue
                run = dict(rep=rep, wall_s=r["wall_s"], peak_rss_mib=r["peak_rss_mib"], user_s=r["user_s"], sys_s=r["sys_s"], rss_method=r["rss_method"])
                if tool == "spsr":
                    run["compute_s"] = spsr_compute_seconds(r["stderr"])
                    run.update(spsr_profile(r["stderr"]))
                elif tool == "poisson_reconstruction":
                    m = re.search(r"compute_seconds ([\d.]+)", r["stderr"])
                    run["compute_s"] = float(m.group(1)) if m else None
                else:
                    line = next((l for l in r["stdout"].splitlines() if l.startswith("BENCH ")), None)
                    if line:
                        info = json.loads(line[6:])
                        run["compute_s"] = info["compute_seconds"]
                        s["given"], s["fixed"] = info["given"], info["fixed"]
                s["runs"].append(run)
                print(f"  {tool:24s} {n} d{d} rep {rep}: {r['wall_s']:7.2f} s {r['peak_rss_mib']:8.0f} MiB", flush=True)
                if s["score"] is None and inp["gt"]:
                    s["score"] = score(out, inp["gt"], args)
                    if not args.no_thumbnails:
                        s["thumbnail"] = thumbnail(out, os.path.join(thumbs, f"{tool}-{n}-d{d}.png"), args)
                if not args.keep_meshes:
                    os.remove(out)
    end_time = datetime.datetime.now()

    rows = []
    for (tool, n, d), s in state.items():
        row = dict(input=n, points=resolved[n]["points"], depth=d, tool=tool, label=LABELS[tool])
        if s["runs"]:
            walls = [r["wall_s"] for r in s["runs"]]
            rss = [r["peak_rss_mib"] for r in s["runs"]]
            comp = [r["compute_s"] for r in s["runs"] if r.get("compute_s") is not None]
            if s["runs"][0].get("octree_nodes"):
                row["octree_nodes"] = s["runs"][0]["octree_nodes"]
            row.update(reps=len(walls), wall_s=statistics.median(walls), wall_min_s=min(walls), wall_max_s=max(walls),
                       peak_rss_mib=statistics.median(rss), compute_s=statistics.median(comp) if comp else None)
            if s["score"]:
                row["score"] = s["score"]
            if s["thumbnail"]:
                row["thumbnail"] = os.path.relpath(s["thumbnail"], args.out)
            if s["failed"]:
                row["later_failure"] = s["failed"]
        else:
            row["failed"] = s["failed"] or "not run"
        if s["given"]:
            row["given"] = s["given"]
        if s["fixed"]:
            row["fixed"] = s["fixed"]
        row["runs"] = s["runs"]
        rows.append(row)

    os.makedirs(args.out, exist_ok=True)
    res = dict(
        name=name,
        started=start_time.isoformat(timespec="seconds"),
        finished=end_time.isoformat(timespec="seconds"),
        machine=dict(machine_info, load_average_at_end=os.getloadavg()),
        versions=versions,
        command=" ".join(["bash bench/run.sh"] + sys.argv[1:]),
        data="shared" if shared else "generated (no shared data found at %s)" % args.data,
        inputs={n: {k: v for k, v in r.items() if k != "path"} | dict(path=os.path.relpath(r["path"], ROOT) if r["path"].startswith(ROOT) else r["path"]) for n, r in resolved.items()},
        parameters=dict(params(args, "D"), reps=args.reps, timeout_s=args.timeout, max_rss_gib=args.max_rss_gib,
                        slow_s=args.slow, eval_samples=args.samples, scaling_depth=args.scaling_depth,
                        peak_rss_method="GNU time (ru_maxrss of its child)" if os.access(GNU_TIME, os.X_OK) else "ru_maxrss from wait4 (includes the harness's fork)",
                        environment=dict(OMP_NUM_THREADS=args.threads, RAYON_NUM_THREADS=args.threads, OMP_WAIT_POLICY=args.omp_wait_policy)),
        tools={t: dict(label=LABELS[t], version=versions.get(t), **static_params(t, args)) | ({"unavailable": unavailable[t]} if t in unavailable else {}) for t in args.tools},
        rows=rows,
    )
    stem = os.path.join(args.out, name)
    with open(stem + ".json", "w") as f:
        json.dump(res, f, indent=1)
    written = [stem + ".json", stem + ".md"]
    try:
        written += plots(res, stem)
    except ImportError as e:
        print(f"bench: no plots ({e})", flush=True)
    write_markdown(res, stem + ".md")
    shutil.rmtree(work, ignore_errors=True)
    print("\n".join("wrote " + p for p in written))
    with open(stem + ".md") as f:
        print(f.read())
    return 0


# ---------------------------------------------------------------------------------------------
# Reporting


def fmt_num(x, digits=3):
    return "—" if x is None else f"{x:.{digits}g}"


def fmt_e(x):
    return "—" if x is None else f"{x:.2e}"


def topo(sc):
    if not sc or "closed" not in sc:
        return "—"
    manifold = sc["edge_manifold"] and sc["vertex_manifold"]
    return ("closed" if sc["closed"] else f"open ({sc.get('boundary_edges', '?')} b.e.)") + (", manifold" if manifold else ", non-manifold")


def write_markdown(res, path):
    m = res["machine"]
    p = res["parameters"]
    v = res["versions"]
    lines = [
        f"# Benchmark {res['name']}",
        "",
        f"- Date: {res['started']} to {res['finished']}",
        f"- Machine: {m.get('cpu', '?')}, {m['cores']} cores, {m.get('memory_gib', '?')} GiB; {m['os']}; load average "
        f"{' / '.join(f'{x:.2f}' for x in m['load_average_at_start'])} at start, {' / '.join(f'{x:.2f}' for x in m['load_average_at_end'])} at end "
        "(other jobs may have shared the machine)" + (f"; note: {m['note']}" if m.get("note") else ""),
        f"- Command: `{res['command']}`",
        f"- Inputs: {res['data']}; " + "; ".join(f"{n}: {i['points']:,} points, {i['source']}, ground truth {i['gt']['about'] if i['gt'] else 'none'}" for n, i in res["inputs"].items()),
        f"- Parameters: depth D as listed, degree {p['degree']}, point weight (alpha) {p['point_weight']:g}, samples per node {p['samples_per_node']:g}, "
        f"{p['boundary']} boundary, scale {p['scale']:g}, full depth min({p['full_depth']}, D), {p['iters']} Gauss-Seidel sweeps per depth for the peers (spsr: {'the same' if '--iters' in res['command'] else 'its default solver cycles'}), {p['threads']} threads "
        f"(environment: {', '.join(f'{k}={v}' for k, v in p.get('environment', {}).items())}); "
        f"median of up to {p['reps']} repetitions (a case whose first run took over {p['slow_s']:g} s ran once), "
        f"time limit {p['timeout_s']:g} s and memory limit {p['max_rss_gib']:g} GiB per run",
        "- Versions: " + "; ".join(f"{LABELS.get(t, t)}: {res['versions'].get(t) or 'n/a'}" for t in res["tools"]) + f"; numpy {v.get('numpy')}, matplotlib {v.get('matplotlib')}; {m.get('rustc', '')}",
        f"- Scoring: `spsr eval` with {p['eval_samples']:,} area-uniform samples per surface (fixed seed); distances relative to the ground truth's bounding-box diagonal; "
        "Chamfer = mean of the two directions' mean distances, Hausdorff = largest sampled distance, F-score at 0.5 % and 1 % of the diagonal",
        "",
        "Time: wall time of the whole process (reading the input and writing the mesh included), median, with the range over repetitions; "
        "compute: the tool's own reconstruction time without file I/O. Peak RSS: the process's maximum resident memory "
        "(for the Python peers this includes the interpreter, NumPy and the peer's module, about 30-150 MiB). ",
        "",
        "| input | D | tool | time (s) | range (s) | compute (s) | peak RSS (MiB) | Chamfer (rel.) | Hausdorff (rel.) | F@0.5% | F@1% | normal cons. | vertices | topology |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = sorted(res["rows"], key=lambda r: (r["points"] or 0, r["input"], r["depth"], TOOLS.index(r["tool"])))
    for r in rows:
        head = f"| {r['input']} | {r['depth']} | {r['label']} |"
        if "failed" in r:
            why = r["failed"] if r["failed"].startswith("skipped") else "failed: " + r["failed"]
            lines.append(head + f" {why} | | | | | | | | | | |")
            continue
        sc = r.get("score") or {}
        if "error" in sc:
            acc = f" scoring failed: {sc['error']} | | | | | | |"
        else:
            acc = (f" {fmt_e(sc.get('chamfer_rel'))} | {fmt_e(sc.get('hausdorff_rel'))} | {fmt_num(sc.get('fscore_0_5'), 4)} | {fmt_num(sc.get('fscore_1'), 4)} | "
                   f"{fmt_num(sc.get('normal_consistency'), 4)} | {sc.get('vertices', 0):,} | {topo(sc)} |")
        rng = f"{r['wall_min_s']:.2f}–{r['wall_max_s']:.2f}" if r["reps"] > 1 else f"({r['reps']} run)"
        lines.append(head + f" {r['wall_s']:.2f} | {rng} | {fmt_num(r.get('compute_s'))} | {r['peak_rss_mib']:.0f} |" + acc)
    lines += ["", "## What each tool was given", ""]
    for t, info in res["tools"].items():
        given = dict(info["given"])
        got = [r for r in res["rows"] if r["tool"] == t and r.get("given")]
        if got:
            # What the runner reported, from the deepest case, with the depth written as D.
            deepest = max(got, key=lambda r: r["depth"])
            given = {k: ("D" if k == "depth" else v) for k, v in deepest["given"].items()}
        fixed = next((r.get("fixed") for r in res["rows"] if r["tool"] == t and r.get("fixed")), None)
        cm = dict(info.get("cannot_match") or {})
        if fixed:
            cm.update({k: str(v) + (" (reported by the runner)" if k not in cm else "") for k, v in fixed.items() if k not in cm})
        lines.append(f"- **{info['label']}** ({info.get('version') or 'version unknown'}): " + ", ".join(f"{k}={v}" for k, v in given.items())
                     + (("; cannot match: " + "; ".join(f"{k}: {v}" for k, v in cm.items())) if cm else "; matches every parameter")
                     + (f"; UNAVAILABLE: {info['unavailable']}" if info.get("unavailable") else ""))
    failures = [r for r in rows if "failed" in r]
    if failures:
        lines += ["", "## Failures", ""]
        lines += [f"- {r['label']} on {r['input']} at depth {r['depth']}: {r['failed']}" for r in failures]
    pngs = [os.path.basename(path)[:-3] + s for s in ("-points.png", "-depth.png", "-accuracy.png")]
    lines += ["", "## Plots", ""] + [f"![{x}]({x})" for x in pngs if os.path.exists(os.path.join(os.path.dirname(path), x))]
    lines += thumbnail_lines(res, path)
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


STYLE = {
    "spsr": dict(color="#d62728", marker="o"),
    "pypoisson2": dict(color="#1f77b4", marker="s"),
    "open3d": dict(color="#2ca02c", marker="^"),
    "pymeshlab": dict(color="#9467bd", marker="D"),
    "poisson_reconstruction": dict(color="#8c564b", marker="v"),
}


def plots(res, stem):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    def subs(axis):
        lo, hi = axis.get_view_interval()
        narrow = lo > 0 and hi / lo < 30
        return (1.0, 1.5, 2.0, 3.0, 5.0, 7.0) if narrow else (1.0, 2.0, 5.0)

    def log_axis(axis):
        # Log scale labelled 1, 2, 5, 10, 20, ... (more in a narrow range) in plain numbers.
        axis.set_major_locator(LogLocator(base=10, subs=subs(axis)))
        axis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:,.0f}" if x >= 10 else f"{x:g}"))
        axis.set_minor_formatter(NullFormatter())

    def sci_axis(axis):
        axis.set_major_locator(LogLocator(base=10, subs=subs(axis)))
        def sci(x, _):
            mantissa, exponent = f"{x:.2e}".split("e")
            return f"{mantissa.rstrip('0').rstrip('.')}e{int(exponent)}"

        axis.set_major_formatter(FuncFormatter(sci))
        axis.set_minor_formatter(NullFormatter())

    ok = [r for r in res["rows"] if "wall_s" in r]
    tools = [t for t in TOOLS if t in res["tools"]]
    title_tail = f"{res['machine']['cores']} cores, {res['parameters']['threads']} threads, {res['name']}"
    written = []

    # 1. Time and memory against point count, at the scaling depth, for each input family
    #    (name prefix before the size) with at least two sizes.
    sd = res["parameters"]["scaling_depth"]
    fams = {}
    for r in ok:
        if r["depth"] == sd:
            fams.setdefault(r["input"].rsplit("_", 1)[0], set()).add(r["input"])
    fams = {k: v for k, v in fams.items() if len(v) >= 2}
    if fams:
        fam = max(fams, key=lambda k: len(fams[k]))
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.3))
        for ax, key, ylabel in ((axes[0], "wall_s", "wall time (s)"), (axes[1], "peak_rss_mib", "peak resident memory (MiB)")):
            for t in tools:
                pts = sorted((r["points"], r[key]) for r in ok if r["tool"] == t and r["depth"] == sd and r["input"] in fams[fam])
                if pts:
                    ax.plot(*zip(*pts), label=LABELS[t], **STYLE[t])
            ax.set_xscale("log")
            ax.set_yscale("log")
            log_axis(ax.xaxis)
            log_axis(ax.yaxis)
            ax.set_xlabel("input points")
            ax.set_ylabel(ylabel)
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=8)
        fig.suptitle(f"{fam} family at depth {sd}: time and memory against point count\n({title_tail})", fontsize=10)
        fig.tight_layout()
        written.append(stem + "-points.png")
        fig.savefig(written[-1], dpi=110)
        plt.close(fig)

    # 2. Time and memory against depth, one column per input with several depths.
    by_input = {}
    for r in ok:
        by_input.setdefault(r["input"], set()).add(r["depth"])
    grid_inputs = sorted((n for n, ds in by_input.items() if len(ds) >= 2), key=lambda n: res["inputs"][n]["points"] or 0)
    if grid_inputs:
        fig, axes = plt.subplots(2, len(grid_inputs), figsize=(max(4.2 * len(grid_inputs), 6), 7.5), squeeze=False)
        for j, n in enumerate(grid_inputs):
            for i, (key, ylabel) in enumerate((("wall_s", "wall time (s)"), ("peak_rss_mib", "peak resident memory (MiB)"))):
                ax = axes[i][j]
                for t in tools:
                    pts = sorted((r["depth"], r[key]) for r in ok if r["tool"] == t and r["input"] == n)
                    if pts:
                        ax.plot(*zip(*pts), label=LABELS[t], **STYLE[t])
                ax.set_yscale("log")
                log_axis(ax.yaxis)
                ax.set_xticks(sorted(by_input[n]))
                ax.set_xlabel("depth")
                ax.set_ylabel(ylabel)
                ax.grid(True, which="both", alpha=0.3)
                if i == 0:
                    ax.set_title(f"{n} ({res['inputs'][n]['points']:,} points)", fontsize=10)
        axes[0][0].legend(fontsize=8)
        fig.suptitle(f"Time and memory against depth\n({title_tail})", fontsize=10)
        fig.tight_layout()
        written.append(stem + "-depth.png")
        fig.savefig(written[-1], dpi=110)
        plt.close(fig)

    # 3. Accuracy against time: relative Chamfer distance, one panel per input, depths labelled.
    scored = [r for r in ok if r.get("score") and "chamfer_rel" in r["score"]]
    # The inputs of the depth grid first, then the single-depth ones; three panels a row.
    acc_inputs = sorted({r["input"] for r in scored}, key=lambda n: (n not in grid_inputs, res["inputs"][n]["points"] or 0))
    if acc_inputs:
        cols = min(3, len(acc_inputs))
        nrows = (len(acc_inputs) + cols - 1) // cols
        fig, axes = plt.subplots(nrows, cols, figsize=(max(4.8 * cols, 6), 4.3 * nrows + 0.6), squeeze=False)
        for ax in axes.flat[len(acc_inputs):]:
            ax.set_visible(False)
        for j, n in enumerate(acc_inputs):
            ax = axes.flat[j]
            for t in tools:
                pts = sorted((r["depth"], r["wall_s"], r["score"]["chamfer_rel"]) for r in scored if r["tool"] == t and r["input"] == n)
                if not pts:
                    continue
                ax.plot([p[1] for p in pts], [p[2] for p in pts], label=LABELS[t], **STYLE[t])
                for d, x, y in pts:
                    ax.annotate(str(d), (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7, color=STYLE[t]["color"])
            ax.set_xscale("log")
            ax.set_yscale("log")
            log_axis(ax.xaxis)
            sci_axis(ax.yaxis)
            ax.set_xlabel("wall time (s)")
            ax.set_ylabel("Chamfer distance / bbox diagonal")
            ax.set_title(f"{n} ({res['inputs'][n]['points']:,} points)", fontsize=10)
            ax.grid(True, which="both", alpha=0.3)
        handles = {h.get_label(): h for ax in axes.flat for h in ax.get_lines()}
        axes[0][0].legend(handles.values(), handles.keys(), fontsize=8)
        fig.suptitle(f"Accuracy against time (labels: depth; lower left is better)\n({title_tail})", fontsize=10)
        fig.tight_layout()
        written.append(stem + "-accuracy.png")
        fig.savefig(written[-1], dpi=110)
        plt.close(fig)
    return written


if __name__ == "__main__":
    sys.exit(main())
