//! `spsr reconstruct --slabs` and several inputs (tiles): one seamless mesh that matches the
//! run in one piece, and clean failures that leave no output and no spill files.

use std::fs;
use std::path::Path;

use crate::common::{assert_fails, s, sphere, spsr, stderr, stdout, USAGE};

/// Exit code of a resource limit (memory, a full disk).
const RESOURCE: i32 = 3;

/// Writes points as `x y z nx ny nz` lines.
fn write_xyz(path: &Path, points: &[([f64; 3], [f64; 3])]) {
    let text: String = points
        .iter()
        .map(|(p, n)| format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]))
        .collect();
    fs::write(path, text).unwrap();
}

/// The sphere in one file and in two tiles (split unevenly, so the tiles are not slabs).
fn sphere_files(dir: &Path) -> (String, String, String) {
    let pts = sphere(20_000);
    let whole = dir.join("whole.xyz");
    let a = dir.join("a.xyz");
    let b = dir.join("b.xyz");
    write_xyz(&whole, &pts);
    write_xyz(&a, &pts[..7_000]);
    write_xyz(&b, &pts[7_000..]);
    (s(&whole).into(), s(&a).into(), s(&b).into())
}

/// The JSON number after `"key": ` in `spsr eval --json`'s output.
fn json_number(json: &str, key: &str) -> f64 {
    let at = json.find(&format!("\"{key}\": ")).expect(key) + key.len() + 4;
    let end = json[at..].find([',', '}']).unwrap() + at;
    json[at..end].trim().parse().unwrap()
}

#[test]
fn tiles_are_one_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, a, b) = sphere_files(dir.path());
    let one = dir.path().join("one.ply");
    let two = dir.path().join("two.ply");
    for (inputs, out) in [(vec![whole.as_str()], &one), (vec![&a, &b], &two)] {
        let mut args = vec!["reconstruct"];
        args.extend(inputs);
        args.extend(["-o", s(out), "--depth", "6"]);
        let run = spsr(&args);
        assert!(run.status.success(), "{}", stderr(&run));
    }
    assert_eq!(fs::read(&one).unwrap(), fs::read(&two).unwrap());
}

#[test]
fn a_warning_about_tiles_names_them_all() {
    // A point with no usable position in the second tile: the warning about the dropped
    // point is about the whole cloud, so it names the first tile and how many more.
    let dir = tempfile::tempdir().unwrap();
    let (_, a, b) = sphere_files(dir.path());
    let mut text = fs::read_to_string(&b).unwrap();
    text.push_str("nan 0 0 0 0 1\n");
    fs::write(&b, text).unwrap();
    let out = dir.path().join("out.ply");
    for slabs in ["auto", "1", "2"] {
        let run = spsr(&[
            "reconstruct",
            &a,
            &b,
            "-o",
            s(&out),
            "--depth",
            "6",
            "--slabs",
            slabs,
        ]);
        assert!(run.status.success(), "{}", stderr(&run));
        let said = stderr(&run);
        let line = said
            .lines()
            .find(|l| l.starts_with("spsr: warning:") && l.contains("1 of"))
            .unwrap_or_else(|| panic!("no warning of the dropped point: {said}"));
        assert!(
            line.starts_with(&format!("spsr: warning: {a} and 1 more file: ")),
            "{line}"
        );
    }
}

