//! Integration tests of `spsr::io`: PLY/text point reading in every encoding and type family,
//! malformed inputs, mesh write/read round trips, atomic writes and output path checks.

use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use spsr::io::{check_output_path, read_mesh, read_points, write_mesh, WriteOptions};
use spsr::{Error, Mesh};

use crate::common::{assert_parse, write_file, OCTAHEDRON_TRIANGLES};

// ---------------------------------------------------------------------------------------------
// A small PLY writer for tests: any encoding, either type-name family.

#[derive(Clone, Copy, Debug, PartialEq)]
enum Enc {
    Ascii,
    Le,
    Be,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn name(self, sized: bool) -> &'static str {
        let (classic, sized_name) = match self {
            Ty::I8 => ("char", "int8"),
            Ty::U8 => ("uchar", "uint8"),
            Ty::I16 => ("short", "int16"),
            Ty::U16 => ("ushort", "uint16"),
            Ty::I32 => ("int", "int32"),
            Ty::U32 => ("uint", "uint32"),
            Ty::F32 => ("float", "float32"),
            Ty::F64 => ("double", "float64"),
        };
        if sized {
            sized_name
        } else {
            classic
        }
    }
}

/// A property value to encode.
#[derive(Clone, Debug)]
enum Val {
    S(Ty, f64),
    L(Ty, Ty, Vec<f64>),
}

fn put(out: &mut Vec<u8>, enc: Enc, ty: Ty, v: f64) {
    macro_rules! b {
        ($x:expr) => {{
            let x = $x;
            if enc == Enc::Be {
                out.extend_from_slice(&x.to_be_bytes())
            } else {
                out.extend_from_slice(&x.to_le_bytes())
            }
        }};
    }
    match enc {
        Enc::Ascii => {
            let s = match ty {
                Ty::F32 => format!("{}", v as f32),
                Ty::F64 => format!("{v:?}"),
                _ => format!("{}", v as i64),
            };
            out.extend_from_slice(s.as_bytes());
            out.push(b' ');
        }
        _ => match ty {
            Ty::I8 => b!(v as i8),
            Ty::U8 => b!(v as u8),
            Ty::I16 => b!(v as i16),
            Ty::U16 => b!(v as u16),
            Ty::I32 => b!(v as i32),
            Ty::U32 => b!(v as u32),
            Ty::F32 => b!(v as f32),
            Ty::F64 => b!(v),
        },
    }
}

#[derive(Clone)]
struct PlyElement {
    name: String,
    /// Property names; the types are taken from the first record.
    props: Vec<String>,
    records: Vec<Vec<Val>>,
}

fn element(name: &str, prop_names: &[&str], records: Vec<Vec<Val>>) -> PlyElement {
    PlyElement {
        name: name.into(),
        props: prop_names.iter().map(|s| s.to_string()).collect(),
        records,
    }
}

fn encode_ply(enc: Enc, sized: bool, crlf: bool, elements: &[PlyElement]) -> Vec<u8> {
    let nl = if crlf { "\r\n" } else { "\n" };
    let mut h = String::new();
    let fmt = match enc {
        Enc::Ascii => "ascii",
        Enc::Le => "binary_little_endian",
        Enc::Be => "binary_big_endian",
    };
    write!(
        h,
        "ply{nl}format {fmt} 1.0{nl}comment test file{nl}obj_info made by the test{nl}"
    )
    .unwrap();
    for e in elements {
        write!(h, "element {} {}{nl}", e.name, e.records.len()).unwrap();
        let first = e
            .records
            .first()
            .expect("elements need one record for types");
        for (name, v) in e.props.iter().zip(first) {
            match v {
                Val::S(t, _) => write!(h, "property {} {name}{nl}", t.name(sized)).unwrap(),
                Val::L(c, i, _) => write!(
                    h,
                    "property list {} {} {name}{nl}",
                    c.name(sized),
                    i.name(sized)
                )
                .unwrap(),
            }
        }
    }
    write!(h, "end_header{nl}").unwrap();
    let mut out = h.into_bytes();
    for e in elements {
        for rec in &e.records {
            for v in rec {
                match v {
                    Val::S(t, x) => put(&mut out, enc, *t, *x),
                    Val::L(c, i, xs) => {
                        put(&mut out, enc, *c, xs.len() as f64);
                        for &x in xs {
                            put(&mut out, enc, *i, x);
                        }
                    }
                }
            }
            if enc == Enc::Ascii {
                out.pop();
                out.extend_from_slice(nl.as_bytes());
            }
        }
    }
    out
}

