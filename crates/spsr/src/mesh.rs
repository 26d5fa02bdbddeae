//! Triangle meshes produced by the reconstruction, and their topological checks.

/// A triangle mesh with optional per-vertex density.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Optional per-vertex density (estimated sampling depth, ALGORITHM.md §9.5).
    pub density: Option<Vec<f32>>,
}
