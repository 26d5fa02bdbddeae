//! Shared helpers of the integration tests: analytic point clouds with exact normals and
//! exact point-to-mesh distances.
#![allow(dead_code)]

use spsr::{Mesh, PointCloud};

/// The fuzz targets' bodies and the invariants they check (`fuzz/src/harness.rs`, shared
/// with the fuzz crate).
#[path = "../../../../fuzz/src/harness.rs"]
pub mod harness;

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
        let v = [
            2.0 * rng.next() - 1.0,
            2.0 * rng.next() - 1.0,
            2.0 * rng.next() - 1.0,
        ];
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

#[allow(unused_imports)]
pub use spsr::metrics::MeshDistance;

/// Asserts the mesh is a closed, oriented 2-manifold; returns its topology.
pub fn assert_closed_manifold(mesh: &Mesh, what: &str) -> spsr::mesh::Topology {
    let topo = mesh.topology();
    assert!(topo.faces > 0, "{what}: empty mesh");
    assert!(
        topo.closed,
        "{what}: not closed ({} boundary edges)",
        topo.boundary_edges
    );
    assert!(
        topo.edge_manifold,
        "{what}: {} non-manifold edges",
        topo.non_manifold_edges
    );
    assert!(
        topo.vertex_manifold,
        "{what}: {} non-manifold vertices",
        topo.non_manifold_vertices
    );
    assert!(topo.oriented, "{what}: not consistently oriented");
    topo
}

pub fn repo_file(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(rel)
}