fn sample_points(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let p = (0..n)
        .map(|i| {
            let t = i as f64;
            [0.1 + t * 1.0e-3, -2.5 + t * 0.37, 1.0e-4 * t * t]
        })
        .collect();
    let nn = (0..n)
        .map(|i| {
            let a = i as f64 * 0.7;
            [a.cos(), a.sin(), 0.25]
        })
        .collect();
    (p, nn)
}

// ---------------------------------------------------------------------------------------------
// Points from PLY.

/// Vertex records in a shuffled order with extra scalar and list properties.
fn vertex_element(pos: &[[f64; 3]], nrm: &[[f64; 3]], t: Ty) -> PlyElement {
    let names = [
        "nz",
        "red",
        "x",
        "ny",
        "extra_list",
        "y",
        "nx",
        "confidence",
        "z",
    ];
    let records = pos
        .iter()
        .zip(nrm)
        .enumerate()
        .map(|(i, (p, n))| {
            vec![
                Val::S(t, n[2]),
                Val::S(Ty::U8, (i % 256) as f64),
                Val::S(t, p[0]),
                Val::S(t, n[1]),
                Val::L(
                    Ty::U8,
                    Ty::I32,
                    (0..(i % 4)).map(|k| k as f64 - 1.0).collect(),
                ),
                Val::S(t, p[1]),
                Val::S(t, n[0]),
                Val::S(Ty::F64, 0.5),
                Val::S(t, p[2]),
            ]
        })
        .collect();
    element("vertex", &names, records)
}

/// An element before `vertex` with a scalar and a list (like a scanner's `range_grid`).
fn grid_element() -> PlyElement {
    let records = (0..5)
        .map(|i| {
            vec![
                Val::S(Ty::I16, -(i as f64)),
                Val::L(Ty::U32, Ty::U16, (0..(i % 3)).map(|k| k as f64).collect()),
            ]
        })
        .collect();
    element("range_grid", &["id", "vertex_indices"], records)
}

fn face_element() -> PlyElement {
    let records = (0..3)
        .map(|i| vec![Val::L(Ty::U8, Ty::I32, vec![0.0, 1.0, (2 + i) as f64])])
        .collect();
    element("face", &["vertex_indices"], records)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * b.abs().max(1.0)
}

