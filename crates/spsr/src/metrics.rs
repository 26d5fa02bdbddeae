//! Accuracy metrics: exact point-to-mesh distances, area-uniform surface samples, and the
//! evaluation of a mesh against a ground truth ([`evaluate`]: Chamfer and Hausdorff distances,
//! F-scores, normal consistency, topology).
//!
//! Everything here is deterministic: samples come from a counter-based generator (sample `i`
//! depends only on the seed and `i`), parallel queries are collected in order and reduced
//! sequentially, so the numbers do not depend on the number of threads.

use rayon::prelude::*;

use crate::mesh::Topology;
use crate::morton::BoxKeys;
use crate::vec3::{add, cross, dot, norm, norm2, scale, sub, V3};
use crate::{Error, Mesh, Result};

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

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Four uniform numbers in `[0, 1)` for sample `i` of the stream `seed` (counter-based, so
/// samples can be drawn in parallel and in any order).
#[inline]
fn uniforms(seed: u64, i: u64) -> [f64; 4] {
    let base = mix64(seed ^ 0x9e37_79b9_7f4a_7c15).wrapping_add(i.wrapping_mul(4));
    std::array::from_fn(|k| {
        let r = mix64(
            base.wrapping_add(k as u64)
                .wrapping_mul(0x9e37_79b9_7f4a_7c15),
        );
        (r >> 11) as f64 / (1u64 << 53) as f64
    })
}

/// Walker's alias table over `weights` (Vose's construction): `pick(u, v)` returns index `i`
/// with probability `weights[i] / Σ weights` in O(1), with two memory reads.
struct AliasTable {
    prob: Vec<f64>,
    alias: Vec<u32>,
}

impl AliasTable {
    fn new(weights: &[f64], total: f64) -> Self {
        let n = weights.len();
        let scale = n as f64 / total;
        let mut prob: Vec<f64> = weights.iter().map(|w| w * scale).collect();
        let mut alias: Vec<u32> = (0..n as u32).collect();
        let (mut small, mut large): (Vec<u32>, Vec<u32>) =
            (0..n as u32).partition(|&i| prob[i as usize] < 1.0);
        while let (Some(&s), Some(&l)) = (small.last(), large.last()) {
            small.pop();
            alias[s as usize] = l;
            let rest = prob[l as usize] - (1.0 - prob[s as usize]);
            prob[l as usize] = rest;
            if rest < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // Leftovers are 1 up to rounding; a zero-weight leftover keeps its own index and is
        // caught by the caller's fallback.
        for i in large.into_iter().chain(small) {
            if prob[i as usize] > 0.0 {
                prob[i as usize] = 1.0;
            }
        }
        AliasTable { prob, alias }
    }

    #[inline]
    fn pick(&self, u: f64, v: f64) -> usize {
        let n = self.prob.len();
        let i = ((u * n as f64) as usize).min(n - 1);
        if v < self.prob[i] {
            i
        } else {
            self.alias[i] as usize
        }
    }
}

/// A point sampled on a surface, with the surface's unit normal there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// Position.
    pub point: [f64; 3],
    /// Unit normal (of the sampled triangle, or radial on a sphere).
    pub normal: [f64; 3],
}

/// `n` points sampled area-uniformly on the mesh's triangles, with the normal of the triangle
/// each lies on. Deterministic: the same mesh, `n` and seed give the same samples, whatever the
/// number of threads. Empty when the mesh has no area (or `n == 0`); triangles with
/// out-of-range indices are ignored.
pub fn sample_surface_with_normals(mesh: &Mesh, n: usize, seed: u64) -> Vec<SurfaceSample> {
    let nv = mesh.vertices.len();
    let areas: Vec<f64> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            if t.iter().any(|&i| i as usize >= nv) {
                return 0.0;
            }
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            let a2 = 0.5 * norm(cross(sub(b, a), sub(c, a)));
            if a2.is_finite() {
                a2
            } else {
                0.0
            }
        })
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) || n == 0 {
        return Vec::new();
    }
    let table = AliasTable::new(&areas, total);
    (0..n as u64)
        .into_par_iter()
        .map(|i| {
            let [r, q, mut u, mut v] = uniforms(seed, i);
            let mut t = table.pick(r, q);
            if areas[t] <= 0.0 {
                // Rounding in the table's construction; never in practice. Take the first
                // triangle with area instead.
                t = areas.iter().position(|&a| a > 0.0).unwrap_or(0);
            }
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.vertices[i as usize]);
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            SurfaceSample {
                point: std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k])),
                normal: triangle_normal(a, b, c),
            }
        })
        .collect()
}

