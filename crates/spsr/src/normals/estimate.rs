//! Normal lines from local plane fits: principal component analysis of each point's k nearest
//! neighbours (Hoppe et al. 1992), with the neighbourhood size chosen from the noise.

use rayon::prelude::*;

use super::knn::Tree;

/// The symmetric 3×3 matrix `[xx, yy, zz, xy, xz, yz]`.
pub(crate) type Sym3 = [f64; 6];

/// Eigenvalues (ascending) and unit eigenvectors of a symmetric 3×3 matrix, by cyclic Jacobi
/// rotations. Robust for repeated and zero eigenvalues, which the closed-form solution is not.
pub(crate) fn eigen_sym3(m: &Sym3) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut a = [[m[0], m[3], m[4]], [m[3], m[1], m[5]], [m[4], m[5], m[2]]];
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..32 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let diag = a[0][0] * a[0][0] + a[1][1] * a[1][1] + a[2][2] * a[2][2];
        if off <= 1e-30 * diag || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            // Rotation that zeroes a[p][q] (Golub & Van Loan, symmetric Schur decomposition).
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[k][p], v[k][q]);
                v[k][p] = c * vkp - s * vkq;
                v[k][q] = s * vkp + c * vkq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let vals = order.map(|i| a[i][i]);
    let vecs = order.map(|i| [v[0][i], v[1][i], v[2][i]]);
    (vals, vecs)
}

/// The result of one plane fit.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Fit {
    /// Unit normal of the fitted plane (arbitrary sign), zero when the fit is degenerate.
    pub normal: [f64; 3],
    /// Eigenvalues of the neighbourhood's covariance, ascending.
    pub lambda: [f64; 3],
}

/// Relative size below which the second eigenvalue marks a neighbourhood as a line (or a
/// point): the neighbourhood is less than 1/1000 as wide as it is long, so no plane is
/// defined to better than about a radian.
const COLLINEAR: f64 = 1e-6;

/// Fits a plane to `p` and the points `nbr` (offsets are taken from `p` so that large
/// coordinates lose no precision).
pub(crate) fn fit_plane(positions: &[[f64; 3]], p: [f64; 3], nbr: &[(u32, f64)]) -> Fit {
    weighted_fit(positions, p, nbr, |_| 1.0)
}

/// As [`fit_plane`], with weight `w(k)` for the `k`-th neighbour (the point itself has 1).
fn weighted_fit(
    positions: &[[f64; 3]],
    p: [f64; 3],
    nbr: &[(u32, f64)],
    w: impl Fn(usize) -> f64,
) -> Fit {
    let mut total = 1.0;
    let mut mean = [0.0; 3];
    for (k, &(j, _)) in nbr.iter().enumerate() {
        let q = positions[j as usize];
        let wk = w(k);
        total += wk;
        for a in 0..3 {
            mean[a] += wk * (q[a] - p[a]);
        }
    }
    let mean = mean.map(|m| m / total);
    let mut c: Sym3 = [0.0; 6];
    let mut add = |d: [f64; 3], wk: f64| {
        c[0] += wk * d[0] * d[0];
        c[1] += wk * d[1] * d[1];
        c[2] += wk * d[2] * d[2];
        c[3] += wk * d[0] * d[1];
        c[4] += wk * d[0] * d[2];
        c[5] += wk * d[1] * d[2];
    };
    add([-mean[0], -mean[1], -mean[2]], 1.0);
    for (k, &(j, _)) in nbr.iter().enumerate() {
        let q = positions[j as usize];
        add(std::array::from_fn(|a| q[a] - p[a] - mean[a]), w(k));
    }
    let c = c.map(|x| x / total);
    let (lambda, vecs) = eigen_sym3(&c);
    let degenerate = lambda[2].is_nan() || lambda[2] <= 0.0 || lambda[1] <= COLLINEAR * lambda[2];
    Fit {
        normal: if degenerate { [0.0; 3] } else { vecs[0] },
        lambda,
    }
}

/// Reweighting rounds of [`refine`]; measured, the angles settle after 4–5.
const REFINE_ROUNDS: usize = 5;

/// Width of the Gaussian weight of [`refine`], in robust scales of the residuals. Measured
/// (mean angle to the true normals): narrower weights follow facets and creases more closely
/// (fandisk 2.1° at 2, 1.5° at 0.5, 2.7° without refinement) but lose accuracy on smooth
/// and scanned surfaces (torus 0.39° at 2, 0.54° at 0.5, 0.33° without; kitten 2.0°, 2.5°,
/// 2.2°); 2 improves all but the analytic shapes.
const REFINE_WIDTH: f64 = 2.0;