#[test]
fn points_round_trip_in_every_encoding_and_type_family() {
    let dir = tempfile::tempdir().unwrap();
    let (pos, nrm) = sample_points(50);
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        for sized in [false, true] {
            for t in [Ty::F32, Ty::F64] {
                for crlf in [false, true] {
                    let els = [
                        grid_element(),
                        vertex_element(&pos, &nrm, t),
                        face_element(),
                    ];
                    let bytes = encode_ply(enc, sized, crlf, &els);
                    let name = format!("p_{enc:?}_{sized}_{t:?}_{crlf}.ply");
                    let path = write_file(dir.path(), &name, &bytes);
                    let cloud = read_points(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                    assert_eq!(cloud.positions.len(), pos.len(), "{name}");
                    assert_eq!(cloud.normals.len(), pos.len(), "{name}");
                    // Values come back exactly as the declared type holds them.
                    let tol = 0.0;
                    for i in 0..pos.len() {
                        for k in 0..3 {
                            let rounded = |v: f64| if t == Ty::F32 { v as f32 as f64 } else { v };
                            assert!(
                                close(cloud.positions[i][k], rounded(pos[i][k]), tol),
                                "{name} point {i}: {:?} vs {:?}",
                                cloud.positions[i],
                                pos[i]
                            );
                            assert!(
                                close(cloud.normals[i][k], rounded(nrm[i][k]), tol),
                                "{name} normal {i}"
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn integer_typed_coordinates_are_converted() {
    let dir = tempfile::tempdir().unwrap();
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        let tys = [Ty::I8, Ty::U8, Ty::I16, Ty::U16, Ty::I32, Ty::U32];
        let rec: Vec<Val> = tys
            .iter()
            .enumerate()
            .map(|(k, &t)| Val::S(t, (k as f64 + 1.0) * if k % 2 == 0 { -1.0 } else { 1.0 }))
            .collect();
        let el = element("vertex", &["x", "y", "z", "nx", "ny", "nz"], vec![rec]);
        let path = write_file(dir.path(), "int.ply", &encode_ply(enc, true, false, &[el]));
        let c = read_points(&path).unwrap();
        assert_eq!(c.positions, vec![[-1.0, 2.0, -3.0]], "{enc:?}");
        assert_eq!(c.normals, vec![[4.0, -5.0, 6.0]], "{enc:?}");
    }
}

#[test]
fn ply_is_detected_by_magic_or_uppercase_extension() {
    let dir = tempfile::tempdir().unwrap();
    let (pos, nrm) = sample_points(3);
    let bytes = encode_ply(
        Enc::Le,
        false,
        false,
        &[vertex_element(&pos, &nrm, Ty::F32)],
    );
    for name in ["noext", "points.txt", "POINTS.PLY"] {
        let p = write_file(dir.path(), name, &bytes);
        assert_eq!(read_points(&p).unwrap().len(), 3, "{name}");
    }
    let bytes = encode_ply(
        Enc::Ascii,
        false,
        true,
        &[vertex_element(&pos, &nrm, Ty::F32)],
    );
    let p = write_file(dir.path(), "crlf.xyz", &bytes);
    assert_eq!(read_points(&p).unwrap().len(), 3);
}

#[test]
fn invalid_points_are_kept() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(
        dir.path(),
        "nan.ply",
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
          property float z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n\
          nan 0 0 0 0 1\n1 2 3 0 0 0\n",
    );
    let c = read_points(&p).unwrap();
    assert_eq!(c.len(), 2);
    assert!(c.positions[0][0].is_nan());
    assert_eq!(c.normals[1], [0.0, 0.0, 0.0]);
}

const XYZN: &str = "property float x\nproperty float y\nproperty float z\n\
                    property float nx\nproperty float ny\nproperty float nz\n";

#[test]
fn malformed_headers_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        ("magic", format!("plx\nformat ascii 1.0\nelement vertex 0\n{XYZN}end_header\n"), vec!["line 1", "ply"]),
        ("format", format!("ply\nformat binary_middle_endian 1.0\nelement vertex 0\n{XYZN}end_header\n"), vec!["line 2", "binary_middle_endian"]),
        ("type", "ply\nformat ascii 1.0\nelement vertex 0\nproperty flot x\nend_header\n".into(), vec!["line 4", "flot"]),
        ("list type", "ply\nformat ascii 1.0\nelement face 0\nproperty list uchar integer vertex_indices\nend_header\n".into(), vec!["line 4", "integer"]),
        ("no end", format!("ply\nformat ascii 1.0\nelement vertex 0\n{XYZN}"), vec!["end_header"]),
        ("count", format!("ply\nformat ascii 1.0\nelement vertex abc\n{XYZN}end_header\n"), vec!["line 3", "abc"]),
        ("prop first", format!("ply\nformat ascii 1.0\n{XYZN}element vertex 0\nend_header\n"), vec!["line 3", "before any"]),
        ("keyword", format!("ply\nformat ascii 1.0\nelement vertex 0\n{XYZN}bogus\nend_header\n"), vec!["line 10", "bogus"]),
        ("no format", format!("ply\nelement vertex 0\n{XYZN}end_header\n"), vec!["format"]),
        ("no x", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float y\nproperty float z\nend_header\n".into(), vec!["'x'", "line 3"]),
        ("no vertex", "ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n".into(), vec!["'vertex'"]),
    ];
    for (what, text, needles) in cases {
        let p = write_file(dir.path(), "bad.ply", text.as_bytes());
        let e = read_points(&p).expect_err(what);
        assert_parse(e, &needles);
    }
}

#[test]
fn missing_normals_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    for enc in [Enc::Ascii, Enc::Le] {
        let el = element(
            "vertex",
            &["x", "y", "z"],
            vec![vec![
                Val::S(Ty::F32, 1.0),
                Val::S(Ty::F32, 2.0),
                Val::S(Ty::F32, 3.0),
            ]],
        );
        let p = write_file(
            dir.path(),
            "nonormals.ply",
            &encode_ply(enc, false, false, &[el]),
        );
        assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
    }
}

#[test]
fn truncated_binary_files_name_the_record() {
    let dir = tempfile::tempdir().unwrap();
    let (pos, nrm) = sample_points(10);
    for enc in [Enc::Le, Enc::Be] {
        // Plain fixed-size records (fast path): cut in the middle of record 5.
        let simple = element(
            "vertex",
            &["x", "y", "z", "nx", "ny", "nz"],
            pos.iter()
                .zip(&nrm)
                .map(|(p, n)| p.iter().chain(n).map(|&v| Val::S(Ty::F32, v)).collect())
                .collect(),
        );
        let bytes = encode_ply(enc, false, false, &[simple]);
        let cut = bytes.len() - 4 * 24 - 10;
        let p = write_file(dir.path(), "trunc.ply", &bytes[..cut]);
        assert_parse(
            read_points(&p).unwrap_err(),
            &["truncated", "vertex record 5 of 10", "byte offset"],
        );
        // Records with lists, and an element before the vertices.
        let bytes = encode_ply(
            enc,
            true,
            false,
            &[grid_element(), vertex_element(&pos, &nrm, Ty::F64)],
        );
        let p = write_file(dir.path(), "trunc2.ply", &bytes[..bytes.len() - 3]);
        assert_parse(
            read_points(&p).unwrap_err(),
            &["truncated", "vertex record 9 of 10"],
        );
        // Truncated inside the element before the vertices.
        let header_len = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let p = write_file(dir.path(), "trunc3.ply", &bytes[..header_len + 3]);
        assert_parse(
            read_points(&p).unwrap_err(),
            &["truncated", "range_grid record 0 of 5"],
        );
    }
}

#[test]
fn ascii_body_errors_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let head = format!("ply\nformat ascii 1.0\nelement vertex 3\n{XYZN}end_header\n");
    // Header is 10 lines, so body lines are 11, 12, 13.
    let cases = [
        (
            "1 2 3 0 0 1\n1 2 3 0 0\n1 2 3 0 0 1\n",
            vec!["line 12", "too few"],
        ),
        (
            "1 2 3 0 0 1\n1 2 3 0 0 1\n1 2 3 0 0 1 7\n",
            vec!["line 13", "too many"],
        ),
        (
            "1 2 3 0 0 1\n1 2 x 0 0 1\n1 2 3 0 0 1\n",
            vec!["line 12", "'x'"],
        ),
        (
            "1 2 3 0 0 1\n1 2 3 0 0 1\n",
            vec!["truncated", "line 12", "vertex record 2 of 3"],
        ),
    ];
    for (body, needles) in cases {
        let p = write_file(dir.path(), "a.ply", format!("{head}{body}").as_bytes());
        assert_parse(read_points(&p).unwrap_err(), &needles);
    }
}

// ---------------------------------------------------------------------------------------------
// Points from text.

#[test]
fn text_points_with_commas_whitespace_and_comments() {
    let dir = tempfile::tempdir().unwrap();
    let text = "# a comment\n\n  1 2 3 0 0 1\n4,5,6,0,1,0\n7, 8,\t9 , 1 0 0 255 128 0\r\n   # indented comment\n-1e-3 2.5E2 +3 0.5 0.5 0.5\n";
    let p = write_file(dir.path(), "pts.xyz", text.as_bytes());
    let c = read_points(&p).unwrap();
    assert_eq!(
        c.positions,
        vec![
            [1.0, 2.0, 3.0],
            [4.0, 5.0, 6.0],
            [7.0, 8.0, 9.0],
            [-1e-3, 250.0, 3.0]
        ]
    );
    assert_eq!(c.normals[2], [1.0, 0.0, 0.0]);
    assert_eq!(c.normals[3], [0.5, 0.5, 0.5]);
}

#[test]
fn text_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(dir.path(), "a.txt", b"# header\n1 2 3 0 0 1\n1 2 3 0 0\n");
    assert_parse(read_points(&p).unwrap_err(), &["line 3", "5 numbers"]);
    let p = write_file(dir.path(), "b.txt", b"1 2 3 0 0 1\n\n1 2 3 zero 0 1\n");
    assert_parse(read_points(&p).unwrap_err(), &["line 3", "'zero'"]);
    let p = write_file(dir.path(), "c.txt", b"# only positions\n1 2 3\n4 5 6\n");
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
    // Three numbers on a later line is an ordinary error.
    let p = write_file(dir.path(), "d.txt", b"1 2 3 0 0 1\n1 2 3\n");
    assert_parse(read_points(&p).unwrap_err(), &["line 2"]);
    // An empty text file is an empty cloud.
    let p = write_file(dir.path(), "e.txt", b"# nothing\n");
    assert!(read_points(&p).unwrap().is_empty());
}

#[test]
fn unreadable_inputs_are_io_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = read_points(dir.path()).unwrap_err();
    assert!(matches!(e, Error::Io { .. }), "{e:?}");
    assert!(e.to_string().contains(&dir.path().display().to_string()));
    let missing = dir.path().join("missing.ply");
    assert!(matches!(read_points(&missing), Err(Error::Io { .. })));
    assert!(matches!(read_mesh(&missing), Err(Error::Io { .. })));
    assert!(matches!(read_mesh(dir.path()), Err(Error::Io { .. })));
}

// ---------------------------------------------------------------------------------------------
// Meshes.

fn test_mesh(with_density: bool) -> Mesh {
    // An octahedron, with coordinates that are not exact in f32.
    let vertices = vec![
        [1.1, 0.0, 0.0],
        [-1.1, 0.0, 0.0],
        [0.0, 1.0 / 3.0, 0.0],
        [0.0, -1.0 / 3.0, 0.0],
        [0.0, 0.0, 123456.789],
        [0.0, 0.0, -1e-7],
    ];
    let triangles = OCTAHEDRON_TRIANGLES.to_vec();
    let density = with_density.then(|| vec![0.5, 1.5, 2.25, 3.0, 4.125, -1.0]);
    Mesh {
        vertices,
        triangles,
        density,
        ..Default::default()
    }
}

fn as_f32(m: &Mesh) -> Vec<[f64; 3]> {
    m.vertices
        .iter()
        .map(|v| v.map(|c| c as f32 as f64))
        .collect()
}

/// A tiny OBJ reader for the round trip: `v` and triangular `f` lines only.
fn read_obj(path: &Path) -> Mesh {
    let mut m = Mesh::default();
    for line in fs::read_to_string(path).unwrap().lines() {
        let mut t = line.split_whitespace();
        match t.next() {
            Some("v") => {
                // Coordinates are written as f32.
                let v: Vec<f64> = t.map(|s| s.parse::<f32>().unwrap() as f64).collect();
                m.vertices.push([v[0], v[1], v[2]]);
            }
            Some("f") => {
                let f: Vec<u32> = t.map(|s| s.parse::<u32>().unwrap() - 1).collect();
                assert_eq!(f.len(), 3);
                m.triangles.push([f[0], f[1], f[2]]);
            }
            _ => {}
        }
    }
    m
}

#[test]
fn mesh_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for with_density in [false, true] {
        let mesh = test_mesh(with_density);
        for ascii in [false, true] {
            let p = dir.path().join(format!("m_{ascii}_{with_density}.ply"));
            write_mesh(&p, &mesh, &WriteOptions { ascii }).unwrap();
            let head = fs::read(&p).unwrap();
            let end = head.windows(11).position(|w| w == b"end_header\n").unwrap();
            let head = String::from_utf8_lossy(&head[..end]);
            assert!(head.starts_with("ply\n"));
            assert!(head.contains("comment generated by spsr\n"));
            assert!(head.contains(if ascii {
                "format ascii 1.0\n"
            } else {
                "format binary_little_endian 1.0\n"
            }));
            assert!(head.contains("element vertex 6\n"));
            assert!(head.contains("element face 8\nproperty list uchar int vertex_indices\n"));
            assert_eq!(
                head.contains("property float density\n"),
                with_density,
                "{head}"
            );
            let back = read_mesh(&p).unwrap();
            assert_eq!(back.vertices, as_f32(&mesh), "ascii={ascii}");
            assert_eq!(back.triangles, mesh.triangles);
            assert_eq!(back.density, mesh.density);
        }
        for name in ["m.obj", "M.OBJ"] {
            let p = dir.path().join(name);
            write_mesh(&p, &mesh, &WriteOptions::default()).unwrap();
            let back = read_obj(&p);
            assert_eq!(back.vertices, as_f32(&mesh));
            assert_eq!(back.triangles, mesh.triangles);
        }
    }
    // An empty mesh is written and read back as empty.
    let p = dir.path().join("empty.ply");
    write_mesh(&p, &Mesh::default(), &WriteOptions::default()).unwrap();
    assert_eq!(read_mesh(&p).unwrap(), Mesh::default());
}

