//! What `spsr reconstruct` tells its user: the summary line, the warnings on a likely useless
//! result (with the flag that helps), `-v`'s parameters and their sources, silence off a
//! terminal, and PoissonRecon's spellings.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use tempfile::TempDir;

use crate::common::*;

/// Writes points and normals as a binary little-endian PLY.
fn write_ply(path: &Path, points: &[([f64; 3], [f64; 3])]) {
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        points.len()
    )
    .into_bytes();
    for (p, n) in points {
        for v in p.iter().chain(n) {
            bytes.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    fs::write(path, bytes).unwrap();
}

/// Runs `spsr reconstruct` on `points` (written as `in.ply`) with `args`, where `IN` and
/// `OUT` stand for the input and output paths.
fn run(points: &[([f64; 3], [f64; 3])], args: &[&str]) -> (TempDir, PathBuf, Output) {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("in.ply");
    write_ply(&input, points);
    let output = dir.path().join("out.ply");
    let args: Vec<&str> = args
        .iter()
        .map(|&a| match a {
            "IN" => s(&input),
            "OUT" => s(&output),
            a => a,
        })
        .collect();
    let out = spsr(&args);
    (dir, output, out)
}

/// The one `spsr: warning:` line of stderr.
fn the_warning(out: &Output) -> String {
    let err = stderr(out);
    assert!(out.status.success(), "{err}");
    let warnings: Vec<&str> = err.lines().filter(|l| l.contains("warning:")).collect();
    assert_eq!(warnings.len(), 1, "{err}");
    warnings[0].to_string()
}

#[test]
fn the_summary_gives_pieces_closedness_and_memory_and_nothing_else_is_printed() {
    let (_dir, output, out) = run(
        &sphere(3000),
        &["reconstruct", "IN", "-o", "OUT", "--depth", "5"],
    );
    assert!(out.status.success(), "{}", stderr(&out));
    // stderr is not a terminal here: no progress bar, no warning, nothing.
    assert_eq!(stderr(&out), "");
    let line = stdout(&out);
    let prefix = format!("spsr: wrote {}: ", s(&output));
    assert!(line.starts_with(&prefix), "{line}");
    assert!(
        line.contains(" vertices, ") && line.contains(" faces, 1 piece, closed, in "),
        "{line}"
    );
    if cfg!(target_os = "linux") {
        assert!(
            line.contains(", peak memory ") && line.trim_end().ends_with(" MiB"),
            "{line}"
        );
    }
}

#[test]
fn verbose_first_echoes_every_parameter_with_its_source() {
    let (_dir, _, out) = run(
        &sphere(3000),
        &[
            "reconstruct",
            "IN",
            "-o",
            "OUT",
            "--depth",
            "4",
            "--scale",
            "1.1",
            "-v",
            "--threads",
            "2",
        ],
    );
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    let row = |flag: &str| {
        err.lines()
            .find(|l| l.split_whitespace().next() == Some(flag))
            .unwrap_or_else(|| panic!("no {flag} in\n{err}"))
            .split_whitespace()
            .skip(1)
            .collect::<Vec<_>>()
            .join(" ")
    };
    assert_eq!(row("--depth"), "4 flag");
    // Given with its default value, still given.
    assert_eq!(row("--scale"), "1.1 flag");
    assert_eq!(row("--samples-per-node"), "1.5 default");
    assert_eq!(row("--full-depth"), "4 derived: no deeper than --depth");
    assert_eq!(row("--point-weight"), "2 derived: 2 × --degree");
    assert_eq!(row("--boundary"), "neumann default");
    assert_eq!(row("--threads"), "2 flag");
    assert!(row("--max-memory").contains("derived: the memory available"));
    assert_eq!(row("--noise"), "adaptive default");
    assert_eq!(
        row("--orient"),
        "mst derived: viewpoint instead when the file records scan positions"
    );
    assert_eq!(
        row("--neighbours"),
        "auto derived: from the noise, 16 to 192"
    );
    for flag in [
        "--degree",
        "--iters",
        "--confidence",
        "--normals",
        "--density",
        "--trim",
        "--linear-fit",
        "--two-level-splat",
        "--data-pull",
        "--no-attributes",
        "--keep-outliers",
        "--keep-normals",
        "--ascii",
        "--estimate-normals",
        "--viewpoint",
        "--preview",
    ] {
        row(flag);
    }
    // The parameters come before the per-stage table.
    let params = err.find("parameters:").unwrap();
    assert!(params < err.find("timings:").unwrap(), "{err}");
    assert!(err.contains("check       1 pieces, closed"), "{err}");
}

/// Tuning the samples per node by hand turns the noise adaptation off, and `-v` says why.
#[test]
fn verbose_says_why_the_noise_adaptation_is_off() {
    let (_dir, _, out) = run(
        &sphere(3000),
        &[
            "reconstruct",
            "IN",
            "-o",
            "OUT",
            "--depth",
            "4",
            "--samples-per-node",
            "3",
            "-v",
        ],
    );
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    let row = |flag: &str| {
        err.lines()
            .find(|l| l.split_whitespace().next() == Some(flag))
            .unwrap_or_else(|| panic!("no {flag} in\n{err}"))
            .split_whitespace()
            .skip(1)
            .collect::<Vec<_>>()
            .join(" ")
    };
    assert_eq!(
        row("--noise"),
        "off derived: --samples-per-node or --point-weight given"
    );
    assert_eq!(row("--samples-per-node"), "3 flag");
}

#[test]
fn normals_flipped_in_places_warn_with_the_flags_that_help() {
    let points: Vec<_> = sphere(20_000)
        .into_iter()
        .map(|(p, n)| {
            if n[2] > 0.3 {
                (p, n.map(|c| -c))
            } else {
                (p, n)
            }
        })
        .collect();
    let (_dir, _, out) = run(&points, &["reconstruct", "IN", "-o", "OUT", "--depth", "7"]);
    let w = the_warning(&out);
    assert!(
        w.contains("in.ply: the surface runs on to the bounding cube")
            && w.contains("--estimate-normals")
            && w.contains("--trim auto"),
        "{w}"
    );
    assert!(stdout(&out).contains(", open ("), "{}", stdout(&out));
}

#[test]
fn contradictory_normals_warn_with_the_flag_that_helps() {
    let points: Vec<_> = sphere(20_000)
        .into_iter()
        .enumerate()
        .map(|(i, (p, n))| {
            if i % 4 == 0 {
                (p, n.map(|c| -c))
            } else {
                (p, n)
            }
        })
        .collect();
    let (_dir, _, out) = run(
        &points,
        &[
            "reconstruct",
            "IN",
            "-o",
            "OUT",
            "--noise",
            "off",
            "--keep-normals",
            "--depth",
            "7",
        ],
    );
    let w = the_warning(&out);
    assert!(
        w.contains("normals pointing into the reconstructed solid")
            && w.contains("--estimate-normals"),
        "{w}"
    );
}

#[test]
fn noise_warns_of_many_pieces_with_the_flags_that_help() {
    // Radial noise of 4 % of the radius, normals perturbed: bubbles at depth 7.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut uniform = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut gauss = || {
        let u = uniform().max(1e-300);
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * uniform()).cos()
    };
    let points: Vec<_> = sphere(30_000)
        .into_iter()
        .map(|(p, n)| {
            let r = 1.0 + 0.04 * gauss();
            let p = std::array::from_fn(|a| CENTRE[a] + r * (p[a] - CENTRE[a]));
            let m: [f64; 3] = std::array::from_fn(|a| n[a] + 0.2 * gauss());
            let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
            (p, m.map(|c| c / l))
        })
        .collect();
    let (_dir, _, out) = run(
        &points,
        &[
            "reconstruct",
            "IN",
            "-o",
            "OUT",
            "--noise",
            "off",
            "--keep-normals",
            "--depth",
            "7",
        ],
    );
    let w = the_warning(&out);
    assert!(
        w.contains("pieces: the points are likely noisy")
            && w.contains("--samples-per-node 5 to 10")
            && w.contains("--depth 6"),
        "{w}"
    );
}

