//! Evaluating the implicit function χ and its gradient (ALGORITHM.md §8.1).
//!
//! At a point in leaf `t` of depth `d`, χ is the sum of three O(1) windows: the cumulative
//! coarser solution `P_{d−1}` around `t`'s parent, the depth-`d` coefficients around `t`, and
//! the depth-`d+1` coefficients of the children of `t`'s neighbours. Deeper functions cannot
//! reach a leaf's closure because the tree is conforming.

use std::borrow::Borrow;

use crate::bspline::{Basis, Window};
use crate::extract::Field;
use crate::octree::{
    func_index, neighbor_in, neighbor_in_row, window_index, Octree, DEPTH_OFFSET, NONE,
};
use crate::solver::Solution;

/// Evaluates χ from a solved hierarchy.
pub struct Evaluator<'a> {
    tree: &'a Octree,
    fem: Basis,
    sol: &'a Solution,
    /// Deepest level.
    t_max: u32,
}

impl<'a> Evaluator<'a> {
    /// An evaluator over a solution.
    pub fn new(tree: &'a Octree, fem: Basis, sol: &'a Solution) -> Self {
        Self {
            tree,
            fem,
            sol,
            t_max: tree.depth_count() - 1,
        }
    }

    /// B-spline degree of the elements.
    pub fn degree(&self) -> u8 {
        self.fem.degree.get()
    }

    /// Deepest unit depth of the tree.
    pub fn max_depth(&self) -> u32 {
        self.t_max - DEPTH_OFFSET
    }

    /// The leaf (level, node) containing unit-cube point `p` (lower cell on ties, clamped).
    pub fn leaf(&self, p: [f64; 3]) -> (u32, u32) {
        self.tree.descend(self.key(p), self.t_max, self.t_max)
    }

    /// The deepest tree key of the cell containing `p` (lower cell on ties, clamped).
    fn key(&self, p: [f64; 3]) -> [u64; 3] {
        p.map(|x| self.key_coord(x))
    }

    /// One coordinate of [`Evaluator::key`].
    fn key_coord(&self, x: f64) -> u64 {
        let n = 1i64 << self.max_depth();
        (((x * n as f64).floor() as i64).clamp(0, n - 1) + n) as u64
    }

    /// χ(p) alone.
    pub fn value(&self, p: [f64; 3]) -> f64 {
        self.sum::<false>(p).0
    }

    /// χ(p) and ∇χ(p) (unit-cube units).
    pub fn value_grad(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        self.sum::<true>(p)
    }

    fn sum<const GRAD: bool>(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let (t, n) = self.leaf(p);
        self.sum_in::<GRAD, _>(t, n, &|d| self.windows(d, p))
    }

    /// [`Evaluator::sum`] at a point on or near the closure of leaf `near` (same bits: the
    /// leaf containing `p` is found from `near` instead of from the root).
    fn sum_near<const GRAD: bool>(&self, p: [f64; 3], near: (u32, u32)) -> (f64, [f64; 3]) {
        let (t, n) = self.tree.descend_near(self.key(p), self.t_max, near);
        self.sum_in::<GRAD, _>(t, n, &|d| self.windows(d, p))
    }

    /// χ (and ∇χ) at a point of leaf `(t, n)` whose per-axis windows at unit depth `d` are
    /// `win(d)`. The windows are asked for only when a level has coefficients, and the terms
    /// are summed in one fixed order, so any `win` that returns the same windows gives the
    /// same bits. `win` may hand out references (a table's windows): copying three windows
    /// per level was a tenth of extraction's time.
    fn sum_in<const GRAD: bool, W: Borrow<Window>>(
        &self,
        t: u32,
        n: u32,
        win: &impl Fn(u32) -> [W; 3],
    ) -> (f64, [f64; 3]) {
        let mut acc = (0.0, [0.0; 3]);
        let base = self.sol.base_level;
        if t > base {
            let par = self.tree.parent(t, n);
            self.window_sum::<GRAD, _>(t - 1, par, win, &self.sol.p[t as usize - 1], &mut acc);
        }
        if t >= base {
            self.window_sum::<GRAD, _>(t, n, win, &self.sol.x[t as usize], &mut acc);
        }
        if t < self.t_max && t >= base {
            self.finer_sum::<GRAD, _>(t, n, win, &mut acc);
        }
        acc
    }

