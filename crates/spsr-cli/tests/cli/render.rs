//! `spsr render` and `spsr reconstruct --preview`: the pictures they write and their errors.

use std::fs;
use std::path::{Path, PathBuf};

use tempfile::TempDir;

use crate::common::*;

/// An ASCII PLY mesh: a box with a vertex property `quality`, and a small loose triangle.
fn mesh_ply() -> String {
    let mut v = Vec::new();
    for i in 0..8 {
        let p: Vec<f64> = (0..3).map(|k| ((i >> k) & 1) as f64).collect();
        v.push(format!("{} {} {} {}", p[0], p[1], p[2], i));
    }
    v.push("2 0 0 8".into());
    v.push("2.2 0 0 8".into());
    v.push("2 0.2 0 8".into());
    let faces = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut f: Vec<String> = faces
        .iter()
        .map(|q| format!("4 {} {} {} {}", q[0], q[1], q[2], q[3]))
        .collect();
    f.push("3 8 9 10".into());
    format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float quality\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n{}\n{}\n",
        v.len(),
        f.len(),
        v.join("\n"),
        f.join("\n")
    )
}

fn setup() -> (TempDir, PathBuf) {
    let dir = TempDir::new().unwrap();
    let mesh = dir.path().join("box.ply");
    fs::write(&mesh, mesh_ply()).unwrap();
    (dir, mesh)
}

/// The decoded PNG: width, height and RGB(A) bytes per pixel.
fn decode(path: &Path) -> (u32, u32, usize, Vec<u8>) {
    let file = std::io::BufReader::new(fs::File::open(path).unwrap());
    let mut reader = png::Decoder::new(file).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    let channels = info.color_type.samples();
    (info.width, info.height, channels, buf)
}

/// Pixels that are not the white background.
fn drawn(pixels: &[u8], channels: usize) -> usize {
    pixels
        .chunks_exact(channels)
        .filter(|p| p[..3] != [255, 255, 255])
        .count()
}

#[test]
fn render_writes_a_png_of_the_asked_size() {
    let (dir, mesh) = setup();
    for (view, size, (w, h)) in [
        ("iso", "320x200", (320, 200)),
        ("all", "301x151", (301, 151)),
        ("front", "64", (64, 64)),
    ] {
        let out_png = dir.path().join(format!("{view}.png"));
        let out = spsr(&[
            "render",
            s(&mesh),
            "-o",
            s(&out_png),
            "--view",
            view,
            "--size",
            size,
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
        assert!(stdout(&out).starts_with(&format!("spsr: wrote {}", out_png.display())));
        let (width, height, channels, pixels) = decode(&out_png);
        assert_eq!((width, height), (w, h));
        assert_eq!(pixels.len(), (w * h) as usize * channels);
        // The box fills a good part of each view (the margins and the corners stay white;
        // the loose triangle beside it makes the front view twice as wide).
        let share = drawn(&pixels, channels) as f64 / (w * h) as f64;
        assert!(share > 0.15 && share < 0.95, "{view}: {share}");
    }
}

#[test]
fn colours_and_highlights_are_reported_with_verbose() {
    let (dir, mesh) = setup();
    let out_png = dir.path().join("q.png");
    let out = spsr(&[
        "render",
        s(&mesh),
        "-o",
        s(&out_png),
        "--color",
        "attribute:quality",
        "--highlight",
        "pieces",
        "-v",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let err = stderr(&out);
    assert!(
        err.contains("colours     0 (purple) to 8 (yellow)"),
        "{err}"
    );
    assert!(err.contains("pieces      2 (1 highlighted)"), "{err}");
    let (_, _, channels, pixels) = decode(&out_png);
    // Magenta: the loose triangle.
    assert!(pixels
        .chunks_exact(channels)
        .any(|p| p[0] > 150 && p[2] > 130 && p[1] < 40));
}

#[test]
fn bad_requests_fail_cleanly_and_leave_no_picture() {
    let (dir, mesh) = setup();
    let out_png = dir.path().join("x.png");
    let o = s(&out_png);
    let m = s(&mesh);
    let out = spsr(&["render", m, "-o", o, "--size", "0x10"]);
    assert_fails_one_line(
        &out,
        USAGE,
        &["invalid parameter --size 0x10", "from 1 to 16384"],
        &out_png,
    );
    let out = spsr(&["render", m, "-o", o, "--size", "20000x10"]);
    assert_fails_one_line(&out, USAGE, &["--size 20000x10"], &out_png);
    let out = spsr(&["render", m, "-o", o, "--size", "wide"]);
    assert_fails(&out, USAGE, &["'wide' is not a size"], &out_png);
    let out = spsr(&["render", m, "-o", o, "--view", "back"]);
    assert_fails(&out, USAGE, &["front, side, top, iso, all"], &out_png);
    let out = spsr(&["render", m, "-o", o, "--color", "attribute:intensity"]);
    assert_fails_one_line(
        &out,
        USAGE,
        &["--color", "'intensity'", "(it has: quality)"],
        &out_png,
    );
    let out = spsr(&["render", m, "-o", o, "--color", "density"]);
    assert_fails_one_line(
        &out,
        DATA,
        &["no per-vertex density", "--density"],
        &out_png,
    );
    let missing = dir.path().join("missing.ply");
    let out = spsr(&["render", s(&missing), "-o", o]);
    assert_fails_one_line(&out, DATA, &["missing.ply"], &out_png);
    let jpg = dir.path().join("x.jpg");
    let out = spsr(&["render", m, "-o", s(&jpg)]);
    assert_fails_one_line(&out, USAGE, &["x.jpg", ".png"], &jpg);
    let out = spsr(&["render", m, "-o", s(&dir.path().join("no/x.png"))]);
    assert_eq!(out.status.code(), Some(USAGE), "{}", stderr(&out));
    // Only the mesh is left in the folder.
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
}

/// An oriented sphere cloud as text.
fn cloud(dir: &Path) -> PathBuf {
    let path = dir.join("sphere.xyz");
    let text: String = sphere(2000)
        .iter()
        .map(|(p, n)| format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]))
        .collect();
    fs::write(&path, text).unwrap();
    path
}

#[test]
fn reconstruct_writes_a_preview_beside_the_mesh() {
    let dir = TempDir::new().unwrap();
    let input = cloud(dir.path());
    let mesh = dir.path().join("m.ply");
    let preview = dir.path().join("m.png");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&mesh),
        "--depth",
        "5",
        "--preview",
        s(&preview),
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let (w, h, channels, pixels) = decode(&preview);
    assert_eq!((w, h), (800, 800));
    // A sphere fills π/4 of the square within the margins: 0.9² π/4 ≈ 0.64 of the picture.
    let share = drawn(&pixels, channels) as f64 / (w * h) as f64;
    assert!((share - 0.636).abs() < 0.02, "{share}");

    // A bad preview name is refused before anything is reconstructed.
    let mesh2 = dir.path().join("m2.ply");
    let bad = dir.path().join("m2.gif");
    let out = spsr(&[
        "reconstruct",
        s(&input),
        "-o",
        s(&mesh2),
        "--depth",
        "5",
        "--preview",
        s(&bad),
    ]);
    assert_fails_one_line(&out, USAGE, &[".png"], &mesh2);
    assert!(!bad.exists());
}
