//! Slab mode (issue 15): the mesh of a run cut into slabs is one closed manifold surface
//! that matches the in-core mesh within a fraction of a finest cell.

use spsr::attributes::{Attribute, AttributeData, ScalarType};
use spsr::metrics::MeshDistance;
use spsr::slabs::{self, SlabOptions, Source};
use spsr::trim::{Threshold, TrimParams};
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

/// The slab runs of `params` against the in-core run of the same parameters (the slabs run
/// the same solver cycles, the coarse depths' across all slabs).
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
fn slabs_match_the_in_core_noisy_sphere_with_noise_adaptation() {
    // Noise the adaptation measures and acts on: each slab queries its own density at each
    // noisy sample's raised samples per node, as the in-core run does.
    let cloud = crate::noise::noisy_sphere(30_000, 0.02, 0.1, 3);
    let params = Params {
        depth: 8,
        ..Params::default()
    };
    compare("noisy sphere (adaptive)", &cloud, &params, &[3]);
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
    run_job_trimmed(cloud, params, None, k, root, out)
}

/// As [`run_job`], for a job that trims its mesh (`trim`).
fn run_job_trimmed(
    cloud: &PointCloud,
    params: &Params,
    trim: Option<&TrimParams>,
    k: usize,
    root: &std::path::Path,
    out: &std::path::Path,
) -> slabs::Written {
    use slabs::job;
    let j = job::prepare(Source::Cloud(cloud), params, trim, k, root).unwrap();
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
    for _ in 1..j.cycles {
        // The iso-value waits for the last cycle.
        assert!(job::iso(&j.dir).is_err());
        job::cycle(&j.dir).unwrap();
        each(job::solve);
    }
    assert!(job::cycle(&j.dir).is_err(), "no cycle after the last");
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
        Params {
            solver: spsr::Solver::VCycle,
            cycles: Some(3),
            ..plain(7)
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
    let j = job::prepare(Source::Cloud(&cloud), &plain(6), None, 2, dir.path()).unwrap();
    // Extraction before the iso-value, a slab the job lacks, a solve before the coarse solve.
    let e = job::extract(&j.dir, 0).unwrap_err().to_string();
    assert!(e.contains("iso"), "{e}");
    assert!(job::coarse(&j.dir, j.slabs).is_err());
    assert!(job::solve(&j.dir, 0).is_err());
    assert!(job::cycle(&j.dir).is_err());
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
fn slabs_refuse_w_cycles_with_the_field_named() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = torus(2_000, 0.3, 0.1, 7);
    let params = Params {
        solver: spsr::Solver::WCycle,
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
        other => panic!("{other:?}"),
    }
}

#[test]
fn slabs_refuse_a_residual_report_with_the_field_named() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = torus(2_000, 0.3, 0.1, 7);
    let params = Params {
        report_residuals: true,
        ..Params::default()
    };
    let options = SlabOptions {
        slabs: 2,
        work_dir: dir.path().to_path_buf(),
    };
    match slabs::reconstruct(Source::Cloud(&cloud), &params, &options, &|_| {}) {
        Err(spsr::Error::InvalidParameter { field, .. }) => assert_eq!(field, "report_residuals"),
        other => panic!("{:?}", other.map(|r| r.mesh.vertices.len())),
    }
}

#[test]
fn slabs_run_v_cycles_across_the_slabs() {
    // Three V-cycles: the slabs' finer depths are relaxed going down too, before the whole
    // cloud's coarse depths; the mesh is the in-core V-cycles' mesh, not the cascadic one.
    let dir = tempfile::tempdir().unwrap();
    let cloud = bunny();
    let params = Params {
        solver: spsr::Solver::VCycle,
        cycles: Some(3),
        ..plain(8)
    };
    let slab = slabs::reconstruct(
        Source::Cloud(&cloud),
        &params,
        &slab_options(3, dir.path()),
        &|_| {},
    )
    .unwrap()
    .mesh;
    let v = spsr::reconstruct(&cloud, &params).unwrap().mesh;
    let cascadic = spsr::reconstruct(
        &cloud,
        &Params {
            solver: spsr::Solver::Cascadic,
            ..params.clone()
        },
    )
    .unwrap()
    .mesh;
    let h = cell(&cloud, &params);
    let (to_v, _) = distances(&slab, &v);
    let (apart, _) = distances(&cascadic, &v);
    eprintln!(
        "V-cycle slabs to in-core: {:.2e} cells; cascadic to V in-core: {:.2e} cells",
        to_v / h,
        apart / h
    );
    assert!(to_v < 0.01 * h, "{} cells", to_v / h);
    assert!(to_v < 0.1 * apart, "{to_v} against {apart}");
    let topo = assert_closed_manifold(&slab, "V-cycle slabs");
    assert_eq!(topo.components, 1);
}