    /// χ (and ∇χ) at the corner `c` of the finest grid (integer coordinates at
    /// [`Evaluator::max_depth`]), with the per-axis windows taken from `table`. Equal to
    /// [`Evaluator::value_grad`] at `c · 2^-max_depth`, bit for bit: the leaf is the one
    /// [`Evaluator::leaf`] finds (the point times `2^max_depth` is exactly `c`) and the table
    /// holds the windows [`Basis::window`] gives there.
    fn corner_sum<const GRAD: bool>(
        &self,
        c: [u32; 3],
        table: &CornerWindows,
        near: (u32, u32),
    ) -> (f64, [f64; 3]) {
        let n = 1u64 << self.max_depth();
        let key = c.map(|x| u64::from(x).min(n - 1) + n);
        let (t, node) = self.tree.descend_near(key, self.t_max, near);
        self.sum_in::<GRAD, _>(t, node, &|d| table.get(d, c))
    }

    /// [`Evaluator::value_grad`] at the point just below corner `c` that
    /// [`CornerWindows::below`] describes, from the table: the same leaf (its key is the
    /// table's) and the same windows, so the same bits as evaluating at that point.
    fn below_sum(
        &self,
        c: [u32; 3],
        table: &CornerWindows,
        below: &Below,
        near: (u32, u32),
    ) -> (f64, [f64; 3]) {
        let key = c.map(|x| below.key[x as usize]);
        let (t, node) = self.tree.descend_near(key, self.t_max, near);
        self.sum_in::<true, _>(t, node, &|d| table.below_windows(below, d, c))
    }

    fn windows(&self, d: u32, p: [f64; 3]) -> [Window; 3] {
        [
            self.fem.window(d, p[0]),
            self.fem.window(d, p[1]),
            self.fem.window(d, p[2]),
        ]
    }

    fn window_sum<const GRAD: bool, W: Borrow<Window>>(
        &self,
        t: u32,
        node: u32,
        win: &impl Fn(u32) -> [W; 3],
        coeff: &[f32],
        acc: &mut (f64, [f64; 3]),
    ) {
        if coeff.is_empty() {
            return;
        }
        let d = t - DEPTH_OFFSET;
        let level = &self.tree.levels[t as usize];
        let own = func_index(level.key(node), d);
        let w = win(d);
        let w = w.each_ref().map(|w| w.borrow());
        let k = i64::from(self.fem.degree.get());
        let [rx, ry, rz] = w.each_ref().map(|w| live::<GRAD>(w, k));
        // One neighbour at a time: at the deepest level a brood's row is not stored but
        // derived, all 27 slots of it, while a corner's value needs one function per axis.
        for z in rz.clone() {
            for y in ry.clone() {
                for x in rx.clone() {
                    let o = [
                        w[0].first + x - own[0],
                        w[1].first + y - own[1],
                        w[2].first + z - own[2],
                    ];
                    let m = neighbor_in(level, node, window_index(o));
                    if m == NONE {
                        continue;
                    }
                    accumulate::<GRAD>(&w, [x, y, z], f64::from(coeff[m as usize]), acc);
                }
            }
        }
    }

    fn finer_sum<const GRAD: bool, W: Borrow<Window>>(
        &self,
        t: u32,
        node: u32,
        win: &impl Fn(u32) -> [W; 3],
        acc: &mut (f64, [f64; 3]),
    ) {
        let coeff = &self.sol.x[t as usize + 1];
        if coeff.is_empty() {
            return;
        }
        let level = &self.tree.levels[t as usize];
        if !level.row_has_children(node >> 3) {
            return;
        }
        let d = t - DEPTH_OFFSET;
        let own = func_index(level.key(node), d);
        let w = win(d + 1);
        let w = w.each_ref().map(|w| w.borrow());
        let k = i64::from(self.fem.degree.get());
        let [rx, ry, rz] = w.each_ref().map(|w| live::<GRAD>(w, k));
        let row = level.brood_row(node >> 3);
        for z in rz.clone() {
            for y in ry.clone() {
                for x in rx.clone() {
                    let j = [w[0].first + x, w[1].first + y, w[2].first + z];
                    let o = [
                        (j[0] >> 1) - own[0],
                        (j[1] >> 1) - own[1],
                        (j[2] >> 1) - own[2],
                    ];
                    let m = neighbor_in_row(&row, node, window_index(o));
                    if m == NONE {
                        continue;
                    }
                    let b = level.child(m);
                    if b == NONE {
                        continue;
                    }
                    let bits = (j[0] & 1) | ((j[1] & 1) << 1) | ((j[2] & 1) << 2);
                    accumulate::<GRAD>(
                        &w,
                        [x, y, z],
                        f64::from(coeff[(b * 8) as usize + bits as usize]),
                        acc,
                    );
                }
            }
        }
    }
}

