//! End-to-end tests of density trimming on the command line: `spsr reconstruct --trim` and
//! `spsr trim`, their outputs and their errors.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use tempfile::TempDir;

use crate::common::*;

/// Centre and radius of the dome below.
const CENTER: [f64; 3] = [1.0, 2.0, 3.0];
const RADIUS: f64 = 0.8;

/// A sphere scanned from above only: points with exact outward normals (Fibonacci lattice)
/// where the unit normal's z is above −0.5, so a cap around the bottom pole has no samples.
fn dome_points() -> String {
    let n = 6000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut rows = Vec::new();
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        if z < -0.5 {
            continue;
        }
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let u = [r * phi.cos(), r * phi.sin(), z];
        let p: Vec<f64> = (0..3).map(|k| CENTER[k] + RADIUS * u[k]).collect();
        rows.push(format!(
            "{} {} {} {} {} {}",
            p[0], p[1], p[2], u[0], u[1], u[2]
        ));
    }
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        rows.len()
    );
    for r in rows {
        text += &r;
        text.push('\n');
    }
    text
}

fn dome_dir() -> (TempDir, PathBuf) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("dome.ply");
    fs::write(&input, dome_points()).unwrap();
    (dir, input)
}

fn header(path: &Path) -> String {
    let bytes = fs::read(path).unwrap();
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .unwrap_or_else(|| panic!("{} has no end_header", path.display()));
    String::from_utf8(bytes[..end + 10].to_vec()).unwrap()
}

/// `spsr reconstruct dome.ply -o <name> --depth 6 <extra>`, which must succeed.
fn reconstruct_dome(dir: &Path, input: &Path, name: &str, extra: &[&str]) -> (PathBuf, Output) {
    let output = dir.join(name);
    let mut args = vec!["reconstruct", s(input), "-o", s(&output), "--depth", "6"];
    args.extend_from_slice(extra);
    let out = spsr(&args);
    assert!(out.status.success(), "spsr failed:\n{}", stderr(&out));
    (output, out)
}

/// The height of the mesh's lowest vertex.
fn lowest(mesh: &spsr::Mesh) -> f64 {
    mesh.vertices
        .iter()
        .map(|v| v[2])
        .fold(f64::INFINITY, f64::min)
}

#[test]
fn reconstruct_with_trim_auto_opens_the_unscanned_cap() {
    let (dir, input) = dome_dir();
    let (closed, _) = reconstruct_dome(dir.path(), &input, "closed.ply", &[]);
    let closed = spsr::io::read_mesh(&closed).unwrap();
    // The samples reach down to z = 3 − 0.5 × 0.8 = 2.6; the reconstruction closes the cap
    // below (down to the bounding cube).
    assert!(lowest(&closed) < 2.4);

    let (output, out) = reconstruct_dome(dir.path(), &input, "open.ply", &["--trim", "auto", "-v"]);
    let err = stderr(&out);
    assert!(
        err.contains("trim        V = ") && err.contains("auto: "),
        "{err}"
    );
    assert!(err.contains("holes restored"), "{err}");
    assert!(
        !header(&output).contains("density"),
        "density written without --density"
    );
    let open = spsr::io::read_mesh(&output).unwrap();
    let topo = open.topology();
    assert!(topo.boundary_edges > 0 && topo.edge_manifold && topo.oriented);
    assert_eq!(topo.components, 1);
    // The cap is gone but for a rim below the samples; the scanned part is kept.
    assert!(lowest(&open) > 2.5);
    assert!(open.area() > 0.7 * closed.area() && open.area() < 0.98 * closed.area());

    let (output, _) = reconstruct_dome(
        dir.path(),
        &input,
        "open-density.ply",
        &["--trim", "auto", "--density"],
    );
    assert!(header(&output).contains("property float density"));
    let with_density = spsr::io::read_mesh(&output).unwrap();
    assert_eq!(with_density.triangles, open.triangles);
}

#[test]
fn trim_command_trims_a_mesh_written_with_density() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "mesh.ply", &["--density"]);
    let before = fs::read(&mesh).unwrap();
    let output = dir.path().join("trimmed.ply");
    let out = spsr(&[
        "trim",
        s(&mesh),
        "--trim",
        "auto",
        "-o",
        s(&output),
        "-v",
        "--ascii",
    ]);
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("V = "), "{err}");
    assert!(header(&output).contains("format ascii"));
    let trimmed = spsr::io::read_mesh(&output).unwrap();
    assert!(trimmed.topology().boundary_edges > 0);
    assert!(trimmed.density.is_some(), "the density is kept");
    assert_eq!(fs::read(&mesh).unwrap(), before, "the input changed");

    // An explicit value; islands and holes kept as they are.
    let output = dir.path().join("explicit.obj");
    let out = spsr(&[
        "trim",
        s(&mesh),
        "--trim",
        "3.5",
        "--min-island-area",
        "0",
        "--hole-area",
        "0",
        "-o",
        s(&output),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(fs::read_to_string(&output).unwrap().contains("\nf "));
}

#[test]
fn trim_needs_a_density_property() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "plain.ply", &[]);
    let output = dir.path().join("out.ply");
    let out = spsr(&["trim", s(&mesh), "--trim", "auto", "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["plain.ply", "density", "--density"], &output);
}

#[test]
fn trim_refuses_to_overwrite_its_input() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "mesh.ply", &["--density"]);
    let before = fs::read(&mesh).unwrap();
    let out = spsr(&["trim", s(&mesh), "--trim", "auto", "-o", s(&mesh)]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(USAGE), "{err}");
    assert!(
        err.starts_with("spsr: error: ") && err.lines().count() == 1,
        "{err}"
    );
    assert_eq!(fs::read(&mesh).unwrap(), before);
}

