//! Round trips through every reader and writer of `spsr::io` beyond the basic PLY/text tests
//! of `io_roundtrip`: clouds with attributes and without normals, LAS/LAZ, E57 and PCD
//! (written with those formats' own crates), and meshes as PLY, OBJ, STL and GLB; plus a
//! malformed file of each format.

use std::fs;
use std::path::{Path, PathBuf};

use spsr::attributes::{Attribute, AttributeData, ScalarType};
use spsr::io::{
    read_cloud, read_mesh, read_points, read_points_chunks, write_cloud, write_mesh, CloudFormat,
    MeshFormat, WriteOptions,
};
use spsr::{Error, Mesh, PointCloud, ScanOrigin};

use crate::common::{assert_parse, write_file, OCTAHEDRON_TRIANGLES};

/// A small deterministic cloud: positions that need `f64`, unit-ish normals, one NaN point,
/// and attributes of several types.
fn sample_cloud(n: usize) -> PointCloud {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for i in 0..n {
        let t = i as f64 * 0.37;
        positions.push([t.sin() * 1000.1, t.cos() / 3.0, 1e6 + t]);
        normals.push([t.cos(), -t.sin(), 0.25]);
    }
    positions[1] = [f64::NAN, 0.0, 0.0];
    normals[2] = [0.0; 3];
    let u8s = |k: usize| AttributeData::U8((0..n).map(|i| ((i * k) % 256) as u8).collect());
    let attributes = vec![
        Attribute::new("red", u8s(3)),
        Attribute::new("green", u8s(5)),
        Attribute::new("blue", u8s(7)),
        Attribute::new(
            "confidence",
            AttributeData::F32((0..n).map(|i| i as f32 / 7.0).collect()),
        ),
        Attribute::new(
            "label",
            AttributeData::I32((0..n).map(|i| i as i32 - 5).collect()),
        ),
        Attribute::new(
            "time",
            AttributeData::F64((0..n).map(|i| 1e9 + i as f64 * 1e-7).collect()),
        ),
        Attribute::new(
            "flag",
            AttributeData::I8((0..n).map(|i| -(i as i8 % 3)).collect()),
        ),
        Attribute::new(
            "count",
            AttributeData::U16((0..n).map(|i| i as u16 * 1000).collect()),
        ),
    ];
    PointCloud {
        positions,
        normals,
        attributes,
        scan_origins: vec![
            ScanOrigin {
                first_point: 0,
                origin: [0.1, 0.2, 0.3],
            },
            ScanOrigin {
                first_point: 4,
                origin: [-1.0, 1e6, 3.5],
            },
        ],
    }
}

/// Cloud equality where NaN equals NaN.
fn same_cloud(a: &PointCloud, b: &PointCloud) {
    let same = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
    assert_eq!(a.len(), b.len());
    for (p, q) in a.positions.iter().zip(&b.positions) {
        assert!((0..3).all(|k| same(p[k], q[k])), "{p:?} != {q:?}");
    }
    assert_eq!(a.normals, b.normals);
    assert_eq!(a.attributes, b.attributes);
    assert_eq!(a.scan_origins, b.scan_origins);
}

// ---------------------------------------------------------------------------------------------
// PLY and text clouds.

#[test]
fn ply_clouds_round_trip_with_attributes_types_and_scan_origins() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = sample_cloud(10);
    for ascii in [false, true] {
        let p = dir.path().join(format!("c{ascii}.ply"));
        write_cloud(&p, &cloud, &WriteOptions { ascii }).unwrap();
        let text = String::from_utf8_lossy(&fs::read(&p).unwrap()).into_owned();
        // Positions need double; normals are exact in float; attributes keep their type.
        for line in [
            "property double x",
            "property double nx",
            "property uchar red",
            "property int label",
            "property char flag",
            "property ushort count",
            "property double time",
            "comment spsr scan_origin 4 -1.0 1000000.0 3.5",
        ] {
            assert!(text.contains(line), "{line} missing (ascii {ascii})");
        }
        same_cloud(&read_cloud(&p).unwrap(), &cloud);
        // And read_points accepts it.
        assert_eq!(read_points(&p).unwrap().len(), 10);
    }
}

/// The chunks of `read_points_chunks`, and their concatenation.
fn chunks(path: &Path, chunk: usize) -> (Vec<usize>, PointCloud) {
    let mut sizes = Vec::new();
    let mut all: Option<PointCloud> = None;
    read_points_chunks(path, chunk, &mut |c| {
        sizes.push(c.len());
        match &mut all {
            None => all = Some(c),
            Some(a) => a.append(c).unwrap(),
        }
        Ok(())
    })
    .unwrap();
    (sizes, all.unwrap())
}

/// Each chunk's scan origins, as (first point, x of the origin).
fn chunk_origins(path: &Path, chunk: usize) -> Vec<Vec<(usize, f64)>> {
    let mut out = Vec::new();
    read_points_chunks(path, chunk, &mut |c| {
        out.push(
            c.scan_origins
                .iter()
                .map(|o| (o.first_point, o.origin[0]))
                .collect(),
        );
        Ok(())
    })
    .unwrap();
    out
}

#[test]
fn chunked_reading_gives_the_whole_file_in_order() {
    let dir = tempfile::tempdir().unwrap();
    let mut cloud = sample_cloud(23);
    cloud.scan_origins.push(ScanOrigin {
        first_point: 12,
        origin: [5.0, 6.0, 7.0],
    });
    for (name, ascii) in [("c.ply", false), ("a.ply", true), ("c.xyz", false)] {
        let p = dir.path().join(name);
        write_cloud(&p, &cloud, &WriteOptions { ascii }).unwrap();
        let whole = read_points(&p).unwrap();
        let (sizes, joined) = chunks(&p, 5);
        assert_eq!(sizes, [5, 5, 5, 5, 3], "{name}");
        let same = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
        for (a, b) in joined.positions.iter().zip(&whole.positions) {
            assert!((0..3).all(|k| same(a[k], b[k])), "{name}");
        }
        assert_eq!(joined.normals, whole.normals, "{name}");
        if name.ends_with("ply") {
            assert_eq!(joined.attributes, whole.attributes, "{name}");
        }
        let (sizes, one) = chunks(&p, 1000);
        assert_eq!(sizes, [23]);
        same_cloud(&one, &whole);
    }
    // Scan origins, counted from each chunk's first point: the one in force, then any new.
    let p = dir.path().join("c.ply");
    assert_eq!(
        chunk_origins(&p, 5),
        [
            vec![(0, 0.1), (4, -1.0)],
            vec![(0, -1.0)],
            vec![(0, -1.0), (2, 5.0)],
            vec![(0, 5.0)],
            vec![(0, 5.0)],
        ]
    );
    // LAS/LAZ: whole decoder chunks.
    let p = dir.path().join("scan.laz");
    let pos = write_las(&p, 70_000, true);
    let (sizes, joined) = chunks(&p, 1000);
    assert_eq!(sizes, [65_536, 4_464]);
    assert_eq!(joined.len(), pos.len());
    same_cloud(&joined, &read_points(&p).unwrap());
    // Errors: a chunk of 0; an error of the callback stops the reading.
    assert!(matches!(
        read_points_chunks(&p, 0, &mut |_| Ok(())),
        Err(Error::InvalidParameter { .. })
    ));
    let mut calls = 0;
    let r = read_points_chunks(&dir.path().join("c.ply"), 5, &mut |_| {
        calls += 1;
        Err(Error::invalid("stop", 1, "nothing"))
    });
    assert!(r.is_err() && calls == 1);
}

