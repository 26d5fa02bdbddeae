//! Multigrid cycles over the depths (issue 18; ALGORITHM.md §7.4).
//!
//! The cascade (§7.1) solves each depth once, against the coarser depths' solution, and never
//! looks back: what a depth's Gauss–Seidel sweeps leave unsolved stays unsolved. The cycles
//! solve one system over all depths at once, the hierarchical system
//!
//! ```text
//! (L_d + S_d) x_d = b_d − A_{d,<d} x_{<d} − L_{d,>d} x_{>d}     for every depth d ≥ base
//! ```
//!
//! where `b_d − A_{d,<d} x_{<d}` is the cascade's right-hand side (the coarser solution's
//! gradient coupling and its screening at the depth's clusters) and `L_{d,>d} x_{>d}` is the
//! gradient coupling with the finer depths, `U_d[i] = Σ_{j finer} ∫∇B_i·∇B_j x_j`. The
//! gradient term of the energy couples every pair of depths both ways; the screening stays as
//! the cascade has it: depth `d`'s clusters screen the partial sum `χ_{≤d}`. With no finer
//! solution (`U = 0`) the system's first pass is the cascade itself.
//!
//! `U_d` is gathered fine to coarse: the next depth's solution pushed through the parent
//! stiffness stencils (the transpose of the cascade's pull), plus the restriction of `U_{d+1}`
//! by the two-scale relation, which is exact because the conforming windows guarantee every
//! child function such a finer solution touches (the same argument as for the divergence
//! constraints of V two depths finer, `system::divergence_constraints`).
//!
//! A cycle after the first: going down, each depth is relaxed (V and W; not cascadic) and its
//! `U` handed to the next coarser depth; the base depth is solved by conjugate gradients;
//! going up, each depth is relaxed against the new coarser solution and its cumulative
//! solution prolonged. A W-cycle visits the coarser depths twice from every depth above the
//! base's next.

use rayon::prelude::*;

use super::{
    coarse_cluster_values, deepest_reads_little, prolong_field, prolong_solution,
    prolong_solution_f32, prolong_solution_for_deepest, remove_mean, to_f32, BaseSystem, Carry,
    Laps, Op, Problem, Solution, TAU,
};
use crate::octree::{for_each_node, map_nodes, DEPTH_OFFSET};
use crate::shared_slice::written_zeros;
use crate::system::{restrict_one, DepthTables, PlainLanes};
use crate::Solver;

/// The relative residual of one depth's equations around one relaxation (or the base solve):
/// `‖r − A x‖ / ‖r‖` for the right-hand side `r` the depth was relaxed against.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthResidual {
    /// The cycle, from 1.
    pub cycle: u32,
    /// The unit depth.
    pub depth: u32,
    /// `"down"`, `"up"` or `"base"`.
    pub phase: &'static str,
    /// Before the relaxation.
    pub before: f64,
    /// After it.
    pub after: f64,
}

/// The residuals of a solve ([`crate::Params::report_residuals`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SolveReport {
    /// The shape of the cycles.
    pub solver: Solver,
    /// Gauss–Seidel sweeps per relaxation.
    pub iters: u32,
    /// Gauss–Seidel sweeps of the deepest depth's first relaxation.
    pub first_deepest_iters: u32,
    /// Every relaxation in order.
    pub depths: Vec<DepthResidual>,
    /// After each cycle, the relative residual of the whole hierarchical system,
    /// `‖b − M x‖ / ‖b‖` over every depth's equations (see the module's documentation).
    pub after_cycle: Vec<f64>,
    /// After each cycle, the work so far: Gauss–Seidel sweeps × nodes, over the depths above
    /// the base.
    pub work: Vec<f64>,
    /// After each cycle, the solve's wall time so far without the residuals' measurement,
    /// in seconds (the divergence constraints not included).
    pub seconds: Vec<f64>,
}

/// The parts of a cycle after the first, timed for the profile (`-v`).
/// The residuals' measurement (with `--residuals` only) is last: it takes what the others leave out.
const PARTS: [&str; 6] = [
    "finer coupling",
    "base depth",
    "right-hand sides",
    "Gauss-Seidel",
    "prolongation",
    "residuals",
];
const COUPLING: usize = 0;
const BASE: usize = 1;
const RHS: usize = 2;
const SWEEPS: usize = 3;
const PROLONG: usize = 4;

