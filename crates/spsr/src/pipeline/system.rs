//! Stage 5 (ALGORITHM.md §3.7): the screening term of the system — the samples grouped into
//! clusters per depth, each with its position and screening weight — and, when attributes
//! are carried, the samples' data summed up the tree.

use rayon::prelude::*;

use crate::bspline::Basis;
use crate::data::DataField;
use crate::density::cell_of;
use crate::octree::{Octree, DEPTH_OFFSET};
use crate::system::{build_clusters, Clusters};
use crate::Params;

/// The samples as the screening and the attributes see them.
#[derive(Debug, Clone, Default)]
pub struct SamplePoints {
    /// Positions, unit-cube coordinates.
    pub positions: Vec<[f64; 3]>,
    /// Weights.
    pub weights: Vec<f64>,
}

/// The output of [`screening`].
#[derive(Debug)]
pub struct Screening {
    /// Clusters per tree level (all empty without screening).
    pub clusters: Vec<Clusters>,
    /// The samples' attributes summed up the tree, when they are carried.
    pub data: Option<DataField>,
}

/// Clusters the samples for screening and sums their attributes up the tree (stage 5).
/// `values` holds `channels` attribute values per sample.
pub fn screening(
    tree: &Octree,
    fem: Basis,
    samples: &SamplePoints,
    values: Vec<f64>,
    channels: usize,
    mean_area: f64,
    params: &Params,
) -> Screening {
    let leaf_of = deepest_nodes(tree, &samples.positions);
    let data = (channels > 0).then(|| {
        DataField::build(
            tree,
            &leaf_of,
            &samples.weights,
            &values,
            channels,
            params.data_pull,
        )
    });
    drop(values);
    let alpha = params.alpha();
    let base = params.base_depth().max(1).min(params.depth);
    let clusters = if alpha > 0.0 {
        build_clusters(
            tree,
            fem,
            base + DEPTH_OFFSET,
            &leaf_of,
            &samples.positions,
            &samples.weights,
            alpha * mean_area,
        )
    } else {
        (0..tree.levels.len()).map(|_| Default::default()).collect()
    };
    Screening { clusters, data }
}

/// The deepest node `(level, node)` containing each position.
pub(crate) fn deepest_nodes(tree: &Octree, positions: &[[f64; 3]]) -> Vec<(u32, u32)> {
    let t_max = tree.depth_count() - 1;
    positions
        .par_iter()
        .map(|p| {
            let dm = t_max - DEPTH_OFFSET;
            let c = cell_of(*p, dm);
            let n = 1i64 << dm;
            tree.descend(
                [(c[0] + n) as u64, (c[1] + n) as u64, (c[2] + n) as u64],
                t_max,
                t_max,
            )
        })
        .collect()
}