#[test]
fn mesh_reading_polygons_names_and_errors() {
    let dir = tempfile::tempdir().unwrap();
    let verts = element(
        "vertex",
        &["x", "y", "z", "value"],
        (0..5)
            .map(|i| {
                vec![
                    Val::S(Ty::F64, i as f64),
                    Val::S(Ty::F32, 0.0),
                    Val::S(Ty::F32, 1.0),
                    Val::S(Ty::F32, i as f64 * 0.5),
                ]
            })
            .collect(),
    );
    let faces = element(
        "face",
        &["flags", "vertex_index"],
        vec![
            vec![
                Val::S(Ty::U8, 1.0),
                Val::L(Ty::U8, Ty::U32, vec![0.0, 1.0, 2.0, 3.0, 4.0]),
            ],
            vec![
                Val::S(Ty::U8, 1.0),
                Val::L(Ty::U8, Ty::U32, vec![4.0, 3.0, 2.0]),
            ],
        ],
    );
    for enc in [Enc::Ascii, Enc::Le, Enc::Be] {
        // Faces before vertices, and an element in between.
        let p = write_file(
            dir.path(),
            "poly.ply",
            &encode_ply(
                enc,
                false,
                false,
                &[faces.clone(), grid_element(), verts.clone()],
            ),
        );
        let m = read_mesh(&p).unwrap();
        assert_eq!(m.vertices.len(), 5);
        assert_eq!(
            m.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [4, 3, 2]],
            "{enc:?}"
        );
        assert_eq!(m.density, Some(vec![0.0, 0.5, 1.0, 1.5, 2.0]));
    }
    // Out-of-range index.
    let bad = element(
        "face",
        &["vertex_indices"],
        vec![
            vec![Val::L(Ty::U8, Ty::I32, vec![0.0, 1.0, 2.0])],
            vec![Val::L(Ty::U8, Ty::I32, vec![0.0, 1.0, 5.0])],
        ],
    );
    for enc in [Enc::Ascii, Enc::Le] {
        let p = write_file(
            dir.path(),
            "oob.ply",
            &encode_ply(enc, false, false, &[verts.clone(), bad.clone()]),
        );
        assert_parse(
            read_mesh(&p).unwrap_err(),
            &["face 1", "vertex 5", "5 vertices"],
        );
    }
    // No faces at all.
    let p = write_file(
        dir.path(),
        "nofaces.ply",
        &encode_ply(Enc::Le, false, false, std::slice::from_ref(&verts)),
    );
    assert_parse(read_mesh(&p).unwrap_err(), &["'face'"]);
}

