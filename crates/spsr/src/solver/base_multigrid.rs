//! A multigrid V-cycle as the preconditioner of the base level's conjugate gradients
//! (issue 20).
//!
//! The base level is complete: its unknowns fill a box of function indices. PoissonRecon
//! solves it with a Galerkin multigrid V-cycle over the coarser complete depths
//! (ALGORITHM.md §7.2, `_solveRegularMG`); spsr keeps its conjugate gradients, to the same
//! tolerance as before, and lets one V-cycle over those depths precondition them in place of
//! the diagonal (Jacobi), which cuts the iterations from about a hundred to five to eight.
//!
//! Each coarser grid holds the functions of one depth less whose two-scale children reach the
//! finer grid. Its matrix is the same energy discretised there: the stiffness from that
//! depth's 1-D tables, and the base level's screening clusters evaluated with that depth's
//! functions (the restriction of the finer screening, since a coarse B-spline is the sum of
//! its children). Transfers are the two-scale relation per axis, restriction its transpose.
//! Smoothing is damped Jacobi, the same sweeps before and after the coarse correction (the
//! base level's through the conjugate gradients' own matrix), and the coarsest grid is solved
//! by conjugate gradients: the V-cycle is then a symmetric operator, as preconditioned
//! conjugate gradients need. Every sum runs in a fixed order, so the result does not depend on
//! the thread count.
//!
//! Degree 1 only. At degree 2 the same V-cycle, and one with Gauss–Seidel smoothing, left the
//! coarse correction nothing to do (B-splines of degree 2 have oscillating modes of small
//! energy, which pointwise smoothing does not damp and the coarser grid cannot hold), and the
//! iterations fell only from 77 to 13–15, at a higher cost than the diagonal's.

use rayon::prelude::*;

use crate::bspline::{table, Basis, Integrand};
use crate::octree::NONE;
use crate::system::{stiffness_3d, Clusters};

use super::{conjugate_gradients, remove_mean};

/// Damping of the Jacobi sweeps.
const OMEGA: f64 = 0.7;
/// Jacobi sweeps before and after the coarse correction, on every grid.
const SWEEPS: usize = 2;
/// The coarsest grid: at most this many points per axis.
const COARSEST_SIDE: usize = 5;

/// Per axis, the two-scale relation between a coarse grid and the next finer one.
struct Transfer {
    /// Per coarse index (from the coarse box's first), its children in the finer box: finer
    /// index (from the finer box's first) and weight.
    children: Vec<Vec<(usize, f64)>>,
    /// Per finer index, its parents in the coarse box: coarse index and weight.
    parents: Vec<Vec<(usize, f64)>>,
}

/// One grid coarser than the base level.
struct Grid {
    /// Points per axis.
    side: usize,
    /// The transfer from this grid to the next finer one (per axis, the same on all three).
    transfer: Transfer,
    /// Row of each point: one value per window slot, `(2k + 1)³` slots (single precision).
    rows: Vec<f32>,
    /// Inverse diagonal of each point's row (0 for an empty row).
    inv: Vec<f64>,
}

/// The V-cycle over the complete depths below the base level.
pub(super) struct BaseMultigrid {
    /// Grid point of each node of the base level (`NONE` for nodes that are not unknowns).
    point: Vec<u32>,
    /// Whether each node of the base level is an unknown.
    valid: Vec<bool>,
    /// Points per axis of the base level's box.
    side: usize,
    /// Inverse diagonal of the base level's rows, per node.
    inv: Vec<f64>,
    /// The coarser grids, finest first.
    grids: Vec<Grid>,
    /// Window radius: the degree.
    radius: usize,
    /// Whether the system has the constants in its kernel (then corrections keep mean zero).
    singular: bool,
}

