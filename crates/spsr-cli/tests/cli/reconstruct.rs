//! End-to-end tests of the `spsr` binary: every bad input fails with one error line, the
//! documented exit code and no output file; good inputs give meshes in the requested format.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use tempfile::TempDir;

use crate::common::*;

fn write_ascii_ply(path: &Path, points: &[([f64; 3], [f64; 3])]) {
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        points.len()
    );
    for (p, n) in points {
        text += &format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]);
    }
    fs::write(path, text).unwrap();
}

/// A temporary folder holding a valid sphere cloud `in.ply`.
fn sphere_dir() -> (TempDir, PathBuf) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("in.ply");
    write_ascii_ply(&input, &sphere(3000));
    (dir, input)
}

/// Names of the entries of `dir`, sorted.
fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Runs `spsr reconstruct <input> -o <dir>/out.ply <extra>` on a file with the given content.
fn run_on(content: &[u8], name: &str, extra: &[&str]) -> (TempDir, PathBuf, PathBuf, Output) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join(name);
    fs::write(&input, content).unwrap();
    let output = dir.path().join("out.ply");
    let mut args = vec!["reconstruct", s(&input), "-o", s(&output)];
    args.extend_from_slice(extra);
    let out = spsr(&args);
    (dir, input, output, out)
}

// ---- bad input data: exit code 1 ----

#[test]
fn missing_input_file() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("no-such-cloud.ply");
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["no-such-cloud.ply"], &output);
}

#[test]
fn input_is_a_directory() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("cloud-dir.ply");
    fs::create_dir(&input).unwrap();
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["cloud-dir.ply"], &output);
}

#[test]
fn malformed_ply_header() {
    let header = b"ply\nformat ascii 1.0\nelement vertex many\nproperty float x\nend_header\n";
    let (_dir, _input, output, out) = run_on(header, "bad-header.ply", &[]);
    assert_fails_one_line(&out, DATA, &["bad-header.ply"], &output);
}

#[test]
fn truncated_binary_ply() {
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n\
        property float x\nproperty float y\nproperty float z\n\
        property float nx\nproperty float ny\nproperty float nz\nend_header\n"
        .to_vec();
    // 100 vertices need 2400 bytes; give one and a half.
    for v in [0.5f32, 0.25, 0.125, 0.0, 0.0, 1.0, 0.5, 0.5, 0.5] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let (_dir, _input, output, out) = run_on(&bytes, "truncated.ply", &[]);
    assert_fails_one_line(&out, DATA, &["truncated.ply"], &output);
}

#[test]
fn ply_without_normals_on_one_line() {
    // Normals are estimated for a cloud without them, but points on one line span no plane.
    let mut text = String::from(
        "ply\nformat ascii 1.0\nelement vertex 8\n\
         property float x\nproperty float y\nproperty float z\nend_header\n",
    );
    for i in 0..8 {
        text += &format!("{i} {} {}\n", 2 * i, 3 * i);
    }
    let (_dir, _input, output, out) = run_on(text.as_bytes(), "no-normals.ply", &[]);
    assert_fails(&out, DATA, &["no-normals.ply", "has no normals"], &output);
    let err = stderr(&out);
    assert_eq!(
        err.lines().count(),
        2,
        "the note and one error line:\n{err}"
    );
    assert!(
        err.lines().nth(1).unwrap().starts_with("spsr: error: "),
        "{err}"
    );
}

#[test]
fn two_points_are_too_few() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("two.ply");
    write_ascii_ply(&input, &sphere(2));
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["two.ply", "too few"], &output);
}

#[test]
fn zero_normals_leave_too_few_points() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("zero-normals.ply");
    let points: Vec<_> = sphere(10).into_iter().map(|(p, _)| (p, [0.0; 3])).collect();
    write_ascii_ply(&input, &points);
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["zero-normals.ply", "too few"], &output);
}