/// `n` points sampled area-uniformly on the mesh's triangles with a fixed seed
/// (deterministic: the same mesh and seed give the same points, whatever the thread count).
pub fn sample_surface(mesh: &Mesh, n: usize, seed: u64) -> Vec<[f64; 3]> {
    sample_surface_with_normals(mesh, n, seed)
        .into_iter()
        .map(|s| s.point)
        .collect()
}

/// `n` points sampled area-uniformly on a sphere (Archimedes: uniform height and angle), with
/// radial normals. Deterministic like [`sample_surface_with_normals`].
pub fn sample_sphere(center: [f64; 3], radius: f64, n: usize, seed: u64) -> Vec<SurfaceSample> {
    (0..n as u64)
        .into_par_iter()
        .map(|i| {
            let [u, v, _, _] = uniforms(seed, i);
            let z = 2.0 * u - 1.0;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let phi = 2.0 * std::f64::consts::PI * v;
            let normal = [s * phi.cos(), s * phi.sin(), z];
            SurfaceSample {
                point: std::array::from_fn(|k| center[k] + radius * normal[k]),
                normal,
            }
        })
        .collect()
}

/// The ground truth a mesh is scored against.
#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// A triangle mesh (closed or open).
    Mesh(Mesh),
    /// An analytic sphere.
    Sphere {
        /// Centre.
        center: [f64; 3],
        /// Radius (positive).
        radius: f64,
    },
}

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EvalOptions {
    /// Samples drawn on each surface (at least 1).
    pub samples: usize,
    /// Seed of the sample generator; the mesh uses `seed`, the reference `seed + 1`.
    pub seed: u64,
}

impl Default for EvalOptions {
    /// One million samples per surface, seed 1.
    fn default() -> Self {
        EvalOptions {
            samples: 1_000_000,
            seed: 1,
        }
    }
}

/// Precision, recall and F-score at one distance threshold.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FScore {
    /// The threshold τ (absolute units).
    pub threshold: f64,
    /// Fraction of mesh samples within τ of the reference.
    pub precision: f64,
    /// Fraction of reference samples within τ of the mesh.
    pub recall: f64,
    /// `2PR / (P + R)`, 0 when both are 0.
    pub fscore: f64,
}

/// Statistics of one direction (samples of one surface measured against the other).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Direction {
    /// Mean distance.
    pub mean: f64,
    /// Largest distance.
    pub max: f64,
    /// Mean of `|n_sample · n_other|` at the closest point.
    pub normal_consistency: f64,
    /// Fraction of samples within the 0.5 % threshold.
    pub within_0_5: f64,
    /// Fraction of samples within the 1 % threshold.
    pub within_1: f64,
}

/// Scores of a mesh against a reference, as computed by [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Evaluation {
    /// Symmetric Chamfer distance: mean of the two directions' mean distances.
    pub chamfer: f64,
    /// [`Self::chamfer`] divided by the reference's bounding-box diagonal.
    pub chamfer_rel: f64,
    /// Hausdorff distance (over the samples): the larger of the two directions' maxima.
    pub hausdorff: f64,
    /// [`Self::hausdorff`] divided by the reference's bounding-box diagonal.
    pub hausdorff_rel: f64,
    /// Mesh samples measured against the reference (accuracy; the meaningful direction
    /// for an open ground truth is usually the other one).
    pub mesh_to_reference: Direction,
    /// Reference samples measured against the mesh (completeness).
    pub reference_to_mesh: Direction,
    /// F-score at 0.5 % of the reference's bounding-box diagonal.
    pub fscore_0_5: FScore,
    /// F-score at 1 % of the reference's bounding-box diagonal.
    pub fscore_1: FScore,
    /// Mean of the two directions' normal consistencies (1 = normals parallel everywhere).
    pub normal_consistency: f64,
    /// Bounding-box diagonal of the reference (of its triangles' vertices; `2√3·r` for a
    /// sphere).
    pub diagonal: f64,
    /// Samples drawn on each surface.
    pub samples: usize,
    /// Surface area of the mesh.
    pub area: f64,
    /// Surface area of the reference.
    pub reference_area: f64,
    /// Topology of the mesh.
    pub topology: Topology,
}

