//! Exact point-to-triangle distances and closest points, and [`MeshDistance`], which answers
//! them for a whole mesh with a bounding-volume hierarchy.

use rayon::prelude::*;

use crate::vec3::{add, cross, dot, norm, norm2, scale, sub, V3};
use crate::Mesh;

/// The point of the triangle `abc` closest to `p` (exact, by the Voronoi regions of the
/// triangle's vertices, edges and face; degenerate triangles are handled as segments or points).
pub fn closest_point_on_triangle(p: V3, a: V3, b: V3, c: V3) -> V3 {
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return add(a, scale(ab, v));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return add(a, scale(ac, w));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        let bc = sub(c, b);
        return add(b, scale(bc, w));
    }
    let denom = va + vb + vc;
    if denom.abs() < f64::MIN_POSITIVE || !denom.is_finite() {
        // Only a degenerate triangle can get here; its closest point lies on one of its edges.
        return [(a, b), (b, c), (c, a)]
            .into_iter()
            .map(|(x, y)| closest_point_on_segment(p, x, y))
            .min_by(|x, y| norm2(sub(p, *x)).total_cmp(&norm2(sub(p, *y))))
            .unwrap_or(a);
    }
    let v = vb / denom;
    let w = vc / denom;
    add(add(a, scale(ab, v)), scale(ac, w))
}

fn closest_point_on_segment(p: V3, a: V3, b: V3) -> V3 {
    let ab = sub(b, a);
    let l = norm2(ab);
    if l <= 0.0 {
        return a;
    }
    let t = (dot(sub(p, a), ab) / l).clamp(0.0, 1.0);
    add(a, scale(ab, t))
}

/// Exact Euclidean distance from `p` to the triangle `abc` (closest point by Voronoi regions).
pub fn point_triangle_distance(p: V3, a: V3, b: V3, c: V3) -> f64 {
    norm(sub(p, closest_point_on_triangle(p, a, b, c)))
}

/// Unit normal of the triangle `abc` (counter-clockwise), or zero for a degenerate triangle.
pub fn triangle_normal(a: V3, b: V3, c: V3) -> V3 {
    let n = cross(sub(b, a), sub(c, a));
    let l = norm(n);
    if l > 0.0 && l.is_finite() {
        [n[0] / l, n[1] / l, n[2] / l]
    } else {
        [0.0; 3]
    }
}

/// Result of a closest-point query against a mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closest {
    /// Euclidean distance from the query point to the mesh.
    pub distance: f64,
    /// The closest point on the mesh.
    pub point: [f64; 3],
    /// Index (into [`Mesh::triangles`]) of the triangle holding the closest point. Ties go to
    /// the triangle met first in the (deterministic) traversal.
    pub triangle: u32,
}

/// Triangles per leaf of the bounding-volume hierarchy.
const LEAF: usize = 4;
/// Subtrees with more triangles than this are built in parallel.
const PAR_BUILD: usize = 1 << 14;

/// A node of the hierarchy: its box and either a leaf range of `order` (`count > 0`) or the
/// index of its right child (`count == 0`; the left child follows the node).
#[derive(Debug, Clone, Copy, Default)]
struct Node {
    lo: [f64; 3],
    hi: [f64; 3],
    index: u32,
    count: u32,
}

impl Node {
    #[inline]
    fn dist2(&self, p: V3) -> f64 {
        let mut d = 0.0;
        for k in 0..3 {
            let e = (self.lo[k] - p[k]).max(p[k] - self.hi[k]).max(0.0);
            d += e * e;
        }
        d
    }
}

/// Number of nodes of the hierarchy over `n` triangles (splits at `n / 2`).
fn node_count(n: usize) -> usize {
    if n <= LEAF {
        1
    } else {
        1 + node_count(n / 2) + node_count(n - n / 2)
    }
}

/// Exact distances and closest points from query points to a triangle mesh, accelerated by a
/// bounding-volume hierarchy (median splits along the longest axis of the triangle
/// centroids, built in parallel). Queries are exact: boxes only prune, every
/// candidate triangle is measured exactly.
///
/// Triangles with an out-of-range index or zero area are left out (a zero-area triangle has
/// no normal and its points lie on its neighbours' edges in any sane mesh). A mesh with no
/// usable triangle gives infinite distances and no closest point.
pub struct MeshDistance<'a> {
    mesh: &'a Mesh,
    nodes: Vec<Node>,
    /// Triangle indices in leaf order.
    order: Vec<u32>,
}

