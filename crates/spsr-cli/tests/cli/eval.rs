//! End-to-end tests of `spsr eval`: JSON and table output, and one-line errors with the
//! documented exit codes for every bad input.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use spsr::Mesh;
use tempfile::TempDir;

use crate::common::*;

/// Octahedron-based sphere: each octant face split into `n²` triangles, vertices pushed onto
/// the sphere of radius `r` centred at `c` (8 n² faces).
fn sphere(c: [f64; 3], r: f64, n: usize) -> Mesh {
    let mut vertices: Vec<[f64; 3]> = Vec::new();
    let mut triangles = Vec::new();
    let mut index = std::collections::HashMap::new();
    let mut id = |p: [i64; 3], vertices: &mut Vec<[f64; 3]>| -> u32 {
        *index.entry(p).or_insert_with(|| {
            let v = p.map(|x| x as f64);
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            vertices.push(std::array::from_fn(|k| c[k] + r * v[k] / l));
            vertices.len() as u32 - 1
        })
    };
    let n = n as i64;
    for sx in [-1i64, 1] {
        for sy in [-1i64, 1] {
            for sz in [-1i64, 1] {
                // Lattice points (i, j, n − i − j) of the octant, signs applied.
                let p = |i: i64, j: i64| [sx * i, sy * j, sz * (n - i - j)];
                let flip = sx * sy * sz < 0;
                let mut tri = |a: [i64; 3], b: [i64; 3], cc: [i64; 3]| {
                    let (a, b, cc) = (
                        id(a, &mut vertices),
                        id(b, &mut vertices),
                        id(cc, &mut vertices),
                    );
                    triangles.push(if flip { [a, cc, b] } else { [a, b, cc] });
                };
                for i in 0..n {
                    for j in 0..n - i {
                        tri(p(i, j), p(i + 1, j), p(i, j + 1));
                        if i + j + 2 <= n {
                            tri(p(i + 1, j), p(i + 1, j + 1), p(i, j + 1));
                        }
                    }
                }
            }
        }
    }
    Mesh {
        vertices,
        triangles,
        ..Default::default()
    }
}

fn write(dir: &Path, name: &str, mesh: &Mesh) -> PathBuf {
    let path = dir.join(name);
    spsr::io::write_mesh(&path, mesh, &spsr::io::WriteOptions::default()).unwrap();
    path
}

/// A folder with `mesh.ply` (sphere r = 1) and `gt.ply` (sphere r = 1.1).
fn spheres() -> (TempDir, PathBuf, PathBuf) {
    let dir = TempDir::new().unwrap();
    let mesh = write(dir.path(), "mesh.ply", &sphere([0.0; 3], 1.0, 16));
    let gt = write(dir.path(), "gt.ply", &sphere([0.0; 3], 1.1, 16));
    (dir, mesh, gt)
}

/// The value of `"key": value` in a one-line JSON object (string matching, no parser).
fn field<'a>(json: &'a str, key: &str) -> &'a str {
    let pat = format!("\"{key}\": ");
    let start = json.find(&pat).unwrap_or_else(|| panic!("{key} in {json}")) + pat.len();
    let rest = &json[start..];
    let end = rest.find([',', '}']).unwrap();
    rest[..end].trim()
}

fn number(json: &str, key: &str) -> f64 {
    field(json, key)
        .parse()
        .unwrap_or_else(|e| panic!("{key}: {e} in {json}"))
}

fn json_of(out: &Output) -> String {
    let stdout = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout.lines().last().expect("a last line").to_string()
}

