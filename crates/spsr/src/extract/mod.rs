//! Iso-surface extraction on the adaptive octree (ALGORITHM.md §9).
//!
//! Method (a face-based variant of Kazhdan et al. 2007, as in §9.3–9.4):
//!
//! 1. The leaves are visited block by block (a block is a subtree, e.g. one cell of the
//!    complete base depth), blocks in parallel. Within a block the field is evaluated once per
//!    distinct leaf corner (keyed by its integer coordinates at `max_depth`) and cached for the
//!    block only, so memory stays bounded by the largest block, not the tree; corners on block
//!    boundaries are evaluated by each block that needs them. Subtrees on whose closed cell
//!    χ provably stays on one side of the iso-value are not visited (`crate::bounds`; degree
//!    1): they hold no part of the surface.
//! 2. The boundary of each leaf is tiled by *face pieces*: a leaf face whose neighbour is
//!    same-size or coarser is one piece; a face whose neighbour is subdivided is tiled by the
//!    finer leaves' faces (found recursively: a square is subdivided iff the cell of its size
//!    across it is refined). The sides of a piece are split into *finest edges* at every leaf
//!    corner that lies on them (found recursively: a dyadic segment is split iff one of the
//!    cells of its size around it is refined). Both leaves that share a piece therefore see
//!    exactly the same polygon.
//! 3. Each finest edge with a sign change carries one iso-vertex, placed by the quadratic fit
//!    of §9.2 and keyed globally by the edge; only the corners of such edges need gradients.
//! 4. Marching squares on each piece: going round the piece, the crossings alternate between
//!    "entering" (outside → inside) and "leaving"; each entering crossing is joined to the
//!    leaving crossing that closes its inside run, except that pieces with exactly two inside
//!    runs use the asymptotic decider on the piece's four corners to join the outside runs
//!    instead. The rule only uses data of the piece, so both sides agree; the segment
//!    direction is reversed for the leaf on the other side, which gives consistent
//!    orientation. This generalises the "vertex pair" rule of §9.3: a finer crossing pair on a
//!    coarse edge is joined along that edge.
//! 5. The segments of a leaf chain into closed loops (every crossing on the leaf boundary lies
//!    on exactly two of its pieces). Loops of two vertices (a pair joined along an edge from
//!    both sides) enclose nothing and are dropped. Loops are triangulated in manifold mode:
//!    if two non-consecutive vertices lie on a common face of the leaf, fan around the
//!    barycentre, otherwise minimum-area triangulation.
//!
//! Inside is `χ > iso`; corners with `χ == iso` count as outside. Output order depends only on
//! the blocks and their leaf order, never on the thread count.
//!
//! The code follows the steps: `cells` (what extraction reads: [`Cells`], [`Field`], [`Leaf`]
//! lists), `blocks` (step 1, and numbering the blocks' vertices into one mesh), `faces`
//! (steps 2 and 4), `vertex` (step 3), `triangulate` (step 5); `table` is the concurrent
//! edge-key → vertex-index table used when numbering.

mod blocks;
mod cells;
mod faces;
mod table;
#[cfg(test)]
mod tests;
mod triangulate;
mod vertex;

pub use blocks::{extract, extract_blocks, Blocks, ExtractOptions, Part, FOREIGN};
pub use cells::{Cells, Field, Leaf};

/// Largest supported `max_depth` (coordinates must fit the 20-bit key fields).
const MAX_SUPPORTED_DEPTH: u32 = 18;
/// Marks a triangle reference to a barycentre vertex (local to a block).
const BARY: u64 = 1 << 63;

/// Key of a corner (20 bits per axis, x lowest).
#[inline]
fn pack(c: [u32; 3]) -> u64 {
    c[0] as u64 | (c[1] as u64) << 20 | (c[2] as u64) << 40
}

/// Key of the finest edge starting at `start` along `axis`.
#[inline]
fn edge_key(start: [u32; 3], axis: usize) -> u64 {
    pack(start) | (axis as u64) << 60
}
