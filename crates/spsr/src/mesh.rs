//! Triangle meshes produced by the reconstruction, and their topological checks.

use std::borrow::Cow;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};

use rayon::prelude::*;

use crate::shared_slice::split_into;

use crate::attributes::{self, Attribute, Colors};
use crate::vec3::{cross, dot, norm, sub};

/// A triangle mesh with optional per-vertex normals, density and attributes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<[f64; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    /// Optional per-vertex density (estimated sampling depth, ALGORITHM.md §9.5).
    pub density: Option<Vec<f32>>,
    /// Optional per-vertex normals (one per vertex), e.g. the gradient direction of the
    /// implicit function; written by every output format that has normals.
    pub normals: Option<Vec<[f32; 3]>>,
    /// Per-vertex attributes, one value per vertex each (e.g. colours interpolated from the
    /// points: attributes named `red`, `green`, `blue`, optionally `alpha`; see
    /// [`crate::attributes`]).
    pub attributes: Vec<Attribute>,
}

/// Topological summary of a [`Mesh`], as computed by [`Mesh::topology`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Topology {
    /// Vertices referenced by at least one triangle.
    pub vertices: usize,
    /// Number of triangles.
    pub faces: usize,
    /// Edges used by exactly one triangle.
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Referenced vertices whose incident triangles do not form a single fan.
    pub non_manifold_vertices: usize,
    /// Every edge is used by exactly two triangles.
    pub closed: bool,
    /// No edge is used by more than two triangles.
    pub edge_manifold: bool,
    /// The triangles around every vertex form one fan (a single cycle or a single open chain).
    pub vertex_manifold: bool,
    /// No edge is traversed twice in the same direction, so every interior edge is traversed
    /// in opposite directions by its two triangles (a non-manifold edge makes this false).
    pub oriented: bool,
    /// Connected components of triangles (triangles sharing a vertex are connected).
    pub components: usize,
    /// Euler characteristic `V − E + F`, counting only referenced vertices.
    pub euler: i64,
}

fn uf_find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

fn uf_union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (uf_find(parent, a), uf_find(parent, b));
    if ra != rb {
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[hi as usize] = lo;
    }
}

/// Whether a mesh is closed, and its pieces ([`Mesh::closure`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Closure {
    /// Connected components of triangles, as [`Topology::components`].
    pub pieces: usize,
    /// Every edge is used by exactly two triangles, as [`Topology::closed`].
    pub closed: bool,
    /// Edges used by exactly one triangle, as [`Topology::boundary_edges`].
    pub boundary_edges: usize,
}

/// The edges of a triangle list: how many, how many are used once or more than twice, and
/// whether any is traversed twice in the same direction.
struct EdgeCounts {
    edges: usize,
    boundary: usize,
    non_manifold: usize,
    oriented: bool,
}

impl EdgeCounts {
    /// Each edge is listed at its lower vertex with its other vertex and its direction; each
    /// vertex's short list is then sorted and grouped, vertices in parallel, the counts summed
    /// (so they do not depend on the thread count).
    fn of(nv: usize, tris: &[[u32; 3]]) -> Self {
        let zero = || EdgeCounts {
            edges: 0,
            boundary: 0,
            non_manifold: 0,
            oriented: true,
        };
        fold_vertex_lists(
            nv,
            tris,
            |_, t| {
                (0..3).map(move |k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    (a.min(b), u64::from(a.max(b)) << 1 | u64::from(a < b))
                })
            },
            zero,
            |mut c, _, sides| {
                sides.sort_unstable();
                for group in sides.chunk_by(|x, y| x >> 1 == y >> 1) {
                    let forward = group.iter().filter(|&&s| s & 1 == 1).count();
                    c.edges += 1;
                    match group.len() {
                        1 => c.boundary += 1,
                        2 => {}
                        _ => c.non_manifold += 1,
                    }
                    c.oriented &= forward <= 1 && group.len() - forward <= 1;
                }
                c
            },
            |a, b| EdgeCounts {
                edges: a.edges + b.edges,
                boundary: a.boundary + b.boundary,
                non_manifold: a.non_manifold + b.non_manifold,
                oriented: a.oriented && b.oriented,
            },
        )
    }

    /// Every edge is used by exactly two triangles.
    fn closed(&self) -> bool {
        self.boundary == 0 && self.non_manifold == 0
    }
}