#[test]
fn ply_cloud_normals_are_double_unless_float_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("n.ply");
    let mut cloud = PointCloud::new(vec![[1.0, 2.0, 3.0]], vec![[0.1, 0.0, 0.0]]).unwrap();
    write_cloud(&p, &cloud, &WriteOptions::default()).unwrap();
    let text = String::from_utf8_lossy(&fs::read(&p).unwrap()).into_owned();
    assert!(text.contains("property float x") && text.contains("property double nx"));
    assert_eq!(read_cloud(&p).unwrap(), cloud);
    cloud.normals[0] = [0.5, 0.0, 0.0];
    write_cloud(&p, &cloud, &WriteOptions::default()).unwrap();
    let text = String::from_utf8_lossy(&fs::read(&p).unwrap()).into_owned();
    assert!(text.contains("property float nx"));
    assert_eq!(read_cloud(&p).unwrap(), cloud);
}

#[test]
fn clouds_without_normals_read_and_write() {
    let dir = tempfile::tempdir().unwrap();
    let mut cloud = PointCloud::from_positions(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]]);
    assert!(!cloud.has_normals());
    cloud.attributes.push(Attribute::new(
        "intensity",
        AttributeData::U16(vec![7, 65535]),
    ));
    let p = dir.path().join("nonormals.ply");
    write_cloud(&p, &cloud, &WriteOptions::default()).unwrap();
    let text = String::from_utf8_lossy(&fs::read(&p).unwrap()).into_owned();
    assert!(!text.contains("nx"));
    let back = read_cloud(&p).unwrap();
    assert_eq!(back, cloud);
    assert_eq!(
        back.find_scalar(&["quality", "intensity"]).unwrap().len(),
        2
    );
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
}

#[test]
fn write_cloud_rejects_inconsistent_clouds_and_unusable_names() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.ply");
    let mut cloud = PointCloud::from_positions(vec![[0.0; 3]; 2]);
    cloud.normals = vec![[0.0; 3]];
    let e = write_cloud(&p, &cloud, &WriteOptions::default()).unwrap_err();
    assert!(matches!(e, Error::Output { .. }) && e.to_string().contains("1 normals for 2 points"));
    cloud.normals.clear();
    cloud
        .attributes
        .push(Attribute::new("a", AttributeData::U8(vec![1])));
    let e = write_cloud(&p, &cloud, &WriteOptions::default()).unwrap_err();
    assert!(
        e.to_string()
            .contains("attribute 'a' has 1 values for 2 points"),
        "{e}"
    );
    cloud.attributes[0] = Attribute::new("z", AttributeData::U8(vec![1, 2]));
    let e = write_cloud(&p, &cloud, &WriteOptions::default()).unwrap_err();
    assert!(e.to_string().contains("'z'"), "{e}");
    cloud.attributes[0].name = "two words".into();
    assert!(write_cloud(&p, &cloud, &WriteOptions::default()).is_err());
    assert!(!p.exists());
}

#[test]
fn text_layouts_three_six_and_nine_columns() {
    let dir = tempfile::tempdir().unwrap();
    let p = write_file(dir.path(), "a.xyz", b"1 2 3\n4 5 6 7\n");
    let c = read_cloud(&p).unwrap();
    assert_eq!(c.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert!(!c.has_normals() && c.attributes.is_empty());
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));

    let p = write_file(
        dir.path(),
        "b.txt",
        b"1 2 3 0 0 1 255 0 10\n4,5,6,0,1,0,1,2,3,99\n",
    );
    let c = read_points(&p).unwrap();
    assert_eq!(c.normals[1], [0.0, 1.0, 0.0]);
    let colors = c.colors().unwrap();
    assert_eq!(colors.red.data, AttributeData::U8(vec![255, 1]));
    assert_eq!(colors.blue.data, AttributeData::U8(vec![10, 3]));

    let p = write_file(dir.path(), "c.txt", b"1 2 3 0 0 1 0.5 0.25 1\n");
    let c = read_cloud(&p).unwrap();
    assert_eq!(
        c.attribute("green").unwrap().data,
        AttributeData::F32(vec![0.25])
    );

    // The first line fixes the layout: a later line with fewer values is an error.
    let p = write_file(dir.path(), "d.txt", b"1 2 3 0 0 1 5 5 5\n1 2 3 0 0 1\n");
    assert_parse(
        read_cloud(&p).unwrap_err(),
        &["line 2", "found 6 numbers, expected 9"],
    );
    let p = write_file(dir.path(), "e.txt", b"1 2\n");
    assert_parse(read_cloud(&p).unwrap_err(), &["line 1", "at least 3"]);
}

// ---------------------------------------------------------------------------------------------
// LAS / LAZ.

/// A 192-byte Extra Bytes descriptor.
fn extra_descriptor(name: &str, data_type: u8, scale_offset: Option<(f64, f64)>) -> Vec<u8> {
    let mut d = vec![0u8; 192];
    d[2] = data_type;
    d[4..4 + name.len()].copy_from_slice(name.as_bytes());
    if let Some((s, o)) = scale_offset {
        d[3] = 0b1_1000;
        d[112..120].copy_from_slice(&s.to_le_bytes());
        d[136..144].copy_from_slice(&o.to_le_bytes());
    }
    d
}

