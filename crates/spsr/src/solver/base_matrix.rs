//! The base level's matrix as conjugate gradients applies it (issue 20).
//!
//! The base level is complete. A row whose window holds only unknowns is applied on a grid in
//! index order, four neighbouring rows at a time, reading the coefficients as vectors: with the
//! stencil's values where the row is the interior stiffness stencil and nothing else (no
//! screening cluster touches its function), else with its own values, stored interleaved four
//! rows at a time. The other rows (at the boundary, where the window leaves the unknowns) keep
//! their assembled entries, summed four rows side by side. Each row's sum takes the same
//! products in the same order as [`FixedRows::apply`] does, so the result is the same to the
//! bit, while a stencil row reads neither column indices nor values and the others no column
//! indices: the base solve's hundred or so products read a fraction of the bytes and overlap
//! their additions.

use rayon::prelude::*;

use super::FixedRows;
use crate::octree::NONE;

/// What [`BaseMatrix::apply`] computes for a node.
#[derive(Clone, Copy, PartialEq)]
enum RowKind {
    /// Not an unknown: an empty sum.
    Empty,
    /// The stencil row of grid point `g`.
    Stencil(u32),
    /// A row with its own values and every slot an unknown, at grid point `g`.
    Own(u32),
    /// Row `k` of the assembled rows.
    Assembled(u32),
}

/// A run of rows of one kind at consecutive grid points along x.
struct Run {
    /// First grid point.
    g: u32,
    /// Number of rows.
    len: u32,
    /// Where the run's values start in its plane's values (`None`: stencil rows).
    vals: Option<usize>,
}

/// The level's matrix, split into rows on the grid and assembled rows.
pub(super) struct BaseMatrix {
    /// Points per axis of the grid: the level's index range and a margin of the window's
    /// radius on each side, so that every grid row's window is on the grid.
    side: usize,
    /// Grid point of each unknown (`NONE` for the others).
    point: Vec<u32>,
    /// Per node, which sum gives its row.
    kind: Vec<RowKind>,
    /// The stencil: grid offset and value of each window slot, in the assembled rows' order.
    stencil: Vec<(isize, f64)>,
    /// Per plane of constant z, the runs of grid rows.
    runs: Vec<Vec<Run>>,
    /// Per plane, the values of its runs of rows with their own values: per four rows, slot
    /// by slot, the four rows' values; then the run's last rows, one after another.
    own: Vec<Vec<f64>>,
    /// The rows whose window leaves the unknowns, in the order of [`RowKind::Assembled`].
    assembled: FixedRows,
}

/// Rows summed side by side.
const LANES: usize = 4;

