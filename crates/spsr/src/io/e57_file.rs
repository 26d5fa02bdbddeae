//! E57 (ASTM E2807) scanner files through the `e57` crate.
//!
//! Every scan (E57 "data3D" point cloud) is read, its points moved by the scan's pose
//! (rotation, then translation) into the file's common frame, and appended in file order.
//! Cartesian coordinates are used when a scan has them, spherical ones (range, azimuth,
//! elevation) otherwise; points whose coordinates are flagged invalid get NaN coordinates
//! (kept, as every reader keeps invalid points); so do points flagged as directions only. Normals come from the E57 surface-normals
//! extension (`nor:normalX`, `nor:normalY`, `nor:normalZ`), rotated by the pose.
//!
//! Attributes: `red green blue` and `intensity` in their stored type (an integer range
//! picks the smallest integer type that holds it; scaled integers become `f64`), and the
//! other per-point fields (`row`, `column`, `return_index`, `return_count`, `timestamp`,
//! and extension fields under their own name). A field missing from one scan reads as 0 in
//! that scan's points, and so do invalid colours and intensities; a field whose type
//! differs between scans is kept as `f64`. When some scans have normals and others do not,
//! the others get zero normals (unusable, so the reconstruction drops them).
//!
//! Each scan's sensor position (its pose's translation; the origin when the scan has no
//! pose) is recorded in [`PointCloud::scan_origins`].

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use ::e57::{E57Reader, RecordDataType, RecordName, Transform};

use crate::attributes::{Attribute, AttributeData, ScalarType};
use crate::error::Error;
use crate::points::{PointCloud, ScanOrigin};
use crate::Result;

use super::parse_err;

/// What one prototype record of a scan is.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Cartesian(usize),
    CartesianInvalid,
    Spherical(usize),
    SphericalInvalid,
    Normal(usize),
    ColorInvalid,
    IntensityInvalid,
    /// Index into the cloud's attributes; colour channels are marked so that an invalid
    /// flag can zero them.
    Attr {
        index: usize,
        color: bool,
        intensity: bool,
    },
    Skip,
}

fn attribute_name(name: &RecordName) -> Option<String> {
    Some(match name {
        RecordName::ColorRed => "red".into(),
        RecordName::ColorGreen => "green".into(),
        RecordName::ColorBlue => "blue".into(),
        RecordName::Intensity => "intensity".into(),
        RecordName::RowIndex => "row".into(),
        RecordName::ColumnIndex => "column".into(),
        RecordName::ReturnCount => "return_count".into(),
        RecordName::ReturnIndex => "return_index".into(),
        RecordName::TimeStamp => "timestamp".into(),
        RecordName::Unknown { name, .. } => name.clone(),
        _ => return None,
    })
}

fn normal_axis(name: &RecordName) -> Option<usize> {
    match name {
        RecordName::Unknown { name, .. } => match name.as_str() {
            "normalX" => Some(0),
            "normalY" => Some(1),
            "normalZ" => Some(2),
            _ => None,
        },
        _ => None,
    }
}

fn record_type(dt: &RecordDataType) -> ScalarType {
    match dt {
        RecordDataType::Single { .. } => ScalarType::F32,
        RecordDataType::Double { .. } => ScalarType::F64,
        RecordDataType::ScaledInteger { .. } => ScalarType::F64,
        RecordDataType::Integer { min, max } => ScalarType::for_integer_range(*min, *max),
    }
}

fn e57_err(path: &Path, e: ::e57::Error) -> Error {
    parse_err(path, format!("not a valid E57 file: {e}"))
}

