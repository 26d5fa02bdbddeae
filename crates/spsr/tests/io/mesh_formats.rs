//! Meshes through every format spsr writes and reads back (PLY, OBJ, STL, OFF, GLB): the same
//! vertices and triangles, a closed sphere still closed; the readers' own features (OBJ corner
//! forms and negative indices, OFF headers and colours, STL detection, GLB node transforms
//! and interleaved accessors); mesh files as point clouds; refused output extensions; damaged
//! files of each format.

use std::fs;
use std::path::{Path, PathBuf};

use spsr::attributes::{Attribute, AttributeData};
use spsr::io::{
    read_cloud, read_mesh, read_points, write_cloud, write_mesh, CloudFormat, MeshFormat,
    WriteOptions,
};
use spsr::{Error, Mesh, PointCloud};

use crate::common::{assert_closed_manifold, assert_parse, write_file};

/// A closed sphere: an octahedron subdivided `levels` times, projected onto the sphere of
/// radius `r` around `c`, with outward normals, byte colours and a density.
fn sphere_mesh(levels: u32, c: [f64; 3], r: f64) -> Mesh {
    let mut dirs: Vec<[f64; 3]> = vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let mut tris = crate::common::OCTAHEDRON_TRIANGLES.to_vec();
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::new();
        for t in &tris {
            let m: [u32; 3] = std::array::from_fn(|k| {
                let (a, b) = (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]));
                *mid.entry((a, b)).or_insert_with(|| {
                    let p: [f64; 3] =
                        std::array::from_fn(|i| dirs[a as usize][i] + dirs[b as usize][i]);
                    let l = p.iter().map(|x| x * x).sum::<f64>().sqrt();
                    dirs.push(p.map(|x| x / l));
                    dirs.len() as u32 - 1
                })
            });
            next.extend([
                [t[0], m[0], m[2]],
                [m[0], t[1], m[1]],
                [m[2], m[1], t[2]],
                [m[0], m[1], m[2]],
            ]);
        }
        tris = next;
    }
    let n = dirs.len();
    let byte = |d: &[f64; 3], k: usize| ((d[k] + 1.0) * 127.5).round() as u8;
    Mesh {
        vertices: dirs
            .iter()
            .map(|d| std::array::from_fn(|k| c[k] + r * d[k]))
            .collect(),
        triangles: tris,
        density: Some((0..n).map(|i| 5.0 + (i % 7) as f32 * 0.25).collect()),
        normals: Some(dirs.iter().map(|d| d.map(|x| x as f32)).collect()),
        attributes: ["red", "green", "blue"]
            .iter()
            .enumerate()
            .map(|(k, name)| {
                Attribute::new(
                    *name,
                    AttributeData::U8(dirs.iter().map(|d| byte(d, k)).collect()),
                )
            })
            .collect(),
    }
}

fn f32_round(v: &[f64; 3]) -> [f64; 3] {
    v.map(|c| f64::from(c as f32))
}

/// Colours as `[0, 1]` values, whatever their type.
fn unit_colours(m: &Mesh) -> Vec<[f32; 4]> {
    let c = m.colors().expect("the mesh has colours");
    (0..m.vertices.len()).map(|i| c.unit(i)).collect()
}

/// What each format keeps: (extension, ASCII?, exact f64 positions (not `f32`, as every
/// format writes a mesh this close to the origin)?, normals?, colours?, density?, vertex
/// order kept?).
const FORMATS: [(&str, bool, bool, bool, bool, bool, bool); 8] = [
    ("ply", false, false, true, true, true, true),
    ("ply", true, false, true, true, true, true),
    ("obj", false, false, true, true, false, true),
    ("off", false, false, true, true, false, true),
    ("glb", false, false, true, true, true, true),
    ("stl", false, false, false, false, false, false),
    ("stl", true, false, false, false, false, false),
    ("OFF", false, false, true, true, false, true),
];