/// The functions of a window that can add to a sum: for a value alone, those whose value is
/// not 0 (a point on a grid corner of a level sees one non-zero degree-1 function per axis
/// there, two of the three degree-2 ones); all of them for a gradient. The values are 0 only
/// at the ends of the window, and skipping a term whose weight is 0 leaves the sum bit for bit
/// as it was, since adding a zero changes no non-zero sum.
/// Half-open, as an inclusive range's iterator costs a branch more per step.
#[inline]
fn live<const GRAD: bool>(w: &Window, k: i64) -> std::ops::Range<i64> {
    if GRAD {
        return 0..k + 1;
    }
    let lo = i64::from(w.values[0] == 0.0);
    let end = if w.values[k as usize] == 0.0 {
        k
    } else {
        k + 1
    };
    lo..end
}

#[inline]
fn accumulate<const GRAD: bool>(w: &[&Window; 3], k: [i64; 3], c: f64, acc: &mut (f64, [f64; 3])) {
    if c == 0.0 {
        return;
    }
    let (x, y, z) = (k[0] as usize, k[1] as usize, k[2] as usize);
    let (vx, vy, vz) = (w[0].values[x], w[1].values[y], w[2].values[z]);
    acc.0 += c * vx * vy * vz;
    if !GRAD {
        return;
    }
    acc.1[0] += c * w[0].derivs[x] * vy * vz;
    acc.1[1] += c * vx * w[1].derivs[y] * vz;
    acc.1[2] += c * vx * vy * w[2].derivs[z];
}

/// The per-axis B-spline windows at every coordinate of the finest corner grid, for each unit
/// depth: corners on a lattice share their 1-D windows, so extraction looks them up instead
/// of locating and evaluating the B-splines three times per level per corner.
pub struct CornerWindows {
    /// Corners per axis (`2^max_depth + 1`).
    side: usize,
    /// Window of depth `d` at coordinate `c`, at `d · side + c`.
    windows: Vec<Window>,
    /// The same just below each coordinate, for degree 1 (see [`CornerField::corner`]).
    below: Option<Below>,
}

/// The points just below the corner coordinates, where [`CornerField::corner`] takes the
/// other one-sided derivative for degree 1: per coordinate, the tree key coordinate of the
/// cell holding the point and the windows there (laid out as [`CornerWindows::windows`]).
/// Evaluating there was a sixth of extraction, most of it locating and evaluating the
/// B-splines, which depend on one coordinate each.
struct Below {
    key: Vec<u64>,
    windows: Vec<Window>,
}

/// Deepest corner grid given a window table (beyond it the table would outgrow the caches it
/// is meant to stay in; such grids evaluate the windows directly).
const MAX_TABLE_DEPTH: u32 = 14;

impl CornerWindows {
    /// The table for the corner grid of `eval`'s deepest level, or `None` when too deep.
    fn new(eval: &Evaluator) -> Option<Self> {
        let dm = eval.max_depth();
        if dm > MAX_TABLE_DEPTH {
            return None;
        }
        let side = (1usize << dm) + 1;
        let s = 1.0 / (1u64 << dm) as f64;
        let windows = (0..=dm)
            .flat_map(|d| (0..side).map(move |c| eval.fem.window(d, c as f64 * s)))
            .collect();
        let below = (eval.degree() == 1).then(|| {
            let q: Vec<f64> = (0..side as u32).map(|c| below_coord(c, dm)).collect();
            Below {
                key: q.iter().map(|&x| eval.key_coord(x)).collect(),
                windows: (0..=dm)
                    .flat_map(|d| q.iter().map(move |&x| eval.fem.window(d, x)))
                    .collect(),
            }
        });
        Some(Self {
            side,
            windows,
            below,
        })
    }