impl BaseMatrix {
    /// The matrix whose row `n` `row(n, cols, vals)` writes (one slot per position of
    /// `window`, given as `NONE` and zeros; called for the unknowns only). `index[n]` is node
    /// `n`'s function index (`None` for a node that is not an unknown), each coordinate in
    /// `lo..=hi`; `window` lists each slot's offset and the interior stencil's value there.
    /// Where the grid would be much larger than the level (not a complete level), every row
    /// is assembled. Stencil rows are never stored.
    pub(super) fn new(
        row: impl Fn(usize, &mut [u32], &mut [f64]) + Sync,
        index: &[Option<[i64; 3]>],
        (lo, hi): (i64, i64),
        window: &[([i64; 3], f64)],
    ) -> Self {
        let width = window.len();
        let radius = window
            .iter()
            .flat_map(|(o, _)| o.iter().map(|c| c.abs()))
            .max()
            .unwrap_or(0);
        let side = usize::try_from(hi - lo + 1 + 2 * radius).unwrap_or(0);
        let points = side.checked_pow(3).unwrap_or(usize::MAX);
        let side = if points <= 4 * index.len().max(1) && points < NONE as usize {
            side
        } else {
            0
        };
        let at = |i: [i64; 3]| -> u32 {
            if side == 0 {
                return NONE;
            }
            let c = i.map(|c| (c - lo + radius) as usize);
            (c[0] + side * (c[1] + side * c[2])) as u32
        };
        let stencil: Vec<(isize, f64)> = window
            .iter()
            .map(|&(o, v)| {
                let step = o[0] + side as i64 * (o[1] + side as i64 * o[2]);
                (step as isize, v)
            })
            .collect();
        let point: Vec<u32> = index.iter().map(|i| i.map_or(NONE, at)).collect();
        // The rows are made twice: once to tell their kind, once to keep their values.
        let on_grid = |n: usize, cols: &[u32]| {
            point[n] != NONE
                && cols.iter().zip(&stencil).all(|(&c, &(step, _))| {
                    c != NONE && point[c as usize] as isize == point[n] as isize + step
                })
        };
        let is_stencil = |vals: &[f64]| {
            vals.iter()
                .zip(&stencil)
                .all(|(&v, &(_, s))| v.to_bits() == s.to_bits())
        };
        let mut kept = 0u32;
        let kind: Vec<RowKind> = (0..index.len())
            .into_par_iter()
            .map_init(
                || (vec![NONE; width], vec![0.0; width]),
                |(cols, vals), n| {
                    if index[n].is_none() {
                        return RowKind::Empty;
                    }
                    cols.fill(NONE);
                    vals.fill(0.0);
                    row(n, cols, vals);
                    match (on_grid(n, cols), is_stencil(vals)) {
                        (true, true) => RowKind::Stencil(point[n]),
                        (true, false) => RowKind::Own(point[n]),
                        (false, _) => RowKind::Assembled(0),
                    }
                },
            )
            .collect::<Vec<_>>()
            .into_iter()
            .map(|k| match k {
                RowKind::Assembled(_) => {
                    kept += 1;
                    RowKind::Assembled(kept - 1)
                }
                k => k,
            })
            .collect();
        let mut node_at = vec![NONE; side.pow(3)];
        let mut grid_kind = vec![0u8; side.pow(3)];
        let mut assembled_nodes = Vec::with_capacity(kept as usize);
        for (n, k) in kind.iter().enumerate() {
            match *k {
                RowKind::Stencil(g) => grid_kind[g as usize] = 1,
                RowKind::Own(g) => {
                    grid_kind[g as usize] = 2;
                    node_at[g as usize] = n as u32;
                }
                RowKind::Assembled(_) => assembled_nodes.push(n),
                RowKind::Empty => {}
            }
        }
        let (runs, own): (Vec<Vec<Run>>, Vec<Vec<f64>>) = (0..side)
            .into_par_iter()
            .map(|z| {
                let mut vals = Vec::new();
                let mut scratch = vec![NONE; width];
                let runs = runs_of_plane(&grid_kind, side, z)
                    .into_iter()
                    .map(|(g, len, k)| Run {
                        g,
                        len,
                        vals: (k == 2).then(|| {
                            let at = vals.len();
                            vals.resize(at + len as usize * width, 0.0);
                            let nodes = (0..len).map(|j| node_at[(g + j) as usize] as usize);
                            interleave(&row, nodes, &mut scratch, &mut vals[at..]);
                            at
                        }),
                    })
                    .collect();
                (runs, vals)
            })
            .unzip();
        let mut assembled = FixedRows {
            width,
            cols: vec![NONE; assembled_nodes.len() * width],
            vals: vec![0.0; assembled_nodes.len() * width],
        };
        assembled
            .cols
            .par_chunks_mut(width.max(1))
            .zip(assembled.vals.par_chunks_mut(width.max(1)))
            .zip(&assembled_nodes)
            .for_each(|((cols, vals), &n)| row(n, cols, vals));
        BaseMatrix {
            side,
            point,
            kind,
            stencil,
            runs,
            own,
            assembled,
        }
    }

    /// How many rows are of each kind: empty, stencil, own values, assembled.
    #[cfg(test)]
    pub(super) fn kinds(&self) -> [usize; 4] {
        let mut k = [0; 4];
        for r in &self.kind {
            k[match r {
                RowKind::Empty => 0,
                RowKind::Stencil(_) => 1,
                RowKind::Own(_) => 2,
                RowKind::Assembled(_) => 3,
            }] += 1;
        }
        k
    }

    /// `y = A x`, the same to the bit as the assembled matrix's [`FixedRows::apply`].
    pub(super) fn apply(&self, x: &[f64]) -> Vec<f64> {
        let mut grid = vec![0.0; self.side.pow(3)];
        for (&g, &v) in self.point.iter().zip(x) {
            if g != NONE {
                grid[g as usize] = v;
            }
        }
        let plane = (self.side * self.side).max(1);
        let mut sums = vec![0.0; grid.len()];
        sums.par_chunks_mut(plane)
            .zip(&self.runs)
            .zip(&self.own)
            .enumerate()
            .for_each(|(z, ((out, runs), own))| {
                for run in runs {
                    let g = run.g as usize;
                    let local = g - z * plane;
                    let out = &mut out[local..local + run.len as usize];
                    match run.vals {
                        None => self.stencil_run(&grid, g, out),
                        Some(at) => {
                            let vals = &own[at..at + out.len() * self.stencil.len()];
                            self.own_run(&grid, g, vals, out)
                        }
                    }
                }
            });
        let kept = self.assembled_sums(x);
        self.kind
            .par_iter()
            .map(|&k| match k {
                RowKind::Empty => std::iter::empty::<f64>().sum(),
                RowKind::Stencil(g) | RowKind::Own(g) => sums[g as usize],
                RowKind::Assembled(k) => kept[k as usize],
            })
            .collect()
    }