impl BaseMultigrid {
    /// The V-cycle for a base level of degree 1 at unit depth `depth` whose unknowns have
    /// function indices `index` (`None` for the others), diagonal `diag` and screening
    /// clusters `cl`; `None` at degree 2, where the unknowns do not fill a box, or where there
    /// is no coarser grid.
    pub(super) fn new(
        fem: Basis,
        depth: u32,
        index: &[Option<[i64; 3]>],
        diag: &[f32],
        cl: &Clusters,
        singular: bool,
    ) -> Option<Self> {
        if fem.degree.get() != 1 {
            return None;
        }
        let (lo, side) = unknown_box(index)?;
        let point: Vec<u32> = index
            .iter()
            .map(|i| {
                i.map_or(NONE, |i| {
                    let c = i.map(|c| (c - lo) as usize);
                    (c[0] + side * (c[1] + side * c[2])) as u32
                })
            })
            .collect();
        let inv = diag.iter().map(|&d| inverse(f64::from(d))).collect();
        let radius = usize::from(fem.degree.get());
        let positions: Vec<[f64; 3]> = cl.pos.iter().map(|p| p.map(f64::from)).collect();
        let mut grids = Vec::new();
        let (mut fine_lo, mut fine_side, mut d) = (lo, side, depth);
        while fine_side > COARSEST_SIDE && d > 1 {
            d -= 1;
            let (transfer, coarse_lo, coarse_side) = two_scale(fem, d, fine_lo, fine_side);
            if coarse_side == 0 || coarse_side >= fine_side {
                break;
            }
            let rows = rows(fem, d, coarse_lo, coarse_side, &positions, &cl.omega);
            let width = (2 * radius + 1).pow(3);
            let inv = rows
                .par_chunks(width)
                .map(|r| inverse(f64::from(r[width / 2])))
                .collect();
            grids.push(Grid {
                side: coarse_side,
                transfer,
                rows,
                inv,
            });
            (fine_lo, fine_side) = (coarse_lo, coarse_side);
        }
        (!grids.is_empty()).then_some(BaseMultigrid {
            valid: point.iter().map(|&g| g != NONE).collect(),
            point,
            side,
            inv,
            grids,
            radius,
            singular,
        })
    }

    /// Number of grids below the base level.
    #[cfg(test)]
    pub(super) fn coarser_grids(&self) -> usize {
        self.grids.len()
    }

    /// One V-cycle for `A z = r` from `z = 0`, `apply` being the base level's `A` (node order).
    pub(super) fn precondition(&self, apply: &dyn Fn(&[f64]) -> Vec<f64>, r: &[f64]) -> Vec<f64> {
        let mut z = first_sweep(r, &self.inv);
        for _ in 1..SWEEPS {
            jacobi(&mut z, r, &self.inv, apply);
        }
        let az = apply(&z);
        let mut grid = vec![0.0; self.side.pow(3)];
        for ((&g, r), a) in self.point.iter().zip(r).zip(&az) {
            if g != NONE {
                grid[g as usize] = r - a;
            }
        }
        let coarse = self.cycle(0, restrict(&grid, self.side, &self.grids[0]));
        let up = prolong(&coarse, self.side, &self.grids[0]);
        for (zn, &g) in z.iter_mut().zip(&self.point) {
            if g != NONE {
                *zn += up[g as usize];
            }
        }
        for _ in 0..SWEEPS {
            jacobi(&mut z, r, &self.inv, apply);
        }
        if self.singular {
            remove_mean(&mut z, &self.valid);
        }
        z
    }

    /// The correction on grid `l` for residual `r` (grid order).
    fn cycle(&self, l: usize, r: Vec<f64>) -> Vec<f64> {
        let g = &self.grids[l];
        let stencil = Stencil::new(g.side, self.radius);
        let apply = |x: &[f64]| stencil.apply(&g.rows, &stencil.pad(x));
        if l + 1 == self.grids.len() {
            return coarsest(g, &apply, r, self.singular);
        }
        let mut z = first_sweep(&r, &g.inv);
        for _ in 1..SWEEPS {
            jacobi(&mut z, &r, &g.inv, &apply);
        }
        let az = apply(&z);
        let res: Vec<f64> = r.iter().zip(&az).map(|(r, a)| r - a).collect();
        let next = &self.grids[l + 1];
        let coarse = self.cycle(l + 1, restrict(&res, g.side, next));
        let up = prolong(&coarse, g.side, next);
        for (z, u) in z.iter_mut().zip(&up) {
            *z += u;
        }
        for _ in 0..SWEEPS {
            jacobi(&mut z, &r, &g.inv, &apply);
        }
        z
    }
}