// ---------------------------------------------------------------------------------------------
// Atomic writes and output checks.

fn dir_entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn writing_into_a_missing_directory_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nope").join("m.ply");
    let e = write_mesh(&p, &test_mesh(false), &WriteOptions::default()).unwrap_err();
    assert!(
        matches!(e, Error::Output { .. } | Error::Io { .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("create the directory"), "{e}");
    assert!(!p.exists());
    assert!(dir_entries(dir.path()).is_empty());
}

#[cfg(unix)]
#[test]
fn writing_into_a_read_only_directory_fails_cleanly() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let ro = dir.path().join("ro");
    fs::create_dir(&ro).unwrap();
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o555)).unwrap();
    // Privileged users (root) can write anyway; then there is nothing to test.
    let probe = ro.join("probe");
    let privileged = fs::write(&probe, b"x").is_ok();
    let _ = fs::remove_file(&probe);
    if !privileged {
        let p = ro.join("m.ply");
        let e = write_mesh(&p, &test_mesh(false), &WriteOptions::default()).unwrap_err();
        assert!(
            matches!(e, Error::Output { .. } | Error::Io { .. }),
            "{e:?}"
        );
        assert!(!p.exists());
        assert!(dir_entries(&ro).is_empty());
        let e = check_output_path(&p, Path::new("in.ply")).unwrap_err();
        assert!(matches!(e, Error::Output { .. }), "{e:?}");
        assert!(e.to_string().contains("not writable"), "{e}");
    }
    fs::set_permissions(&ro, fs::Permissions::from_mode(0o755)).unwrap();
}