#[test]
fn slabs_run_the_solver_cycles_across_the_slabs() {
    // The default's second cycle passes the slabs' finer depths down to the whole cloud's
    // coarse depths and back: the slab mesh is the in-core mesh of two cycles, much closer to
    // it than the in-core mesh of one cascade of the same sweeps is.
    let dir = tempfile::tempdir().unwrap();
    let cloud = bunny();
    let params = plain(8);
    assert_eq!((params.cycles(), params.iters()), (2, 4));
    let slab = slabs::reconstruct(
        Source::Cloud(&cloud),
        &params,
        &SlabOptions {
            slabs: 4,
            work_dir: dir.path().to_path_buf(),
        },
        &|_| {},
    )
    .unwrap();
    let cycles = spsr::reconstruct(&cloud, &params).unwrap().mesh;
    let cascade = spsr::reconstruct(
        &cloud,
        &Params {
            cycles: Some(1),
            iters: Some(8),
            ..params.clone()
        },
    )
    .unwrap()
    .mesh;
    let h = cell(&cloud, &params);
    let (to_cycles, mean_cycles) = distances(&slab.mesh, &cycles);
    let (apart, mean_apart) = distances(&cascade, &cycles);
    eprintln!(
        "slabs to two cycles: max {:.2e} mean {:.2e} cells; one cascade to two cycles: max {:.2e} \
         mean {:.2e} cells",
        to_cycles / h,
        mean_cycles / h,
        apart / h,
        mean_apart / h
    );
    assert!(to_cycles < 0.1 * apart, "{to_cycles} against {apart}");
    assert!(mean_cycles < 0.1 * mean_apart);
    // Stage by stage, the progress heard each cycle.
    let names: Vec<&str> = slab.stats.stages.iter().map(|s| s.0.as_str()).collect();
    assert!(
        names.contains(&"cycle 2: coarse depths") && names.contains(&"cycle 2: slabs"),
        "{names:?}"
    );
}

/// For each vertex of `a`, the index of the nearest vertex of `b` and its distance (a grid of
/// buckets of width `h`, searched in the 27 around the vertex).
fn nearest_vertices(a: &Mesh, b: &Mesh, h: f64) -> Vec<(usize, f64)> {
    use std::collections::HashMap;
    let key = |p: [f64; 3]| p.map(|c| (c / h).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (i, p) in b.vertices.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(i);
    }
    a.vertices
        .iter()
        .map(|p| {
            let k = key(*p);
            let mut best = (usize::MAX, f64::INFINITY);
            for o in 0..27i64 {
                let c = [k[0] + o % 3 - 1, k[1] + (o / 3) % 3 - 1, k[2] + o / 9 - 1];
                for &j in grid.get(&c).into_iter().flatten() {
                    let q = b.vertices[j];
                    let d = (0..3).map(|x| (p[x] - q[x]).powi(2)).sum::<f64>().sqrt();
                    if d < best.1 {
                        best = (j, d);
                    }
                }
            }
            best
        })
        .collect()
}

fn slab_options(k: usize, dir: &std::path::Path) -> SlabOptions {
    SlabOptions {
        slabs: k,
        work_dir: dir.to_path_buf(),
    }
}