/// Writes `n` LAS points (format 3: GPS time and colour) with extra bytes
/// `NormalX NormalY NormalZ` (f32), `confidence` (f32) and a scaled i16 `temperature`.
fn write_las(path: &Path, n: usize, with_normals: bool) -> Vec<[f64; 3]> {
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(3).unwrap();
    let mut data = Vec::new();
    let mut extra_len = 0;
    if with_normals {
        for name in ["NormalX", "NormalY", "NormalZ"] {
            data.extend(extra_descriptor(name, 9, None));
        }
        extra_len += 12;
    }
    data.extend(extra_descriptor("confidence", 9, None));
    data.extend(extra_descriptor("temperature", 4, Some((0.5, 10.0))));
    extra_len += 6;
    b.point_format.extra_bytes = extra_len;
    b.vlrs.push(las::Vlr {
        user_id: "LASF_Spec".into(),
        record_id: 4,
        description: "extra bytes".into(),
        data,
    });
    let header = b.into_header().unwrap();
    let mut w = las::Writer::from_path(path, header).unwrap();
    let mut positions = Vec::new();
    for i in 0..n {
        let p = [i as f64 * 0.25, 1000.0 - i as f64 * 0.125, 0.001 * i as f64];
        positions.push(p);
        let mut extra = Vec::new();
        if with_normals {
            for c in [1.0f32, -(i as f32), 0.5] {
                extra.extend(c.to_le_bytes());
            }
        }
        extra.extend((i as f32 * 0.5).to_le_bytes());
        extra.extend((i as i16).wrapping_sub(3).to_le_bytes());
        w.write_point(las::Point {
            x: p[0],
            y: p[1],
            z: p[2],
            intensity: (i as u16).wrapping_mul(100),
            return_number: 1,
            number_of_returns: 2,
            classification: las::point::Classification::new(2 + (i % 3) as u8).unwrap(),
            gps_time: Some(1000.5 + i as f64),
            color: Some(las::Color::new((i as u16).wrapping_mul(256), 65535, 7)),
            extra_bytes: extra,
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    positions
}

#[test]
fn las_and_laz_round_trip_with_extra_bytes_normals() {
    let dir = tempfile::tempdir().unwrap();
    for ext in ["las", "laz"] {
        let p = dir.path().join(format!("scan.{ext}"));
        let pos = write_las(&p, 70_000, true); // more than one 65,536-point chunk
        assert_eq!(CloudFormat::detect(&p).unwrap(), CloudFormat::Las);
        let c = read_points(&p).unwrap();
        assert_eq!(c.len(), pos.len());
        for (a, b) in c.positions.iter().zip(&pos) {
            assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-9), "{a:?} {b:?}");
        }
        assert_eq!(c.normals[3], [1.0, -3.0, 0.5]);
        assert_eq!(c.normals[69_999], [1.0, -69_999.0, 0.5]);
        let names: Vec<&str> = c.attributes.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "intensity",
                "return_number",
                "number_of_returns",
                "classification",
                "scan_angle",
                "user_data",
                "point_source_id",
                "gps_time",
                "red",
                "green",
                "blue",
                "confidence",
                "temperature"
            ]
        );
        let get = |n: &str, i: usize| c.attribute(n).unwrap().data.get(i).unwrap();
        assert_eq!(
            c.attribute("red").unwrap().data.scalar_type(),
            ScalarType::U16
        );
        assert_eq!(get("red", 5), 5.0 * 256.0);
        assert_eq!(get("green", 5), 65535.0);
        assert_eq!(get("classification", 4), 3.0);
        assert_eq!(get("number_of_returns", 4), 2.0);
        assert_eq!(get("gps_time", 9), 1009.5);
        assert_eq!(get("intensity", 9), 900.0);
        assert_eq!(
            c.attribute("confidence").unwrap().data.scalar_type(),
            ScalarType::F32
        );
        assert_eq!(get("confidence", 9), 4.5);
        // Scaled: (i - 3) * 0.5 + 10.
        assert_eq!(
            c.attribute("temperature").unwrap().data.scalar_type(),
            ScalarType::F64
        );
        assert_eq!(get("temperature", 0), 8.5);
        assert_eq!(get("temperature", 7), 12.0);
    }
}

