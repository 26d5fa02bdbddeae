//! The cascadic coarse-to-fine solver (ALGORITHM.md §7).
//!
//! The base depth (complete) is solved with conjugate gradients. Each finer depth then solves
//! `(L_d + S_d) x_d = b_d − A_{d,<d} x_{<d}` with Gauss–Seidel sweeps, where the coarser
//! solution enters through the cumulative prolonged coefficients `P_{d−1}` and the parent
//! stencils, so each depth costs O(nodes). Matrices are never stored: rows are rebuilt from
//! the stencils, and the screening term goes through per-cluster running values
//! `χ_d(p_c)`, updated as each unknown changes.

use rayon::prelude::*;

use crate::bspline::Basis;
use crate::gpu::Device;
use crate::octree::{
    brood_offset, for_each_node, func_index, map_nodes, neighbor_in_row, window_index, BroodRow,
    Level, Octree, DEPTH_OFFSET, NONE,
};
use crate::shared_slice::{written_zeros, SharedSlice};
use crate::system::{
    any_with_v, broods_with_v, cluster_offsets, divergence_constraints, prolong, prolong_broods,
    prolong_in_place, BroodStencil, Clusters, DepthTables, Lanes, PlainLanes, Prolongation,
};
use crate::Solver;
use base_matrix::BaseMatrix;
use base_multigrid::BaseMultigrid;

mod base_matrix;
mod base_multigrid;
mod cycles;
#[cfg(feature = "gpu")]
mod device;
pub(crate) use cycles::finer_couplings;
pub use cycles::{cascade_for_cycles, cycle_below, CycleState, DepthResidual, SolveReport};

/// The screening target τ at the samples (PR18 convention: χ ≈ 1 inside, 0 outside).
pub const TAU: f64 = 0.5;

/// Solved coefficients, per level.
#[derive(Debug, Default)]
pub struct Solution {
    /// Coefficients solved at each level (empty below the base level).
    pub x: Vec<Vec<f32>>,
    /// Cumulative solution of all levels up to and including this one, prolonged to it
    /// (empty below the base level and at the deepest level, which evaluation never reads).
    pub p: Vec<Vec<f32>>,
    /// Level of the base solve.
    pub base_level: u32,
    /// Wall time of each part of the solve.
    pub timings: Vec<(String, std::time::Duration, Option<u64>)>,
    /// The residuals of the solve, when [`Problem::report`] asked for them.
    pub report: Option<SolveReport>,
}

/// Everything the solver reads.
pub struct Problem<'a> {
    /// The tree.
    pub tree: &'a Octree,
    /// FEM basis.
    pub fem: Basis,
    /// Tables per level (present at levels ≥ base).
    pub tables: &'a [Option<DepthTables>],
    /// Clusters per level.
    pub clusters: &'a [Clusters],
    /// Base level.
    pub base_level: u32,
    /// Gauss–Seidel sweeps per level.
    pub iters: u32,
    /// The tree's deepest level, whose first relaxation makes [`Problem::first_deepest_iters`]
    /// sweeps (`u32::MAX` for a problem that stops above it: a slab's coarse levels).
    pub deepest_level: u32,
    /// The sweeps of that level's first relaxation ([`Params::first_deepest_iters`]; the
    /// later cycles' relaxations make [`Problem::iters`]).
    ///
    /// [`Params::first_deepest_iters`]: crate::Params::first_deepest_iters
    pub first_deepest_iters: u32,
    /// Whether constants are in the kernel (Neumann/free boundary without screening).
    pub singular: bool,
    /// Shape of the cycles over the depths.
    pub solver: Solver,
    /// Cycles (the first is the cascade).
    pub cycles: u32,
    /// Whether to measure the residuals (costs about one more sweep per depth and cycle;
    /// does not change the solution).
    pub report: bool,
    /// Called with a stage name at each level.
    pub progress: &'a (dyn Fn(&str) + Sync),
    /// The GPU that relaxes the levels above the base, if any (`crate::gpu`).
    pub gpu: Option<&'a Device>,
}

impl Problem<'_> {
    /// The sweeps of level `t`'s first relaxation: [`Problem::iters`], or
    /// [`Problem::first_deepest_iters`] at the reconstruction's deepest level.
    fn first_iters(&self, t: usize) -> u32 {
        if t as u32 == self.deepest_level {
            self.first_deepest_iters
        } else {
            self.iters
        }
    }
}

/// Operator of one level.
struct Op<'a> {
    tree: &'a Octree,
    t: u32,
    level: &'a Level,
    d: u32,
    tab: &'a DepthTables,
    cl: &'a Clusters,
    degree: u8,
    /// Same-level window offsets used by the stiffness stencil.
    win: Vec<(usize, [i64; 3])>,
    /// The interior stiffness stencil by neighbouring brood.
    brood: BroodStencil<1>,
    /// Per child position, the neighbouring broods whose nodes' clusters can touch a
    /// function, with the mask of those nodes.
    cbroods: [Vec<(u8, u8)>; 8],
    /// Whether constants are in the system's kernel.
    singular: bool,
    /// The GPU that relaxes the level, if any.
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    gpu: Option<&'a Device>,
    /// The level's system on the GPU, copied there on first use (`None`: the copy failed).
    #[cfg(feature = "gpu")]
    resident: std::sync::OnceLock<Option<crate::gpu::Resident>>,
    /// The boundary condition (the GPU evaluates the basis at the clusters).
    #[cfg(feature = "gpu")]
    boundary: crate::bspline::Boundary,
}

impl<'a> Op<'a> {
    fn new(p: &'a Problem, t: u32) -> Self {
        let tab = p.tables[t as usize]
            .as_ref()
            .expect("tables exist at solved levels");
        let r = i64::from(p.fem.degree.get());
        let mut win = Vec::new();
        for z in -r..=r {
            for y in -r..=r {
                for x in -r..=r {
                    win.push((window_index([x, y, z]), [x, y, z]));
                }
            }
        }
        Op {
            tree: p.tree,
            t,
            level: &p.tree.levels[t as usize],
            d: t - DEPTH_OFFSET,
            tab,
            cl: &p.clusters[t as usize],
            degree: p.fem.degree.get(),
            win,
            brood: BroodStencil::new([&tab.stencil]),
            cbroods: cluster_broods(p.fem.degree.get()),
            singular: p.singular,
            gpu: p.gpu,
            #[cfg(feature = "gpu")]
            resident: std::sync::OnceLock::new(),
            #[cfg(feature = "gpu")]
            boundary: p.fem.boundary,
        }
    }

