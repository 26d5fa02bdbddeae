//! Block scheduling: the leaves are polygonised block by block in parallel
//! ([`extract_blocks`]), each block with its own corner cache and output, and the blocks'
//! outputs are then numbered globally and assembled into one mesh ([`Blocks::assemble`]).

use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use super::cells::{bad_leaves, check_depth, LeafSet};
use super::faces::{boundary_uniform, leaf_faces, Here};
use super::table::Table;
use super::triangulate::triangulate_loops;
use super::vertex::{place_vertices, Crossing};
use super::{pack, Cells, Field, Leaf, BARY};
use crate::mesh::Mesh;
use crate::shared_slice::split_into;

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

/// Shared read-only state of the per-leaf pass.
pub(super) struct Ctx<'a, C: Cells> {
    pub(super) cells: &'a C,
    field: &'a dyn Field<C::Handle>,
    iso: f64,
    pub(super) max_depth: u32,
    pub(super) full: u32,
    pub(super) inv: f64,
    pub(super) linear: bool,
    pub(super) normals: bool,
    /// The field is trilinear on the corner grid's cells ([`Field::trilinear`]).
    trilinear: bool,
}

/// The field at the corners a block has asked for: `χ − iso`, and the gradient once needed.
///
/// Corners inside the block's box (set by [`CornerCache::begin`]) are found through a dense
/// grid of slots, which costs one load instead of a hash probe; a corner outside it, or every
/// corner of a box too large for the grid, goes through the hash map.
pub(super) struct CornerCache<H> {
    index: FxHashMap<u64, u32>,
    /// For each corner of the box, its index plus one, or 0 while not yet asked for.
    grid: Vec<u32>,
    /// Lowest corner of the box.
    lo: [u32; 3],
    /// Corners per axis of the box (all 0 when the grid is off).
    dims: [u32; 3],
    at: Vec<[u32; 3]>,
    /// For each corner, a leaf whose closure holds it (the field's hint).
    near: Vec<H>,
    pub(super) d: Vec<f64>,
    /// The derivatives along each axis, NaN until needed ([`CornerCache::slope`]).
    g: Vec<[f64; 3]>,
}

/// Most slots of the dense corner grid (16 MiB): a block of 128 finest cells per axis (129³
/// corners) fits, which is a block of the base depth 5 at depth 12.
const MAX_GRID: usize = 1 << 22;

impl<H> Default for CornerCache<H> {
    fn default() -> Self {
        Self {
            index: FxHashMap::default(),
            grid: Vec::new(),
            lo: [0; 3],
            dims: [0; 3],
            at: Vec::new(),
            near: Vec::new(),
            d: Vec::new(),
            g: Vec::new(),
        }
    }
}

impl<H: Copy> CornerCache<H> {
    /// Starts a block whose leaves' corners lie in the box `lo ..= hi`, forgetting the
    /// previous block's corners (only the slots they used are reset).
    fn begin(&mut self, lo: [u32; 3], hi: [u32; 3]) {
        for i in 0..self.at.len() {
            if let Some(k) = self.slot(self.at[i]) {
                self.grid[k] = 0;
            }
        }
        self.index.clear();
        self.at.clear();
        self.near.clear();
        self.d.clear();
        self.g.clear();
        let dims: [u32; 3] = std::array::from_fn(|a| (hi[a] + 1).saturating_sub(lo[a]));
        let size = dims.iter().map(|&x| x as usize).product::<usize>();
        if size > MAX_GRID || size == 0 {
            self.dims = [0; 3];
            return;
        }
        if self.grid.len() < size {
            self.grid.resize(size, 0);
        }
        self.lo = lo;
        self.dims = dims;
    }

    /// The grid slot of corner `c`, if it lies in the box.
    #[inline]
    fn slot(&self, c: [u32; 3]) -> Option<usize> {
        let r: [u32; 3] = std::array::from_fn(|a| c[a].wrapping_sub(self.lo[a]));
        if (0..3).all(|a| r[a] < self.dims[a]) {
            let [nx, ny, _] = self.dims.map(|x| x as usize);
            Some(r[0] as usize + nx * (r[1] as usize + ny * r[2] as usize))
        } else {
            None
        }
    }