#[test]
fn all_points_identical() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("same.ply");
    let points: Vec<_> = sphere(50)
        .into_iter()
        .map(|(_, n)| ([1.0, 2.0, 3.0], n))
        .collect();
    write_ascii_ply(&input, &points);
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output)]);
    assert_fails_one_line(&out, DATA, &["same.ply", "degenerate"], &output);
}

// ---- bad usage: exit code 2, before any reading (the input does not even exist) ----

fn bad_parameter(extra: &[&str], fragment: &str) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("never-read.ply");
    let output = dir.path().join("out.ply");
    let mut args = vec!["reconstruct", s(&input), "-o", s(&output)];
    args.extend_from_slice(extra);
    let out = spsr(&args);
    assert_fails_one_line(&out, USAGE, &[fragment], &output);
    assert!(!stderr(&out).contains("never-read.ply"), "{}", stderr(&out));
}

#[test]
fn depth_beyond_max_depth() {
    bad_parameter(&["--depth", "40"], "--depth");
}

#[test]
fn negative_point_weight() {
    bad_parameter(&["--point-weight", "-1"], "--point-weight");
}

#[test]
fn negative_numbers_are_read_as_values_of_their_flag() {
    // Read as a flag of its own, `--width -1` was "unexpected argument '-1'", with advice
    // (`-- -1`) that does not work for an option's value.
    bad_parameter(&["--width", "-1"], "--width -1");
    let dir = TempDir::new().unwrap();
    let output = dir.path().join("out.ply");
    for (flag, value) in [
        ("--full-depth", "-1"),
        ("--max-memory", "-1"),
        ("--grid-res", "-4"),
        ("--threads", "-2"),
    ] {
        let out = spsr(&["reconstruct", "in.ply", "-o", s(&output), flag, value]);
        assert_fails(&out, USAGE, &[flag, &format!("'{value}'")], &output);
        assert!(!stderr(&out).contains("unexpected argument"), "{flag}");
    }
}

#[test]
fn zero_iters() {
    bad_parameter(&["--iters", "0"], "--iters");
}

#[test]
fn zero_samples_per_node() {
    bad_parameter(&["--samples-per-node", "0"], "--samples-per-node");
}

#[test]
fn explicit_full_depth_deeper_than_depth() {
    bad_parameter(&["--depth", "4", "--full-depth", "6"], "--full-depth");
}

#[test]
fn zero_threads() {
    let dir = TempDir::new().unwrap();
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", "in.ply", "-o", s(&output), "--threads", "0"]);
    assert_fails(&out, USAGE, &["--threads", "at least 1"], &output);
}