    /// Where the level's solution is prolonged to: the level, from its parent level.
    fn prolongation(&self) -> Prolongation<'a> {
        Prolongation {
            tree: self.tree,
            t: self.t,
            weights: &self.tab.prolong,
            range: self.tab.range,
        }
    }

    #[inline]
    fn index(&self, n: u32) -> [i64; 3] {
        func_index(self.level.key(n), self.d)
    }

    /// `Σ_j L_ij x_j` for row `n`, reading coefficients through `x`.
    #[inline(always)]
    fn stiffness_row<L: Lanes>(
        &self,
        nbrs: &BroodRow,
        n: u32,
        i: [i64; 3],
        x: &(impl Coefficients + ?Sized),
    ) -> f64 {
        if self.tab.range.interior(i, 3) {
            return self.brood.row::<L>(nbrs, n, |b| [x.brood(b as usize)]);
        }
        let mut s = 0.0;
        for &(w, o) in &self.win {
            let m = neighbor_in_row(nbrs, n, w);
            if m != NONE {
                let xm = x.at(m as usize);
                if xm != 0.0 {
                    s += self.tab.stiffness(i, o) * xm;
                }
            }
        }
        s
    }

    /// Calls `f(cluster, B_i(p_c))` for every screening cluster that touches function `i`
    /// (node `n`), brood by brood: one rank word per neighbouring brood gives its members.
    #[inline(always)]
    fn for_each_cluster(&self, nbrs: &BroodRow, n: u32, i: [i64; 3], mut f: impl FnMut(u32, f64)) {
        for &(slot, mask) in &self.cbroods[(n & 7) as usize] {
            let b = nbrs[usize::from(slot)];
            if b == NONE {
                continue;
            }
            let (members, first) = self.cl.of_node.brood(b);
            let mut bits = members & mask;
            while bits != 0 {
                let k = bits.trailing_zeros();
                let c = first + (members & ((1u8 << k) - 1)).count_ones();
                let bv = self.cl.basis_value(c as usize, i, self.degree);
                if bv != 0.0 {
                    f(c, bv);
                }
                bits &= bits - 1;
            }
        }
    }

    /// Adds to `s` the coupling of function `i` (node `n`, above the base) with the coarser
    /// levels: `− Σ_q A_iq pc_q + ∫∇B_i·V_q` over the parent-window functions `q`, from the
    /// cumulative coarser solution `pc` and the cumulative coarser V `vc` on the parent level.
    /// `SOL` and `VEC` choose the terms: the coarser solution's, the coarser V's, or both.
    #[inline]
    fn add_coarse_coupling<const SOL: bool, const VEC: bool>(
        &self,
        s: f64,
        n: u32,
        i: [i64; 3],
        pc: &[f64],
        vc: &[[f32; 3]],
    ) -> f64 {
        self.coarse_coupling::<SOL, VEC, false>([s, 0.0], n, i, pc, vc)[0]
    }

    /// [`Op::add_coarse_coupling`] into `s[0]`; with `FIX`, the coarser V's term also into
    /// `s[1]` (the part the solver's further cycles keep), from the same walk over the parent
    /// window. Each sum gets exactly the operations, in the same order, that it would get alone.
    #[inline]
    fn coarse_coupling<const SOL: bool, const VEC: bool, const FIX: bool>(
        &self,
        s: [f64; 2],
        n: u32,
        i: [i64; 3],
        pc: &[f64],
        vc: &[[f32; 3]],
    ) -> [f64; 2] {
        let par = self.level.brood_parent[(n >> 3) as usize];
        if self.tab.is_interior(i) {
            self.add_interior_coupling::<SOL, VEC, FIX>(s, i, par, pc, vc)
        } else {
            self.add_boundary_coupling::<SOL, VEC, FIX>(s, i, par, pc, vc)
        }
    }

    /// Whether the coarser V (`with_v`: per brood of the parent level, whether its V is
    /// nonzero, [`broods_with_v`]) is nonzero anywhere on the parent windows of brood `b`'s
    /// nodes: the broods around the brood's parent. Mostly not: V lives at the samples'
    /// splat depths, and the coarser V is zero away from them.
    #[inline]
    fn coarser_v_near(&self, b: u32, with_v: &[bool]) -> bool {
        let par = self.level.brood_parent[b as usize];
        any_with_v(
            &self.tree.levels[self.t as usize - 1].brood_row(par >> 3),
            with_v,
        )
    }

    /// [`Op::coarse_coupling`] with the coarser solution's terms and, where `near_v`
    /// ([`Op::coarser_v_near`]), the coarser V's. Elsewhere V is zero on the whole parent
    /// window, and its terms, each ±0 (which only the interior stencils add; the boundary
    /// path skips zero V), are left out: adding them changes no sum but, at most, the sign of
    /// an exact zero (checked: the same bytes on every configuration of the comparison in
    /// `bench/results/issue20-speed9.md`).
    #[inline]
    fn coarse_coupling_near_v<const FIX: bool>(
        &self,
        s: [f64; 2],
        n: u32,
        i: [i64; 3],
        (pc, vc): (&[f64], &[[f32; 3]]),
        near_v: bool,
    ) -> [f64; 2] {
        if near_v {
            self.coarse_coupling::<true, true, FIX>(s, n, i, pc, vc)
        } else {
            self.coarse_coupling::<true, false, FIX>(s, n, i, pc, vc)
        }
    }

    /// [`Op::add_coarse_coupling`] for an interior function: the precomputed parent stencils
    /// of its child position, over their nonzero entries.
    #[inline]
    fn add_interior_coupling<const SOL: bool, const VEC: bool, const FIX: bool>(
        &self,
        mut s: [f64; 2],
        i: [i64; 3],
        par: u32,
        pc: &[f64],
        vc: &[[f32; 3]],
    ) -> [f64; 2] {
        let tab = self.tab;
        let parent_level = &self.tree.levels[self.t as usize - 1];
        let c = ((i[0] & 1) | ((i[1] & 1) << 1) | ((i[2] & 1) << 2)) as usize;
        let ps = &tab.pstencil[c];
        let pv = &tab.pvstencil[c];
        let row = parent_level.brood_row(par >> 3);
        // Without the V term, only the entries where the stiffness is nonzero (the others
        // would subtract zeros).
        let window = if VEC {
            &tab.pnonzero[c]
        } else {
            &tab.psnonzero[c]
        };
        for &w in window {
            let w = usize::from(w);
            let q = neighbor_in_row(&row, par, w);
            if q == NONE {
                continue;
            }
            if SOL {
                s[0] -= ps[w] * pc[q as usize];
            }
            if VEC {
                let v = vc[q as usize];
                let term = f64::from(v[0]) * pv[0][w]
                    + f64::from(v[1]) * pv[1][w]
                    + f64::from(v[2]) * pv[2][w];
                s[0] += term;
                if FIX {
                    s[1] += term;
                }
            }
        }
        s
    }

    /// [`Op::add_coarse_coupling`] for a function near the boundary: the parent window's
    /// entries from the 1-D mass, stiffness and V tables.
    fn add_boundary_coupling<const SOL: bool, const VEC: bool, const FIX: bool>(
        &self,
        mut s: [f64; 2],
        i: [i64; 3],
        par: u32,
        pc: &[f64],
        vc: &[[f32; 3]],
    ) -> [f64; 2] {
        let tab = self.tab;
        let parent_level = &self.tree.levels[self.t as usize - 1];
        let mut pm = [[0.0; 5]; 3];
        let mut ps = [[0.0; 5]; 3];
        let mut vm = [[0.0; 5]; 3];
        let mut vd = [[0.0; 5]; 3];
        for a in 0..3 {
            for o in 0..5 {
                pm[a][o] = tab.pmass.get(i[a], o as i64 - 2);
                ps[a][o] = tab.pstiff.get(i[a], o as i64 - 2);
                vm[a][o] = tab.pvmass.get(i[a], o as i64 - 2);
                vd[a][o] = tab.pvderiv.get(i[a], o as i64 - 2);
            }
        }
        let row = parent_level.brood_row(par >> 3);
        for w in 0..125usize {
            let (ox, oy, oz) = (w % 5, (w / 5) % 5, w / 25);
            let q = neighbor_in_row(&row, par, w);
            if q == NONE {
                continue;
            }
            let xq = if SOL { pc[q as usize] } else { 0.0 };
            if xq != 0.0 {
                let k = ps[0][ox] * pm[1][oy] * pm[2][oz]
                    + pm[0][ox] * ps[1][oy] * pm[2][oz]
                    + pm[0][ox] * pm[1][oy] * ps[2][oz];
                s[0] -= k * xq;
            }
            let v = if VEC { vc[q as usize] } else { [0.0; 3] };
            if v != [0.0; 3] {
                let v = v.map(f64::from);
                let term = v[0] * vd[0][ox] * vm[1][oy] * vm[2][oz]
                    + v[1] * vm[0][ox] * vd[1][oy] * vm[2][oz]
                    + v[2] * vm[0][ox] * vm[1][oy] * vd[2][oz];
                s[0] += term;
                if FIX {
                    s[1] += term;
                }
            }
        }
        s
    }

    fn diagonal(&self) -> Vec<f32> {
        map_nodes(self.level, |n, nbrs| {
            let i = self.index(n);
            if !self.tab.range.contains(i) {
                return 0.0;
            }
            let mut dg = self.tab.stiffness(i, [0, 0, 0]);
            self.for_each_cluster(nbrs, n, i, |c, bv| {
                dg += self.cl.omega[c as usize] * bv * bv
            });
            dg as f32
        })
    }

    /// χ_d at every cluster from the level's coefficients.
    fn cluster_values(&self, x: impl Fn(usize) -> f64 + Sync) -> Vec<f64> {
        (0..self.cl.len())
            .into_par_iter()
            .map(|c| cluster_value(self.level, self.cl, c, self.d, self.degree, &x))
            .collect()
    }

    /// `y = (L + S) x`.
    fn apply(&self, x: &[f64], valid: &[bool]) -> Vec<f64> {
        let chi = self.cluster_values(|n| x[n]);
        map_nodes(self.level, |n, nbrs| {
            if !valid[n as usize] {
                return 0.0;
            }
            let i = self.index(n);
            let mut s = self.stiffness_row::<PlainLanes>(nbrs, n, i, x);
            self.for_each_cluster(nbrs, n, i, |c, bv| {
                s += self.cl.omega[c as usize] * bv * chi[c as usize]
            });
            s
        })
    }

    /// The level's matrix `L + S` with one fixed-width row per node (the stiffness window's
    /// slots; `NONE` columns where a neighbour is missing or not an unknown).
    #[cfg(test)]
    fn assemble(&self, valid: &[bool]) -> FixedRows {
        let width = self.win.len();
        let len = self.level.len();
        let mut out = FixedRows {
            width,
            cols: vec![NONE; len * width],
            vals: vec![0.0; len * width],
        };
        let slot_of = self.slot_of();
        out.cols
            .par_chunks_mut(width)
            .zip(out.vals.par_chunks_mut(width))
            .enumerate()
            .for_each(|(n, (cols, vals))| {
                if valid[n] {
                    self.assemble_row(n as u32, valid, &slot_of, cols, vals);
                }
            });
        out
    }

    /// Each window position's slot in an assembled row (`usize::MAX` outside the window).
    fn slot_of(&self) -> [usize; 125] {
        let mut slot_of = [usize::MAX; 125];
        for (k, &(w, _)) in self.win.iter().enumerate() {
            slot_of[w] = k;
        }
        slot_of
    }

    /// Row `n` (an unknown) of the level's matrix `L + S` into `cols` and `vals` (one slot per
    /// window position, [`Op::slot_of`]; given as `NONE` and zeros): the neighbours that are
    /// unknowns, with their stiffness and the screening of the clusters around the function.
    fn assemble_row(
        &self,
        n: u32,
        valid: &[bool],
        slot_of: &[usize; 125],
        cols: &mut [u32],
        vals: &mut [f64],
    ) {
        let k = usize::from(self.degree);
        let i = self.index(n);
        let interior = self.tab.range.interior(i, 3);
        let nbrs = self.level.brood_row(n >> 3);
        for (slot, &(w, o)) in self.win.iter().enumerate() {
            let m = neighbor_in_row(&nbrs, n, w);
            if m != NONE && valid[m as usize] {
                cols[slot] = m;
                vals[slot] = if interior {
                    self.tab.stencil[w]
                } else {
                    self.tab.stiffness(i, o)
                };
            }
        }
        self.for_each_cluster(&nbrs, n, i, |c, bv| {
            let c = c as usize;
            let w_c = self.cl.omega[c] * bv;
            let f = self.cl.first(c, i);
            let v = |a, k| f64::from(self.cl.axis_value(c, a, k));
            for z in 0..=k {
                for y in 0..=k {
                    for x in 0..=k {
                        let o = [
                            f[0] + x as i64 - i[0],
                            f[1] + y as i64 - i[1],
                            f[2] + z as i64 - i[2],
                        ];
                        let slot = slot_of[window_index(o)];
                        if slot != usize::MAX && cols[slot] != NONE {
                            vals[slot] += w_c * v(0, x) * v(1, y) * v(2, z);
                        }
                    }
                }
            }
        });
    }

    /// The level's matrix `L + S` for conjugate gradients ([`BaseMatrix`]): the rows whose
    /// window holds only unknowns applied on a grid (from the interior stencil where nothing
    /// screens them), the boundary rows assembled.
    fn base_matrix(&self, valid: &[bool]) -> BaseMatrix {
        let index: Vec<Option<[i64; 3]>> = (0..self.level.len() as u32)
            .map(|n| valid[n as usize].then(|| self.index(n)))
            .collect();
        let window: Vec<([i64; 3], f64)> = self
            .win
            .iter()
            .map(|&(w, o)| (o, self.tab.stencil[w]))
            .collect();
        let range = self.tab.range;
        let slot_of = self.slot_of();
        BaseMatrix::new(
            |n, cols: &mut [u32], vals: &mut [f64]| {
                self.assemble_row(n as u32, valid, &slot_of, cols, vals)
            },
            &index,
            (range.lo, range.hi),
            &window,
        )
    }

    /// `iters` Gauss–Seidel sweeps ([`Op::gauss_seidel_cpu`]), on the GPU when the problem
    /// has one (the same result to the last bit). A level the GPU cannot relax (too large for
    /// its memory, say) is relaxed on the CPU, and the device keeps the reason.
    fn gauss_seidel(&self, r: &[f32], x: &mut [f32], iters: u32) {
        #[cfg(feature = "gpu")]
        if self.gauss_seidel_gpu(r, x, iters) {
            return;
        }
        self.gauss_seidel_cpu(r, x, iters);
    }

    /// Multi-colour Gauss–Seidel sweeps (ALGORITHM.md §7.1), relaxed block by block.
    ///
    /// Nodes are coloured by their function index modulo `degree + 1` per axis: two nodes of
    /// one colour share no stiffness entry and no screening cluster. For degree 1 the colour
    /// of node `8b + c` is its child position `c` (a function index's parity is its key's).
    ///
    /// For locality the level is cut into blocks: the nodes below one ancestor four levels
    /// up, contiguous in the level's Morton order. Blocks are coloured by their ancestor's key
    /// parity, so two blocks of one colour are at least 17 nodes apart, far more than the two
    /// nodes over which a relaxation reads or writes coefficients and cluster values. A sweep
    /// relaxes the blocks colour by colour, blocks of one colour in parallel, and inside a
    /// block the node colours one after the other: a block's data is read once per sweep
    /// rather than once per node colour. The order depends only on the tree, so the result
    /// does not depend on the thread count.
    ///
    /// Where the processor has AVX2 the blocks are relaxed by a copy of the same code compiled
    /// for it ([`Wide`]): the brood sums' eight lanes go four at a time instead of two, with
    /// the same operations in the same order, so the bits are the same.
    fn gauss_seidel_cpu<R: Copy + Into<f64> + Sync>(&self, r: &[R], x: &mut [f32], iters: u32) {
        self.gauss_seidel_with(r, x, iters, Wide::detect());
    }

    /// [`Op::gauss_seidel_cpu`] with the instruction set chosen by the caller.
    fn gauss_seidel_with<R: Copy + Into<f64> + Sync>(
        &self,
        r: &[R],
        x: &mut [f32],
        iters: u32,
        wide: Wide,
    ) {
        let blocks = self.colour_blocks();
        let residues = self.brood_residues();
        let mut chi = self.cluster_values(|n| f64::from(x[n]));
        let xs = SharedSlice::new(x);
        let cs = SharedSlice::new(&mut chi);
        for _ in 0..iters {
            for list in &blocks {
                list.par_iter().for_each_init(Vec::new, |rows, &block| {
                    let job = BlockJob {
                        block,
                        residues: &residues,
                        r,
                        x: &xs,
                        chi: &cs,
                    };
                    // SAFETY: only this block's task touches the coefficients and cluster
                    // values within two nodes of its nodes (above).
                    unsafe { wide.relax_block(self, rows, &job) };
                });
            }
        }
    }

    /// Relaxes the nodes of one block, colour by colour ([`Op::gauss_seidel_cpu`]). `rows`
    /// is scratch space for the block's brood rows, made once for its node colours (the
    /// deepest level derives them).
    ///
    /// # Safety
    /// No other thread may touch the coefficients or cluster values within two nodes of the
    /// block's nodes meanwhile.
    #[inline(always)]
    unsafe fn relax_block<L: Lanes, R: Copy + Into<f64>>(
        &self,
        rows: &mut Vec<BroodRow>,
        job: &BlockJob<R>,
    ) {
        let (b0, b1) = job.block;
        rows.clear();
        rows.extend((b0..b1).map(|b| *self.level.brood_row(b)));
        for c in 0..self.node_colours() {
            for (b, nbrs) in (b0..b1).zip(rows.iter()) {
                let k = self.child_of_colour(c, job.residues.get(b as usize));
                if k == NO_CHILD {
                    continue;
                }
                let n = 8 * b + u32::from(k);
                let (i, r) = (self.index(n), job.r[n as usize].into());
                // SAFETY: the caller's.
                unsafe { self.relax::<L>(nbrs, n, i, r, job.x, job.chi) };
            }
        }
    }

    /// For degree 2, each brood's first function index modulo 3 per axis, as one number
    /// `rx + 3 ry + 9 rz` (empty for degree 1, whose colours are child positions).
    fn brood_residues(&self) -> Vec<u8> {
        if self.degree == 1 {
            return Vec::new();
        }
        (0..(self.level.len() / 8) as u32)
            .into_par_iter()
            .map(|b| {
                let i = self.index(8 * b);
                (i[0].rem_euclid(3) + 3 * i[1].rem_euclid(3) + 9 * i[2].rem_euclid(3)) as u8
            })
            .collect()
    }

    /// The child position of the node of colour `c` in a brood whose residues are `res`
    /// ([`Op::brood_residues`]), or [`NO_CHILD`]: a brood holds at most one node per colour.
    #[inline]
    fn child_of_colour(&self, c: u32, res: Option<&u8>) -> u8 {
        match res {
            None => c as u8,
            Some(&res) => CHILD_OF_COLOUR[c as usize][usize::from(res)],
        }
    }

    /// Number of node colours: `(degree + 1)³`.
    fn node_colours(&self) -> u32 {
        let m = u32::from(self.degree) + 1;
        m * m * m
    }

    /// The level's blocks `(first, end)` of broods, grouped by colour (the parity of the
    /// common ancestor four levels up, or fewer near the root): see [`Op::gauss_seidel`].
    fn colour_blocks(&self) -> [Vec<(u32, u32)>; 8] {
        let up = 4.min(self.t);
        let nb = self.level.len() / 8;
        let mut blocks: [Vec<(u32, u32)>; 8] = Default::default();
        let mut start = 0usize;
        let mut current = NONE;
        let mut colour = 0usize;
        for b in 0..=nb {
            let anc = (b < nb).then(|| {
                let mut a = self.level.brood_parent[b];
                for k in 1..up {
                    a = self.tree.parent(self.t - k, a);
                }
                a
            });
            if anc != Some(current) {
                if current != NONE {
                    blocks[colour].push((start as u32, b as u32));
                }
                if let Some(a) = anc {
                    current = a;
                    start = b;
                    let k = self.tree.levels[(self.t - up) as usize].key(a);
                    colour = ((k[0] & 1) | (k[1] & 1) << 1 | (k[2] & 1) << 2) as usize;
                }
            }
        }
        blocks
    }

    /// One Gauss–Seidel update of node `n` (nothing for a node without a function). The
    /// diagonal `L_nn + Σ_c ω_c B_n(p_c)²` is summed on the way.
    ///
    /// # Safety
    /// No other thread may concurrently write `x[n]`, any `x[m]` this row reads, or the
    /// cluster values of the clusters around `n`.
    #[inline(always)]
    unsafe fn relax<L: Lanes>(
        &self,
        nbrs: &BroodRow,
        n: u32,
        i: [i64; 3],
        r: f64,
        x: &SharedSlice<f32>,
        chi: &SharedSlice<f64>,
    ) {
        if !self.tab.range.contains(i) {
            return;
        }
        let mut s = self.stiffness_row::<L>(nbrs, n, i, &Live(x));
        let mut dg = if self.tab.range.interior(i, 3) {
            self.tab.stencil[62]
        } else {
            self.tab.stiffness(i, [0, 0, 0])
        };
        let mut touched: [(u32, f64); 27] = [(0, 0.0); 27];
        let mut k = 0;
        self.for_each_cluster(nbrs, n, i, |c, bv| {
            let w = self.cl.omega[c as usize] * bv;
            s += w * chi.get(c as usize);
            dg += w * bv;
            touched[k] = (c, bv);
            k += 1;
        });
        let dx = (r - s) / dg;
        x.set(n as usize, (f64::from(x.get(n as usize)) + dx) as f32);
        for &(c, bv) in &touched[..k] {
            chi.set(c as usize, chi.get(c as usize) + dx * bv);
        }
    }
}