    /// The assembled rows' sums, [`LANES`] rows side by side (each row's sum alone is a chain
    /// of dependent additions; side by side, the chains overlap).
    fn assembled_sums(&self, x: &[f64]) -> Vec<f64> {
        let width = self.assembled.width.max(1);
        let rows = self.assembled.cols.len() / width;
        let mut out = vec![0.0; rows];
        out.par_chunks_mut(LANES)
            .zip(self.assembled.cols.par_chunks(LANES * width))
            .zip(self.assembled.vals.par_chunks(LANES * width))
            .for_each(|((out, cols), vals)| {
                if out.len() < LANES {
                    for ((o, c), v) in out
                        .iter_mut()
                        .zip(cols.chunks(width))
                        .zip(vals.chunks(width))
                    {
                        *o = row_sum(c, v, x);
                    }
                    return;
                }
                let mut acc = [-0.0f64; LANES];
                for k in 0..width {
                    for (l, a) in acc.iter_mut().enumerate() {
                        let c = cols[l * width + k];
                        if c != NONE {
                            *a += vals[l * width + k] * x[c as usize];
                        }
                    }
                }
                out.copy_from_slice(&acc);
            });
        out
    }

    /// The stencil rows of grid points `g..g + out.len()` into `out`: each a sum over the
    /// slots in order, from `-0.0` as [`Iterator::sum`] starts, [`LANES`] rows side by side.
    #[inline]
    fn stencil_run(&self, grid: &[f64], g: usize, out: &mut [f64]) {
        let mut chunks = out.chunks_exact_mut(LANES);
        let mut at = g;
        for chunk in &mut chunks {
            let mut acc = [-0.0f64; LANES];
            for &(step, s) in &self.stencil {
                let from = (at as isize + step) as usize;
                let v: &[f64; LANES] = grid[from..from + LANES].try_into().expect("lanes");
                for l in 0..LANES {
                    acc[l] += s * v[l];
                }
            }
            chunk.copy_from_slice(&acc);
            at += LANES;
        }
        for o in chunks.into_remainder() {
            let mut acc = -0.0f64;
            for &(step, s) in &self.stencil {
                acc += s * grid[(at as isize + step) as usize];
            }
            *o = acc;
            at += 1;
        }
    }

    /// As [`BaseMatrix::stencil_run`], for rows with their own values `vals` (laid out by
    /// [`interleave`]).
    #[inline]
    fn own_run(&self, grid: &[f64], g: usize, vals: &[f64], out: &mut [f64]) {
        let width = self.stencil.len();
        let mut chunks = out.chunks_exact_mut(LANES);
        let mut at = g;
        let mut vals = vals.chunks_exact(LANES * width);
        for (chunk, vals) in (&mut chunks).zip(&mut vals) {
            let mut acc = [-0.0f64; LANES];
            for (&(step, _), s) in self.stencil.iter().zip(vals.chunks_exact(LANES)) {
                let from = (at as isize + step) as usize;
                let v: &[f64; LANES] = grid[from..from + LANES].try_into().expect("lanes");
                for l in 0..LANES {
                    acc[l] += s[l] * v[l];
                }
            }
            chunk.copy_from_slice(&acc);
            at += LANES;
        }
        for (o, vals) in chunks
            .into_remainder()
            .iter_mut()
            .zip(vals.remainder().chunks(width))
        {
            let mut acc = -0.0f64;
            for (&(step, _), &s) in self.stencil.iter().zip(vals) {
                acc += s * grid[(at as isize + step) as usize];
            }
            *o = acc;
            at += 1;
        }
    }
}

/// The values of the rows of `nodes` (written by `row`) into `out`: per [`LANES`] rows, slot
/// by slot, the rows' values side by side; the last rows (fewer than [`LANES`]) one after
/// another.
fn interleave(
    row: &impl Fn(usize, &mut [u32], &mut [f64]),
    nodes: impl ExactSizeIterator<Item = usize>,
    cols: &mut [u32],
    out: &mut [f64],
) {
    let width = cols.len();
    let len = nodes.len();
    let full = len / LANES * LANES;
    let mut vals = vec![0.0; width];
    for (j, n) in nodes.enumerate() {
        cols.fill(NONE);
        vals.fill(0.0);
        row(n, cols, &mut vals);
        if j < full {
            let base = (j / LANES) * LANES * width + j % LANES;
            for (k, &v) in vals.iter().enumerate() {
                out[base + k * LANES] = v;
            }
        } else {
            let base = full * width + (j - full) * width;
            out[base..base + width].copy_from_slice(&vals);
        }
    }
}

/// One assembled row's sum: its entries in slot order, missing ones skipped.
#[inline]
pub(super) fn row_sum(cols: &[u32], vals: &[f64], x: &[f64]) -> f64 {
    cols.iter()
        .zip(vals)
        .filter(|(&c, _)| c != NONE)
        .map(|(&c, &v)| v * x[c as usize])
        .sum()
}

/// The runs of plane `z`: consecutive grid points along x with the same nonzero kind
/// (`kinds`: 1 stencil, 2 own values), as (first point, length, kind).
fn runs_of_plane(kinds: &[u8], side: usize, z: usize) -> Vec<(u32, u32, u8)> {
    let mut out = Vec::new();
    for y in 0..side {
        let line = side * (y + side * z);
        let mut x = 0;
        while x < side {
            let k = kinds[line + x];
            if k == 0 {
                x += 1;
                continue;
            }
            let start = x;
            while x < side && kinds[line + x] == k {
                x += 1;
            }
            out.push(((line + start) as u32, (x - start) as u32, k));
        }
    }
    out
}
