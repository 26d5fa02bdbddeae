//! Attributes carried onto the mesh, normals from the implicit function, and per-point
//! confidence from a named property.

use crate::common::*;
use spsr::attributes::{Attribute, AttributeData};
use spsr::{reconstruct, Error, Params, PointCloud, PointWeights};

/// A sphere painted red (255, 0, 0) where x > 0 and blue (0, 0, 255) elsewhere, with a float
/// `temperature` equal to the z coordinate.
fn painted_sphere(n: usize) -> PointCloud {
    let mut cloud = sphere(n, [0.0; 3], 1.0, 11);
    let red: Vec<u8> = cloud
        .positions
        .iter()
        .map(|p| if p[0] > 0.0 { 255 } else { 0 })
        .collect();
    let blue: Vec<u8> = red.iter().map(|&r| 255 - r).collect();
    let green = vec![0u8; red.len()];
    let temperature: Vec<f32> = cloud.positions.iter().map(|p| p[2] as f32).collect();
    cloud.attributes = vec![
        Attribute::new("red", AttributeData::U8(red)),
        Attribute::new("green", AttributeData::U8(green)),
        Attribute::new("blue", AttributeData::U8(blue)),
        Attribute::new("temperature", AttributeData::F32(temperature)),
    ];
    cloud
}

fn column<'a>(mesh: &'a spsr::Mesh, name: &str) -> &'a AttributeData {
    &mesh
        .attributes
        .iter()
        .find(|a| a.name == name)
        .unwrap_or_else(|| panic!("mesh has no attribute {name}"))
        .data
}

#[test]
fn two_colours_stay_on_their_halves_with_a_sharp_edge() {
    let cloud = painted_sphere(100_000);
    let depth = 7;
    let out = reconstruct(&cloud, &at_depth(depth)).unwrap();
    let mesh = &out.mesh;
    let (red, blue) = (column(mesh, "red"), column(mesh, "blue"));
    assert!(matches!(red, AttributeData::U8(_)), "types are kept");
    assert_eq!(red.len(), mesh.vertices.len());
    let cell = 2.2 / f64::from(1u32 << depth);
    let mut far = 0usize;
    for (i, v) in mesh.vertices.iter().enumerate() {
        let (r, b) = (red.get(i).unwrap(), blue.get(i).unwrap());
        // Away from the boundary the colour is pure; the change happens within two cells.
        if v[0] > 2.0 * cell {
            far += 1;
            assert!(r >= 250.0 && b <= 5.0, "vertex {v:?}: red {r} blue {b}");
        } else if v[0] < -2.0 * cell {
            far += 1;
            assert!(b >= 250.0 && r <= 5.0, "vertex {v:?}: red {r} blue {b}");
        }
        assert!((r + b - 255.0).abs() <= 2.0, "red + blue = {}", r + b);
    }
    assert!(far > mesh.vertices.len() * 9 / 10);
    // A smooth float attribute is interpolated to within a few cells of the truth (the
    // finest cells holding samples around a vertex decide: a piecewise-constant
    // interpolant, as PoissonRecon's), and much better on average.
    let t = column(mesh, "temperature");
    assert!(matches!(t, AttributeData::F32(_)));
    let mut sum = 0.0;
    for (i, v) in mesh.vertices.iter().enumerate() {
        let err = (t.get(i).unwrap() - v[2]).abs();
        assert!(err < 3.0 * cell, "temperature at {v:?} off by {err}");
        sum += err;
    }
    let mean = sum / mesh.vertices.len() as f64;
    eprintln!("temperature: mean error {} cells", mean / cell);
    assert!(mean < 0.5 * cell, "mean temperature error {mean}");
}

#[test]
fn attributes_can_be_left_behind() {
    let cloud = painted_sphere(20_000);
    let out = reconstruct(
        &cloud,
        &Params {
            depth: 5,
            attributes: false,
            ..Params::default()
        },
    )
    .unwrap();
    assert!(out.mesh.attributes.is_empty());
}

