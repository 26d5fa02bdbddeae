//! The depth from a cell width or from the points' spacing (issue 18, `Params::resolution`).

use spsr::{DepthLimit, DepthReason, Error, Params, Resolution};

use crate::common::sphere;

/// The largest side of the points' bounding box.
fn box_side(cloud: &spsr::PointCloud) -> f64 {
    (0..3)
        .map(|a| {
            let c = cloud.positions.iter().map(|p| p[a]);
            c.clone().fold(f64::MIN, f64::max) - c.fold(f64::MAX, f64::min)
        })
        .fold(0.0, f64::max)
}

#[test]
fn a_width_lands_on_the_depth_it_implies_with_cells_exactly_that_wide() {
    let cloud = sphere(4000, [0.5, -1.0, 2.0], 1.0, 7);
    let cube = 1.1 * box_side(&cloud);
    for (cells, depth) in [(20.0, 5), (40.0, 6), (63.9, 6), (64.1, 7)] {
        let width = cube / cells;
        let params = Params {
            resolution: Resolution::Width(width),
            ..Params::default()
        };
        let r = spsr::resolve(&cloud, &params).unwrap();
        let choice = r.choice.expect("a width is a choice");
        assert_eq!(choice.depth, depth, "{cells} cells");
        assert_eq!(r.params.depth, depth);
        assert_eq!(r.params.resolution, Resolution::Depth);
        assert!(r.params.full_depth <= depth);
        assert_eq!(choice.reason, DepthReason::Width { width });
        // The cube is widened so that 2^depth cells of the width span it exactly.
        let widened = r.params.scale * box_side(&cloud);
        let exact = width * f64::from(1u32 << depth);
        assert!((widened / exact - 1.0).abs() < 1e-12, "{widened} {exact}");
        assert!(widened >= cube * (1.0 - 1e-12) && widened < 2.0 * cube);
    }
    // The run itself: its octree reaches that depth, and it reports the choice.
    let params = Params {
        resolution: Resolution::Width(cube / 40.0),
        ..Params::default()
    };
    let out = spsr::reconstruct(&cloud, &params).unwrap();
    assert_eq!(out.stats.nodes_per_depth.len(), 7);
    assert_eq!(out.stats.depth_choice.map(|c| c.depth), Some(6));
}

#[test]
fn a_width_finer_than_the_deepest_depth_allows_is_refused_by_name() {
    let cloud = sphere(500, [0.0; 3], 1.0, 1);
    for width in [1e-9, 0.0, -1.0, f64::NAN] {
        let params = Params {
            resolution: Resolution::Width(width),
            ..Params::default()
        };
        match spsr::resolve(&cloud, &params) {
            Err(Error::InvalidParameter { field, .. }) => assert_eq!(field, "width"),
            other => panic!("width {width}: {other:?}"),
        }
    }
}

#[test]
fn depth_auto_goes_deeper_for_a_denser_sampling_of_the_same_shape() {
    let auto = Params {
        resolution: Resolution::Auto,
        max_memory: Some(1 << 40),
        ..Params::default()
    };
    // A thin torus: curved enough everywhere (a tube of radius 0.15) that the spacing, not
    // the curvature, sets the depth.
    let depth_of = |n: usize| {
        let r = spsr::resolve(&crate::common::torus(n, 1.0, 0.15, 3), &auto).unwrap();
        let c = r.choice.unwrap();
        let DepthReason::Spacing {
            spacing,
            clean,
            smooth,
            limited,
            ..
        } = c.reason
        else {
            panic!("{:?}", c.reason)
        };
        assert_eq!((clean, smooth, limited), (true, None, None));
        // The finest cells' face diagonals are no longer than the spacing, and one depth
        // coarser they would be.
        let diagonal = c.cell * std::f64::consts::SQRT_2;
        assert!(diagonal <= spacing && 2.0 * diagonal > spacing, "{c:?}");
        (c.depth, spacing)
    };
    let (sparse, s1) = depth_of(2_000);
    let (dense, s2) = depth_of(32_000);
    // 16 times the points on the same surface: a quarter of the spacing, two depths deeper.
    assert!((s1 / s2 - 4.0).abs() < 1.0, "spacings {s1} {s2}");
    assert!(dense > sparse, "{sparse} {dense}");
    assert!((dense - sparse).abs_diff(2) <= 1, "{sparse} {dense}");
}

