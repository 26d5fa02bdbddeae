//! Normal estimation and orientation on generated clouds whose true normals are known.

use crate::common::{boxed, sphere, torus, Rng};
use spsr::normals::{compare, estimate, orient, Comparison, NormalParams, Orientation};
use spsr::{Error, PointCloud};

/// Estimates and orients the normals of `cloud`'s positions, compares them with its normals.
fn run(cloud: &PointCloud, how: &Orientation) -> Comparison {
    let mut n = estimate(&cloud.positions, &NormalParams::default())
        .unwrap()
        .normals;
    orient(&cloud.positions, &mut n, how).unwrap();
    compare(&n, &cloud.normals).unwrap()
}

/// A hollow ball: the sphere of radius 1 with outward normals and, `gap` inside it, the
/// sphere of radius `1 − gap` whose normals point to the centre (outward from the solid wall).
fn hollow_ball(n: usize, gap: f64, seed: u64) -> PointCloud {
    let r_in = 1.0 - gap;
    let n_out = (n as f64 / (1.0 + r_in * r_in)).round() as usize;
    let outer = sphere(n_out, [0.0; 3], 1.0, seed);
    let inner = sphere(n - n_out, [0.0; 3], r_in, seed + 1);
    let mut pos = outer.positions;
    let mut nor = outer.normals;
    pos.extend(inner.positions);
    nor.extend(inner.normals.iter().map(|v| v.map(|c| -c)));
    PointCloud::new(pos, nor).unwrap()
}

fn gaussian(rng: &mut Rng) -> f64 {
    let (u, v) = (rng.next().max(1e-300), rng.next());
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}

#[test]
fn sphere_normals_are_accurate_and_outward() {
    let cloud = sphere(10_000, [0.3, -0.2, 5.0], 2.0, 1);
    for how in [Orientation::mst(), Orientation::global()] {
        let c = run(&cloud, &how);
        assert_eq!(c.compared, 10_000);
        assert_eq!(c.flipped_fraction, 0.0, "{how:?}: {c:?}");
        assert!(c.mean_angle_deg < 1.0, "{c:?}");
    }
}

#[test]
fn torus_normals_are_outward_on_both_sides_of_the_hole() {
    let cloud = torus(20_000, 1.0, 0.35, 2);
    for how in [Orientation::mst(), Orientation::global()] {
        let c = run(&cloud, &how);
        assert!(c.flipped_fraction <= 0.005, "{how:?}: {c:?}");
        assert!(c.mean_angle_deg < 1.5, "{c:?}");
    }
}

#[test]
fn box_with_sharp_edges_is_oriented_across_the_creases() {
    let cloud = boxed(20_000, [1.0, 0.7, 0.4], 3);
    for how in [Orientation::mst(), Orientation::global()] {
        let c = run(&cloud, &how);
        assert!(c.flipped_fraction <= 0.005, "{how:?}: {c:?}");
        // Exact on the faces; only the points within a neighbourhood of an edge are blended.
        assert!(c.median_angle_deg < 0.01, "{c:?}");
    }
}

#[test]
fn global_corrects_the_inner_wall_of_a_hollow_ball_that_mst_gets_wrong() {
    // The two walls are 4–5 point spacings apart: no neighbourhood spans both, so the
    // propagation sees two separate pieces and turns both to point away from the centre.
    let cloud = hollow_ball(20_000, 0.15, 4);
    let inner = 20_000.0 * 0.85 * 0.85 / (1.0 + 0.85 * 0.85);
    let mst = run(&cloud, &Orientation::mst());
    assert!(
        mst.flipped_fraction > 0.9 * inner / 20_000.0,
        "mst was expected to fail here: {mst:?}"
    );
    let global = run(&cloud, &Orientation::global());
    assert!(global.flipped_fraction <= 0.005, "{global:?}");
    assert!(global.flipped_fraction < mst.flipped_fraction);
}

