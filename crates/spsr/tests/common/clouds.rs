//! Analytic point clouds with exact normals, from a deterministic generator. Shared by the
//! integration tests and `examples/normals_bench.rs` (which includes this file), so keep it
//! to `spsr` and `std`.
#![allow(dead_code)]

use spsr::PointCloud;

/// Deterministic xorshift generator in [0, 1): a cloud is a function of its seed.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A uniformly random unit vector (rejection from the cube, away from the centre).
    pub fn unit(&mut self) -> [f64; 3] {
        loop {
            let v = [
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
                2.0 * self.next() - 1.0,
            ];
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 0.1 && l <= 1.0 {
                return [v[0] / l, v[1] / l, v[2] / l];
            }
        }
    }
}

/// `n` points uniform on a sphere, exact outward normals.
pub fn sphere(n: usize, c: [f64; 3], r: f64, seed: u64) -> PointCloud {
    let mut rng = Rng(seed);
    let mut pos = Vec::with_capacity(n);
    let mut nor = Vec::with_capacity(n);
    while pos.len() < n {
        let u = rng.unit();
        pos.push([c[0] + r * u[0], c[1] + r * u[1], c[2] + r * u[2]]);
        nor.push(u);
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

/// Signed distance of each vertex to the torus about the z axis (major radius `big`, minor
/// `small`).
pub fn torus_errors(mesh: &spsr::Mesh, big: f64, small: f64) -> Vec<f64> {
    mesh.vertices
        .iter()
        .map(|v| {
            let rho = (v[0] * v[0] + v[1] * v[1]).sqrt();
            ((rho - big).powi(2) + v[2] * v[2]).sqrt() - small
        })
        .collect()
}

/// `n` points area-uniform on the faces of the box `[-h, h]`, exact outward face normals.
pub fn boxed(n: usize, h: [f64; 3], seed: u64) -> PointCloud {
    let mut rng = Rng(seed);
    let areas = [h[1] * h[2], h[0] * h[2], h[0] * h[1]];
    let total: f64 = areas.iter().sum();
    let mut pos = Vec::with_capacity(n);
    let mut nor = Vec::with_capacity(n);
    while pos.len() < n {
        let mut r = rng.next() * total;
        let mut a = 0;
        while a < 2 && r >= areas[a] {
            r -= areas[a];
            a += 1;
        }
        let side = if rng.next() < 0.5 { -1.0 } else { 1.0 };
        let mut p: [f64; 3] = std::array::from_fn(|b| (2.0 * rng.next() - 1.0) * h[b]);
        p[a] = side * h[a];
        let mut nn = [0.0; 3];
        nn[a] = side;
        pos.push(p);
        nor.push(nn);
    }
    PointCloud::new(pos, nor).unwrap()
}