/// One block of a Gauss–Seidel sweep and what its relaxation reads and writes
/// ([`Op::relax_block`]).
struct BlockJob<'a, R> {
    /// The block's broods, `first..end`.
    block: (u32, u32),
    residues: &'a [u8],
    r: &'a [R],
    x: &'a SharedSlice<f32>,
    chi: &'a SharedSlice<f64>,
}

/// Which compiled copy of the Gauss–Seidel block relaxes: the baseline one (SSE2 on x86-64),
/// or one compiled for AVX2 where the processor has it. Both do the same operations in the
/// same order (no fused multiply-adds: Rust does not contract), so the bits do not depend on
/// the choice; only the brood sums' lanes go twice as wide.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Wide {
    Baseline,
    #[cfg(target_arch = "x86_64")]
    Avx2,
}

impl Wide {
    /// The widest copy this processor runs.
    fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            return Wide::Avx2;
        }
        Wide::Baseline
    }

    /// [`Op::relax_block`] in this copy.
    ///
    /// # Safety
    /// That of [`Op::relax_block`].
    #[inline]
    unsafe fn relax_block<R: Copy + Into<f64>>(
        self,
        op: &Op<'_>,
        rows: &mut Vec<BroodRow>,
        job: &BlockJob<R>,
    ) {
        match self {
            // SAFETY: the caller's.
            Wide::Baseline => unsafe { op.relax_block::<PlainLanes, R>(rows, job) },
            // SAFETY: the caller's; `detect` chose this copy only where AVX2 runs.
            #[cfg(target_arch = "x86_64")]
            Wide::Avx2 => unsafe { relax_block_avx2(op, rows, job) },
        }
    }
}

