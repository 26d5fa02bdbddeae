//! What extraction reads: the octree's cells ([`Cells`]), the implicit function at their
//! corners ([`Field`]), and [`LeafSet`], which makes a plain leaf list a [`Cells`].

use rayon::prelude::*;
use rustc_hash::FxHashSet;

use super::MAX_SUPPORTED_DEPTH;

/// A leaf cell of the octree: depth in the unit cube and integer offset (`0..2^depth` per axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Leaf {
    /// Depth (the unit cube is depth 0).
    pub depth: u32,
    /// Offset of the cell, in cells of width `2^-depth`.
    pub offset: [u32; 3],
}

/// The implicit function, sampled at cell corners. `H` is the [`Cells::Handle`] of the cells
/// it is sampled on: each corner comes with the handle of a leaf whose closure holds it, which
/// a field may use to find its way (it must not change the result).
pub trait Field<H = ()>: Sync {
    /// χ and ∇χ (unit-cube units) at the corner with integer coordinates `c` at depth
    /// `max_depth` (each coordinate in `0..=2^max_depth`), on the closure of leaf `near`.
    fn corner(&self, c: [u32; 3], near: H) -> (f64, [f64; 3]);

    /// χ alone at a corner. Extraction asks every corner for its value but only the corners
    /// of edges the surface crosses for their gradient, so a cheaper value-only path pays.
    fn value(&self, c: [u32; 3], near: H) -> f64 {
        self.corner(c, near).0
    }

    /// Whether the field is trilinear on every cell of the corner grid, so that along a grid
    /// edge it is linear and its derivative at a corner can be read from the neighbouring
    /// corners' values. Only for a field whose [`Field::corner`] gradient is then the mean
    /// of the one-sided derivatives there.
    fn trilinear(&self) -> bool {
        false
    }
}

/// The octree as extraction sees it: its leaves, grouped in blocks, and whether a cell is
/// refined. The leaves of all blocks together must tile the unit cube.
pub trait Cells: Sync {
    /// A handle on a leaf that makes questions about cells near it cheap.
    type Handle: Copy;
    /// Depth of the finest leaves (corner coordinates are integers at this depth).
    fn max_depth(&self) -> u32;
    /// Number of blocks.
    fn block_count(&self) -> usize;
    /// Calls `f(handle, depth, offset)` for every leaf of block `b`, in a fixed order. It may
    /// leave out leaves whose closure it knows the surface not to reach (χ strictly on one
    /// side of the iso-value there): they would make no polygon, so the mesh is the same.
    fn for_each_leaf(&self, b: usize, f: &mut dyn FnMut(Self::Handle, u32, [u32; 3]));
    /// Whether the cell of `depth` and `offset` (inside the unit cube) exists and has
    /// children. The cell touches the closure of the leaf `near` and is no coarser than it.
    fn refined(&self, near: Self::Handle, depth: u32, offset: [u32; 3]) -> bool;

    /// Bit `(dx+1) + 3(dy+1) + 9(dz+1)` is set when the cell of the leaf's own depth at the
    /// leaf's offset plus `(dx, dy, dz)` (inside the unit cube) is refined.
    fn refined_around(&self, leaf: Self::Handle, depth: u32, offset: [u32; 3]) -> u32 {
        let n = 1i64 << depth;
        let mut mask = 0;
        for s in 0..27u32 {
            let q: [i64; 3] = std::array::from_fn(|a| {
                i64::from(offset[a]) + i64::from((s / 3u32.pow(a as u32)) % 3) - 1
            });
            if q.iter().all(|&c| (0..n).contains(&c))
                && self.refined(leaf, depth, q.map(|c| c as u32))
            {
                mask |= 1 << s;
            }
        }
        mask
    }
}

pub(super) fn bad_leaves(message: &str) -> crate::Error {
    crate::Error::invalid("leaves", message, "leaves that tile the unit cube")
}

/// Rejects a `max_depth` beyond [`MAX_SUPPORTED_DEPTH`].
pub(super) fn check_depth(max_depth: u32) -> crate::Result<()> {
    if max_depth > MAX_SUPPORTED_DEPTH {
        return Err(crate::Error::invalid(
            "depth",
            max_depth,
            format!("at most {MAX_SUPPORTED_DEPTH}, the deepest extraction supports"),
        ));
    }
    Ok(())
}

/// A leaf list as [`Cells`]: the refined cells are the leaves' proper ancestors, and the
/// blocks are the cells of the shallowest leaf depth (at most 3).
pub(super) struct LeafSet<'a> {
    leaves: &'a [Leaf],
    max_depth: u32,
    internal: FxHashSet<(u32, [u32; 3])>,
    blocks: Vec<Vec<u32>>,
}

impl<'a> LeafSet<'a> {
    pub(super) fn new(leaves: &'a [Leaf], max_depth: u32) -> crate::Result<Self> {
        check_depth(max_depth)?;
        if leaves.is_empty() {
            return Err(bad_leaves("no leaves: they must tile the unit cube"));
        }
        if leaves.len() >= u32::MAX as usize {
            return Err(bad_leaves("too many leaves for 32-bit indices"));
        }
        let in_range = |l: &Leaf| {
            l.depth <= max_depth && l.offset.iter().all(|&o| (o as u64) < 1u64 << l.depth)
        };
        // Overlaps plus gaps could still cancel in the volume; the distinct-leaf and
        // refined-leaf checks below catch those.
        let volume: Option<u128> = leaves
            .par_iter()
            .map(|l| in_range(l).then(|| 1u128 << (3 * (max_depth - l.depth))))
            .try_reduce(|| 0, |a, b| Some(a + b));
        if volume != Some(1u128 << (3 * max_depth)) {
            return Err(bad_leaves("the leaves do not tile the unit cube"));
        }
        let mut internal = FxHashSet::default();
        for l in leaves {
            let (mut d, mut o) = (l.depth, l.offset);
            while d > 0 {
                d -= 1;
                o = o.map(|x| x / 2);
                if !internal.insert((d, o)) {
                    break;
                }
            }
        }
        if leaves
            .iter()
            .any(|l| internal.contains(&(l.depth, l.offset)))
        {
            return Err(bad_leaves(
                "the leaves do not tile the unit cube (a leaf contains another)",
            ));
        }
        let bd = leaves.iter().map(|l| l.depth).min().unwrap_or(0).min(3);
        let mut blocks = vec![Vec::new(); 1 << (3 * bd)];
        for (i, l) in leaves.iter().enumerate() {
            let o = l.offset.map(|x| x >> (l.depth - bd));
            blocks[(o[0] | o[1] << bd | o[2] << (2 * bd)) as usize].push(i as u32);
        }
        Ok(LeafSet {
            leaves,
            max_depth,
            internal,
            blocks,
        })
    }
}

impl Cells for LeafSet<'_> {
    type Handle = ();
    fn max_depth(&self) -> u32 {
        self.max_depth
    }
    fn block_count(&self) -> usize {
        self.blocks.len()
    }
    fn for_each_leaf(&self, b: usize, f: &mut dyn FnMut((), u32, [u32; 3])) {
        for &i in &self.blocks[b] {
            let l = self.leaves[i as usize];
            f((), l.depth, l.offset);
        }
    }
    fn refined(&self, _near: (), depth: u32, offset: [u32; 3]) -> bool {
        self.internal.contains(&(depth, offset))
    }
}