/// Vertices per block of [`fold_vertex_lists`]: a block's lists are sorted out in cache.
const BLOCK_BITS: u32 = 14;

/// Entries carry their vertex within its block above this bit, their payload below it.
const PAYLOAD_BITS: u32 = 48;

/// Folds `visit(acc, v, list)` over every vertex `v`, where `list` holds the payloads
/// (below 2^48) of the `(vertex, payload)` pairs that `each(f, t)` gives for every triangle
/// `f`, in triangle order; `reduce` combines the folds of the blocks of vertices, which run
/// in parallel. Chunks of triangles first write their pairs into the blocks' stretches of one
/// buffer (counted, then placed by prefix sums, chunks in order), then each block sorts its
/// stretch by vertex, all without atomics; the lists do not depend on the thread count.
fn fold_vertex_lists<A: Send, I: Iterator<Item = (u32, u64)>>(
    nv: usize,
    tris: &[[u32; 3]],
    each: impl Fn(u32, [u32; 3]) -> I + Sync,
    init: impl Fn() -> A + Sync + Send,
    visit: impl Fn(A, usize, &mut [u64]) -> A + Sync + Send,
    reduce: impl Fn(A, A) -> A + Sync + Send,
) -> A {
    let blocks = nv.div_ceil(1 << BLOCK_BITS);
    let chunk = tris.len().div_ceil(256).max(1 << 16);
    // Pairs per (chunk, block).
    let counts: Vec<Vec<usize>> = tris
        .par_chunks(chunk)
        .enumerate()
        .map(|(c, part)| {
            let mut count = vec![0; blocks];
            for_chunk_pairs(&each, part, c * chunk, |v, _| {
                count[(v >> BLOCK_BITS) as usize] += 1;
            });
            count
        })
        .collect();
    let mut block_start = vec![0; blocks + 1];
    for b in 0..blocks {
        block_start[b + 1] = block_start[b] + counts.iter().map(|c| c[b]).sum::<usize>();
    }
    let mut buffer = vec![0u64; block_start[blocks]];
    // Each chunk's stretch of every block, block-major so that a block's stretch is whole.
    let mut stretches: Vec<Vec<&mut [u64]>> = counts.iter().map(|_| Vec::new()).collect();
    let lens = (0..blocks).flat_map(|b| counts.iter().map(move |c| c[b]));
    for (i, mine) in split_into(&mut buffer, lens).into_iter().enumerate() {
        stretches[i % counts.len()].push(mine);
    }
    stretches
        .into_par_iter()
        .zip(tris.par_chunks(chunk))
        .enumerate()
        .for_each(|(c, (mut own, part))| {
            let mut fill = vec![0; blocks];
            for_chunk_pairs(&each, part, c * chunk, |v, e| {
                let b = (v >> BLOCK_BITS) as usize;
                let local = u64::from(v & ((1 << BLOCK_BITS) - 1));
                own[b][fill[b]] = local << PAYLOAD_BITS | e;
                fill[b] += 1;
            });
        });
    (0..blocks)
        .into_par_iter()
        .fold(
            || (init(), Vec::new(), Vec::new()),
            |(mut acc, mut start, mut sorted): (A, Vec<usize>, Vec<u64>), b| {
                let first = b << BLOCK_BITS;
                let local_count = (nv - first).min(1 << BLOCK_BITS);
                let stretch = &buffer[block_start[b]..block_start[b + 1]];
                sort_by_vertex(stretch, local_count, &mut start, &mut sorted);
                for l in 0..local_count {
                    acc = visit(acc, first + l, &mut sorted[start[l]..start[l + 1]]);
                }
                (acc, start, sorted)
            },
        )
        .map(|(acc, _, _)| acc)
        .reduce(&init, &reduce)
}

/// Calls `f` on the pairs of the triangles of `part`, the first of which is triangle `first`.
fn for_chunk_pairs<I: Iterator<Item = (u32, u64)>>(
    each: &impl Fn(u32, [u32; 3]) -> I,
    part: &[[u32; 3]],
    first: usize,
    mut f: impl FnMut(u32, u64),
) {
    for (i, t) in part.iter().enumerate() {
        for (v, e) in each((first + i) as u32, *t) {
            f(v, e);
        }
    }
}

