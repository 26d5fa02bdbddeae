//! Iso-surface extraction on the adaptive octree (ALGORITHM.md §9): marching cubes over the
//! leaves with iso-vertices shared across depths, so the mesh has no cracks, and a
//! triangulation that keeps it manifold. (Being implemented; the signatures are the contract.)

use crate::mesh::Mesh;

/// A leaf cell of the octree: depth in the unit cube and integer offset (`0..2^depth` per axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Leaf {
    /// Depth (the unit cube is depth 0).
    pub depth: u32,
    /// Offset of the cell, in cells of width `2^-depth`.
    pub offset: [u32; 3],
}

/// The implicit function, sampled at cell corners.
pub trait Field: Sync {
    /// χ and ∇χ (unit-cube units) at the corner with integer coordinates `c` at depth
    /// `max_depth` (each coordinate in `0..=2^max_depth`).
    fn corner(&self, c: [u32; 3]) -> (f64, [f64; 3]);
}

/// Options of [`extract`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExtractOptions {
    /// Place iso-vertices by linear interpolation instead of the quadratic fit.
    pub linear_fit: bool,
}

/// Extracts the level set `χ = iso` over `leaves`, which tile the unit cube. Inside is
/// `χ > iso`. Vertices are in unit-cube coordinates; triangles are counter-clockwise seen
/// from outside (their normals point along −∇χ).
pub fn extract(
    leaves: &[Leaf],
    max_depth: u32,
    field: &dyn Field,
    iso: f64,
    opts: &ExtractOptions,
) -> crate::Result<Mesh> {
    let _ = (leaves, max_depth, field, iso, opts);
    unimplemented!()
}