/// [`Op::relax_block`] compiled for AVX2 (its callees inlined into it).
///
/// # Safety
/// That of [`Op::relax_block`], and the processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn relax_block_avx2<R: Copy + Into<f64>>(
    op: &Op<'_>,
    rows: &mut Vec<BroodRow>,
    job: &BlockJob<R>,
) {
    // SAFETY: the caller's; AVX2 includes AVX.
    unsafe { op.relax_block::<crate::system::AvxLanes, R>(rows, job) }
}

/// For each child position, the neighbouring brood slots holding cells within the offsets
/// of [`cluster_offsets`] (the cells whose clusters can touch the node's function), each with
/// the mask of its nodes among them.
pub(crate) fn cluster_broods(degree: u8) -> [Vec<(u8, u8)>; 8] {
    let offsets = cluster_offsets(degree);
    std::array::from_fn(|c| {
        let mut out = Vec::new();
        for slot in 0..27u8 {
            let mut mask = 0u8;
            for k in 0..8usize {
                let o = brood_offset(c, slot, k);
                if o.iter().all(|v| offsets.contains(v)) {
                    mask |= 1 << k;
                }
            }
            if mask != 0 {
                out.push((slot, mask));
            }
        }
        out
    })
}

/// A level's coefficients, read one node or one brood (eight consecutive nodes) at a time.
trait Coefficients {
    fn at(&self, m: usize) -> f64;
    fn brood(&self, b: usize) -> [f64; 8];
}

impl Coefficients for [f64] {
    #[inline]
    fn at(&self, m: usize) -> f64 {
        self[m]
    }
    #[inline]
    fn brood(&self, b: usize) -> [f64; 8] {
        let v: &[f64; 8] = self[8 * b..8 * b + 8].try_into().expect("eight nodes");
        *v
    }
}

impl Coefficients for [f32] {
    #[inline]
    fn at(&self, m: usize) -> f64 {
        f64::from(self[m])
    }
    #[inline]
    fn brood(&self, b: usize) -> [f64; 8] {
        let v: &[f32; 8] = self[8 * b..8 * b + 8].try_into().expect("eight nodes");
        v.map(f64::from)
    }
}