/// Refits the plane of a clean neighbourhood with the neighbours weighted by how well they
/// lie on the plane through the point itself (iteratively reweighted least squares with a
/// Gaussian weight whose width follows the median residual). Where the neighbourhood spans a
/// crease, or several facets of a faceted surface, the fit settles on the piece the point is
/// on instead of averaging the pieces; on a smooth surface it leans towards the nearest
/// neighbours. Keeps the previous normal if a refit degenerates.
pub(crate) fn refine(
    positions: &[[f64; 3]],
    p: [f64; 3],
    nbr: &[(u32, f64)],
    fit: Fit,
) -> [f64; 3] {
    let mut n = fit.normal;
    if n == [0.0; 3] || nbr.is_empty() {
        return n;
    }
    let radius = nbr.iter().map(|e| e.1).fold(0.0, f64::max).sqrt();
    let mut r: Vec<f64> = vec![0.0; nbr.len()];
    let mut abs: Vec<f64> = vec![0.0; nbr.len()];
    for _ in 0..REFINE_ROUNDS {
        for (k, &(j, _)) in nbr.iter().enumerate() {
            let q = positions[j as usize];
            r[k] = (q[0] - p[0]) * n[0] + (q[1] - p[1]) * n[1] + (q[2] - p[2]) * n[2];
            abs[k] = r[k].abs();
        }
        let m = abs.len() / 2;
        let mad = *abs.select_nth_unstable_by(m, f64::total_cmp).1;
        // Robust scale of the residuals (1.4826 × median for a normal distribution), kept
        // above rounding level.
        let h = (1.4826 * mad).max(1e-9 * radius);
        let width = REFINE_WIDTH * h;
        let f = weighted_fit(positions, p, nbr, |k| (-0.5 * (r[k] / width).powi(2)).exp());
        if f.normal == [0.0; 3] {
            break;
        }
        let s = if f.normal[0] * n[0] + f.normal[1] * n[1] + f.normal[2] * n[2] < 0.0 {
            -1.0
        } else {
            1.0
        };
        n = f.normal.map(|c| s * c);
    }
    n
}

/// Ladder of neighbourhood sizes the automatic choice picks from; the first is the size for
/// clean clouds.
pub(crate) const K_LADDER: [usize; 8] = [16, 24, 32, 48, 64, 96, 128, 192];

/// Median flatness `λ0/λ1` of the smallest neighbourhoods above which a cloud counts as noisy.
/// Measured: clean scans and CAD samples 0.000–0.01, the sparse `oni` set 0.14, the bunny
/// with noise of 0.25 % and 0.5 % of its diagonal 0.40 and 0.55 (a flat disc of points has
/// `λ1 = r²/4`, so 0.25 means noise of a quarter of the neighbourhood radius).
const NOISY_FLATNESS: f64 = 0.25;

/// Points sampled to choose the neighbourhood size.
const K_PROBES: usize = 2048;

/// The estimated angular error of a plane fit, `sqrt(λ0 / (λ1 k))` (radians, up to a constant
/// near 1): for a disc of `k` points with noise σ across it, the tilt of the least-squares
/// plane has standard deviation about `2σ / (r √k)` while `λ0 ≈ σ²` and `λ1 ≈ r²/4`.
fn fit_error(f: &Fit, k: usize) -> f64 {
    if f.lambda[1] > 0.0 {
        (f.lambda[0].max(0.0) / (f.lambda[1] * k as f64)).sqrt()
    } else {
        f64::INFINITY
    }
}

/// The automatic neighbourhood size: the first of [`K_LADDER`] for clean clouds; for noisy
/// ones (see [`NOISY_FLATNESS`]) the smallest whose median estimated angular error is at
/// most `target` (the largest if none is).
/// Also says whether the cloud is clean.
pub(crate) fn choose_k(
    positions: &[[f64; 3]],
    tree: &Tree,
    finite: &[u32],
    target: f64,
) -> (usize, bool) {
    let (flat, errs) = probe(positions, tree, finite);
    if flat <= NOISY_FLATNESS {
        return (K_LADDER[0], true);
    }
    let l = errs
        .iter()
        .position(|&e| e <= target)
        .unwrap_or(K_LADDER.len() - 1);
    (K_LADDER[l], false)
}

