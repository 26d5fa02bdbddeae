//! Iso-surface extraction on the adaptive octree (ALGORITHM.md §9).
//!
//! Method (a face-based variant of Kazhdan et al. 2007, as in §9.3–9.4):
//!
//! 1. The leaves are visited block by block (a block is a subtree, e.g. one cell of the
//!    complete base depth), blocks in parallel. Within a block the field is evaluated once per
//!    distinct leaf corner (keyed by its integer coordinates at `max_depth`) and cached for the
//!    block only, so memory stays bounded by the largest block, not the tree; corners on block
//!    boundaries are evaluated by each block that needs them.
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

mod table;
#[cfg(test)]
mod tests;

use crate::mesh::Mesh;
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};
use table::Table;

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

    /// χ alone at a corner. Extraction asks every corner for its value but only the corners
    /// of edges the surface crosses for their gradient, so a cheaper value-only path pays.
    fn value(&self, c: [u32; 3]) -> f64 {
        self.corner(c).0
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
    /// Calls `f(handle, depth, offset)` for every leaf of block `b`, in a fixed order.
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

/// Options of [`extract`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExtractOptions {
    /// Place iso-vertices by linear interpolation instead of the quadratic fit.
    pub linear_fit: bool,
    /// Give every vertex a unit normal: `−∇χ` interpolated linearly between the gradients at
    /// the ends of its edge (as PoissonRecon 18 does); a barycentre vertex gets the mean of its
    /// polygon's vertex normals.
    pub normals: bool,
}

/// Largest supported `max_depth` (coordinates must fit the 20-bit key fields).
const MAX_SUPPORTED_DEPTH: u32 = 18;
/// Marks a triangle reference to a barycentre vertex (local to a block).
const BARY: u64 = 1 << 63;
/// Largest polygon triangulated by dynamic programming; larger ones are fanned.
const MAX_DP: usize = 16;

#[inline]
fn pack(c: [u32; 3]) -> u64 {
    c[0] as u64 | (c[1] as u64) << 20 | (c[2] as u64) << 40
}

/// Key of the finest edge starting at `start` along `axis`.
#[inline]
fn edge_key(start: [u32; 3], axis: usize) -> u64 {
    pack(start) | (axis as u64) << 60
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
    extract_impl(leaves, max_depth, field, iso, opts).map(|(mesh, _, _)| mesh)
}

fn bad_leaves(message: &str) -> crate::Error {
    crate::Error::invalid("leaves", message, "leaves that tile the unit cube")
}

fn depth_too_large(depth: u32) -> crate::Error {
    crate::Error::invalid(
        "depth",
        depth,
        format!("at most {MAX_SUPPORTED_DEPTH}, the deepest extraction supports"),
    )
}

/// A leaf list as [`Cells`]: the refined cells are the leaves' proper ancestors, and the
/// blocks are the cells of the shallowest leaf depth (at most 3).
struct LeafSet<'a> {
    leaves: &'a [Leaf],
    max_depth: u32,
    internal: FxHashSet<(u32, [u32; 3])>,
    blocks: Vec<Vec<u32>>,
}