/// The bunny with three attributes that vary across it: a `u8` red channel along x, an `f32`
/// intensity along y and an `f64` height (z), as a scan's colours and measurements do.
fn coloured_bunny() -> PointCloud {
    let mut cloud = bunny();
    let red = cloud
        .positions
        .iter()
        .map(|p| (127.5 + 127.0 * (8.0 * p[0]).sin()) as u8)
        .collect();
    let intensity = cloud
        .positions
        .iter()
        .map(|p| (p[1] * 3.0).cos() as f32)
        .collect();
    let height = cloud.positions.iter().map(|p| p[2]).collect();
    cloud.attributes = vec![
        Attribute::new("red", AttributeData::U8(red)),
        Attribute::new("intensity", AttributeData::F32(intensity)),
        Attribute::new("height", AttributeData::F64(height)),
    ];
    cloud
}

/// Each slab vertex carries the attributes of the in-core vertex at its place: the samples'
/// sums are the whole cloud's at the depths coarser than the slabs' padding (summed from
/// every slab's own samples) and the slab's own at the finer ones. A pull factor of 1 weighs
/// every depth alike, so a coarse sum that missed another slab's samples would show in the
/// `f64` height; the default (32) is checked on the written mesh, which also has the
/// in-core mesh's properties in its order and types.
#[test]
fn slabs_carry_attributes_as_one_piece() {
    let cloud = coloured_bunny();
    let dir = tempfile::tempdir().unwrap();
    for pull in [1.0, 32.0] {
        let params = Params {
            attributes: true,
            data_pull: pull,
            ..plain(8)
        };
        let whole = spsr::reconstruct(&cloud, &params).unwrap().mesh;
        let h = cell(&cloud, &params);
        for k in [3, 5] {
            let out = if pull == 1.0 {
                slabs::reconstruct(
                    Source::Cloud(&cloud),
                    &params,
                    &slab_options(k, dir.path()),
                    &|_| {},
                )
                .unwrap()
                .mesh
            } else {
                let path = dir.path().join(format!("slabs-{k}.ply"));
                slabs::reconstruct_into(
                    Source::Cloud(&cloud),
                    &params,
                    &slab_options(k, dir.path()),
                    &path,
                    &|_| {},
                )
                .unwrap();
                spsr::io::read_mesh(&path).unwrap()
            };
            let names = |m: &Mesh| -> Vec<(String, ScalarType)> {
                m.attributes
                    .iter()
                    .map(|a| (a.name.clone(), a.data.scalar_type()))
                    .collect()
            };
            assert_eq!(names(&out), names(&whole), "pull {pull}, {k} slabs");
            assert_eq!(
                out.vertices.len(),
                whole.vertices.len(),
                "pull {pull}, {k} slabs"
            );
            let near = nearest_vertices(&out, &whole, h);
            let mut worst = [0.0f64; 3];
            for (i, &(j, dist)) in near.iter().enumerate() {
                assert!(
                    dist < 0.01 * h,
                    "pull {pull}, {k} slabs: vertex {i} {dist} from in-core"
                );
                for (c, w) in worst.iter_mut().enumerate() {
                    let a = out.attributes[c].data.get(i).unwrap();
                    let b = whole.attributes[c].data.get(j).unwrap();
                    *w = w.max((a - b).abs());
                }
            }
            eprintln!(
                "pull {pull}, {k} slabs: largest differences (red, intensity, height) {worst:?}"
            );
            // The vertices lie within 1e-4 cells of the in-core ones, and the sums differ by
            // the order of their additions only.
            assert!(worst[0] <= 1.0, "pull {pull}, {k} slabs: red {}", worst[0]);
            assert!(
                worst[1] <= 1e-5,
                "pull {pull}, {k} slabs: intensity {}",
                worst[1]
            );
            assert!(
                worst[2] <= 1e-5 * h,
                "pull {pull}, {k} slabs: height {}",
                worst[2]
            );
        }
    }
}