/// A block's entries sorted by their vertex within the block (a counting sort, stable):
/// `sorted[start[l]..start[l + 1]]` are the payloads of vertex `l`.
fn sort_by_vertex(
    stretch: &[u64],
    local_count: usize,
    start: &mut Vec<usize>,
    sorted: &mut Vec<u64>,
) {
    start.clear();
    start.resize(local_count + 1, 0);
    for e in stretch {
        start[(e >> PAYLOAD_BITS) as usize + 1] += 1;
    }
    for l in 0..local_count {
        start[l + 1] += start[l];
    }
    sorted.clear();
    sorted.resize(stretch.len(), 0);
    let mut fill = start[..local_count].to_vec();
    for e in stretch {
        let l = (e >> PAYLOAD_BITS) as usize;
        sorted[fill[l]] = e & ((1 << PAYLOAD_BITS) - 1);
        fill[l] += 1;
    }
}

/// Replaces each value by the sum of those before it (wrapping, as `u32`), in parallel by
/// chunks; returns the total.
fn exclusive_prefix_sums(values: &mut [u32]) -> u32 {
    const CHUNK: usize = 1 << 16;
    let totals: Vec<u32> = values
        .par_chunks(CHUNK)
        .map(|c| c.iter().fold(0u32, |a, &x| a.wrapping_add(x)))
        .collect();
    let mut offsets = Vec::with_capacity(totals.len());
    let mut total = 0u32;
    for t in totals {
        offsets.push(total);
        total = total.wrapping_add(t);
    }
    values
        .par_chunks_mut(CHUNK)
        .zip(offsets)
        .for_each(|(chunk, mut acc)| {
            for x in chunk {
                let v = *x;
                *x = acc;
                acc = acc.wrapping_add(v);
            }
        });
    total
}

/// Vertices joined into sets by many threads at once (a lock-free union-find). A root is
/// only ever linked under a smaller one, so each set's root is its smallest vertex: the sets
/// and their roots do not depend on the order of the joins or on the thread count.
struct VertexSets {
    parent: Vec<AtomicU32>,
}

impl VertexSets {
    /// The sets of `nv` vertices where the vertices of each triangle of `tris` that
    /// `valid` accepts are joined.
    fn of(nv: usize, tris: &[[u32; 3]], valid: impl Fn(&[u32; 3]) -> bool + Sync) -> Self {
        let sets = VertexSets {
            parent: (0..nv as u32).into_par_iter().map(AtomicU32::new).collect(),
        };
        tris.par_iter().filter(|t| valid(t)).for_each(|t| {
            sets.join(t[0], t[1]);
            sets.join(t[0], t[2]);
        });
        sets
    }

    /// The root of `x`'s set, halving the path on the way (parents only ever decrease, so
    /// any parent read, however stale, is in the same set).
    fn root(&self, mut x: u32) -> u32 {
        loop {
            let p = self.parent[x as usize].load(Relaxed);
            if p == x {
                return x;
            }
            let up = self.parent[p as usize].load(Relaxed);
            if up != p {
                // A plain store: racing halvings store ancestors too, and links only ever
                // change roots, which `x` is not.
                self.parent[x as usize].store(up, Relaxed);
            }
            x = up;
        }
    }

    /// Joins the sets of `a` and `b`: the larger root is linked under the smaller one,
    /// retried when another thread linked it first.
    fn join(&self, a: u32, b: u32) {
        let (mut a, mut b) = (a, b);
        loop {
            (a, b) = (self.root(a), self.root(b));
            if a == b {
                return;
            }
            let (lo, hi) = (a.min(b), a.max(b));
            if self.parent[hi as usize]
                .compare_exchange(hi, lo, Relaxed, Relaxed)
                .is_ok()
            {
                return;
            }
        }
    }
}

/// Connected components of triangles through shared vertices: the sets that hold the first
/// vertex of some triangle.
fn components(nv: usize, tris: &[[u32; 3]]) -> usize {
    let sets = VertexSets::of(nv, tris, |_| true);
    let used: Vec<AtomicBool> = (0..nv)
        .into_par_iter()
        .map(|_| AtomicBool::new(false))
        .collect();
    tris.par_iter().for_each(|t| {
        let r = sets.root(t[0]) as usize;
        // Read first: a store to a root every thread shares would bounce its cache line.
        if !used[r].load(Relaxed) {
            used[r].store(true, Relaxed);
        }
    });
    used.par_iter().filter(|u| u.load(Relaxed)).count()
}

