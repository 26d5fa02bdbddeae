//! End-to-end tests of `spsr normals` and of `spsr reconstruct` on clouds without normals, on
//! small synthetic clouds.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use tempfile::TempDir;

use crate::common::*;

fn assert_ok(out: &Output) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr:\n{}\nstdout:\n{}",
        stderr(out),
        stdout(out)
    );
}

/// ASCII PLY with `x y z`, optionally `nx ny nz`, then `uchar red` and `float intensity`
/// (the point's index and its tenth), and optional header comments.
fn write_ply(path: &Path, points: &[([f64; 3], [f64; 3])], normals: bool, comments: &[&str]) {
    let mut text = String::from("ply\nformat ascii 1.0\n");
    for c in comments {
        text += &format!("comment {c}\n");
    }
    text += &format!(
        "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        points.len()
    );
    if normals {
        text += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    text += "property uchar red\nproperty float intensity\nend_header\n";
    for (i, (p, n)) in points.iter().enumerate() {
        text += &format!("{} {} {}", p[0], p[1], p[2]);
        if normals {
            text += &format!(" {} {} {}", n[0], n[1], n[2]);
        }
        text += &format!(" {} {}\n", i % 256, i as f64 / 10.0);
    }
    fs::write(path, text).unwrap();
}

/// A folder with `in.ply` (sphere without normals) and `ref.ply` (the same with normals).
fn sphere_dir(n: usize) -> (TempDir, PathBuf, PathBuf) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("in.ply");
    let reference = dir.path().join("ref.ply");
    let pts = sphere(n);
    write_ply(&input, &pts, false, &[]);
    write_ply(&reference, &pts, true, &[]);
    (dir, input, reference)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[test]
fn normals_keep_points_order_and_properties_and_point_outward() {
    let (dir, input, _) = sphere_dir(3000);
    let output = dir.path().join("out.ply");
    let out = spsr(&["normals", s(&input), "-o", s(&output)]);
    assert_ok(&out);
    assert!(
        stdout(&out).contains("3000 points with normals"),
        "{}",
        stdout(&out)
    );
    assert!(stdout(&out).contains("orient mst"), "{}", stdout(&out));

    let before = spsr::io::read_cloud(&input).unwrap();
    let after = spsr::io::read_cloud(&output).unwrap();
    assert_eq!(after.positions, before.positions);
    assert!(after.has_normals());
    for (p, n) in after.positions.iter().zip(&after.normals) {
        let radial = std::array::from_fn(|a| p[a] - CENTRE[a]);
        let cos = dot(*n, radial) / 0.8;
        assert!(cos > 0.95, "normal {n:?} at {p:?} is not outward");
    }
    let names: Vec<&str> = after.attributes.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["red", "intensity"]);
    for (a, b) in before.attributes.iter().zip(&after.attributes) {
        assert_eq!(a.data.scalar_type(), b.data.scalar_type());
        assert!(
            a.data.iter_f64().eq(b.data.iter_f64()),
            "{} changed",
            a.name
        );
    }
}

#[test]
fn compare_reports_agreement_with_the_reference() {
    let (dir, input, reference) = sphere_dir(3000);
    // Without -o: only the comparison, no file.
    let out = spsr(&["normals", s(&input), "--compare", s(&reference)]);
    assert_ok(&out);
    let text = stdout(&out);
    assert!(
        text.contains("100.000 % oriented like the reference"),
        "{text}"
    );
    assert!(text.contains("mean angle"), "{text}");
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 2);

    // A reference with other points is an error naming it.
    let other = dir.path().join("other.ply");
    write_ply(&other, &sphere(100), true, &[]);
    let output = dir.path().join("out.ply");
    let out = spsr(&["normals", s(&input), "--compare", s(&other)]);
    assert_fails(&out, DATA, &["other.ply", "same points"], &output);
    // A reference without normals too.
    let out = spsr(&["normals", s(&input), "--compare", s(&input)]);
    assert_fails(
        &out,
        DATA,
        &[
            "in.ply",
            "the reference has no normals (nx, ny, nz) to compare with",
        ],
        &output,
    );
}

#[test]
fn global_mode_orients_the_sphere() {
    let (_dir, input, reference) = sphere_dir(2000);
    let out = spsr(&[
        "normals",
        s(&input),
        "--orient",
        "global",
        "--compare",
        s(&reference),
    ]);
    assert_ok(&out);
    assert!(
        stdout(&out).contains("100.000 % oriented"),
        "{}",
        stdout(&out)
    );
}

/// A wavy 60 × 60 patch around z = 0 (no normals), split into two scans of 1800 points.
fn patch() -> Vec<([f64; 3], [f64; 3])> {
    (0..3600)
        .map(|i| {
            let (x, y) = ((i % 60) as f64 / 60.0, (i / 60) as f64 / 60.0);
            ([x, y, 0.05 * (6.0 * x).sin()], [0.0; 3])
        })
        .collect()
}