impl<'a> LeafSet<'a> {
    fn new(leaves: &'a [Leaf], max_depth: u32) -> crate::Result<Self> {
        if max_depth > MAX_SUPPORTED_DEPTH {
            return Err(depth_too_large(max_depth));
        }
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

/// Shared read-only state of the per-leaf pass.
struct Ctx<'a, C: Cells> {
    cells: &'a C,
    field: &'a dyn Field,
    iso: f64,
    max_depth: u32,
    full: u32,
    inv: f64,
    linear: bool,
    normals: bool,
}

/// The leaf being polygonised: its handle, depth, offset, and which same-depth cells around it
/// are refined (see [`Cells::refined_around`]).
#[derive(Clone, Copy)]
struct Here<H> {
    h: H,
    depth: u32,
    offset: [u32; 3],
    around: u32,
}

impl<H: Copy> Here<H> {
    /// Whether the cell of `depth` and `offset` is refined, answered from `around` when the
    /// cell has the leaf's depth.
    #[inline]
    fn refined<C: Cells<Handle = H>>(&self, cells: &C, depth: u32, offset: [u32; 3]) -> bool {
        if depth == self.depth {
            let mut s = 0;
            let mut mul = 1;
            for a in 0..3 {
                let r = i64::from(offset[a]) - i64::from(self.offset[a]) + 1;
                if !(0..3).contains(&r) {
                    return cells.refined(self.h, depth, offset);
                }
                s += r as u32 * mul;
                mul *= 3;
            }
            return self.around >> s & 1 != 0;
        }
        cells.refined(self.h, depth, offset)
    }
}

/// One crossing on a finest edge, as seen by a leaf.
#[derive(Clone, Copy)]
struct Crossing {
    key: u64,
    lo: [u32; 3],
    axis: u8,
    len: u32,
    i0: u32,
    i1: u32,
}

/// The field at the corners a block has asked for: `χ − iso`, and the gradient once needed.
#[derive(Default)]
struct CornerCache {
    index: FxHashMap<u64, u32>,
    at: Vec<[u32; 3]>,
    d: Vec<f64>,
    g: Vec<Option<[f64; 3]>>,
}

impl CornerCache {
    fn clear(&mut self) {
        self.index.clear();
        self.at.clear();
        self.d.clear();
        self.g.clear();
    }

    /// Index of the corner at `c`, evaluating the field there the first time.
    #[inline]
    fn get<C: Cells>(&mut self, ctx: &Ctx<C>, c: [u32; 3]) -> u32 {
        let next = self.d.len() as u32;
        let i = *self.index.entry(pack(c)).or_insert(next);
        if i == next {
            self.at.push(c);
            self.d.push(ctx.field.value(c) - ctx.iso);
            self.g.push(None);
        }
        i
    }

