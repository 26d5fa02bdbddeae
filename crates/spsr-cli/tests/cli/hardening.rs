//! Issue 7 at the command line: standard input and output (`-`), the exit codes of each kind
//! of failure with messages that name the file and the place, and interruption (no partial
//! output, an existing output kept).

use std::fs;
use std::io::Write;
use std::process::{Command, Output, Stdio};

use tempfile::TempDir;

use crate::common::*;

/// Runs spsr with `input` on standard input.
fn with_stdin(args: &[&str], input: &[u8]) -> Output {
    let mut child = bin()
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let data = input.to_vec();
    let feeder = std::thread::spawn(move || {
        let _ = stdin.write_all(&data);
    });
    let out = child.wait_with_output().unwrap();
    feeder.join().unwrap();
    out
}

/// An ASCII PLY cloud of `n` points on the unit sphere (Fibonacci lattice).
fn sphere_ply(n: usize) -> Vec<u8> {
    let mut t = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty double x\nproperty double y\n\
         property double z\nproperty double nx\nproperty double ny\nproperty double nz\n\
         end_header\n"
    );
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let (x, y) = (r * (golden * i as f64).cos(), r * (golden * i as f64).sin());
        t += &format!("{x} {y} {z} {x} {y} {z}\n");
    }
    t.into_bytes()
}

fn element_count(ply: &[u8], element: &str) -> usize {
    let text = String::from_utf8_lossy(&ply[..ply.len().min(4096)]).into_owned();
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("element {element} ")))
        .and_then(|n| n.trim().parse().ok())
        .unwrap_or_else(|| panic!("no element {element}"))
}

#[test]
fn reconstruct_reads_stdin_and_writes_stdout() {
    let out = with_stdin(
        &["reconstruct", "-", "-o", "-", "--depth", "5"],
        &sphere_ply(2000),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(out.stdout.starts_with(b"ply\nformat binary_little_endian"));
    assert!(element_count(&out.stdout, "face") > 100);
    // The summary goes to stderr, so stdout holds only the mesh.
    assert!(
        stderr(&out).contains("spsr: wrote <stdout>"),
        "{}",
        stderr(&out)
    );

    // And the mesh from stdout trims through stdin and stdout too (ASCII this time).
    let dir = TempDir::new().unwrap();
    let meshed = with_stdin(
        &[
            "reconstruct",
            "-",
            "-o",
            "-",
            "--depth",
            "5",
            "--density",
            "--ascii",
        ],
        &sphere_ply(2000),
    );
    assert!(meshed.status.success());
    let trimmed = with_stdin(&["trim", "-", "--trim", "auto", "-o", "-"], &meshed.stdout);
    assert!(trimmed.status.success(), "{}", stderr(&trimmed));
    assert!(trimmed.stdout.starts_with(b"ply\n"));
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn errors_on_stdin_name_it_and_exit_1() {
    let out = with_stdin(
        &["reconstruct", "-", "-o", "-"],
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
          property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
          end_header\n0 0 0 0 0 1\n0 0 zero 0 0 1\n",
    );
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(out.stdout.is_empty());
    assert!(
        err.starts_with("spsr: error: <stdin>: ") && err.contains("line 12"),
        "{err}"
    );
}

#[test]
fn each_exit_code_with_a_message_that_says_what_to_do() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("cloud.ply");
    fs::write(&input, sphere_ply(3000)).unwrap();
    let output = dir.path().join("mesh.ply");
    let run = |extra: &[&str]| {
        let mut args = vec!["reconstruct", s(&input), "-o", s(&output)];
        args.extend_from_slice(extra);
        bin().args(&args).output().unwrap()
    };
    // 0: success; -v reports the memory estimate.
    let ok = run(&["--depth", "8", "-v"]);
    assert_eq!(ok.status.code(), Some(0));
    fs::remove_file(&output).unwrap();
    let estimate_mib: u64 = stderr(&ok)
        .lines()
        .find_map(|l| {
            l.strip_prefix("memory")?
                .trim()
                .split(' ')
                .next()?
                .parse()
                .ok()
        })
        .expect("-v prints the memory estimate");
    // 1: bad data, naming the file and the element.
    let bad = dir.path().join("bad.ply");
    fs::write(
        &bad,
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
          property float y\nproperty float z\nproperty float nx\nproperty float ny\n\
          property float nz\nend_header\n\0\0\0\0",
    )
    .unwrap();
    let out = bin()
        .args(["reconstruct", s(&bad), "-o", s(&output)])
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("bad.ply: ") && err.contains("vertex") && err.contains("record 0"),
        "{err}"
    );
    // 2: bad usage, naming the flag and what is allowed.
    let out = run(&["--depth", "0"]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--depth") && err.contains("from 1 to 18"),
        "{err}"
    );
    // 3: a resource limit, with the estimate and a depth that fits.
    let limit = format!("{}M", estimate_mib - 2);
    let out = run(&["--depth", "8", "--max-memory", &limit]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("GiB") && err.contains("use --depth") && err.contains("--max-memory"),
        "{err}"
    );
    let out = run(&["--depth", "8", "--max-memory", "1M"]);
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("even the coarsest depth does not fit"),
        "{err}"
    );
    assert!(!output.exists());
}

/// Ctrl-C (SIGINT) while a reconstruction runs: exit code 130, the previous output intact,
/// no temporary file left. Whether the signal lands while computing or while writing
/// depends on the machine's speed; both must end the same way (or, on a machine fast
/// enough to finish first, with a complete new output).
#[cfg(unix)]
#[test]
fn interrupting_leaves_the_previous_output_and_no_temporary_file() {
    let dir = TempDir::new().unwrap();
    let input = dir.path().join("cloud.ply");
    fs::write(&input, sphere_ply(100_000)).unwrap();
    let output = dir.path().join("mesh.ply");
    fs::write(&output, b"previous output").unwrap();
    for delay_ms in [300, 1500] {
        let child = bin()
            .args([
                "reconstruct",
                s(&input),
                "-o",
                s(&output),
                "--depth",
                "9",
                "--ascii",
            ])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status();
        let out = child.wait_with_output().unwrap();
        let mut names: Vec<String> = fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["cloud.ply", "mesh.ply"], "{}", stderr(&out));
        match out.status.code() {
            Some(130) => {
                assert_eq!(fs::read(&output).unwrap(), b"previous output");
                assert!(stderr(&out).contains("spsr: interrupted"));
            }
            Some(0) => {
                assert!(fs::read(&output).unwrap().starts_with(b"ply\n"));
                fs::write(&output, b"previous output").unwrap();
            }
            other => panic!("exit {other:?}: {}", stderr(&out)),
        }
    }
}