/// The coefficients a Gauss–Seidel sweep is updating. Built only in [`Op::relax`], whose
/// caller guarantees that no other thread writes the coefficients a row reads.
struct Live<'a>(&'a SharedSlice<f32>);

impl Coefficients for Live<'_> {
    #[inline]
    fn at(&self, m: usize) -> f64 {
        // SAFETY: see the type's comment.
        f64::from(unsafe { self.0.get(m) })
    }
    #[inline]
    fn brood(&self, b: usize) -> [f64; 8] {
        // SAFETY: see the type's comment.
        unsafe { self.0.get_array::<8>(8 * b) }.map(f64::from)
    }
}

/// No node of the asked colour in a brood ([`Op::child_of_colour`]).
const NO_CHILD: u8 = 8;

/// Degree 2: the child position with node colour `c` (`cx + 3 cy + 9 cz`, function index
/// modulo 3 per axis) in a brood whose first node's residues are `r`, or [`NO_CHILD`]. Per
/// axis the child at position `p ∈ {0, 1}` has residue `r + p` modulo 3.
static CHILD_OF_COLOUR: [[u8; 27]; 27] = {
    let mut t = [[NO_CHILD; 27]; 27];
    let mut c = 0;
    while c < 27 {
        let mut r = 0;
        while r < 27 {
            let cc = [c % 3, c / 3 % 3, c / 9];
            let rr = [r % 3, r / 3 % 3, r / 9];
            let mut k = 0u8;
            let mut ok = true;
            let mut a = 0;
            while a < 3 {
                let p = (cc[a] + 3 - rr[a]) % 3;
                if p > 1 {
                    ok = false;
                }
                k |= (p as u8) << a;
                a += 1;
            }
            if ok {
                t[c][r] = k;
            }
            r += 1;
        }
        c += 1;
    }
    t
};

/// A sparse matrix with the same number of slots in every row.
struct FixedRows {
    width: usize,
    cols: Vec<u32>,
    vals: Vec<f64>,
}

impl FixedRows {
    /// `y = A x` (the tests' reference for [`BaseMatrix::apply`]).
    #[cfg(test)]
    fn apply(&self, x: &[f64]) -> Vec<f64> {
        self.cols
            .par_chunks(self.width)
            .zip(self.vals.par_chunks(self.width))
            .map(|(c, v)| base_matrix::row_sum(c, v, x))
            .collect()
    }
}

/// `Σ_j B_j(p_c) x_j` over the level's functions around cluster `c`.
fn cluster_value(
    level: &Level,
    cl: &Clusters,
    c: usize,
    d: u32,
    degree: u8,
    x: &impl Fn(usize) -> f64,
) -> f64 {
    let node = cl.node[c];
    let own = func_index(level.key(node), d);
    let f = cl.first(c, own);
    let v = |a, k: i64| f64::from(cl.axis_value(c, a, k as usize));
    let k = i64::from(degree);
    let row = level.brood_row(node >> 3);
    let mut s = 0.0;
    for z in 0..=k {
        for y in 0..=k {
            for xx in 0..=k {
                let j = [f[0] + xx, f[1] + y, f[2] + z];
                let m = neighbor_in_row(
                    &row,
                    node,
                    window_index([j[0] - own[0], j[1] - own[1], j[2] - own[2]]),
                );
                if m == NONE {
                    continue;
                }
                s += v(0, xx) * v(1, y) * v(2, z) * x(m as usize);
            }
        }
    }
    s
}

/// Single-precision copy of a coefficient vector (storage; arithmetic stays in f64).
fn to_f32(v: &[f64]) -> Vec<f32> {
    v.par_iter().map(|&x| x as f32).collect()
}

/// Elements a chunk of the deterministic dot products ([`dot`]).
const DOT_CHUNK: usize = 4096;

/// Deterministic dot product: fixed-size chunks summed in order.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    chunk_sums(
        a.par_chunks(DOT_CHUNK)
            .zip(b.par_chunks(DOT_CHUNK))
            .map(|(x, y)| x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>()),
    )
}

/// The sum of per-chunk sums, in chunk order whatever the threads ([`dot`]).
fn chunk_sums(parts: impl IndexedParallelIterator<Item = f64>) -> f64 {
    parts.collect::<Vec<f64>>().iter().sum()
}

/// Conjugate gradients on `op`, preconditioned by its diagonal (Jacobi), to relative residual
/// `tol` (measured in the unpreconditioned norm).
fn conjugate_gradients(
    apply: impl Fn(&[f64]) -> Vec<f64>,
    diag: &[f32],
    b: &[f64],
    valid: &[bool],
    max_iter: usize,
    tol: f64,
) -> Vec<f64> {
    conjugate_gradients_with(apply, diag, None, b, valid, max_iter, tol)
}

/// `z = M⁻¹ r` for preconditioned conjugate gradients.
type Preconditioner<'a> = dyn Fn(&[f64]) -> Vec<f64> + 'a;

/// [`conjugate_gradients`] preconditioned by `precondition` (`z = M⁻¹ r`, symmetric) in
/// place of the diagonal where given.
fn conjugate_gradients_with(
    apply: impl Fn(&[f64]) -> Vec<f64>,
    diag: &[f32],
    precondition: Option<&Preconditioner>,
    b: &[f64],
    valid: &[bool],
    max_iter: usize,
    tol: f64,
) -> Vec<f64> {
    let n = b.len();
    // The diagonal's inverse, where it preconditions.
    let inv: Vec<f64> = diag
        .iter()
        .take(if precondition.is_none() { n } else { 0 })
        .zip(valid)
        .map(|(&d, &v)| {
            if v && d > 0.0 {
                1.0 / f64::from(d)
            } else {
                0.0
            }
        })
        .collect();
    let mut x = vec![0.0; n];
    let mut r = b.to_vec();
    let mut z: Vec<f64> = match precondition {
        Some(m) => m(&r),
        None => r.iter().zip(&inv).map(|(r, m)| r * m).collect(),
    };
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let target = tol * tol * dot(&r, &r);
    if target == 0.0 {
        return x;
    }
    for _ in 0..max_iter {
        let ap = apply(&p);
        let pap = dot(&p, &ap);
        if pap <= 0.0 || !pap.is_finite() {
            break;
        }
        let alpha = rz / pap;
        // x += αp and r −= αAp, and ‖r‖² summed as `dot` sums it, in one pass.
        let rr = chunk_sums(
            x.par_chunks_mut(DOT_CHUNK)
                .zip(r.par_chunks_mut(DOT_CHUNK))
                .zip(p.par_chunks(DOT_CHUNK).zip(ap.par_chunks(DOT_CHUNK)))
                .map(|((x, r), (p, ap))| {
                    x.iter_mut().zip(p).for_each(|(xi, pi)| *xi += alpha * pi);
                    r.iter_mut().zip(ap).for_each(|(ri, ai)| *ri -= alpha * ai);
                    r.iter().map(|v| v * v).sum::<f64>()
                }),
        );
        if rr <= target {
            break;
        }
        let rz_new = if let Some(m) = precondition {
            z = m(&r);
            dot(&r, &z)
        } else {
            // z = M⁻¹r, and r·z summed as `dot` sums it, in one pass.
            chunk_sums(
                z.par_chunks_mut(DOT_CHUNK)
                    .zip(r.par_chunks(DOT_CHUNK).zip(inv.par_chunks(DOT_CHUNK)))
                    .map(|(z, (r, m))| {
                        z.iter_mut()
                            .zip(r.iter().zip(m))
                            .for_each(|(zi, (ri, mi))| *zi = ri * mi);
                        r.iter().zip(z.iter()).map(|(p, q)| p * q).sum::<f64>()
                    }),
            )
        };
        let beta = rz_new / rz;
        rz = rz_new;
        p.par_iter_mut()
            .zip(&z)
            .for_each(|(pi, zi)| *pi = zi + beta * *pi);
    }
    x
}