fn json_number(x: f64) -> String {
    if !x.is_finite() {
        "null".into()
    } else if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

impl Evaluation {
    /// The evaluation as one line of JSON (an object; numbers in shortest round-trip form,
    /// booleans as booleans). Keys: `chamfer`, `chamfer_rel`, `hausdorff`, `hausdorff_rel`,
    /// `mesh_to_reference_mean`/`_max`, `reference_to_mesh_mean`/`_max`, `fscore_0_5`,
    /// `precision_0_5`, `recall_0_5`, `tau_0_5` (and the same with `_1`),
    /// `normal_consistency` (and per direction), `diagonal`, `samples`, `area`,
    /// `reference_area`, then the mesh's `vertices`, `faces`, `closed`, `edge_manifold`,
    /// `vertex_manifold`, `oriented`, `components`, `euler`, `boundary_edges`,
    /// `non_manifold_edges`, `non_manifold_vertices`.
    pub fn to_json(&self) -> String {
        let t = &self.topology;
        let nums = [
            ("chamfer", self.chamfer),
            ("chamfer_rel", self.chamfer_rel),
            ("hausdorff", self.hausdorff),
            ("hausdorff_rel", self.hausdorff_rel),
            ("mesh_to_reference_mean", self.mesh_to_reference.mean),
            ("mesh_to_reference_max", self.mesh_to_reference.max),
            ("reference_to_mesh_mean", self.reference_to_mesh.mean),
            ("reference_to_mesh_max", self.reference_to_mesh.max),
            ("fscore_0_5", self.fscore_0_5.fscore),
            ("precision_0_5", self.fscore_0_5.precision),
            ("recall_0_5", self.fscore_0_5.recall),
            ("tau_0_5", self.fscore_0_5.threshold),
            ("fscore_1", self.fscore_1.fscore),
            ("precision_1", self.fscore_1.precision),
            ("recall_1", self.fscore_1.recall),
            ("tau_1", self.fscore_1.threshold),
            ("normal_consistency", self.normal_consistency),
            (
                "normal_consistency_mesh_to_reference",
                self.mesh_to_reference.normal_consistency,
            ),
            (
                "normal_consistency_reference_to_mesh",
                self.reference_to_mesh.normal_consistency,
            ),
            ("diagonal", self.diagonal),
            ("area", self.area),
            ("reference_area", self.reference_area),
        ];
        let ints = [
            ("samples", self.samples as i64),
            ("vertices", t.vertices as i64),
            ("faces", t.faces as i64),
            ("components", t.components as i64),
            ("euler", t.euler),
            ("boundary_edges", t.boundary_edges as i64),
            ("non_manifold_edges", t.non_manifold_edges as i64),
            ("non_manifold_vertices", t.non_manifold_vertices as i64),
        ];
        let bools = [
            ("closed", t.closed),
            ("edge_manifold", t.edge_manifold),
            ("vertex_manifold", t.vertex_manifold),
            ("oriented", t.oriented),
        ];
        let fields: Vec<String> = nums
            .iter()
            .map(|(k, v)| format!("\"{k}\": {}", json_number(*v)))
            .chain(ints.iter().map(|(k, v)| format!("\"{k}\": {v}")))
            .chain(bools.iter().map(|(k, v)| format!("\"{k}\": {v}")))
            .collect();
        format!("{{{}}}", fields.join(", "))
    }
}

/// Checks that `mesh` can be sampled and measured: indices in range, finite coordinates on
/// every triangle, positive finite area. `what` names the mesh in the message.
fn check_mesh(mesh: &Mesh, what: &str) -> Result<()> {
    let nv = mesh.vertices.len();
    if mesh.triangles.is_empty() {
        return Err(Error::Degenerate(format!("the {what} has no triangles")));
    }
    if let Some((f, _)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&i| i as usize >= nv))
    {
        return Err(Error::Degenerate(format!(
            "triangle {f} of the {what} refers to a vertex that does not exist ({nv} vertices)"
        )));
    }
    let bad = mesh.triangles.par_iter().position_first(|t| {
        t.iter()
            .any(|&i| mesh.vertices[i as usize].iter().any(|x| !x.is_finite()))
    });
    if let Some(f) = bad {
        return Err(Error::Degenerate(format!(
            "triangle {f} of the {what} has a vertex with non-finite coordinates"
        )));
    }
    let area = mesh.area();
    if !(area > 0.0 && area.is_finite()) {
        return Err(Error::Degenerate(format!(
            "the {what} has no area (all {} triangles are degenerate)",
            mesh.triangles.len()
        )));
    }
    Ok(())
}

