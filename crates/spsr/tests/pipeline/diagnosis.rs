//! Stage 9, the checks of the result: clean clouds give one closed piece and no warning; each
//! kind of likely garbage (normals flipped in places, contradictory normals, noise, an open
//! scan) gives its one warning. And the stage plan the front ends count is the one reported.

use std::sync::Mutex;

use spsr::{Diagnosis, Params, PointCloud, Warning};

use crate::common::*;

/// PoissonRecon's behaviour (no noise adaptation, normals and outliers as given), which
/// leaves the garbage these checks are for.
fn at(depth: u32) -> Params {
    Params {
        depth,
        noise: spsr::Noise::Off,
        keep_normals: true,
        ..Params::default()
    }
}

/// The diagnosis of a reconstruction and the warnings it gave.
fn diagnose(cloud: &PointCloud, params: &Params) -> (Diagnosis, Vec<Warning>) {
    let r = spsr::reconstruct(cloud, params).unwrap();
    (r.stats.diagnosis, r.stats.warnings)
}

/// A standard normal deviate (Box–Muller).
fn gauss(rng: &mut Rng) -> f64 {
    let u = rng.next().max(1e-300);
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * rng.next()).cos()
}

/// The unit sphere with radial noise of `sigma` and normals perturbed by N(0, 0.2²) per
/// component, as the noisy scans of the shared data.
fn noisy_sphere(n: usize, sigma: f64) -> PointCloud {
    let mut rng = Rng(17);
    let clean = sphere(n, [0.0; 3], 1.0, 5);
    let mut positions = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    for (p, u) in clean.positions.iter().zip(&clean.normals) {
        let r = 1.0 + sigma * gauss(&mut rng);
        positions.push(p.map(|c| c * r));
        let m: [f64; 3] = std::array::from_fn(|a| u[a] + 0.2 * gauss(&mut rng));
        let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        normals.push(m.map(|c| c / l));
    }
    PointCloud::new(positions, normals).unwrap()
}

/// `cloud` with the normals of the points that `flip` picks reversed.
fn flipped(mut cloud: PointCloud, flip: impl Fn(usize, [f64; 3]) -> bool) -> PointCloud {
    for (i, (p, n)) in cloud
        .positions
        .iter()
        .zip(cloud.normals.iter_mut())
        .enumerate()
    {
        if flip(i, *p) {
            *n = n.map(|c| -c);
        }
    }
    cloud
}

fn is_diagnosis(w: &Warning) -> bool {
    matches!(
        w,
        Warning::SurfaceOnCube(_) | Warning::ContradictoryNormals(_) | Warning::ManyPieces(_)
    )
}

#[test]
fn clean_closed_clouds_give_one_closed_piece_and_no_warning() {
    for (what, cloud) in [
        ("sphere", sphere(20_000, [0.1, -0.2, 0.3], 1.0, 1)),
        ("torus", torus(30_000, 1.0, 0.35, 2)),
        ("bunny", bunny()),
    ] {
        let (d, warnings) = diagnose(&cloud, &at(8));
        assert_eq!(
            (d.pieces, d.closed, d.on_cube),
            (1, true, 0),
            "{what}: {d:?}"
        );
        assert!(d.contradicted_normals < 0.01, "{what}: {d:?}");
        assert!(warnings.is_empty(), "{what}: {warnings:?}");
    }
}

#[test]
fn half_flipped_normals_warn_of_a_surface_cut_by_the_cube() {
    let cloud = flipped(sphere(20_000, [0.0; 3], 1.0, 3), |_, p| p[2] > 0.3);
    let (d, warnings) = diagnose(&cloud, &at(7));
    assert!(!d.closed && d.on_cube > 0, "{d:?}");
    assert!(
        matches!(warnings[..], [Warning::SurfaceOnCube(_)]),
        "{warnings:?}"
    );
    let text = warnings[0].to_string();
    assert!(
        text.contains("flipped") && text.contains("re-orient the normals"),
        "{text}"
    );
}