    /// Gradient at corner `i`, evaluated the first time it is needed.
    #[inline]
    fn grad<C: Cells>(&mut self, ctx: &Ctx<C>, i: u32) -> [f64; 3] {
        let i = i as usize;
        match self.g[i] {
            Some(g) => g,
            None => {
                let g = ctx.field.corner(self.at[i]).1;
                self.g[i] = Some(g);
                g
            }
        }
    }
}

/// Reusable per-thread buffers.
struct Scratch<H> {
    leaves: Vec<(H, u32, [u32; 3])>,
    corners: CornerCache,
    bv: Vec<([u32; 3], u32)>,
    cr: Vec<(u64, bool)>,
    cross: Vec<Crossing>,
    pos: Vec<[f64; 3]>,
    nrm: Vec<[f64; 3]>,
    segs: Vec<(u64, u64)>,
    used: Vec<bool>,
    poly: Vec<u32>,
    bad: bool,
}

impl<H> Default for Scratch<H> {
    fn default() -> Self {
        Self {
            leaves: Vec::new(),
            corners: CornerCache::default(),
            bv: Vec::new(),
            cr: Vec::new(),
            cross: Vec::new(),
            pos: Vec::new(),
            nrm: Vec::new(),
            segs: Vec::new(),
            used: Vec::new(),
            poly: Vec::new(),
            bad: false,
        }
    }
}

/// Output of one block of leaves.
#[derive(Default)]
struct ChunkOut {
    owned_keys: Vec<u64>,
    owned_pos: Vec<[f64; 3]>,
    owned_nrm: Vec<[f32; 3]>,
    bary: Vec<[f64; 3]>,
    bary_nrm: Vec<[f32; 3]>,
    tris: Vec<[u64; 3]>,
    bad: bool,
}

/// The per-block output of [`extract_blocks`], before vertices are numbered globally.
pub struct Blocks {
    chunks: Vec<ChunkOut>,
}

/// The extraction proper on a leaf list; also returns the number of edge iso-vertices
/// (without barycentres) and, in test builds only, which output vertices are edge
/// iso-vertices.
fn extract_impl(
    leaves: &[Leaf],
    max_depth: u32,
    field: &dyn Field,
    iso: f64,
    opts: &ExtractOptions,
) -> crate::Result<(Mesh, usize, Vec<bool>)> {
    let cells = LeafSet::new(leaves, max_depth)?;
    extract_blocks(&cells, field, iso, opts)?.assemble_impl()
}

/// Polygonises every block of `cells` (in parallel); [`Blocks::assemble`] then numbers the
/// vertices and builds the mesh. The two steps are separate so that a caller can release the
/// octree and the solution, which the first step reads, before the second.
pub fn extract_blocks<C: Cells>(
    cells: &C,
    field: &dyn Field,
    iso: f64,
    opts: &ExtractOptions,
) -> crate::Result<Blocks> {
    let max_depth = cells.max_depth();
    if max_depth > MAX_SUPPORTED_DEPTH {
        return Err(depth_too_large(max_depth));
    }
    let ctx = Ctx {
        cells,
        field,
        iso,
        max_depth,
        full: 1u32 << max_depth,
        inv: 1.0 / (1u64 << max_depth) as f64,
        linear: opts.linear_fit,
        normals: opts.normals,
    };
    let chunks: Vec<ChunkOut> = (0..cells.block_count())
        .into_par_iter()
        .map_init(Scratch::<C::Handle>::default, |sc, b| {
            let mut out = ChunkOut::default();
            sc.corners.clear();
            let mut leaves = std::mem::take(&mut sc.leaves);
            leaves.clear();
            cells.for_each_leaf(b, &mut |h, d, o| leaves.push((h, d, o)));
            for &(h, depth, offset) in &leaves {
                process_leaf(&ctx, sc, h, depth, offset, &mut out);
                if sc.bad {
                    sc.bad = false;
                    out.bad = true;
                }
            }
            sc.leaves = leaves;
            out
        })
        .collect();
    if chunks.iter().any(|c| c.bad) {
        return Err(bad_leaves(
            "the leaves do not tile the unit cube (inconsistent boundaries)",
        ));
    }
    Ok(Blocks { chunks })
}

impl Blocks {
    /// Numbers the vertices (each edge vertex is emitted by exactly one owner leaf; block `b`
    /// contributes its owned vertices, then its barycentres) and builds the mesh.
    pub fn assemble(self) -> crate::Result<Mesh> {
        self.assemble_impl().map(|(mesh, _, _)| mesh)
    }

