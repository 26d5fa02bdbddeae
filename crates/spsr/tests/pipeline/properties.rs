//! Property tests (issue 7): random small clouds on random spheres, boxes and tori, with
//! noise, duplicates and outliers, at random small depths. `reconstruct` must return a mesh
//! with finite vertices that is an edge-manifold, closed except where the bounding cube cuts
//! it (extraction stops at the cube, as PoissonRecon's does), or a clear error; never panic.
//! Few cases and small depths keep this to seconds.

use proptest::prelude::*;
use spsr::{Boundary, Error, Params, PointCloud};

use crate::common::{harness, Rng};

#[derive(Debug, Clone)]
struct Case {
    shape: u8,
    seed: u64,
    points: usize,
    size: f64,
    center: [f64; 3],
    noise: f64,
    duplicates: usize,
    outliers: usize,
    depth: u32,
    degree: u8,
    boundary: u8,
}

fn cases() -> impl Strategy<Value = Case> {
    (
        (0u8..3, 1u64..u64::MAX, 8usize..300, -3.0f64..3.0),
        (prop::array::uniform3(-1e3f64..1e3), 0.0f64..0.1),
        (0usize..50, 0usize..3, 2u32..6, 1u8..3, 0u8..3),
    )
        .prop_map(
            |(
                (shape, seed, points, log_size),
                (center, noise),
                (duplicates, outliers, depth, degree, boundary),
            )| Case {
                shape,
                seed,
                points,
                size: 10f64.powf(log_size),
                center,
                noise,
                duplicates,
                outliers,
                depth,
                degree,
                boundary,
            },
        )
}

fn cloud(c: &Case) -> PointCloud {
    let mut rng = Rng(c.seed | 1);
    let mut pos = Vec::new();
    let mut nor = Vec::new();
    for _ in 0..c.points {
        let (p, n) = match c.shape {
            0 => {
                let u = rng.unit();
                (u, u)
            }
            1 => {
                // A box 2 × 1 × 0.5: a face by area, a point on it.
                let half = [1.0, 0.5, 0.25];
                let a = (rng.next() * 3.0) as usize;
                let s = if rng.next() < 0.5 { -1.0 } else { 1.0 };
                let mut p = [0.0; 3];
                for k in 0..3 {
                    p[k] = (2.0 * rng.next() - 1.0) * half[k];
                }
                p[a] = s * half[a];
                let mut n = [0.0; 3];
                n[a] = s;
                (p, n)
            }
            _ => {
                let (big, small) = (1.0, 0.3);
                let u = 2.0 * std::f64::consts::PI * rng.next();
                let v = 2.0 * std::f64::consts::PI * rng.next();
                let n = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
                let ring = big + small * v.cos();
                ([ring * u.cos(), ring * u.sin(), small * v.sin()], n)
            }
        };
        let jitter = rng.unit();
        let q: [f64; 3] = std::array::from_fn(|k| {
            c.center[k] + c.size * (p[k] + c.noise * rng.next() * jitter[k])
        });
        pos.push(q);
        nor.push(n);
    }
    for i in 0..c.duplicates.min(pos.len()) {
        pos.push(pos[i % 3]);
        nor.push(nor[i % 3]);
    }
    for _ in 0..c.outliers {
        let d = rng.unit();
        let far = 10f64.powf(1.0 + 5.0 * rng.next());
        pos.push(std::array::from_fn(|k| c.center[k] + c.size * far * d[k]));
        nor.push(rng.unit());
    }
    PointCloud::new(pos, nor).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 24,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn reconstruct_gives_a_closed_manifold_or_a_clear_error(c in cases()) {
        let cloud = cloud(&c);
        let params = Params {
            depth: c.depth,
            full_depth: c.depth.min(5),
            degree: spsr::Degree::from_number(c.degree).unwrap(),
            boundary: [Boundary::Neumann, Boundary::Dirichlet, Boundary::Free][c.boundary as usize],
            density: true,
            // The harness finds open edges against the cube of all the points.
            keep_outliers: true,
            ..Params::default()
        };
        match spsr::reconstruct(&cloud, &params) {
            Ok(out) => {
                let m = &out.mesh;
                harness::check_mesh(m);
                prop_assert!(m.vertices.iter().flatten().all(|v| v.is_finite()), "NaN vertex");
                prop_assert!(m.density.as_ref().unwrap().iter().all(|v| v.is_finite()));
                let t = m.topology();
                prop_assert!(t.edge_manifold, "{t:?}");
                let open = harness::open_edges_inside_cube(m, &cloud, &params);
                prop_assert_eq!(open, 0, "open edges inside the cube: {:?}", t);
            }
            Err(e) => {
                let clear = matches!(e, Error::TooFewPoints { .. } | Error::Degenerate(_));
                prop_assert!(clear, "unexpected error: {}", e);
            }
        }
    }
}