#[test]
fn output_in_missing_directory() {
    let (_dir, input) = sphere_dir();
    let output = Path::new("/nonexistent-dir/out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(output)]);
    assert_fails_one_line(&out, USAGE, &["/nonexistent-dir/out.ply"], output);
}

#[test]
fn output_path_is_checked_before_reading() {
    // A malformed input would exit with 1 if it were read first.
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("bad.xyz");
    fs::write(&input, "not a point cloud\n").unwrap();
    let output = Path::new("/nonexistent-dir/out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(output)]);
    assert_fails_one_line(&out, USAGE, &["/nonexistent-dir/out.ply"], output);
}

#[test]
fn output_equal_to_input() {
    let (dir, input) = sphere_dir();
    let before = fs::read(&input).unwrap();
    let out = spsr(&["reconstruct", s(&input), "-o", s(&input)]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(USAGE), "stderr:\n{err}");
    assert!(
        err.starts_with("spsr: error: ") && err.lines().count() == 1,
        "{err}"
    );
    assert!(err.contains("in.ply") && !err.contains("panicked"), "{err}");
    assert_eq!(fs::read(&input).unwrap(), before, "the input was changed");
    assert_eq!(entries(dir.path()), ["in.ply"]);
}

// ---- help and version ----

#[test]
fn help_lists_every_flag_with_its_default() {
    let out = spsr(&["reconstruct", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    for (flag, default) in [
        ("--output", ""),
        ("--depth", "[default: 8]"),
        ("--full-depth", "[default: 5"),
        ("--samples-per-node", "[default: 1.5]"),
        ("--point-weight", "[default: 2 × degree]"),
        ("--degree", "[default: 1]"),
        ("--boundary", "[default: neumann]"),
        ("--scale", "[default: 1.1]"),
        ("--iters", "[default: 8 for one cycle, 4 for more]"),
        ("--cycles", "[default: 2 at degree 1, 1 at degree 2]"),
        ("--confidence", "[default: off]"),
        ("--density", "[default: off]"),
        ("--threads", "[default: all cores]"),
        ("--ascii", "[default: off]"),
        ("--verbose", "[default: off]"),
    ] {
        // The flag's entry: from its line in the option list to the next option's line.
        let lines: Vec<&str> = help.lines().collect();
        let is_option = |l: &str| {
            let t = l.trim_start();
            t.starts_with('-') && l.len() - t.len() <= 6
        };
        let start = lines
            .iter()
            .position(|l| is_option(l) && l.split([' ', ',']).any(|w| w == flag))
            .unwrap_or_else(|| panic!("{flag} missing:\n{help}"));
        let end = (start + 1..lines.len())
            .find(|&i| is_option(lines[i]))
            .unwrap_or(lines.len());
        let entry = lines[start..end].join("\n");
        assert!(
            entry.contains(default),
            "{flag}: no {default:?} in\n{entry}"
        );
    }
    for needle in [
        "PoissonRecon 18",
        "2013 paper",
        "Exit codes",
        ".obj",
        ".stl",
        ".glb",
        "LAS or LAZ",
        "E57",
        "PCD",
        "nx ny nz",
    ] {
        assert!(help.contains(needle), "help lacks {needle:?}");
    }
}

#[test]
fn version() {
    let out = spsr(&["--version"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.starts_with("spsr ") && text.contains(env!("CARGO_PKG_VERSION")),
        "{text}"
    );
}

// ---- reconstructions (need the library) ----

/// The header of a PLY file, up to and including `end_header`.
fn ply_header(path: &Path) -> String {
    let bytes = fs::read(path).unwrap();
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .unwrap_or_else(|| panic!("{} has no end_header", path.display()));
    String::from_utf8(bytes[..end + 10].to_vec()).unwrap()
}

fn element_count(header: &str, element: &str) -> usize {
    let prefix = format!("element {element} ");
    header
        .lines()
        .find_map(|l| l.strip_prefix(&prefix))
        .unwrap_or_else(|| panic!("no {prefix:?} in\n{header}"))
        .trim()
        .parse()
        .unwrap()
}

fn reconstruct_sphere(out_name: &str, extra: &[&str]) -> (TempDir, PathBuf, Output) {
    let (dir, input) = sphere_dir();
    let output = dir.path().join(out_name);
    let mut args = vec!["reconstruct", s(&input), "-o", s(&output), "--depth", "5"];
    args.extend_from_slice(extra);
    let out = spsr(&args);
    assert!(out.status.success(), "spsr failed:\n{}", stderr(&out));
    let err = stderr(&out);
    assert!(!err.contains("warning"), "{err}");
    // stderr is a pipe here, not a terminal: no progress line.
    assert!(!err.contains('\r'), "{err:?}");
    (dir, output, out)
}

#[test]
fn sphere_gives_binary_ply_with_faces() {
    let (dir, output, _) = reconstruct_sphere("out.ply", &[]);
    let header = ply_header(&output);
    assert!(
        header.contains("format binary_little_endian 1.0"),
        "{header}"
    );
    assert!(element_count(&header, "vertex") > 0);
    assert!(element_count(&header, "face") > 0);
    assert!(!header.contains("density"), "{header}");
    assert_eq!(entries(dir.path()), ["in.ply", "out.ply"], "stray files");
}

#[test]
fn ascii_flag_writes_ascii_ply() {
    let (_dir, output, _) = reconstruct_sphere("out.ply", &["--ascii"]);
    let header = ply_header(&output);
    assert!(header.contains("format ascii 1.0"), "{header}");
    assert!(element_count(&header, "face") > 0);
}

#[test]
fn obj_extension_writes_obj() {
    let (_dir, output, _) = reconstruct_sphere("out.obj", &[]);
    let text = fs::read_to_string(&output).unwrap();
    assert!(text.lines().any(|l| l.starts_with("v ")), "no vertices");
    assert!(text.lines().any(|l| l.starts_with("f ")), "no faces");
    assert!(!text.starts_with("ply"));
}

#[test]
fn stl_and_glb_extensions_write_stl_and_glb() {
    let (_dir, output, _) = reconstruct_sphere("out.stl", &[]);
    let bytes = fs::read(&output).unwrap();
    let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
    assert!(n > 0 && bytes.len() == 84 + 50 * n, "binary STL");
    let (_dir, output, _) = reconstruct_sphere("out.stl", &["--ascii"]);
    assert!(fs::read_to_string(&output).unwrap().starts_with("solid"));
    let (_dir, output, _) = reconstruct_sphere("out.glb", &[]);
    assert!(fs::read(&output).unwrap().starts_with(b"glTF"));
}

#[test]
fn text_and_pcd_inputs_are_recognised() {
    let points = sphere(3000);
    let dir = TempDir::new().unwrap();
    let mut text = String::new();
    for (p, n) in &points {
        text += &format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]);
    }
    let xyz = dir.path().join("in.xyz");
    fs::write(&xyz, &text).unwrap();
    let pcd = dir.path().join("in.pcd");
    let head = format!(
        "VERSION .7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\n\
         TYPE F F F F F F\nWIDTH {}\nDATA ascii\n",
        points.len()
    );
    fs::write(&pcd, head + &text).unwrap();
    for input in [&xyz, &pcd] {
        let output = dir.path().join("out.ply");
        let out = spsr(&["reconstruct", s(input), "-o", s(&output), "--depth", "5"]);
        assert!(
            out.status.success(),
            "{}: {}",
            input.display(),
            stderr(&out)
        );
        assert!(element_count(&ply_header(&output), "face") > 0);
    }
}

#[test]
fn density_flag_adds_density_property() {
    let (_dir, output, _) = reconstruct_sphere("out.ply", &["--density"]);
    let header = ply_header(&output);
    assert!(header.contains("property float density"), "{header}");
}

#[test]
fn verbose_prints_statistics() {
    let (_dir, output, out) = reconstruct_sphere("out.ply", &["-v", "--threads", "2"]);
    let err = stderr(&out);
    for needle in [
        "iso-value",
        "samples",
        "octree",
        "vertices",
        "faces",
        "total",
    ] {
        assert!(err.contains(needle), "no {needle:?} in\n{err}");
    }
    assert!(err.contains(s(&output)), "{err}");
    // The residuals cost a sweep per relaxation: -v times a plain run, without them.
    assert!(!err.contains("relative residual"), "{err}");
}

#[test]
fn residuals_are_measured_on_request_and_leave_the_mesh_alone() {
    let (_dir, plain, _) = reconstruct_sphere("plain.ply", &["--full-depth", "3"]);
    let (_dir2, measured, out) =
        reconstruct_sphere("measured.ply", &["--residuals", "--full-depth", "3"]);
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    let line = err
        .lines()
        .find(|l| l.contains("relative residual per depth"))
        .unwrap_or_else(|| panic!("no residual report in\n{err}"));
    assert!(line.starts_with("solver      cascadic"), "{line}");
    // The whole system's residual after each of the two degree-1 cycles, each below 1.
    let after: Vec<f64> = err
        .lines()
        .filter_map(|l| l.split("whole system after cycle ").nth(1))
        .map(|r| {
            r.split(':')
                .nth(1)
                .unwrap()
                .split_whitespace()
                .next()
                .unwrap()
                .parse()
                .unwrap()
        })
        .collect();
    assert_eq!(after.len(), 2, "{err}");
    assert!(after.iter().all(|&r| r > 0.0 && r < 1.0), "{after:?}");
    assert_eq!(fs::read(plain).unwrap(), fs::read(measured).unwrap());
}

#[test]
fn text_input_is_read() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("in.xyz");
    let text: String = sphere(3000)
        .iter()
        .map(|(p, n)| format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]))
        .collect();
    fs::write(&input, text).unwrap();
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output), "--depth", "5"]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(element_count(&ply_header(&output), "face") > 0);
}