    /// Index of the corner at `c`, on the closure of leaf `near`, evaluating the field there
    /// the first time.
    #[inline]
    pub(super) fn get<C: Cells<Handle = H>>(&mut self, ctx: &Ctx<C>, c: [u32; 3], near: H) -> u32 {
        let (i, new) = self.register(c, near);
        if new {
            self.d[i as usize] = ctx.field.value(c, near) - ctx.iso;
        }
        i
    }

    /// Index of the corner at `c`, and whether it is new (its value then still to be set).
    #[inline]
    fn register(&mut self, c: [u32; 3], near: H) -> (u32, bool) {
        let next = self.d.len() as u32;
        let i = match self.slot(c) {
            Some(k) => {
                let e = &mut self.grid[k];
                if *e == 0 {
                    *e = next + 1;
                }
                *e - 1
            }
            None => *self.index.entry(pack(c)).or_insert(next),
        };
        if i == next {
            self.at.push(c);
            self.near.push(near);
            self.d.push(0.0);
            self.g.push([f64::NAN; 3]);
        }
        (i, i == next)
    }

    /// Gradient at corner `i` (unit-cube units), evaluated the first time it is needed.
    #[inline]
    pub(super) fn grad<C: Cells<Handle = H>>(&mut self, ctx: &Ctx<C>, i: u32) -> [f64; 3] {
        [0, 1, 2].map(|a| self.slope(ctx, i, a))
    }

    /// The derivative along `axis` at corner `i` (unit-cube units), evaluated the first time
    /// it is needed: from the field's gradient, or, for a field trilinear on the corner
    /// grid's cells ([`Field::trilinear`]), from the values at the corner's two neighbours
    /// on that axis.
    #[inline]
    pub(super) fn slope<C: Cells<Handle = H>>(&mut self, ctx: &Ctx<C>, i: u32, axis: usize) -> f64 {
        let k = i as usize;
        let known = self.g[k][axis];
        if !known.is_nan() {
            return known;
        }
        if ctx.trilinear {
            let s = self.central_difference(ctx, i, axis);
            self.g[k][axis] = s;
            s
        } else {
            let g = ctx.field.corner(self.at[k], self.near[k]).1;
            self.g[k] = g;
            g[axis]
        }
    }

    /// The derivative along `axis` at corner `i` of a field trilinear on the corner grid's
    /// cells: the mean of the slopes of the two grid edges that meet there along the axis
    /// (the one edge's at the unit cube's faces). Along an edge of a cell the field is linear,
    /// so each slope is exact: this is the mean of the one-sided derivatives, the central
    /// gradient [`Field::corner`] gives for degree 1, from two values instead of two
    /// gradients (issue 20). Most neighbours are corners of leaves already asked for.
    fn central_difference<C: Cells<Handle = H>>(
        &mut self,
        ctx: &Ctx<C>,
        i: u32,
        axis: usize,
    ) -> f64 {
        let (c, near) = (self.at[i as usize], self.near[i as usize]);
        let step = |me: &mut Self, up: bool| {
            let mut p = c;
            p[axis] = if up { p[axis] + 1 } else { p[axis] - 1 };
            let j = me.get(ctx, p, near);
            me.d[j as usize]
        };
        let up = (c[axis] < ctx.full).then(|| step(self, true));
        let down = (c[axis] > 0).then(|| step(self, false));
        let here = self.d[i as usize];
        let per_cell = (1u64 << ctx.max_depth) as f64;
        match (down, up) {
            (Some(a), Some(b)) => 0.5 * (b - a) * per_cell,
            (None, Some(b)) => (b - here) * per_cell,
            (Some(a), None) => (here - a) * per_cell,
            (None, None) => 0.0,
        }
    }
}

