//! Stage 5 (ALGORITHM.md §3.7): the screening term of the system — the samples grouped into
//! clusters per depth, each with its position and screening weight — and, when attributes
//! are carried, the samples' data summed up the tree.

use rayon::prelude::*;

use crate::bspline::Basis;
use crate::data::DataField;
use crate::density::{cell_of, DepthAndArea};
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
    /// The finest depth whose screening clusters take each sample
    /// ([`crate::density::DepthAndArea::screen_depth`]); empty: every depth, for all.
    pub screen_depths: Vec<u32>,
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
        let screened_at = screened_nodes(tree, leaf_of, &samples.screen_depths);
        build_clusters(
            tree,
            fem,
            base + DEPTH_OFFSET,
            &screened_at,
            &samples.positions,
            &samples.weights,
            alpha * mean_area,
        )
    } else {
        (0..tree.levels.len()).map(|_| Default::default()).collect()
    };
    Screening { clusters, data }
}

/// Each sample's screening depth ([`SamplePoints::screen_depths`]), empty when every sample
/// is screened at every depth.
pub fn screen_depths(depths: &[DepthAndArea]) -> Vec<u32> {
    if depths.iter().any(DepthAndArea::screened_coarser) {
        depths.iter().map(|q| q.screen_depth).collect()
    } else {
        Vec::new()
    }
}

/// The node `(level, node)` whose cluster takes each sample first: its deepest node
/// (`leaf_of`), or that node's ancestor at the sample's screening depth where that is
/// coarser (`screen_depths`, unit depths; empty: the deepest nodes).
pub(crate) fn screened_nodes(
    tree: &Octree,
    leaf_of: Vec<(u32, u32)>,
    screen_depths: &[u32],
) -> Vec<(u32, u32)> {
    if screen_depths.is_empty() {
        return leaf_of;
    }
    leaf_of
        .into_par_iter()
        .zip(screen_depths)
        .map(|((mut t, mut n), &d)| {
            let finest = d.saturating_add(DEPTH_OFFSET);
            while t > finest {
                n = tree.parent(t, n);
                t -= 1;
            }
            (t, n)
        })
        .collect()
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