/// A directory nobody can create files in, even root: `/proc` on Linux.
#[cfg(target_os = "linux")]
#[test]
fn writing_into_an_unwritable_system_directory_fails() {
    let proc_dir = Path::new("/proc");
    if !proc_dir.is_dir() {
        return;
    }
    let p = proc_dir.join("spsr-io-test.ply");
    let e = write_mesh(&p, &test_mesh(false), &WriteOptions::default()).unwrap_err();
    assert!(
        matches!(e, Error::Output { .. } | Error::Io { .. }),
        "{e:?}"
    );
    assert!(!p.exists());
    let e = check_output_path(&p, Path::new("in.ply")).unwrap_err();
    assert!(matches!(e, Error::Output { .. }), "{e:?}");
    assert!(e.to_string().contains("not writable"), "{e}");
}

#[test]
fn existing_output_is_replaced_only_on_success() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("out.ply");
    fs::write(&p, b"old content").unwrap();
    // A mesh that cannot be written (index out of range): the old file stays.
    let mut bad = test_mesh(false);
    bad.triangles.push([0, 1, 99]);
    let e = write_mesh(&p, &bad, &WriteOptions::default()).unwrap_err();
    assert!(matches!(e, Error::Output { .. }), "{e:?}");
    assert!(e.to_string().contains("triangle 8"), "{e}");
    assert_eq!(fs::read(&p).unwrap(), b"old content");
    assert_eq!(dir_entries(dir.path()), vec!["out.ply"]);
    // A good mesh replaces it, with no temporary file left behind.
    write_mesh(&p, &test_mesh(true), &WriteOptions::default()).unwrap();
    assert_eq!(read_mesh(&p).unwrap().triangles.len(), 8);
    assert_eq!(dir_entries(dir.path()), vec!["out.ply"]);
    // A directory in the way is an error, and stays a directory.
    let d = dir.path().join("adir.ply");
    fs::create_dir(&d).unwrap();
    assert!(write_mesh(&d, &test_mesh(false), &WriteOptions::default()).is_err());
    assert!(d.is_dir());
}