#[test]
fn dropped_points_are_reported() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("some-zero.ply");
    let mut points = sphere(3000);
    for p in points.iter_mut().take(7) {
        p.1 = [0.0; 3];
    }
    write_ascii_ply(&input, &points);
    let output = dir.path().join("out.ply");
    let out = spsr(&["reconstruct", s(&input), "-o", s(&output), "--depth", "5"]);
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("warning: ") && err.contains("some-zero.ply: 7 of 3000 points dropped"),
        "{err}"
    );
}

#[test]
fn run_over_the_memory_limit_exits_3_and_suggests_a_depth() {
    let (dir, input) = sphere_dir();
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--depth",
        "10",
        "--max-memory",
        "2M",
    ]);
    assert_fails_one_line(&out, 3, &["--depth", "--max-memory", "GiB"], &output);
}

#[test]
fn max_memory_needs_a_size() {
    let (dir, input) = sphere_dir();
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--max-memory",
        "lots",
    ]);
    assert_fails(&out, 2, &["512M"], &output);
}

#[test]
fn output_files_are_byte_identical_for_1_2_and_7_threads() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("in.ply");
    write_ascii_ply(&input, &sphere(20_000));
    for degree in ["1", "2"] {
        let mut files = Vec::new();
        for threads in ["1", "2", "7"] {
            let out = dir.path().join(format!("d{degree}-t{threads}.ply"));
            let run = spsr(&[
                "reconstruct",
                s(&input),
                "-o",
                s(&out),
                "--depth",
                "7",
                "--degree",
                degree,
                "--density",
                "--threads",
                threads,
            ]);
            assert!(run.status.success(), "{}", stderr(&run));
            files.push(fs::read(&out).unwrap());
        }
        assert!(files[0].len() > 1000);
        assert!(
            files[0] == files[1],
            "degree {degree}: 2 threads differ from 1"
        );
        assert!(
            files[0] == files[2],
            "degree {degree}: 7 threads differ from 1"
        );
    }
}