#[test]
fn las_without_normals_and_malformed_las() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("plain.las");
    write_las(&p, 10, false);
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
    let c = read_cloud(&p).unwrap();
    assert!(!c.has_normals() && c.len() == 10);

    let bytes = fs::read(&p).unwrap();
    let t = write_file(dir.path(), "trunc.las", &bytes[..bytes.len() - 7]);
    assert_parse(read_cloud(&t).unwrap_err(), &["truncated", "of the 10"]);
    let t = write_file(dir.path(), "head.las", &bytes[..100]);
    assert_parse(read_cloud(&t).unwrap_err(), &["LAS"]);
    let mut bad = bytes.clone();
    bad[..4].copy_from_slice(b"LASX");
    let t = write_file(dir.path(), "magic.las", &bad);
    assert_parse(read_cloud(&t).unwrap_err(), &["LAS"]);

    // A LAZ file whose compressed points are garbage: an error, never a panic.
    let z = dir.path().join("good.laz");
    write_las(&z, 2000, true);
    let mut bytes = fs::read(&z).unwrap();
    let n = bytes.len();
    for (k, b) in bytes[n / 2..n - 200].iter_mut().enumerate() {
        *b = (k * 131 % 251) as u8;
    }
    let t = write_file(dir.path(), "garbage.laz", &bytes);
    assert!(matches!(
        read_cloud(&t),
        Err(Error::Parse { .. } | Error::Io { .. })
    ));
    let t = write_file(dir.path(), "short.laz", &bytes[..n / 2]);
    assert!(matches!(
        read_cloud(&t),
        Err(Error::Parse { .. } | Error::Io { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// E57.

fn unknown(ns: &str, name: &str, dt: e57::RecordDataType) -> e57::Record {
    e57::Record {
        name: e57::RecordName::Unknown {
            namespace: ns.into(),
            name: name.into(),
        },
        data_type: dt,
    }
}

/// Two scans: Cartesian with normals, colour and intensity, posed by a 90° turn about z and
/// a shift; spherical without normals, with float intensity, unposed.
fn write_e57(path: &Path) {
    use e57::{Record, RecordValue as V};
    let mut w = e57::E57Writer::from_file(path, "file-guid").unwrap();
    w.register_extension(e57::Extension::new(
        "nor",
        "http://www.libe57.org/E57_NOR_surface_normals.txt",
    ))
    .unwrap();
    let proto = vec![
        Record::CARTESIAN_X_F64,
        Record::CARTESIAN_Y_F64,
        Record::CARTESIAN_Z_F64,
        unknown("nor", "normalX", e57::RecordDataType::F32),
        unknown("nor", "normalY", e57::RecordDataType::F32),
        unknown("nor", "normalZ", e57::RecordDataType::F32),
        Record::COLOR_RED_U8,
        Record::COLOR_GREEN_U8,
        Record::COLOR_BLUE_U8,
        Record::INTENSITY_U16,
    ];
    let mut pc = w.add_pointcloud("scan-1", proto).unwrap();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    pc.set_transform(Some(e57::Transform {
        rotation: e57::Quaternion {
            w: h,
            x: 0.0,
            y: 0.0,
            z: h,
        },
        translation: e57::Translation {
            x: 10.0,
            y: 20.0,
            z: 30.0,
        },
    }));
    for i in 0..5 {
        pc.add_point(vec![
            V::Double(1.0 + i as f64),
            V::Double(0.0),
            V::Double(2.0),
            V::Single(1.0),
            V::Single(0.0),
            V::Single(0.0),
            V::Integer(i * 50),
            V::Integer(255),
            V::Integer(0),
            V::Integer(1000 * i),
        ])
        .unwrap();
    }
    pc.finalize().unwrap();
    let proto = vec![
        Record::SPHERICAL_RANGE_F64,
        Record::SPHERICAL_AZIMUTH_F64,
        Record::SPHERICAL_ELEVATION_F64,
        Record::INTENSITY_UNIT_F32,
    ];
    let mut pc = w.add_pointcloud("scan-2", proto).unwrap();
    for i in 0..3 {
        pc.add_point(vec![
            V::Double(2.0),
            V::Double(std::f64::consts::FRAC_PI_2),
            V::Double(0.0),
            V::Single(i as f32 * 0.25),
        ])
        .unwrap();
    }
    pc.finalize().unwrap();
    w.finalize().unwrap();
}

#[test]
fn e57_scans_are_posed_into_one_frame() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("scans.e57");
    write_e57(&p);
    assert_eq!(CloudFormat::detect(&p).unwrap(), CloudFormat::E57);
    let c = read_cloud(&p).unwrap();
    assert_eq!(c.len(), 8);
    let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-9);
    // 90° about z: (x, y, z) -> (-y, x, z), then + (10, 20, 30).
    assert!(
        close(c.positions[2], [10.0, 23.0, 32.0]),
        "{:?}",
        c.positions[2]
    );
    assert!(close(c.normals[2], [0.0, 1.0, 0.0]), "{:?}", c.normals[2]);
    // Spherical (r 2, azimuth 90°, elevation 0) = (0, 2, 0), no pose; no normals there.
    assert!(
        close(c.positions[6], [0.0, 2.0, 0.0]),
        "{:?}",
        c.positions[6]
    );
    assert_eq!(c.normals[6], [0.0; 3]);
    assert_eq!(
        c.scan_origins,
        vec![
            ScanOrigin {
                first_point: 0,
                origin: [10.0, 20.0, 30.0]
            },
            ScanOrigin {
                first_point: 5,
                origin: [0.0; 3]
            }
        ]
    );
    let colors = c.colors().unwrap();
    assert_eq!(
        colors.red.data,
        AttributeData::U8(vec![0, 50, 100, 150, 200, 0, 0, 0])
    );
    // Intensity is u16 in one scan and f32 in the other: kept as f64.
    let int = &c.attribute("intensity").unwrap().data;
    assert_eq!(int.scalar_type(), ScalarType::F64);
    assert_eq!(int.get(3), Some(3000.0));
    assert_eq!(int.get(7), Some(0.5));
    assert!(read_points(&p).is_ok());
}

#[test]
fn malformed_e57_files_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("scans.e57");
    write_e57(&p);
    let bytes = fs::read(&p).unwrap();
    let t = write_file(dir.path(), "trunc.e57", &bytes[..bytes.len() - 1000]);
    assert_parse(read_cloud(&t).unwrap_err(), &["E57"]);
    let t = write_file(dir.path(), "text.e57", b"ASTM-E57 but not really\n");
    assert_parse(read_cloud(&t).unwrap_err(), &["E57"]);
    let mut bad = bytes.clone();
    let n = bad.len();
    for b in &mut bad[1024..n / 2] {
        *b ^= 0x5a;
    }
    let t = write_file(dir.path(), "corrupt.e57", &bad);
    assert_parse(read_cloud(&t).unwrap_err(), &["E57"]);
}

// ---------------------------------------------------------------------------------------------
// PCD.

fn pcd_schema() -> pcd_rs::Schema {
    use pcd_rs::ValueKind as K;
    [
        ("x", K::F32, 1),
        ("y", K::F32, 1),
        ("z", K::F64, 1),
        ("normal_x", K::F32, 1),
        ("normal_y", K::F32, 1),
        ("normal_z", K::F32, 1),
        ("rgb", K::F32, 1),
        ("label", K::U32, 1),
        ("hist", K::I16, 3),
    ]
    .into_iter()
    .collect()
}

fn write_pcd(path: &Path, kind: pcd_rs::DataKind, n: usize) {
    use pcd_rs::Field as F;
    let mut w = pcd_rs::WriterInit {
        width: n as u64,
        height: 1,
        viewpoint: pcd_rs::ViewPoint {
            tx: 1.0,
            ty: 2.0,
            tz: 3.0,
            ..Default::default()
        },
        data_kind: kind,
        schema: Some(pcd_schema()),
        version: None,
    }
    .create::<pcd_rs::DynRecord, _>(path)
    .unwrap();
    for i in 0..n {
        let rgb = f32::from_bits((i as u32 % 256) << 16 | 128 << 8 | 7);
        w.push(&pcd_rs::DynRecord(vec![
            F::F32(vec![i as f32 * 0.5]),
            F::F32(vec![-(i as f32)]),
            F::F64(vec![0.1 * i as f64]),
            F::F32(vec![0.0]),
            F::F32(vec![1.0]),
            F::F32(vec![if i == 3 { f32::NAN } else { 0.0 }]),
            F::F32(vec![rgb]),
            F::U32(vec![i as u32 * 7]),
            F::I16(vec![i as i16, -(i as i16), 5]),
        ]))
        .unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn pcd_ascii_binary_and_compressed_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for (name, kind) in [
        ("a.pcd", pcd_rs::DataKind::Ascii),
        ("b.pcd", pcd_rs::DataKind::Binary),
        ("c.pcd", pcd_rs::DataKind::BinaryCompressed),
    ] {
        let p = dir.path().join(name);
        let n = 20_000;
        write_pcd(&p, kind, n);
        assert_eq!(CloudFormat::detect(&p).unwrap(), CloudFormat::Pcd);
        let c = read_points(&p).unwrap();
        assert_eq!(c.len(), n, "{name}");
        assert_eq!(c.positions[9], [4.5, -9.0, 0.1 * 9.0], "{name}");
        assert_eq!(c.normals[9], [0.0, 1.0, 0.0]);
        assert!(c.normals[3][2].is_nan());
        let colors = c.colors().unwrap();
        assert_eq!(colors.red.data.get(300), Some(300.0 % 256.0), "{name}");
        assert_eq!(colors.green.data.get(300), Some(128.0));
        assert_eq!(colors.blue.data.get(300), Some(7.0));
        assert!(colors.alpha.is_none());
        let names: Vec<&str> = c.attributes.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            ["red", "green", "blue", "label", "hist_0", "hist_1", "hist_2"]
        );
        assert_eq!(c.attribute("label").unwrap().data.get(11), Some(77.0));
        assert_eq!(c.attribute("hist_1").unwrap().data, {
            AttributeData::I16((0..n).map(|i| -(i as i16)).collect())
        });
        assert_eq!(
            c.scan_origins,
            vec![ScanOrigin {
                first_point: 0,
                origin: [1.0, 2.0, 3.0]
            }]
        );
    }
}

#[test]
fn pcd_rgba_as_unsigned_and_positions_only() {
    let dir = tempfile::tempdir().unwrap();
    let text = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgba _\nSIZE 4 4 4 4 1\nTYPE F F F U U\nCOUNT 1 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 4278190335 0\nnan nan nan 2164195328 9\n";
    // 4278190335 = 0xFF0000FF: alpha 255, blue 255; 2164195328 = 0x80FF0000.
    let p = write_file(dir.path(), "cloud.dat", text.as_bytes());
    let c = read_cloud(&p).unwrap();
    assert!(!c.has_normals());
    assert!(c.positions[1][0].is_nan());
    let colors = c.colors().unwrap();
    assert_eq!(
        colors.alpha.unwrap().data,
        AttributeData::U8(vec![255, 128])
    );
    assert_eq!(colors.red.data, AttributeData::U8(vec![0, 255]));
    assert_eq!(colors.blue.data, AttributeData::U8(vec![255, 0]));
    assert_eq!(c.attributes.len(), 4, "padding is skipped");
    assert!(c.scan_origins.is_empty());
    assert!(matches!(read_points(&p), Err(Error::MissingNormals { .. })));
}

#[test]
fn malformed_pcd_files_name_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let head = |fields: &str, size: &str, ty: &str, rest: &str| {
        format!("VERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {ty}\n{rest}")
    };
    let cases: Vec<(String, Vec<&str>)> = vec![
        (
            head(
                "x y z",
                "4 4",
                "F F F",
                "WIDTH 1\nPOINTS 1\nDATA ascii\n1 2 3\n",
            ),
            vec!["3 FIELDS but 2 SIZE"],
        ),
        (
            head("x y z", "4 4 4", "F F Q", "WIDTH 1\nDATA ascii\n1 2 3\n"),
            vec!["header line 4", "TYPE 'Q'"],
        ),
        (
            head("x y z", "4 4 2", "F F F", "WIDTH 1\nDATA ascii\n1 2 3\n"),
            vec!["field 'z'", "SIZE 2"],
        ),
        (
            head("x y", "4 4", "F F", "WIDTH 1\nDATA ascii\n1 2\n"),
            vec!["only some of the fields x y z"],
        ),
        (
            head("a b", "4 4", "F F", "WIDTH 1\nDATA ascii\n1 2\n"),
            vec!["no x y z"],
        ),
        (
            head(
                "x y z",
                "4 4 4",
                "F F F",
                "WIDTH 2\nHEIGHT 1\nPOINTS 3\nDATA ascii\n",
            ),
            vec!["POINTS 3", "WIDTH × HEIGHT = 2 × 1"],
        ),
        (
            head("x y z", "4 4 4", "F F F", "WIDTH 2\nDATA ascii\n1 2 3\n"),
            vec!["truncated", "point 1 of 2"],
        ),
        (
            head(
                "x y z",
                "4 4 4",
                "F F F",
                "WIDTH 2\nDATA ascii\n1 2 3\n1 2 x\n",
            ),
            vec!["line 8", "'x'", "field 'z'"],
        ),
        (
            head("x y z", "4 4 4", "F F F", "WIDTH 1\nDATA ascii\n1 2 3 4\n"),
            vec!["line 7", "too many"],
        ),
        (
            head("x y z", "4 4 4", "F F F", "WIDTH 1\nDATA zipped\n"),
            vec!["unknown DATA 'zipped'"],
        ),
        (
            head("x y z", "4 4 4", "F F F", "WIDTH 1\nSTUFF 3\nDATA ascii\n"),
            vec!["unknown keyword 'STUFF'"],
        ),
        (
            head("x y z", "4 4 4", "F F F", "WIDTH 1\n"),
            vec!["no DATA line"],
        ),
        (
            head(
                "x y z",
                "4 4 4",
                "F F F",
                "WIDTH 3\nDATA binary\n0123456789ab",
            ),
            vec!["truncated", "points 0 to 2"],
        ),
    ];
    for (i, (text, needles)) in cases.iter().enumerate() {
        let p = write_file(dir.path(), &format!("m{i}.pcd"), text.as_bytes());
        assert_parse(read_cloud(&p).unwrap_err(), needles);
    }
    // Compressed bodies: sizes that disagree with the header, truncation, corruption.
    let p = dir.path().join("c.pcd");
    write_pcd(&p, pcd_rs::DataKind::BinaryCompressed, 500);
    let bytes = fs::read(&p).unwrap();
    let body = bytes
        .windows(23)
        .position(|w| w == b"DATA binary_compressed\n")
        .unwrap()
        + 23;
    let mut bad = bytes.clone();
    bad[body + 4] ^= 1; // uncompressed size
    let t = write_file(dir.path(), "c1.pcd", &bad);
    assert_parse(read_cloud(&t).unwrap_err(), &["decompresses to"]);
    let t = write_file(dir.path(), "c2.pcd", &bytes[..bytes.len() - 10]);
    assert_parse(read_cloud(&t).unwrap_err(), &["truncated"]);
    let mut bad = bytes.clone();
    for b in &mut bad[body + 8..body + 40] {
        *b = 0xff;
    }
    let t = write_file(dir.path(), "c3.pcd", &bad);
    assert_parse(read_cloud(&t).unwrap_err(), &["compressed"]);
}