/// Tiles read as one cloud must carry the same properties, as when they are read into memory;
/// the error names the tile that differs.
#[test]
fn slab_tiles_with_different_properties_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let plain_tile = dir.path().join("plain.ply");
    let coloured_tile = dir.path().join("coloured.ply");
    spsr::io::write_cloud(&plain_tile, &bunny(), &Default::default()).unwrap();
    spsr::io::write_cloud(&coloured_tile, &coloured_bunny(), &Default::default()).unwrap();
    let tiles = [plain_tile, coloured_tile.clone()];
    let params = Params {
        attributes: true,
        ..plain(6)
    };
    let e = slabs::reconstruct(
        Source::Files(&tiles),
        &params,
        &slab_options(2, dir.path()),
        &|_| {},
    )
    .expect_err("refused");
    let text = e.to_string();
    assert!(
        text.contains("coloured.ply") && text.contains("properties differ"),
        "{text}"
    );
    // Without attributes the tiles are one cloud.
    let params = Params {
        attributes: false,
        ..params
    };
    slabs::reconstruct(
        Source::Files(&tiles),
        &params,
        &slab_options(2, dir.path()),
        &|_| {},
    )
    .unwrap();
    // Only the tiles remain: no job folder.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}

/// The density of each slab vertex is the in-core estimator's at that place: the slabs read
/// the whole cloud's estimator at the depths coarser than their padding (the bunny's open
/// bottom is closed by surface far from the samples, whose density walks up to those
/// depths). At depth 6 the kernel depth lies above the columns' depth and every depth is the
/// whole cloud's; at depth 8 the finer depths are the slab's own.
#[test]
fn slab_density_is_the_in_core_density() {
    let cloud = bunny();
    let dir = tempfile::tempdir().unwrap();
    for depth in [6, 8] {
        let params = Params {
            density: true,
            cycles: Some(1),
            iters: Some(8),
            ..plain(depth)
        };
        let whole = spsr::reconstruct(&cloud, &params).unwrap().mesh;
        let h = cell(&cloud, &params);
        let wd = whole.density.as_ref().expect("in-core density");
        let (lo, hi) = wd
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &d| (lo.min(d), hi.max(d)));
        for k in [3, 5] {
            let out = slabs::reconstruct(
                Source::Cloud(&cloud),
                &params,
                &slab_options(k, dir.path()),
                &|_| {},
            )
            .unwrap()
            .mesh;
            let sd = out.density.as_ref().expect("slab density");
            assert_eq!(sd.len(), out.vertices.len());
            let near = nearest_vertices(&out, &whole, h);
            let mut worst = 0.0f64;
            let mut off = 0;
            for (i, &(j, dist)) in near.iter().enumerate() {
                assert!(
                    dist < 0.01 * h,
                    "depth {depth}, {k} slabs: vertex {i} {dist} from in-core"
                );
                let diff = f64::from((sd[i] - wd[j]).abs());
                worst = worst.max(diff);
                if diff > 1e-3 {
                    off += 1;
                }
            }
            eprintln!(
                "depth {depth}, {k} slabs: {} / {} vertices, density {lo}..{hi}, largest difference {worst:.2e}, {off} over 1e-3",
                out.vertices.len(),
                whole.vertices.len()
            );
            assert_eq!(
                out.vertices.len(),
                whole.vertices.len(),
                "depth {depth}, {k} slabs"
            );
            assert_eq!(
                out.triangles.len(),
                whole.triangles.len(),
                "depth {depth}, {k} slabs"
            );
            // The vertices lie within 1e-4 cells of the in-core ones and the density moves
            // with them by as little (at most 8e-5 here). Slabs reading their own estimator
            // at every depth are up to 5e-3 off at depth 8 (4 vertices over 1e-3 with 5
            // slabs): the coarse depths must be the whole cloud's.
            assert_eq!(off, 0, "depth {depth}, {k} slabs: {off} vertices differ");
        }
    }
}

/// `--density` in slabs, written as the slabs come: the density of the mesh assembled in
/// memory, and the same bytes from the tasks of a job. (The slab count moves the vertices by
/// up to 1e-4 finest cells, as it does without density, so the bytes depend on it; the
/// estimator the density is read from does not: see `slab_density_is_the_in_core_density`.)
#[test]
fn slab_density_is_written_as_the_slabs_come_and_by_tasks() {
    let cloud = bunny();
    let dir = tempfile::tempdir().unwrap();
    let params = Params {
        density: true,
        ..plain(8)
    };
    let options = slab_options(3, dir.path());
    let in_memory = slabs::reconstruct(Source::Cloud(&cloud), &params, &options, &|_| {})
        .unwrap()
        .mesh;
    let one = dir.path().join("one.ply");
    slabs::reconstruct_into(Source::Cloud(&cloud), &params, &options, &one, &|_| {}).unwrap();
    let read = spsr::io::read_mesh(&one).unwrap();
    assert_eq!(read.triangles, in_memory.triangles);
    assert_eq!(
        read.density, in_memory.density,
        "the density written as the slabs come"
    );
    let tasks = dir.path().join("tasks.ply");
    run_job(&cloud, &params, 3, dir.path(), &tasks);
    assert!(
        std::fs::read(&one).unwrap() == std::fs::read(&tasks).unwrap(),
        "the tasks' mesh differs from the one-process run's"
    );
}

