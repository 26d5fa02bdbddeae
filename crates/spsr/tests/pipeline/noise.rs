//! The noise adaptation (issue 16): measured noise, smoother surfaces where the points are
//! noisy, unchanged surfaces where they are clean, and the removal of noise bubbles.

use crate::common::{assert_closed_manifold, sphere, Rng};
use spsr::attributes::{Attribute, AttributeData, ScalarType};
use spsr::{Mesh, Noise, Params, PointCloud};

/// A standard normal variate (Box–Muller).
fn gauss(rng: &mut Rng) -> f64 {
    let u = rng.next().max(1e-12);
    let v = rng.next();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

/// The unit sphere's points moved by Gaussian noise of `sigma` on every coordinate, normals
/// tilted by noise of `tilt` on every component.
pub(crate) fn noisy_sphere(n: usize, sigma: f64, tilt: f64, seed: u64) -> PointCloud {
    let mut cloud = sphere(n, [0.0; 3], 1.0, seed);
    let mut rng = Rng(seed ^ 0x9e37_79b9);
    for (p, nrm) in cloud.positions.iter_mut().zip(&mut cloud.normals) {
        for a in 0..3 {
            p[a] += sigma * gauss(&mut rng);
            nrm[a] += tilt * gauss(&mut rng);
        }
    }
    cloud
}

/// Mean distance of the mesh's vertices from the unit sphere.
fn radial_error(mesh: &Mesh) -> f64 {
    let sum: f64 = mesh
        .vertices
        .iter()
        .map(|v| ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs())
        .sum();
    sum / mesh.vertices.len() as f64
}

fn params(noise: Noise) -> Params {
    Params {
        depth: 8,
        noise,
        ..Params::default()
    }
}

#[test]
fn noisy_points_give_a_smoother_single_surface() {
    let sigma = 0.02;
    let cloud = noisy_sphere(40_000, sigma, 0.15, 7);
    let off = spsr::reconstruct(&cloud, &params(Noise::Off)).unwrap();
    let on = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    let topo = assert_closed_manifold(&on.mesh, "adaptive, noisy sphere");
    assert_eq!(topo.components, 1);
    let (e_off, e_on) = (radial_error(&off.mesh), radial_error(&on.mesh));
    assert!(e_on < 0.8 * e_off, "adaptive {e_on} against off {e_off}");
    // The measured noise (in the input's units) is the noise put in: the residual of a
    // quadratic height field fitted around each sample leaves the noise and nothing of the
    // sphere's curvature.
    let summary = on.stats.noise.expect("the noise stage ran");
    let measured = summary.median;
    assert!(
        (0.8 * sigma..1.2 * sigma).contains(&measured),
        "measured noise {measured}, put in {sigma}"
    );
    assert!(summary.adapted > 0.5, "{summary:?}");
    assert!(off.stats.noise.is_none());
}

#[test]
fn noise_too_thin_to_bend_the_sparse_finer_neighbourhoods_is_still_measured() {
    // Noise of 0.01 on 40,000 points of the unit sphere: the neighbourhoods one depth finer
    // than the planes hold too few samples to show it, and it read 0 before the thick rule;
    // it is about a third of the planes' cells (depth 6 or finer), so it counts.
    let sigma = 0.01;
    let cloud = noisy_sphere(40_000, sigma, 0.0, 11);
    let off = spsr::reconstruct(&cloud, &params(Noise::Off)).unwrap();
    let on = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    let summary = on.stats.noise.expect("the noise stage ran");
    let measured = summary.median;
    assert!(
        (0.8 * sigma..1.2 * sigma).contains(&measured),
        "measured noise {measured}, put in {sigma}: {summary:?}"
    );
    assert!(summary.adapted > 0.5, "{summary:?}");
    let (e_off, e_on) = (radial_error(&off.mesh), radial_error(&on.mesh));
    assert!(e_on < e_off, "adaptive {e_on} against off {e_off}");
}

/// Mean distance from the unit sphere of the mesh's vertices on each side of the plane
/// `y = 0`: (below, above).
fn radial_error_by_half(mesh: &Mesh) -> (f64, f64) {
    let mut sums = [(0.0, 0usize); 2];
    for v in &mesh.vertices {
        let e = ((v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() - 1.0).abs();
        let half = &mut sums[usize::from(v[1] > 0.0)];
        *half = (half.0 + e, half.1 + 1);
    }
    (sums[0].0 / sums[0].1 as f64, sums[1].0 / sums[1].1 as f64)
}

#[test]
fn a_noise_ramp_is_smoothed_where_it_is_noisy_and_nowhere_else() {
    // The unit sphere, clean below y = 0, with noise growing from 0 at y = 0 to 0.04 at the
    // top, as a range scanner's grows with the distance.
    let mut cloud = sphere(40_000, [0.0; 3], 1.0, 5);
    let mut rng = Rng(0x5eed);
    for p in &mut cloud.positions {
        let sigma = 0.04 * p[1].max(0.0);
        for c in p.iter_mut() {
            *c += sigma * gauss(&mut rng);
        }
    }
    let off = spsr::reconstruct(&cloud, &params(Noise::Off)).unwrap();
    let on = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    assert_eq!(assert_closed_manifold(&on.mesh, "noise ramp").components, 1);
    let (clean_off, noisy_off) = radial_error_by_half(&off.mesh);
    let (clean_on, noisy_on) = radial_error_by_half(&on.mesh);
    // The noisy half is smoothed: much closer to the sphere.
    assert!(
        noisy_on < 0.7 * noisy_off,
        "noisy half: {noisy_on} against {noisy_off}"
    );
    // The clean half keeps its detail: within a tenth of the unadapted mesh's error.
    assert!(
        clean_on < 1.1 * clean_off,
        "clean half: {clean_on} against {clean_off}"
    );
    // Raising the samples per node everywhere instead smooths the clean half too.
    let five = Params {
        samples_per_node: 5.0,
        ..params(Noise::Off)
    };
    let (clean_five, _) = radial_error_by_half(&spsr::reconstruct(&cloud, &five).unwrap().mesh);
    assert!(
        clean_on < clean_five,
        "clean half: {clean_on} against {clean_five} with S = 5"
    );
}

#[test]
fn clean_points_keep_their_detail() {
    let cloud = sphere(40_000, [0.0; 3], 1.0, 3);
    let off = spsr::reconstruct(&cloud, &params(Noise::Off)).unwrap();
    let on = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    let summary = on.stats.noise.expect("the noise stage ran");
    assert!(summary.adapted < 0.05, "{summary:?}");
    let (e_off, e_on) = (radial_error(&off.mesh), radial_error(&on.mesh));
    assert!(e_on <= 1.05 * e_off, "adaptive {e_on} against off {e_off}");
}

#[test]
fn noise_adaptation_is_invariant_under_translation_and_scaling() {
    let cloud = noisy_sphere(20_000, 0.02, 0.1, 11);
    let a = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    let mut moved = cloud.clone();
    for p in &mut moved.positions {
        *p = [p[0] * 250.0 + 1e3, p[1] * 250.0 - 7.0, p[2] * 250.0 + 3.5];
    }
    let b = spsr::reconstruct(&moved, &params(Noise::Adaptive)).unwrap();
    let (ta, tb) = (a.mesh.triangles.len() as f64, b.mesh.triangles.len() as f64);
    assert!((ta - tb).abs() <= 0.01 * ta, "{ta} against {tb} triangles");
    let sa = a.stats.noise.unwrap();
    let sb = b.stats.noise.unwrap();
    assert!(
        (sa.median_cells - sb.median_cells).abs() <= 1e-6 * sa.median_cells,
        "{sa:?} {sb:?}"
    );
    assert!(
        (250.0 * sa.median - sb.median).abs() <= 1e-6 * sb.median,
        "{sa:?} {sb:?}"
    );
    assert!((sa.adapted - sb.adapted).abs() <= 0.01, "{sa:?} {sb:?}");
}

/// Two tetrahedra, one 100 times smaller than the other, with a density and an attribute.
fn two_pieces() -> Mesh {
    let tet = |s: f64, o: f64| [[o, o, o], [o + s, o, o], [o, o + s, o], [o, o, o + s]];
    let mut vertices: Vec<[f64; 3]> = tet(1.0, 0.0).to_vec();
    vertices.extend(tet(0.01, 5.0));
    let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut triangles: Vec<[u32; 3]> = faces.to_vec();
    // The small piece's vertices come first in the triangle list's second half.
    triangles.extend(faces.iter().map(|t| t.map(|v| v + 4)));
    Mesh {
        vertices,
        triangles,
        density: Some((0..8).map(|i| i as f32).collect()),
        normals: None,
        attributes: vec![Attribute::new(
            "quality",
            AttributeData::from_f64(ScalarType::F32, (0..8).map(|i| 10.0 * i as f64)),
        )],
    }
}

#[test]
fn pieces_and_their_areas() {
    let mesh = two_pieces();
    let (piece_of, areas) = mesh.pieces();
    assert_eq!(piece_of, vec![0, 0, 0, 0, 1, 1, 1, 1]);
    assert!((areas[0] / areas[1] - 1e4).abs() < 1e-6);
    let keep: Vec<bool> = piece_of.iter().map(|&p| p == 1).collect();
    let small = mesh.keep_triangles(&keep);
    assert_eq!(small.vertices.len(), 4);
    assert_eq!(small.vertices[0], [5.0, 5.0, 5.0]);
    assert_eq!(small.density.as_deref(), Some(&[4.0, 5.0, 6.0, 7.0][..]));
    assert_eq!(small.attributes[0].data.get(3), Some(70.0));
    assert!(small.topology().closed);
}

/// A vertex at infinity must not make its piece's area NaN, or the largest piece could no
/// longer be told (the renderer's `--highlight pieces` picks it by area).
#[test]
fn a_non_finite_vertex_adds_no_area_to_its_piece() {
    let mut mesh = two_pieces();
    let finite = mesh.pieces().1;
    mesh.vertices.push([f64::INFINITY, 0.0, 0.0]);
    mesh.triangles.push([0, 1, 8]);
    let (piece_of, areas) = mesh.pieces();
    assert_eq!(piece_of[8], 0, "the triangle joins the large piece");
    assert_eq!(areas, finite);
}

#[test]
fn every_second_normal_flipped_still_gives_one_closed_surface() {
    let mut cloud = sphere(20_000, [0.0; 3], 1.0, 5);
    for n in cloud.normals.iter_mut().skip(1).step_by(2) {
        *n = n.map(|c| -c);
    }
    let out = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    let topo = assert_closed_manifold(&out.mesh, "every second normal flipped");
    assert_eq!(topo.components, 1);
    assert!(out.mesh.signed_volume() > 0.0, "the surface faces outward");
    let Some(spsr::Warning::NormalsReoriented {
        flipped, samples, ..
    }) = out
        .stats
        .warnings
        .iter()
        .find(|w| matches!(w, spsr::Warning::NormalsReoriented { .. }))
    else {
        panic!("{:?}", out.stats.warnings)
    };
    let share = *flipped as f64 / *samples as f64;
    assert!((share - 0.5).abs() < 0.05, "{flipped} of {samples}");
    // Kept as given, the surface falls apart.
    let kept = Params {
        keep_normals: true,
        ..params(Noise::Adaptive)
    };
    let out = spsr::reconstruct(&cloud, &kept).unwrap();
    assert!(!out.mesh.topology().closed || out.mesh.topology().components > 1);
    assert!(!out
        .stats
        .warnings
        .iter()
        .any(|w| matches!(w, spsr::Warning::NormalsReoriented { .. })));
}

#[test]
fn consistent_normals_are_left_alone() {
    let cloud = noisy_sphere(20_000, 0.02, 0.2, 9);
    let out = spsr::reconstruct(&cloud, &params(Noise::Adaptive)).unwrap();
    assert!(out.stats.warnings.is_empty(), "{:?}", out.stats.warnings);
}

/// Curvature and creases are not noise: a clean scan of a curved shape, reconstructed at a
/// depth whose cells hold several points, keeps the reference's splat depths nearly
/// everywhere. (The estimate once took the spread of offsets from a plane, and read the
/// curvature of clean 100,000-point bunny, fandisk and rocker arm scans at depths 8 and 9 as
/// noise, costing 3–8 % in accuracy.)
#[test]
fn clean_curved_shapes_read_no_noise_at_coarse_depths() {
    let bunny = crate::common::bunny();
    let torus = crate::common::torus(40_000, 1.0, 0.15, 5);
    // A sparse scan: every 13th point of the bunny, 1,539 points, whose shape the coarse
    // neighbourhoods do not resolve.
    let mut sparse = bunny.clone();
    let keep: Vec<usize> = (0..sparse.positions.len()).step_by(13).collect();
    sparse.positions = keep.iter().map(|&i| bunny.positions[i]).collect();
    sparse.normals = keep.iter().map(|&i| bunny.normals[i]).collect();
    sparse.attributes.clear();
    for (name, cloud) in [
        ("bunny", &bunny),
        ("torus", &torus),
        ("sparse bunny", &sparse),
    ] {
        for depth in [6, 7, 8] {
            let p = Params {
                depth,
                ..Params::default()
            };
            let on = spsr::reconstruct(cloud, &p).unwrap();
            let summary = on.stats.noise.expect("the noise stage ran");
            // Splat depths lowered by under 0.01 levels on average over all samples.
            let lowering = summary.adapted * summary.mean_lowering;
            assert!(
                summary.median_cells < 0.25 && lowering < 0.01,
                "{name} at depth {depth}: {summary:?}"
            );
        }
    }
}

/// Moves every point by Gaussian noise of `sigma` on each coordinate.
fn add_noise(cloud: &mut PointCloud, sigma: f64, seed: u64) {
    let mut rng = Rng(seed);
    for p in &mut cloud.positions {
        for c in p.iter_mut() {
            *c += sigma * gauss(&mut rng);
        }
    }
}

/// How far strong noise is smoothed depends on the shape under it: a sphere is still a
/// quadratic at twice the scale its noise is measured at, so its noise is smoothed past the
/// cap of 6 times the samples per node that protects thin parts and features. Under a cap of 8
/// alone, sampling the same noisy sphere more densely gave a worse surface (finer cells, and
/// no more smoothing allowed): a mean distance of 0.00171 from 200,000 points against 0.00140
/// from 100,000.
#[test]
fn a_denser_sampling_of_a_noisy_smooth_shape_is_not_worse() {
    let sparse = noisy_sphere(100_000, 0.02, 0.2, 13);
    let dense = noisy_sphere(200_000, 0.02, 0.2, 14);
    let on = |cloud: &PointCloud| spsr::reconstruct(cloud, &params(Noise::Adaptive)).unwrap();
    let (sparse_on, dense_on) = (on(&sparse), on(&dense));
    let topo = assert_closed_manifold(&dense_on.mesh, "noisy sphere");
    assert_eq!((topo.components, topo.euler), (1, 2));
    let (e_sparse, e_dense) = (radial_error(&sparse_on.mesh), radial_error(&dense_on.mesh));
    assert!(
        e_dense < e_sparse,
        "200,000 points: {e_dense}; 100,000: {e_sparse}"
    );
    // Far nearer the sphere than 12 samples per node everywhere, more smoothing than the cap
    // of 6 gives anywhere (9).
    let twelve = Params {
        samples_per_node: 12.0,
        ..params(Noise::Off)
    };
    let e_12 = radial_error(&spsr::reconstruct(&dense, &twelve).unwrap().mesh);
    assert!(e_dense < 0.6 * e_12, "{e_dense} against {e_12} with S = 12");
}

/// A thin tube under strong noise (the noise a quarter of the tube's radius) is smoothed but
/// kept: one closed piece of genus 1.
#[test]
fn a_noisy_thin_tube_keeps_its_topology() {
    let mut torus = crate::common::torus(40_000, 1.0, 0.12, 3);
    add_noise(&mut torus, 0.03, 17);
    let on = spsr::reconstruct(&torus, &params(Noise::Adaptive)).unwrap();
    let topo = assert_closed_manifold(&on.mesh, "noisy thin torus");
    assert_eq!((topo.components, topo.euler), (1, 0));
}

/// The cap of 6 times the samples per node that protects thin parts and features grows with
/// the density (`pipeline::noise`, *Denser clouds*): a denser cloud's finest cells are smaller,
/// so the same noise needs a larger factor to be averaged over as wide a patch, while its
/// extra samples average the noise down further. Under the fixed cap, four times the samples
/// of the same noisy thin torus landed only 7 % nearer the truth (0.00164 against 0.00176),
/// because its splats shrank with its density; with the growing cap 40 % nearer. Since the
/// screening depth (`pipeline::noise`, *Screening depth*), which brought the sparser cloud
/// 19 % nearer (0.00142) and the denser one hardly (0.00107), 25 % nearer.
#[test]
fn a_denser_sampling_of_a_noisy_thin_tube_is_smoothed_as_its_density_allows() {
    let (big, small) = (1.0, 0.25);
    let noisy = |n: usize, seed: u64| {
        let mut cloud = crate::common::torus(n, big, small, seed);
        add_noise(&mut cloud, 0.02, seed + 1);
        cloud
    };
    let depth9 = Params {
        depth: 9,
        ..params(Noise::Adaptive)
    };
    let error = |cloud: &PointCloud| {
        let out = spsr::reconstruct(cloud, &depth9).unwrap();
        let topo = assert_closed_manifold(&out.mesh, "noisy torus");
        assert_eq!((topo.components, topo.euler), (1, 0));
        let e = crate::common::torus_errors(&out.mesh, big, small);
        e.iter().map(|e| e.abs()).sum::<f64>() / e.len() as f64
    };
    let (sparse, dense) = (error(&noisy(100_000, 5)), error(&noisy(400_000, 6)));
    assert!(
        dense < 0.8 * sparse,
        "400,000 points: {dense}; 100,000: {sparse}"
    );
}