#[test]
fn randomly_flipped_normals_warn_of_contradictory_normals() {
    let cloud = flipped(sphere(20_000, [0.0; 3], 1.0, 4), |i, _| i % 4 == 0);
    let (d, warnings) = diagnose(&cloud, &at(7));
    assert!(d.contradicted_normals > 0.1, "{d:?}");
    assert!(
        matches!(warnings[..], [Warning::ContradictoryNormals(_)]),
        "{warnings:?}"
    );
}

#[test]
fn noise_warns_of_many_pieces_and_the_advice_helps() {
    let cloud = noisy_sphere(30_000, 0.04);
    let (d, warnings) = diagnose(&cloud, &at(7));
    assert!(d.pieces > 20, "{d:?}");
    assert!(
        matches!(warnings[..], [Warning::ManyPieces(_)]),
        "{warnings:?}"
    );
    let text = warnings[0].to_string();
    assert!(
        text.contains("noisy") && text.contains("samples_per_node 5") && text.contains("depth 6"),
        "{text}"
    );
    // The advice: more samples per node average the noise out.
    let smoother = Params {
        samples_per_node: 5.0,
        ..at(7)
    };
    let (d, warnings) = diagnose(&cloud, &smoother);
    assert!(d.pieces < 20 && !warnings.iter().any(is_diagnosis), "{d:?}");
}

#[test]
fn an_open_scan_reaches_the_cube_and_trimming_is_advised_until_it_is_done() {
    // A bumpy square patch, normals up: Poisson continues it to the cube.
    let mut rng = Rng(9);
    let (mut positions, mut normals) = (Vec::new(), Vec::new());
    for _ in 0..20_000 {
        let (x, y) = (2.0 * rng.next() - 1.0, 2.0 * rng.next() - 1.0);
        positions.push([x, y, 0.1 * (3.0 * x).sin() * (2.0 * y).cos()]);
        let g = [
            0.3 * (3.0 * x).cos() * (2.0 * y).cos(),
            -0.2 * (3.0 * x).sin() * (2.0 * y).sin(),
        ];
        let l = (1.0 + g[0] * g[0] + g[1] * g[1]).sqrt();
        normals.push([-g[0] / l, -g[1] / l, 1.0 / l]);
    }
    let patch = PointCloud::new(positions, normals).unwrap();
    let (d, warnings) = diagnose(&patch, &at(7));
    assert!(d.on_cube > 0 && !d.closed, "{d:?}");
    assert!(matches!(warnings[..], [Warning::SurfaceOnCube(_)]));
    assert!(warnings[0].to_string().contains("threshold auto"));
    // Trimmed, the invented surface (and the warning) is gone.
    let trim = spsr::trim::TrimParams::default();
    let (r, _) = spsr::reconstruct_and_trim(patch, &at(7), &trim, &|_| {}).unwrap();
    let d = r.stats.diagnosis;
    assert!(d.trimmed && d.on_cube == 0, "{d:?}");
    assert!(!r.stats.warnings.iter().any(is_diagnosis));
}

#[test]
fn the_stage_plan_is_what_the_progress_callback_hears() {
    let cloud = sphere(3_000, [0.0; 3], 1.0, 6);
    let quadratic = Params {
        depth: 6,
        full_depth: 3,
        degree: spsr::Degree::Quadratic,
        ..Params::default()
    };
    let cycles = Params {
        solver: spsr::Solver::WCycle,
        cycles: Some(3),
        ..at(6)
    };
    for (params, trimming) in [
        (at(5), false),
        (quadratic, false),
        (at(6), true),
        (cycles, false),
    ] {
        let heard = Mutex::new(Vec::new());
        let progress = |s: &str| heard.lock().unwrap().push(s.to_string());
        if trimming {
            let trim = spsr::trim::TrimParams::default();
            spsr::reconstruct_and_trim(cloud.clone(), &params, &trim, &progress).unwrap();
        } else {
            spsr::reconstruct_with_progress(&cloud, &params, &progress).unwrap();
        }
        assert_eq!(
            heard.into_inner().unwrap(),
            spsr::stage_plan(&params, trimming)
        );
    }
}
