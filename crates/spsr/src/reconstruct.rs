//! The front door: the whole pipeline of ALGORITHM.md §2, stage by stage.

use std::time::Duration;

use crate::{Mesh, Params, PointCloud, Result};

/// The output of [`reconstruct`].
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// The mesh, in the input's frame and units.
    pub mesh: Mesh,
    /// Counts and timings of the run.
    pub stats: Stats,
}

/// Counts and timings gathered during a reconstruction.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Points given.
    pub points: usize,
    /// Points dropped (non-finite values or zero-length normals).
    pub dropped: usize,
    /// Samples after merging points that share a finest cell.
    pub samples: usize,
    /// Octree nodes per depth (index 0 is the unit cube).
    pub nodes_per_depth: Vec<usize>,
    /// The iso-value γ.
    pub iso_value: f64,
    /// Wall time of each stage, in order.
    pub stages: Vec<(&'static str, Duration)>,
}

/// Reconstructs a watertight surface from oriented points.
pub fn reconstruct(points: &PointCloud, params: &Params) -> Result<Reconstruction> {
    reconstruct_with_progress(points, params, &|_| {})
}

/// As [`reconstruct`], calling `progress` with the name of each stage as it starts.
pub fn reconstruct_with_progress(
    points: &PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    let _ = (points, params, progress);
    unimplemented!()
}