/// Reusable per-thread buffers.
pub(super) struct Scratch<H> {
    leaves: Vec<(H, u32, [u32; 3])>,
    pub(super) corners: CornerCache<H>,
    pub(super) bv: Vec<([u32; 3], u32)>,
    pub(super) cr: Vec<(u64, bool)>,
    pub(super) cross: Vec<Crossing>,
    pub(super) pos: Vec<[f64; 3]>,
    pub(super) nrm: Vec<[f64; 3]>,
    pub(super) segs: Vec<(u64, u64)>,
    pub(super) used: Vec<bool>,
    pub(super) poly: Vec<u32>,
    pub(super) bad: bool,
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
pub(super) struct ChunkOut {
    pub(super) owned_keys: Vec<u64>,
    pub(super) owned_pos: Vec<[f64; 3]>,
    pub(super) owned_nrm: Vec<[f32; 3]>,
    pub(super) bary: Vec<[f64; 3]>,
    pub(super) bary_nrm: Vec<[f32; 3]>,
    pub(super) tris: Vec<[u64; 3]>,
    bad: bool,
}

impl ChunkOut {
    /// Gives back the spare capacity the vectors grew into: the blocks of a whole run are
    /// held together until they are assembled, and doubling leaves up to half of each
    /// block's arrays unused (about 90 MiB at a million points, depth 10; issue 20).
    fn shrink_to_fit(&mut self) {
        self.owned_keys.shrink_to_fit();
        self.owned_pos.shrink_to_fit();
        self.owned_nrm.shrink_to_fit();
        self.bary.shrink_to_fit();
        self.bary_nrm.shrink_to_fit();
        self.tris.shrink_to_fit();
    }
}

/// The per-block output of [`extract_blocks`], before vertices are numbered globally.
pub struct Blocks {
    chunks: Vec<ChunkOut>,
}

/// The extraction proper on a leaf list; also returns the number of edge iso-vertices
/// (without barycentres) and, in test builds only, which output vertices are edge
/// iso-vertices.
pub(super) fn extract_impl(
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
    field: &dyn Field<C::Handle>,
    iso: f64,
    opts: &ExtractOptions,
) -> crate::Result<Blocks> {
    let max_depth = cells.max_depth();
    check_depth(max_depth)?;
    let ctx = Ctx {
        cells,
        field,
        iso,
        max_depth,
        full: 1u32 << max_depth,
        inv: 1.0 / (1u64 << max_depth) as f64,
        linear: opts.linear_fit,
        normals: opts.normals,
        trilinear: field.trilinear(),
    };
    let chunks: Vec<ChunkOut> = (0..cells.block_count())
        .into_par_iter()
        .map_init(Scratch::<C::Handle>::default, |sc, b| {
            let mut out = ChunkOut::default();
            let mut leaves = std::mem::take(&mut sc.leaves);
            leaves.clear();
            cells.for_each_leaf(b, &mut |h, d, o| leaves.push((h, d, o)));
            let (lo, hi) = corner_box(&leaves, max_depth);
            sc.corners.begin(lo, hi);
            for &(h, depth, offset) in &leaves {
                process_leaf(&ctx, sc, h, depth, offset, &mut out);
                if sc.bad {
                    sc.bad = false;
                    out.bad = true;
                }
            }
            sc.leaves = leaves;
            out.shrink_to_fit();
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

/// The box of finest-grid corners of a block's leaves (empty, `lo > hi`, without leaves).
fn corner_box<H>(leaves: &[(H, u32, [u32; 3])], max_depth: u32) -> ([u32; 3], [u32; 3]) {
    let mut lo = [u32::MAX; 3];
    let mut hi = [0u32; 3];
    for &(_, depth, offset) in leaves {
        let s = 1u32 << (max_depth - depth);
        for a in 0..3 {
            lo[a] = lo[a].min(offset[a] * s);
            hi[a] = hi[a].max((offset[a] + 1) * s);
        }
    }
    (lo, hi)
}

/// One part's vertices numbered on their own (see [`Blocks::into_part`]).
#[derive(Debug, Default)]
pub struct Part {
    /// Vertex positions, unit-cube coordinates.
    pub vertices: Vec<[f64; 3]>,
    /// Vertex normals, when extracted with normals.
    pub normals: Option<Vec<[f32; 3]>>,
    /// The edge key of each vertex (`u64::MAX` for a barycentre).
    pub keys: Vec<u64>,
    /// Triangles: a local vertex index, or [`FOREIGN`] plus the edge key of a vertex that
    /// another part owns (on a face the parts share).
    pub triangles: Vec<[u64; 3]>,
    /// Per-vertex density, when asked for (set by the caller: `crate::slabs`).
    pub density: Option<Vec<f32>>,
    /// Per-vertex attribute values, one per carried attribute, vertex after vertex (set by
    /// the caller: `crate::slabs`).
    pub attributes: Option<Vec<f64>>,
}

/// Marks a triangle corner of a [`Part`] that refers to another part's vertex by edge key.
pub const FOREIGN: u64 = 1 << 62;

impl Blocks {
    /// Numbers this part's own vertices (owned edge vertices and barycentres, block by block,
    /// as [`Blocks::assemble`] does) without the other parts': a corner whose vertex another
    /// part owns keeps its edge key, marked [`FOREIGN`]. Vertices no triangle of this part
    /// uses are kept (another part may use them).
    pub fn into_part(self) -> Part {
        let chunks = self.chunks;
        let total: usize = chunks
            .iter()
            .map(|c| c.owned_keys.len() + c.bary.len())
            .sum();
        let with_normals = chunks
            .iter()
            .any(|c| !c.owned_nrm.is_empty() || !c.bary_nrm.is_empty());
        let mut own: FxHashMap<u64, u32> = FxHashMap::default();
        own.reserve(total);
        let mut part = Part {
            vertices: Vec::with_capacity(total),
            normals: with_normals.then(|| Vec::with_capacity(total)),
            keys: Vec::with_capacity(total),
            triangles: Vec::with_capacity(chunks.iter().map(|c| c.tris.len()).sum()),
            density: None,
            attributes: None,
        };
        let mut base = 0u64;
        let mut bases = Vec::with_capacity(chunks.len());
        for c in &chunks {
            for (i, &k) in c.owned_keys.iter().enumerate() {
                own.insert(k, (base + i as u64) as u32);
            }
            bases.push(base);
            base += (c.owned_keys.len() + c.bary.len()) as u64;
        }
        for (c, base) in chunks.into_iter().zip(bases) {
            let bary_base = base + c.owned_keys.len() as u64;
            part.triangles.extend(c.tris.iter().map(|t| {
                t.map(|r| {
                    if r & BARY != 0 {
                        bary_base + (r & !BARY)
                    } else {
                        own.get(&r).map_or(FOREIGN | r, |&i| u64::from(i))
                    }
                })
            }));
            part.keys.extend_from_slice(&c.owned_keys);
            part.keys
                .extend(std::iter::repeat_n(u64::MAX, c.bary.len()));
            part.vertices.extend_from_slice(&c.owned_pos);
            part.vertices.extend_from_slice(&c.bary);
            if let Some(n) = &mut part.normals {
                n.extend_from_slice(&c.owned_nrm);
                n.extend_from_slice(&c.bary_nrm);
            }
        }
        part
    }

    /// The vertex positions in the order [`Blocks::assemble`] and [`Blocks::into_part`]
    /// number them (each block's owned vertices, then its barycentres).
    pub fn vertices(&self) -> impl Iterator<Item = &[f64; 3]> {
        self.chunks
            .iter()
            .flat_map(|c| c.owned_pos.iter().chain(&c.bary))
    }

    /// The blocks of several parts (slabs) in order, to be numbered as one mesh.
    pub fn concat(parts: Vec<Blocks>) -> Blocks {
        Blocks {
            chunks: parts.into_iter().flat_map(|b| b.chunks).collect(),
        }
    }

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
        let with_normals = chunks
            .iter()
            .any(|c| !c.owned_nrm.is_empty() || !c.bary_nrm.is_empty());
        let is_edge = if cfg!(test) {
            chunks
                .iter()
                .flat_map(|c| {
                    let own = std::iter::repeat_n(true, c.owned_pos.len());
                    own.chain(std::iter::repeat_n(false, c.bary.len()))
                })
                .collect()
        } else {
            Vec::new()
        };
        // Each block's share of the mesh is a fixed range of each array (its place in the
        // block order), filled by blocks in parallel; a block's output is freed once copied.
        let mut triangles = vec![[0u32; 3]; chunks.iter().map(|c| c.tris.len()).sum()];
        let mut vertices = vec![[0.0f64; 3]; total];
        let nrm_len = |c: &ChunkOut| c.owned_nrm.len() + c.bary_nrm.len();
        let mut normals = vec![[0.0f32; 3]; chunks.iter().map(nrm_len).sum()];
        let tri_parts = split_into(&mut triangles, chunks.iter().map(|c| c.tris.len()));
        let pos_parts = split_into(
            &mut vertices,
            chunks.iter().map(|c| c.owned_pos.len() + c.bary.len()),
        );
        let nrm_parts = split_into(&mut normals, chunks.iter().map(nrm_len));
        chunks
            .into_par_iter()
            .zip(bases)
            .zip(tri_parts)
            .zip(pos_parts)
            .zip(nrm_parts)
            .for_each(|((((c, base), tris), pos), nrm)| {
                let bary_base = (base + c.owned_keys.len()) as u64;
                for (out, t) in tris.iter_mut().zip(&c.tris) {
                    *out = t.map(|r| {
                        if r & BARY != 0 {
                            (bary_base + (r & !BARY)) as u32
                        } else {
                            vt.get(r).unwrap_or(u32::MAX)
                        }
                    });
                }
                let (own, bary) = pos.split_at_mut(c.owned_pos.len());
                own.copy_from_slice(&c.owned_pos);
                bary.copy_from_slice(&c.bary);
                let (own, bary) = nrm.split_at_mut(c.owned_nrm.len());
                own.copy_from_slice(&c.owned_nrm);
                bary.copy_from_slice(&c.bary_nrm);
            });
        drop(vt);
        // Per triangle, not `flatten`: rayon's `flatten` makes an iterator of each triangle,
        // which cost more than the test.
        let unowned = triangles.par_iter().any(|t| t.contains(&u32::MAX));
        if unowned {
            return Err(bad_leaves(
                "the leaves do not tile the unit cube (unowned iso-vertex)",
            ));
        }
        let mut is_edge = is_edge;
        drop_unused(
            &mut vertices,
            &mut normals,
            with_normals,
            &mut is_edge,
            &mut triangles,
        );
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

/// Drops the vertices no triangle uses (possible only next to dropped two-vertex loops), with
/// their normals and (in test builds) edge flags, and renumbers the triangles.
fn drop_unused(
    vertices: &mut Vec<[f64; 3]>,
    normals: &mut Vec<[f32; 3]>,
    with_normals: bool,
    is_edge: &mut Vec<bool>,
    triangles: &mut [[u32; 3]],
) {
    let marks: Vec<AtomicBool> = (0..vertices.len())
        .map(|_| AtomicBool::new(false))
        .collect();
    triangles.par_iter().for_each(|t| {
        for &i in t {
            marks[i as usize].store(true, Ordering::Relaxed);
        }
    });
    if marks.par_iter().all(|u| u.load(Ordering::Relaxed)) {
        return;
    }
    let used: Vec<bool> = marks.into_iter().map(AtomicBool::into_inner).collect();
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
    *vertices = kept;
    *normals = kept_nrm;
    if cfg!(test) {
        *is_edge = is_edge
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
        *ci = sc.corners.get(ctx, p, h);
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
    if (inside == 0 || inside == 0xff) && boundary_uniform(ctx, sc, here, lo, s, inside != 0) {
        return; // no corner on the boundary changes sign
    }
    sc.cross.clear();
    sc.segs.clear();
    leaf_faces(ctx, sc, here, lo, s, &cidx);
    if sc.segs.is_empty() || sc.bad {
        return;
    }
    place_vertices(ctx, sc, lo, s, out);
    triangulate_loops(sc, lo, s, out);
}