impl<'a> MeshDistance<'a> {
    /// Builds the hierarchy over the mesh's triangles.
    pub fn new(mesh: &'a Mesh) -> Self {
        let nv = mesh.vertices.len();
        let usable = |t: &[u32; 3]| -> Option<V3> {
            if t.iter().any(|&i| i as usize >= nv) {
                return None;
            }
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            let n = cross(sub(b, a), sub(c, a));
            let area2 = norm2(n);
            if !(area2 > 0.0 && area2.is_finite()) {
                return None;
            }
            Some(std::array::from_fn(|k| (a[k] + b[k] + c[k]) / 3.0))
        };
        let centroids: Vec<(u32, V3)> = mesh
            .triangles
            .par_iter()
            .enumerate()
            .filter_map(|(i, t)| usable(t).map(|c| (i as u32, c)))
            .collect();
        if centroids.is_empty() {
            return MeshDistance {
                mesh,
                nodes: Vec::new(),
                order: Vec::new(),
            };
        }
        let mut items: Vec<(u32, [f32; 3])> = centroids
            .into_iter()
            .map(|(t, c)| (t, c.map(|x| x as f32)))
            .collect();
        let mut nodes = vec![Node::default(); node_count(items.len())];
        build(mesh, &mut nodes, &mut items, 0, 0);
        let order = items.into_iter().map(|(t, _)| t).collect();
        MeshDistance { mesh, nodes, order }
    }

    /// The mesh this structure answers queries about.
    pub fn mesh(&self) -> &'a Mesh {
        self.mesh
    }

    /// The closest point of the mesh to `p`, or `None` when the mesh has no usable triangle.
    pub fn closest(&self, p: [f64; 3]) -> Option<Closest> {
        if self.nodes.is_empty() {
            return None;
        }
        let verts = &self.mesh.vertices;
        let tris = &self.mesh.triangles;
        let mut best_d2 = f64::INFINITY;
        let mut best_t = u32::MAX;
        let mut best_q = p;
        // The tree is balanced (depth ≤ 33 for u32 triangle counts): at most one pending
        // sibling per level.
        let mut stack = [(0u32, 0.0f64); 80];
        let mut sp = 1usize;
        stack[0] = (0, self.nodes[0].dist2(p));
        while sp > 0 {
            sp -= 1;
            let (mut i, d) = stack[sp];
            if d >= best_d2 {
                continue;
            }
            loop {
                let node = &self.nodes[i as usize];
                if node.count > 0 {
                    let start = node.index as usize;
                    for &t in &self.order[start..start + node.count as usize] {
                        let [a, b, c] = tris[t as usize].map(|v| verts[v as usize]);
                        let q = closest_point_on_triangle(p, a, b, c);
                        let d2 = norm2(sub(p, q));
                        if d2 < best_d2 {
                            best_d2 = d2;
                            best_t = t;
                            best_q = q;
                        }
                    }
                    break;
                }
                let (l, r) = (i + 1, node.index);
                let (dl, dr) = (
                    self.nodes[l as usize].dist2(p),
                    self.nodes[r as usize].dist2(p),
                );
                let ((near, dn), (far, df)) = if dl <= dr {
                    ((l, dl), (r, dr))
                } else {
                    ((r, dr), (l, dl))
                };
                if df < best_d2 {
                    stack[sp] = (far, df);
                    sp += 1;
                }
                if dn < best_d2 {
                    i = near;
                } else {
                    break;
                }
            }
        }
        (best_t != u32::MAX).then(|| Closest {
            distance: best_d2.sqrt(),
            point: best_q,
            triangle: best_t,
        })
    }

    /// Distance from `p` to the mesh surface (infinite when the mesh has no usable triangle).
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        self.closest(p).map_or(f64::INFINITY, |c| c.distance)
    }

    /// Distances from many points, in parallel (order preserved).
    pub fn distances(&self, pts: &[[f64; 3]]) -> Vec<f64> {
        pts.par_iter().map(|&p| self.distance(p)).collect()
    }

    /// Mean distance from the points to the mesh (0 for no points).
    pub fn mean_distance(&self, pts: &[[f64; 3]]) -> f64 {
        if pts.is_empty() {
            return 0.0;
        }
        self.distances(pts).iter().sum::<f64>() / pts.len() as f64
    }
}