/// Bounding-box diagonal of the vertices used by the triangles.
fn diagonal(mesh: &Mesh) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in &mesh.triangles {
        for &v in t {
            let x = mesh.vertices[v as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
    }
    norm(sub(hi, lo))
}

/// Sorts samples along a Morton (Z-order) curve, so consecutive queries visit the same parts
/// of the hierarchy (far fewer cache misses). The order is fully determined by the samples.
fn sort_spatially(samples: &mut [SurfaceSample]) {
    if samples.is_empty() {
        return;
    }
    let keys = BoxKeys::around(samples.iter().map(|s| s.point));
    let mut keyed: Vec<(u64, SurfaceSample)> = samples
        .par_iter()
        .map(|s| (keys.key(s.point), *s))
        .collect();
    // Stable, so equal keys keep their (deterministic) sample order.
    keyed.par_sort_by_key(|e| e.0);
    samples
        .par_iter_mut()
        .zip(keyed.par_iter())
        .for_each(|(s, e)| *s = e.1);
}

/// Distance and `|n · n_other|` for each sample, in order.
type Measured = Vec<(f64, f64)>;

fn measure_against_mesh(samples: &[SurfaceSample], target: &MeshDistance) -> Measured {
    let mesh = target.mesh();
    samples
        .par_iter()
        .map(|s| match target.closest(s.point) {
            Some(c) => {
                let [a, b, cc] =
                    mesh.triangles[c.triangle as usize].map(|i| mesh.vertices[i as usize]);
                (c.distance, dot(s.normal, triangle_normal(a, b, cc)).abs())
            }
            None => (f64::INFINITY, 0.0),
        })
        .collect()
}

fn measure_against_sphere(samples: &[SurfaceSample], center: V3, radius: f64) -> Measured {
    samples
        .par_iter()
        .map(|s| {
            let d = sub(s.point, center);
            let r = norm(d);
            // At the centre every point of the sphere is closest; no radial direction exists.
            let cos = if r > 0.0 {
                (dot(s.normal, d) / r).abs().min(1.0)
            } else {
                0.0
            };
            ((r - radius).abs(), cos)
        })
        .collect()
}

/// Sequential (hence thread-count independent) reduction of one direction.
fn summarize(m: &Measured, tau: [f64; 2]) -> Direction {
    let n = m.len().max(1) as f64;
    let (mut sum, mut max, mut cos) = (0.0, 0.0f64, 0.0);
    let mut within = [0usize; 2];
    for &(d, c) in m {
        sum += d;
        max = max.max(d);
        cos += c;
        for k in 0..2 {
            within[k] += (d <= tau[k]) as usize;
        }
    }
    Direction {
        mean: sum / n,
        max,
        normal_consistency: cos / n,
        within_0_5: within[0] as f64 / n,
        within_1: within[1] as f64 / n,
    }
}

fn fscore(threshold: f64, precision: f64, recall: f64) -> FScore {
    let fscore = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    FScore {
        threshold,
        precision,
        recall,
        fscore,
    }
}

/// Scores `mesh` against `reference` with `opts.samples` area-uniform samples on each surface
/// and exact point-to-triangle distances (point-to-sphere for an analytic sphere).
///
/// The F-score thresholds are 0.5 % and 1 % of the reference's bounding-box diagonal; a
/// sample is "within" τ when its distance is at most τ. Normal consistency compares each
/// sample's normal with the normal of the other surface at the closest point (the closest
/// triangle's face normal, or the radial direction of a sphere), ignoring orientation. The
/// Hausdorff distance is the largest sampled distance, so it is a lower bound of the true one.
/// The result is deterministic and independent of the number of threads.
///
/// # Errors
/// [`Error::InvalidParameter`] if `opts.samples` is 0 or the sphere's centre or radius is
/// not finite or the radius not positive; [`Error::Degenerate`] if either mesh has no
/// triangles, no area, an index out of range or non-finite coordinates (the message says
/// whether it is the mesh or the reference).
pub fn evaluate(mesh: &Mesh, reference: &Reference, opts: &EvalOptions) -> Result<Evaluation> {
    if opts.samples == 0 {
        return Err(Error::InvalidParameter {
            name: "--samples",
            message: "must be at least 1".into(),
        });
    }
    if let Reference::Sphere { center, radius } = reference {
        if !(center.iter().all(|x| x.is_finite()) && *radius > 0.0 && radius.is_finite()) {
            return Err(Error::InvalidParameter {
                name: "--reference-sphere",
                message: format!(
                    "the centre must be finite and the radius positive, got centre {center:?}, radius {radius}"
                ),
            });
        }
    }
    check_mesh(mesh, "mesh")?;
    if let Reference::Mesh(r) = reference {
        check_mesh(r, "reference mesh")?;
    }
    let n = opts.samples;
    let seed_ref = opts.seed.wrapping_add(1);
    let (diag, reference_area) = match reference {
        Reference::Mesh(r) => (diagonal(r), r.area()),
        Reference::Sphere { radius, .. } => (
            2.0 * 3f64.sqrt() * radius,
            4.0 * std::f64::consts::PI * radius * radius,
        ),
    };
    let tau = [0.005 * diag, 0.01 * diag];
    let (to_ref, from_ref) = match reference {
        Reference::Mesh(r) => {
            let ((mesh_tree, ref_tree), (mesh_samples, ref_samples)) = rayon::join(
                || rayon::join(|| MeshDistance::new(mesh), || MeshDistance::new(r)),
                || {
                    rayon::join(
                        || sample_surface_with_normals(mesh, n, opts.seed),
                        || sample_surface_with_normals(r, n, seed_ref),
                    )
                },
            );
            let (mut mesh_samples, mut ref_samples) = (mesh_samples, ref_samples);
            rayon::join(
                || sort_spatially(&mut mesh_samples),
                || sort_spatially(&mut ref_samples),
            );
            (
                measure_against_mesh(&mesh_samples, &ref_tree),
                measure_against_mesh(&ref_samples, &mesh_tree),
            )
        }
        Reference::Sphere { center, radius } => {
            let (mesh_tree, (mesh_samples, ref_samples)) = rayon::join(
                || MeshDistance::new(mesh),
                || {
                    rayon::join(
                        || sample_surface_with_normals(mesh, n, opts.seed),
                        || sample_sphere(*center, *radius, n, seed_ref),
                    )
                },
            );
            let mut ref_samples = ref_samples;
            sort_spatially(&mut ref_samples);
            (
                measure_against_sphere(&mesh_samples, *center, *radius),
                measure_against_mesh(&ref_samples, &mesh_tree),
            )
        }
    };
    let a = summarize(&to_ref, tau);
    let b = summarize(&from_ref, tau);
    let chamfer = 0.5 * (a.mean + b.mean);
    let hausdorff = a.max.max(b.max);
    Ok(Evaluation {
        chamfer,
        chamfer_rel: chamfer / diag,
        hausdorff,
        hausdorff_rel: hausdorff / diag,
        mesh_to_reference: a,
        reference_to_mesh: b,
        fscore_0_5: fscore(tau[0], a.within_0_5, b.within_0_5),
        fscore_1: fscore(tau[1], a.within_1, b.within_1),
        normal_consistency: 0.5 * (a.normal_consistency + b.normal_consistency),
        diagonal: diag,
        samples: n,
        area: mesh.area(),
        reference_area,
        topology: mesh.topology(),
    })
}
#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn samples_are_area_uniform_and_deterministic() {
        // Two triangles, areas 1 and 3: about a quarter of the samples land on the first.
        let mesh = Mesh {
            vertices: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 2.0, 0.0],
                [10.0, 0.0, 0.0],
                [13.0, 0.0, 0.0],
                [10.0, 2.0, 0.0],
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
            ..Default::default()
        };
        let s = sample_surface_with_normals(&mesh, 40_000, 5);
        let first = s.iter().filter(|s| s.point[0] < 5.0).count() as f64 / 40_000.0;
        assert!((first - 0.25).abs() < 0.01, "{first}");
        assert!(s
            .iter()
            .all(|s| s.normal == [0.0, 0.0, 1.0] && s.point[2] == 0.0));
        assert_eq!(s, sample_surface_with_normals(&mesh, 40_000, 5));
        assert_ne!(s, sample_surface_with_normals(&mesh, 40_000, 6));
        // A prefix of a longer run is the shorter run.
        assert_eq!(s[..100], sample_surface_with_normals(&mesh, 100, 5)[..]);
    }

    #[test]
    fn sphere_samples_are_uniform() {
        let s = sample_sphere([1.0, 2.0, 3.0], 2.0, 50_000, 3);
        let mut mean = [0.0; 3];
        for x in &s {
            let d = sub(x.point, [1.0, 2.0, 3.0]);
            assert!((norm(d) - 2.0).abs() < 1e-12);
            assert!((dot(d, x.normal) - 2.0).abs() < 1e-12);
            for k in 0..3 {
                mean[k] += x.normal[k] / s.len() as f64;
            }
        }
        assert!(norm(mean) < 0.02, "{mean:?}");
        // Upper hemisphere above z = 0.5 holds a quarter of the area (Archimedes).
        let cap = s.iter().filter(|x| x.normal[2] > 0.5).count() as f64 / s.len() as f64;
        assert!((cap - 0.25).abs() < 0.01, "{cap}");
    }

    #[test]
    fn json_numbers() {
        assert_eq!(json_number(0.0), "0");
        assert_eq!(json_number(0.25), "0.25");
        assert_eq!(json_number(1.5e-7), "1.5e-7");
        assert_eq!(json_number(f64::NAN), "null");
    }
}