/// Right-hand side contributions from the clusters: `Σ_c ω_c B_i(p_c) (τ − coarse_c)`.
fn add_screening_targets(op: &Op, r: &mut [f64]) {
    for_each_node(op.level, r, |n, nbrs, rn| {
        let i = op.index(n);
        if !op.tab.range.contains(i) {
            return;
        }
        op.for_each_cluster(nbrs, n, i, |c, bv| {
            *rn += op.cl.omega[c as usize] * bv * TAU;
        });
    });
}

/// Wall times of the parts of a solve, with the peak memory after each (see [`Solution::timings`]).
pub struct Laps {
    clock: std::time::Instant,
    timings: Vec<(String, std::time::Duration, Option<u64>)>,
}

impl Default for Laps {
    fn default() -> Self {
        Self::new()
    }
}

impl Laps {
    /// A clock started now, with no laps.
    pub fn new() -> Self {
        Laps {
            clock: std::time::Instant::now(),
            timings: Vec::new(),
        }
    }

    /// Records the time since the previous lap under `name`.
    fn lap(&mut self, name: String) {
        let peak = crate::resources::peak_rss();
        self.timings.push((name, self.clock.elapsed(), peak));
        self.clock = std::time::Instant::now();
    }

    /// Records the time since the previous lap as the parts `parts` (name and time each,
    /// measured by the caller within that span); what they leave out goes to the last.
    fn laps(&mut self, mut parts: Vec<(String, std::time::Duration)>) {
        let peak = crate::resources::peak_rss();
        let total = self.clock.elapsed();
        let counted: std::time::Duration = parts.iter().map(|p| p.1).sum();
        if let Some(last) = parts.last_mut() {
            last.1 += total.saturating_sub(counted);
        }
        self.timings
            .extend(parts.into_iter().map(|(name, time)| (name, time, peak)));
        self.clock = std::time::Instant::now();
    }
}

/// Solves the whole hierarchy (ALGORITHM.md §7): the divergence constraints of every level,
/// the base level by conjugate gradients, then level by level the right-hand side from the
/// coarser solution, Gauss–Seidel sweeps and the prolongation of the cumulative solution.
/// `v` is the splatted vector field per level (may be empty); each level's V is released as
/// soon as the cascade no longer needs it.
/// (The pipeline makes the constraints as a stage of their own and calls
/// [`solve_constrained`]; this whole solve is the tests'.)
#[cfg(test)]
pub(crate) fn solve(p: &Problem, mut v: Vec<Vec<[f32; 3]>>) -> Solution {
    (p.progress)("constraints");
    let mut laps = Laps::new();
    let tcons = constraints_releasing_v(p, &mut v);
    laps.lap("divergence constraints".into());
    solve_constrained(p, tcons, v, laps)
}

/// The divergence constraints of every level from the base up ([`constraints`]); the finest
/// level's V, which nothing after them reads, is released (`v` is made one entry per level).
pub fn constraints_releasing_v(p: &Problem, v: &mut Vec<Vec<[f32; 3]>>) -> Vec<Vec<f32>> {
    let nlev = p.tree.levels.len();
    v.resize_with(nlev, Vec::new);
    let tcons = constraints(p, v, p.base_level);
    // The finest level's V has entered the constraints; the cascade only prolongs coarser V.
    v[nlev - 1] = Vec::new();
    tcons
}

/// [`solve`] from the constraints `tcons` made by [`constraints_releasing_v`] (so that the
/// screening clusters, which the constraints do not read, need not exist while they are
/// made); the solve's parts are laps of `laps`.
pub fn solve_constrained(
    p: &Problem,
    tcons: Vec<Vec<f32>>,
    v: Vec<Vec<[f32; 3]>>,
    laps: Laps,
) -> Solution {
    if p.solver == Solver::Cascadic && p.cycles <= 1 && !p.report {
        cascade(p, tcons, v, None, false, None, laps).0
    } else {
        cycles::solve(p, tcons, v, laps)
    }
}

/// What a level hands to the next finer one in the cascade: the cumulative solution and the
/// cumulative V, both prolonged to `level`'s nodes. Slabs carry the coarse levels' solution to
/// their finer levels with it (`crate::slabs`).
#[derive(Debug, Clone, Default)]
pub struct Carry {
    /// The level the vectors live on.
    pub level: u32,
    /// The cumulative solution of all levels up to `level`, in double precision.
    pub p: Vec<f64>,
    /// The cumulative V of all levels up to `level`.
    pub vc: Vec<[f32; 3]>,
}

/// The cascade from the base level (`start` = `None`: solved by conjugate gradients) or from
/// the level after `start`'s up to the tree's deepest level. `tcons` are the divergence
/// constraints per level (from [`constraints`]), `v` the V per level. With `keep_last`, the
/// deepest level's cumulative solution and V are returned too, for a finer tree to go on from.
///
/// With `previous` (the coefficients of an earlier cycle, per level; with a `start`), the
/// pass is a cascadic cycle after the first instead ([`cycles`]' up pass): each level is
/// relaxed from its previous coefficients, against the new coarser solution and the gradient
/// coupling `U` of the finer levels' previous coefficients. A slab's finer levels take the
/// cycles this way between the whole cloud's coarse cycles ([`crate::slabs`]).
pub fn cascade(
    p: &Problem,
    mut tcons: Vec<Vec<f32>>,
    mut v: Vec<Vec<[f32; 3]>>,
    start: Option<Carry>,
    keep_last: bool,
    previous: Option<Vec<Vec<f32>>>,
    mut laps: Laps,
) -> (Solution, Option<Carry>) {
    let nlev = p.tree.levels.len();
    let max_level = nlev - 1;
    v.resize_with(nlev, Vec::new);
    let (mut previous, mut u) = match (previous, &start) {
        (Some(x), Some(c)) => {
            let u = cycles::finer_couplings(p, &x, c.level as usize + 1, |_, _| true);
            (x, u)
        }
        _ => (vec![Vec::new(); nlev], vec![Vec::new(); nlev]),
    };
    previous.resize_with(nlev, Vec::new);
    let mut sol = Solution {
        x: vec![Vec::new(); nlev],
        p: vec![Vec::new(); nlev],
        base_level: p.base_level,
        timings: Vec::new(),
        report: None,
    };
    // The cumulative solution of the previous level, kept in full precision for the cascade;
    // the stored copies (for evaluation) are single precision.
    let (first, mut p_prev, mut vc) = match start {
        Some(c) => (c.level as usize + 1, c.p, c.vc),
        None => {
            let tb = p.base_level as usize;
            (p.progress)("solving base depth");
            let p_base = solve_base(p, std::mem::take(&mut tcons[tb]));
            sol.x[tb] = to_f32(&p_base);
            sol.p[tb] = to_f32(&p_base);
            laps.lap(format!(
                "depth {}: conjugate gradients",
                tb as u32 - DEPTH_OFFSET
            ));
            // Cumulative V, prolonged level by level (stored in single precision).
            let mut vc: Vec<[f32; 3]> = std::mem::take(&mut v[tb]);
            if vc.is_empty() {
                vc = vec![[0.0; 3]; p.tree.levels[tb].len()];
            }
            (tb + 1, p_base, vc)
        }
    };
    for t in first..=max_level {
        let dd = t as u32 - DEPTH_OFFSET;
        (p.progress)(&format!("solving depth {dd}"));
        let op = Op::new(p, t as u32);
        let u_t = u.get_mut(t).map(std::mem::take).unwrap_or_default();
        let r = right_hand_side(
            &op,
            p.fem,
            std::mem::take(&mut tcons[t]),
            &p_prev,
            &vc,
            &u_t,
        );
        drop(u_t);
        let carry_on = t < max_level || keep_last;
        if !carry_on {
            // The coarser V has entered the right-hand side for the last time.
            vc = Vec::new();
        }
        laps.lap(format!("depth {dd}: right-hand side"));
        let mut x = std::mem::take(&mut previous[t]);
        let iters = if x.len() == op.level.len() {
            p.iters
        } else {
            x = written_zeros(op.level.len());
            p.first_iters(t)
        };
        op.gauss_seidel(&r, &mut x, iters);
        drop(r);
        laps.lap(format!("depth {dd}: Gauss-Seidel"));
        // Cumulative solution and V at this level, for the next level. The deepest level
        // needs neither (evaluation reads a leaf's parent's cumulative solution).
        if carry_on {
            if !keep_last && deepest_reads_little(&op) {
                sol.p[t] = prolong_solution_f32(&op, &p_prev, &x);
                p_prev = prolong_solution_for_deepest(&op, &p_prev, &x);
            } else {
                let cum = prolong_solution(&op, &p_prev, &x);
                sol.p[t] = to_f32(&cum);
                p_prev = cum;
            }
            vc = prolong_field(&op, &vc, std::mem::take(&mut v[t]));
        }
        sol.x[t] = x;
        laps.lap(format!("depth {dd}: prolongation"));
    }
    sol.timings = laps.timings;
    let carry = keep_last.then_some(Carry {
        level: max_level as u32,
        p: p_prev,
        vc,
    });
    (sol, carry)
}