// ---------------------------------------------------------------------------------------------
// Format detection.

#[test]
fn formats_are_detected_by_magic_before_extension() {
    let dir = tempfile::tempdir().unwrap();
    let las = dir.path().join("x.las");
    write_las(&las, 3, true);
    let renamed = dir.path().join("lidar.xyz");
    fs::copy(&las, &renamed).unwrap();
    assert_eq!(CloudFormat::detect(&renamed).unwrap(), CloudFormat::Las);
    assert_eq!(read_points(&renamed).unwrap().len(), 3);
    let t = write_file(dir.path(), "pts.PCD", b"1 2 3 0 0 1\n");
    assert_eq!(CloudFormat::detect(&t).unwrap(), CloudFormat::Pcd);
    let t = write_file(dir.path(), "pts.dat", b"1 2 3 0 0 1\n");
    assert_eq!(CloudFormat::detect(&t).unwrap(), CloudFormat::Text);
    assert_eq!(
        MeshFormat::from_path(Path::new("a.GLB")).unwrap(),
        MeshFormat::Glb
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("a.Stl")).unwrap(),
        MeshFormat::Stl
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("a.obj")).unwrap(),
        MeshFormat::Obj
    );
    assert_eq!(
        MeshFormat::from_path(Path::new("a.off")).unwrap(),
        MeshFormat::Off
    );
    assert!(MeshFormat::from_path(Path::new("a.mesh")).is_err());
    assert!(MeshFormat::from_path(Path::new("mesh")).is_err());
}

