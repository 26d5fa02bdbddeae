//! The solver's steps on the GPU (`crate::gpu`): a level's system laid out for the kernels and
//! kept on the card for the solve, the order of [`Op::gauss_seidel_cpu`] as classes of
//! independent nodes, and the right-hand sides and relaxations run there. Each step returns
//! `None` where the level cannot be put on the card (the device keeps the reason), and the
//! caller then does it on the CPU.

use rayon::prelude::*;

use super::{Op, Problem};
use crate::bspline::{Boundary, Table1D};
use crate::gpu::{ConstraintLevel, CouplingLevel, Device, LevelShape, LevelSystem, Resident};
use crate::octree::{Level, DEPTH_OFFSET};
use crate::system::brood_tiles;

impl Op<'_> {
    /// The device and this level's system on it, copied there on first use; `None` without a
    /// device, or where the copy failed (the device records why).
    fn on_gpu(&self) -> Option<(&Device, &Resident)> {
        let dev = self.gpu?;
        let res = self.resident.get_or_init(|| {
            dev.upload(&self.level_system())
                .map_err(|reason| dev.record_failure(reason))
                .ok()
        });
        res.as_ref().map(|r| (dev, r))
    }

    /// [`Op::gauss_seidel_cpu`] on the GPU, with the same result to the last bit; `false`
    /// where it did not run there.
    pub(super) fn gauss_seidel_gpu(&self, r: &[f32], x: &mut [f32], iters: u32) -> bool {
        let Some((dev, lvl)) = self.on_gpu() else {
            return false;
        };
        dev.gauss_seidel(lvl, r, x, iters)
            .map_err(|reason| dev.record_failure(reason))
            .is_ok()
    }

    /// The cascade's right-hand sides of the level on the GPU (`cycles::right_hand_sides`, and
    /// with `fixed` false `super::right_hand_side`), bit for bit; the coarser solution at the
    /// level's clusters is made on the card from `pc`.
    pub(super) fn first_right_hand_sides_gpu(
        &self,
        tcons: &[f32],
        pc: &[f64],
        vc: &[[f32; 3]],
        fixed: bool,
    ) -> Option<(Vec<f32>, Vec<f32>)> {
        let (dev, lvl) = self.on_gpu()?;
        dev.first_right_hand_sides(lvl, tcons, pc, vc, fixed)
            .map_err(|reason| dev.record_failure(reason))
            .ok()
    }

    /// A further cycle's right-hand side of the level on the GPU
    /// (`cycles::cycle_right_hand_side`), bit for bit, the coarser solution at the clusters
    /// made on the card.
    pub(super) fn cycle_right_hand_side_gpu(
        &self,
        b: &[f32],
        pc: &[f64],
        u: &[f64],
    ) -> Option<Vec<f32>> {
        let (dev, lvl) = self.on_gpu()?;
        dev.cycle_right_hand_side(lvl, b, pc, u)
            .map_err(|reason| dev.record_failure(reason))
            .ok()
    }

    /// The level's cumulative solution on the GPU (`super::prolong_solution`), bit for bit.
    pub(super) fn prolong_solution_gpu(&self, pc: &[f64], x: &[f32]) -> Option<Vec<f64>> {
        let (dev, lvl) = self.on_gpu()?;
        dev.prolong_solution(lvl, pc, x)
            .map_err(|reason| dev.record_failure(reason))
            .ok()
    }

    /// The level's cumulative V on the GPU (`super::prolong_field`), bit for bit.
    pub(super) fn prolong_field_gpu(
        &self,
        vc: &[[f32; 3]],
        vt: &[[f32; 3]],
    ) -> Option<Vec<[f32; 3]>> {
        let (dev, lvl) = self.on_gpu()?;
        dev.prolong_field(lvl, vc, vt)
            .map_err(|reason| dev.record_failure(reason))
            .ok()
    }

    /// The finer depths' coupling of the parent level on the GPU
    /// (`cycles::coupling_below_of`, same arguments and result), bit for bit.
    pub(super) fn coupling_below_gpu(&self, p: &Problem, x: &[f32], u: &[f64]) -> Option<Vec<f64>> {
        let (dev, lvl) = self.on_gpu()?;
        dev.coupling(lvl, &self.coupling_level(p, x, u))
            .map_err(|reason| dev.record_failure(reason))
            .ok()
    }

    /// The finer depths' coupling of the parent level as the kernels read it.
    pub(super) fn coupling_level<'b>(
        &'b self,
        p: &'b Problem,
        x: &'b [f32],
        u: &'b [f64],
    ) -> CouplingLevel<'b> {
        let mut runs = Vec::new();
        let mut run_ends = Vec::with_capacity(8);
        for tiles in super::cycles::push_tiles(self) {
            runs.extend(tiles.iter().map(|r| [r.start, r.end]));
            run_ends.push(runs.len());
        }
        let t = self.t as usize - 1;
        let range = p.tables[t]
            .as_ref()
            .expect("tables exist at solved levels")
            .range;
        let parent = &self.tree.levels[t];
        let d = self.d - 1;
        let (child_count, child_index, child_weight) = child_tables(p, d, range.lo, range.hi);
        CouplingLevel {
            runs,
            run_ends,
            x,
            parent: level_shape(parent, d, range.lo, range.hi),
            children: parent.children(),
            child_count,
            child_index,
            child_weight,
            u,
        }
    }

    /// The level's system as the kernels read it.
    pub(super) fn level_system(&self) -> LevelSystem<'_> {
        let (lo, hi) = (self.tab.range.lo, self.tab.range.hi);
        let row = |t: &Table1D| table_rows(t, lo, hi);
        let (rank_bits, rank_before) = self.cl.of_node.words();
        let (order, class_ends) = self.relaxation_classes();
        let parent = &self.tree.levels[self.t as usize - 1];
        let mut nonzero_start = vec![0u32];
        let mut nonzero = Vec::new();
        for list in &self.tab.pnonzero {
            nonzero.extend(list.iter().map(|&w| u32::from(w)));
            nonzero_start.push(nonzero.len() as u32);
        }
        let (mut brood_start, mut brood_slot, mut brood_coef) = (vec![0u32], vec![], vec![]);
        for row in self.brood.rows() {
            for (slot, [coef]) in row {
                brood_slot.push(u32::from(*slot));
                brood_coef.extend_from_slice(coef);
            }
            brood_start.push(brood_slot.len() as u32);
        }
        LevelSystem {
            degree: self.degree,
            shape: level_shape(self.level, self.d, lo, hi),
            stencil: &self.tab.stencil,
            brood_start,
            brood_slot,
            brood_coef,
            mass: row(&self.tab.mass),
            stiff: row(&self.tab.stiff),
            rank_bits,
            rank_before,
            omega: &self.cl.omega,
            first: self.cl.first_indices(self.level, self.d).into(),
            vals: self.cl.values_3x3().into(),
            cl_node: &self.cl.node,
            pos: self.cl.pos.iter().map(|p| p.map(f64::from)).collect(),
            boundary: match self.boundary {
                Boundary::Free => 0,
                Boundary::Neumann => 1,
                Boundary::Dirichlet => 2,
            },
            brood_parent: &self.level.brood_parent,
            parent_nbrs: parent.brood_rows(),
            parent_nbrs_id: parent.brood_rows_identity(),
            parent_keys: parent.brood_keys(),
            pstencil: &self.tab.pstencil,
            pvstencil: &self.tab.pvstencil,
            nonzero_start,
            nonzero,
            prolong: self.tab.prolong.rows(),
            vprolong: self.tab.vprolong.rows(),
            vrange: (self.tab.vrange.lo, self.tab.vrange.hi),
            pmass: row(&self.tab.pmass),
            pstiff: row(&self.tab.pstiff),
            pvmass: row(&self.tab.pvmass),
            pvderiv: row(&self.tab.pvderiv),
            order,
            class_ends,
        }
    }

    /// The nodes with a function, grouped as the CPU sweep visits them: by block colour, then
    /// by node colour (see [`Op::gauss_seidel_cpu`]). Within a class the order is free: its
    /// nodes share no coefficient and no cluster, so they can be relaxed at once.
    fn relaxation_classes(&self) -> (Vec<u32>, Vec<usize>) {
        let blocks = self.colour_blocks();
        let colours = self.node_colours() as usize;
        let mut order = Vec::with_capacity(self.level.len());
        let mut ends = Vec::with_capacity(8 * colours);
        for list in &blocks {
            // Per node colour, this block colour's nodes, gathered in parallel over blocks.
            let per_block: Vec<Vec<Vec<u32>>> = list
                .par_iter()
                .map(|&(b0, b1)| {
                    let mut by_colour = vec![Vec::new(); colours];
                    for n in 8 * b0..8 * b1 {
                        let i = self.index(n);
                        if self.tab.range.contains(i) {
                            by_colour[self.node_colour(n, i) as usize].push(n);
                        }
                    }
                    by_colour
                })
                .collect();
            for c in 0..colours {
                for b in &per_block {
                    order.extend_from_slice(&b[c]);
                }
                ends.push(order.len());
            }
        }
        (order, ends)
    }

    /// The colour of node `n` (function index `i`): see [`Op::gauss_seidel_cpu`], whose
    /// sweep finds the node of each colour per brood with [`Op::child_of_colour`].
    #[inline]
    fn node_colour(&self, n: u32, i: [i64; 3]) -> u32 {
        if self.degree == 1 {
            n & 7
        } else {
            let m = i64::from(self.degree) + 1;
            (i[0].rem_euclid(m) + m * (i[1].rem_euclid(m) + m * i[2].rem_euclid(m))) as u32
        }
    }
}

