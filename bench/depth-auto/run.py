#!/usr/bin/env python3
"""Issue 18's check of `--depth auto`: on every shared point set with a ground truth, the Chamfer
distance to the truth (spsr eval, relative to the truth's bounding-box diagonal) at each fixed
depth, the depth that minimises it, and the depth `--depth auto` chooses.

    python3 bench/depth-auto/run.py [--inputs bunny_20k ...] [--samples 200000]
        [--name issue18-depth-auto] [--sweep-only]

Reads ../shared/data (points/*.ply, each .json naming its gt/ mesh). Each run is one
`spsr reconstruct` process with default settings but the depth; runs are cached in
bench/results/<name>.json, so a second call only runs what is missing (the auto runs after a
change to the choice: delete their entries). Standard library only.
"""
import argparse
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SPSR = os.environ.get("SPSR_BIN", os.path.join(ROOT, "target", "release", "spsr"))
DATA = os.path.normpath(os.path.join(ROOT, "..", "..", "shared", "data"))
if not os.path.isdir(DATA):
    DATA = "/work/shared/data"

# Depths swept per input size (a million points reaches deeper).
def depths_for(points):
    if points >= 1_000_000:
        return list(range(7, 13))
    if points >= 100_000:
        return list(range(6, 12))
    return list(range(5, 11))


def reconstruct(cloud, depth, out):
    cmd = [SPSR, "reconstruct", cloud, "-o", out, "--depth", str(depth), "--threads", "2"]
    t = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t
    if r.returncode:
        return {"error": r.stderr.strip()[-300:]}, wall
    return {"stderr": r.stderr}, wall


def evaluate(mesh, gt, samples):
    ref = ["--reference-sphere", gt] if gt.startswith("sphere:") else ["--reference", gt]
    ref = [r.replace("sphere:", "") for r in ref]
    r = subprocess.run([SPSR, "eval", mesh, "--json", "--samples", str(samples), *ref,
                        "--threads", "2"], capture_output=True, text=True)
    if r.returncode:
        return {"error": r.stderr.strip()[-300:]}
    j = json.loads(r.stdout.strip().splitlines()[-1])
    return {"chamfer": j["chamfer_rel"], "pieces": j["components"], "closed": j["closed"]}


def fine_torus(meta, n_major=1200, n_minor=420):
    """A torus of `meta`'s radii triangulated finely enough (chord error about 1e-5 of the
    radii, 0.003 × 10⁻³ of the diagonal) not to limit the scores, as binary PLY in a cache
    file: gt/torus.ply's facets are about as far from the true torus as the meshes it scores."""
    import math
    import struct
    big, small = meta["major_radius"], meta["minor_radius"]
    assert meta["center"] == [0, 0, 0] and meta["rotation_euler_xyz_deg"] == [0, 0, 0]
    path = os.path.join(tempfile.gettempdir(),
                        f"spsr-bench-torus-{big}-{small}-{n_major}x{n_minor}.ply")
    if os.path.exists(path):
        return path
    verts = bytearray()
    for i in range(n_major):
        u = 2 * math.pi * i / n_major
        for j in range(n_minor):
            v = 2 * math.pi * j / n_minor
            rho = big + small * math.cos(v)
            verts += struct.pack("<3f", rho * math.cos(u), rho * math.sin(u), small * math.sin(v))
    faces = bytearray()
    idx = lambda i, j: (i % n_major) * n_minor + (j % n_minor)
    for i in range(n_major):
        for j in range(n_minor):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            faces += struct.pack("<B3I", 3, a, b, c) + struct.pack("<B3I", 3, a, c, d)
    head = ("ply\nformat binary_little_endian 1.0\n"
            f"element vertex {n_major * n_minor}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {2 * n_major * n_minor}\n"
            "property list uchar int vertex_indices\nend_header\n")
    tmp = path + ".part"
    with open(tmp, "wb") as f:
        f.write(head.encode() + verts + faces)
    os.replace(tmp, path)
    return path


def run_case(cloud, gt, depth, samples):
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "mesh.ply")
        rec, wall = reconstruct(cloud, depth, out)
        if "error" in rec:
            return {"error": rec["error"], "wall_s": wall}
        res = evaluate(out, gt, samples)
        res["wall_s"] = round(wall, 2)
        if depth == "auto":
            m = re.search(r"note: (.*depth (\d+).*)", rec["stderr"])
            res["note"] = m.group(1) if m else None
            res["depth"] = int(m.group(2)) if m else None
        return res