// ---------------------------------------------------------------------------------------------
// Meshes.

/// An octahedron with normals, colours, another attribute and density.
fn octahedron(center: [f64; 3]) -> Mesh {
    let dirs = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let vertices = dirs
        .iter()
        .map(|d: &[f64; 3]| [0, 1, 2].map(|k| center[k] + 0.5 * d[k]))
        .collect();
    let normals = dirs.iter().map(|d| d.map(|c| c as f32)).collect();
    Mesh {
        vertices,
        triangles: OCTAHEDRON_TRIANGLES.to_vec(),
        density: Some(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5]),
        normals: Some(normals),
        attributes: vec![
            Attribute::new("red", AttributeData::U8(vec![255, 0, 0, 128, 64, 0])),
            Attribute::new("green", AttributeData::U8(vec![0, 255, 0, 128, 64, 0])),
            Attribute::new("blue", AttributeData::U8(vec![0, 0, 255, 128, 64, 0])),
            Attribute::new(
                "quality",
                AttributeData::F64(vec![0.5, 1.5, 2.5, 3.5, 4.5, 5.5]),
            ),
        ],
    }
}

#[test]
fn ply_meshes_keep_normals_attributes_and_density() {
    let dir = tempfile::tempdir().unwrap();
    let m = octahedron([1.0, 2.0, 3.0]);
    for ascii in [false, true] {
        let p = dir.path().join("m.ply");
        write_mesh(&p, &m, &WriteOptions { ascii }).unwrap();
        let back = read_mesh(&p).unwrap();
        assert_eq!(back, m, "ascii {ascii}");
    }
}

#[test]
fn far_meshes_keep_their_precision_in_ply_obj_and_glb() {
    let dir = tempfile::tempdir().unwrap();
    let m = octahedron([500_000.125, 5_000_000.25, 100.0]);
    let p = dir.path().join("utm.ply");
    write_mesh(&p, &m, &WriteOptions::default()).unwrap();
    assert_eq!(read_mesh(&p).unwrap().vertices, m.vertices);
    let o = dir.path().join("utm.obj");
    write_mesh(&o, &m, &WriteOptions::default()).unwrap();
    assert!(fs::read_to_string(&o)
        .unwrap()
        .contains("\nv 500000.625 5000000.25 100 1 0 0\n"));
    let g = dir.path().join("utm.glb");
    write_mesh(&g, &m, &WriteOptions::default()).unwrap();
    let glb = parse_glb(&fs::read(&g).unwrap());
    let t = &glb.json["nodes"][0]["translation"];
    assert_eq!(t[0].as_f64(), Some(500_000.125));
    assert_eq!(t[1].as_f64(), Some(5_000_000.25));
    let pos = glb.floats(&glb.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"]);
    assert_eq!(&pos[..3], &[0.5, 0.0, 0.0]);
}

#[test]
fn obj_writes_colours_normals_and_faces() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.obj");
    let m = octahedron([0.0; 3]);
    write_mesh(&p, &m, &WriteOptions::default()).unwrap();
    let text = fs::read_to_string(&p).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let v: Vec<Vec<f64>> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| l.split(' ').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(v.len(), 6);
    assert_eq!(v[0], [0.5, 0.0, 0.0, 1.0, 0.0, 0.0]);
    assert!((v[3][3] - 128.0 / 255.0).abs() < 1e-6);
    let vn: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("vn "))
        .copied()
        .collect();
    assert_eq!(vn[5], "vn 0 0 -1");
    let faces: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("f "))
        .copied()
        .collect();
    assert_eq!(faces.len(), 8);
    assert_eq!(faces[0], "f 1//1 3//3 5//5");
    // Without normals and colours: plain lines.
    let plain = Mesh {
        vertices: m.vertices.clone(),
        triangles: m.triangles.clone(),
        ..Default::default()
    };
    write_mesh(&p, &plain, &WriteOptions::default()).unwrap();
    let text = fs::read_to_string(&p).unwrap();
    assert!(text.contains("\nv 0.5 0 0\n") && text.contains("\nf 1 3 5\n"));
    assert!(!text.contains("vn"));
}

/// Triangles of an STL file, binary or ASCII, as (normal, corners).
fn read_stl(bytes: &[u8]) -> Vec<([f32; 3], [[f32; 3]; 3])> {
    let f = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    if bytes.starts_with(b"solid") {
        let text = std::str::from_utf8(bytes).unwrap();
        assert!(text.trim_end().ends_with("endsolid spsr"));
        let nums = |l: &str, key: &str| -> [f32; 3] {
            let v: Vec<f32> = l
                .trim()
                .strip_prefix(key)
                .unwrap()
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            [v[0], v[1], v[2]]
        };
        let lines: Vec<&str> = text.lines().collect();
        let mut out = Vec::new();
        for (i, l) in lines.iter().enumerate() {
            if l.trim().starts_with("facet normal") {
                assert_eq!(lines[i + 1].trim(), "outer loop");
                let c = [2, 3, 4].map(|k| nums(lines[i + k], "vertex"));
                out.push((nums(l, "facet normal"), c));
            }
        }
        out
    } else {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        assert_eq!(bytes.len(), 84 + 50 * n);
        (0..n)
            .map(|t| {
                let r = &bytes[84 + 50 * t..];
                let v = |k: usize| [f(&r[k..]), f(&r[k + 4..]), f(&r[k + 8..])];
                (v(0), [v(12), v(24), v(36)])
            })
            .collect()
    }
}

#[test]
fn stl_binary_and_ascii_hold_the_triangles_and_their_normals() {
    let dir = tempfile::tempdir().unwrap();
    let m = octahedron([1.0, 1.0, 1.0]);
    for ascii in [false, true] {
        let p = dir.path().join("m.stl");
        write_mesh(&p, &m, &WriteOptions { ascii }).unwrap();
        let tris = read_stl(&fs::read(&p).unwrap());
        assert_eq!(tris.len(), m.triangles.len());
        for ((n, c), t) in tris.iter().zip(&m.triangles) {
            for k in 0..3 {
                assert_eq!(c[k], m.vertices[t[k] as usize].map(|x| x as f32));
            }
            // Outward: the normal points away from the centre (1, 1, 1), unit length.
            let centroid = [0, 1, 2].map(|a| (c[0][a] + c[1][a] + c[2][a]) / 3.0 - 1.0);
            let dot: f32 = (0..3).map(|a| n[a] * centroid[a]).sum();
            let len: f32 = n.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!(dot > 0.0 && (len - 1.0).abs() < 1e-6, "{n:?}");
        }
    }
}

/// A parsed GLB: its JSON (through `serde_json` as re-exported by `gltf`) and BIN chunk.
struct Glb {
    json: gltf::json::Value,
    bin: Vec<u8>,
}