/// The state of the cycles: per level, the fixed right-hand side, the solution, the
/// cumulative solution and the finer depths' coupling.
struct Cycles<'a> {
    p: &'a Problem<'a>,
    /// Operators of the levels above the base (`None` at and below it).
    ops: Vec<Option<Op<'a>>>,
    base: BaseSystem<'a>,
    tb: usize,
    max: usize,
    /// `b_d` of the levels above the base: the constraints, the coarser V and the screening
    /// targets (everything the solution does not change).
    b: Vec<Vec<f32>>,
    /// The base level's right-hand side without the finer coupling.
    b_base: Vec<f64>,
    /// Solution of the levels above the base.
    x: Vec<Vec<f32>>,
    /// Solution of the base level.
    x_base: Vec<f64>,
    /// Cumulative solution of each level below the deepest.
    pcum: Vec<Vec<f64>>,
    /// `U_t`, the finer depths' gradient coupling, of each level below the deepest.
    u: Vec<Vec<f64>>,
    /// Whether the deepest level's parent keeps its cumulative solution only where the deepest
    /// level reads it ([`prolong_solution_for_deepest`]): in one piece, where nothing else
    /// reads it (the slabs' carry and parts read it whole).
    sparse_top: bool,
    /// Whether this is the last cycle of a solve that keeps no state after it (in one piece,
    /// no residuals reported, not W-cycles): each level's fixed part `b` is then last read
    /// by its relaxation going up, which writes its right-hand side over it.
    last_use: bool,
    report: Option<SolveReport>,
    /// Time spent in this cycle on each of [`PARTS`].
    parts: [std::time::Duration; PARTS.len()],
    cycle: u32,
    work: f64,
    /// Time spent measuring residuals, left out of the report's seconds.
    measuring: std::time::Duration,
    started: std::time::Instant,
}

/// Solves the hierarchy with [`Problem::cycles`] cycles of shape [`Problem::solver`], the
/// first being the cascade (bit for bit: the same arithmetic as [`super::cascade`]).
pub(super) fn solve(
    p: &Problem,
    mut tcons: Vec<Vec<f32>>,
    mut v: Vec<Vec<[f32; 3]>>,
    mut laps: Laps,
) -> Solution {
    let nlev = p.tree.levels.len();
    let tb = p.base_level as usize;
    let max = nlev - 1;
    v.resize_with(nlev, Vec::new);
    (p.progress)("solving base depth");
    let base = BaseSystem::new(p);
    let b_base = base.right_hand_side(std::mem::take(&mut tcons[tb]));
    let mut c = Cycles::empty(p, b_base, base);
    c.sparse_top = max > tb + 1 && deepest_reads_little(c.op(max - 1));
    c.report = p.report.then(|| SolveReport {
        solver: p.solver,
        iters: p.iters,
        first_deepest_iters: p.first_deepest_iters,
        ..SolveReport::default()
    });
    // The first cycle is timed by parts, with the cascade's names (issue 20's profile).
    c.first_pass(tcons, v, &mut laps, false);
    c.end_cycle();
    for k in 2..=p.cycles.max(1) {
        if max == tb {
            break;
        }
        c.cycle = k;
        c.last_use = k == p.cycles && c.report.is_none() && p.solver != Solver::WCycle;
        (p.progress)(&format!("solver cycle {k}"));
        c.parts = [std::time::Duration::ZERO; PARTS.len()];
        c.cycle_from(max);
        c.end_cycle();
        let measured = if c.report.is_some() {
            PARTS.len()
        } else {
            PARTS.len() - 1
        };
        laps.laps(
            PARTS
                .iter()
                .zip(c.parts)
                .take(measured)
                .map(|(part, time)| (format!("cycle {k}: {part}"), time))
                .collect(),
        );
    }
    let mut sol = Solution {
        x: vec![Vec::new(); nlev],
        p: vec![Vec::new(); nlev],
        base_level: p.base_level,
        timings: laps.timings,
        report: c.report.take(),
    };
    sol.x[tb] = to_f32(&c.x_base);
    sol.p[tb] = to_f32(&c.x_base);
    for t in tb + 1..=max {
        if t + 1 == max && c.sparse_top {
            // The deepest level's parent whole, from the final coarser solution (the same
            // bits as the sums kept near the deepest level).
            sol.p[t] = prolong_solution_f32(c.op(t), &c.pcum[t - 1], &c.x[t]);
        } else if t < max {
            sol.p[t] = to_f32(&c.pcum[t]);
        }
        sol.x[t] = std::mem::take(&mut c.x[t]);
    }
    sol
}