/// Rotation matrix (rows) of a unit quaternion (normalised here).
fn rotation(t: &Transform) -> [[f64; 3]; 3] {
    let q = &t.rotation;
    let n = (q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z).sqrt();
    let (w, x, y, z) = if n > 0.0 && n.is_finite() {
        (q.w / n, q.x / n, q.y / n, q.z / n)
    } else {
        (1.0, 0.0, 0.0, 0.0)
    };
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

fn apply(r: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

pub(crate) fn read_e57(
    path: &Path,
    reader: BufReader<File>,
    file_len: u64,
    need_normals: bool,
) -> Result<PointCloud> {
    super::whole_cloud(|emit| {
        read_e57_chunks(path, reader, file_len, need_normals, usize::MAX, emit)
    })
}

/// [`read_e57`] handed to `emit` in clouds of at most `chunk` points, in file order, each
/// with its scan origins counted from its own first point (the origin in force at its start
/// first). With an unbounded `chunk`, one cloud: the whole file.
pub(crate) fn read_e57_chunks(
    path: &Path,
    reader: BufReader<File>,
    file_len: u64,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let mut e57 = E57Reader::new(reader).map_err(|e| e57_err(path, e))?;
    let scans = e57.pointclouds();
    let mut attributes: Vec<Attribute> = Vec::new();
    let mut roles: Vec<Vec<Role>> = Vec::with_capacity(scans.len());
    let mut has_normals = false;
    for (s, pc) in scans.iter().enumerate() {
        let (r, normals) = scan_roles(path, s, pc, &mut attributes)?;
        has_normals |= normals;
        roles.push(r);
    }
    if need_normals && !has_normals {
        return Err(Error::MissingNormals {
            path: path.to_path_buf(),
        });
    }
    let total: u64 = scans.iter().map(|pc| pc.records).sum();
    let cap = total.min(file_len).min(chunk as u64).min(usize::MAX as u64) as usize;
    let mut out = Columns {
        cloud: PointCloud {
            positions: Vec::with_capacity(cap),
            normals: Vec::with_capacity(if has_normals { cap } else { 0 }),
            attributes,
            scan_origins: Vec::with_capacity(scans.len().min(cap.max(1))),
        },
        has_normals,
        chunk,
        cap,
        origin: [0.0; 3],
        carried: false,
        emitted: false,
        emit,
    };
    for a in &mut out.cloud.attributes {
        a.data.reserve(cap);
    }
    for (s, (pc, roles)) in scans.iter().zip(&roles).enumerate() {
        out.start_scan(pc.transform.as_ref().map_or([0.0; 3], |t| {
            [t.translation.x, t.translation.y, t.translation.z]
        }));
        read_scan(path, &mut e57, s, pc, roles, &mut out)?;
    }
    out.finish()
}

/// The role of each record of scan `s`, adding its attributes to `attributes` (in order of
/// first appearance, with a common type); also whether the scan has normals.
fn scan_roles(
    path: &Path,
    s: usize,
    pc: &e57::PointCloud,
    attributes: &mut Vec<Attribute>,
) -> Result<(Vec<Role>, bool)> {
    let mut r = Vec::with_capacity(pc.prototype.len());
    let mut axes = [false; 3];
    for rec in &pc.prototype {
        let role = match &rec.name {
            RecordName::CartesianX => Role::Cartesian(0),
            RecordName::CartesianY => Role::Cartesian(1),
            RecordName::CartesianZ => Role::Cartesian(2),
            RecordName::CartesianInvalidState => Role::CartesianInvalid,
            RecordName::SphericalRange => Role::Spherical(0),
            RecordName::SphericalAzimuth => Role::Spherical(1),
            RecordName::SphericalElevation => Role::Spherical(2),
            RecordName::SphericalInvalidState => Role::SphericalInvalid,
            RecordName::IsColorInvalid => Role::ColorInvalid,
            RecordName::IsIntensityInvalid => Role::IntensityInvalid,
            RecordName::IsTimeStampInvalid => Role::Skip,
            name => match (normal_axis(name), attribute_name(name)) {
                (Some(a), _) => {
                    axes[a] = true;
                    Role::Normal(a)
                }
                (None, Some(n)) => {
                    let ty = record_type(&rec.data_type);
                    let index = match attributes.iter().position(|a| a.name == n) {
                        Some(i) => {
                            if attributes[i].data.scalar_type() != ty {
                                attributes[i].data = AttributeData::new(ScalarType::F64);
                            }
                            i
                        }
                        None => {
                            attributes.push(Attribute::new(n, AttributeData::new(ty)));
                            attributes.len() - 1
                        }
                    };
                    Role::Attr {
                        index,
                        color: matches!(
                            name,
                            RecordName::ColorRed | RecordName::ColorGreen | RecordName::ColorBlue
                        ),
                        intensity: matches!(name, RecordName::Intensity),
                    }
                }
                (None, None) => Role::Skip,
            },
        };
        r.push(role);
    }
    if axes.iter().any(|&a| a) && !axes.iter().all(|&a| a) {
        return Err(parse_err(
            path,
            format!("scan {s} has only some of the normal fields normalX, normalY, normalZ"),
        ));
    }
    let has = |f: fn(&Role) -> bool| r.iter().filter(|x| f(x)).count() == 3;
    if !has(|x| matches!(x, Role::Cartesian(_))) && !has(|x| matches!(x, Role::Spherical(_))) {
        return Err(parse_err(
            path,
            format!(
                "scan {s} has neither Cartesian (cartesianX/Y/Z) nor spherical (sphericalRange/Azimuth/Elevation) coordinates"
            ),
        ));
    }
    Ok((r, axes[0]))
}

/// Where the points go: the chunk being filled, handed to `emit` when it holds `chunk`
/// points.
struct Columns<'e> {
    cloud: PointCloud,
    has_normals: bool,
    chunk: usize,
    /// Points reserved per chunk.
    cap: usize,
    /// The scan origin in force (the scan being read).
    origin: [f64; 3],
    /// Whether the chunk's only scan origin is the one carried over from the previous chunk.
    carried: bool,
    emitted: bool,
    emit: &'e mut dyn FnMut(PointCloud) -> Result<()>,
}

impl Columns<'_> {
    /// A scan begins at the next point, seen from `origin`.
    fn start_scan(&mut self, origin: [f64; 3]) {
        self.origin = origin;
        let first_point = self.cloud.positions.len();
        if self.carried && first_point == 0 {
            // The origin carried into this chunk is replaced before it covers any point.
            self.cloud.scan_origins.clear();
        }
        self.carried = false;
        self.cloud.scan_origins.push(ScanOrigin {
            first_point,
            origin,
        });
    }

    /// After each point: hands the chunk over when it is full.
    fn point_done(&mut self) -> Result<()> {
        if self.cloud.positions.len() < self.chunk {
            return Ok(());
        }
        let next = PointCloud {
            positions: Vec::with_capacity(self.cap),
            normals: Vec::with_capacity(if self.has_normals { self.cap } else { 0 }),
            attributes: self
                .cloud
                .attributes
                .iter()
                .map(|a| {
                    let mut data = AttributeData::new(a.data.scalar_type());
                    data.reserve(self.cap);
                    Attribute::new(a.name.clone(), data)
                })
                .collect(),
            scan_origins: vec![ScanOrigin {
                first_point: 0,
                origin: self.origin,
            }],
        };
        self.carried = true;
        self.emitted = true;
        (self.emit)(std::mem::replace(&mut self.cloud, next))
    }

    /// Hands over the last chunk (also an empty one when nothing was handed over yet).
    fn finish(mut self) -> Result<()> {
        if self.cloud.positions.is_empty() && self.emitted {
            return Ok(());
        }
        if self.carried && self.cloud.positions.is_empty() {
            self.cloud.scan_origins.clear();
        }
        (self.emit)(self.cloud)
    }
}