/// `--trim` in slabs: one threshold for the whole mesh, chosen from the whole mesh's
/// densities as in one piece, and the trimmed mesh of one piece within a fraction of a cell
/// (same counts, pieces and boundary) for any slab count; the tasks of a job write the bytes
/// of the one-process run.
#[test]
fn slab_trim_is_the_in_core_trim() {
    let cloud = bunny();
    let dir = tempfile::tempdir().unwrap();
    let params = Params {
        cycles: Some(1),
        iters: Some(8),
        ..plain(8)
    };
    let h = cell(&cloud, &params);
    for threshold in [Threshold::Auto, Threshold::Value(6.5)] {
        let trim = TrimParams {
            threshold,
            ..TrimParams::default()
        };
        let (whole, wt) =
            spsr::reconstruct_and_trim(cloud.clone(), &params, &trim, &|_| {}).unwrap();
        let mut meshes = Vec::new();
        for k in [2, 3] {
            let (out, st) = slabs::reconstruct_and_trim(
                Source::Cloud(&cloud),
                &params,
                &slab_options(k, dir.path()),
                &trim,
                &|_| {},
            )
            .unwrap();
            eprintln!(
                "{threshold:?}, {k} slabs: threshold {} (in one piece {}), {} / {} vertices, {} / {} triangles, pieces {} / {}",
                st.threshold,
                wt.threshold,
                out.mesh.vertices.len(),
                whole.mesh.vertices.len(),
                out.mesh.triangles.len(),
                whole.mesh.triangles.len(),
                out.stats.diagnosis.pieces,
                whole.stats.diagnosis.pieces,
            );
            assert!(
                (st.threshold - wt.threshold).abs() < 1e-4,
                "{threshold:?}: thresholds"
            );
            assert!(
                out.mesh.density.is_none(),
                "density kept only when asked for"
            );
            assert_eq!(out.mesh.triangles.len(), whole.mesh.triangles.len());
            assert_eq!(out.mesh.vertices.len(), whole.mesh.vertices.len());
            assert_eq!(out.stats.diagnosis.pieces, whole.stats.diagnosis.pieces);
            assert_eq!(out.stats.diagnosis.closed, whole.stats.diagnosis.closed);
            assert_eq!(
                out.stats.diagnosis.boundary_edges,
                whole.stats.diagnosis.boundary_edges
            );
            let (max, mean) = distances(&out.mesh, &whole.mesh);
            assert!(
                max <= 0.01 * h,
                "{threshold:?}, {k} slabs: {} cells apart",
                max / h
            );
            assert!(
                mean <= 1e-3 * h,
                "{threshold:?}, {k} slabs: mean {} cells",
                mean / h
            );
            meshes.push(out.mesh);
        }
        // The tasks of a job write the same bytes as the one-process run.
        let one = dir.path().join("one.ply");
        spsr::io::write_mesh(&one, &meshes[1], &spsr::io::WriteOptions { ascii: false }).unwrap();
        let tasks = dir.path().join("tasks.ply");
        run_job_trimmed(&cloud, &params, Some(&trim), 3, dir.path(), &tasks);
        assert!(
            std::fs::read(&one).unwrap() == std::fs::read(&tasks).unwrap(),
            "{threshold:?}: the tasks' trimmed mesh differs"
        );
    }
    // Only the meshes are left.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
}

