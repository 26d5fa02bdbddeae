//! Replays the inputs kept in `fuzz/regressions/<target>/` (inputs that once crashed a fuzz
//! target, and the seeds in `fuzz/seeds/<target>/`) through the fuzz targets' own code, which
//! is included from `fuzz/src/harness.rs`: every one must now run without a panic and keep
//! the targets' invariants.

use std::path::Path;

use crate::common::harness;

fn replay(target: &str, f: fn(&[u8])) -> usize {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz");
    let mut n = 0;
    for kind in ["regressions", "seeds"] {
        let dir = root.join(kind).join(target);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut files: Vec<_> = entries.map(|e| e.unwrap().path()).collect();
        files.sort();
        for p in files.into_iter().filter(|p| p.is_file()) {
            let data = std::fs::read(&p).unwrap();
            let r = std::panic::catch_unwind(|| f(&data));
            assert!(r.is_ok(), "fuzz input {} fails again", p.display());
            n += 1;
        }
    }
    n
}

#[test]
fn ply_inputs() {
    assert!(replay("ply", harness::ply) > 0);
}

#[test]
fn ply_mesh_inputs() {
    assert!(replay("ply_mesh", harness::ply_mesh) > 0);
}

#[test]
fn mesh_inputs() {
    assert!(replay("mesh", harness::mesh) > 0);
}

#[test]
fn text_inputs() {
    assert!(replay("text", harness::text) > 0);
}

#[test]
fn las_inputs() {
    assert!(replay("las", harness::las) > 0);
}

#[test]
fn e57_inputs() {
    assert!(replay("e57", harness::e57) > 0);
}

#[test]
fn pcd_inputs() {
    assert!(replay("pcd", harness::pcd) > 0);
}

#[test]
fn reconstruct_inputs() {
    assert!(replay("reconstruct", harness::reconstruct) > 0);
}