impl<'a> Cycles<'a> {
    fn op(&self, t: usize) -> &Op<'a> {
        self.ops[t].as_ref().expect("operators above the base")
    }

    /// The cascade, keeping each level's fixed right-hand side for the cycles to come; each
    /// depth's parts are laps of `laps`, as in [`super::cascade`], with the fixed right-hand
    /// side and the residual's measurement as parts of their own.
    ///
    /// With `keep_top`, the cumulative V of the deepest level is made and returned (empty
    /// otherwise), for finer levels to go on from ([`cascade_for_cycles`]).
    fn first_pass(
        &mut self,
        mut tcons: Vec<Vec<f32>>,
        mut v: Vec<Vec<[f32; 3]>>,
        laps: &mut Laps,
        keep_top: bool,
    ) -> Vec<[f32; 3]> {
        let p = self.p;
        let (tb, max) = (self.tb, self.max);
        self.x_base = self.base.solve(&self.b_base);
        if self.report.is_some() {
            let after = self.base_residual(&self.b_base.clone());
            self.record(tb, "base", 1.0, after);
        }
        laps.lap(format!(
            "depth {}: conjugate gradients",
            tb as u32 - DEPTH_OFFSET
        ));
        self.pcum[tb] = self.x_base.clone();
        let mut vc: Vec<[f32; 3]> = std::mem::take(&mut v[tb]);
        if vc.is_empty() {
            vc = vec![[0.0; 3]; p.tree.levels[tb].len()];
        }
        for t in tb + 1..=max {
            let dd = t as u32 - DEPTH_OFFSET;
            (p.progress)(&format!("solving depth {dd}"));
            let op = self.ops[t].as_ref().expect("operators above the base");
            let tc = std::mem::take(&mut tcons[t]);
            let (r, b) = right_hand_sides(op, p.fem, tc, &self.pcum[t - 1], &vc);
            if t == max && !keep_top {
                vc = Vec::new();
            }
            laps.lap(format!("depth {dd}: right-hand sides"));
            let mut x = written_zeros(op.level.len());
            let iters = p.first_iters(t);
            op.gauss_seidel(&r, &mut x, iters);
            self.work += f64::from(iters) * op.level.len() as f64;
            laps.lap(format!("depth {dd}: Gauss-Seidel"));
            if self.report.is_some() {
                let clock = std::time::Instant::now();
                let after = relative_residual(op, &r, &x);
                self.measuring += clock.elapsed();
                record(&mut self.report, 1, t, "up", 1.0, after);
                laps.lap(format!("depth {dd}: residual"));
            }
            if t < max {
                self.pcum[t] = self.cumulative(t, &x);
            }
            if t < max || keep_top {
                vc = prolong_field(op, &vc, std::mem::take(&mut v[t]));
            }
            laps.lap(format!("depth {dd}: prolongation"));
            self.b[t] = b;
            self.x[t] = x;
        }
        if keep_top {
            vc
        } else {
            Vec::new()
        }
    }

    /// One cycle over levels `tb..=t`, the finer levels' coupling `U_t` fixed.
    fn cycle_from(&mut self, t: usize) {
        if self.p.solver != Solver::Cascadic {
            self.relax(t, "down");
        }
        let clock = std::time::Instant::now();
        self.u[t - 1] = self.coupling_below(t, &self.u[t]);
        self.parts[COUPLING] += clock.elapsed();
        if t - 1 == self.tb {
            let clock = std::time::Instant::now();
            self.solve_base();
            self.parts[BASE] += clock.elapsed();
        } else {
            self.cycle_from(t - 1);
            if self.p.solver == Solver::WCycle {
                self.cycle_from(t - 1);
            }
        }
        // Level t − 1 has been relaxed against the finer coupling for the last time in this
        // cycle; the next cycle gathers it afresh.
        self.u[t - 1] = Vec::new();
        self.relax(t, "up");
        let clock = std::time::Instant::now();
        if t < self.max {
            self.pcum[t] = self.cumulative(t, &self.x[t]);
        }
        self.parts[PROLONG] += clock.elapsed();
    }

    /// The cumulative solution of level `t < max` with its coefficients `x`: whole, or for
    /// the deepest level's parent with [`Cycles::sparse_top`] only where the deepest level
    /// reads it.
    fn cumulative(&self, t: usize, x: &[f32]) -> Vec<f64> {
        if self.sparse_top && t + 1 == self.max {
            prolong_solution_for_deepest(self.op(t), &self.pcum[t - 1], x)
        } else {
            prolong_solution(self.op(t), &self.pcum[t - 1], x)
        }
    }

    /// `U_{t−1}` from level `t`'s solution and `u_t` ([`coupling_below_of`]).
    fn coupling_below(&self, t: usize, u_t: &[f64]) -> Vec<f64> {
        coupling_below_of(self.p, self.op(t), &self.x[t], u_t)
    }

    /// The right-hand side level `t` is relaxed against ([`cycle_right_hand_side`]), written
    /// over the level's fixed part when this relaxation is its last use ([`Cycles::last_use`]).
    fn level_right_hand_side(&mut self, t: usize, phase: &'static str) -> Vec<f32> {
        let b = if self.last_use && phase == "up" {
            std::mem::take(&mut self.b[t])
        } else {
            self.b[t].clone()
        };
        cycle_right_hand_side(self.op(t), self.p.fem, b, &self.pcum[t - 1], &self.u[t])
    }

    /// `iters` Gauss–Seidel sweeps on level `t` from its current solution.
    fn relax(&mut self, t: usize, phase: &'static str) {
        let clock = std::time::Instant::now();
        let r = self.level_right_hand_side(t, phase);
        self.parts[RHS] += clock.elapsed();
        let op = self.ops[t].as_ref().expect("operators above the base");
        let before = self
            .report
            .is_some()
            .then(|| relative_residual(op, &r, &self.x[t]));
        let mut x = std::mem::take(&mut self.x[t]);
        let clock = std::time::Instant::now();
        op.gauss_seidel(&r, &mut x, self.p.iters);
        self.parts[SWEEPS] += clock.elapsed();
        self.work += f64::from(self.p.iters) * op.level.len() as f64;
        if let Some(before) = before {
            let clock = std::time::Instant::now();
            let after = relative_residual(op, &r, &x);
            self.measuring += clock.elapsed();
            self.record(t, phase, before, after);
        }
        self.x[t] = x;
    }

    /// The base level solved for `b − U`.
    fn solve_base(&mut self) {
        let tb = self.tb;
        let mut b = self.b_base.clone();
        for (bi, ui) in b.iter_mut().zip(&self.u[tb]) {
            *bi -= ui;
        }
        if self.base.singular() {
            remove_mean(&mut b, &self.base.valid);
        }
        let before = self.report.is_some().then(|| self.base_residual(&b));
        // From the previous solution: conjugate gradients on the correction, to the same
        // 1e-7 of the whole right-hand side as the cascade's base solve.
        let ax = self.base.apply(&self.x_base);
        let mut r: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        if self.base.singular() {
            remove_mean(&mut r, &self.base.valid);
        }
        let (rn, bn) = (norm2(&r).sqrt(), norm2(&b).sqrt());
        if rn > 1e-7 * bn {
            let e = self.base.solve_to(&r, 1e-7 * bn / rn);
            for (x, e) in self.x_base.iter_mut().zip(&e) {
                *x += e;
            }
        }
        if let Some(before) = before {
            let after = self.base_residual(&b);
            self.record(tb, "base", before, after);
        }
        self.pcum[tb] = self.x_base.clone();
    }

    fn base_residual(&mut self, b: &[f64]) -> f64 {
        let clock = std::time::Instant::now();
        let ax = self.base.apply(&self.x_base);
        let r: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let out = (norm2(&r) / norm2(b)).sqrt();
        self.measuring += clock.elapsed();
        out
    }

    fn record(&mut self, t: usize, phase: &'static str, before: f64, after: f64) {
        record(&mut self.report, self.cycle, t, phase, before, after);
    }

    /// Records the whole system's residual, the work and the time after a cycle.
    fn end_cycle(&mut self) {
        if self.report.is_none() {
            return;
        }
        let seconds = (self.started.elapsed() - self.measuring).as_secs_f64();
        let clock = std::time::Instant::now();
        let residual = self.system_residual();
        self.measuring += clock.elapsed();
        let work = self.work;
        let r = self.report.as_mut().expect("report");
        r.after_cycle.push(residual);
        r.work.push(work);
        r.seconds.push(seconds);
    }

    /// `‖b − M x‖ / ‖b‖` over every level's equations, with the finer coupling gathered
    /// afresh from the current solution.
    fn system_residual(&self) -> f64 {
        let (tb, max) = (self.tb, self.max);
        let mut u_next: Vec<f64> = Vec::new();
        let (mut r2, mut b2) = (0.0, 0.0);
        for t in (tb + 1..=max).rev() {
            let op = self.op(t);
            let pc = &self.pcum[t - 1];
            let coarse_chi = coarse_cluster_values(op, self.p.fem, pc);
            let b = &self.b[t];
            let rhs: Vec<f64> = map_nodes(op.level, |n, nbrs| {
                let i = op.index(n);
                if !op.tab.range.contains(i) {
                    return 0.0;
                }
                let b = f64::from(b[n as usize]);
                let mut s = op.add_coarse_coupling::<true, false>(b, n, i, pc, &[]);
                op.for_each_cluster(nbrs, n, i, |c, bv| {
                    s -= op.cl.omega[c as usize] * bv * coarse_chi[c as usize];
                });
                if !u_next.is_empty() {
                    s -= u_next[n as usize];
                }
                s
            });
            r2 += residual_squared(op, &rhs, &self.x[t]);
            b2 += norm2(&b.iter().map(|&x| f64::from(x)).collect::<Vec<_>>());
            u_next = self.coupling_below(t, &u_next);
        }
        let mut b = self.b_base.clone();
        for (bi, ui) in b.iter_mut().zip(&u_next) {
            *bi -= ui;
        }
        let ax = self.base.op.apply(&self.x_base, &self.base.valid);
        let mut r: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        if self.base.singular() {
            remove_mean(&mut r, &self.base.valid);
        }
        r2 += norm2(&r);
        b2 += norm2(&self.b_base);
        (r2 / b2).sqrt()
    }
}