def load_avg():
    try:
        return open("/proc/loadavg").read().split()[:3]
    except OSError:
        return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--inputs", nargs="*")
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--name", default="issue18-depth-auto")
    ap.add_argument("--sweep-only", action="store_true")
    a = ap.parse_args()
    path = os.path.join(ROOT, "bench", "results", a.name + ".json")
    db = json.load(open(path)) if os.path.exists(path) else {"cases": {}, "load": []}
    names = a.inputs or sorted(os.path.basename(p)[:-4]
                               for p in glob.glob(os.path.join(DATA, "points", "*.ply")))
    for name in names:
        meta = json.load(open(os.path.join(DATA, "points", name + ".json")))
        # The analytic sets name their shape; gt/ holds a fine triangulation of it.
        # gt/sphere.ply's facets are coarser than the meshes it would score, so the sphere is
        # scored against the exact surface.
        gt = os.path.join(DATA, meta.get("ground_truth") or "gt/%s.ply" % meta["shape"])
        if not os.path.exists(gt):
            # bunny_100k_noiseramp names its truth without the gt/ folder.
            gt = os.path.join(DATA, "gt", os.path.basename(gt))
        if meta.get("shape") == "sphere":
            gt = "sphere:" + ",".join(str(c) for c in meta["center"] + [meta["radius"]])
        if meta.get("shape") == "torus":
            gt = fine_torus(meta)
        cloud = os.path.join(DATA, "points", name + ".ply")
        case = db["cases"].setdefault(name, {"points": meta["points"], "depths": {}})
        todo = [str(d) for d in depths_for(meta["points"])]
        if not a.sweep_only:
            todo.append("auto")
        for d in todo:
            if d in case["depths"]:
                continue
            res = run_case(cloud, gt, d if d == "auto" else int(d), a.samples)
            case["depths"][d] = res
            db["load"].append(load_avg())
            print(name, d, res, file=sys.stderr, flush=True)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            json.dump(db, open(path, "w"), indent=1)
    write_table(db, os.path.join(ROOT, "bench", "results", a.name + ".md"))


def write_table(db, path):
    rows = []
    within = 0
    within_flat = 0
    total = 0
    for name, case in db["cases"].items():
        fixed = {int(d): r for d, r in case["depths"].items()
                 if d != "auto" and "chamfer" in r}
        if not fixed:
            continue
        best = min(fixed, key=lambda d: fixed[d]["chamfer"])
        cells = " | ".join(f"{fixed[d]['chamfer'] * 1e3:.3f}" if d in fixed else "" for d in range(5, 13))
        auto = case["depths"].get("auto", {})
        ad = auto.get("depth")
        ok = ad is not None and abs(ad - best) <= 1
        near = min(fixed[d]["chamfer"] for d in fixed) * 1.02
        flat = [d for d in sorted(fixed) if fixed[d]["chamfer"] <= near]
        if ad is not None:
            total += 1
            within += ok
            within_flat += any(abs(ad - d) <= 1 for d in flat)
        rows.append(f"| {name} | {case['points']} | {cells} | {best} | {flat[0]}–{flat[-1]} | "
                    f"{ad if ad is not None else ''} | {'yes' if ok else ('no' if ad is not None else '')} |")
    head = ("| input | points | " + " | ".join(f"D={d}" for d in range(5, 13))
            + " | best D | within 2 % | auto D | auto within 1 |\n|" + "---|" * 14 + "\n")
    loads = [l for l in db.get("load", []) if l]
    load = (f"Load average (1 min) during the runs: {min(float(l[0]) for l in loads):.2f}–"
            f"{max(float(l[0]) for l in loads):.2f} on 2 cores.\n" if loads else "")
    text = ("Chamfer distance to the ground truth (× 10⁻³ of its bounding-box diagonal, "
            "spsr eval, 200,000 samples a side; the spheres against the exact sphere, the torus "
            "against a fine triangulation of the exact torus) "
            "per depth at default settings; the best depth, "
            "the depths within 2 % of the best, and the depth `--depth auto` chose. "
            f"Auto within one depth of the best on {within} of {total} sets; within one depth "
            f"of a depth within 2 % of the best (where the curve is flat the best is decided by "
            f"the sampling of the score) on {within_flat} of {total}.\n\n"
            + head + "\n".join(rows) + "\n\n" + load)
    open(path, "w").write(text)


if __name__ == "__main__":
    main()