#[test]
fn noisy_sphere_gets_larger_neighbourhoods_and_stays_oriented() {
    let clean = sphere(20_000, [0.0; 3], 1.0, 5);
    let mut rng = Rng(99);
    // Noise of 1 % of the diameter in every coordinate, 0.8 point spacings (about the ratio
    // of the shared bunny set with noise of 0.25 % of its diagonal).
    let sigma = 0.02;
    let noisy: Vec<[f64; 3]> = clean
        .positions
        .iter()
        .map(|p| p.map(|c| c + sigma * gaussian(&mut rng)))
        .collect();
    let est = estimate(&noisy, &NormalParams::default()).unwrap();
    assert!(est.noisy && est.neighbours > 16, "chose {}", est.neighbours);
    let at16 = estimate(
        &noisy,
        &NormalParams {
            neighbours: Some(16),
            ..NormalParams::default()
        },
    )
    .unwrap();
    let c_auto = compare(&est.normals, &clean.normals).unwrap();
    let c_16 = compare(&at16.normals, &clean.normals).unwrap();
    assert!(
        c_auto.mean_angle_deg < c_16.mean_angle_deg,
        "{c_auto:?} {c_16:?}"
    );
    assert!(c_auto.mean_angle_deg < 6.0, "{c_auto:?}");
    for how in [Orientation::mst(), Orientation::global()] {
        let mut n = est.normals.clone();
        orient(&noisy, &mut n, &how).unwrap();
        let c = compare(&n, &clean.normals).unwrap();
        assert!(c.flipped_fraction <= 0.005, "{how:?}: {c:?}");
    }
}

#[test]
fn viewpoint_and_scan_origins_orient_towards_the_sensor() {
    // A wavy height field z = 0.1 sin(3x) cos(2y) over [-1, 1]², seen from above.
    let mut rng = Rng(7);
    let mut pos = Vec::new();
    let mut nor = Vec::new();
    for _ in 0..10_000 {
        let (x, y) = (2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0);
        let z = 0.1 * (3.0 * x).sin() * (2.0 * y).cos();
        let g = [
            0.3 * (3.0 * x).cos() * (2.0 * y).cos(),
            -0.2 * (3.0 * x).sin() * (2.0 * y).sin(),
        ];
        let l = (1.0 + g[0] * g[0] + g[1] * g[1]).sqrt();
        pos.push([x, y, z]);
        nor.push([-g[0] / l, -g[1] / l, 1.0 / l]);
    }
    let est = estimate(&pos, &NormalParams::default()).unwrap();
    assert!(!est.noisy && est.neighbours == 16);
    let mut n = est.normals.clone();
    orient(&pos, &mut n, &Orientation::Viewpoint([0.2, -0.1, 3.0])).unwrap();
    let c = compare(&n, &nor).unwrap();
    assert_eq!(c.flipped_fraction, 0.0, "{c:?}");

    // Without a viewpoint an open sheet has no outside; the global correction must at least
    // keep it consistent (all one way).
    let mut n = est.normals.clone();
    orient(&pos, &mut n, &Orientation::global()).unwrap();
    let c = compare(&n, &nor).unwrap();
    assert!(
        c.flipped_fraction.min(1.0 - c.flipped_fraction) == 0.0,
        "{c:?}"
    );

    // The same points as two scans: the first half seen from above, the second from below,
    // so the second half's normals must point down.
    let half = pos.len() / 2;
    let mut n = est.normals;
    let scans = vec![(0, [0.0, 0.0, 3.0]), (half, [0.0, 0.0, -3.0])];
    orient(&pos, &mut n, &Orientation::ScanOrigins(scans)).unwrap();
    assert!(n[..half].iter().zip(&nor).all(|(a, b)| a[2] * b[2] > 0.0));
    assert!(n[half..]
        .iter()
        .zip(&nor[half..])
        .all(|(a, b)| a[2] * b[2] < 0.0));
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let cloud = hollow_ball(5_000, 0.25, 8);
    let compute = || {
        let est = estimate(&cloud.positions, &NormalParams::default()).unwrap();
        let mut mst = est.normals.clone();
        orient(&cloud.positions, &mut mst, &Orientation::mst()).unwrap();
        let mut global = est.normals.clone();
        orient(&cloud.positions, &mut global, &Orientation::global()).unwrap();
        (est.normals, mst, global)
    };
    let pool = |t| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
    };
    let one = pool(1).install(compute);
    let three = pool(3).install(compute);
    assert!(one == three, "normals differ between 1 and 3 threads");
}