#[cfg(unix)]
#[test]
fn written_files_get_normal_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("perm.ply");
    write_mesh(&p, &test_mesh(false), &WriteOptions::default()).unwrap();
    let mode = fs::metadata(&p).unwrap().permissions().mode() & 0o777;
    // Not the private 0600 of a temporary file (unless the umask is that strict).
    assert!(mode & 0o600 == 0o600, "mode {mode:o}");
}

#[test]
fn check_output_path_cases() {
    let dir = tempfile::tempdir().unwrap();
    let input = write_file(dir.path(), "a.ply", b"ply\n");
    // Same file, different spellings.
    for out in [
        dir.path().join("a.ply"),
        dir.path().join(".").join("a.ply"),
        dir.path().join("sub").join("..").join("a.ply"),
    ] {
        if out.to_string_lossy().contains("sub") {
            fs::create_dir_all(dir.path().join("sub")).unwrap();
        }
        let e = check_output_path(&out, &input).unwrap_err();
        assert!(matches!(e, Error::Output { .. }), "{e:?}");
        assert!(
            e.to_string().contains("choose a different output file"),
            "{e}"
        );
    }
    #[cfg(unix)]
    {
        let link = dir.path().join("link.ply");
        std::os::unix::fs::symlink(&input, &link).unwrap();
        assert!(check_output_path(&link, &input).is_err());
    }
    // Relative spellings of the same existing file (cwd is the package root in tests).
    assert!(check_output_path(Path::new("./Cargo.toml"), Path::new("Cargo.toml")).is_err());
    // A directory.
    let e = check_output_path(dir.path(), &input).unwrap_err();
    assert!(matches!(e, Error::Output { .. }), "{e:?}");
    assert!(e.to_string().contains("directory"), "{e}");
    // Missing parent.
    let e = check_output_path(&dir.path().join("x").join("out.ply"), &input).unwrap_err();
    assert!(matches!(e, Error::Output { .. }), "{e:?}");
    assert!(e.to_string().contains("create the directory first"), "{e}");
    // Fine: a new file, or an existing other file; nothing is left behind.
    let before = dir_entries(dir.path());
    check_output_path(&dir.path().join("out.ply"), &input).unwrap();
    let other = write_file(dir.path(), "b.ply", b"x");
    check_output_path(&other, &input).unwrap();
    assert_eq!(dir_entries(dir.path()).len(), before.len() + 1);
    // A bare file name lives in the current directory.
    check_output_path(Path::new("spsr-io-test-output-not-created.ply"), &input).unwrap();
    assert!(!Path::new("spsr-io-test-output-not-created.ply").exists());
}