    fn assemble_impl(self) -> crate::Result<(Mesh, usize, Vec<bool>)> {
        let chunks = self.chunks;
        let mut bases = Vec::with_capacity(chunks.len());
        let mut total = 0usize;
        let mut n_edge_vertices = 0usize;
        for c in &chunks {
            bases.push(total);
            total += c.owned_keys.len() + c.bary.len();
            n_edge_vertices += c.owned_keys.len();
        }
        if total >= u32::MAX as usize {
            return Err(bad_leaves("too many vertices for 32-bit indices"));
        }
        let vt = Table::with_capacity(n_edge_vertices);
        chunks.par_iter().zip(&bases).for_each(|(c, &base)| {
            for (i, &k) in c.owned_keys.iter().enumerate() {
                if let Some(slot) = vt.insert(k) {
                    vt.set(slot, (base + i) as u32);
                }
            }
        });
        let mut triangles: Vec<[u32; 3]> =
            Vec::with_capacity(chunks.iter().map(|c| c.tris.len()).sum());
        let with_normals = chunks
            .iter()
            .any(|c| !c.owned_nrm.is_empty() || !c.bary_nrm.is_empty());
        let mut normals: Vec<[f32; 3]> = Vec::with_capacity(if with_normals { total } else { 0 });
        let mut vertices = Vec::with_capacity(total);
        let mut is_edge = Vec::with_capacity(if cfg!(test) { total } else { 0 });
        let mut unowned = false;
        for (c, &base) in chunks.into_iter().zip(&bases) {
            let bary_base = (base + c.owned_keys.len()) as u64;
            triangles.par_extend(c.tris.par_iter().map(|t| {
                t.map(|r| {
                    if r & BARY != 0 {
                        (bary_base + (r & !BARY)) as u32
                    } else {
                        vt.get(r).unwrap_or(u32::MAX)
                    }
                })
            }));
            vertices.extend_from_slice(&c.owned_pos);
            vertices.extend_from_slice(&c.bary);
            if with_normals {
                normals.extend_from_slice(&c.owned_nrm);
                normals.extend_from_slice(&c.bary_nrm);
            }
            if cfg!(test) {
                is_edge.extend(std::iter::repeat_n(true, c.owned_pos.len()));
                is_edge.extend(std::iter::repeat_n(false, c.bary.len()));
            }
        }
        drop(vt);
        unowned |= triangles.par_iter().flatten().any(|&i| i == u32::MAX);
        if unowned {
            return Err(bad_leaves(
                "the leaves do not tile the unit cube (unowned iso-vertex)",
            ));
        }
        // Drop vertices no triangle uses (possible only next to dropped two-vertex loops).
        let mut used = vec![false; vertices.len()];
        for &i in triangles.iter().flatten() {
            used[i as usize] = true;
        }
        if used.iter().any(|&u| !u) {
            let mut remap = vec![u32::MAX; vertices.len()];
            let mut kept = Vec::with_capacity(vertices.len());
            let mut kept_nrm = Vec::with_capacity(normals.len());
            for (i, v) in vertices.iter().enumerate() {
                if used[i] {
                    remap[i] = kept.len() as u32;
                    kept.push(*v);
                    if with_normals {
                        kept_nrm.push(normals[i]);
                    }
                }
            }
            vertices = kept;
            normals = kept_nrm;
            if cfg!(test) {
                is_edge = is_edge
                    .iter()
                    .zip(&used)
                    .filter(|(_, &u)| u)
                    .map(|(&e, _)| e)
                    .collect();
            }
            triangles
                .par_iter_mut()
                .for_each(|t| *t = t.map(|i| remap[i as usize]));
        }
        Ok((
            Mesh {
                vertices,
                triangles,
                normals: with_normals.then_some(normals),
                ..Default::default()
            },
            n_edge_vertices,
            is_edge,
        ))
    }
}

/// Builds and triangulates the iso-polygons of one leaf.
fn process_leaf<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    h: C::Handle,
    depth: u32,
    offset: [u32; 3],
    out: &mut ChunkOut,
) {
    let s = 1u32 << (ctx.max_depth - depth);
    let lo = offset.map(|o| o * s);
    let mut cidx = [0u32; 8];
    let mut inside = 0u32;
    for (c, ci) in cidx.iter_mut().enumerate() {
        let p = [
            lo[0] + s * (c as u32 & 1),
            lo[1] + s * ((c as u32 >> 1) & 1),
            lo[2] + s * ((c as u32 >> 2) & 1),
        ];
        *ci = sc.corners.get(ctx, p);
        if sc.corners.d[*ci as usize] > 0.0 {
            inside |= 1 << c;
        }
    }
    if s == 1 && (inside == 0 || inside == 0xff) {
        return; // finest leaf: nothing can cross its boundary
    }
    let around = ctx.cells.refined_around(h, depth, offset);
    if around == 0 && (inside == 0 || inside == 0xff) {
        return; // no finer neighbour: the leaf's boundary has only its own corners
    }
    let here = Here {
        h,
        depth,
        offset,
        around,
    };
    sc.cross.clear();
    sc.segs.clear();
    for n in 0..3 {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        for side in 0..2u32 {
            let mut origin = lo;
            origin[n] += side * s;
            let c0 = (side as usize) << n;
            let known = [
                cidx[c0],
                cidx[c0 | 1 << u],
                cidx[c0 | 1 << u | 1 << v],
                cidx[c0 | 1 << v],
            ];
            face(ctx, sc, &here, origin, s, n, side == 0, Some(known));
        }
    }
    if sc.segs.is_empty() || sc.bad {
        return;
    }
    finish_leaf(ctx, sc, lo, s, out);
}

