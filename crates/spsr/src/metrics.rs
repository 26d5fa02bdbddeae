//! Accuracy metrics: exact point-to-mesh distances and area-uniform surface samples.

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::Mesh;

/// Distance from `p` to the triangle `abc`.
/// Exact Euclidean distance from `p` to the triangle `abc` (closest-point by Voronoi regions).
pub fn point_triangle_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let sub = |x: [f64; 3], y: [f64; 3]| [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    let closest = if d1 <= 0.0 && d2 <= 0.0 {
        a
    } else {
        let bp = sub(p, b);
        let d3 = dot(ab, bp);
        let d4 = dot(ac, bp);
        if d3 >= 0.0 && d4 <= d3 {
            b
        } else {
            let vc = d1 * d4 - d3 * d2;
            if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
                let v = d1 / (d1 - d3);
                [a[0] + v * ab[0], a[1] + v * ab[1], a[2] + v * ab[2]]
            } else {
                let cp = sub(p, c);
                let d5 = dot(ab, cp);
                let d6 = dot(ac, cp);
                if d6 >= 0.0 && d5 <= d6 {
                    c
                } else {
                    let vb = d5 * d2 - d1 * d6;
                    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
                        let w = d2 / (d2 - d6);
                        [a[0] + w * ac[0], a[1] + w * ac[1], a[2] + w * ac[2]]
                    } else {
                        let va = d3 * d6 - d5 * d4;
                        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
                            let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
                            let bc = sub(c, b);
                            [b[0] + w * bc[0], b[1] + w * bc[1], b[2] + w * bc[2]]
                        } else {
                            let denom = 1.0 / (va + vb + vc);
                            let v = vb * denom;
                            let w = vc * denom;
                            [
                                a[0] + ab[0] * v + ac[0] * w,
                                a[1] + ab[1] * v + ac[1] * w,
                                a[2] + ab[2] * v + ac[2] * w,
                            ]
                        }
                    }
                }
            }
        }
    };
    let d = sub(p, closest);
    dot(d, d).sqrt()
}

/// Exact distances from query points to a triangle mesh, accelerated by a uniform grid of
/// triangle buckets (a ring search around the query's cell).
pub struct MeshDistance<'a> {
    mesh: &'a Mesh,
    lo: [f64; 3],
    cell: f64,
    dims: [i64; 3],
    buckets: FxHashMap<(i64, i64, i64), Vec<u32>>,
}

impl<'a> MeshDistance<'a> {
    /// Buckets the mesh's triangles.
    pub fn new(mesh: &'a Mesh) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in &mesh.vertices {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        let diag =
            ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let cell = diag / (mesh.triangles.len() as f64).sqrt().max(8.0);
        let dims: [i64; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / cell).ceil() as i64 + 1);
        let mut buckets: FxHashMap<(i64, i64, i64), Vec<u32>> = FxHashMap::default();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let vs = tri.map(|i| mesh.vertices[i as usize]);
            let bl: [i64; 3] = std::array::from_fn(|a| {
                ((vs.iter().map(|v| v[a]).fold(f64::INFINITY, f64::min) - lo[a]) / cell).floor()
                    as i64
            });
            let bh: [i64; 3] = std::array::from_fn(|a| {
                ((vs.iter().map(|v| v[a]).fold(f64::NEG_INFINITY, f64::max) - lo[a]) / cell).floor()
                    as i64
            });
            for z in bl[2]..=bh[2] {
                for y in bl[1]..=bh[1] {
                    for x in bl[0]..=bh[0] {
                        buckets.entry((x, y, z)).or_default().push(t as u32);
                    }
                }
            }
        }
        Self {
            mesh,
            lo,
            cell,
            dims,
            buckets,
        }
    }

    /// Distance from `p` to the mesh surface.
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        let c: [i64; 3] = std::array::from_fn(|a| ((p[a] - self.lo[a]) / self.cell).floor() as i64);
        let mut best = f64::INFINITY;
        let max_r =
            self.dims.iter().copied().max().unwrap() + c.iter().map(|v| v.abs()).max().unwrap() + 2;
        for r in 0..=max_r {
            // Once a candidate is closer than the inner boundary of this ring, stop.
            if best < (r as f64 - 1.0).max(0.0) * self.cell {
                break;
            }
            for z in c[2] - r..=c[2] + r {
                for y in c[1] - r..=c[1] + r {
                    for x in c[0] - r..=c[0] + r {
                        if (x - c[0]).abs() != r && (y - c[1]).abs() != r && (z - c[2]).abs() != r {
                            continue;
                        }
                        if let Some(ts) = self.buckets.get(&(x, y, z)) {
                            for &t in ts {
                                let tri = self.mesh.triangles[t as usize];
                                let d = point_triangle_distance(
                                    p,
                                    self.mesh.vertices[tri[0] as usize],
                                    self.mesh.vertices[tri[1] as usize],
                                    self.mesh.vertices[tri[2] as usize],
                                );
                                best = best.min(d);
                            }
                        }
                    }
                }
            }
        }
        best
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

/// `n` points sampled area-uniformly on the mesh's triangles with a fixed seed
/// (deterministic: the same mesh and seed give the same points).
pub fn sample_surface(mesh: &Mesh, n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut cum = Vec::with_capacity(mesh.triangles.len());
    let mut total = 0.0;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let cr = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        total += 0.5 * (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt();
        cum.push(total);
    }
    if total <= 0.0 || n == 0 {
        return Vec::new();
    }
    let mut s = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let r = next() * total;
            let t = cum.partition_point(|&c| c < r).min(cum.len() - 1);
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.vertices[i as usize]);
            let (mut u, mut v) = (next(), next());
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k]))
        })
        .collect()
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
            density: None,
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
}