impl Glb {
    fn accessor(&self, index: &gltf::json::Value) -> (&gltf::json::Value, &[u8]) {
        let a = &self.json["accessors"][index.as_u64().unwrap() as usize];
        let v = &self.json["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let off = v["byteOffset"].as_u64().unwrap() as usize;
        let len = v["byteLength"].as_u64().unwrap() as usize;
        assert_eq!(off % 4, 0, "aligned");
        (a, &self.bin[off..off + len])
    }

    fn floats(&self, index: &gltf::json::Value) -> Vec<f32> {
        let (a, data) = self.accessor(index);
        assert_eq!(a["componentType"], 5126);
        data.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }
}

fn parse_glb(bytes: &[u8]) -> Glb {
    let u = |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    assert_eq!(&bytes[..4], b"glTF");
    assert_eq!(u(4), 2);
    assert_eq!(u(8) as usize, bytes.len());
    let jlen = u(12) as usize;
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(jlen % 4, 0);
    let json: gltf::json::Value =
        gltf::json::deserialize::from_slice(&bytes[20..20 + jlen]).unwrap();
    let mut bin = Vec::new();
    if bytes.len() > 20 + jlen {
        let o = 20 + jlen;
        assert_eq!(&bytes[o + 4..o + 8], b"BIN\0");
        let blen = u(o) as usize;
        assert_eq!(blen % 4, 0);
        bin = bytes[o + 8..o + 8 + blen].to_vec();
        assert_eq!(o + 8 + blen, bytes.len());
        assert_eq!(json["buffers"][0]["byteLength"].as_u64(), Some(blen as u64));
    }
    // The gltf crate validates the document (references, POSITION min/max, ...).
    gltf::Gltf::from_slice(bytes).expect("valid glTF");
    Glb { json, bin }
}

#[test]
fn glb_holds_positions_normals_colours_density_and_indices() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.glb");
    let mut m = octahedron([1.0, 2.0, 3.0]);
    m.normals.as_mut().unwrap()[1] = [0.0, 0.0, 0.0]; // written as +Z
    m.normals.as_mut().unwrap()[2] = [0.0, 3.0, 0.0]; // normalised
    write_mesh(&p, &m, &WriteOptions::default()).unwrap();
    let glb = parse_glb(&fs::read(&p).unwrap());
    let prim = &glb.json["meshes"][0]["primitives"][0];
    assert_eq!(prim["mode"], 4);
    let attrs = &prim["attributes"];
    let (pa, _) = glb.accessor(&attrs["POSITION"]);
    assert_eq!(pa["count"], 6);
    assert_eq!(pa["min"], gltf::json::Value::from(vec![0.5, 1.5, 2.5]));
    assert_eq!(pa["max"], gltf::json::Value::from(vec![1.5, 2.5, 3.5]));
    let pos = glb.floats(&attrs["POSITION"]);
    assert_eq!(&pos[3..6], &[0.5, 2.0, 3.0]);
    let nor = glb.floats(&attrs["NORMAL"]);
    assert_eq!(&nor[3..9], &[0.0, 0.0, 1.0, 0.0, 1.0, 0.0]);
    let dens = glb.floats(&attrs["_DENSITY"]);
    assert_eq!(dens, m.density.clone().unwrap());
    let (ca, cdata) = glb.accessor(&attrs["COLOR_0"]);
    assert_eq!(
        (ca["componentType"].as_u64(), ca["type"].as_str()),
        (Some(5123), Some("VEC4"))
    );
    assert_eq!(ca["normalized"], true);
    let c: Vec<u16> = cdata
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    assert_eq!(&c[..4], &[65535, 0, 0, 65535]);
    // sRGB 128/255 is linear 0.2158.
    assert!((c[12] as f64 / 65535.0 - 0.2158).abs() < 1e-3, "{}", c[12]);
    let (ia, idata) = glb.accessor(&prim["indices"]);
    assert_eq!(
        (ia["componentType"].as_u64(), ia["count"].as_u64()),
        (Some(5125), Some(24))
    );
    let idx: Vec<u32> = idata
        .chunks_exact(4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let expected: Vec<u32> = m.triangles.iter().flatten().copied().collect();
    assert_eq!(idx, expected);

    // Positions only, and an empty mesh.
    let plain = Mesh {
        vertices: m.vertices.clone(),
        triangles: m.triangles.clone(),
        ..Default::default()
    };
    write_mesh(&p, &plain, &WriteOptions::default()).unwrap();
    let glb = parse_glb(&fs::read(&p).unwrap());
    let attrs = glb.json["meshes"][0]["primitives"][0]["attributes"]
        .as_object()
        .unwrap()
        .clone();
    assert_eq!(attrs.keys().collect::<Vec<_>>(), ["POSITION"]);
    write_mesh(&p, &Mesh::default(), &WriteOptions::default()).unwrap();
    let glb = parse_glb(&fs::read(&p).unwrap());
    assert!(glb.json.get("meshes").is_none() && glb.bin.is_empty());
}

// ---------------------------------------------------------------------------------------------
// Damaged files: every truncation and many byte changes give a result or an error, never a
// panic (a panic fails the test).

#[test]
fn damaged_files_of_every_format_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let ply = dir.path().join("c.ply");
    write_cloud(&ply, &sample_cloud(6), &WriteOptions::default()).unwrap();
    let ascii = dir.path().join("a.ply");
    write_cloud(&ascii, &sample_cloud(3), &WriteOptions { ascii: true }).unwrap();
    let las = dir.path().join("c.las");
    write_las(&las, 5, true);
    let laz = dir.path().join("c.laz");
    write_las(&laz, 50, true);
    let e57 = dir.path().join("c.e57");
    write_e57(&e57);
    let mut pcds = Vec::new();
    for (name, kind) in [
        ("a.pcd", pcd_rs::DataKind::Ascii),
        ("b.pcd", pcd_rs::DataKind::Binary),
        ("c.pcd", pcd_rs::DataKind::BinaryCompressed),
    ] {
        let p = dir.path().join(name);
        write_pcd(&p, kind, 40);
        pcds.push(p);
    }
    for p in [ply, ascii, las, laz, e57].into_iter().chain(pcds) {
        let bytes = fs::read(&p).unwrap();
        files.push((p, bytes));
    }
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for (path, bytes) in &files {
        let name = path.file_name().unwrap().to_str().unwrap();
        let damaged = dir.path().join(format!("damaged-{name}"));
        let step = (bytes.len() / 150).max(1);
        let mut cases: Vec<Vec<u8>> = (0..bytes.len())
            .step_by(step)
            .map(|n| bytes[..n].to_vec())
            .collect();
        for _ in 0..150 {
            let mut b = bytes.clone();
            for _ in 0..1 + rand() % 4 {
                let i = (rand() % b.len() as u64) as usize;
                b[i] = rand() as u8;
            }
            cases.push(b);
        }
        for case in cases {
            fs::write(&damaged, &case).unwrap();
            let _ = read_cloud(&damaged);
        }
    }
}