/// Depth of the cells of width `size` (in finest-cell units).
#[inline]
fn depth_of(ctx_max: u32, size: u32) -> u32 {
    ctx_max - size.trailing_zeros()
}

/// Visits the pieces tiling the square `origin + [0,size]²` (normal `n`) of a leaf face; the
/// leaf lies above the square when `flip`, below otherwise.
#[allow(clippy::too_many_arguments)]
fn face<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    origin: [u32; 3],
    size: u32,
    n: usize,
    flip: bool,
    known: Option<[u32; 4]>,
) {
    let (u, v) = ((n + 1) % 3, (n + 2) % 3);
    if size > 1 {
        // The square is subdivided iff the cell of its size across it is refined.
        let k = depth_of(ctx.max_depth, size);
        let across = if flip {
            origin[n].checked_sub(size)
        } else {
            (origin[n] < ctx.full).then_some(origin[n])
        };
        if let Some(a) = across {
            let mut cell = origin.map(|x| x / size);
            cell[n] = a / size;
            if here.refined(ctx.cells, k, cell) {
                let half = size / 2;
                for (du, dv) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                    let mut o = origin;
                    o[u] += du * half;
                    o[v] += dv * half;
                    face(ctx, sc, here, o, half, n, flip, None);
                }
                return;
            }
        }
    }
    piece(ctx, sc, here, origin, size, n, flip, known);
}

/// Whether the midpoint of the dyadic segment from `a` (length `len` along `axis`, towards +
/// when `forward`) is a leaf corner: iff one of the four cells of size `len` around the
/// segment is refined.
fn segment_split<C: Cells>(
    ctx: &Ctx<C>,
    here: &Here<C::Handle>,
    a: [u32; 3],
    axis: usize,
    forward: bool,
    len: u32,
) -> bool {
    let k = depth_of(ctx.max_depth, len);
    let mut e = a;
    if !forward {
        e[axis] -= len;
    }
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let cell_count = ctx.full / len;
    for du in 0..2u32 {
        for dv in 0..2u32 {
            let (Some(cu), Some(cv)) = ((e[u] / len).checked_sub(du), (e[v] / len).checked_sub(dv))
            else {
                continue;
            };
            if cu >= cell_count || cv >= cell_count {
                continue;
            }
            let mut cell = [0u32; 3];
            cell[axis] = e[axis] / len;
            cell[u] = cu;
            cell[v] = cv;
            if here.refined(ctx.cells, k, cell) {
                return true;
            }
        }
    }
    false
}

/// Pushes the leaf corners strictly inside the dyadic segment from `a` (length `len` along
/// `axis`, direction `forward`), in order from `a`.
#[allow(clippy::too_many_arguments)]
fn split_side<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    a: [u32; 3],
    axis: usize,
    forward: bool,
    len: u32,
) {
    if len <= 1 || !segment_split(ctx, here, a, axis, forward, len) {
        return;
    }
    let half = len / 2;
    let mut m = a;
    if forward {
        m[axis] += half;
    } else {
        m[axis] -= half;
    }
    split_side(ctx, sc, here, a, axis, forward, half);
    let i = sc.corners.get(ctx, m);
    sc.bv.push((m, i));
    split_side(ctx, sc, here, m, axis, forward, half);
}

