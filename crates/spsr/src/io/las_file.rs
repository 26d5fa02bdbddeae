//! LAS and LAZ (ASPRS lidar) files through the `las` crate, read in chunks.
//!
//! Positions are the scaled integer coordinates in `f64`. Attributes: `intensity` (`u16`),
//! `return_number`, `number_of_returns`, `classification`, `user_data` (`u8`),
//! `scan_angle` (`f32`, degrees), `point_source_id` (`u16`), then `gps_time` (`f64`),
//! `red green blue` (`u16`) and `nir` (`u16`) when the point format has them, then the
//! extra bytes described by the Extra Bytes VLR (LAS 1.4, record 4 of `LASF_Spec`): each in
//! its own type, or `f64` when it has a scale or offset or is a 64-bit integer; deprecated
//! two- and three-element types become `name_0 .. name_2`. Undocumented extra bytes are
//! skipped.
//!
//! Normals are three extra-bytes fields whose names, lower-cased and with spaces, `_` and
//! `-` removed, are `normalx normaly normalz` or `nx ny nz` (so `NormalX`, `normal_x`,
//! `Nx`, `normal x` all match).

use std::fs::File;
use std::io::BufReader;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use ::las::{PointDataBuilder, Reader};

use crate::attributes::{Attribute, AttributeData, ScalarType};
use crate::error::Error;
use crate::points::PointCloud;
use crate::Result;

use super::{io_err, parse_err};

/// Points decoded per chunk.
const CHUNK_POINTS: u64 = 1 << 16;
/// Size of one Extra Bytes descriptor.
const DESCRIPTOR: usize = 192;