/// `U_{t−1}`, the gradient coupling of the levels from `op`'s level `t` on with the functions
/// of level `t − 1`: level `t`'s coefficients `x_t` pushed through the parent stencils, plus
/// `u_t` (the coupling of the levels finer than `t`; empty for none) restricted.
pub(super) fn coupling_below_of(p: &Problem, op: &Op, x_t: &[f32], u_t: &[f64]) -> Vec<f64> {
    #[cfg(feature = "gpu")]
    if let Some(g) = op.coupling_below_gpu(p, x_t, u_t) {
        return g;
    }
    let mut g = push_to_parents(op, x_t);
    if !u_t.is_empty() {
        let tree = p.tree;
        let t = op.t as usize;
        let coarse = &tree.levels[t - 1];
        let d = (t - 1) as u32 - DEPTH_OFFSET;
        let range = p.tables[t - 1].as_ref().expect("tables").range;
        g.par_iter_mut().enumerate().for_each(|(n, gn)| {
            let i = crate::octree::func_index(coarse.key(n as u32), d);
            if range.contains(i) {
                *gn += restrict_one(tree, coarse, op.level, p.fem, d, n as u32, i, u_t);
            }
        });
    }
    g
}

/// `U_t` of every level `t` from `lowest` up (empty above the deepest level's parent and below
/// `lowest`): the gradient coupling with the finer levels' coefficients `x` (per level),
/// counting only the nodes `keep(t, node)` accepts. A slab counts its own nodes, so that the
/// slabs' couplings add up to the whole cloud's ([`crate::slabs`]).
pub(crate) fn finer_couplings(
    p: &Problem,
    x: &[Vec<f32>],
    lowest: usize,
    keep: impl Fn(usize, u32) -> bool + Sync,
) -> Vec<Vec<f64>> {
    let nlev = p.tree.levels.len();
    let mut u = vec![Vec::new(); nlev];
    for t in (lowest.max(1) + 1..nlev).rev() {
        let Some(x_t) = x.get(t).filter(|x| x.len() == p.tree.levels[t].len()) else {
            continue;
        };
        let kept: Vec<f32> = (x_t.par_iter().enumerate())
            .map(|(n, &v)| if keep(t, n as u32) { v } else { 0.0 })
            .collect();
        let op = Op::new(p, t as u32);
        let below = coupling_below_of(p, &op, &kept, &u[t]);
        u[t - 1] = below;
    }
    u
}

