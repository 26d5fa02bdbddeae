//! Degenerate and hostile inputs (issue 7): each gets a sensible result or a clear error,
//! never a panic or non-finite output.

use crate::common::{assert_closed_manifold, at_depth, harness, sphere};
use spsr::{reconstruct, Error, PointCloud, Warning};

fn assert_finite(mesh: &spsr::Mesh) {
    assert!(mesh.vertices.iter().flatten().all(|c| c.is_finite()));
}

fn bbox(mesh: &spsr::Mesh) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for v in &mesh.vertices {
        for a in 0..3 {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    (lo, hi)
}

#[test]
fn points_on_a_plane_give_a_finite_manifold_surface_through_them() {
    let mut pos = Vec::new();
    for i in 0..40 {
        for j in 0..40 {
            pos.push([f64::from(i) / 39.0, f64::from(j) / 39.0, 0.25]);
        }
    }
    let n = pos.len();
    let cloud = PointCloud::new(pos, vec![[0.0, 0.0, 1.0]; n]).unwrap();
    let out = reconstruct(&cloud, &at_depth(6)).unwrap();
    assert!(!out.mesh.triangles.is_empty());
    assert_finite(&out.mesh);
    assert!(out.mesh.topology().edge_manifold);
    // The surface passes through the plane of the points.
    let near = out
        .mesh
        .vertices
        .iter()
        .filter(|v| (v[0] - 0.5).abs() < 0.3 && (v[1] - 0.5).abs() < 0.3)
        .map(|v| (v[2] - 0.25).abs())
        .fold(f64::INFINITY, f64::min);
    assert!(near < 0.05, "closest vertex {near} from the plane");
}

#[test]
fn points_on_a_line_give_a_finite_result_or_a_clear_error() {
    // Normals all one way (a line seen from one side) and alternating (cancelling).
    for alternate in [false, true] {
        let cloud = PointCloud::new(
            (0..200).map(|i| [f64::from(i) * 0.01, 0.0, 0.0]).collect(),
            (0..200)
                .map(|i| {
                    if alternate && i % 2 == 1 {
                        [0.0, -1.0, 0.0]
                    } else {
                        [0.0, 1.0, 0.0]
                    }
                })
                .collect(),
        )
        .unwrap();
        match reconstruct(&cloud, &at_depth(6)) {
            Ok(out) => {
                assert_finite(&out.mesh);
                assert!(out.mesh.topology().edge_manifold);
            }
            Err(e) => assert!(matches!(e, Error::Degenerate(_)), "{e}"),
        }
    }
}

#[test]
fn two_points_are_too_few() {
    let cloud = PointCloud::new(vec![[0.0; 3], [1.0; 3]], vec![[1.0, 0.0, 0.0]; 2]).unwrap();
    let e = reconstruct(&cloud, &at_depth(8)).unwrap_err();
    assert!(matches!(e, Error::TooFewPoints { usable: 2, .. }), "{e}");
    assert!(e.to_string().contains("at least 4"), "{e}");
}

#[test]
fn a_million_duplicates_of_one_point_are_identical_points() {
    let n = 1_000_000;
    let cloud = PointCloud::new(vec![[0.5, -2.0, 7.0]; n], vec![[0.0, 0.0, 1.0]; n]).unwrap();
    let e = reconstruct(&cloud, &at_depth(10)).unwrap_err();
    assert!(matches!(e, Error::Degenerate(_)), "{e}");
    assert!(e.to_string().contains("identical"), "{e}");
}

#[test]
fn a_million_duplicates_beside_a_sphere_reconstruct_the_sphere() {
    let mut cloud = sphere(2000, [0.0; 3], 1.0, 21);
    let n = 1_000_000;
    cloud
        .positions
        .extend(std::iter::repeat_n([0.0, 0.0, 1.0], n));
    cloud
        .normals
        .extend(std::iter::repeat_n([0.0, 0.0, 1.0], n));
    let out = reconstruct(&cloud, &at_depth(6)).unwrap();
    assert_closed_manifold(&out.mesh, "sphere with duplicates");
    // Merged into one sample: the sphere keeps its size.
    let (lo, hi) = bbox(&out.mesh);
    for a in 0..3 {
        assert!((hi[a] - lo[a] - 2.0).abs() < 0.15, "{lo:?} {hi:?}");
    }
}

#[test]
fn huge_and_tiny_coordinates_scale_with_the_input() {
    let unit = reconstruct(&sphere(1000, [0.0; 3], 1.0, 5), &at_depth(5)).unwrap();
    let (ulo, uhi) = bbox(&unit.mesh);
    for (scale, offset) in [(1e30, 0.0), (1e-30, 0.0), (1e300, 0.0), (1e-300, 0.0)] {
        let mut cloud = sphere(1000, [0.0; 3], 1.0, 5);
        for p in &mut cloud.positions {
            for c in p.iter_mut() {
                *c = *c * scale + offset;
            }
        }
        let out = reconstruct(&cloud, &at_depth(5)).unwrap();
        assert_finite(&out.mesh);
        assert_eq!(out.mesh.vertices.len(), unit.mesh.vertices.len(), "{scale}");
        let (lo, hi) = bbox(&out.mesh);
        for a in 0..3 {
            assert!((lo[a] / scale - ulo[a]).abs() < 1e-6, "{scale}");
            assert!((hi[a] / scale - uhi[a]).abs() < 1e-6, "{scale}");
        }
    }
}

#[test]
fn a_small_object_far_from_the_origin_is_a_clear_error_or_a_mesh() {
    // Radius 1 at 1e30: f64 cannot tell the points apart, they are all identical.
    let mut cloud = sphere(500, [0.0; 3], 1.0, 5);
    for p in &mut cloud.positions {
        p[0] += 1e30;
        p[1] += 1e30;
        p[2] += 1e30;
    }
    let e = reconstruct(&cloud, &at_depth(6)).unwrap_err();
    assert!(matches!(e, Error::Degenerate(_)), "{e}");
    // Coordinates whose spread overflows f64.
    let cloud = PointCloud::new(
        vec![
            [-1.7e308, 0.0, 0.0],
            [1.7e308, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        vec![[1.0, 0.0, 0.0]; 4],
    )
    .unwrap();
    let e = reconstruct(&cloud, &at_depth(6)).unwrap_err();
    assert!(e.to_string().contains("not finite"), "{e}");
}

#[test]
fn normal_lengths_do_not_matter_without_confidence() {
    let unit = sphere(1500, [0.0; 3], 1.0, 9);
    let mut wild = unit.clone();
    let scales = [1e-300, 1e-150, 1e-20, 1.0, 1e20, 1e150, 1e300];
    for (i, n) in wild.normals.iter_mut().enumerate() {
        let s = scales[i % scales.len()];
        for c in n.iter_mut() {
            *c *= s;
        }
    }
    let a = reconstruct(&unit, &at_depth(5)).unwrap();
    let b = reconstruct(&wild, &at_depth(5)).unwrap();
    assert_eq!(b.stats.dropped, 0);
    assert_eq!(a.mesh.vertices.len(), b.mesh.vertices.len());
    let max = a
        .mesh
        .vertices
        .iter()
        .zip(&b.mesh.vertices)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max);
    assert!(max < 1e-9, "vertices moved by {max}");
}

#[test]
fn one_outlier_a_million_units_away_is_left_out_by_default() {
    let clean = sphere(500, [0.0; 3], 1.0, 3);
    let mut cloud = clean.clone();
    cloud.positions.push([1.0e6, 0.0, 0.0]);
    cloud.normals.push([1.0, 0.0, 0.0]);
    let out = reconstruct(&cloud, &at_depth(8)).unwrap();
    let without = reconstruct(&clean, &at_depth(8)).unwrap();
    assert_eq!(out.mesh.vertices, without.mesh.vertices);
    assert_eq!(out.mesh.triangles, without.mesh.triangles);
    let topo = out.mesh.topology();
    assert!(topo.closed && topo.components == 1, "{topo:?}");
    assert_eq!(out.stats.warnings.len(), 1, "{:?}", out.stats.warnings);
    let Warning::OutliersDropped(o) = &out.stats.warnings[0] else {
        panic!("{:?}", out.stats.warnings)
    };
    assert_eq!((o.far, o.total), (1, 501));
    let text = out.stats.warnings[0].to_string();
    assert!(
        text.starts_with("left out 1 far outlier(s) of 501 points, kept the 500"),
        "{text}"
    );
    assert_eq!(out.stats.dropped, 1);
}

#[test]
fn one_outlier_a_million_units_away_is_reported_with_the_fix_when_kept() {
    let mut cloud = sphere(500, [0.0; 3], 1.0, 3);
    cloud.positions.push([1.0e6, 0.0, 0.0]);
    cloud.normals.push([1.0, 0.0, 0.0]);
    let keep = |depth| spsr::Params {
        keep_outliers: true,
        ..at_depth(depth)
    };
    let out = reconstruct(&cloud, &keep(8)).unwrap();
    assert_finite(&out.mesh);
    assert_eq!(out.stats.warnings.len(), 1, "{:?}", out.stats.warnings);
    let Warning::FarOutliers(o) = &out.stats.warnings[0] else {
        panic!("{:?}", out.stats.warnings)
    };
    assert_eq!((o.far, o.total, o.depth, o.effective_depth), (1, 501, 8, 0));
    // Depth 8 + 18 is beyond the deepest depth: only cropping is suggested.
    assert_eq!(o.compensating_depth, None);
    let text = out.stats.warnings[0].to_string();
    for needle in [
        "1 of 501 points (0.200 %)",
        "lie far outside the box (",
        "depth 8 resolves the surface like depth 0",
        "crop the input to that box",
    ] {
        assert!(text.contains(needle), "'{needle}' not in: {text}");
    }
    assert!(!text.contains("raise the depth"), "{text}");
    // A nearer outlier costs fewer depths, and a deeper run is a fix too.
    cloud.positions.last_mut().unwrap()[0] = 100.0;
    let out = reconstruct(&cloud, &keep(8)).unwrap();
    let Warning::FarOutliers(o) = &out.stats.warnings[0] else {
        panic!("{:?}", out.stats.warnings)
    };
    assert_eq!((o.effective_depth, o.compensating_depth), (3, Some(13)));
    let text = out.stats.warnings[0].to_string();
    assert!(text.contains("or raise the depth to 13"), "{text}");
}

#[test]
fn depths_up_to_the_maximum_work_on_a_small_cloud() {
    let cloud = sphere(300, [0.0; 3], 1.0, 17);
    for depth in [16, spsr::MAX_DEPTH] {
        let p = at_depth(depth);
        let out = reconstruct(&cloud, &p).unwrap();
        assert_finite(&out.mesh);
        assert!(out.mesh.topology().edge_manifold);
        // 300 points are too few for the cube's margin: the surface may reach its faces.
        assert_eq!(harness::open_edges_inside_cube(&out.mesh, &cloud, &p), 0);
    }
    let e = reconstruct(&cloud, &at_depth(spsr::MAX_DEPTH + 1)).unwrap_err();
    assert!(
        matches!(&e, Error::InvalidParameter { field: "depth", value, .. } if value == "19"),
        "{e}"
    );
}