    #[inline]
    fn get(&self, d: u32, c: [u32; 3]) -> [&Window; 3] {
        let row = &self.windows[d as usize * self.side..][..self.side];
        c.map(|x| &row[x as usize])
    }

    /// [`CornerWindows::get`] just below the corner.
    #[inline]
    fn below_windows<'b>(&self, below: &'b Below, d: u32, c: [u32; 3]) -> [&'b Window; 3] {
        let row = &below.windows[d as usize * self.side..][..self.side];
        c.map(|x| &row[x as usize])
    }
}

/// The coordinate just below corner coordinate `c` of the grid of unit depth `depth`, clamped
/// at the cube's lower face (see [`CornerField::corner`]).
#[inline]
fn below_coord(c: u32, depth: u32) -> f64 {
    let s = 1.0 / (1u64 << depth) as f64;
    let eps = s * 1e-6;
    (f64::from(c) * s - eps).max(0.0)
}

/// χ sampled at corners of the finest grid, for extraction.
pub struct CornerField<'a> {
    /// The evaluator.
    eval: &'a Evaluator<'a>,
    /// Depth of the corner grid.
    depth: u32,
    /// Per-axis windows, when the corner grid is the evaluator's finest grid.
    table: Option<CornerWindows>,
}

impl<'a> CornerField<'a> {
    /// χ at the corners of the grid of unit depth `depth`.
    pub fn new(eval: &'a Evaluator<'a>, depth: u32) -> Self {
        let table = (depth == eval.max_depth())
            .then(|| CornerWindows::new(eval))
            .flatten();
        Self { eval, depth, table }
    }

    /// χ and ∇χ at corner `c` of the closure of leaf `near`, through the window table when
    /// there is one.
    fn sum<const GRAD: bool>(&self, c: [u32; 3], near: (u32, u32)) -> (f64, [f64; 3]) {
        match &self.table {
            Some(table) => self.eval.corner_sum::<GRAD>(c, table, near),
            None => self.eval.sum_near::<GRAD>(self.point(c), near),
        }
    }

    /// The unit-cube point of corner `c`.
    fn point(&self, c: [u32; 3]) -> [f64; 3] {
        let s = 1.0 / (1u64 << self.depth) as f64;
        c.map(|x| f64::from(x) * s)
    }
}

/// The hint of a corner is the (tree depth, node) of a leaf whose closure holds it.
impl Field<(u32, u32)> for CornerField<'_> {
    fn value(&self, c: [u32; 3], near: (u32, u32)) -> f64 {
        self.sum::<false>(c, near).0
    }

    /// Degree-1 elements are trilinear on the cells of their depth, so χ is trilinear on the
    /// cells of any grid at least as fine as the tree's finest depth.
    fn trilinear(&self) -> bool {
        self.eval.degree() == 1 && self.depth >= self.eval.max_depth()
    }

    /// The value at the corner, and the central gradient: the mean of the one-sided
    /// derivatives on either side of the corner. With degree-1 elements χ is piecewise
    /// trilinear and its derivative jumps at every corner; a one-sided derivative there is the
    /// slope of one neighbouring edge only, which bends the quadratic vertex fit (§9.2) towards
    /// that edge. For degree 2 (C¹) both sides agree and nothing changes.
    fn corner(&self, c: [u32; 3], near: (u32, u32)) -> (f64, [f64; 3]) {
        let (v, g) = self.sum::<true>(c, near);
        if self.eval.degree() != 1 {
            return (v, g);
        }
        // Just below the corner on every axis (clamped at the cube's lower faces), where the
        // evaluation uses the cells on the other side.
        let gl = match &self.table {
            Some(
                table @ CornerWindows {
                    below: Some(below), ..
                },
            ) => self.eval.below_sum(c, table, below, near).1,
            _ => {
                let q = c.map(|x| below_coord(x, self.depth));
                self.eval.sum_near::<true>(q, near).1
            }
        };
        (
            v,
            [
                0.5 * (g[0] + gl[0]),
                0.5 * (g[1] + gl[1]),
                0.5 * (g[2] + gl[2]),
            ],
        )
    }
}