#[test]
fn a_poissonrecon_command_line_runs_unchanged() {
    let (_dir, output, out) = run(
        &sphere(3000),
        &[
            "reconstruct",
            "--in",
            "IN",
            "--out",
            "OUT",
            "--depth",
            "5",
            "--degree",
            "2",
            "--bType",
            "2",
            "--samplesPerNode",
            "2",
            "--pointWeight",
            "3",
            "--fullDepth",
            "3",
            "--linearFit",
            "--colors",
            "--data",
            "16",
            "--density",
            "--iters",
            "8",
            "--scale",
            "1.1",
            "--confidence",
            "--maxMemory",
            "4",
            "--threads",
            "2",
            "--verbose",
            "--showResidual",
        ],
    );
    let err = stderr(&out);
    assert!(out.status.success(), "{err}");
    assert!(output.exists());
    assert!(err.contains("relative residual per depth"), "{err}");
    for row in [
        "--boundary             dirichlet    flag",
        "--samples-per-node     2            flag",
        "--point-weight         3            flag",
        "--full-depth           3            flag",
        "--linear-fit           on           flag",
        "--data-pull            16           flag",
        "--max-memory           4.00 GiB     flag",
        "--degree               2            flag",
        "--residuals            on           flag",
    ] {
        assert!(err.contains(row), "no {row:?} in\n{err}");
    }
}

#[test]
fn an_unsupported_poissonrecon_option_is_named_not_guessed() {
    let dir = TempDir::new().unwrap();
    let output = dir.path().join("out.ply");
    for (flag, instead) in [
        ("--tempDir", "spsr always works in memory"),
        ("--polygonMesh", "triangles only"),
        ("--gradients", "use --normals"),
        ("--cgDepth=3", "--full-depth"),
    ] {
        let out = spsr(&["reconstruct", "--in", "in.ply", "--out", s(&output), flag]);
        let name = flag.split('=').next().unwrap();
        assert_fails(
            &out,
            USAGE,
            &[
                &format!("{name} is a PoissonRecon option that spsr reconstruct does not support"),
                instead,
            ],
            &output,
        );
        assert!(!stderr(&out).contains("similar"), "{}", stderr(&out));
    }
    // Bad reference values are clap's usage errors too.
    let out = spsr(&["reconstruct", "in.ply", "-o", s(&output), "--bType", "4"]);
    assert_fails(
        &out,
        USAGE,
        &["1 (free), 2 (Dirichlet) or 3 (Neumann)"],
        &output,
    );
    let out = spsr(&[
        "reconstruct",
        "in.ply",
        "-o",
        s(&output),
        "--bType",
        "2",
        "--boundary",
        "free",
    ]);
    assert_fails(&out, USAGE, &["cannot be used with"], &output);
}
