//! Stage 6 (ALGORITHM.md §6, §7): the system's tables per depth and the cascadic
//! coarse-to-fine solve for the coefficients of χ.

use rayon::prelude::*;

use crate::bspline::{Basis, Boundary, Degree};
use crate::gpu::Device;
use crate::octree::{Octree, DEPTH_OFFSET};
use crate::solver::{self, Problem, Solution};
use crate::system::{Clusters, DepthTables};
use crate::Params;

/// Solves for χ's coefficients (stage 6). V is consumed level by level as the cascade passes.
pub fn solve(
    tree: &Octree,
    fem: Basis,
    clusters: &[Clusters],
    v: Vec<Vec<[f32; 3]>>,
    params: &Params,
    gpu: Option<&Device>,
    progress: &(dyn Fn(&str) + Sync),
) -> Solution {
    let base = params.base_depth().max(1).min(params.depth);
    let tb = base + DEPTH_OFFSET;
    // V lives in the degree-2 basis of the derivatives' boundary type (§3.6).
    let vb = Basis::new(Degree::Quadratic, params.boundary.derivative());
    let tables: Vec<Option<DepthTables>> = (0..tree.levels.len())
        .into_par_iter()
        .map(|t| (t as u32 >= tb).then(|| DepthTables::new(fem, vb, t as u32 - DEPTH_OFFSET)))
        .collect();
    let singular = params.alpha() == 0.0 && params.boundary != Boundary::Dirichlet;
    solver::solve(
        &Problem {
            tree,
            fem,
            tables: &tables,
            clusters,
            base_level: tb,
            iters: params.iters(),
            singular,
            solver: params.solver,
            cycles: params.cycles(),
            report: params.report_residuals,
            progress,
            gpu,
        },
        v,
    )
}