#[test]
fn json_last_line_has_every_key() {
    let (_dir, mesh, gt) = spheres();
    let out = spsr(&[
        "eval",
        s(&mesh),
        "--reference",
        s(&gt),
        "--samples",
        "20000",
        "--json",
    ]);
    let json = json_of(&out);
    assert!(json.starts_with('{') && json.ends_with('}'), "{json}");
    for key in [
        "chamfer",
        "chamfer_rel",
        "hausdorff",
        "hausdorff_rel",
        "mesh_to_reference_mean",
        "reference_to_mesh_mean",
        "fscore_0_5",
        "fscore_1",
        "normal_consistency",
    ] {
        let x = number(&json, key);
        assert!(x.is_finite() && x >= 0.0, "{key} = {x}");
    }
    for key in ["vertices", "faces", "components", "euler"] {
        field(&json, key).parse::<i64>().unwrap();
    }
    for key in ["closed", "edge_manifold", "vertex_manifold", "oriented"] {
        assert_eq!(field(&json, key), "true", "{key} in {json}");
    }
    assert_eq!(field(&json, "faces"), "2048");
    assert_eq!(field(&json, "euler"), "2");
    assert_eq!(field(&json, "components"), "1");
    // Radii 1 and 1.1: about 0.1 apart (less the tessellation's sagitta, written as f32).
    let chamfer = number(&json, "chamfer");
    assert!(chamfer > 0.09 && chamfer < 0.1 + 1e-6, "{chamfer}");
    let h = number(&json, "hausdorff");
    assert!(h > 0.09 && h < 0.1 + 1e-6, "{h}");
    let rel = number(&json, "chamfer_rel");
    assert!((rel - chamfer / (2.2 * 3f64.sqrt())).abs() < 1e-6, "{rel}");
    assert_eq!(number(&json, "fscore_1"), 0.0);
    assert!(number(&json, "normal_consistency") > 0.98);
}

#[test]
fn thread_count_does_not_change_the_numbers() {
    let (_dir, mesh, gt) = spheres();
    let run = |threads: &str| {
        json_of(&spsr(&[
            "eval",
            s(&mesh),
            "--reference",
            s(&gt),
            "--samples",
            "30000",
            "--json",
            "--threads",
            threads,
        ]))
    };
    assert_eq!(run("1"), run("3"));
}

#[test]
fn sphere_reference_and_open_mesh() {
    let dir = TempDir::new().unwrap();
    let mut m = sphere([1.0, -2.0, 0.5], 2.0, 24);
    m.triangles.truncate(m.triangles.len() - 10);
    let mesh = write(dir.path(), "open.ply", &m);
    let out = spsr(&[
        "eval",
        s(&mesh),
        "--reference-sphere",
        "1,-2,0.5,2",
        "--samples",
        "20000",
        "--json",
    ]);
    let json = json_of(&out);
    assert_eq!(field(&json, "closed"), "false");
    assert_eq!(field(&json, "edge_manifold"), "true");
    assert!(number(&json, "mesh_to_reference_mean") < 0.01);
    assert!(number(&json, "fscore_1") > 0.9);
    assert!(number(&json, "normal_consistency") > 0.99);
    assert!((number(&json, "diagonal") - 4.0 * 3f64.sqrt()).abs() < 1e-9);
}

#[test]
fn table_output() {
    let (_dir, mesh, gt) = spheres();
    let out = spsr(&["eval", s(&mesh), "--reference", s(&gt), "--samples", "5000"]);
    let stdout = String::from_utf8(out.stdout.clone()).unwrap();
    assert_eq!(out.status.code(), Some(0));
    for label in [
        "chamfer",
        "hausdorff",
        "mesh -> reference",
        "reference -> mesh",
        "f-score @ 0.5 %",
        "f-score @ 1 %",
        "normal consistency",
        "vertices",
        "faces",
        "closed",
        "edge-manifold",
        "vertex-manifold",
        "oriented",
        "components",
        "euler characteristic",
    ] {
        assert!(
            stdout.lines().any(|l| l.starts_with(label)),
            "{label} in\n{stdout}"
        );
    }
    assert!(stdout.contains("faces                    2048"), "{stdout}");
    assert!(stdout.contains("closed                   yes"), "{stdout}");
    assert!(!stdout.contains('{'));
}

/// Asserts a clean failure: exit code, one `spsr: error:` line with the fragments, no panic.
fn assert_fails(out: &Output, code: i32, fragments: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "stderr:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(err.lines().count(), 1, "one line:\n{err}");
    assert!(err.starts_with("spsr: error: "), "{err}");
    for f in fragments {
        assert!(err.contains(f), "{f:?} in {err}");
    }
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
}

#[test]
fn missing_files() {
    let (dir, mesh, gt) = spheres();
    let missing = dir.path().join("missing.ply");
    let out = spsr(&["eval", s(&missing), "--reference", s(&gt)]);
    assert_fails(&out, DATA, &["missing.ply"]);
    let out = spsr(&["eval", s(&mesh), "--reference", s(&missing)]);
    assert_fails(&out, DATA, &["missing.ply"]);
}