#[test]
fn slabs_give_the_mesh_of_one_piece() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, a, b) = sphere_files(dir.path());
    let work = dir.path().join("work");
    fs::create_dir(&work).unwrap();
    let one = dir.path().join("one.ply");
    let run = spsr(&["reconstruct", &whole, "-o", s(&one), "--depth", "7"]);
    assert!(run.status.success(), "{}", stderr(&run));
    for k in ["2", "4"] {
        let sl = dir.path().join(format!("slabs{k}.ply"));
        let run = spsr(&[
            "reconstruct",
            &a,
            &b,
            "-o",
            s(&sl),
            "--depth",
            "7",
            "--slabs",
            k,
            "--work-dir",
            s(&work),
        ]);
        assert!(run.status.success(), "{}", stderr(&run));
        let said = stdout(&run) + &stderr(&run);
        assert!(said.contains("1 piece, closed"), "{said}");
        let eval = spsr(&["eval", s(&sl), "--reference", s(&one), "--json"]);
        assert!(eval.status.success(), "{}", stderr(&eval));
        let json = stdout(&eval);
        // The finest cell is 1.1 × 1.6 / 128 of the bounding box; the slabs' mesh is within a
        // small fraction of it everywhere.
        let cell = 1.1 * 1.6 / 128.0;
        assert!(json_number(&json, "hausdorff") < 0.1 * cell, "{json}");
        assert_eq!(json_number(&json, "components"), 1.0, "{json}");
        assert!(json.contains("\"closed\": true"), "{json}");
        assert_eq!(fs::read_dir(&work).unwrap().count(), 0, "spill files left");
        // The same header as in one piece: `float` coordinates near the origin.
        assert_eq!(ply_header(&sl), ply_header(&one));
    }
}

