//! Stage 9 (issue 16, with the noise adaptation): remove the small closed bubbles that noise
//! far from the surface leaves in the indicator function.
//!
//! Measured on the noise ramp (bunny, 100 k points, depth 9): after the noise adaptation
//! three pieces of 8–16 triangles remained at the noisy end, beside a surface of 190 k
//! triangles. A piece whose area is below [`MIN_PIECE_AREA`] of the mesh's total is such a
//! bubble, the same share the reference's trimmer (`--aRatio`) and `spsr trim` take for
//! islands. Runs only with [`crate::Noise::Adaptive`], so `Noise::Off` gives exactly
//! PoissonRecon's mesh.

use crate::mesh::Mesh;

/// Pieces smaller than this share of the mesh's area are removed.
pub const MIN_PIECE_AREA: f64 = 1e-3;

/// Removes the pieces (triangles connected through shared vertices) smaller than
/// [`MIN_PIECE_AREA`] of the total area; returns how many were removed. A mesh of one piece
/// is left untouched.
pub fn remove_fragments(mesh: &mut Mesh) -> usize {
    let (piece_of, areas) = mesh.pieces();
    if areas.len() < 2 {
        return 0;
    }
    let total: f64 = areas.iter().sum();
    let small: Vec<bool> = areas.iter().map(|&a| a < MIN_PIECE_AREA * total).collect();
    let removed = small.iter().filter(|&&s| s).count();
    if removed == 0 || removed == areas.len() {
        return 0;
    }
    let keep: Vec<bool> = piece_of.iter().map(|&p| !small[p as usize]).collect();
    *mesh = mesh.keep_triangles(&keep);
    removed
}