/// Scratch space for checking one vertex's link ([`Mesh::topology`]).
#[derive(Default)]
struct LinkScratch {
    link: Vec<(u32, u32)>,
    ids: Vec<u32>,
    parent: Vec<u32>,
    degree: Vec<u32>,
}

impl LinkScratch {
    /// Whether the link of vertex `v` (the opposite edges of its incident `faces`) is one
    /// path or one cycle, with no degenerate triangle: the vertex is manifold.
    fn is_disk_or_fan(
        &mut self,
        v: usize,
        faces: impl Iterator<Item = u32>,
        tris: &[[u32; 3]],
    ) -> bool {
        let LinkScratch {
            link,
            ids,
            parent,
            degree,
        } = self;
        link.clear();
        ids.clear();
        for f in faces {
            let t = tris[f as usize];
            let k = t.iter().position(|&x| x as usize == v).unwrap_or(0);
            let (a, b) = (t[(k + 1) % 3], t[(k + 2) % 3]);
            link.push((a, b));
            ids.push(a);
            ids.push(b);
        }
        ids.sort_unstable();
        ids.dedup();
        parent.clear();
        parent.extend(0..ids.len() as u32);
        degree.clear();
        degree.resize(ids.len(), 0);
        let mut ok = true;
        for &(a, b) in link.iter() {
            let ia = ids.binary_search(&a).unwrap_or(0) as u32;
            let ib = ids.binary_search(&b).unwrap_or(0) as u32;
            if ia == ib {
                ok = false; // degenerate triangle
            }
            degree[ia as usize] += 1;
            degree[ib as usize] += 1;
            uf_union(parent, ia, ib);
        }
        if degree.iter().any(|&d| d > 2) {
            ok = false;
        }
        let root = uf_find(parent, 0);
        ok && (0..ids.len() as u32).all(|i| uf_find(parent, i) == root)
    }
}

impl Mesh {
    /// The vertex attribute called `name` (ASCII case ignored), if any.
    pub fn attribute(&self, name: &str) -> Option<&Attribute> {
        attributes::find(&self.attributes, name)
    }