/// The header of a PLY file, less its counts (the lines up to `end_header`, `element` lines
/// cut after the name).
fn ply_header(path: &Path) -> Vec<String> {
    let bytes = fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("a PLY header");
    String::from_utf8_lossy(&bytes[..end])
        .lines()
        .map(|l| {
            l.split(' ')
                .take(if l.starts_with("element") { 2 } else { 9 })
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect()
}

#[test]
fn slabs_far_from_the_origin_keep_double_coordinates_as_one_piece_does() {
    let dir = tempfile::tempdir().unwrap();
    // A sphere of radius 1.6 moved 1e6 away, as georeferenced lidar is: f32 would lose more
    // than a millionth of its size.
    let pts: Vec<_> = sphere(8_000)
        .into_iter()
        .map(|(p, n)| ([p[0] + 1.0e6, p[1] - 2.0e6, p[2]], n))
        .collect();
    let input = dir.path().join("far.xyz");
    write_xyz(&input, &pts);
    let one = dir.path().join("one.ply");
    let sl = dir.path().join("slabs.ply");
    let run = spsr(&["reconstruct", s(&input), "-o", s(&one), "--depth", "6"]);
    assert!(run.status.success(), "{}", stderr(&run));
    let run = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&sl),
        "--depth",
        "6",
        "--slabs",
        "3",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let header = ply_header(&sl);
    assert!(
        header.contains(&"property double x".to_string()),
        "{header:?}"
    );
    assert_eq!(header, ply_header(&one));
}

/// The vertex and face counts of the summary line (`spsr: wrote F: V vertices, F faces, ...`).
fn counts(said: &str) -> (u64, u64) {
    let v = said.find(" vertices, ").expect("vertex count");
    let start = said[..v].rfind(' ').unwrap() + 1;
    let vertices = said[start..v].parse().unwrap();
    let rest = &said[v + " vertices, ".len()..];
    let faces = rest[..rest.find(' ').unwrap()].parse().unwrap();
    (vertices, faces)
}

/// `--density` and `--trim` in slabs give the mesh of one piece: the same counts, within a
/// hundredth of a finest cell, the density property where asked for (the density is read
/// from the in-core estimator; the trimming's threshold is the whole mesh's, as in one
/// piece). The bunny is open at the bottom, so `--trim auto` opens it; 6.5 cuts it into many
/// pieces.
#[test]
fn slabs_compute_the_density_and_trim_as_one_piece() {
    let dir = tempfile::tempdir().unwrap();
    let bunny = concat!(env!("CARGO_MANIFEST_DIR"), "/../../examples/bunny.ply");
    let work = dir.path().join("work");
    fs::create_dir(&work).unwrap();
    let base = [
        "--depth",
        "8",
        "--cycles",
        "1",
        "--iters",
        "8",
        "--noise",
        "off",
        "--no-attributes",
    ];
    for (name, extra) in [
        ("density", vec!["--density"]),
        ("trim", vec!["--trim", "auto"]),
        ("trim-value", vec!["--trim", "6.5", "--density"]),
    ] {
        let one = dir.path().join(format!("{name}-one.ply"));
        let mut args = vec!["reconstruct", bunny, "-o", s(&one)];
        args.extend(base);
        args.extend(&extra);
        let run = spsr(&args);
        assert!(run.status.success(), "{}", stderr(&run));
        let whole = counts(&(stdout(&run) + &stderr(&run)));
        for k in ["2", "3"] {
            let sl = dir.path().join(format!("{name}-{k}.ply"));
            let mut args = vec!["reconstruct", bunny, "-o", s(&sl), "--slabs", k];
            args.extend(["--work-dir", s(&work)]);
            args.extend(base);
            args.extend(&extra);
            // The trimming's report with -v, though the mesh was trimmed as it was written.
            let verbose = name.starts_with("trim") && k == "2";
            if verbose {
                args.push("-v");
            }
            let run = spsr(&args);
            assert!(run.status.success(), "{}", stderr(&run));
            let said = stdout(&run) + &stderr(&run);
            assert_eq!(counts(&said), whole, "{name}, {k} slabs: {said}");
            if verbose {
                assert!(
                    said.contains("trim        V = ") && said.contains("% of the area"),
                    "{name}: {said}"
                );
            }
            let bytes = fs::read(&sl).unwrap();
            let header = String::from_utf8_lossy(&bytes[..bytes.len().min(400)]).to_string();
            assert_eq!(
                header.contains("property float density"),
                extra.contains(&"--density"),
                "{name}: {header}"
            );
            let eval = spsr(&["eval", s(&sl), "--reference", s(&one), "--json"]);
            assert!(eval.status.success(), "{}", stderr(&eval));
            let json = stdout(&eval);
            // A finest cell of the bunny at depth 8 is about 1.1 × 0.156 / 256 (its
            // bounding box's longest side, 0.156, and the default scale).
            let cell = 1.1 * 0.156 / 256.0;
            assert!(
                json_number(&json, "hausdorff") < 0.01 * cell,
                "{name}: {json}"
            );
            assert_eq!(fs::read_dir(&work).unwrap().count(), 0, "spill files left");
        }
    }
}

#[test]
fn slab_runs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let (_, a, _) = sphere_files(dir.path());
    let out = dir.path().join("out.ply");
    let work = dir.path().join("work");
    fs::create_dir(&work).unwrap();
    let missing = dir.path().join("missing.xyz");
    // An unreadable tile: an error naming it (as for one input); no output, no spill files.
    let run = spsr(&[
        "reconstruct",
        &a,
        s(&missing),
        "-o",
        s(&out),
        "--slabs",
        "2",
        "--work-dir",
        s(&work),
        "--depth",
        "6",
    ]);
    assert_fails(&run, USAGE, &["missing.xyz"], &out);
    assert_eq!(fs::read_dir(&work).unwrap().count(), 0);
    // A work folder that cannot be made (under a file).
    let file = dir.path().join("file");
    fs::write(&file, "x").unwrap();
    let run = spsr(&[
        "reconstruct",
        &a,
        "-o",
        s(&out),
        "--slabs",
        "2",
        "--work-dir",
        s(&file.join("sub")),
        "--depth",
        "6",
    ]);
    assert_fails(&run, USAGE, &["file"], &out);
    // What slab mode cannot do yet is refused before any work.
    let run = spsr(&[
        "reconstruct",
        &a,
        "-o",
        s(&out),
        "--slabs",
        "2",
        "--estimate-normals",
    ]);
    assert!(!run.status.success());
    assert!(
        stderr(&run).contains("--estimate-normals"),
        "{}",
        stderr(&run)
    );
    assert!(!out.exists());
    let run = spsr(&["reconstruct", "-", "-o", s(&out), "--slabs", "2"]);
    assert_fails(&run, USAGE, &["standard input"], &out);
    let run = spsr(&["reconstruct", &a, "-o", s(&out), "--slabs", "0"]);
    assert_fails(&run, USAGE, &["auto"], &out);
}

