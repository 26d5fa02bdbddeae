#!/usr/bin/env python3
"""Issue 16, a lead not yet built: does the local shape stay a quadratic at scales coarser than the
one the noise is measured at? On a smooth shape it does, and the noise adaptation could smooth
further than its cap (bench/results/issue16-unseen.md: the noisy sphere ramp wants S = 20); near
ears, horns and thin parts it does not, and the cap protects them.

For 200 samples of the noisiest 30 % of a ramp cloud (t > 0.7 along its ramp axis), fits a quadratic
height field over the PCA plane of all points within r of the sample, for r = 2, 4 and 8 % of the
diagonal, and prints the median and 90th percentile of the residual's standard deviation relative
to the diagonal, beside the noise the ramp put there.

    ~/.cache/spsr-bench-venv/bin/python bench/noise/scale_residual.py sphere_200k_noiseramp spot_100k_noiseramp
"""
import os
import sys

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from run import ROOT, read_ply, source  # noqa: E402

AXES = {"_noiseramp_x": 0, "_noiseramp_z": 2, "_noiseramp": 1}


def residual(p, centre, tree, r):
    """The standard deviation of the points within r of centre about their quadratic height field."""
    q = p[tree.query_ball_point(centre, r)]
    x = q - q.mean(0)
    _, v = np.linalg.eigh(x.T @ x)
    u, w, h = x @ v[:, 1], x @ v[:, 2], x @ v[:, 0]
    a = np.stack([np.ones_like(u), u, w, u * u, u * w, w * w], 1)
    coef = np.linalg.lstsq(a, h, rcond=None)[0]
    return np.sqrt(((a @ coef - h) ** 2).sum() / max(len(h) - 6, 1))


def main():
    data = os.path.join(ROOT, "..", "shared", "data")
    for name in sys.argv[1:]:
        cloud, _ = source(data, name)
        p, _ = read_ply(cloud)
        axis = next(a for k, a in AXES.items() if name.endswith(k))
        diag = float(np.linalg.norm(p.max(0) - p.min(0)))
        t = (p[:, axis] - p[:, axis].min()) / np.ptp(p[:, axis])
        pick = np.random.default_rng(0).choice(np.where(t > 0.7)[0], 200, replace=False)
        tree = cKDTree(p)
        print(f"{name}: noise put there {0.006 * t[pick].mean():.4f} of the diagonal (mean)")
        for r in (0.02, 0.04, 0.08):
            res = np.array([residual(p, p[i], tree, r * diag) for i in pick]) / diag
            print(f"  r = {r:.2f}: residual median {np.median(res):.4f}, 90th percentile {np.percentile(res, 90):.4f}")


if __name__ == "__main__":
    main()