#[test]
fn colours_normals_and_confidence_reach_the_output() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("coloured.ply");
    let points = sphere(20_000);
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         property float quality\nend_header\n",
        points.len()
    );
    for (p, n) in &points {
        let red = if p[0] > 1.0 { 255 } else { 0 };
        text += &format!(
            "{} {} {} {} {} {} {red} 0 {} 1\n",
            p[0],
            p[1],
            p[2],
            n[0],
            n[1],
            n[2],
            255 - red
        );
    }
    fs::write(&input, text).unwrap();
    let out = dir.path().join("mesh.ply");
    let run = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&out),
        "--depth",
        "6",
        "--normals",
        "--confidence-property",
        "quality",
        "--ascii",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let mesh = spsr_read_mesh(&out);
    assert!(mesh.normals.is_some(), "normals written");
    let red = mesh
        .attributes
        .iter()
        .find(|a| a.name == "red")
        .expect("red kept");
    assert_eq!(red.data.scalar_type(), spsr::attributes::ScalarType::U8);
    let header = fs::read_to_string(&out).unwrap();
    for prop in [
        "property float nx",
        "property uchar red",
        "property uchar blue",
        "property float quality",
    ] {
        assert!(header.contains(prop), "missing {prop}");
    }
    // Without attributes the mesh has only its geometry; a missing property is refused.
    let plain = dir.path().join("plain.ply");
    let run = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&plain),
        "--depth",
        "5",
        "--no-attributes",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(spsr_read_mesh(&plain).attributes.is_empty());
    let bad = dir.path().join("bad.ply");
    let run = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&bad),
        "--confidence-property",
        "weight",
    ]);
    assert_fails(
        &run,
        USAGE,
        &["--confidence-property", "weight", "quality"],
        &bad,
    );
}