/// A disk that fills up during the run, at each kind of file the run writes (the spill files,
/// the phases' records, the mesh's pieces, the output): simulated by a file-size limit
/// (`ulimit -f`, which fails writes as a full disk does, without privileges). Each run fails
/// with the limit named and advice, leaves no output and removes its spill files.
#[test]
#[cfg(unix)]
fn a_full_disk_fails_cleanly_at_every_step() {
    let dir = tempfile::tempdir().unwrap();
    let (whole, _, _) = sphere_files(dir.path());
    let out = dir.path().join("out.ply");
    let work = dir.path().join("work");
    fs::create_dir(&work).unwrap();
    let mut failures = std::collections::BTreeSet::new();
    // Limits in 512-byte blocks (POSIX sh), from below the first spill file to above all.
    for blocks in [4, 64, 256, 2048, 3072, 6144, 100_000] {
        let run = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!(
                "trap '' XFSZ; ulimit -f {blocks}; exec \"$0\" \"$@\""
            ))
            .arg(env!("CARGO_BIN_EXE_spsr"))
            .args(["reconstruct", &whole, "-o", s(&out), "--slabs", "2"])
            .args(["--work-dir", s(&work), "--depth", "7"])
            .output()
            .unwrap();
        assert_eq!(fs::read_dir(&work).unwrap().count(), 0, "spill files left");
        if run.status.success() {
            assert!(out.exists());
            fs::remove_file(&out).unwrap();
            continue;
        }
        assert_fails(&run, RESOURCE, &["too large", "--work-dir"], &out);
        // Which file it was: the name after the job folder.
        let err = stderr(&run);
        let file = err
            .split("spsr-slabs-")
            .nth(1)
            .and_then(|t| t.split(['/', ':']).nth(1));
        failures.insert(file.map_or("output".to_string(), |f| {
            f.split('-').next().unwrap().to_string()
        }));
    }
    assert!(
        failures.len() >= 3,
        "the limits met too few steps: {failures:?}"
    );
}

/// A sparse cloud's tree stops short of the asked depth (its samples sit at coarser depths):
/// the slabs still meet on their shared faces, and the mesh written slab by slab is closed and
/// in one piece, like the run in one piece. (Its edge keys were in units of the tree's own
/// depth while the faces between slabs were at the asked one: every shared vertex was lost.)
/// A cloud so sparse that its tree stops above the depth where slabs part is refused with
/// advice, not a panic.
#[test]
fn a_tree_shallower_than_the_depth_still_stitches() {
    let dir = tempfile::tempdir().unwrap();
    let bunny = concat!(env!("CARGO_MANIFEST_DIR"), "/../../examples/bunny.ply");
    let one = dir.path().join("one.ply");
    let args = |out: &Path| -> Vec<String> {
        [
            "reconstruct",
            bunny,
            "-o",
            s(out),
            "--depth",
            "10",
            "--noise",
            "off",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = spsr(&args(&one).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run.status.success(), "{}", stderr(&run));
    for k in ["2", "3"] {
        let out = dir.path().join(format!("slabs{k}.ply"));
        let mut a = args(&out);
        a.extend(["--slabs".to_string(), k.to_string()]);
        let run = spsr(&a.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(run.status.success(), "{k} slabs: {}", stderr(&run));
        let said = stdout(&run) + &stderr(&run);
        assert!(said.contains("1 piece, closed"), "{said}");
        let eval = spsr(&["eval", s(&out), "--reference", s(&one), "--json"]);
        let json = stdout(&eval);
        assert_eq!(json_number(&json, "components"), 1.0, "{json}");
        assert!(json.contains("\"closed\": true"), "{json}");
    }
    let sparse = dir.path().join("sparse.xyz");
    write_xyz(&sparse, &sphere(3_000));
    let out = dir.path().join("sparse.ply");
    let run = spsr(&[
        "reconstruct",
        s(&sparse),
        "-o",
        s(&out),
        "--depth",
        "10",
        "--slabs",
        "2",
    ]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    assert!(
        stderr(&run).contains("leave out --slabs"),
        "{}",
        stderr(&run)
    );
    assert!(!out.exists());
}