/// `--trim` written as the slabs come: the mesh is trimmed from the work files a slab at a
/// time, never whole in memory, and the file holds the bytes of the mesh trimmed in memory
/// (`slabs::reconstruct_and_trim`, written by `io::write_mesh`), with the same figures: the
/// automatic threshold from the whole mesh's densities (its sorted runs merged), the cut
/// vertices on the shared faces made once, the islands and holes that cross slabs. Checked
/// with colours and other properties interpolated on the cut, with and without the density
/// kept, at the automatic threshold and at one that cuts the bunny into islands (removed or
/// kept whole by the area rule).
#[test]
fn slab_trim_written_as_the_slabs_come_is_the_trim_in_memory() {
    let cloud = coloured_bunny();
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (Threshold::Auto, 0.001, false, 3),
        (Threshold::Value(6.6), 0.001, true, 4),
        (Threshold::Value(6.6), 0.0, false, 2),
        (Threshold::Value(6.3), 0.01, false, 5),
    ];
    for (threshold, areas, density, k) in cases {
        let params = Params {
            attributes: true,
            density,
            cycles: Some(1),
            ..plain(8)
        };
        let trim = TrimParams {
            threshold,
            min_island_area: areas,
            hole_area: areas,
        };
        let options = slab_options(k, dir.path());
        let (memory, stats) =
            slabs::reconstruct_and_trim(Source::Cloud(&cloud), &params, &options, &trim, &|_| {})
                .unwrap();
        let expected = dir.path().join("memory.ply");
        let opts = spsr::io::WriteOptions { ascii: false };
        spsr::io::write_mesh(&expected, &memory.mesh, &opts).unwrap();
        let streamed = dir.path().join("streamed.ply");
        let (st, written, streamed_stats) = slabs::reconstruct_and_trim_into(
            Source::Cloud(&cloud),
            &params,
            &options,
            &trim,
            &streamed,
            &|_| {},
        )
        .unwrap();
        let what = format!("{threshold:?}, areas {areas}, density {density}, {k} slabs");
        eprintln!(
            "{what}: V = {}, {} of {} triangles, {} cut vertices, {} islands removed, {} holes \
             restored, {} pieces, {} open edges",
            stats.threshold,
            stats.triangles_out,
            stats.triangles_in,
            stats.cut_vertices,
            stats.islands_removed,
            stats.holes_filled,
            written.pieces,
            written.open_edges
        );
        assert_eq!(streamed_stats, stats, "{what}: the trimming's figures");
        assert!(
            std::fs::read(&expected).unwrap() == std::fs::read(&streamed).unwrap(),
            "{what}: the streamed trim's bytes differ from the trim in memory"
        );
        assert_eq!(written.vertices as usize, memory.mesh.vertices.len());
        assert_eq!(written.triangles as usize, memory.mesh.triangles.len());
        let d = &memory.stats.diagnosis;
        assert_eq!(
            (written.pieces, written.open_edges as usize),
            (d.pieces, d.boundary_edges),
            "{what}: the checks on the way"
        );
        assert_eq!(
            (
                st.diagnosis.pieces,
                st.diagnosis.closed,
                st.diagnosis.trimmed
            ),
            (d.pieces, d.closed, true)
        );
        // The trimmed mesh has boundaries, and what it keeps is manifold.
        let topo = spsr::io::read_mesh(&streamed).unwrap().topology();
        assert!(!topo.closed && topo.edge_manifold, "{what}: {topo:?}");
        // Only the meshes are left: the work files, cut and runs included, are gone.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, "{what}");
    }
}