#[test]
fn malformed_and_empty_meshes() {
    let (dir, mesh, _gt) = spheres();
    let bad = dir.path().join("bad.ply");
    fs::write(
        &bad,
        "ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n",
    )
    .unwrap();
    let out = spsr(&["eval", s(&bad), "--reference", s(&mesh)]);
    assert_fails(&out, DATA, &["bad.ply"]);

    let empty = write(dir.path(), "empty.ply", &Mesh::default());
    let out = spsr(&["eval", s(&empty), "--reference", s(&mesh)]);
    assert_fails(&out, DATA, &["empty.ply", "no faces"]);
    let out = spsr(&["eval", s(&mesh), "--reference", s(&empty)]);
    assert_fails(&out, DATA, &["empty.ply", "no faces"]);

    let flat = Mesh {
        vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
        triangles: vec![[0, 1, 2]],
        ..Default::default()
    };
    let flat = write(dir.path(), "flat.ply", &flat);
    let out = spsr(&["eval", s(&flat), "--reference-sphere", "0,0,0,1"]);
    assert_fails(&out, DATA, &["flat.ply", "no surface area"]);
}

#[test]
fn bad_reference_sphere() {
    let (_dir, mesh, _gt) = spheres();
    for (spec, fragment) in [
        ("1,2,3", "3 values"),
        ("1,2,3,4,5", "5 values"),
        ("a,0,0,1", "'a' is not a finite number"),
        ("0,0,0,inf", "'inf' is not a finite number"),
        ("0,0,0,0", "radius must be positive"),
        ("0,0,0,-1", "radius must be positive"),
        ("", "1 values"),
    ] {
        let out = spsr(&["eval", s(&mesh), "--reference-sphere", spec]);
        assert_fails(&out, USAGE, &["--reference-sphere", fragment]);
    }
}

#[test]
fn neither_or_both_references() {
    let (_dir, mesh, gt) = spheres();
    let out = spsr(&["eval", s(&mesh)]);
    assert_fails(&out, USAGE, &["no reference"]);
    let out = spsr(&[
        "eval",
        s(&mesh),
        "--reference",
        s(&gt),
        "--reference-sphere",
        "0,0,0,1",
    ]);
    assert_fails(&out, USAGE, &["cannot be used together"]);
}

#[test]
fn bad_sample_counts() {
    let (_dir, mesh, gt) = spheres();
    for n in ["0", "-5"] {
        let out = spsr(&["eval", s(&mesh), "--reference", s(&gt), "--samples", n]);
        assert_fails(&out, USAGE, &["--samples", "at least 1"]);
    }
}

#[test]
fn every_mesh_format_is_scored_alike() {
    let (dir, mesh, gt) = spheres();
    let score = |path: &Path, reference: &Path| {
        let out = spsr(&[
            "eval",
            s(path),
            "--reference",
            s(reference),
            "--samples",
            "5000",
            "--json",
        ]);
        json_of(&out)
    };
    let ply = score(&mesh, &gt);
    let m = spsr::io::read_mesh(&mesh).unwrap();
    for ext in ["obj", "stl", "off", "glb"] {
        let path = write(dir.path(), &format!("mesh.{ext}"), &m);
        let json = score(&path, &gt);
        // The same surface, so the same numbers; STL too, its corners merged into vertices.
        for key in ["vertices", "faces", "euler", "closed", "oriented"] {
            assert_eq!(field(&json, key), field(&ply, key), "{ext}: {key}");
        }
        let (a, b) = (number(&json, "chamfer"), number(&ply, "chamfer"));
        assert!((a - b).abs() < 1e-6, "{ext}: chamfer {a} against {b}");
        // As the reference, too.
        let reference = write(
            dir.path(),
            &format!("gt.{ext}"),
            &spsr::io::read_mesh(&gt).unwrap(),
        );
        let json = score(&mesh, &reference);
        assert!(
            (number(&json, "chamfer") - b).abs() < 1e-6,
            "{ext} as reference"
        );
    }
    let unknown = dir.path().join("mesh.dat");
    fs::copy(dir.path().join("mesh.obj"), &unknown).unwrap();
    let out = spsr(&["eval", s(&unknown), "--reference", s(&gt)]);
    assert_fails(&out, DATA, &["mesh.dat", "not a mesh format", ".obj"]);
}