/// Writes small valid files of every cloud format into `fuzz/seeds/<target>/`, the starting
/// corpus of the fuzz targets (see `fuzz/README.md`). Run by hand:
/// `cargo test -p spsr --test io -- --ignored write_fuzz_seeds`.
#[test]
#[ignore = "writes the fuzzing seed corpus into the source tree"]
fn write_fuzz_seeds() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/seeds");
    let dir = |t: &str| {
        let d = root.join(t);
        fs::create_dir_all(&d).unwrap();
        d
    };
    let cloud = sample_cloud(5);
    let ply = dir("ply");
    write_cloud(
        &ply.join("ascii.ply"),
        &cloud,
        &WriteOptions { ascii: true },
    )
    .unwrap();
    write_cloud(&ply.join("binary.ply"), &cloud, &WriteOptions::default()).unwrap();
    write_file(
        &ply,
        "big_endian.ply",
        b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\n\
          property double y\nproperty double z\nproperty float nx\nproperty float ny\n\
          property float nz\nproperty list uchar int extra\nend_header\n\
          \x3f\xf0\0\0\0\0\0\0\x40\0\0\0\0\0\0\0\x40\x08\0\0\0\0\0\0\
          \x3f\x80\0\0\0\0\0\0\0\0\0\0\x01\0\0\0\x07",
    );
    let mesh = Mesh {
        vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        density: Some(vec![1.0, 2.0, 3.0, 4.0]),
        ..Default::default()
    };
    let pm = dir("ply_mesh");
    write_mesh(&pm.join("ascii.ply"), &mesh, &WriteOptions { ascii: true }).unwrap();
    write_mesh(&pm.join("binary.ply"), &mesh, &WriteOptions::default()).unwrap();
    let meshes = dir("mesh");
    let coloured = octahedron([0.5, -1.0, 2.0]);
    for (name, ascii) in [
        ("octahedron.obj", false),
        ("octahedron.off", false),
        ("octahedron.glb", false),
        ("binary.stl", false),
        ("ascii.stl", true),
    ] {
        write_mesh(&meshes.join(name), &coloured, &WriteOptions { ascii }).unwrap();
    }
    write_file(
        &meshes,
        "polygons.obj",
        b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -1//1 -2 -3/1\n",
    );
    write_file(
        &meshes,
        "polygons.off",
        b"# comment\nSTCOFF\n4 1 4\n0 0 0 1 0 0 1 0 0\n1 0 0 0 1 0 1 1 0\n1 1 0 0 0 1 1 1 1\n0 1 0 1 1 1 1 0 1\n4 0 1 2 3 0.5 0.5 0.5\n",
    );
    let text = dir("text");
    write_file(
        &text,
        "six.xyz",
        b"# x y z nx ny nz\n0 0 0 0 0 1\n1,2,3,0,1,0\n",
    );
    write_file(
        &text,
        "nine.xyz",
        b"0 0 0 0 0 1 255 0 7\n1 2 3 0 1 0 1 2 3\n",
    );
    write_file(&text, "three.xyz", b"1e3 -2.5 3\n4 5 6\n");
    let las = dir("las");
    write_las(&las.join("points.las"), 4, true);
    write_las(&las.join("points.laz"), 4, true);
    write_las(&las.join("no_normals.las"), 2, false);
    let e57 = dir("e57");
    write_e57(&e57.join("scans.e57"));
    let pcd = dir("pcd");
    write_pcd(&pcd.join("ascii.pcd"), pcd_rs::DataKind::Ascii, 4);
    write_pcd(&pcd.join("binary.pcd"), pcd_rs::DataKind::Binary, 4);
    write_pcd(
        &pcd.join("compressed.pcd"),
        pcd_rs::DataKind::BinaryCompressed,
        4,
    );
    // LAZ: the extension does not compress by itself in every version of `las`; keep only
    // files that read back.
    for d in ["ply", "ply_mesh", "text", "las", "e57", "pcd"] {
        for f in fs::read_dir(root.join(d)).unwrap() {
            let p = f.unwrap().path();
            if d == "ply_mesh" {
                read_mesh(&p).unwrap();
            } else {
                read_cloud(&p).unwrap();
            }
        }
    }
}

/// E57 and PCD are streamed too: chunks of the asked size in file order, whose concatenation
/// is the whole file, each with the scan origin in force at its start (E57: per scan; PCD: the
/// viewpoint). A `binary_compressed` PCD body is one chunk.
#[test]
fn e57_and_pcd_are_read_in_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("scans.e57");
    write_e57(&p);
    let whole = read_points(&p).unwrap();
    let origins = |chunk: usize| chunk_origins(&p, chunk);
    let (sizes, joined) = chunks(&p, 3);
    assert_eq!(sizes, [3, 3, 2]);
    assert_eq!(joined.positions, whole.positions);
    assert_eq!(joined.normals, whole.normals);
    assert_eq!(joined.attributes, whole.attributes);
    assert_eq!(
        origins(3),
        [vec![(0, 10.0)], vec![(0, 10.0), (2, 0.0)], vec![(0, 0.0)]]
    );
    // A chunk that ends with a scan: the next starts with the next scan's origin only.
    assert_eq!(chunks(&p, 5).0, [5, 3]);
    assert_eq!(origins(5), [vec![(0, 10.0)], vec![(0, 0.0)]]);
    let (sizes, one) = chunks(&p, 100);
    assert_eq!(sizes, [8]);
    same_cloud(&one, &whole);

    for (name, kind, expect) in [
        ("a.pcd", pcd_rs::DataKind::Ascii, vec![400, 400, 200]),
        ("b.pcd", pcd_rs::DataKind::Binary, vec![400, 400, 200]),
        ("c.pcd", pcd_rs::DataKind::BinaryCompressed, vec![1000]),
    ] {
        let p = dir.path().join(name);
        write_pcd(&p, kind, 1000);
        let whole = read_points(&p).unwrap();
        let (sizes, joined) = chunks(&p, 400);
        assert_eq!(sizes, expect, "{name}");
        let same = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
        for (a, b) in joined.normals.iter().zip(&whole.normals) {
            assert!((0..3).all(|k| same(a[k], b[k])), "{name}");
        }
        assert_eq!(joined.positions, whole.positions, "{name}");
        assert_eq!(joined.attributes, whole.attributes, "{name}");
        let mut seen = 0;
        read_points_chunks(&p, 400, &mut |c| {
            assert_eq!(c.scan_origins, whole.scan_origins, "{name}");
            seen += 1;
            Ok(())
        })
        .unwrap();
        assert_eq!(seen, expect.len());
    }
}
