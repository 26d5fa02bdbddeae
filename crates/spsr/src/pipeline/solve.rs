//! Stage 6 (ALGORITHM.md §6, §7): the system's tables per depth, the divergence constraints,
//! and the cascadic coarse-to-fine solve for the coefficients of χ.
//!
//! The constraints are made before the screening clusters are built, and the clusters after
//! them: the constraints read V at every depth, and so are the run's peak of memory without
//! the clusters alive beside them (issue 20).

use rayon::prelude::*;

use crate::bspline::{Basis, Boundary, Degree};
use crate::gpu::Device;
use crate::octree::{Octree, DEPTH_OFFSET};
use crate::solver::{self, Laps, Problem, Solution};
use crate::system::{Clusters, DepthTables};
use crate::Params;

/// The divergence constraints of every solved depth, the tables they and the solve use, and
/// the V the solve still reads (all but the finest depth's).
pub struct Constrained {
    tables: Vec<Option<DepthTables>>,
    tcons: Vec<Vec<f32>>,
    v: Vec<Vec<[f32; 3]>>,
}

/// The divergence constraints (stage 6) from V per level, on `gpu` where there is one; the
/// finest depth's V, which the solve does not read, is released.
pub fn constraints(
    tree: &Octree,
    fem: Basis,
    mut v: Vec<Vec<[f32; 3]>>,
    params: &Params,
    gpu: Option<&Device>,
) -> Constrained {
    let tables = tables(tree, fem, params);
    let tcons = solver::constraints_releasing_v(
        &problem(tree, fem, &tables, &[], params, gpu, &|_| {}),
        &mut v,
    );
    Constrained { tables, tcons, v }
}

/// Solves for χ's coefficients from the constraints (stage 6). V is consumed level by level
/// as the cascade passes.
pub fn solve(
    tree: &Octree,
    fem: Basis,
    constrained: Constrained,
    clusters: &[Clusters],
    params: &Params,
    gpu: Option<&Device>,
    progress: &(dyn Fn(&str) + Sync),
) -> Solution {
    let Constrained { tables, tcons, v } = constrained;
    let p = problem(tree, fem, &tables, clusters, params, gpu, progress);
    solver::solve_constrained(&p, tcons, v, Laps::new())
}

/// The level of the base depth's complete solve.
pub(crate) fn base_level(params: &Params) -> u32 {
    params.base_depth().max(1).min(params.depth) + DEPTH_OFFSET
}

/// The system's tables of every level of `tree` from the base level on.
pub(crate) fn tables(tree: &Octree, fem: Basis, params: &Params) -> Vec<Option<DepthTables>> {
    let tb = base_level(params);
    // V lives in the degree-2 basis of the derivatives' boundary type (§3.6).
    let vb = Basis::new(Degree::Quadratic, params.boundary.derivative());
    (0..tree.levels.len())
        .into_par_iter()
        .map(|t| (t as u32 >= tb).then(|| DepthTables::new(fem, vb, t as u32 - DEPTH_OFFSET)))
        .collect()
}

/// The solver's problem for `params` over the tree, its tables and its clusters.
pub(crate) fn problem<'a>(
    tree: &'a Octree,
    fem: Basis,
    tables: &'a [Option<DepthTables>],
    clusters: &'a [Clusters],
    params: &Params,
    gpu: Option<&'a Device>,
    progress: &'a (dyn Fn(&str) + Sync),
) -> Problem<'a> {
    Problem {
        tree,
        fem,
        tables,
        clusters,
        base_level: base_level(params),
        iters: params.iters(),
        deepest_level: (tree.levels.len() as u32).saturating_sub(1),
        first_deepest_iters: params.first_deepest_iters(),
        singular: params.alpha() == 0.0 && params.boundary != Boundary::Dirichlet,
        solver: params.solver,
        cycles: params.cycles(),
        report: params.report_residuals,
        progress,
        gpu,
    }
}