    /// The vertex colour channels, if the mesh has them (see
    /// [`attributes::find_colors`]).
    pub fn colors(&self) -> Option<Colors<'_>> {
        attributes::find_colors(&self.attributes)
    }

    /// Computes the topological summary: boundary and non-manifold edges, vertex manifoldness,
    /// orientation consistency, connected components and Euler characteristic.
    /// Triangles with out-of-range indices are ignored.
    pub fn topology(&self) -> Topology {
        let nv = self.vertices.len();
        let tris = self.valid_triangles();
        let edges = EdgeCounts::of(nv, &tris);
        // Each vertex's link checked in parallel (counts, so the result does not depend on
        // the thread count), with scratch space per task.
        let (referenced, non_manifold_vertices, _) = fold_vertex_lists(
            nv,
            &tris,
            |f, t| t.into_iter().map(move |v| (v, u64::from(f))),
            || (0, 0, LinkScratch::default()),
            |(used, bad, mut scratch), v, faces| {
                if faces.is_empty() {
                    return (used, bad, scratch);
                }
                let fan = scratch.is_disk_or_fan(v, faces.iter().map(|&f| f as u32), &tris);
                (used + 1, bad + usize::from(!fan), scratch)
            },
            |a, b| (a.0 + b.0, a.1 + b.1, a.2),
        );
        Topology {
            vertices: referenced,
            faces: tris.len(),
            boundary_edges: edges.boundary,
            non_manifold_edges: edges.non_manifold,
            non_manifold_vertices,
            closed: edges.closed(),
            edge_manifold: edges.non_manifold == 0,
            vertex_manifold: non_manifold_vertices == 0,
            oriented: edges.oriented,
            components: components(nv, &tris),
            euler: referenced as i64 - edges.edges as i64 + tris.len() as i64,
        }
    }

    /// The part of [`Mesh::topology`] that says whether the mesh is closed and in how many
    /// pieces, without the vertex links (the costliest part, which the reconstruction's own
    /// check does not need).
    pub fn closure(&self) -> Closure {
        let tris = self.valid_triangles();
        let edges = EdgeCounts::of(self.vertices.len(), &tris);
        Closure {
            pieces: components(self.vertices.len(), &tris),
            closed: edges.closed(),
            boundary_edges: edges.boundary,
        }
    }

    /// The triangles whose indices are all in range: borrowed when they all are (the
    /// usual case, which spares a copy of the triangles).
    fn valid_triangles(&self) -> Cow<'_, [[u32; 3]]> {
        let nv = self.vertices.len();
        let valid = |t: &[u32; 3]| t.iter().all(|&v| (v as usize) < nv);
        if self.triangles.par_iter().all(valid) {
            return Cow::Borrowed(&self.triangles);
        }
        Cow::Owned(self.triangles.par_iter().copied().filter(valid).collect())
    }

    /// The pieces of the mesh: for each triangle the piece it belongs to (triangles sharing
    /// a vertex are in one piece, as [`Topology::components`] counts them), numbered in order
    /// of their first triangle, and each piece's area. A triangle with an index out of range
    /// is in no piece (`u32::MAX`); one with a non-finite vertex adds no area to its piece.
    ///
    /// The vertices are joined in parallel; then, a block of triangles at a time, each
    /// triangle's root and area are found in parallel and numbered and added in triangle
    /// order, as a serial loop would (so the areas do not depend on the thread count).
    pub fn pieces(&self) -> (Vec<u32>, Vec<f64>) {
        const BLOCK: usize = 1 << 20;
        let nv = self.vertices.len();
        let valid = |t: &[u32; 3]| t.iter().all(|&v| (v as usize) < nv);
        let sets = VertexSets::of(nv, &self.triangles, valid);
        let mut number = vec![u32::MAX; nv];
        let mut areas: Vec<f64> = Vec::new();
        let mut piece_of = Vec::with_capacity(self.triangles.len());
        let mut block = Vec::with_capacity(BLOCK.min(self.triangles.len()));
        for tris in self.triangles.chunks(BLOCK) {
            block.clear();
            block.par_extend(tris.par_iter().map(|t| {
                if !valid(t) {
                    return (u32::MAX, 0.0);
                }
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                (sets.root(t[0]), 0.5 * norm(cross(sub(b, a), sub(c, a))))
            }));
            piece_of.extend(block.iter().map(|&(r, area)| {
                let Some(n) = number.get_mut(r as usize) else {
                    return u32::MAX;
                };
                if *n == u32::MAX {
                    *n = areas.len() as u32;
                    areas.push(0.0);
                }
                if area.is_finite() {
                    areas[*n as usize] += area;
                }
                *n
            }));
        }
        (piece_of, areas)
    }

    /// The mesh with only the triangles where `keep` is true, and only the vertices they use
    /// (in their original order), every per-vertex value carried along. Built in parallel:
    /// the used vertices are marked, then numbered by prefix sums.
    pub fn keep_triangles(&self, keep: &[bool]) -> Mesh {
        let nv = self.vertices.len();
        let kept = || {
            self.triangles
                .par_iter()
                .zip(keep)
                .filter(|(_, &k)| k)
                .map(|(t, _)| t)
        };
        let marked: Vec<AtomicBool> = (0..nv)
            .into_par_iter()
            .map(|_| AtomicBool::new(false))
            .collect();
        kept().for_each(|t| {
            for &v in t.iter().filter(|&&v| (v as usize) < nv) {
                if !marked[v as usize].load(Relaxed) {
                    marked[v as usize].store(true, Relaxed);
                }
            }
        });
        let is_used: Vec<bool> = marked.into_par_iter().map(AtomicBool::into_inner).collect();
        let used: Vec<usize> = (0..nv).into_par_iter().filter(|&v| is_used[v]).collect();
        // A used vertex's new index is the number of used vertices before it.
        let mut new_index: Vec<u32> = is_used.par_iter().map(|&u| u32::from(u)).collect();
        exclusive_prefix_sums(&mut new_index);
        let pick = |col: &[f32]| used.par_iter().map(|&v| col[v]).collect::<Vec<f32>>();
        Mesh {
            vertices: used.par_iter().map(|&v| self.vertices[v]).collect(),
            triangles: kept()
                .filter(|t| t.iter().all(|&v| (v as usize) < nv))
                .map(|t| t.map(|v| new_index[v as usize]))
                .collect(),
            density: self.density.as_deref().map(pick),
            normals: self
                .normals
                .as_ref()
                .map(|n| used.par_iter().map(|&v| n[v]).collect()),
            attributes: self
                .attributes
                .iter()
                .map(|a| {
                    let values = used.iter().map(|&v| a.data.get(v).unwrap_or(0.0));
                    crate::attributes::Attribute::new(a.name.clone(), a.data.like_from_f64(values))
                })
                .collect(),
        }
    }

    /// Signed enclosed volume (positive when the triangles are counter-clockwise seen from
    /// outside). Meaningful for closed meshes.
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                dot(a, cross(b, c)) / 6.0
            })
            .sum()
    }

    /// Total surface area of the triangles.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                0.5 * norm(cross(sub(b, a), sub(c, a)))
            })
            .sum()
    }

    /// Applies `f` to every vertex position (e.g. to map unit-cube coordinates to world
    /// coordinates).
    pub fn transform(&mut self, f: impl Fn([f64; 3]) -> [f64; 3]) {
        for v in &mut self.vertices {
            *v = f(*v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra() -> Mesh {
        Mesh {
            vertices: vec![[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [0., 0., 1.]],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            ..Default::default()
        }
    }

    #[test]
    fn tetrahedron_is_closed() {
        let m = tetra();
        let t = m.topology();
        assert!(t.closed && t.edge_manifold && t.vertex_manifold && t.oriented);
        assert_eq!((t.vertices, t.faces, t.components, t.euler), (4, 4, 1, 2));
        assert!((m.signed_volume() - 1.0 / 6.0).abs() < 1e-12);
        let area = 1.5 + 3f64.sqrt() / 2.0;
        assert!((m.area() - area).abs() < 1e-12);
    }

    #[test]
    fn open_tetrahedron() {
        let mut m = tetra();
        m.triangles.pop();
        let t = m.topology();
        assert!(!t.closed && t.edge_manifold && t.vertex_manifold && t.oriented);
        assert_eq!(t.boundary_edges, 3);
        assert_eq!(t.euler, 1);
    }

    #[test]
    fn two_tetrahedra_sharing_a_vertex() {
        let mut m = tetra();
        m.vertices
            .extend([[-1., 0., 0.], [0., -1., 0.], [0., 0., -1.]]);
        m.triangles
            .extend([[0, 4, 5], [0, 6, 4], [0, 5, 6], [4, 6, 5]]);
        let t = m.topology();
        assert!(t.closed && t.edge_manifold && t.oriented);
        assert!(!t.vertex_manifold);
        assert_eq!(t.non_manifold_vertices, 1);
        assert_eq!(t.components, 1);
    }

    #[test]
    fn three_triangles_on_an_edge() {
        let m = Mesh {
            vertices: vec![
                [0., 0., 0.],
                [1., 0., 0.],
                [0., 1., 0.],
                [0., -1., 0.],
                [0., 0., 1.],
            ],
            triangles: vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]],
            ..Default::default()
        };
        let t = m.topology();
        assert!(!t.edge_manifold && !t.closed && !t.oriented);
        assert_eq!(t.non_manifold_edges, 1);
    }

    #[test]
    fn flipped_triangle() {
        let mut m = tetra();
        m.triangles[3] = [1, 3, 2];
        let t = m.topology();
        assert!(t.closed && t.edge_manifold && !t.oriented);
    }

    #[test]
    fn closure_agrees_with_topology() {
        let mut open = tetra();
        open.triangles.pop();
        let mut apart = tetra();
        apart
            .vertices
            .extend([[5., 0., 0.], [6., 0., 0.], [5., 1., 0.]]);
        apart.triangles.extend([[4, 5, 6], [4, 6, 5]]);
        let mut stray = tetra();
        stray.triangles.push([0, 1, 9]);
        for m in [tetra(), open, apart, stray] {
            let (t, c) = (m.topology(), m.closure());
            assert_eq!(
                (c.pieces, c.closed, c.boundary_edges),
                (t.components, t.closed, t.boundary_edges)
            );
        }
        let mut apart = tetra();
        apart
            .vertices
            .extend([[5., 0., 0.], [6., 0., 0.], [5., 1., 0.]]);
        apart.triangles.extend([[4, 5, 6], [4, 6, 5]]);
        assert_eq!(apart.closure().pieces, 2);
    }

    #[test]
    fn transform_scales_volume() {
        let mut m = tetra();
        m.transform(|p| [2.0 * p[0], 2.0 * p[1], 2.0 * p[2]]);
        assert!((m.signed_volume() - 8.0 / 6.0).abs() < 1e-12);
    }
}
