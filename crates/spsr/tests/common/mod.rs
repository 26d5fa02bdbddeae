//! Shared helpers of the integration tests: analytic point clouds with exact normals and
//! exact point-to-mesh distances.
#![allow(dead_code)]

use spsr::{Mesh, PointCloud};

/// Deterministic xorshift generator in [0, 1).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `n` points uniform on a sphere, exact outward normals.
pub fn sphere(n: usize, c: [f64; 3], r: f64, seed: u64) -> PointCloud {
    let mut rng = Rng(seed);
    let mut pos = Vec::with_capacity(n);
    let mut nor = Vec::with_capacity(n);
    while pos.len() < n {
        let v = [2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0];
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l > 0.1 && l <= 1.0 {
            let u = [v[0] / l, v[1] / l, v[2] / l];
            pos.push([c[0] + r * u[0], c[1] + r * u[1], c[2] + r * u[2]]);
            nor.push(u);
        }
    }
    PointCloud::new(pos, nor).unwrap()
}

/// `n` points area-uniform on a torus about the z axis (major radius `big`, minor `small`).
pub fn torus(n: usize, big: f64, small: f64, seed: u64) -> PointCloud {
    let mut rng = Rng(seed);
    let mut pos = Vec::with_capacity(n);
    let mut nor = Vec::with_capacity(n);
    while pos.len() < n {
        let u = 2.0 * std::f64::consts::PI * rng.next();
        let v = 2.0 * std::f64::consts::PI * rng.next();
        // Area element ∝ big + small·cos v: rejection sampling.
        if rng.next() * (big + small) > big + small * v.cos() {
            continue;
        }
        let nrm = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
        let ring = big + small * v.cos();
        pos.push([ring * u.cos(), ring * u.sin(), small * v.sin()]);
        nor.push(nrm);
    }
    PointCloud::new(pos, nor).unwrap()
}

/// Distance from `p` to the triangle `abc`.
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

/// Exact distances from query points to a triangle mesh, with a uniform grid of triangles.
pub struct MeshDistance<'a> {
    mesh: &'a Mesh,
    lo: [f64; 3],
    cell: f64,
    dims: [i64; 3],
    buckets: std::collections::HashMap<(i64, i64, i64), Vec<u32>>,
}

impl<'a> MeshDistance<'a> {
    pub fn new(mesh: &'a Mesh) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in &mesh.vertices {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        let diag = ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let cell = diag / (mesh.triangles.len() as f64).sqrt().max(8.0);
        let dims: [i64; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / cell).ceil() as i64 + 1);
        let mut buckets: std::collections::HashMap<(i64, i64, i64), Vec<u32>> = Default::default();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            let vs = tri.map(|i| mesh.vertices[i as usize]);
            let bl: [i64; 3] = std::array::from_fn(|a| ((vs.iter().map(|v| v[a]).fold(f64::INFINITY, f64::min) - lo[a]) / cell).floor() as i64);
            let bh: [i64; 3] = std::array::from_fn(|a| ((vs.iter().map(|v| v[a]).fold(f64::NEG_INFINITY, f64::max) - lo[a]) / cell).floor() as i64);
            for z in bl[2]..=bh[2] {
                for y in bl[1]..=bh[1] {
                    for x in bl[0]..=bh[0] {
                        buckets.entry((x, y, z)).or_default().push(t as u32);
                    }
                }
            }
        }
        Self { mesh, lo, cell, dims, buckets }
    }

    /// Distance from `p` to the mesh surface.
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        let c: [i64; 3] = std::array::from_fn(|a| ((p[a] - self.lo[a]) / self.cell).floor() as i64);
        let mut best = f64::INFINITY;
        let max_r = self.dims.iter().copied().max().unwrap() + c.iter().map(|v| v.abs()).max().unwrap() + 2;
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

    /// Mean distance from the points to the mesh.
    pub fn mean_distance(&self, pts: &[[f64; 3]]) -> f64 {
        pts.iter().map(|&p| self.distance(p)).sum::<f64>() / pts.len() as f64
    }
}

/// Asserts the mesh is a closed, oriented 2-manifold; returns its topology.
pub fn assert_closed_manifold(mesh: &Mesh, what: &str) -> spsr::mesh::Topology {
    let topo = mesh.topology();
    assert!(topo.faces > 0, "{what}: empty mesh");
    assert!(topo.closed, "{what}: not closed ({} boundary edges)", topo.boundary_edges);
    assert!(topo.edge_manifold, "{what}: {} non-manifold edges", topo.non_manifold_edges);
    assert!(topo.vertex_manifold, "{what}: {} non-manifold vertices", topo.non_manifold_vertices);
    assert!(topo.oriented, "{what}: not consistently oriented");
    topo
}

pub fn repo_file(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}
