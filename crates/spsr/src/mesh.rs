//! Triangle meshes produced by the reconstruction, and their topological checks.

use rayon::prelude::*;

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
        let (start, list) = per_vertex(nv, tris, |_, t| {
            (0..3).map(move |k| {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                (a.min(b), (a.max(b), a < b))
            })
        });
        let zero = || EdgeCounts {
            edges: 0,
            boundary: 0,
            non_manifold: 0,
            oriented: true,
        };
        (0..nv)
            .into_par_iter()
            .fold(
                || (zero(), Vec::new()),
                |(mut c, mut sides): (EdgeCounts, Vec<(u32, bool)>), v| {
                    sides.clear();
                    sides.extend_from_slice(&list[start[v] as usize..start[v + 1] as usize]);
                    sides.sort_unstable();
                    for group in sides.chunk_by(|x, y| x.0 == y.0) {
                        let forward = group.iter().filter(|s| s.1).count();
                        c.edges += 1;
                        match group.len() {
                            1 => c.boundary += 1,
                            2 => {}
                            _ => c.non_manifold += 1,
                        }
                        c.oriented &= forward <= 1 && group.len() - forward <= 1;
                    }
                    (c, sides)
                },
            )
            .map(|(c, _)| c)
            .reduce(zero, |a, b| EdgeCounts {
                edges: a.edges + b.edges,
                boundary: a.boundary + b.boundary,
                non_manifold: a.non_manifold + b.non_manifold,
                oriented: a.oriented && b.oriented,
            })
    }

    /// Every edge is used by exactly two triangles.
    fn closed(&self) -> bool {
        self.boundary == 0 && self.non_manifold == 0
    }
}

/// A list per vertex: `entries[start[v]..start[v + 1]]` are the entries of vertex `v`, in
/// triangle order; `each(f, t)` gives the (vertex, entry) pairs of triangle `f`.
fn per_vertex<T: Copy + Default, I: Iterator<Item = (u32, T)>>(
    nv: usize,
    tris: &[[u32; 3]],
    each: impl Fn(u32, [u32; 3]) -> I,
) -> (Vec<u32>, Vec<T>) {
    let mut start = vec![0u32; nv + 1];
    for (f, t) in tris.iter().enumerate() {
        for (v, _) in each(f as u32, *t) {
            start[v as usize + 1] += 1;
        }
    }
    for v in 0..nv {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut entries = vec![T::default(); start[nv] as usize];
    for (f, t) in tris.iter().enumerate() {
        for (v, e) in each(f as u32, *t) {
            entries[fill[v as usize] as usize] = e;
            fill[v as usize] += 1;
        }
    }
    (start, entries)
}

/// Connected components of triangles through shared vertices.
fn components(nv: usize, tris: &[[u32; 3]]) -> usize {
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    let mut referenced = vec![false; nv];
    for t in tris {
        uf_union(&mut parent, t[0], t[1]);
        uf_union(&mut parent, t[0], t[2]);
        for &v in t {
            referenced[v as usize] = true;
        }
    }
    (0..nv)
        .filter(|&v| referenced[v] && uf_find(&mut parent, v as u32) == v as u32)
        .count()
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
    fn is_disk_or_fan(&mut self, v: usize, faces: &[u32], tris: &[[u32; 3]]) -> bool {
        let LinkScratch {
            link,
            ids,
            parent,
            degree,
        } = self;
        link.clear();
        ids.clear();
        for &f in faces {
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
        let (start, inc) = per_vertex(nv, &tris, |f, t| t.into_iter().map(move |v| (v, f)));
        // Each vertex's link checked in parallel (a count, so the result does not depend on
        // the thread count), with scratch space per task.
        let incident = |v: usize| &inc[start[v] as usize..start[v + 1] as usize];
        let referenced = (0..nv).filter(|&v| !incident(v).is_empty()).count();
        let non_manifold_vertices = (0..nv)
            .into_par_iter()
            .map_init(LinkScratch::default, |scratch, v| {
                let faces = incident(v);
                !faces.is_empty() && !scratch.is_disk_or_fan(v, faces, &tris)
            })
            .filter(|&bad| bad)
            .count();
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

    /// The triangles whose indices are all in range.
    fn valid_triangles(&self) -> Vec<[u32; 3]> {
        let nv = self.vertices.len();
        self.triangles
            .par_iter()
            .copied()
            .filter(|t| t.iter().all(|&v| (v as usize) < nv))
            .collect()
    }

    /// The pieces of the mesh: for each triangle the piece it belongs to (triangles sharing
    /// a vertex are in one piece, as [`Topology::components`] counts them), numbered in order
    /// of their first triangle, and each piece's area. A triangle with an index out of range
    /// is in no piece (`u32::MAX`); one with a non-finite vertex adds no area to its piece.
    pub fn pieces(&self) -> (Vec<u32>, Vec<f64>) {
        let nv = self.vertices.len();
        let mut parent: Vec<u32> = (0..nv as u32).collect();
        fn root(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                let up = parent[parent[x as usize] as usize];
                parent[x as usize] = up;
                x = up;
            }
            x
        }
        let valid = |t: &[u32; 3]| t.iter().all(|&v| (v as usize) < nv);
        for t in self.triangles.iter().filter(|t| valid(t)) {
            let a = root(&mut parent, t[0]);
            for &v in &t[1..] {
                let b = root(&mut parent, v);
                if a != b {
                    parent[b as usize] = a;
                }
            }
        }
        let mut number = vec![u32::MAX; nv];
        let mut areas: Vec<f64> = Vec::new();
        let piece_of = self
            .triangles
            .iter()
            .map(|t| {
                if !valid(t) {
                    return u32::MAX;
                }
                let r = root(&mut parent, t[0]) as usize;
                if number[r] == u32::MAX {
                    number[r] = areas.len() as u32;
                    areas.push(0.0);
                }
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                let area = 0.5 * norm(cross(sub(b, a), sub(c, a)));
                if area.is_finite() {
                    areas[number[r] as usize] += area;
                }
                number[r]
            })
            .collect();
        (piece_of, areas)
    }

    /// The mesh with only the triangles where `keep` is true, and only the vertices they use
    /// (in their original order), every per-vertex value carried along.
    pub fn keep_triangles(&self, keep: &[bool]) -> Mesh {
        let nv = self.vertices.len();
        let mut new_index = vec![u32::MAX; nv];
        for (t, _) in self.triangles.iter().zip(keep).filter(|(_, &k)| k) {
            for &v in t {
                if (v as usize) < nv {
                    new_index[v as usize] = 0;
                }
            }
        }
        let used: Vec<usize> = (0..nv).filter(|&v| new_index[v] == 0).collect();
        for (i, &v) in used.iter().enumerate() {
            new_index[v] = i as u32;
        }
        let pick = |col: &[f32]| used.iter().map(|&v| col[v]).collect::<Vec<f32>>();
        Mesh {
            vertices: used.iter().map(|&v| self.vertices[v]).collect(),
            triangles: self
                .triangles
                .iter()
                .zip(keep)
                .filter(|(t, &k)| k && t.iter().all(|&v| (v as usize) < nv))
                .map(|(t, _)| t.map(|v| new_index[v as usize]))
                .collect(),
            density: self.density.as_deref().map(pick),
            normals: self
                .normals
                .as_ref()
                .map(|n| used.iter().map(|&v| n[v]).collect()),
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