/// On a fixed sample of points: the median flatness `λ0/λ1` of the smallest neighbourhoods,
/// and the median estimated angular error of the plane fits at each size of the ladder.
fn probe(positions: &[[f64; 3]], tree: &Tree, finite: &[u32]) -> (f64, Vec<f64>) {
    let stride = (finite.len() / K_PROBES).max(1);
    let probes: Vec<u32> = finite.iter().step_by(stride).copied().collect();
    let kmax = *K_LADDER.last().unwrap();
    let rows: Vec<(f64, Vec<f64>)> = probes
        .par_iter()
        .map_init(Vec::new, |buf, &i| {
            let p = positions[i as usize];
            tree.nearest(p, kmax + 1, buf);
            buf.retain(|&(j, _)| j != i);
            let fits: Vec<Fit> = K_LADDER
                .iter()
                .map(|&k| fit_plane(positions, p, &buf[..k.min(buf.len())]))
                .collect();
            let f = &fits[0];
            let flat = if f.lambda[1] > 0.0 {
                f.lambda[0].max(0.0) / f.lambda[1]
            } else {
                f64::INFINITY
            };
            let errs = fits.iter().zip(K_LADDER).map(|(f, k)| fit_error(f, k));
            (flat, errs.collect())
        })
        .collect();
    let median = |mut v: Vec<f64>| {
        if v.is_empty() {
            return f64::INFINITY;
        }
        let m = v.len() / 2;
        *v.select_nth_unstable_by(m, f64::total_cmp).1
    };
    let flat = median(rows.iter().map(|r| r.0).collect());
    let errs = (0..K_LADDER.len())
        .map(|l| median(rows.iter().map(|r| r.1[l]).collect()))
        .collect();
    (flat, errs)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rotate(m: [[f64; 3]; 3], d: [f64; 3]) -> Sym3 {
        // m · diag(d) · mᵀ
        let a = |i: usize, j: usize| (0..3).map(|k| m[i][k] * d[k] * m[j][k]).sum::<f64>();
        [a(0, 0), a(1, 1), a(2, 2), a(0, 1), a(0, 2), a(1, 2)]
    }

    #[test]
    fn jacobi_recovers_eigenpairs_including_repeated_and_zero_ones() {
        let (c, s) = (0.6f64, 0.8f64);
        // An orthonormal basis: rotation about z then about x.
        let rz = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        let rx = [[1.0, 0.0, 0.0], [0.0, s, -c], [0.0, c, s]];
        let m: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| rx[i][k] * rz[k][j]).sum())
        });
        for d in [
            [3.0, 1.0, 0.5],
            [2.0, 2.0, 0.0],
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 1.0],
            [5.0, 0.0, 0.0],
        ] {
            let (vals, vecs) = eigen_sym3(&rotate(m, d));
            let mut want = d;
            want.sort_by(f64::total_cmp);
            for k in 0..3 {
                assert!((vals[k] - want[k]).abs() < 1e-12, "{d:?}: {vals:?}");
                let l: f64 = vecs[k].iter().map(|x| x * x).sum();
                assert!((l - 1.0).abs() < 1e-12);
            }
            // Distinct smallest eigenvalue: its vector is the matching column of m.
            if want[0] < want[1] {
                let col = (0..3).find(|&k| d[k] == want[0]).unwrap();
                let dotp: f64 = (0..3).map(|i| vecs[0][i] * m[i][col]).sum();
                assert!((dotp.abs() - 1.0).abs() < 1e-12, "{d:?}");
            }
        }
    }

    #[test]
    fn plane_fit_is_exact_on_a_plane_and_degenerate_on_a_line() {
        let n = [1.0, 2.0, 2.0].map(|c: f64| c / 3.0);
        // Two vectors spanning the plane n · x = 0.
        let (u, v) = ([2.0, -1.0, 0.0], [2.0, 4.0, -5.0]);
        let pts: Vec<[f64; 3]> = (0..30)
            .map(|i| {
                let (a, b) = ((i % 6) as f64, (i / 6) as f64 * 0.7);
                std::array::from_fn(|k| 1e6 + a * u[k] + b * v[k])
            })
            .collect();
        let nbr: Vec<(u32, f64)> = (1..30).map(|j| (j, 0.0)).collect();
        let f = fit_plane(&pts, pts[0], &nbr);
        let c: f64 = (0..3).map(|k| f.normal[k] * n[k]).sum();
        assert!((c.abs() - 1.0).abs() < 1e-12, "{f:?}");
        let line: Vec<[f64; 3]> = (0..30).map(|i| [i as f64, 0.5 * i as f64, 3.0]).collect();
        assert_eq!(fit_plane(&line, line[0], &nbr).normal, [0.0; 3]);
        let same = vec![[1.0, 2.0, 3.0]; 30];
        assert_eq!(fit_plane(&same, same[0], &nbr).normal, [0.0; 3]);
    }
}