/// What a cycle after the first (cascadic or V) needs of a hierarchy whose deepest level is coupled
/// to finer levels solved elsewhere (the whole cloud's coarse levels under the slabs'
/// finer ones, [`crate::slabs`]): per level the fixed right-hand side and the coefficients,
/// and the cumulative V on the deepest level for the finer levels.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CycleState {
    /// `b_d` of the levels above the base (empty at and below it).
    pub b: Vec<Vec<f32>>,
    /// The base level's right-hand side without the finer coupling.
    pub b_base: Vec<f64>,
    /// The coefficients of the levels above the base (empty at and below it).
    pub x: Vec<Vec<f32>>,
    /// The base level's coefficients.
    pub x_base: Vec<f64>,
    /// The cumulative V on the deepest level.
    pub vc: Vec<[f32; 3]>,
}

impl<'a> Cycles<'a> {
    /// The cycles' state for `p` with no solution yet, the base system built.
    fn empty(p: &'a Problem<'a>, b_base: Vec<f64>, base: BaseSystem<'a>) -> Cycles<'a> {
        let nlev = p.tree.levels.len();
        let tb = p.base_level as usize;
        Cycles {
            p,
            ops: (0..nlev)
                .map(|t| (t > tb).then(|| Op::new(p, t as u32)))
                .collect(),
            base,
            tb,
            max: nlev - 1,
            b: vec![Vec::new(); nlev],
            b_base,
            x: vec![Vec::new(); nlev],
            x_base: Vec::new(),
            pcum: vec![Vec::new(); nlev],
            u: vec![Vec::new(); nlev],
            sparse_top: false,
            last_use: false,
            report: None,
            parts: [std::time::Duration::ZERO; PARTS.len()],
            cycle: 1,
            work: 0.0,
            measuring: std::time::Duration::ZERO,
            started: std::time::Instant::now(),
        }
    }

    /// The solution of the levels, with the cumulative solution of every level (the deepest's
    /// too) and the carry on the deepest level.
    fn parts(&mut self, vc: Vec<[f32; 3]>) -> (Solution, Carry) {
        let (tb, max) = (self.tb, self.max);
        if max > tb {
            self.pcum[max] = prolong_solution(self.op(max), &self.pcum[max - 1], &self.x[max]);
        }
        let nlev = max + 1;
        let mut sol = Solution {
            x: vec![Vec::new(); nlev],
            p: vec![Vec::new(); nlev],
            base_level: self.p.base_level,
            timings: Vec::new(),
            report: None,
        };
        sol.x[tb] = to_f32(&self.x_base);
        for t in tb..=max {
            sol.p[t] = to_f32(&self.pcum[t]);
            if t > tb {
                sol.x[t] = self.x[t].clone();
            }
        }
        let carry = Carry {
            level: max as u32,
            p: self.pcum[max].clone(),
            vc,
        };
        (sol, carry)
    }

    fn state(self, vc: Vec<[f32; 3]>) -> CycleState {
        CycleState {
            b: self.b,
            b_base: self.b_base,
            x: self.x,
            x_base: self.x_base,
            vc,
        }
    }
}

/// The cascade of `p` kept for the cycles after it ([`cycle_below`]): the same solution as
/// [`super::cascade`] with `keep_last` (bit for bit), the carry on the deepest level, and the
/// state the cycles need. `v` is the V per level, its deepest level's included (it is
/// prolonged into the carry).
pub fn cascade_for_cycles(
    p: &Problem,
    mut tcons: Vec<Vec<f32>>,
    mut v: Vec<Vec<[f32; 3]>>,
) -> (Solution, Carry, CycleState) {
    let nlev = p.tree.levels.len();
    let tb = p.base_level as usize;
    v.resize_with(nlev, Vec::new);
    let base = BaseSystem::new(p);
    let b_base = base.right_hand_side(std::mem::take(&mut tcons[tb]));
    let mut c = Cycles::empty(p, b_base, base);
    let vc = c.first_pass(tcons, v, &mut Laps::new(), true);
    let (sol, carry) = c.parts(vc.clone());
    (sol, carry, c.state(vc))
}

/// A cycle after the first over the levels of `p` (cascadic, or a V-cycle that relaxes each
/// level going down too), whose deepest level is coupled to finer levels solved elsewhere: `u_top` is their gradient coupling `U` on the deepest level
/// (the sum of the parts' [`finer_couplings`]). The coarser levels' `U` is gathered from it
/// and their coefficients going down, the base level solved by conjugate gradients, each level
/// relaxed going up; `state` is updated. Returns the solution and the carry on the deepest
/// level, as [`cascade_for_cycles`].
pub fn cycle_below(p: &Problem, state: &mut CycleState, u_top: Vec<f64>) -> (Solution, Carry) {
    let st = std::mem::take(state);
    let base = BaseSystem::new(p);
    let mut c = Cycles::empty(p, st.b_base, base);
    c.b = st.b;
    c.x = st.x;
    c.x_base = st.x_base;
    c.pcum[c.tb] = c.x_base.clone();
    let max = c.max;
    if p.solver != Solver::Cascadic {
        // V-cycles relax each level going down, against the coarser cumulative solution of
        // the cycle before.
        for t in c.tb + 1..max {
            c.pcum[t] = prolong_solution(c.op(t), &c.pcum[t - 1], &c.x[t]);
        }
    }
    c.u[max] = u_top;
    if max == c.tb {
        c.solve_base();
    } else {
        c.cycle_from(max);
    }
    let (sol, carry) = c.parts(st.vc.clone());
    *state = c.state(st.vc);
    (sol, carry)
}

fn record(
    report: &mut Option<SolveReport>,
    cycle: u32,
    t: usize,
    phase: &'static str,
    before: f64,
    after: f64,
) {
    if let Some(r) = report {
        r.depths.push(DepthResidual {
            cycle,
            depth: t as u32 - DEPTH_OFFSET,
            phase,
            before,
            after,
        });
    }
}

/// A level's right-hand side for the first pass, bit for bit the cascade's
/// ([`super::right_hand_side`]), and, from the same walk over the parent windows, its fixed
/// part: its constraints, the coarser V (`vc`, cumulative, on the parent level) and the
/// screening targets `Σ_c ω_c B_i(p_c) τ`, which the further cycles keep. The right-hand
/// side is written over `tcons`.
pub(super) fn right_hand_sides(
    op: &Op,
    fem: crate::bspline::Basis,
    mut tcons: Vec<f32>,
    pc: &[f64],
    vc: &[[f32; 3]],
) -> (Vec<f32>, Vec<f32>) {
    #[cfg(feature = "gpu")]
    if let Some(out) = op.first_right_hand_sides_gpu(&tcons, pc, vc, true) {
        return out;
    }
    let coarse_chi = coarse_cluster_values(op, fem, pc);
    let with_v = crate::system::broods_with_v(vc);
    let mut fixed = vec![0.0f32; tcons.len()];
    (tcons.par_chunks_mut(8).zip(fixed.par_chunks_mut(8)))
        .enumerate()
        .for_each(|(brood, (rows, fixed))| {
            let nbrs = op.level.brood_row(brood as u32);
            let near_v = op.coarser_v_near(brood as u32, &with_v);
            for (k, (row, fixed)) in rows.iter_mut().zip(fixed).enumerate() {
                let n = 8 * brood as u32 + k as u32;
                let i = op.index(n);
                if !op.tab.range.contains(i) {
                    *row = 0.0;
                    continue;
                }
                let t = f64::from(*row);
                let [mut r, mut b] =
                    op.coarse_coupling_near_v::<true>([t, t], n, i, (pc, vc), near_v);
                op.for_each_cluster(&nbrs, n, i, |c, bv| {
                    r += op.cl.omega[c as usize] * bv * (TAU - coarse_chi[c as usize]);
                    b += op.cl.omega[c as usize] * bv * TAU;
                });
                *row = r as f32;
                *fixed = b as f32;
            }
        });
    (tcons, fixed)
}

/// The right-hand side a further cycle relaxes a level against: its fixed part `b`, minus the
/// coarser solution's coupling (`pc`, cumulative, on the parent level, and the coarser
/// solution at the level's clusters), minus the finer levels' `u` (empty for none); stored in
/// single precision, as the cascade's. On the GPU where the problem has one. Written over `b`.
pub(super) fn cycle_right_hand_side(
    op: &Op,
    fem: crate::bspline::Basis,
    mut b: Vec<f32>,
    pc: &[f64],
    u: &[f64],
) -> Vec<f32> {
    #[cfg(feature = "gpu")]
    if let Some(r) = op.cycle_right_hand_side_gpu(&b, pc, u) {
        return r;
    }
    let coarse_chi = coarse_cluster_values(op, fem, pc);
    for_each_node(op.level, &mut b, |n, nbrs, row| {
        let i = op.index(n);
        if !op.tab.range.contains(i) {
            *row = 0.0;
            return;
        }
        let mut s = f64::from(*row);
        s = op.add_coarse_coupling::<true, false>(s, n, i, pc, &[]);
        op.for_each_cluster(nbrs, n, i, |c, bv| {
            s -= op.cl.omega[c as usize] * bv * coarse_chi[c as usize];
        });
        if !u.is_empty() {
            s -= u[n as usize];
        }
        *row = s as f32;
    });
    b
}

/// `Σ_n (r_n − ((L + S) x)_n)²` over the level's functions, summed in a fixed order.
fn residual_squared<R: Copy + Into<f64> + Sync>(op: &Op, r: &[R], x: &[f32]) -> f64 {
    let chi = op.cluster_values(|n| f64::from(x[n]));
    let res: Vec<f64> = map_nodes(op.level, |n, nbrs| {
        let i = op.index(n);
        if !op.tab.range.contains(i) {
            return 0.0;
        }
        let mut s = op.stiffness_row::<PlainLanes>(nbrs, n, i, x);
        op.for_each_cluster(nbrs, n, i, |c, bv| {
            s += op.cl.omega[c as usize] * bv * chi[c as usize];
        });
        r[n as usize].into() - s
    });
    norm2(&res)
}

/// `‖r − (L + S) x‖ / ‖r‖` on one level (0 for a zero right-hand side).
fn relative_residual<R: Copy + Into<f64> + Sync>(op: &Op, r: &[R], x: &[f32]) -> f64 {
    let rr: Vec<f64> = r.par_iter().map(|&v| v.into()).collect();
    let b2 = norm2(&rr);
    if b2 == 0.0 {
        return 0.0;
    }
    (residual_squared(op, r, x) / b2).sqrt()
}

/// `Σ a²`, in fixed-size chunks summed in order (the same for any thread count).
fn norm2(a: &[f64]) -> f64 {
    a.par_chunks(4096)
        .map(|c| c.iter().map(|v| v * v).sum::<f64>())
        .collect::<Vec<f64>>()
        .iter()
        .sum()
}

/// `Σ_j ∫∇B_q·∇B_j x_j` for every function `q` of the parent level of `op`'s level, from its
/// coefficients `x`: each function pushes into its parent window through the parent stiffness
/// stencils (the transpose of the cascade's pull).
///
/// Each brood's eight coefficients are pushed at once ([`parent_stiffness_push`]), tile by tile
/// ([`crate::system::push_to_parent_windows`]), so every sum is taken in an order that does
/// not depend on the thread count.
fn push_to_parents(op: &Op, x: &[f32]) -> Vec<f64> {
    let parent_level = &op.tree.levels[op.t as usize - 1];
    crate::system::push_to_parent_windows(parent_level, op.level, |b| {
        let xs: [f64; 8] = std::array::from_fn(|c| f64::from(x[8 * b as usize + c]));
        if xs.iter().all(|&v| v == 0.0) {
            return None;
        }
        Some(parent_stiffness_push(op.tab, op.index(8 * b), xs))
    })
}

/// The tiles of [`push_to_parents`] in its eight colours ([`crate::system::brood_tiles`]).
/// The GPU pushes the same tiles in the same order (`super::device`).
#[cfg(feature = "gpu")]
pub(super) fn push_tiles(op: &Op) -> Vec<Vec<std::ops::Range<u32>>> {
    crate::system::brood_tiles(&op.tree.levels[op.t as usize - 1], op.level)
}

/// `Σ_c ∫∇B_q·∇B_c x_c` over the eight children `c` of one brood (`i0`: its first node's
/// function index, `x`: its coefficients, zero for a node without a function) for the
/// 5×5×5 functions `q` around their parent, by window index. Each entry is a sum of three
/// products of 1-D integrals, so the sum is taken one axis at a time over the brood's 2×2×2
/// values, with each index's 1-D tables (boundary rows included). (Issue 20: one write per
/// parent-window entry instead of one per child and entry.)
pub(super) fn parent_stiffness_push(tab: &DepthTables, i0: [i64; 3], x: [f64; 8]) -> [f64; 125] {
    let x: [f64; 8] = std::array::from_fn(|c| {
        let i = std::array::from_fn(|a| i0[a] + ((c >> a) & 1) as i64);
        if tab.range.contains(i) {
            x[c]
        } else {
            0.0
        }
    });
    // Per axis, window offset r + 2 and child bit: the parent value and derivative tables.
    let mut m = [[[0.0f64; 2]; 5]; 3];
    let mut k = [[[0.0f64; 2]; 5]; 3];
    for a in 0..3 {
        for r in 0..5 {
            for bit in 0..2 {
                m[a][r][bit] = tab.pmass.get(i0[a] + bit as i64, r as i64 - 2);
                k[a][r][bit] = tab.pstiff.get(i0[a] + bit as i64, r as i64 - 2);
            }
        }
    }
    // The stiffness is `K_x M_y M_z + M_x K_y M_z + M_x M_y K_z`: V's form with one
    // coefficient in all three components.
    crate::system::tensor_push(&m, &k, |c, _| x[c])
}

/// `M x` of the whole hierarchical system for the coefficients `xs` (per level, the base's
/// and above), without the screening: the gradient coupling of every pair of depths.
#[cfg(test)]
pub(super) fn apply_stiffness(p: &Problem, xs: &[Vec<f32>]) -> Vec<Vec<f64>> {
    let nlev = p.tree.levels.len();
    let (tb, max) = (p.base_level as usize, nlev - 1);
    let ops: Vec<Option<Op>> = (0..nlev)
        .map(|t| (t >= tb).then(|| Op::new(p, t as u32)))
        .collect();
    let mut out = vec![Vec::new(); nlev];
    // Cumulative coarser solution, pulled through the parent stencils.
    let mut pcum: Vec<f64> = xs[tb].iter().map(|&v| f64::from(v)).collect();
    for t in tb..=max {
        let op = ops[t].as_ref().expect("op");
        let x = &xs[t];
        let prev = pcum.clone();
        let y: Vec<f64> = map_nodes(op.level, |n, nbrs| {
            let i = op.index(n);
            if !op.tab.range.contains(i) {
                return 0.0;
            }
            let mut s = op.stiffness_row::<PlainLanes>(nbrs, n, i, &x[..]);
            if t > tb {
                s -= op.add_coarse_coupling::<true, false>(0.0, n, i, &prev, &[]);
            }
            s
        });
        out[t] = y;
        if t > tb && t < max {
            pcum = prolong_solution(op, &prev, x);
        }
    }
    // Finer coupling, fine to coarse.
    let mut u: Vec<f64> = Vec::new();
    for t in (tb + 1..=max).rev() {
        let op = ops[t].as_ref().expect("op");
        let mut g = push_to_parents(op, &xs[t]);
        if !u.is_empty() {
            let coarse = &p.tree.levels[t - 1];
            let d = (t - 1) as u32 - DEPTH_OFFSET;
            let range = p.tables[t - 1].as_ref().expect("tables").range;
            for (n, gn) in g.iter_mut().enumerate() {
                let i = crate::octree::func_index(coarse.key(n as u32), d);
                if range.contains(i) {
                    *gn += restrict_one(p.tree, coarse, op.level, p.fem, d, n as u32, i, &u);
                }
            }
        }
        for (o, gi) in out[t - 1].iter_mut().zip(&g) {
            *o += gi;
        }
        u = g;
    }
    out
}
