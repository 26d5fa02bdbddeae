//! Where the surface cannot be: bounds of χ over the octree's cells, so that extraction skips
//! the subtrees on whose closed cell χ stays on one side of the iso-value (issue 20).
//!
//! Split χ on the closed cell `C` of a node `n` at depth `d` into the functions of the depths
//! up to `d` and those of the finer depths:
//!
//! - **Coarse part.** The solver keeps the cumulative solution of depths `≤ d` expanded in
//!   depth `d`'s basis (`Solution::p`). B-splines are non-negative and sum to one away from
//!   the cube's faces, so on `C` that part lies between the smallest and the largest of the
//!   coefficients of the depth-`d` functions that do not vanish on `C` (the convex-hull
//!   property). Where one of those functions has no node, the coarser depths' part is not
//!   wholly expanded there and nothing is bounded. At degree 1 these coefficients are the
//!   values at `C`'s corners, so the bound is exact.
//! - **Finer part.** On `C`, the functions of depth `d + 1` add at most the largest magnitude
//!   of their coefficients among those that reach `C`, and the deeper depths at most the
//!   largest such bound over `n`'s children, whose cells cover `C`: `F(n) = A(n) + max_c F(c)`,
//!   computed once from the deepest depth up. A leaf's cell is reached by depth `d + 1` alone
//!   (the tree is conforming; see `crate::evaluate`).
//!
//! χ on `C` so lies within `[lo − F, hi + F]`; when that interval is strictly above the
//! iso-value, or strictly below it, with a margin of `1e-5` of its magnitude for the rounding
//! of the single-precision coefficients (a relative `6e-8` per depth), no corner of any leaf in
//! the subtree changes sign and the subtree holds no part of the surface. Cells within one cell
//! of the cube's faces are never skipped: the boundary conditions change the B-splines there.
//! Skipping such a subtree leaves the mesh bit for bit as it was: its leaves would have made no
//! polygon, and vertices are numbered by the leaves that make them.

use rayon::prelude::*;

use crate::bspline::Basis;
use crate::octree::{
    func_index, neighbor_in, neighbor_in_row, window_index, BroodRow, Octree, DEPTH_OFFSET, NONE,
};
use crate::solver::Solution;

/// Relative margin of a bound (see the module docs).
const MARGIN: f64 = 1e-5;

/// Which cells cannot hold the level set `χ = iso` ([`CellBounds::one_side`]).
pub struct CellBounds<'a> {
    tree: &'a Octree,
    sol: &'a Solution,
    iso: f64,
    /// A depth's functions that do not vanish on the closed cell of index `i`: `i + own.0 ..=
    /// i + own.1` per axis, as window indices ([`window_index`]).
    own: Vec<usize>,
    /// The finer depth's functions that reach the closed cell of index `i` are children of the
    /// nodes `i + up.0 ..= i + up.1` per axis, as window indices.
    up: Vec<usize>,
    /// Per tree level, per brood: the largest magnitude of its nodes' coefficients (empty
    /// where the level has none).
    largest: Vec<Vec<f32>>,
    /// Per tree level, per brood: the largest `F` of its nodes (empty at the deepest level,
    /// whose `F` is 0, and where nothing is known).
    finer: Vec<Vec<f32>>,
}

impl<'a> CellBounds<'a> {
    /// The bounds of χ, solved as `sol` in basis `fem` on `tree`, against the iso-value `iso`;
    /// `None` for degrees other than 1 (see the module docs).
    pub fn new(tree: &'a Octree, fem: Basis, sol: &'a Solution, iso: f64) -> Option<Self> {
        if fem.degree.get() != 1 {
            return None;
        }
        // The window at a cell's midpoint holds exactly the functions that do not vanish on
        // it (depth and cell are arbitrary away from the faces).
        let first = fem.window(4, 8.5 / 16.0).first - 8;
        let own = (first, first + i64::from(fem.degree.get()));
        // The finer depth's functions on the closed cell `i` have indices `2i + own.0 ..=
        // 2i + 1 + own.1`.
        let up = (own.0.div_euclid(2), (1 + own.1).div_euclid(2));
        let levels = tree.depth_count() as usize;
        let largest: Vec<Vec<f32>> = (0..levels)
            .map(|t| brood_largest(sol.x.get(t).map_or(&[][..], |x| x.as_slice())))
            .collect();
        let mut bounds = Self {
            tree,
            sol,
            iso,
            own: cube(own).map(window_index).collect(),
            up: cube(up).map(window_index).collect(),
            largest,
            finer: vec![Vec::new(); levels],
        };
        // From the level above the deepest up to the base.
        for t in (0..levels.saturating_sub(1)).rev() {
            if sol.p.get(t).is_none_or(|p| p.is_empty()) {
                break;
            }
            bounds.finer[t] = bounds.brood_finer(t as u32);
        }
        Some(bounds)
    }