/// An integer with the order of the float (IEEE total order).
#[inline]
fn ordered(x: f32) -> i32 {
    let b = x.to_bits() as i32;
    b ^ (((b >> 31) as u32) >> 1) as i32
}

/// Builds the subtree over `items` into `nodes` (exactly `node_count(items.len())` long);
/// `node_base` is the global index of `nodes[0]`, `item_base` that of `items[0]`.
fn build(
    mesh: &Mesh,
    nodes: &mut [Node],
    items: &mut [(u32, [f32; 3])],
    node_base: u32,
    item_base: u32,
) {
    let n = items.len();
    if n <= LEAF {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for &(t, _) in items.iter() {
            for v in mesh.triangles[t as usize] {
                let x = mesh.vertices[v as usize];
                for k in 0..3 {
                    lo[k] = lo[k].min(x[k]);
                    hi[k] = hi[k].max(x[k]);
                }
            }
        }
        nodes[0] = Node {
            lo,
            hi,
            index: item_base,
            count: n as u32,
        };
        return;
    }
    let mut clo = [f32::INFINITY; 3];
    let mut chi = [f32::NEG_INFINITY; 3];
    for (_, c) in items.iter() {
        for k in 0..3 {
            clo[k] = clo[k].min(c[k]);
            chi[k] = chi[k].max(c[k]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
        .unwrap_or(0);
    // Median split along the centroids' longest axis (ties by triangle index, so the split
    // is fully determined).
    let mid = n / 2;
    items.select_nth_unstable_by_key(mid, |x| (ordered(x.1[axis]), x.0));
    let left_nodes = node_count(mid);
    let (head, rest) = nodes.split_at_mut(1);
    let (lnodes, rnodes) = rest.split_at_mut(left_nodes);
    let (litems, ritems) = items.split_at_mut(mid);
    let right_base = node_base + 1 + left_nodes as u32;
    if n > PAR_BUILD {
        rayon::join(
            || build(mesh, lnodes, litems, node_base + 1, item_base),
            || build(mesh, rnodes, ritems, right_base, item_base + mid as u32),
        );
    } else {
        build(mesh, lnodes, litems, node_base + 1, item_base);
        build(mesh, rnodes, ritems, right_base, item_base + mid as u32);
    }
    let (l, r) = (&lnodes[0], &rnodes[0]);
    head[0] = Node {
        lo: std::array::from_fn(|k| l.lo[k].min(r.lo[k])),
        hi: std::array::from_fn(|k| l.hi[k].max(r.hi[k])),
        index: right_base,
        count: 0,
    };
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::sample_surface;

    #[test]
    fn distance_to_a_triangle_matches_hand_computed_cases() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert!((point_triangle_distance([0.25, 0.25, 2.0], a, b, c) - 2.0).abs() < 1e-15);
        assert!((point_triangle_distance([-1.0, 0.0, 0.0], a, b, c) - 1.0).abs() < 1e-15);
        assert!((point_triangle_distance([1.0, 1.0, 0.0], a, b, c) - 0.5f64.sqrt()).abs() < 1e-15);
        assert!((point_triangle_distance([2.0, -1.0, 0.0], a, b, c) - 2f64.sqrt()).abs() < 1e-15);
    }

    #[test]
    fn grid_search_equals_brute_force() {
        // A coarse octahedron and random query points near and far.
        let mesh = Mesh {
            vertices: vec![
                [1.0, 0.0, 0.0],
                [-1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, -1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, 0.0, -1.0],
            ],
            triangles: vec![
                [0, 2, 4],
                [2, 1, 4],
                [1, 3, 4],
                [3, 0, 4],
                [2, 0, 5],
                [1, 2, 5],
                [3, 1, 5],
                [0, 3, 5],
            ],
            ..Default::default()
        };
        let md = MeshDistance::new(&mesh);
        let mut s = 3u64;
        for _ in 0..300 {
            let mut r = || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64 * 6.0 - 3.0
            };
            let p = [r(), r(), r()];
            let brute = mesh
                .triangles
                .iter()
                .map(|t| {
                    point_triangle_distance(
                        p,
                        mesh.vertices[t[0] as usize],
                        mesh.vertices[t[1] as usize],
                        mesh.vertices[t[2] as usize],
                    )
                })
                .fold(f64::INFINITY, f64::min);
            assert!((md.distance(p) - brute).abs() < 1e-12);
        }
        let pts = sample_surface(&mesh, 1000, 1);
        assert!(md.distances(&pts).iter().all(|&d| d < 1e-12));
    }

    fn xorshift(s: &mut u64) -> f64 {
        *s ^= *s << 13;
        *s ^= *s >> 7;
        *s ^= *s << 17;
        (*s >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A bumpy open grid of 2 × 40 × 40 triangles plus a far-away triangle.
    fn bumpy() -> Mesh {
        let n = 40u32;
        let mut vertices = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
                vertices.push([x, y, 0.1 * (7.0 * x).sin() * (5.0 * y).cos()]);
            }
        }
        let id = |i: u32, j: u32| j * (n + 1) + i;
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        let k = vertices.len() as u32;
        vertices.extend([[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [5.0, 6.0, 5.0]]);
        triangles.push([k, k + 1, k + 2]);
        Mesh {
            vertices,
            triangles,
            ..Default::default()
        }
    }

    #[test]
    fn closest_triangle_equals_brute_force() {
        let mesh = bumpy();
        let md = MeshDistance::new(&mesh);
        let mut s = 7u64;
        for _ in 0..2000 {
            let p = [
                xorshift(&mut s) * 8.0 - 1.0,
                xorshift(&mut s) * 8.0 - 1.0,
                xorshift(&mut s) * 8.0 - 1.0,
            ];
            let (bt, bd) = mesh
                .triangles
                .iter()
                .enumerate()
                .map(|(i, t)| {
                    let [a, b, c] = t.map(|v| mesh.vertices[v as usize]);
                    (i, point_triangle_distance(p, a, b, c))
                })
                .min_by(|x, y| x.1.total_cmp(&y.1))
                .unwrap();
            let c = md.closest(p).unwrap();
            assert!((c.distance - bd).abs() < 1e-12, "{p:?}");
            // The reported triangle really is at that distance, and so is the reported point.
            let [a, b, cc] = mesh.triangles[c.triangle as usize].map(|v| mesh.vertices[v as usize]);
            assert!((point_triangle_distance(p, a, b, cc) - bd).abs() < 1e-12);
            assert!((norm(sub(p, c.point)) - bd).abs() < 1e-12);
            if c.triangle as usize != bt {
                // Only a tie may pick another triangle.
                let [a, b, cc] = mesh.triangles[bt].map(|v| mesh.vertices[v as usize]);
                assert!((point_triangle_distance(p, a, b, cc) - c.distance).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn degenerate_and_invalid_triangles_are_skipped() {
        let mut mesh = bumpy();
        let k = mesh.vertices.len() as u32;
        mesh.vertices.push([0.5, 0.5, 3.0]);
        mesh.triangles.push([k, k, k]); // a point far above the grid
        mesh.triangles.push([0, 1, 99_999]); // out of range
        let md = MeshDistance::new(&mesh);
        assert!(md.distance([0.5, 0.5, 3.0]) > 2.0);
        let empty = Mesh::default();
        assert_eq!(MeshDistance::new(&empty).closest([0.0; 3]), None);
        assert_eq!(MeshDistance::new(&empty).distance([0.0; 3]), f64::INFINITY);
        assert!(sample_surface(&empty, 10, 1).is_empty());
    }

    #[test]
    fn degenerate_triangle_closest_point() {
        // Collinear vertices: the closest point is on the segment.
        let q =
            closest_point_on_triangle([0.5, 1.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert!(norm2(sub(q, [0.5, 0.0, 0.0])) < 1e-24);
        assert_eq!(
            triangle_normal([0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]),
            [0.0; 3]
        );
    }
}