#[test]
fn viewpoint_and_scan_positions_orient_towards_the_sensor() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("patch.ply");
    write_ply(&input, &patch(), false, &[]);
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "normals",
        s(&input),
        "-o",
        s(&output),
        "--viewpoint",
        "0.5,0.5,-3",
    ]);
    assert_ok(&out);
    let cloud = spsr::io::read_cloud(&output).unwrap();
    assert!(cloud.normals.iter().all(|n| n[2] < 0.0));

    // Two scans recorded in the file, one seen from above, one from below: orientation
    // towards them is the default.
    let scans = dir.path().join("scans.ply");
    write_ply(
        &scans,
        &patch(),
        false,
        &[
            "spsr scan_origin 0 0.5 0.5 3",
            "spsr scan_origin 1800 0.5 0.5 -3",
        ],
    );
    let out = spsr(&["normals", s(&scans), "-o", s(&output), "-v"]);
    assert_ok(&out);
    assert!(
        stdout(&out).contains("2 scan position(s)"),
        "{}",
        stdout(&out)
    );
    let cloud = spsr::io::read_cloud(&output).unwrap();
    assert_eq!(cloud.scan_origins.len(), 2, "scan positions kept");
    for (i, n) in cloud.normals.iter().enumerate() {
        assert_eq!(n[2] > 0.0, i < 1800, "point {i}: {n:?}");
    }
}

#[test]
fn the_result_does_not_depend_on_the_thread_count() {
    let (dir, input, _) = sphere_dir(3000);
    let one = dir.path().join("one.ply");
    let two = dir.path().join("two.ply");
    assert_ok(&spsr(&[
        "normals",
        s(&input),
        "-o",
        s(&one),
        "--threads",
        "1",
    ]));
    assert_ok(&spsr(&[
        "normals",
        s(&input),
        "-o",
        s(&two),
        "--threads",
        "2",
    ]));
    assert_eq!(fs::read(&one).unwrap(), fs::read(&two).unwrap());
}

#[test]
fn bad_values_are_usage_errors() {
    let (dir, input, _) = sphere_dir(500);
    let output = dir.path().join("out.ply");
    let o = s(&output);
    let i = s(&input);
    for (args, fragment) in [
        (vec!["--viewpoint", "1,2"], "three comma-separated"),
        (vec!["--viewpoint", "1,2,nan"], "finite"),
        (vec!["--viewpoint", "a,b,c"], "finite"),
        (vec!["--neighbours", "2"], "at least 3"),
        (vec!["--neighbours", "four"], "whole number"),
        (vec!["--orient", "sideways"], "sideways"),
        (vec!["--threads", "0"], "at least 1"),
        (vec!["--orient", "viewpoint"], "needs --viewpoint"),
        (
            vec!["--orient", "mst", "--viewpoint", "0,0,1"],
            "only used by --orient viewpoint",
        ),
    ] {
        let mut all = vec!["normals", i, "-o", o];
        all.extend(args.iter().copied());
        let out = spsr(&all);
        assert_fails(&out, USAGE, &[fragment], &output);
    }
    // No output and nothing to compare with.
    let out = spsr(&["normals", i]);
    assert_fails(&out, USAGE, &["--output"], &output);
    // The output must not be the input.
    let out = spsr(&["normals", i, "-o", i]);
    assert_eq!(out.status.code(), Some(USAGE), "{}", stderr(&out));
    // A missing input is a data error naming it.
    let missing = dir.path().join("missing.ply");
    let out = spsr(&["normals", s(&missing), "-o", o]);
    assert_fails(&out, DATA, &["missing.ply"], &output);
}

#[test]
fn help_shows_every_default() {
    let out = spsr(&["normals", "--help"]);
    assert_ok(&out);
    let text = stdout(&out);
    let help = &text[text.find("Options:").expect("an options list")..];
    for flag in [
        "--orient",
        "--viewpoint",
        "--neighbours",
        "--compare",
        "--threads",
        "--ascii",
        "--verbose",
    ] {
        let at = help.find(flag).unwrap_or_else(|| panic!("{flag} missing"));
        let rest = &help[at..];
        let end = rest[2..].find("\n  -").map_or(rest.len(), |e| e + 2);
        assert!(
            rest[..end].contains("[default: "),
            "{flag}: {}",
            &rest[..end]
        );
    }
    let out = spsr(&["reconstruct", "--help"]);
    let help = stdout(&out);
    for flag in [
        "--estimate-normals",
        "--orient",
        "--viewpoint",
        "--neighbours",
    ] {
        assert!(
            help.contains(flag),
            "{flag} missing from reconstruct --help"
        );
    }
}