    /// Whether χ stays strictly above the iso-value, or strictly below it, on the closed cell
    /// of node `n` at tree level `t`: then no leaf under `n` holds any part of the surface.
    /// `false` where nothing is known.
    pub fn one_side(&self, t: u32, n: u32) -> bool {
        if self.finer.get(t as usize).is_none_or(|f| f.is_empty()) {
            return false;
        }
        let level = &self.tree.levels[t as usize];
        let d = t - DEPTH_OFFSET;
        let i = func_index(level.key(n), d);
        let last = (1i64 << d) - 3;
        if i.iter().any(|&c| c < 1 || c > last) {
            return false;
        }
        let p = &self.sol.p[t as usize];
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        // Neighbour by neighbour: where a level's rows are derived, a whole row is dearer than
        // the few slots needed here.
        for &w in &self.own {
            let m = neighbor_in(level, n, w);
            if m == NONE {
                // The coarser depths' part is not wholly in this depth's functions here.
                return false;
            }
            let v = f64::from(p[m as usize]);
            lo = lo.min(v);
            hi = hi.max(v);
        }
        let f = if level.row_has_children(n >> 3) {
            self.finer_part(t, n, &level.brood_row(n >> 3))
        } else {
            0.0 // as `finer_part` finds
        };
        let margin = MARGIN * (lo.abs().max(hi.abs()) + f + self.iso.abs());
        lo - f - margin > self.iso || hi + f + margin < self.iso
    }

    /// `F(n)` for node `n` at level `t` (whose brood's row is `row`), in double precision.
    fn finer_part(&self, t: u32, n: u32, row: &BroodRow) -> f64 {
        let t = t as usize;
        let level = &self.tree.levels[t];
        let (Some(largest), Some(finer)) = (self.largest.get(t + 1), self.finer.get(t + 1)) else {
            return 0.0;
        };
        if !level.row_has_children(n >> 3) {
            // Neither `n` nor any node the row reaches has children.
            return 0.0;
        }
        let mut a = 0.0f32;
        if !largest.is_empty() {
            for &w in &self.up {
                let m = neighbor_in_row(row, n, w);
                if m != NONE {
                    let b = level.child(m);
                    if b != NONE {
                        a = a.max(largest[b as usize]);
                    }
                }
            }
        }
        let below = match level.child(n) {
            b if b != NONE && !finer.is_empty() => finer[b as usize],
            _ => 0.0,
        };
        f64::from(a) + f64::from(below)
    }

    /// The largest `F` of each brood of level `t`, from level `t + 1`'s.
    fn brood_finer(&self, t: u32) -> Vec<f32> {
        let level = &self.tree.levels[t as usize];
        (0..level.broods() as u32)
            .into_par_iter()
            .map(|b| {
                if !level.row_has_children(b) {
                    return 0.0;
                }
                let row = level.brood_row(b);
                let f = (0..8).fold(0.0f64, |m, k| m.max(self.finer_part(t, 8 * b + k, &row)));
                round_up(f)
            })
            .collect()
    }
}

/// The offsets `r.0 ..= r.1` per axis.
fn cube(r: (i64, i64)) -> impl Iterator<Item = [i64; 3]> {
    (r.0..=r.1)
        .flat_map(move |z| (r.0..=r.1).flat_map(move |y| (r.0..=r.1).map(move |x| [x, y, z])))
}

/// The largest magnitude of each brood's eight coefficients.
fn brood_largest(x: &[f32]) -> Vec<f32> {
    x.par_chunks(8)
        .map(|c| c.iter().fold(0.0f32, |m, v| m.max(v.abs())))
        .collect()
}

/// The nearest single-precision number at least `v`.
fn round_up(v: f64) -> f32 {
    let f = v as f32;
    if f64::from(f) < v {
        f.next_up()
    } else {
        f
    }
}