/// Marching squares on one face piece; appends its oriented segments and crossings.
#[allow(clippy::too_many_arguments)]
fn piece<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    origin: [u32; 3],
    size: u32,
    n: usize,
    flip: bool,
    known: Option<[u32; 4]>,
) {
    let (u, v) = ((n + 1) % 3, (n + 2) % 3);
    let mut p = [origin; 4];
    p[1][u] += size;
    p[2][u] += size;
    p[2][v] += size;
    p[3][v] += size;
    let idx = match known {
        Some(k) => k,
        None => p.map(|c| sc.corners.get(ctx, c)),
    };
    // Boundary, counter-clockwise around +n.
    sc.bv.clear();
    let sides = [(u, true), (v, true), (u, false), (v, false)];
    for (c, &(axis, fwd)) in sides.iter().enumerate() {
        sc.bv.push((p[c], idx[c]));
        split_side(ctx, sc, here, p[c], axis, fwd, size);
    }
    let d = &sc.corners.d;
    let first = d[sc.bv[0].1 as usize] > 0.0;
    if sc.bv.iter().all(|b| (d[b.1 as usize] > 0.0) == first) {
        return;
    }
    sc.cr.clear();
    let nb = sc.bv.len();
    for i in 0..nb {
        let (pa, ia) = sc.bv[i];
        let (pb, ib) = sc.bv[(i + 1) % nb];
        let (ina, inb) = (d[ia as usize] > 0.0, d[ib as usize] > 0.0);
        if ina == inb {
            continue;
        }
        let axis = if pa[0] != pb[0] {
            0
        } else if pa[1] != pb[1] {
            1
        } else {
            2
        };
        let (lo, i0, i1, len) = if pa[axis] < pb[axis] {
            (pa, ia, ib, pb[axis] - pa[axis])
        } else {
            (pb, ib, ia, pa[axis] - pb[axis])
        };
        let key = edge_key(lo, axis);
        sc.cr.push((key, inb));
        sc.cross.push(Crossing {
            key,
            lo,
            axis: axis as u8,
            len,
            i0,
            i1,
        });
    }
    // Pairing rule (see module docs).
    let f = idx.map(|i| d[i as usize]);
    let fin = f.map(|x| x > 0.0);
    let join_outside = sc.cr.len() == 4
        && fin[0] == fin[2]
        && fin[1] == fin[3]
        && fin[0] != fin[1]
        && (f[0] * f[2] - f[1] * f[3]) / (f[0] + f[2] - f[1] - f[3]) > 0.0;
    let m = sc.cr.len();
    for i in 0..m {
        let (ki, entry) = sc.cr[i];
        let kn = sc.cr[(i + 1) % m].0;
        let seg = match (entry, join_outside) {
            (true, false) => (ki, kn),
            (false, true) => (kn, ki),
            _ => continue,
        };
        sc.segs.push(if flip { (seg.1, seg.0) } else { seg });
    }
}

/// Root of the fitted edge function in `[0, 1]` (ALGORITHM.md §9.2). `x0, x1` are the
/// endpoint values minus iso (opposite signs), `g0, g1` the derivatives along the edge in
/// edge-parameter units.
fn edge_root(x0: f64, x1: f64, g0: f64, g1: f64, linear: bool) -> f64 {
    let lin = x0 / (x0 - x1);
    let lin = if lin.is_nan() {
        0.5
    } else {
        lin.clamp(0.0, 1.0)
    };
    if linear {
        return lin;
    }
    let delta = x1 - x0;
    let scale = delta / ((g0 + g1) * 0.5);
    if !scale.is_finite() {
        return lin;
    }
    let (g0, g1) = (g0 * scale, g1 * scale);
    let a = 3.0 * delta - g1 - 2.0 * g0;
    let b = g0;
    let c = x0;
    const EPS: f64 = 1e-12;
    let ok = |t: f64| t.is_finite() && (-EPS..=1.0 + EPS).contains(&t);
    let (mut sum, mut count) = (0.0, 0);
    if a == 0.0 {
        if b != 0.0 && ok(-c / b) {
            sum = -c / b;
            count = 1;
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            let q = -0.5 * (b + if b >= 0.0 { sq } else { -sq });
            let r1 = q / a;
            let r2 = if q != 0.0 { c / q } else { r1 };
            for r in [r1, r2] {
                if ok(r) {
                    sum += r;
                    count += 1;
                }
            }
        }
    }
    if count == 0 {
        lin
    } else {
        (sum / count as f64).clamp(0.0, 1.0)
    }
}