/// The torus of `depth_auto_goes_deeper_for_a_denser_sampling_of_the_same_shape`, each point
/// moved along its normal by a uniform offset in [−a, a] (a standard deviation of a / √3).
fn noisy_torus(n: usize, a: f64) -> spsr::PointCloud {
    let clean = crate::common::torus(n, 1.0, 0.15, 3);
    let mut rng = crate::common::Rng(11);
    let pos = (clean.positions.iter().zip(&clean.normals))
        .map(|(p, n)| {
            let t = a * (2.0 * rng.next() - 1.0);
            std::array::from_fn(|k| p[k] + t * n[k])
        })
        .collect();
    spsr::PointCloud::new(pos, clean.normals.clone()).unwrap()
}

#[test]
fn depth_auto_gives_a_clean_cloud_finer_cells_than_a_noisy_one() {
    let auto = Params {
        resolution: Resolution::Auto,
        max_memory: Some(1 << 40),
        ..Params::default()
    };
    let read = |cloud: &spsr::PointCloud| {
        let c = spsr::resolve(cloud, &auto).unwrap().choice.unwrap();
        let DepthReason::Spacing {
            spacing,
            noise,
            clean,
            ..
        } = c.reason
        else {
            panic!("{:?}", c.reason)
        };
        (c, spacing, noise.expect("the noise is measured"), clean)
    };
    let (c, spacing, noise, clean) = read(&noisy_torus(32_000, 0.0));
    assert!(clean && noise < 0.05 * spacing, "{noise} {spacing}");
    let diagonal = c.cell * std::f64::consts::SQRT_2;
    assert!(diagonal <= spacing && 2.0 * diagonal > spacing, "{c:?}");
    let clean_depth = c.depth;
    // Noise as large as the spacing (about 0.01): read within a factor of 1.5, and the cells
    // are as wide as the spacing, not as their diagonals.
    let sigma = 0.02 / 3f64.sqrt();
    let (c, spacing, noise, clean) = read(&noisy_torus(32_000, 0.02));
    assert!(!clean, "{c:?}");
    assert!(
        (sigma / 1.5..sigma * 1.5).contains(&noise),
        "{noise} {sigma}"
    );
    assert!(c.cell <= spacing && 2.0 * c.cell > spacing, "{c:?}");
    assert!(c.depth < clean_depth, "{} {clean_depth}", c.depth);
    let note = c.message(&|f| format!("--{f}"));
    assert!(note.contains("follow the noise"), "{note}");
}

/// `side²` points on a grid over [−1, 1]², lifted to a bowl of radius of curvature 4 at
/// its centre, `z = (x² + y²) / 8`, plus ripples of amplitude `ripple` and wavelength π/10.
fn bowl(side: usize, ripple: f64) -> spsr::PointCloud {
    let mut pos = Vec::new();
    let mut nor = Vec::new();
    for i in 0..side * side {
        let x = -1.0 + 2.0 * (i % side) as f64 / (side - 1) as f64;
        let y = -1.0 + 2.0 * (i / side) as f64 / (side - 1) as f64;
        let (sx, sy) = ((20.0 * x).sin(), (20.0 * y).sin());
        let z = (x * x + y * y) / 8.0 + ripple * sx * sy;
        let zx = x / 4.0 + 20.0 * ripple * (20.0 * x).cos() * sy;
        let zy = y / 4.0 + 20.0 * ripple * sx * (20.0 * y).cos();
        let l = (zx * zx + zy * zy + 1.0).sqrt();
        pos.push([x, y, z]);
        nor.push([-zx / l, -zy / l, 1.0 / l]);
    }
    spsr::PointCloud::new(pos, nor).unwrap()
}