// ---------------------------------------------------------------------------------------------
// The real data shipped with the repository.

#[test]
fn bunny_example_and_ground_truth() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cloud = read_points(&root.join("../../examples/bunny.ply")).unwrap();
    assert_eq!(cloud.len(), 20_000);
    for n in &cloud.normals {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-5, "normal length {len}");
    }
    let gt = read_mesh(&root.join("tests/data/bunny_gt.ply")).unwrap();
    assert_eq!(gt.vertices.len(), 34_834);
    assert_eq!(gt.triangles.len(), 69_451);
    assert!(gt.density.is_none());
}

// ---------------------------------------------------------------------------------------------
// Speed (run with `cargo test --release -p spsr --test io -- --ignored --nocapture speed_read`).

#[test]
#[ignore = "timing; run by hand"]
fn speed_read_1m_points_write_2m_faces() {
    let dir = tempfile::tempdir().unwrap();
    let n = 1_000_000usize;
    let mut bytes =
        format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n{XYZN}end_header\n")
            .into_bytes();
    for i in 0..n {
        for k in 0..6 {
            bytes.extend_from_slice(&((i * 6 + k) as f32).to_le_bytes());
        }
    }
    let p = write_file(dir.path(), "big.ply", &bytes);
    let t = std::time::Instant::now();
    let c = read_points(&p).unwrap();
    println!("read {} points: {:?}", c.len(), t.elapsed());
    let mesh = Mesh {
        vertices: c.positions.clone(),
        triangles: (0..2_000_000u32)
            .map(|i| [i % 1_000_000, (i + 1) % 1_000_000, (i + 2) % 1_000_000])
            .collect(),
        ..Default::default()
    };
    let out = dir.path().join("big_out.ply");
    let t = std::time::Instant::now();
    write_mesh(&out, &mesh, &WriteOptions::default()).unwrap();
    println!("write binary 2M faces: {:?}", t.elapsed());
    let t = std::time::Instant::now();
    let m = read_mesh(&out).unwrap();
    println!("read mesh 2M faces: {:?}", t.elapsed());
    assert_eq!(m.triangles.len(), 2_000_000);
    let t = std::time::Instant::now();
    write_mesh(&dir.path().join("big.obj"), &mesh, &WriteOptions::default()).unwrap();
    println!("write obj 2M faces: {:?}", t.elapsed());
    let t = std::time::Instant::now();
    write_mesh(&out, &mesh, &WriteOptions { ascii: true }).unwrap();
    println!("write ascii ply 2M faces: {:?}", t.elapsed());
}
