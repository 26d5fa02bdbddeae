//! Shared helpers of the integration tests (`golden.rs`, `pipeline/`, `io/`): analytic point
//! clouds with exact normals, the example bunny, mesh and error checks, and the fuzz targets'
//! harness.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use spsr::{Error, Mesh, Params, PointCloud};

mod clouds;
#[allow(unused_imports)]
pub use clouds::*;

/// The fuzz targets' bodies and the invariants they check (`fuzz/src/harness.rs`, shared
/// with the fuzz crate).
#[path = "../../../../fuzz/src/harness.rs"]
pub mod harness;

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

/// A file of the repository, by its path from the repository's root.
pub fn repo_file(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(rel)
}

/// The example bunny (`examples/bunny.ply`).
pub fn bunny() -> PointCloud {
    spsr::io::read_points(&repo_file("examples/bunny.ply")).unwrap()
}

/// The example bunny and its ground-truth mesh (open at the bottom).
pub fn bunny_and_truth() -> (PointCloud, Mesh) {
    let gt = spsr::io::read_mesh(&repo_file("crates/spsr/tests/data/bunny_gt.ply")).unwrap();
    (bunny(), gt)
}

/// The default parameters at `depth`.
pub fn at_depth(depth: u32) -> Params {
    Params {
        depth,
        ..Params::default()
    }
}

/// Writes `bytes` to `dir/name`, returns the path.
pub fn write_file(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Asserts `e` is a parse error with a one-line message that contains every needle.
pub fn assert_parse(e: Error, needles: &[&str]) {
    let msg = e.to_string();
    assert!(
        matches!(e, Error::Parse { .. }),
        "expected a parse error, got {e:?}"
    );
    assert!(!msg.contains('\n'), "message is not one line: {msg}");
    for n in needles {
        assert!(msg.contains(n), "message {msg:?} lacks {n:?}");
    }
}

/// The faces of an octahedron whose vertices are +x, −x, +y, −y, +z, −z, oriented outward.
pub const OCTAHEDRON_TRIANGLES: [[u32; 3]; 8] = [
    [0, 2, 4],
    [2, 1, 4],
    [1, 3, 4],
    [3, 0, 4],
    [2, 0, 5],
    [1, 2, 5],
    [3, 1, 5],
    [0, 3, 5],
];
