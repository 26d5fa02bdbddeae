//! Helpers shared by the command-line tests: running the binary, reading its output, the
//! checks of a clean failure, and a sphere cloud with exact normals.
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

/// Exit code of bad input data.
pub const DATA: i32 = 1;
/// Exit code of bad usage.
pub const USAGE: i32 = 2;

/// The `spsr` binary, not yet run.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_spsr"))
}

/// Runs `spsr` with `args`.
pub fn spsr(args: &[&str]) -> Output {
    bin().args(args).output().expect("the spsr binary runs")
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

pub fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

pub fn s(p: &Path) -> &str {
    p.to_str().expect("temporary paths are UTF-8")
}

/// Asserts a clean failure: the exit code, the fragments in stderr, no panic, and no output
/// file.
pub fn assert_fails(out: &Output, code: i32, fragments: &[&str], output: &Path) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(code), "exit code; stderr:\n{err}");
    assert!(!err.contains("panicked"), "panic:\n{err}");
    for f in fragments {
        assert!(err.contains(f), "stderr lacks {f:?}:\n{err}");
    }
    assert!(!output.exists(), "{} was left behind", output.display());
}

/// As [`assert_fails`], for errors reported by spsr itself (not clap): exactly one
/// `spsr: error:` line.
pub fn assert_fails_one_line(out: &Output, code: i32, fragments: &[&str], output: &Path) {
    assert_fails(out, code, fragments, output);
    let err = stderr(out);
    assert!(err.starts_with("spsr: error: "), "stderr:\n{err}");
    assert_eq!(err.lines().count(), 1, "more than one line:\n{err}");
}

/// Centre of the test sphere.
pub const CENTRE: [f64; 3] = [1.0, 2.0, 3.0];

/// Points on a sphere of radius 0.8 around [`CENTRE`], with exact outward normals
/// (Fibonacci lattice, so the sampling is even).
pub fn sphere(n: usize) -> Vec<([f64; 3], [f64; 3])> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            let nrm = [r * phi.cos(), r * phi.sin(), z];
            let pos = std::array::from_fn(|a| CENTRE[a] + 0.8 * nrm[a]);
            (pos, nrm)
        })
        .collect()
}