#[test]
fn every_format_round_trips_a_closed_sphere() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(3, [0.25, -1.5, 3.0], 2.0);
    let topo = assert_closed_manifold(&m, "the sphere");
    for (ext, ascii, exact, normals, colours, density, order) in FORMATS {
        let what = format!("{ext} (ascii {ascii})");
        let p = dir.path().join(format!("sphere.{ext}"));
        write_mesh(&p, &m, &WriteOptions { ascii }).unwrap();
        let back = read_mesh(&p).unwrap();
        let t = assert_closed_manifold(&back, &what);
        assert_eq!(
            (t.vertices, t.faces, t.euler, t.components),
            (topo.vertices, topo.faces, topo.euler, topo.components),
            "{what}"
        );
        // Text formats write the shortest decimal of each `f32`, which reads back as that
        // `f32` once rounded to single precision.
        let precision = |v: &[[f64; 3]]| -> Vec<[f64; 3]> {
            if exact {
                v.to_vec()
            } else {
                v.iter().map(f32_round).collect()
            }
        };
        let (expected, got) = (precision(&m.vertices), precision(&back.vertices));
        if order {
            assert_eq!(back.triangles, m.triangles, "{what}");
            assert_eq!(got, expected, "{what}");
        } else {
            // STL: vertices numbered by first appearance; the same corners in the same order.
            assert_eq!(back.triangles.len(), m.triangles.len(), "{what}");
            for (a, b) in back.triangles.iter().zip(&m.triangles) {
                for k in 0..3 {
                    assert_eq!(got[a[k] as usize], expected[b[k] as usize], "{what}");
                }
            }
        }
        assert_eq!(back.normals.is_some(), normals, "{what}");
        if normals {
            let n = back.normals.as_ref().unwrap();
            for (a, b) in n.iter().zip(m.normals.as_ref().unwrap()) {
                assert!(
                    (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6),
                    "{what}: {a:?} {b:?}"
                );
            }
        }
        assert_eq!(back.colors().is_some(), colours, "{what}");
        if colours {
            for (a, b) in unit_colours(&back).iter().zip(unit_colours(&m)) {
                assert!(
                    (0..4).all(|k| (a[k] - b[k]).abs() < 1e-6),
                    "{what}: {a:?} {b:?}"
                );
            }
        }
        assert_eq!(back.density.is_some(), density, "{what}");
        if density {
            assert_eq!(back.density, m.density, "{what}");
        }
    }
}

#[test]
fn far_meshes_read_back_through_the_glb_translation() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(1, [500_000.125, 5_000_000.25, 100.0], 3.0);
    for ext in ["glb", "obj", "off"] {
        let p = dir.path().join(format!("utm.{ext}"));
        write_mesh(&p, &m, &WriteOptions::default()).unwrap();
        let back = read_mesh(&p).unwrap();
        for (a, b) in back.vertices.iter().zip(&m.vertices) {
            // f32 relative to the centre (GLB), or f64 (OBJ, OFF): far below a millimetre.
            assert!(
                (0..3).all(|k| (a[k] - b[k]).abs() < 1e-6),
                "{ext}: {a:?} {b:?}"
            );
        }
    }
}

#[test]
fn formats_are_told_by_magic_then_extension() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(0, [0.0; 3], 1.0);
    for (ext, format) in [
        ("ply", MeshFormat::Ply),
        ("glb", MeshFormat::Glb),
        ("off", MeshFormat::Off),
    ] {
        let p = dir.path().join(format!("m.{ext}"));
        write_mesh(&p, &m, &WriteOptions::default()).unwrap();
        let renamed = dir.path().join(format!("{ext}.mesh"));
        fs::rename(&p, &renamed).unwrap();
        assert_eq!(MeshFormat::detect(&renamed).unwrap(), format);
        assert_eq!(read_mesh(&renamed).unwrap().triangles, m.triangles);
    }
    let p = dir.path().join("m.stl");
    write_mesh(&p, &m, &WriteOptions { ascii: true }).unwrap();
    let renamed = dir.path().join("ascii-stl.mesh");
    fs::rename(&p, &renamed).unwrap();
    assert_eq!(MeshFormat::detect(&renamed).unwrap(), MeshFormat::Stl);
    // Binary STL and OBJ have no magic: the extension decides, and nothing else guesses.
    let p = dir.path().join("m.obj");
    write_mesh(&p, &m, &WriteOptions::default()).unwrap();
    let renamed = dir.path().join("obj.mesh");
    fs::rename(&p, &renamed).unwrap();
    assert_parse(
        read_mesh(&renamed).unwrap_err(),
        &[
            "obj.mesh",
            "not a mesh format",
            ".ply, .obj, .stl, .off, .glb",
        ],
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("a.OFF")).unwrap(),
        MeshFormat::Off
    );
    assert_eq!(
        MeshFormat::from_extension(Path::new("a.Stl")),
        Some(MeshFormat::Stl)
    );
}