/// The nodes of `level` (unit depth `d`, function indices `lo..=hi`) as the kernels read them.
fn level_shape(level: &Level, d: u32, lo: i64, hi: i64) -> LevelShape<'_> {
    LevelShape {
        depth: d,
        nodes: level.len(),
        brood_nbrs: level.brood_rows(),
        brood_nbrs_id: level.brood_rows_identity(),
        brood_key: level.brood_keys(),
        lo,
        hi,
    }
}

/// A 1-D table's rows `lo..=hi`, five offsets `−2..=2` each, as the kernels read them.
fn table_rows(t: &Table1D, lo: i64, hi: i64) -> Vec<f64> {
    (lo..=hi)
        .flat_map(|i| (-2..=2).map(move |o| t.get(i, o)))
        .collect()
}

/// The divergence constraints of every level from `lowest` up on the GPU
/// (`super::constraints`, same arguments and result), bit for bit. Each level's V and `G`
/// stay on the card for the next coarser level; only the constraints come back. `None`
/// without a device, or where a level failed there (the device keeps the reason; the caller
/// then makes them all on the CPU, which needs the `G` that stayed on the card).
pub(super) fn constraints_gpu(
    p: &Problem,
    v: &[Vec<[f32; 3]>],
    lowest: u32,
) -> Option<Vec<Vec<f32>>> {
    let dev = p.gpu?;
    dev.forget_tables();
    let nlev = p.tree.levels.len();
    let mut tcons: Vec<Vec<f32>> = vec![Vec::new(); nlev];
    let mut finer = None;
    let empty = Vec::new();
    for t in (lowest as usize..nlev).rev() {
        let v_t = v.get(t).unwrap_or(&empty);
        let v_finer = v.get(t + 1).unwrap_or(&empty);
        let sys = constraint_level(p, t as u32, v_t, v_finer, None);
        let (b, on_card) = dev
            .constraints(&sys, finer.take())
            .map_err(|reason| dev.record_failure(reason))
            .ok()?;
        tcons[t] = b;
        finer = Some(on_card);
    }
    Some(tcons)
}