/// The iso-vertex position on a crossing's edge.
fn crossing_point<C: Cells>(
    ctx: &Ctx<C>,
    corners: &mut CornerCache,
    c: &Crossing,
) -> ([f64; 3], [f64; 3]) {
    let axis = c.axis as usize;
    let (x0, x1) = (corners.d[c.i0 as usize], corners.d[c.i1 as usize]);
    let h = c.len as f64 * ctx.inv;
    let t = if ctx.linear {
        edge_root(x0, x1, 0.0, 0.0, true)
    } else {
        let g0 = corners.grad(ctx, c.i0)[axis] * h;
        let g1 = corners.grad(ctx, c.i1)[axis] * h;
        edge_root(x0, x1, g0, g1, false)
    };
    let mut p = c.lo.map(|x| x as f64 * ctx.inv);
    p[axis] += t * h;
    let mut n = [0.0; 3];
    if ctx.normals {
        let (g0, g1) = (corners.grad(ctx, c.i0), corners.grad(ctx, c.i1));
        let g: [f64; 3] = std::array::from_fn(|a| -((1.0 - t) * g0[a] + t * g1[a]));
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if len > 0.0 && len.is_finite() {
            n = g.map(|x| x / len);
        }
    }
    (p, n)
}

/// A unit vector as `f32`, or zero when `v` has no direction.
fn unit_f32(v: [f64; 3]) -> [f32; 3] {
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if len > 0.0 && len.is_finite() {
        v.map(|x| (x / len) as f32)
    } else {
        [0.0; 3]
    }
}

/// Whether the leaf at `lo` (size `s`) owns the edge vertex of `c`: it contains the edge's
/// midpoint nudged towards + along both other axes (towards − on the cube's far faces).
fn owns<C: Cells>(ctx: &Ctx<C>, lo: [u32; 3], s: u32, c: &Crossing) -> bool {
    let a = c.axis as usize;
    (0..3).filter(|&b| b != a).all(|b| {
        let e = c.lo[b];
        if e < ctx.full {
            lo[b] <= e && e < lo[b] + s
        } else {
            lo[b] + s == ctx.full
        }
    })
}

/// Chains the segments of a leaf into loops and triangulates them.
fn finish_leaf<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    lo: [u32; 3],
    s: u32,
    out: &mut ChunkOut,
) {
    sc.cross.sort_unstable_by_key(|c| c.key);
    sc.cross.dedup_by_key(|c| c.key);
    sc.pos.clear();
    sc.nrm.clear();
    for k in 0..sc.cross.len() {
        let c = sc.cross[k];
        let (p, n) = crossing_point(ctx, &mut sc.corners, &c);
        sc.pos.push(p);
        if ctx.normals {
            sc.nrm.push(n);
        }
        if owns(ctx, lo, s, &c) {
            out.owned_keys.push(c.key);
            out.owned_pos.push(p);
            if ctx.normals {
                out.owned_nrm.push(unit_f32(n));
            }
        }
    }
    sc.segs.sort_unstable();
    if sc.segs.windows(2).any(|w| w[0].0 == w[1].0) {
        sc.bad = true;
        return;
    }
    sc.used.clear();
    sc.used.resize(sc.segs.len(), false);
    for start in 0..sc.segs.len() {
        if sc.used[start] {
            continue;
        }
        sc.poly.clear();
        let mut cur = start;
        loop {
            sc.used[cur] = true;
            let (from, to) = sc.segs[cur];
            match sc.cross.binary_search_by_key(&from, |c| c.key) {
                Ok(i) => sc.poly.push(i as u32),
                Err(_) => {
                    sc.bad = true;
                    return;
                }
            }
            match sc.segs.binary_search_by_key(&to, |s| s.0) {
                Ok(j) if j == start => break,
                Ok(j) if !sc.used[j] => cur = j,
                _ => {
                    sc.bad = true;
                    return;
                }
            }
        }
        if sc.poly.len() >= 3 {
            triangulate(sc, lo, s, out);
        }
    }
}