#[test]
fn unknown_output_extensions_are_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(0, [0.0; 3], 1.0);
    for name in ["mesh.xyz", "mesh.mesh", "mesh"] {
        let p = dir.path().join(name);
        let e = write_mesh(&p, &m, &WriteOptions::default()).unwrap_err();
        assert!(matches!(e, Error::Output { .. }), "{e:?}");
        let msg = e.to_string();
        assert!(msg.contains(".ply, .obj, .stl, .off, .glb"), "{msg}");
        assert!(!p.exists());
        assert!(MeshFormat::from_path(&p).is_err());
    }
    let cloud = PointCloud::new(vec![[1.0, 2.0, 3.0]], vec![[0.0, 0.0, 1.0]]).unwrap();
    for name in ["c.las", "c.obj", "c"] {
        let p = dir.path().join(name);
        let e = write_cloud(&p, &cloud, &WriteOptions::default()).unwrap_err();
        assert!(e.to_string().contains(".ply, .xyz, .txt"), "{e}");
        assert!(!p.exists());
    }
    assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn text_clouds_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let positions = vec![[0.1, 1e-7, 500_000.123_456_789], [-3.5, 2.0, 1.0 / 3.0]];
    let normals = vec![[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]];
    let mut cloud = PointCloud::new(positions.clone(), normals.clone()).unwrap();
    for (name, v) in [("red", [255, 0]), ("green", [7, 8]), ("blue", [0, 9])] {
        cloud
            .attributes
            .push(Attribute::new(name, AttributeData::U8(v.to_vec())));
    }
    for ext in ["xyz", "TXT"] {
        let p = dir.path().join(format!("c.{ext}"));
        write_cloud(&p, &cloud, &WriteOptions::default()).unwrap();
        let back = read_points(&p).unwrap();
        assert_eq!(back.positions, positions);
        assert_eq!(back.normals, normals);
        assert_eq!(back.attributes, cloud.attributes);
    }
    let bare = PointCloud::from_positions(positions.clone());
    let p = dir.path().join("bare.xyz");
    write_cloud(&p, &bare, &WriteOptions::default()).unwrap();
    assert_eq!(read_cloud(&p).unwrap().positions, positions);
}

// ---------------------------------------------------------------------------------------------
// OBJ.

#[test]
fn obj_corner_forms_negative_indices_and_polygons() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(
        dir.path(),
        "q.obj",
        b"# a unit square and a triangle\nmtllib x.mtl\no square\n\
          v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvn 0 0 1\n\
          usemtl a\ns off\nf 1/1/1 2/2/1 3/2/1 4/1/1\n\
          v 0 0 1 0.5\nf -1//1 -5 -4/1\nl 1 2\nf 1 2\n",
    );
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.vertices.len(), 5);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [4, 0, 1]]);
    // Vertices 2 and 3 (0-based) get vn 1 from the square; vertex 4 from its own corner.
    assert_eq!(m.normals, Some(vec![[0.0, 0.0, 1.0]; 5]));
    assert!(m.attributes.is_empty());
}

#[test]
fn obj_normals_only_when_each_vertex_has_one() {
    let dir = tempfile::tempdir().unwrap();
    // Two normals meet at vertex 1: no per-vertex normals.
    let p = write_file(
        dir.path(),
        "seam.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nvn 0 0 1\nvn 1 0 0\n\
          f 1//1 2//1 3//1\nf 2//2 4//2 3//2\n",
    );
    assert_eq!(read_mesh(&p).unwrap().normals, None);
    // A point cloud as OBJ: as many vn as v, no faces.
    let p = write_file(
        dir.path(),
        "cloud.obj",
        b"v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nvn 0 0 1\nvn 0 1 0\n",
    );
    let c = read_points(&p).unwrap();
    assert_eq!(c.positions, vec![[0.0; 3], [1.0, 0.0, 0.0]]);
    assert_eq!(c.normals, vec![[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]);
    assert_eq!(c.attributes[0].data, AttributeData::F32(vec![1.0, 0.0]));
}

#[test]
fn malformed_obj_files_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    for (text, needles) in [
        (
            &b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n"[..],
            &["line 4", "vertex 4", "3 vertices"][..],
        ),
        (b"v 0 0 0\nf 0 1 1\n", &["line 2", "index 0"]),
        (b"v 0 0 0\nf -2 1 1\n", &["line 2", "index -2"]),
        (b"v 0 0\n", &["line 1", "'v' has 2 numbers"]),
        (b"v 0 0 zero\n", &["line 1", "'zero' is not a number"]),
        (
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//3 2//1 3//1\nvn 0 0 1\n",
            &["line 4", "normal 3"],
        ),
        (b"v 0 0 0\n\xff\n", &["line 2", "UTF-8"]),
    ] {
        let p = write_file(dir.path(), "bad.obj", text);
        assert_parse(read_mesh(&p).unwrap_err(), needles);
    }
}