fn inverse(d: f64) -> f64 {
    if d > 0.0 {
        1.0 / d
    } else {
        0.0
    }
}

/// The first damped Jacobi sweep from `z = 0`: `z = ω D⁻¹ r`.
fn first_sweep(r: &[f64], inv: &[f64]) -> Vec<f64> {
    r.par_iter().zip(inv).map(|(r, m)| OMEGA * m * r).collect()
}

/// One damped Jacobi sweep `z += ω D⁻¹ (r − A z)`.
fn jacobi(z: &mut [f64], r: &[f64], inv: &[f64], apply: &dyn Fn(&[f64]) -> Vec<f64>) {
    let az = apply(z);
    z.par_iter_mut()
        .zip(r.par_iter().zip(&az).zip(inv))
        .for_each(|(z, ((r, a), m))| *z += OMEGA * m * (r - a));
}

/// A grid's window as steps on the grid padded by the window's radius, so that every slot of
/// every row is a fixed step (the rows hold zeros where the window leaves the grid).
struct Stencil {
    side: usize,
    radius: usize,
    padded: usize,
    steps: Vec<usize>,
}

impl Stencil {
    fn new(side: usize, radius: usize) -> Self {
        let w = 2 * radius + 1;
        let padded = side + 2 * radius;
        let steps = (0..w * w * w)
            .map(|slot| slot % w + padded * ((slot / w) % w + padded * (slot / (w * w))))
            .collect();
        Stencil {
            side,
            radius,
            padded,
            steps,
        }
    }

    /// Where point `p`'s window starts (its offset (−k, −k, −k)) on the padded grid.
    fn corner(&self, p: usize) -> usize {
        let s = self.side;
        p % s + self.padded * ((p / s) % s + self.padded * (p / (s * s)))
    }

    /// Point `p`'s own place on the padded grid.
    fn centre(&self, p: usize) -> usize {
        let k = self.radius;
        self.corner(p) + k + self.padded * (k + self.padded * k)
    }

    fn pad(&self, x: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.padded.pow(3)];
        for (p, &v) in x.iter().enumerate() {
            out[self.centre(p)] = v;
        }
        out
    }

    /// `Σ_slot row[slot] x[corner + step]` for point `p`.
    #[inline]
    fn row_sum(&self, rows: &[f32], p: usize, x: &[f64]) -> f64 {
        let width = self.steps.len();
        let corner = self.corner(p);
        rows[p * width..][..width]
            .iter()
            .zip(&self.steps)
            .map(|(&v, &st)| f64::from(v) * x[corner + st])
            .sum()
    }

    /// `A x` (grid order) from padded `x`.
    fn apply(&self, rows: &[f32], x: &[f64]) -> Vec<f64> {
        (0..self.side.pow(3))
            .into_par_iter()
            .map(|p| self.row_sum(rows, p, x))
            .collect()
    }
}

/// The first index and points per axis of the box the unknowns fill (the same on all three
/// axes), or `None` where they do not fill one.
fn unknown_box(index: &[Option<[i64; 3]>]) -> Option<(i64, usize)> {
    let (mut lo, mut hi, mut count) = (i64::MAX, i64::MIN, 0usize);
    for i in index.iter().flatten() {
        for &c in i {
            lo = lo.min(c);
            hi = hi.max(c);
        }
        count += 1;
    }
    let side = usize::try_from(hi - lo + 1).ok()?;
    (count > 0 && side.checked_pow(3) == Some(count)).then_some((lo, side))
}