/// Bit mask of the leaf faces (2·axis + side) that the crossing lies on.
fn face_mask(c: &Crossing, lo: [u32; 3], s: u32) -> u32 {
    let mut m = 0;
    for (b, (&e, &l)) in c.lo.iter().zip(&lo).enumerate() {
        if b == c.axis as usize {
            continue;
        }
        if e == l {
            m |= 1 << (2 * b);
        } else if e == l + s {
            m |= 1 << (2 * b + 1);
        }
    }
    m
}

/// Triangulates the loop in `sc.poly` (indices into `sc.cross`).
#[allow(clippy::needless_range_loop)]
fn triangulate<H>(sc: &mut Scratch<H>, lo: [u32; 3], s: u32, out: &mut ChunkOut) {
    let poly = &sc.poly;
    let k = poly.len();
    let key = |i: usize| sc.cross[poly[i] as usize].key;
    if k == 3 {
        out.tris.push([key(0), key(1), key(2)]);
        return;
    }
    let mut fan = k > MAX_DP;
    if !fan {
        let mut masks = [0u32; MAX_DP];
        for (m, &p) in masks.iter_mut().zip(poly.iter()) {
            *m = face_mask(&sc.cross[p as usize], lo, s);
        }
        'outer: for i in 0..k {
            for j in i + 2..k {
                if i == 0 && j == k - 1 {
                    continue;
                }
                if masks[i] & masks[j] != 0 {
                    fan = true;
                    break 'outer;
                }
            }
        }
    }
    let pos = |i: usize| sc.pos[poly[i] as usize];
    if fan {
        let mut b = [0.0; 3];
        for i in 0..k {
            let p = pos(i);
            for a in 0..3 {
                b[a] += p[a];
            }
        }
        let b = b.map(|x| x / k as f64);
        let r = BARY | out.bary.len() as u64;
        out.bary.push(b);
        if !sc.nrm.is_empty() {
            let mut n = [0.0; 3];
            for i in 0..k {
                let v = sc.nrm[poly[i] as usize];
                for a in 0..3 {
                    n[a] += v[a];
                }
            }
            out.bary_nrm.push(unit_f32(n));
        }
        for i in 0..k {
            out.tris.push([r, key(i), key((i + 1) % k)]);
        }
        return;
    }
    // Minimum-area triangulation by dynamic programming over polygon intervals.
    let mut cost = [[0.0f64; MAX_DP]; MAX_DP];
    let mut split = [[0u8; MAX_DP]; MAX_DP];
    let mut pts = [[0.0f64; 3]; MAX_DP];
    for (i, p) in pts.iter_mut().enumerate().take(k) {
        *p = pos(i);
    }
    let area = |a: usize, b: usize, c: usize| {
        let (pa, pb, pc) = (pts[a], pts[b], pts[c]);
        let u = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
        let v = [pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]];
        let x = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt()
    };
    for gap in 2..k {
        for i in 0..k - gap {
            let j = i + gap;
            let mut best = f64::INFINITY;
            let mut bm = i + 1;
            for m in i + 1..j {
                let c = cost[i][m] + cost[m][j] + area(i, m, j);
                if c < best {
                    best = c;
                    bm = m;
                }
            }
            cost[i][j] = best;
            split[i][j] = bm as u8;
        }
    }
    let mut stack = [(0usize, 0usize); MAX_DP];
    let mut top = 1;
    stack[0] = (0, k - 1);
    while top > 0 {
        top -= 1;
        let (i, j) = stack[top];
        if j < i + 2 {
            continue;
        }
        let m = split[i][j] as usize;
        out.tris.push([key(i), key(m), key(j)]);
        stack[top] = (i, m);
        stack[top + 1] = (m, j);
        top += 2;
    }
}