/// A threshold that removes the whole mesh is refused as in memory (the field named, the
/// mesh's density range given), with no output written and no work file left.
#[test]
fn a_streamed_trim_that_keeps_nothing_fails_cleanly() {
    let cloud = torus(5_000, 1.0, 0.35, 3);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.ply");
    let trim = TrimParams {
        threshold: Threshold::Value(100.0),
        ..TrimParams::default()
    };
    let e = slabs::reconstruct_and_trim_into(
        Source::Cloud(&cloud),
        &plain(6),
        &slab_options(2, dir.path()),
        &trim,
        &out,
        &|_| {},
    )
    .unwrap_err();
    match e {
        spsr::Error::InvalidParameter {
            field, expected, ..
        } => {
            assert_eq!(field, "threshold");
            assert!(expected.contains("densities range from"), "{expected}");
        }
        e => panic!("{e:?}"),
    }
    assert!(!out.exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// With adaptive noise, the small closed pieces that noise leaves (stage 9) are removed from
/// a mesh written as the slabs come, as from the mesh in memory: the same bytes, and the same
/// warning. The cloud is a sphere with a speck of points beside it, which closes into a
/// piece of less than a thousandth of the area.
#[test]
fn slab_fragments_are_removed_from_the_mesh_written_as_the_slabs_come() {
    let mut cloud = crate::common::sphere(20_000, [0.0; 3], 1.0, 5);
    let speck = crate::common::sphere(400, [1.6, 0.0, 0.0], 0.025, 6);
    cloud.positions.extend(speck.positions);
    cloud.normals.extend(speck.normals);
    let params = Params {
        depth: 8,
        attributes: false,
        keep_outliers: true,
        ..Params::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let options = slab_options(3, dir.path());
    let memory = slabs::reconstruct(Source::Cloud(&cloud), &params, &options, &|_| {}).unwrap();
    let removed = |w: &[spsr::Warning]| {
        w.iter()
            .find_map(|w| match w {
                spsr::Warning::FragmentsRemoved { pieces } => Some(*pieces),
                _ => None,
            })
            .unwrap_or(0)
    };
    assert!(
        removed(&memory.stats.warnings) > 0,
        "the speck is a small piece"
    );
    assert_eq!(memory.stats.diagnosis.pieces, 1);
    let expected = dir.path().join("memory.ply");
    let opts = spsr::io::WriteOptions { ascii: false };
    spsr::io::write_mesh(&expected, &memory.mesh, &opts).unwrap();
    let streamed = dir.path().join("streamed.ply");
    let (stats, written) =
        slabs::reconstruct_into(Source::Cloud(&cloud), &params, &options, &streamed, &|_| {})
            .unwrap();
    assert_eq!(
        removed(&stats.warnings),
        removed(&memory.stats.warnings),
        "the same warning"
    );
    assert_eq!((written.pieces, written.open_edges), (1, 0));
    assert!(
        std::fs::read(&expected).unwrap() == std::fs::read(&streamed).unwrap(),
        "the streamed mesh's bytes differ from the mesh in memory"
    );
    // With the noise adaptation off, nothing is removed (the reference's mesh).
    let off = Params {
        noise: Noise::Off,
        ..params
    };
    let (stats, written) =
        slabs::reconstruct_into(Source::Cloud(&cloud), &off, &options, &streamed, &|_| {}).unwrap();
    assert_eq!(removed(&stats.warnings), 0);
    assert!(written.pieces > 1);
}

#[test]
fn the_slab_stage_plan_is_what_the_progress_callback_hears() {
    // The progress bar's length: the stages of every solver cycle, streamed or in memory,
    // trimmed or not.
    let cloud = torus(5_000, 1.0, 0.35, 3);
    let dir = tempfile::tempdir().unwrap();
    let options = slab_options(2, dir.path());
    let v_cycles = Params {
        solver: spsr::Solver::VCycle,
        cycles: Some(3),
        ..plain(6)
    };
    let one_cycle = Params {
        cycles: Some(1),
        ..plain(6)
    };
    let adaptive = Params {
        depth: 6,
        attributes: false,
        ..Params::default()
    };
    for (params, streamed, trimming) in [
        (plain(6), false, false),
        (v_cycles, true, false),
        (one_cycle, false, true),
        (adaptive, false, false),
    ] {
        let heard = std::sync::Mutex::new(Vec::new());
        let progress = |s: &str| heard.lock().unwrap().push(s.to_string());
        let source = Source::Cloud(&cloud);
        if streamed {
            let out = dir.path().join("out.ply");
            slabs::reconstruct_into(source, &params, &options, &out, &progress).unwrap();
        } else if trimming {
            let trim = TrimParams::default();
            slabs::reconstruct_and_trim(source, &params, &options, &trim, &progress).unwrap();
        } else {
            slabs::reconstruct(source, &params, &options, &progress).unwrap();
        }
        assert_eq!(
            heard.into_inner().unwrap(),
            slabs::stage_plan(&params, streamed, trimming),
            "{:?} with {} cycles",
            params.solver,
            params.cycles()
        );
    }
}
