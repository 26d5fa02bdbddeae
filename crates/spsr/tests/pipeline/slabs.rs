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

/// The slab runs of `params` against the in-core run of the solve the slabs make: one cascade
/// of the cascadic cycles' sweeps (`slabs::cascade_sweeps`).
fn compare(name: &str, cloud: &PointCloud, params: &Params, counts: &[usize]) {
    let dir = tempfile::tempdir().unwrap();
    let one_cascade = Params {
        cycles: Some(1),
        iters: Some(slabs::cascade_sweeps(params)),
        ..params.clone()
    };
    let whole = spsr::reconstruct(cloud, &one_cascade).unwrap().mesh;
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
        let noted = out
            .stats
            .warnings
            .iter()
            .any(|w| matches!(w, spsr::Warning::SlabCascade { .. }));
        assert_eq!(
            noted,
            params.cycles() > 1,
            "{name}: the note of one cascade"
        );
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

/// Runs every step of a job as the Python coordinator does, each slab task of a phase in
/// `order`, and the tasks of `twice` run twice (as a scheduler does when a worker dies).
fn run_job(
    cloud: &PointCloud,
    params: &Params,
    k: usize,
    root: &std::path::Path,
    out: &std::path::Path,
) -> slabs::Written {
    use slabs::job;
    let j = job::prepare(Source::Cloud(cloud), params, k, root).unwrap();
    let order: Vec<usize> = (0..j.slabs).rev().collect();
    let each = |task: fn(&std::path::Path, usize) -> spsr::Result<()>| {
        for &s in &order {
            task(&j.dir, s).unwrap();
        }
        // Idempotent: running a task again changes nothing.
        task(&j.dir, 0).unwrap();
    };
    if j.noise {
        each(job::noise);
        job::smoothing(&j.dir).unwrap();
    }
    each(job::coarse);
    job::solve_coarse(&j.dir).unwrap();
    each(job::solve);
    job::iso(&j.dir).unwrap();
    each(job::extract);
    let (_, written) = job::finish(&j.dir, out).unwrap();
    job::remove(&j.dir).unwrap();
    written
}

#[test]
fn slab_tasks_give_the_bytes_of_the_one_process_run() {
    let cloud = bunny();
    let dir = tempfile::tempdir().unwrap();
    for params in [
        plain(7),
        Params {
            depth: 7,
            attributes: false,
            ..Params::default()
        },
    ] {
        let options = SlabOptions {
            slabs: 3,
            work_dir: dir.path().to_path_buf(),
        };
        let one = dir.path().join("one.ply");
        slabs::reconstruct_into(Source::Cloud(&cloud), &params, &options, &one, &|_| {}).unwrap();
        let tasks = dir.path().join("tasks.ply");
        let written = run_job(&cloud, &params, 3, dir.path(), &tasks);
        assert_eq!((written.pieces, written.open_edges), (1, 0));
        assert!(
            std::fs::read(&one).unwrap() == std::fs::read(&tasks).unwrap(),
            "{:?}: the tasks' mesh differs from the one-process run's",
            params.noise
        );
        // Only the two meshes are left.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    }
}

#[test]
fn slab_tasks_refuse_steps_out_of_order_and_foreign_folders() {
    use slabs::job;
    let cloud = torus(5_000, 1.0, 0.35, 3);
    let dir = tempfile::tempdir().unwrap();
    let j = job::prepare(Source::Cloud(&cloud), &plain(6), 2, dir.path()).unwrap();
    // Extraction before the iso-value, a slab the job lacks, a solve before the coarse solve.
    let e = job::extract(&j.dir, 0).unwrap_err().to_string();
    assert!(e.contains("iso"), "{e}");
    assert!(job::coarse(&j.dir, j.slabs).is_err());
    assert!(job::solve(&j.dir, 0).is_err());
    // A damaged file is an error naming it, not a panic.
    job::coarse(&j.dir, 0).unwrap();
    let part = j.dir.join("slab-0000.coarse");
    let bytes = std::fs::read(&part).unwrap();
    std::fs::write(&part, &bytes[..bytes.len() / 2]).unwrap();
    job::coarse(&j.dir, 1).unwrap();
    let e = job::solve_coarse(&j.dir).unwrap_err().to_string();
    assert!(e.contains("slab-0000.coarse"), "{e}");
    // Only a job folder is removed.
    assert!(job::remove(dir.path()).is_err());
    job::remove(&j.dir).unwrap();
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn slabs_refuse_v_and_w_cycles_with_the_field_named() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = torus(2_000, 0.3, 0.1, 7);
    for solver in [spsr::Solver::VCycle, spsr::Solver::WCycle] {
        let params = Params {
            solver,
            ..Params::default()
        };
        let err = slabs::reconstruct(
            Source::Cloud(&cloud),
            &params,
            &SlabOptions {
                slabs: 2,
                work_dir: dir.path().to_path_buf(),
            },
            &|_| {},
        )
        .expect_err("refused");
        match err {
            spsr::Error::InvalidParameter { field, .. } => assert_eq!(field, "solver"),
            other => panic!("{solver:?}: {other:?}"),
        }
    }
}

#[test]
fn slabs_solve_cascadic_cycles_as_one_cascade_of_their_sweeps() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = torus(20_000, 1.0, 0.35, 7);
    let run = |params: &Params| {
        slabs::reconstruct(
            Source::Cloud(&cloud),
            params,
            &SlabOptions {
                slabs: 3,
                work_dir: dir.path().to_path_buf(),
            },
            &|_| {},
        )
        .unwrap()
    };
    let default = plain(7);
    assert_eq!((default.cycles(), default.iters()), (2, 4));
    let cycles = run(&default);
    let cascade = run(&Params {
        cycles: Some(1),
        iters: Some(8),
        ..plain(7)
    });
    assert_eq!(cycles.mesh.vertices, cascade.mesh.vertices);
    assert_eq!(cycles.mesh.triangles, cascade.mesh.triangles);
    let note = |w: &[spsr::Warning]| {
        w.iter()
            .find(|w| matches!(w, spsr::Warning::SlabCascade { .. }))
            .map(|w| w.to_string())
    };
    let text = note(&cycles.stats.warnings).expect("the default's two cycles are noted");
    assert!(
        text.contains("8 sweeps") && text.contains("2 solver cycles"),
        "{text}"
    );
    assert_eq!(note(&cascade.stats.warnings), None);
}
