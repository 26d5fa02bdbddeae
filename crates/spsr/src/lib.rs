//! # spsr — Screened Poisson Surface Reconstruction
//!
//! Turns an oriented point cloud into a watertight, manifold triangle mesh by the method of
//! Kazhdan & Hoppe (ACM TOG 2013), as specified in the project's `ALGORITHM.md`.
//!
//! ```no_run
//! use spsr::{io, reconstruct, Params};
//! let cloud = io::read_points("scan.ply".as_ref())?;
//! let result = reconstruct(&cloud, &Params::default())?;
//! io::write_mesh("mesh.ply".as_ref(), &result.mesh, &io::WriteOptions::default())?;
//! # Ok::<(), spsr::Error>(())
//! ```
#![deny(missing_docs)]
// Numeric kernels index several parallel arrays by axis; explicit index loops read best there.
#![allow(clippy::needless_range_loop)]

pub mod attributes;
mod bounds;
pub mod bspline;
mod data;
mod density;
mod error;
mod evaluate;
pub mod extract;
mod gpu;
pub mod io;
pub mod mesh;
pub mod metrics;
mod morton;
pub mod normals;
mod octree;
mod params;
mod pipeline;
pub mod points;
pub mod render;
mod resources;
mod shared_slice;
pub mod slabs;
mod solver;
mod system;
pub mod trim;
mod vec3;

pub use bspline::{Boundary, Degree};
pub use error::{gib, Error, FarOutliers, MemoryLimit, MemoryShortfall, Remedy, Result, Warning};
pub use gpu::{GpuKernel, GpuRelaxation};
pub use mesh::Mesh;
pub use params::{Gpu, Noise, Params, PointWeights, Resolution, Solver, MAX_DEPTH};
pub use pipeline::diagnose::{self, Diagnosis};
/// The floor model of each stage's work (issue 20): bytes moved and flops done.
pub use pipeline::work;
pub use pipeline::{
    reconstruct, reconstruct_and_trim, reconstruct_and_trim_implicit, reconstruct_implicit,
    reconstruct_owned, reconstruct_with_progress, resolution::resolve, stage_plan, DepthChoice,
    DepthLimit, DepthReason, Grid, ImplicitFunction, NoiseSummary, Reconstruction, Stats, Work,
};
pub use points::{PointCloud, ScanOrigin};
pub use resources::{memory_budget, peak_rss, share_one_allocator_arena};
pub use solver::{DepthResidual, SolveReport};