/// The two-scale relation from the functions of unit depth `d` onto the finer box
/// `fine_lo ..= fine_lo + fine_side − 1` of depth `d + 1`: the transfer, and the coarse box
/// (the functions of depth `d` with a child in the finer box).
fn two_scale(fem: Basis, d: u32, fine_lo: i64, fine_side: usize) -> (Transfer, i64, usize) {
    let (clo, chi) = fem.index_range(d);
    let fine_hi = fine_lo + fine_side as i64 - 1;
    let mut out = [(0i64, 0.0f64); 4];
    let mut lists: Vec<(i64, Vec<(usize, f64)>)> = Vec::new();
    for c in clo..=chi {
        let k = fem.children(d, c, &mut out);
        let kids: Vec<(usize, f64)> = out[..k]
            .iter()
            .filter(|&&(j, _)| (fine_lo..=fine_hi).contains(&j))
            .map(|&(j, w)| ((j - fine_lo) as usize, w))
            .collect();
        if !kids.is_empty() {
            lists.push((c, kids));
        }
    }
    let Some(coarse_lo) = lists.first().map(|l| l.0) else {
        return (
            Transfer {
                children: Vec::new(),
                parents: Vec::new(),
            },
            0,
            0,
        );
    };
    let children: Vec<Vec<(usize, f64)>> = lists.into_iter().map(|l| l.1).collect();
    let mut parents = vec![Vec::new(); fine_side];
    for (c, kids) in children.iter().enumerate() {
        for &(j, w) in kids {
            parents[j].push((c, w));
        }
    }
    let side = children.len();
    (Transfer { children, parents }, coarse_lo, side)
}

/// The rows of the grid of unit depth `d` over the box `lo ..= lo + side − 1`: stiffness from
/// the depth's tables, and the screening of the clusters at `positions` with weights `omega`,
/// evaluated with the depth's functions. One slot per window offset, in single precision.
fn rows(
    fem: Basis,
    d: u32,
    lo: i64,
    side: usize,
    positions: &[[f64; 3]],
    omega: &[f64],
) -> Vec<f32> {
    let k = i64::from(fem.degree.get());
    let w = 2 * k + 1;
    let width = (w * w * w) as usize;
    let mass = table(fem, fem, d, false, Integrand::ValueValue);
    let stiff = table(fem, fem, d, false, Integrand::DerivDeriv);
    let s = side as i64;
    let inside = |q: [i64; 3]| q.iter().all(|&c| (0..s).contains(&c));
    let slot = |o: [i64; 3]| ((o[0] + k) + w * ((o[1] + k) + w * (o[2] + k))) as usize;
    let mut rows = vec![0.0f64; side.pow(3) * width];
    rows.par_chunks_mut(width).enumerate().for_each(|(p, row)| {
        let p = p as i64;
        let c = [p % s, (p / s) % s, p / (s * s)];
        let i = c.map(|c| c + lo);
        for (sl, v) in row.iter_mut().enumerate() {
            let sl = sl as i64;
            let o = [sl % w - k, (sl / w) % w - k, sl / (w * w) - k];
            if inside([c[0] + o[0], c[1] + o[1], c[2] + o[2]]) {
                *v = stiffness_3d(&mass, &stiff, i, o);
            }
        }
    });
    // The screening: per cluster, the (k + 1)³ functions of the depth around it.
    for (p, &om) in positions.iter().zip(omega) {
        let win: [_; 3] = std::array::from_fn(|a| fem.window(d, p[a]));
        let n = (k + 1) as usize;
        let mut at: Vec<([i64; 3], f64)> = Vec::with_capacity(n * n * n);
        for z in 0..n {
            for y in 0..n {
                for x in 0..n {
                    let i = [
                        win[0].first + x as i64,
                        win[1].first + y as i64,
                        win[2].first + z as i64,
                    ];
                    let v = win[0].values[x] * win[1].values[y] * win[2].values[z];
                    let c = i.map(|c| c - lo);
                    if v != 0.0 && inside(c) {
                        at.push((c, v));
                    }
                }
            }
        }
        for &(a, va) in &at {
            let row = (a[0] + s * (a[1] + s * a[2])) as usize * width;
            for &(b, vb) in &at {
                let o = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                rows[row + slot(o)] += om * va * vb;
            }
        }
    }
    rows.into_iter().map(|v| v as f32).collect()
}