/// Reads the points of scan `s` into `out`, in the file's frame.
fn read_scan(
    path: &Path,
    e57: &mut E57Reader<BufReader<File>>,
    s: usize,
    pc: &e57::PointCloud,
    roles: &[Role],
    out: &mut Columns,
) -> Result<()> {
    let mut vals = vec![0.0f64; out.cloud.attributes.len()];
    let rot = pc.transform.as_ref().map(rotation);
    let shift = pc.transform.as_ref().map_or([0.0; 3], |t| {
        [t.translation.x, t.translation.y, t.translation.z]
    });
    let use_cartesian = roles
        .iter()
        .filter(|r| matches!(r, Role::Cartesian(_)))
        .count()
        == 3;
    let types: Vec<&RecordDataType> = pc.prototype.iter().map(|r| &r.data_type).collect();
    let iter = e57.pointcloud_raw(pc).map_err(|e| e57_err(path, e))?;
    for (i, point) in iter.enumerate() {
        let point = point.map_err(|e| {
            parse_err(
                path,
                format!("not a valid E57 file: scan {s}, point {i}: {e}"),
            )
        })?;
        let mut cart = [0.0; 3];
        let mut sph = [0.0; 3];
        let mut normal = [0.0; 3];
        let mut invalid = false;
        let mut color_invalid = false;
        let mut intensity_invalid = false;
        vals.iter_mut().for_each(|v| *v = 0.0);
        for ((role, value), dt) in roles.iter().zip(&point).zip(&types) {
            let v = value.to_f64(dt).map_err(|e| {
                parse_err(
                    path,
                    format!("not a valid E57 file: scan {s}, point {i}: {e}"),
                )
            })?;
            match *role {
                Role::Cartesian(a) => cart[a] = v,
                Role::Spherical(a) => sph[a] = v,
                Role::Normal(a) => normal[a] = v,
                Role::CartesianInvalid if use_cartesian => invalid |= v != 0.0,
                Role::SphericalInvalid if !use_cartesian => invalid |= v != 0.0,
                Role::ColorInvalid => color_invalid = v != 0.0,
                Role::IntensityInvalid => intensity_invalid = v != 0.0,
                Role::Attr { index, .. } => vals[index] = v,
                _ => {}
            }
        }
        let mut p = if use_cartesian {
            cart
        } else {
            let [r, az, el] = sph;
            [
                r * el.cos() * az.cos(),
                r * el.cos() * az.sin(),
                r * el.sin(),
            ]
        };
        if invalid {
            p = [f64::NAN; 3];
        }
        if let Some(rot) = &rot {
            p = apply(rot, p);
            normal = apply(rot, normal);
        }
        out.cloud
            .positions
            .push([p[0] + shift[0], p[1] + shift[1], p[2] + shift[2]]);
        if out.has_normals {
            out.cloud.normals.push(normal);
        }
        for role in roles {
            if let Role::Attr {
                index,
                color,
                intensity,
            } = *role
            {
                if (color && color_invalid) || (intensity && intensity_invalid) {
                    vals[index] = 0.0;
                }
            }
        }
        for (a, &v) in out.cloud.attributes.iter_mut().zip(&vals) {
            a.data.push_f64(v);
        }
        out.point_done()?;
    }
    Ok(())
}