/// The down pass of a V-cycle on the levels after `from.level` (a slab's finer levels,
/// [`crate::slabs`]), as [`cycles`] makes it: from the deepest level down, each level relaxed
/// from its coefficients `x` against the coarser cumulative solution before the pass (`from`
/// and `x` prolonged), and the gradient coupling of the finer levels' relaxed coefficients.
/// `tcons` are the levels' divergence constraints and `v` their V (both as [`cascade`] takes
/// them; only the levels between `from.level` and the deepest level's parent are read of `v`).
pub fn relax_down(
    p: &Problem,
    tcons: &[Vec<f32>],
    v: &[Vec<[f32; 3]>],
    from: &Carry,
    x: &mut [Vec<f32>],
) {
    let nlev = p.tree.levels.len();
    let first = from.level as usize + 1;
    if first >= nlev {
        return;
    }
    let max = nlev - 1;
    let ops: Vec<Option<Op>> = (0..nlev)
        .map(|t| (t >= first).then(|| Op::new(p, t as u32)))
        .collect();
    let op = |t: usize| ops[t].as_ref().expect("levels after the carry");
    // The cumulative solution and V of every level from the carry's up to the deepest's
    // parent, before the pass.
    let mut pcum = vec![Vec::new(); nlev];
    let mut vcum = vec![Vec::new(); nlev];
    pcum[first - 1] = from.p.clone();
    vcum[first - 1] = from.vc.clone();
    for t in first..max {
        pcum[t] = prolong_solution(op(t), &pcum[t - 1], &x[t]);
        let vt = v.get(t).cloned().unwrap_or_default();
        vcum[t] = prolong_field(op(t), &vcum[t - 1], vt);
    }
    let mut u: Vec<f64> = Vec::new();
    for t in (first..=max).rev() {
        let r = right_hand_side(
            op(t),
            p.fem,
            tcons[t].clone(),
            &pcum[t - 1],
            &vcum[t - 1],
            &u,
        );
        op(t).gauss_seidel(&r, &mut x[t], p.iters);
        if t > first {
            u = cycles::coupling_below_of(p, op(t), &x[t], &u);
        }
    }
}

/// The cumulative solutions `P_t` of the levels after `from.level` (but the deepest), from
/// `from.p` and the levels' own coefficients `x`: what evaluation reads besides `x`.
pub fn cumulate(p: &Problem, from: &Carry, x: &[Vec<f32>]) -> Vec<Vec<f32>> {
    let nlev = p.tree.levels.len();
    let mut out = vec![Vec::new(); nlev];
    let mut p_prev = from.p.clone();
    for t in from.level as usize + 1..nlev - 1 {
        let op = Op::new(p, t as u32);
        let cum = prolong_solution(&op, &p_prev, &x[t]);
        out[t] = to_f32(&cum);
        p_prev = cum;
    }
    out
}

/// The divergence constraints of every level from `lowest` up, computed fine to coarse and
/// stored in single precision (summed in double precision); empty below `lowest`. On the
/// problem's GPU where it has one (the same bits), else, or where that fails, on the CPU.
pub fn constraints(p: &Problem, v: &[Vec<[f32; 3]>], lowest: u32) -> Vec<Vec<f32>> {
    #[cfg(feature = "gpu")]
    if let Some(tcons) = device::constraints_gpu(p, v, lowest) {
        return tcons;
    }
    let nlev = p.tree.levels.len();
    let max_level = nlev - 1;
    let mut tcons: Vec<Vec<f32>> = vec![Vec::new(); nlev];
    let mut g_finer: Vec<f64> = Vec::new();
    let empty: Vec<[f32; 3]> = Vec::new();
    for t in (lowest as usize..=max_level).rev() {
        let tab = p.tables[t].as_ref().expect("tables");
        let v_t = v.get(t).unwrap_or(&empty);
        let v_finer = v.get(t + 1).unwrap_or(&empty);
        let gf = (t < max_level).then_some(g_finer.as_slice());
        let (g, b) = divergence_constraints(p.tree, t as u32, tab, p.fem, v_t, v_finer, gf);
        g_finer = g;
        tcons[t] = b;
    }
    tcons
}

/// The base level's coefficients: its system, assembled (or applied matrix-free when large),
/// solved by Jacobi-preconditioned conjugate gradients. `tcons` are the level's divergence
/// constraints.
fn solve_base(p: &Problem, tcons: Vec<f32>) -> Vec<f64> {
    let base = BaseSystem::new(p);
    let b = base.right_hand_side(tcons);
    base.solve(&b)
}

/// The base level's system, ready to be solved for any right-hand side.
struct BaseSystem<'a> {
    op: Op<'a>,
    valid: Vec<bool>,
    diag: Vec<f32>,
    /// The assembled matrix; `None` for a base level solved matrix-free.
    matrix: Option<BaseMatrix>,
    /// The V-cycle that preconditions the conjugate gradients (`None`: the diagonal does).
    multigrid: Option<BaseMultigrid>,
}

impl<'a> BaseSystem<'a> {
    fn new(p: &'a Problem) -> Self {
        let op = Op::new(p, p.base_level);
        let valid: Vec<bool> = (0..op.level.len() as u32)
            .map(|n| op.tab.range.contains(op.index(n)))
            .collect();
        // A base level of up to 2^18 nodes (depth 5: 46,656) is assembled once; larger ones
        // (a deep --full-depth) are applied matrix-free to bound memory.
        let diag = op.diagonal();
        let matrix = (op.level.len() <= 1 << 18).then(|| op.base_matrix(&valid));
        let index: Vec<Option<[i64; 3]>> = (0..op.level.len() as u32)
            .map(|n| valid[n as usize].then(|| op.index(n)))
            .collect();
        let multigrid = BaseMultigrid::new(p.fem, op.d, &index, &diag, op.cl, op.singular);
        BaseSystem {
            op,
            valid,
            diag,
            matrix,
            multigrid,
        }
    }

    /// The divergence constraints plus the screening targets, made consistent when the
    /// system is singular.
    fn right_hand_side(&self, tcons: Vec<f32>) -> Vec<f64> {
        let mut b: Vec<f64> = tcons.iter().map(|&x| f64::from(x)).collect();
        drop(tcons);
        add_screening_targets(&self.op, &mut b);
        if self.singular() {
            remove_mean(&mut b, &self.valid);
        }
        b
    }

    fn singular(&self) -> bool {
        self.op.singular
    }

    /// Conjugate gradients from zero to a relative residual of 1e-7.
    fn solve(&self, b: &[f64]) -> Vec<f64> {
        self.solve_to(b, 1e-7)
    }

    /// Conjugate gradients from zero to a relative residual of `tol`.
    fn solve_to(&self, b: &[f64], tol: f64) -> Vec<f64> {
        let apply = |x: &[f64]| self.apply(x);
        let vcycle = self
            .multigrid
            .as_ref()
            .map(|mg| move |r: &[f64]| mg.precondition(&apply, r));
        let pre = vcycle.as_ref().map(|v| v as &Preconditioner);
        conjugate_gradients_with(apply, &self.diag, pre, b, &self.valid, 3000, tol)
    }

    /// `A x`.
    fn apply(&self, x: &[f64]) -> Vec<f64> {
        match &self.matrix {
            Some(a) => a.apply(x),
            None => self.op.apply(x, &self.valid),
        }
    }
}

