//! Accuracy metrics: exact point-to-mesh distances, area-uniform surface samples, and the
//! evaluation of a mesh against a ground truth ([`evaluate`]: Chamfer and Hausdorff distances,
//! F-scores, normal consistency, topology).
//!
//! Everything here is deterministic: samples come from a counter-based generator (sample `i`
//! depends only on the seed and `i`), parallel queries are collected in order and reduced
//! sequentially, so the numbers do not depend on the number of threads.
//!
//! The code is split by phase: `distance` (exact point-to-triangle distances and
//! [`MeshDistance`], closest points on a whole mesh through a bounding-volume hierarchy),
//! `sampling` (area-uniform [`SurfaceSample`]s on meshes and spheres) and `report`
//! ([`evaluate`] and its [`Evaluation`]).

mod distance;
mod report;
mod sampling;

pub use distance::{
    closest_point_on_triangle, point_triangle_distance, triangle_normal, Closest, MeshDistance,
};
pub use report::{evaluate, Direction, EvalOptions, Evaluation, FScore, Reference};
pub use sampling::{sample_sphere, sample_surface, sample_surface_with_normals, SurfaceSample};