/// `Rᵀ`-weighted sums from the finer grid (`fine_side` per axis) onto the coarse grid `g`,
/// one axis at a time.
fn restrict(fine: &[f64], fine_side: usize, g: &Grid) -> Vec<f64> {
    let t = &g.transfer.children;
    let cs = g.side;
    let fs = fine_side;
    // x
    let mut a = vec![0.0; cs * fs * fs];
    a.par_chunks_mut(cs).enumerate().for_each(|(yz, out)| {
        let src = &fine[yz * fs..][..fs];
        for (o, kids) in out.iter_mut().zip(t) {
            *o = kids.iter().map(|&(j, w)| w * src[j]).sum();
        }
    });
    // y
    let mut b = vec![0.0; cs * cs * fs];
    b.par_chunks_mut(cs * cs).enumerate().for_each(|(z, out)| {
        for (cy, kids) in t.iter().enumerate() {
            for cx in 0..cs {
                out[cx + cs * cy] = kids
                    .iter()
                    .map(|&(j, w)| w * a[cx + cs * (j + fs * z)])
                    .sum();
            }
        }
    });
    // z
    let mut c = vec![0.0; cs * cs * cs];
    c.par_chunks_mut(cs * cs).enumerate().for_each(|(cz, out)| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = t[cz].iter().map(|&(j, w)| w * b[k + cs * cs * j]).sum();
        }
    });
    c
}

/// The coarse grid `g`'s values prolonged onto the finer grid (`fine_side` per axis), one axis
/// at a time.
fn prolong(coarse: &[f64], fine_side: usize, g: &Grid) -> Vec<f64> {
    let t = &g.transfer.parents;
    let cs = g.side;
    let fs = fine_side;
    // z
    let mut a = vec![0.0; cs * cs * fs];
    a.par_chunks_mut(cs * cs).enumerate().for_each(|(fz, out)| {
        for (k, o) in out.iter_mut().enumerate() {
            *o = t[fz]
                .iter()
                .map(|&(c, w)| w * coarse[k + cs * cs * c])
                .sum();
        }
    });
    // y
    let mut b = vec![0.0; cs * fs * fs];
    b.par_chunks_mut(cs * fs).enumerate().for_each(|(fz, out)| {
        for (fy, parents) in t.iter().enumerate() {
            for cx in 0..cs {
                out[cx + cs * fy] = parents
                    .iter()
                    .map(|&(c, w)| w * a[cx + cs * (c + cs * fz)])
                    .sum();
            }
        }
    });
    // x
    let mut f = vec![0.0; fs * fs * fs];
    f.par_chunks_mut(fs).enumerate().for_each(|(yz, out)| {
        let src = &b[yz * cs..][..cs];
        for (o, parents) in out.iter_mut().zip(t) {
            *o = parents.iter().map(|&(c, w)| w * src[c]).sum();
        }
    });
    f
}

/// The coarsest grid's correction: conjugate gradients to a relative residual of 1e-10 (a
/// few hundred unknowns). A singular system's right-hand side is made consistent first (the
/// constants, the kernel, taken out).
fn coarsest(
    g: &Grid,
    apply: &dyn Fn(&[f64]) -> Vec<f64>,
    mut b: Vec<f64>,
    singular: bool,
) -> Vec<f64> {
    let every = vec![true; b.len()];
    if singular {
        remove_mean(&mut b, &every);
    }
    let width = g.rows.len() / b.len().max(1);
    let diag: Vec<f32> = g.rows.chunks(width.max(1)).map(|r| r[width / 2]).collect();
    conjugate_gradients(apply, &diag, &b, &every, 4 * b.len().max(1), 1e-10)
}