/// Projects the constant null vector out of `b` (over the valid entries), so that a system
/// with constants in its kernel is consistent.
fn remove_mean(b: &mut [f64], valid: &[bool]) {
    let cnt = valid.iter().filter(|&&v| v).count().max(1) as f64;
    let mean = b
        .iter()
        .zip(valid)
        .filter(|(_, &v)| v)
        .map(|(x, _)| *x)
        .sum::<f64>()
        / cnt;
    for (bi, &v) in b.iter_mut().zip(valid) {
        if v {
            *bi -= mean;
        }
    }
}

/// The right-hand side of a level above the base, stored in single precision: its own
/// constraints `tcons`, plus the coarser V (`vc`, cumulative, on the parent level), minus
/// what the coarser solution (`pc`, cumulative, on the parent level) already meets, plus the
/// screening targets `Σ_c ω_c B_i(p_c) (τ − χ_{<d}(p_c))`, minus the finer levels' gradient
/// coupling `u` (empty for none: the cascade's first pass). Written over `tcons`.
fn right_hand_side(
    op: &Op,
    fem: Basis,
    mut tcons: Vec<f32>,
    pc: &[f64],
    vc: &[[f32; 3]],
    u: &[f64],
) -> Vec<f32> {
    #[cfg(feature = "gpu")]
    if u.is_empty() {
        if let Some((r, _)) = op.first_right_hand_sides_gpu(&tcons, pc, vc, false) {
            return r;
        }
    }
    let coarse_chi = coarse_cluster_values(op, fem, pc);
    let with_v = broods_with_v(vc);
    // Each row reads only its own constraint: the right-hand side is written over them.
    tcons.par_chunks_mut(8).enumerate().for_each(|(b, rows)| {
        let nbrs = op.level.brood_row(b as u32);
        let near_v = op.coarser_v_near(b as u32, &with_v);
        for (k, row) in rows.iter_mut().enumerate() {
            let n = 8 * b as u32 + k as u32;
            let i = op.index(n);
            if !op.tab.range.contains(i) {
                *row = 0.0;
                continue;
            }
            let t = f64::from(*row);
            let [mut s, _] = op.coarse_coupling_near_v::<false>([t, 0.0], n, i, (pc, vc), near_v);
            op.for_each_cluster(&nbrs, n, i, |c, bv| {
                s += op.cl.omega[c as usize] * bv * (TAU - coarse_chi[c as usize]);
            });
            if !u.is_empty() {
                s -= u[n as usize];
            }
            *row = s as f32;
        }
    });
    tcons
}

/// The coarser solution `χ_{<d}` at each cluster of the level, from the cumulative
/// coefficients `pc` of the parent level.
fn coarse_cluster_values(op: &Op, fem: Basis, pc: &[f64]) -> Vec<f64> {
    (0..op.cl.len())
        .into_par_iter()
        .map(|c| {
            let node = op.cl.node[c];
            let par = op.tree.parent(op.t, node);
            coarse_value(op.tree, fem, op.t - 1, par, op.cl.pos[c].map(f64::from), pc)
        })
        .collect()
}

/// The cumulative solution of level `op.t`: the coarser cumulative solution `pc` prolonged,
/// plus the level's own coefficients `x`. Carried in double precision.
fn prolong_solution(op: &Op, pc: &[f64], x: &[f32]) -> Vec<f64> {
    #[cfg(feature = "gpu")]
    if let Some(out) = op.prolong_solution_gpu(pc, x) {
        return out;
    }
    prolong::<1, f64>(
        op.prolongation(),
        |q| [pc[q as usize]],
        |n| [f64::from(x[n])],
        |c| c[0],
    )
}

/// [`prolong_solution`] in single precision, as stored for evaluation: the same sums,
/// rounded as [`to_f32`] rounds them, without the level's array in double precision.
fn prolong_solution_f32(op: &Op, pc: &[f64], x: &[f32]) -> Vec<f32> {
    #[cfg(feature = "gpu")]
    if let Some(out) = op.prolong_solution_gpu(pc, x) {
        return to_f32(&out);
    }
    prolong::<1, f32>(
        op.prolongation(),
        |q| [pc[q as usize]],
        |n| [f64::from(x[n])],
        |c| c[0] as f32,
    )
}

/// Whether the cumulative solution of level `op.t`, the deepest level's parent, is made only
/// where the deepest level reads it ([`prolong_solution_for_deepest`]): where the deepest
/// level's nodes reach under half of the level's broods.
fn deepest_reads_little(op: &Op) -> bool {
    #[cfg(test)]
    if KEEP_WHOLE.load(std::sync::atomic::Ordering::Relaxed) {
        return false;
    }
    op.t as usize + 2 == op.tree.levels.len()
        && 2 * op.level.broods_near_children() < op.level.len() / 8
}

/// Tests set this to make every level's cumulative solution whole, to compare the bits.
#[cfg(test)]
static KEEP_WHOLE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// The cumulative solution of level `op.t` as the deepest level (the next) reads it: its
/// right-hand sides and screening read the parent windows of its nodes, which lie in the
/// broods whose rows hold a node with children ([`Level::row_has_children`]); zero on the
/// other broods. Where the samples hardly reach the deepest depth (issue 20: spot_1m at depth
/// 11 has 1,792 nodes there under 8.3 M at depth 10), the whole level in double precision would
/// be a tenth of the peak memory; the zeros are never written, so their pages are never
/// resident. Evaluation reads the level everywhere, in single precision
/// ([`prolong_solution_f32`]).
fn prolong_solution_for_deepest(op: &Op, pc: &[f64], x: &[f32]) -> Vec<f64> {
    prolong_broods(
        op.prolongation(),
        |q| pc[q as usize],
        |n| f64::from(x[n]),
        |b| op.level.row_has_children(b),
    )
}

/// The cumulative V of level `op.t`: the coarser cumulative V `vc` prolonged, plus the
/// level's own V `vt` (may be empty; when not, the sums are written over it).
fn prolong_field(op: &Op, vc: &[[f32; 3]], mut vt: Vec<[f32; 3]>) -> Vec<[f32; 3]> {
    #[cfg(feature = "gpu")]
    if let Some(out) = op.prolong_field_gpu(vc, &vt) {
        return out;
    }
    let at = Prolongation {
        tree: op.tree,
        t: op.t,
        weights: &op.tab.vprolong,
        range: op.tab.vrange,
    };
    if vt.len() == op.level.len() {
        prolong_in_place::<3, [f32; 3]>(
            at,
            |q| vc[q as usize].map(f64::from),
            &mut vt,
            |v| v.map(f64::from),
            |c| c.map(|x| x as f32),
        );
        return vt;
    }
    prolong::<3, [f32; 3]>(
        at,
        |q| vc[q as usize].map(f64::from),
        |n| vt.get(n).map_or([0.0; 3], |v| v.map(f64::from)),
        |c| c.map(|x| x as f32),
    )
}

/// `Σ_J coeff_J B_{d,J}(pos)` over the functions of level `t` around node `node` (which
/// contains `pos`).
pub fn coarse_value(
    tree: &Octree,
    fem: Basis,
    t: u32,
    node: u32,
    pos: [f64; 3],
    coeff: &[f64],
) -> f64 {
    let d = t - DEPTH_OFFSET;
    let level = &tree.levels[t as usize];
    let own = func_index(level.key(node), d);
    let wx = fem.window(d, pos[0]);
    let wy = fem.window(d, pos[1]);
    let wz = fem.window(d, pos[2]);
    let k = i64::from(fem.degree.get());
    let row = level.brood_row(node >> 3);
    let mut s = 0.0;
    for z in 0..=k {
        for y in 0..=k {
            for x in 0..=k {
                let o = [
                    wx.first + x - own[0],
                    wy.first + y - own[1],
                    wz.first + z - own[2],
                ];
                let m = neighbor_in_row(&row, node, window_index(o));
                if m == NONE {
                    continue;
                }
                s += wx.values[x as usize]
                    * wy.values[y as usize]
                    * wz.values[z as usize]
                    * coeff[m as usize];
            }
        }
    }
    s
}

#[cfg(all(test, feature = "gpu"))]
mod emulated;
#[cfg(test)]
mod tests;