/// One value described by the Extra Bytes VLR.
#[derive(Debug, Clone)]
struct Extra {
    name: String,
    /// Byte offset inside the extra bytes of a record.
    offset: usize,
    ty: ExtraType,
    /// `raw * scale + offset` when the descriptor sets either.
    scale_offset: Option<(f64, f64)>,
    /// Normal axis when this is a normal component.
    normal: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ExtraType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

impl ExtraType {
    fn from_code(code: u8) -> Option<Self> {
        use ExtraType::*;
        Some(match code {
            1 => U8,
            2 => I8,
            3 => U16,
            4 => I16,
            5 => U32,
            6 => I32,
            7 => U64,
            8 => I64,
            9 => F32,
            10 => F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        use ExtraType::*;
        match self {
            U8 | I8 => 1,
            U16 | I16 => 2,
            U32 | I32 | F32 => 4,
            U64 | I64 | F64 => 8,
        }
    }

    fn scalar_type(self) -> ScalarType {
        use ExtraType::*;
        match self {
            U8 => ScalarType::U8,
            I8 => ScalarType::I8,
            U16 => ScalarType::U16,
            I16 => ScalarType::I16,
            U32 => ScalarType::U32,
            I32 => ScalarType::I32,
            F32 => ScalarType::F32,
            U64 | I64 | F64 => ScalarType::F64,
        }
    }

    fn decode(self, b: &[u8]) -> f64 {
        use ExtraType::*;
        let mut a = [0u8; 8];
        a[..self.size()].copy_from_slice(&b[..self.size()]);
        match self {
            U8 => a[0] as f64,
            I8 => a[0] as i8 as f64,
            U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            U64 => u64::from_le_bytes(a) as f64,
            I64 => i64::from_le_bytes(a) as f64,
            F64 => f64::from_le_bytes(a),
        }
    }
}

/// Which normal axis an extra-bytes name stands for, if any.
fn normal_axis(name: &str) -> Option<usize> {
    let key: String = name
        .chars()
        .filter(|c| !matches!(c, ' ' | '_' | '-'))
        .flat_map(char::to_lowercase)
        .collect();
    match key.as_str() {
        "normalx" | "nx" => Some(0),
        "normaly" | "ny" => Some(1),
        "normalz" | "nz" => Some(2),
        _ => None,
    }
}

fn f64_at(d: &[u8], at: usize) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&d[at..at + 8]);
    f64::from_le_bytes(a)
}

/// The extra-bytes fields described by the header's Extra Bytes VLRs that fit in
/// `extra_len` bytes per point.
fn extra_fields(header: &::las::Header, extra_len: usize) -> Vec<Extra> {
    let mut out = Vec::new();
    let mut offset = 0usize;
    let vlrs = header.vlrs().iter().chain(header.evlrs());
    let descs = vlrs
        .filter(|v| v.user_id.trim_end_matches('\0') == "LASF_Spec" && v.record_id == 4)
        .flat_map(|v| v.data.chunks_exact(DESCRIPTOR));
    for d in descs {
        let code = d[2];
        let options = d[3];
        let raw_name = &d[4..36];
        let end = raw_name.iter().position(|&b| b == 0).unwrap_or(32);
        let mut name: String = String::from_utf8_lossy(&raw_name[..end])
            .trim()
            .chars()
            .map(|c| if c.is_whitespace() { '_' } else { c })
            .collect();
        if name.is_empty() {
            name = format!("extra_{offset}");
        }
        if code == 0 {
            offset += usize::from(options); // undocumented bytes: skipped
            continue;
        }
        // Deprecated 11..=30: two (11..=20) or three (21..=30) values of type code - 10 / - 20.
        let (base, count) = match code {
            1..=10 => (code, 1),
            11..=20 => (code - 10, 2),
            21..=30 => (code - 20, 3),
            _ => break, // unknown type: its size, and so every later offset, is unknown
        };
        let Some(ty) = ExtraType::from_code(base) else {
            break;
        };
        if offset + ty.size() * count > extra_len {
            break;
        }
        let scaled = options & 0b1_1000 != 0;
        for k in 0..count {
            let scale_offset = scaled.then(|| {
                let s = if options & 0b1000 != 0 {
                    f64_at(d, 112 + 8 * k)
                } else {
                    1.0
                };
                let o = if options & 0b1_0000 != 0 {
                    f64_at(d, 136 + 8 * k)
                } else {
                    0.0
                };
                (if s == 0.0 { 1.0 } else { s }, o)
            });
            out.push(Extra {
                name: if count == 1 {
                    name.clone()
                } else {
                    format!("{name}_{k}")
                },
                offset,
                ty,
                scale_offset,
                normal: if count == 1 { normal_axis(&name) } else { None },
            });
            offset += ty.size();
        }
    }
    // Normals only when all three axes are present, once each.
    let axes: Vec<usize> = out.iter().filter_map(|e| e.normal).collect();
    let complete = axes.len() == 3 && (0..3).all(|a| axes.contains(&a));
    if !complete {
        for e in &mut out {
            e.normal = None;
        }
    }
    out
}

/// Maps a `las` error; `points` is `(points read, points declared)` once the header is read.
fn las_err(path: &Path, e: ::las::Error, points: Option<(u64, u64)>) -> Error {
    let eof = |io: &std::io::Error| io.kind() == std::io::ErrorKind::UnexpectedEof;
    match (e, points) {
        (::las::Error::Io(io), None) if eof(&io) => parse_err(
            path,
            "not a valid LAS/LAZ file: the file ends inside its header".into(),
        ),
        (::las::Error::Io(io), Some((done, total))) if eof(&io) => parse_err(
            path,
            format!(
                "the file is truncated: it ends within points {done} to {} (0-based) of the {total} its header declares",
                (done + CHUNK_POINTS).min(total).saturating_sub(1)
            ),
        ),
        (::las::Error::Io(io), _) => io_err(path, io),
        (other, _) => parse_err(path, format!("not a valid LAS/LAZ file: {other}")),
    }
}

pub(crate) fn read_las(
    path: &Path,
    reader: BufReader<File>,
    file_len: u64,
    need_normals: bool,
) -> Result<PointCloud> {
    super::whole_cloud(|emit| {
        read_las_chunks(path, reader, file_len, need_normals, usize::MAX, emit)
    })
}

/// Reads the points in clouds of about `chunk` points (a multiple of the decoder's chunk,
/// the last one shorter), handed to `emit` in file order.
pub(crate) fn read_las_chunks(
    path: &Path,
    reader: BufReader<File>,
    file_len: u64,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    // The `las` and `laz` crates validate what they read, but a decoder fed garbage is the
    // kind of code that may still hit an unforeseen panic; turn one into an error.
    match catch_unwind(AssertUnwindSafe(|| {
        read(path, reader, file_len, need_normals, chunk, emit)
    })) {
        Ok(r) => r,
        Err(panic) => {
            let msg = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            Err(parse_err(
                path,
                format!("not a valid LAS/LAZ file: the decoder failed on malformed data ({msg})"),
            ))
        }
    }
}

fn read(
    path: &Path,
    reader: BufReader<File>,
    file_len: u64,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let mut las = Reader::new(reader).map_err(|e| las_err(path, e, None))?;
    let header = las.header().clone();
    let format = *header.point_format();
    let total = header.number_of_points();
    let record_len = usize::from(format.len());
    let extra_len = usize::from(format.extra_bytes);
    let extra_at = record_len - extra_len;
    let extras = extra_fields(&header, extra_len);
    let has_normals = extras.iter().any(|e| e.normal.is_some());
    if need_normals && !has_normals {
        return Err(Error::MissingNormals {
            path: path.to_path_buf(),
        });
    }
    // Reserve what the file can hold (at least one byte per point even when compressed), so
    // that a bogus count cannot trigger a huge allocation.
    let fits = if format.is_compressed {
        file_len
    } else {
        file_len / record_len.max(1) as u64 + 1
    };
    let cap = total.min(fits).min(chunk as u64).min(usize::MAX as u64) as usize;
    let mut positions: Vec<[f64; 3]> = Vec::with_capacity(cap);
    let mut normals: Vec<[f64; 3]> = Vec::with_capacity(if has_normals { cap } else { 0 });
    let col =
        |name: &str, ty: ScalarType| Attribute::new(name, AttributeData::with_capacity(ty, cap));
    let mut attributes = vec![
        col("intensity", ScalarType::U16),
        col("return_number", ScalarType::U8),
        col("number_of_returns", ScalarType::U8),
        col("classification", ScalarType::U8),
        col("scan_angle", ScalarType::F32),
        col("user_data", ScalarType::U8),
        col("point_source_id", ScalarType::U16),
    ];
    if format.has_gps_time {
        attributes.push(col("gps_time", ScalarType::F64));
    }
    if format.has_color {
        for c in ["red", "green", "blue"] {
            attributes.push(col(c, ScalarType::U16));
        }
    }
    if format.has_nir {
        attributes.push(col("nir", ScalarType::U16));
    }
    let first_extra = attributes.len();
    for e in extras.iter().filter(|e| e.normal.is_none()) {
        let ty = if e.scale_offset.is_some() {
            ScalarType::F64
        } else {
            e.ty.scalar_type()
        };
        attributes.push(col(&e.name, ty));
    }
    let mut pd = PointDataBuilder::new().for_header(&header).build();
    let mut done = 0u64;
    loop {
        let got = las
            .fill_points(CHUNK_POINTS, &mut pd)
            .map_err(|e| las_err(path, e, Some((done, total))))?;
        if got == 0 {
            break;
        }
        positions.extend(pd.x().zip(pd.y()).zip(pd.z()).map(|((x, y), z)| [x, y, z]));
        macro_rules! fill {
            ($i:expr, $var:ident, $it:expr) => {
                if let AttributeData::$var(d) = &mut attributes[$i].data {
                    d.extend($it);
                }
            };
        }
        fill!(0, U16, pd.intensity());
        fill!(1, U8, pd.return_number());
        fill!(2, U8, pd.number_of_returns());
        fill!(3, U8, pd.classification());
        fill!(4, F32, pd.scan_angle_degrees());
        fill!(5, U8, pd.user_data());
        fill!(6, U16, pd.point_source_id());
        let mut next = 7;
        if let Some(t) = pd.gps_time() {
            fill!(next, F64, t);
            next += 1;
        }
        if let Some(rgb) = pd.rgb() {
            let rgb: Vec<(u16, u16, u16)> = rgb.collect();
            fill!(next, U16, rgb.iter().map(|c| c.0));
            fill!(next + 1, U16, rgb.iter().map(|c| c.1));
            fill!(next + 2, U16, rgb.iter().map(|c| c.2));
        }
        if let Some(nir) = pd.nir() {
            fill!(first_extra - 1, U16, nir);
        }
        if !extras.is_empty() {
            for rec in pd.raw_bytes().chunks_exact(record_len) {
                let bytes = &rec[extra_at..];
                let mut normal = [0.0; 3];
                let mut a = first_extra;
                for e in &extras {
                    let mut v = e.ty.decode(&bytes[e.offset..]);
                    if let Some((s, o)) = e.scale_offset {
                        v = v * s + o;
                    }
                    match e.normal {
                        Some(axis) => normal[axis] = v,
                        None => {
                            attributes[a].data.push_f64(v);
                            a += 1;
                        }
                    }
                }
                if has_normals {
                    normals.push(normal);
                }
            }
        }
        done += got;
        if positions.len() >= chunk {
            let fresh = attributes
                .iter()
                .map(|a| Attribute::new(a.name.clone(), AttributeData::new(a.data.scalar_type())))
                .collect();
            emit(PointCloud {
                positions: std::mem::take(&mut positions),
                normals: std::mem::take(&mut normals),
                attributes: std::mem::replace(&mut attributes, fresh),
                scan_origins: Vec::new(),
            })?;
        }
    }
    if !positions.is_empty() || done == 0 {
        emit(PointCloud {
            positions,
            normals,
            attributes,
            scan_origins: Vec::new(),
        })?;
    }
    Ok(())
}