fn spsr_read_mesh(path: &Path) -> spsr::Mesh {
    spsr::io::read_mesh(path).unwrap()
}

// ---- the depth from a width or from the data (issue 18) ----

/// The `spsr: note:` line of a successful run.
fn the_note(out: &Output) -> String {
    let err = stderr(out);
    assert!(out.status.success(), "{err}");
    let notes: Vec<&str> = err.lines().filter(|l| l.contains("note:")).collect();
    assert_eq!(notes.len(), 1, "{err}");
    notes[0].to_string()
}

#[test]
fn width_lands_on_the_depth_it_implies() {
    let (dir, input) = sphere_dir();
    let output = dir.path().join("out.ply");
    // The sphere's box is 1.6 wide, its cube 1.76: 0.05-wide cells need 35.2, so 2^6.
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--width",
        "0.05",
        "-v",
    ]);
    let note = the_note(&out);
    assert!(note.contains("--width 0.05000 gives --depth 6"), "{note}");
    // The octree's levels run from 0 to 6.
    let err = stderr(&out);
    let levels = err.lines().skip_while(|l| !l.starts_with("octree")).skip(1);
    let last = levels.take_while(|l| l.starts_with("  ")).last().unwrap();
    assert_eq!(last.split_whitespace().next(), Some("6"), "{err}");
}

#[test]
fn depth_and_width_together_are_a_usage_error() {
    let (dir, input) = sphere_dir();
    let output = dir.path().join("out.ply");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--width",
        "0.05",
        "--depth",
        "7",
    ]);
    assert_fails(&out, USAGE, &["--width", "--depth"], &output);
    bad_parameter(&["--width", "0"], "--width");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--depth",
        "deep",
    ]);
    assert_fails(&out, USAGE, &["'deep'", "auto"], &output);
}

#[test]
fn depth_auto_says_which_depth_and_goes_deeper_for_denser_points() {
    let depth = |n: usize| {
        let dir = TempDir::new().unwrap();
        let input = dir.path().join("in.ply");
        write_ascii_ply(&input, &sphere(n));
        let output = dir.path().join("out.ply");
        let out = spsr(&[
            "reconstruct",
            s(&input),
            "-o",
            s(&output),
            "--depth",
            "auto",
        ]);
        let note = the_note(&out);
        let chose = note.split("chose --depth ").nth(1).expect(&note);
        assert!(note.contains("apart"), "{note}");
        chose.split(':').next().unwrap().parse::<u32>().unwrap()
    };
    assert!(depth(8000) > depth(2000));
}

#[test]
fn grid_writes_a_numpy_archive_and_bad_resolutions_are_refused() {
    let (dir, input) = sphere_dir();
    let output = dir.path().join("out.ply");
    let grid = dir.path().join("g.npz");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--depth",
        "5",
        "--grid",
        s(&grid),
        "--grid-res",
        "6",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let bytes = fs::read(&grid).unwrap();
    assert_eq!(&bytes[..4], b"PK\x03\x04");
    assert_eq!(&bytes[30..40], b"values.npy");
    for (res, fragment) in [("1", "at least 2"), ("5000", "at most")] {
        let g = dir.path().join("bad.npz");
        let out = spsr(&[
            "reconstruct",
            s(&input),
            "-o",
            s(&output),
            "--grid",
            s(&g),
            "--grid-res",
            res,
            "--max-memory",
            "1G",
        ]);
        assert_fails_one_line(&out, USAGE, &["--grid-res", fragment], &g);
    }
    // Each flag needs the other.
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&output),
        "--grid",
        s(&grid),
    ]);
    assert_eq!(out.status.code(), Some(USAGE));
}