#[test]
fn degenerate_neighbourhoods_take_the_nearest_good_normal() {
    // A plane of points, plus 40 copies of one point above it and a short line of points
    // sticking out: the copies' neighbourhoods are all coincident.
    let mut rng = Rng(11);
    let mut pos: Vec<[f64; 3]> = (0..2000).map(|_| [rng.next(), rng.next(), 0.0]).collect();
    pos.extend(vec![[0.5, 0.5, 0.3]; 40]);
    let est = estimate(&pos, &NormalParams::default()).unwrap();
    assert_eq!(est.degenerate, 40);
    for n in &est.normals {
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((l - 1.0).abs() < 1e-9, "{n:?}");
        assert!(n[2].abs() > 0.999, "{n:?}");
    }
}

#[test]
fn too_few_collinear_or_non_finite_points_are_handled() {
    // Fewer points than neighbours: all of them are used.
    let few = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.1],
    ];
    let est = estimate(&few, &NormalParams::default()).unwrap();
    assert_eq!(est.neighbours, 3);
    assert!(est.normals.iter().all(|n| n[2].abs() > 0.99));

    // Two points.
    assert!(matches!(
        estimate(&few[..2], &NormalParams::default()),
        Err(Error::TooFewPoints { usable: 2, .. })
    ));

    // All on one line.
    let line: Vec<[f64; 3]> = (0..100).map(|i| [i as f64, 2.0 * i as f64, 1.0]).collect();
    assert!(matches!(
        estimate(&line, &NormalParams::default()),
        Err(Error::Degenerate(_))
    ));

    // Non-finite points are skipped and keep a zero normal, which orient leaves alone.
    let mut pts = sphere(3000, [0.0; 3], 1.0, 12).positions;
    pts[5] = [f64::NAN, 0.0, 0.0];
    pts[9] = [0.0, f64::INFINITY, 0.0];
    let est = estimate(&pts, &NormalParams::default()).unwrap();
    assert_eq!(est.non_finite, 2);
    assert_eq!(est.normals[5], [0.0; 3]);
    let mut n = est.normals;
    let stats = orient(&pts, &mut n, &Orientation::mst()).unwrap();
    assert_eq!(stats.skipped, 2);
    assert_eq!(n[9], [0.0; 3]);
    let c = compare(&n, &pts).unwrap();
    assert_eq!((c.compared, c.skipped), (2998, 2));
    assert_eq!(c.flipped_fraction, 0.0);
}

#[test]
fn bad_parameters_are_errors() {
    let pts = sphere(500, [0.0; 3], 1.0, 13).positions;
    let mut n = estimate(&pts, &NormalParams::default()).unwrap().normals;
    let zero_k = NormalParams {
        neighbours: Some(0),
        ..NormalParams::default()
    };
    assert!(matches!(
        estimate(&pts, &zero_k),
        Err(Error::InvalidParameter { .. })
    ));
    let bad = [
        Orientation::Viewpoint([f64::NAN, 0.0, 0.0]),
        Orientation::ScanOrigins(vec![]),
        Orientation::ScanOrigins(vec![(1, [0.0; 3])]),
        Orientation::ScanOrigins(vec![(0, [0.0; 3]), (10, [1.0; 3]), (10, [2.0; 3])]),
        Orientation::Mst { neighbours: 0 },
    ];
    for how in bad {
        assert!(
            matches!(
                orient(&pts, &mut n, &how),
                Err(Error::InvalidParameter { .. })
            ),
            "{how:?}"
        );
    }
    assert!(matches!(
        orient(&pts[..10], &mut n, &Orientation::mst()),
        Err(Error::LengthMismatch { .. })
    ));
    assert!(matches!(
        compare(&n[..3], &n),
        Err(Error::LengthMismatch { .. })
    ));
}

#[test]
fn compare_measures_line_angles_and_flips() {
    let reference = vec![[0.0, 0.0, 1.0]; 4];
    let t = 10f64.to_radians();
    let tilted = [0.0, t.sin(), t.cos()];
    let flipped = tilted.map(|c| -c);
    let c = compare(&[tilted, tilted, flipped, flipped], &reference).unwrap();
    assert_eq!(c.flipped_fraction, 0.5);
    assert!((c.mean_angle_deg - 10.0).abs() < 1e-9);
    assert!((c.mean_oriented_angle_deg - 90.0).abs() < 1e-9);
}
