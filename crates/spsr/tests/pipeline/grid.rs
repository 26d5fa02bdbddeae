//! The implicit function on a grid and at arbitrary points (issue 18, `Params::grid_res`).

use spsr::{Error, Params};

use crate::common::sphere;

const CENTRE: [f64; 3] = [0.3, -0.1, 0.2];

fn params(grid: u32) -> Params {
    Params {
        depth: 6,
        grid_res: Some(grid),
        ..Params::default()
    }
}

#[test]
fn the_grid_of_a_sphere_is_negative_inside_positive_outside_and_crosses_at_the_radius() {
    let cloud = sphere(20_000, CENTRE, 1.0, 5);
    let r = 24;
    let out = spsr::reconstruct(&cloud, &params(r as u32)).unwrap();
    let g = out.grid.expect("a grid was asked for");
    assert_eq!((g.res, g.values.len()), (r, r * r * r));
    let at = |i: usize, j: usize, k: usize| g.values[(i * r + j) * r + k];
    let pos = |i: usize, j: usize, k: usize| {
        [i, j, k]
            .map(|n| n as f64)
            .map(|n| n * g.spacing)
            .iter()
            .zip(g.origin)
            .map(|(d, o)| o + d)
            .collect::<Vec<_>>()
    };
    // The cube is the box (2 wide) times 1.1, split into r cells.
    assert!((g.spacing * r as f64 - 2.2).abs() < 0.05, "{}", g.spacing);
    let dist = |p: &[f64]| {
        (0..3)
            .map(|a| (p[a] - CENTRE[a]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    // The samples nearest the centre are inside, the corners outside.
    let mid = (0..r).min_by(|&a, &b| {
        let d = |i: usize| (g.origin[0] + i as f64 * g.spacing - CENTRE[0]).abs();
        d(a).total_cmp(&d(b))
    });
    let c = mid.unwrap();
    assert!(dist(&pos(c, c, c)) < 0.2, "{:?}", pos(c, c, c));
    assert!(at(c, c, c) < 0.0, "centre {}", at(c, c, c));
    for (i, j, k) in [
        (0, 0, 0),
        (r - 1, 0, 0),
        (0, r - 1, r - 1),
        (r - 1, r - 1, r - 1),
    ] {
        assert!(at(i, j, k) > 0.0, "corner {i} {j} {k}: {}", at(i, j, k));
    }
    // Wherever neighbours along an axis change sign, the crossing (interpolated) lies within
    // one grid step of the sphere.
    let mut crossings = 0;
    for i in 0..r {
        for j in 0..r {
            for k in 0..r - 1 {
                for (a, b) in [
                    ((i, j, k), (i, j, k + 1)),
                    ((j, k, i), (j, k + 1, i)),
                    ((k, i, j), (k + 1, i, j)),
                ] {
                    let (va, vb) = (at(a.0, a.1, a.2), at(b.0, b.1, b.2));
                    if (va < 0.0) != (vb < 0.0) {
                        let t = f64::from(va / (va - vb));
                        let (pa, pb) = (pos(a.0, a.1, a.2), pos(b.0, b.1, b.2));
                        let p: Vec<f64> = (0..3).map(|x| pa[x] + t * (pb[x] - pa[x])).collect();
                        let err = (dist(&p) - 1.0).abs();
                        assert!(err < g.spacing, "crossing {err} from the sphere at {p:?}");
                        crossings += 1;
                    }
                }
            }
        }
    }
    assert!(crossings > 1000, "{crossings}");
}

#[test]
fn the_kept_function_agrees_with_the_grid_at_its_points_and_its_gradient_points_out() {
    let cloud = sphere(20_000, CENTRE, 1.0, 5);
    let r = 12;
    let (out, f) = spsr::reconstruct_implicit(cloud, &params(r as u32), &|_| {}).unwrap();
    let g = out.grid.unwrap();
    assert_eq!(f.grid(r as u32), g);
    let points: Vec<[f64; 3]> = (0..r * r * r)
        .map(|n| {
            let (i, j, k) = (n / (r * r), n / r % r, n % r);
            [i, j, k]
                .map(|m| m as f64)
                .map(|m| m * g.spacing)
                .map(|d| d) // steps
        })
        .map(|d| std::array::from_fn(|a| g.origin[a] + d[a]))
        .collect();
    let values = f.values(&points);
    for (v, gv) in values.iter().zip(&g.values) {
        assert_eq!(*v as f32, *gv);
    }
    // On the sphere the value is near 0 and the gradient points outward.
    let dirs = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.6, 0.0, 0.8]];
    let on: Vec<[f64; 3]> = dirs
        .iter()
        .map(|d| std::array::from_fn(|a| CENTRE[a] + d[a]))
        .collect();
    let (v, grad) = f.values_and_gradients(&on);
    for ((v, g), d) in v.iter().zip(&grad).zip(&dirs) {
        let len = g.iter().map(|c| c * c).sum::<f64>().sqrt();
        let cos = (0..3).map(|a| g[a] * d[a]).sum::<f64>() / len;
        assert!(
            v.abs() < 0.05 && cos > 0.95,
            "value {v}, gradient {g:?} along {d:?}"
        );
    }
    assert_eq!(values, f.values_and_gradients(&points).0);
}

#[test]
fn bad_grid_resolutions_are_refused_by_name() {
    let cloud = sphere(1000, CENTRE, 1.0, 5);
    for (res, memory) in [(1, None), (0, None), (2000, Some(1u64 << 30))] {
        let p = Params {
            max_memory: memory,
            ..params(res)
        };
        match spsr::reconstruct(&cloud, &p) {
            Err(Error::InvalidParameter {
                field, expected, ..
            }) => {
                assert_eq!(field, "grid_res");
                assert!(res < 2 || expected.contains("at most"), "{expected}");
            }
            other => panic!("{res}: {other:?}"),
        }
    }
}

#[test]
fn the_grid_file_is_a_numpy_archive_of_the_three_arrays() {
    let cloud = sphere(5000, CENTRE, 1.0, 5);
    let g = spsr::reconstruct(&cloud, &params(8)).unwrap().grid.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.npz");
    spsr::io::write_grid(&path, &g).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..4], b"PK\x03\x04");
    // The first entry is values.npy, stored: its data follow the 64-byte-aligned header.
    assert_eq!(&bytes[30..40], b"values.npy");
    let npy = &bytes[40..];
    assert_eq!(&npy[..6], b"\x93NUMPY");
    let header_len = u16::from_le_bytes([npy[8], npy[9]]) as usize;
    let header = std::str::from_utf8(&npy[10..10 + header_len]).unwrap();
    assert!(
        header.contains("'<f4'") && header.contains("(8, 8, 8)"),
        "{header}"
    );
    let data = &npy[10 + header_len..];
    for (n, v) in g.values.iter().enumerate() {
        assert_eq!(
            f32::from_le_bytes(data[4 * n..4 * n + 4].try_into().unwrap()),
            *v
        );
    }
    for name in ["origin.npy", "spacing.npy"] {
        assert!(
            bytes.windows(name.len()).any(|w| w == name.as_bytes()),
            "{name}"
        );
    }
    assert_eq!(&bytes[bytes.len() - 22..bytes.len() - 18], b"PK\x05\x06");
}

#[test]
fn a_trimmed_run_keeps_the_same_function_and_the_same_trimmed_mesh() {
    let cloud = sphere(5000, CENTRE, 1.0, 5);
    let trim = spsr::trim::TrimParams::default();
    let p = Params {
        grid_res: None,
        ..params(2)
    };
    let (plain, plain_stats) =
        spsr::reconstruct_and_trim(cloud.clone(), &p, &trim, &|_| {}).unwrap();
    let (kept, kept_stats, f) =
        spsr::reconstruct_and_trim_implicit(cloud.clone(), &p, &trim, &|_| {}).unwrap();
    assert_eq!(kept.mesh.vertices, plain.mesh.vertices);
    assert_eq!(kept.mesh.triangles, plain.mesh.triangles);
    assert_eq!(kept_stats.threshold, plain_stats.threshold);
    let (_, g) = spsr::reconstruct_implicit(cloud, &p, &|_| {}).unwrap();
    let at = [
        CENTRE,
        [2.0, 2.0, 2.0],
        [CENTRE[0] + 1.0, CENTRE[1], CENTRE[2]],
    ];
    assert_eq!(f.values(&at), g.values(&at));
}