// ---------------------------------------------------------------------------------------------
// OFF.

#[test]
fn off_headers_comments_colours_and_polygons() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(
        dir.path(),
        "c.off",
        b"# made by hand\nCOFF 5 2 0\n\
          0 0 0 1 0 0 0.5\n1 0 0 0 1 0 1\n1 1 0 0 0 1 1\n0 1 0 1 1 1 1 # comment\n\n\
          0 0 1 0.5 0.5 0.5 1\n4 0 1 2 3  1 0 0\n3 0 1 4\n",
    );
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 4]]);
    assert_eq!(m.vertices[4], [0.0, 0.0, 1.0]);
    let names: Vec<&str> = m.attributes.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["red", "green", "blue", "alpha"]);
    assert_eq!(
        m.attributes[3].data,
        AttributeData::F32(vec![0.5, 1.0, 1.0, 1.0, 1.0])
    );
    // Counts on their own line, NOFF normals, byte colours without alpha.
    let p = write_file(
        dir.path(),
        "n.off",
        b"CNOFF\n3 1 3\n0 0 0 0 0 1 255 0 0\n1 0 0 0 0 1 0 255 0\n0 1 0 0 0 1 0 0 255\n3 0 1 2\n",
    );
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.normals, Some(vec![[0.0, 0.0, 1.0]; 3]));
    assert_eq!(m.attributes.len(), 3);
    assert_eq!(m.attributes[0].data, AttributeData::U8(vec![255, 0, 0]));
    let c = read_points(&p).unwrap();
    assert_eq!(c.normals, vec![[0.0, 0.0, 1.0]; 3]);
}

#[test]
fn malformed_off_files_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    for (text, needles) in [
        (&b""[..], &["empty", "OFF header"][..]),
        (b"OFF\n", &["ends before the counts"]),
        (b"OFF\n3\n", &["line 2", "expected the counts"]),
        (b"OFF\n-1 0 0\n", &["line 2", "'-1' is not a vertex count"]),
        (
            b"OFF 3 1 0\n0 0 0\n1 0 0\n",
            &["truncated", "line 1 declares 3 vertices", "after 2"],
        ),
        (
            b"OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
            &["line 5", "vertex 3", "3 vertices"],
        ),
        (
            b"OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n",
            &["line 5", "3 vertex indices", "says 4"],
        ),
        (
            b"OFF 1 0 0\n0 0\n",
            &["line 2", "found 2 numbers", "expected 3"],
        ),
        (
            b"NOFF 1 0 0\n0 0 0\n",
            &["line 2", "expected 6 (x y z nx ny nz)"],
        ),
        (b"4OFF 1 0 0\n0 0 0 0\n", &["line 1", "4-dimensional"]),
    ] {
        let p = write_file(dir.path(), "bad.off", text);
        assert_parse(read_mesh(&p).unwrap_err(), needles);
    }
    // A huge declared count with a tiny body: an error, not a huge reservation.
    let p = write_file(
        dir.path(),
        "big.off",
        b"OFF 4000000000 4000000000 0\n0 0 0\n",
    );
    assert_parse(read_mesh(&p).unwrap_err(), &["truncated"]);
}

// ---------------------------------------------------------------------------------------------
// STL.