#[test]
fn depth_auto_takes_fewer_depths_on_a_smooth_surface_than_on_a_rough_one_sampled_alike() {
    let auto = Params {
        resolution: Resolution::Auto,
        max_memory: Some(1 << 40),
        ..Params::default()
    };
    let choose = |cloud: &spsr::PointCloud| {
        let c = spsr::resolve(cloud, &auto).unwrap().choice.unwrap();
        let DepthReason::Spacing {
            wanted,
            smooth,
            limited,
            ..
        } = c.reason
        else {
            panic!("{:?}", c.reason)
        };
        assert_eq!(limited, None);
        (c.clone(), wanted, smooth)
    };
    // 250 × 250 points 0.008 apart in a cube of 2.2: the spacing asks for depth 9.
    let (smooth, wanted, bound) = choose(&bowl(250, 0.0));
    assert_eq!(wanted, 9);
    // The bowl's radius of curvature, 4 at the centre and more outside, is read as such; cells
    // of a 32nd of it would be depth 5, and the depth goes at most two below the spacing's.
    let (radius, depth) = bound.expect("the bowl is smooth");
    assert!((3.6..4.4).contains(&radius), "{radius}");
    assert_eq!((smooth.depth, depth), (7, 7));
    let note = smooth.message(&|f| format!("--{f}"));
    assert!(
        note.contains("smooth") && note.contains("--depth 7"),
        "{note}"
    );
    // Ripples of curvature ~4 (a radius of a quarter) need every depth the spacing gives.
    let (rough, wanted, bound) = choose(&bowl(250, 0.01));
    assert_eq!((rough.depth, wanted, bound), (9, 9, None));
}

#[test]
fn depth_auto_stays_within_the_memory_limit_and_says_so() {
    let cloud = sphere(32_000, [0.0; 3], 1.0, 3);
    let free = Params {
        resolution: Resolution::Auto,
        max_memory: Some(1 << 40),
        ..Params::default()
    };
    let wanted = spsr::resolve(&cloud, &free).unwrap().params.depth;
    let tight = Params {
        max_memory: Some(90 << 20),
        ..free
    };
    let r = spsr::resolve(&cloud, &tight).unwrap();
    let c = r.choice.unwrap();
    assert!(c.depth < wanted, "{} {wanted}", c.depth);
    let DepthReason::Spacing { limited, .. } = c.reason else {
        panic!()
    };
    assert!(
        matches!(limited, Some(DepthLimit::Memory { .. })),
        "{limited:?}"
    );
    let note = c.message(&|f| f.to_string());
    assert!(
        note.contains("max_memory") && note.contains(&format!("depth {wanted}")),
        "{note}"
    );
    // The run at the chosen depth fits the same limit.
    spsr::reconstruct(&cloud, &r.params).unwrap();
}

#[test]
fn a_given_depth_is_left_alone_and_slabs_take_only_a_given_depth() {
    let cloud = sphere(500, [0.0; 3], 1.0, 1);
    let r = spsr::resolve(&cloud, &Params::default()).unwrap();
    assert_eq!(r.params, Params::default());
    assert!(r.choice.is_none());
    let dir = tempfile::tempdir().unwrap();
    let auto = Params {
        resolution: Resolution::Auto,
        ..Params::default()
    };
    let e = spsr::slabs::reconstruct(
        spsr::slabs::Source::Cloud(&cloud),
        &auto,
        &spsr::slabs::SlabOptions {
            slabs: 2,
            work_dir: dir.path().to_path_buf(),
        },
        &|_| {},
    )
    .unwrap_err();
    assert!(
        matches!(e, Error::InvalidParameter { field: "depth", .. }),
        "{e}"
    );
}