#[test]
fn reconstruct_estimates_missing_normals_and_says_so() {
    let (dir, input, reference) = sphere_dir(3000);
    let output = dir.path().join("mesh.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output), "--depth", "5"]);
    assert_ok(&out);
    assert!(stderr(&out).contains("has no normals"), "{}", stderr(&out));
    assert_eq!(stderr(&out).lines().count(), 1, "{}", stderr(&out));
    let mesh = spsr::io::read_mesh(&output).unwrap();
    // Outward normals give a mesh around the sphere, with positive volume.
    assert!(mesh.signed_volume() > 0.0);
    for v in &mesh.vertices {
        let r = dot(
            std::array::from_fn(|a| v[a] - CENTRE[a]),
            std::array::from_fn(|a| v[a] - CENTRE[a]),
        )
        .sqrt();
        assert!((r - 0.8).abs() < 0.05, "vertex at radius {r}");
    }

    // A cloud with normals: they are used as they are, silently ...
    let out = spsr(&[
        "reconstruct",
        s(&reference),
        "-o",
        s(&output),
        "--depth",
        "5",
    ]);
    assert_ok(&out);
    assert!(!stderr(&out).contains("normals"), "{}", stderr(&out));
    // ... or replaced when asked,
    let out = spsr(&[
        "reconstruct",
        s(&reference),
        "-o",
        s(&output),
        "--depth",
        "5",
        "--estimate-normals",
        "--orient",
        "global",
    ]);
    assert_ok(&out);
    // and orientation flags without --estimate-normals are a usage error.
    fs::remove_file(&output).unwrap();
    let out = spsr(&[
        "reconstruct",
        s(&reference),
        "-o",
        s(&output),
        "--orient",
        "mst",
    ]);
    assert_fails(&out, USAGE, &["--estimate-normals"], &output);
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--orient",
        "viewpoint",
    ]);
    assert_fails(&out, USAGE, &["needs --viewpoint"], &output);
}

#[test]
fn compare_refuses_a_reference_with_other_points() {
    let (dir, input, _) = sphere_dir(500);
    // The same number of points, but another sphere: refused before any work, saying why.
    let shifted: Vec<_> = sphere(500)
        .into_iter()
        .map(|(p, n)| (p.map(|x| x + 0.01), n))
        .collect();
    let other = dir.path().join("shifted.ply");
    write_ply(&other, &shifted, true, &[]);
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "normals",
        s(&input),
        "-o",
        s(&output),
        "--compare",
        s(&other),
    ]);
    assert_fails(
        &out,
        DATA,
        &[
            "shifted.ply",
            "points differ",
            "500 of 500",
            "same points in the same order",
        ],
        &output,
    );
    // One point moved: named, with its distance.
    let mut moved = sphere(500);
    moved[17].0[2] += 0.5;
    write_ply(&other, &moved, true, &[]);
    let out = spsr(&["normals", s(&input), "--compare", s(&other)]);
    assert_fails(&out, DATA, &["1 of 500", "point 17", "5.000e-1"], &output);
}

#[test]
fn output_formats_by_extension_and_mesh_files_as_input() {
    let (dir, input, _) = sphere_dir(800);
    let output = dir.path().join("out.las");
    let out = spsr(&["normals", s(&input), "-o", s(&output)]);
    assert_fails(&out, USAGE, &["out.las", ".ply, .xyz, .txt"], &output);
    // Text output: x y z nx ny nz (the input's `red` alone is no colour), readable as oriented
    // points.
    let xyz = dir.path().join("out.xyz");
    assert_ok(&spsr(&["normals", s(&input), "-o", s(&xyz)]));
    let cloud = spsr::io::read_points(&xyz).unwrap();
    assert_eq!(cloud.len(), 800);
    let first = fs::read_to_string(&xyz).unwrap();
    assert_eq!(first.lines().next().unwrap().split(' ').count(), 6);
    // A mesh file's vertices as the cloud, compared with the same vertices with normals.
    let mesh = spsr::Mesh {
        vertices: sphere(800).iter().map(|(p, _)| *p).collect(),
        normals: Some(
            sphere(800)
                .iter()
                .map(|(_, n)| n.map(|c| c as f32))
                .collect(),
        ),
        ..Default::default()
    };
    let off = dir.path().join("vertices.off");
    spsr::io::write_mesh(&off, &mesh, &spsr::io::WriteOptions::default()).unwrap();
    let out = spsr(&["normals", s(&off), "--compare", s(&off)]);
    assert_ok(&out);
    assert!(
        stdout(&out).contains("100.000 % oriented like the reference"),
        "{}",
        stdout(&out)
    );
    // Against the PLY of the same points (float there, f32 text in the OFF): accepted.
    let out = spsr(&[
        "normals",
        s(&off),
        "--compare",
        s(&dir.path().join("ref.ply")),
    ]);
    assert_ok(&out);
}