#[test]
fn stl_detection_and_errors() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(1, [0.0; 3], 1.0);
    let p = dir.path().join("m.stl");
    write_mesh(&p, &m, &WriteOptions::default()).unwrap();
    let mut bytes = fs::read(&p).unwrap();
    // A binary file whose header starts with "solid", as some exporters write: its size
    // says binary.
    bytes[..5].copy_from_slice(b"solid");
    let p2 = write_file(dir.path(), "solid.stl", &bytes);
    assert_eq!(read_mesh(&p2).unwrap().triangles.len(), m.triangles.len());
    // Truncated binary (not starting with "solid").
    let p3 = write_file(dir.path(), "cut.stl", &fs::read(&p).unwrap()[..500]);
    assert_parse(read_mesh(&p3).unwrap_err(), &["truncated", "32 triangles"]);
    let p4 = write_file(dir.path(), "short.stl", b"\0\0\0");
    assert_parse(read_mesh(&p4).unwrap_err(), &["not an STL file"]);
    for (text, needles) in [
        (
            &b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n"[..],
            &["line 4", "2 coordinates"][..],
        ),
        (
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nendloop\n",
            &["line 5", "has 1 vertices"],
        ),
        (
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
            &["ends inside a facet"],
        ),
        (
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertx 0 0 0\n",
            &["line 4", "unexpected 'vertx'"],
        ),
    ] {
        let p = write_file(dir.path(), "bad.stl", text);
        assert_parse(read_mesh(&p).unwrap_err(), needles);
    }
    // Keywords in capitals; a quad facet is fan-triangulated; STL vertices as a cloud have no
    // normals.
    let p = write_file(
        dir.path(),
        "quad.stl",
        b"SOLID q\nFACET NORMAL 0 0 1\n OUTER LOOP\n  VERTEX 0 0 0\n  VERTEX 1 0 0\n  \
          VERTEX 1 1 0\n  VERTEX 0 1 0\n ENDLOOP\nENDFACET\nENDSOLID q\n",
    );
    assert_eq!(read_mesh(&p).unwrap().triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(read_cloud(&p).unwrap().len(), 4);
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
}

// ---------------------------------------------------------------------------------------------
// GLB from elsewhere.

/// A GLB file of `json` and `bin` (each padded to 4 bytes).
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut j = json.as_bytes().to_vec();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while !b.len().is_multiple_of(4) {
        b.push(0);
    }
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + j.len() + 8 + b.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    out.extend_from_slice(&(b.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&b);
    out
}

/// Two instances of one quad: positions interleaved with u8 colours (stride 16), u16
/// indices; the first node moved by a matrix, the second a child turned about z.
fn quad_glb() -> Vec<u8> {
    let mut bin = Vec::new();
    for (p, c) in [
        ([0f32, 0.0, 0.0], [255u8, 0, 0, 255]),
        ([1.0, 0.0, 0.0], [0, 255, 0, 255]),
        ([1.0, 1.0, 0.0], [0, 0, 255, 255]),
        ([0.0, 1.0, 0.0], [255, 255, 255, 255]),
    ] {
        for x in p {
            bin.extend_from_slice(&x.to_le_bytes());
        }
        bin.extend_from_slice(&c);
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
      "nodes":[{"mesh":0,"matrix":[1,0,0,0, 0,1,0,0, 0,0,1,0, 10,0,0,1],"children":[1]},
               {"mesh":0,"rotation":[0,0,0.7071067811865476,0.7071067811865476]}],
      "meshes":[{"primitives":[{"attributes":{"POSITION":0,"COLOR_0":1},"indices":2},
                               {"attributes":{"POSITION":0},"mode":1}]}],
      "buffers":[{"byteLength":76}],
      "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":64,"byteStride":16},
                     {"buffer":0,"byteOffset":64,"byteLength":12}],
      "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3"},
                   {"bufferView":0,"byteOffset":12,"componentType":5121,"normalized":true,"count":4,"type":"VEC4"},
                   {"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}]}"#;
    glb(json, &bin)
}

#[test]
fn glb_nodes_interleaved_accessors_and_small_indices() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(dir.path(), "quads.glb", &quad_glb());
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.vertices.len(), 8);
    assert_eq!(
        m.triangles,
        vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    );
    assert_eq!(m.vertices[1], [11.0, 0.0, 0.0]);
    // The child: turned a quarter about z, then moved with its parent.
    let v = m.vertices[5];
    assert!(
        (v[0] - 10.0).abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12,
        "{v:?}"
    );
    assert_eq!(m.normals, None);
    assert_eq!(m.attributes.len(), 3, "opaque colours have no alpha");
    assert_eq!(
        m.attributes[0].data,
        AttributeData::U8(vec![255, 0, 0, 255, 255, 0, 0, 255])
    );
}