/// Level `t`'s constraints as the kernels read them.
pub(super) fn constraint_level<'a>(
    p: &'a Problem,
    t: u32,
    v: &'a [[f32; 3]],
    v_finer: &'a [[f32; 3]],
    g_finer: Option<&'a [f64]>,
) -> ConstraintLevel<'a> {
    let tab = p.tables[t as usize]
        .as_ref()
        .expect("tables exist at solved levels");
    let level = &p.tree.levels[t as usize];
    let next = p.tree.levels.get(t as usize + 1);
    let d = t - DEPTH_OFFSET;
    let (lo, hi) = (tab.range.lo, tab.range.hi);
    let (child_count, child_index, child_weight) = child_tables(p, d, lo, hi);
    // As the CPU: the next level's V is pushed when there is a next level and V on it.
    let push = next.is_some() && !v_finer.is_empty();
    let (mut push_runs, mut push_run_ends) = (Vec::new(), Vec::new());
    if let (true, Some(next)) = (push, next) {
        for tiles in brood_tiles(level, next) {
            push_runs.extend(tiles.iter().map(|r| [r.start, r.end]));
            push_run_ends.push(push_runs.len());
        }
    }
    let (coarse_lo, cvmass) = tab.cvmass.rows();
    ConstraintLevel {
        shape: level_shape(level, d, lo, hi),
        vmass: table_rows(&tab.vmass, lo, hi),
        vderiv: table_rows(&tab.vderiv, lo, hi),
        children: level.children(),
        child_count,
        child_index,
        child_weight,
        coarse_lo,
        cvmass,
        cvderiv: tab.cvderiv.rows().1,
        next_parent: next.map_or(&[], |n| &n.brood_parent),
        push_runs,
        push_run_ends,
        push,
        v,
        v_finer,
        g_finer: g_finer.filter(|g| !g.is_empty()),
    }
}

/// The two-scale children of every function index `lo..=hi` at unit depth `d`
/// (`Basis::children`), as `restrict_one` reads them on the card: per index how many, and
/// four slots of (index, weight).
fn child_tables(p: &Problem, d: u32, lo: i64, hi: i64) -> (Vec<u32>, Vec<i64>, Vec<f64>) {
    let (mut count, mut index, mut weight) = (vec![], vec![], vec![]);
    for i in lo..=hi {
        let mut out = [(0i64, 0.0f64); 4];
        count.push(p.fem.children(d, i, &mut out) as u32);
        index.extend(out.iter().map(|c| c.0));
        weight.extend(out.iter().map(|c| c.1));
    }
    (count, index, weight)
}