#[test]
fn trim_rejects_bad_values() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "mesh.ply", &["--density"]);
    let output = dir.path().join("out.ply");
    let out = spsr(&["trim", s(&mesh), "--trim", "lots", "-o", s(&output)]);
    assert_fails(&out, USAGE, &["lots", "auto"], &output);
    let out = spsr(&["trim", s(&mesh), "--trim", "nan", "-o", s(&output)]);
    assert_fails(&out, USAGE, &["auto"], &output);
    let out = spsr(&["trim", s(&mesh), "-o", s(&output)]);
    assert_fails(&out, USAGE, &["--trim"], &output);
    let out = spsr(&[
        "trim",
        s(&mesh),
        "--trim",
        "auto",
        "--min-island-area",
        "1.5",
        "-o",
        s(&output),
    ]);
    assert_fails_one_line(&out, USAGE, &["--min-island-area", "[0, 1)"], &output);
    let out = spsr(&[
        "trim",
        s(&mesh),
        "--trim",
        "auto",
        "--hole-area",
        "-1",
        "-o",
        s(&output),
    ]);
    assert_fails_one_line(&out, USAGE, &["--hole-area"], &output);
    // Above every density: nothing would be left.
    let out = spsr(&["trim", s(&mesh), "--trim", "100", "-o", s(&output)]);
    assert_fails_one_line(&out, USAGE, &["removes the whole mesh", "auto"], &output);
    // Checked before reading: a missing input is not reached.
    let missing = dir.path().join("missing.ply");
    let out = spsr(&[
        "trim",
        s(&missing),
        "--trim",
        "auto",
        "--hole-area",
        "2",
        "-o",
        s(&output),
    ]);
    assert_fails_one_line(&out, USAGE, &["--hole-area"], &output);
    let out = spsr(&["trim", s(&missing), "--trim", "auto", "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["missing.ply"], &output);
}

#[test]
fn island_and_hole_flags_of_reconstruct_need_trim() {
    let (dir, input) = dome_dir();
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--hole-area",
        "0.01",
    ]);
    assert_fails(&out, USAGE, &["--trim"], &output);
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--trim",
        "auto",
        "--min-island-area",
        "7",
    ]);
    assert_fails_one_line(&out, USAGE, &["--min-island-area"], &output);
}

#[test]
fn help_explains_trimming_and_its_defaults() {
    let out = spsr(&["trim", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    for needle in [
        "--trim <V|auto>",
        "--min-island-area",
        "--hole-area",
        "[default: 0.001]",
        "--aRatio",
        "median",
        "--density",
        "Exit codes",
    ] {
        assert!(
            help.contains(needle),
            "trim --help lacks {needle:?}:\n{help}"
        );
    }
    let out = spsr(&["reconstruct", "--help"]);
    let help = String::from_utf8(out.stdout).unwrap();
    assert!(help.contains("--trim <V|auto>"), "{help}");
    let out = spsr(&["--help"]);
    let help = String::from_utf8(out.stdout).unwrap();
    assert!(help.contains("trim"), "{help}");
}

#[test]
fn meshes_without_density_formats_say_where_density_comes_from() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "mesh.obj", &["--density"]);
    let output = dir.path().join("out.ply");
    let out = spsr(&["trim", s(&mesh), "--trim", "auto", "-o", s(&output)]);
    assert_fails_one_line(
        &out,
        DATA,
        &[
            "mesh.obj",
            "no per-vertex density",
            "PLY and GLB",
            "--density",
        ],
        &output,
    );
}

#[test]
fn glb_keeps_the_density_and_trim_writes_the_output_format() {
    let (dir, input) = dome_dir();
    let (mesh, _) = reconstruct_dome(dir.path(), &input, "mesh.glb", &["--density"]);
    assert!(spsr::io::read_mesh(&mesh).unwrap().density.is_some());
    for name in ["trimmed.off", "trimmed.glb"] {
        let output = dir.path().join(name);
        let out = spsr(&["trim", s(&mesh), "--trim", "auto", "-o", s(&output)]);
        assert!(out.status.success(), "{}", stderr(&out));
        let trimmed = spsr::io::read_mesh(&output).unwrap();
        assert!(
            trimmed.topology().boundary_edges > 0,
            "{name}: the cap is cut away"
        );
        assert_eq!(trimmed.density.is_some(), name.ends_with(".glb"), "{name}");
    }
    assert!(fs::read_to_string(dir.path().join("trimmed.off"))
        .unwrap()
        .starts_with("OFF\n"));
}

#[test]
fn unknown_output_extensions_are_refused_before_reading() {
    let dir = TempDir::new().unwrap();
    // The input does not exist: the output is checked first.
    let missing = dir.path().join("missing.ply");
    for name in ["out.xyz", "out"] {
        let output = dir.path().join(name);
        let out = spsr(&["trim", s(&missing), "--trim", "auto", "-o", s(&output)]);
        assert_fails_one_line(
            &out,
            USAGE,
            &[name, ".ply, .obj, .stl, .off, .glb"],
            &output,
        );
        let out = spsr(&["reconstruct", s(&missing), "-o", s(&output)]);
        assert_fails_one_line(&out, USAGE, &[name, "not a mesh format"], &output);
    }
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}