#[test]
fn malformed_glb_files_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let good = quad_glb();
    let cases: Vec<(Vec<u8>, Vec<&str>)> = vec![
        (good[..16].to_vec(), vec!["truncated", "GLB header"]),
        (good[..200].to_vec(), vec!["truncated", "JSON chunk"]),
        (
            {
                let mut b = good.clone();
                b[4] = 1;
                b
            },
            vec!["version 1"],
        ),
        (glb("{not json", &[]), vec!["JSON chunk is malformed"]),
        (
            glb(
                r#"{"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"buffers":[{"byteLength":12,"uri":"x.bin"}],"bufferViews":[{"buffer":0,"byteLength":12}],"accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC3"}]}"#,
                &[0; 12],
            ),
            vec!["outside the file", "uri"],
        ),
        (
            glb(
                r#"{"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"buffers":[{"byteLength":12}],"bufferViews":[{"buffer":0,"byteLength":12}],"accessors":[{"bufferView":0,"componentType":5126,"count":1000000,"type":"VEC3"}]}"#,
                &[0; 12],
            ),
            vec!["accessor 0", "1000000 elements", "does not fit"],
        ),
        (
            glb(
                r#"{"scenes":[{"nodes":[0]}],"nodes":[{"children":[0]}]}"#,
                &[],
            ),
            vec!["node 0 is reached twice"],
        ),
        (
            glb(
                r#"{"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1}]}],"buffers":[{"byteLength":16}],"bufferViews":[{"buffer":0,"byteLength":16}],"accessors":[{"bufferView":0,"componentType":5126,"count":1,"type":"VEC3"},{"bufferView":0,"byteOffset":12,"componentType":5125,"count":1,"type":"SCALAR"}]}"#,
                &[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 5, 0, 0, 0],
            ),
            vec!["index refers to vertex 5", "1 vertices"],
        ),
    ];
    for (bytes, needles) in cases {
        let p = write_file(dir.path(), "bad.glb", &bytes);
        assert_parse(read_mesh(&p).unwrap_err(), &needles);
    }
}

// ---------------------------------------------------------------------------------------------
// Clouds from mesh files, and damaged mesh files.

#[test]
fn mesh_files_are_clouds_of_their_vertices() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(1, [1.0, 2.0, 3.0], 0.5);
    for ext in ["obj", "off", "glb", "stl", "ply"] {
        let p = dir.path().join(format!("m.{ext}"));
        write_mesh(&p, &m, &WriteOptions::default()).unwrap();
        let c = read_cloud(&p).unwrap();
        let expected: Vec<[f64; 3]> = m.vertices.iter().map(f32_round).collect();
        let mut got: Vec<[f64; 3]> = c.positions.iter().map(f32_round).collect();
        let mut want = expected.clone();
        got.sort_by(|a, b| a.partial_cmp(b).unwrap());
        want.sort_by(|a, b| a.partial_cmp(b).unwrap());
        assert_eq!(got, want, "{ext}");
        assert_eq!(
            CloudFormat::detect(&p).unwrap() == CloudFormat::Ply,
            ext == "ply"
        );
        if ext == "stl" {
            assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
        } else {
            let oriented = read_points(&p).unwrap();
            assert_eq!(oriented.normals.len(), oriented.len(), "{ext}");
            assert!(oriented.colors().is_some(), "{ext}");
        }
    }
}

#[test]
fn damaged_mesh_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let m = sphere_mesh(1, [0.0; 3], 1.0);
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for (ext, ascii) in [
        ("obj", false),
        ("off", false),
        ("glb", false),
        ("stl", false),
        ("stl", true),
    ] {
        let p = dir.path().join(format!("m{}.{ext}", u8::from(ascii)));
        write_mesh(&p, &m, &WriteOptions { ascii }).unwrap();
        let bytes = fs::read(&p).unwrap();
        files.push((p, bytes));
    }
    files.push((dir.path().join("quads.glb"), quad_glb()));
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for (path, bytes) in &files {
        let name = path.file_name().unwrap().to_str().unwrap();
        let damaged = dir.path().join(format!("damaged-{name}"));
        let step = (bytes.len() / 120).max(1);
        let mut cases: Vec<Vec<u8>> = (0..bytes.len())
            .step_by(step)
            .map(|n| bytes[..n].to_vec())
            .collect();
        for _ in 0..120 {
            let mut b = bytes.clone();
            for _ in 0..1 + rand() % 4 {
                let i = (rand() % b.len() as u64) as usize;
                b[i] = rand() as u8;
            }
            cases.push(b);
        }
        for case in cases {
            fs::write(&damaged, &case).unwrap();
            if let Ok(m) = read_mesh(&damaged) {
                crate::common::harness::check_mesh(&m);
            }
            if let Ok(c) = read_cloud(&damaged) {
                crate::common::harness::check_cloud(&c);
            }
        }
    }
}
