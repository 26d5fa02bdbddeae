//! Slab mode (issue 15): the mesh of a run cut into slabs is one closed manifold surface
//! that matches the in-core mesh within a fraction of a finest cell.

use spsr::metrics::MeshDistance;
use spsr::slabs::{self, SlabOptions, Source};
use spsr::{Mesh, Noise, Params, PointCloud};

use crate::common::torus;
use crate::common::{assert_closed_manifold, bunny};

/// Largest and mean distance from `a`'s vertices to `b`, in both directions.
fn distances(a: &Mesh, b: &Mesh) -> (f64, f64) {
    let ab = MeshDistance::new(b).distances(&a.vertices);
    let ba = MeshDistance::new(a).distances(&b.vertices);
    let max = ab.iter().chain(&ba).fold(0.0f64, |m, &d| m.max(d));
    let mean = (ab.iter().sum::<f64>() + ba.iter().sum::<f64>()) / (ab.len() + ba.len()) as f64;
    (max, mean)
}

fn cell(cloud: &PointCloud, params: &Params) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in &cloud.positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    side * params.scale / f64::from(1u32 << params.depth)
}

fn compare(name: &str, cloud: &PointCloud, params: &Params, counts: &[usize]) {
    let dir = tempfile::tempdir().unwrap();
    let whole = spsr::reconstruct(cloud, params).unwrap().mesh;
    let h = cell(cloud, params);
    for &k in counts {
        let out = slabs::reconstruct(
            Source::Cloud(cloud),
            params,
            &SlabOptions {
                slabs: k,
                work_dir: dir.path().to_path_buf(),
            },
            &|_| {},
        )
        .unwrap();
        let (max, mean) = distances(&out.mesh, &whole);
        eprintln!(
            "{name} {k} slabs ({} used): {} / {} vertices, max {:.3} cells, mean {:.4} cells",
            out.stats.slabs,
            out.mesh.vertices.len(),
            whole.vertices.len(),
            max / h,
            mean / h
        );
        let topo = assert_closed_manifold(&out.mesh, &format!("{name}, {k} slabs"));
        assert_eq!(topo.components, 1, "{name}, {k} slabs: one piece");
        assert!(max <= h, "{name}, {k} slabs: {} cells apart", max / h);
        assert!(
            mean <= 0.05 * h,
            "{name}, {k} slabs: mean {} cells",
            mean / h
        );
        // The spill files are gone.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}

fn plain(depth: u32) -> Params {
    Params {
        depth,
        noise: Noise::Off,
        keep_normals: true,
        keep_outliers: true,
        attributes: false,
        ..Params::default()
    }
}

#[test]
fn slabs_match_the_in_core_torus() {
    compare("torus", &torus(20_000, 1.0, 0.35, 7), &plain(7), &[1, 3, 5]);
}

#[test]
fn slabs_match_the_in_core_bunny() {
    compare("bunny", &bunny(), &plain(8), &[1, 3, 5]);
}

#[test]
fn slabs_match_the_in_core_bunny_with_noise_adaptation() {
    // The noise stage smooths at one depth for all slabs, found from all slabs' samples.
    let params = Params {
        attributes: false,
        ..Params::default()
    };
    compare(
        "bunny (adaptive)",
        &bunny(),
        &Params { depth: 8, ..params },
        &[4],
    );
}

#[test]
fn slabs_written_as_they_come_match_the_mesh_in_memory() {
    let cloud = torus(20_000, 1.0, 0.35, 11);
    let params = plain(7);
    let dir = tempfile::tempdir().unwrap();
    let options = SlabOptions {
        slabs: 4,
        work_dir: dir.path().to_path_buf(),
    };
    let in_memory = slabs::reconstruct(Source::Cloud(&cloud), &params, &options, &|_| {})
        .unwrap()
        .mesh;
    let out = dir.path().join("torus.ply");
    let (stats, written) =
        slabs::reconstruct_into(Source::Cloud(&cloud), &params, &options, &out, &|_| {}).unwrap();
    let read = spsr::io::read_mesh(&out).unwrap();
    assert_eq!(written.vertices as usize, read.vertices.len());
    assert_eq!(written.triangles as usize, read.triangles.len());
    assert_eq!(read.triangles.len(), in_memory.triangles.len());
    // The torus: one piece, closed, genus one (as the checks on the way found).
    let topo = assert_closed_manifold(&read, "torus written slab by slab");
    assert_eq!((topo.components, topo.euler), (1, 0));
    assert_eq!((stats.diagnosis.pieces, stats.diagnosis.closed), (1, true));
    let (max, _) = distances(&read, &in_memory);
    // Positions are written in single precision.
    assert!(max < 1e-6, "{max}");
    // Only the mesh is left in the folder.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}