#[test]
fn normals_follow_the_gradient_and_point_outward() {
    let c = [0.3, -0.1, 0.2];
    let cloud = sphere(50_000, c, 1.0, 3);
    let out = reconstruct(
        &cloud,
        &Params {
            depth: 6,
            normals: true,
            ..Params::default()
        },
    )
    .unwrap();
    let normals = out.mesh.normals.as_ref().expect("normals requested");
    assert_eq!(normals.len(), out.mesh.vertices.len());
    let mut worst: f64 = 1.0;
    for (v, n) in out.mesh.vertices.iter().zip(normals) {
        let r = [v[0] - c[0], v[1] - c[1], v[2] - c[2]];
        let len = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
        let nl = n
            .iter()
            .map(|&x| f64::from(x) * f64::from(x))
            .sum::<f64>()
            .sqrt();
        assert!((nl - 1.0).abs() < 1e-5, "unit length");
        let dot = (0..3).map(|a| f64::from(n[a]) * r[a] / len).sum::<f64>();
        worst = worst.min(dot);
    }
    // Within about 8 degrees of the radial direction everywhere.
    assert!(worst > 0.99, "worst cosine {worst}");
}

#[test]
fn a_confidence_property_weights_the_points() {
    // Two concentric spheres: the inner one with confidence 1, the outer one (radius 1.05)
    // with a tiny confidence. Sampled at the same density, the weighted iso-surface follows
    // the confident sphere.
    let inner = sphere(30_000, [0.0; 3], 1.0, 5);
    let outer = sphere(30_000, [0.0; 3], 1.05, 6);
    let mut cloud = PointCloud::new(
        [inner.positions.clone(), outer.positions.clone()].concat(),
        [inner.normals.clone(), outer.normals.clone()].concat(),
    )
    .unwrap();
    let conf: Vec<f32> = (0..cloud.len())
        .map(|i| if i < inner.len() { 1.0 } else { 1e-3 })
        .collect();
    cloud.attributes = vec![Attribute::new("confidence", AttributeData::F32(conf))];
    let params = Params {
        depth: 6,
        weights: PointWeights::Property("confidence".into()),
        attributes: false,
        ..Params::default()
    };
    let mean_radius = |mesh: &spsr::Mesh| {
        mesh.vertices
            .iter()
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
            .sum::<f64>()
            / mesh.vertices.len() as f64
    };
    let weighted = mean_radius(&reconstruct(&cloud, &params).unwrap().mesh);
    let unweighted = mean_radius(
        &reconstruct(
            &cloud,
            &Params {
                weights: PointWeights::Uniform,
                ..params.clone()
            },
        )
        .unwrap()
        .mesh,
    );
    assert!(
        (weighted - 1.0).abs() < (unweighted - 1.0).abs() && (weighted - 1.0).abs() < 0.015,
        "weighted radius {weighted}, unweighted {unweighted}"
    );
    // Points whose confidence is zero or not finite are dropped and counted.
    let mut zeroed = cloud.clone();
    if let AttributeData::F32(c) = &mut zeroed.attributes[0].data {
        c[0] = 0.0;
        c[1] = f32::NAN;
    }
    let out = reconstruct(&zeroed, &params).unwrap();
    assert_eq!(out.stats.dropped, 2);
    // A property the cloud does not have is a clear error.
    let missing = reconstruct(
        &cloud,
        &Params {
            weights: PointWeights::Property("quality".into()),
            ..params
        },
    );
    match missing {
        Err(Error::InvalidParameter {
            field,
            value,
            expected,
        }) => {
            assert_eq!(field, "weights");
            assert!(
                value.contains("quality") && expected.contains("confidence"),
                "{value} / {expected}"
            );
        }
        other => panic!("expected an error, got {other:?}"),
    }
}
