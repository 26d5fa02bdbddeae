//! PCD (Point Cloud Library) files, versions 0.5 to 0.7: `ascii`, `binary` and
//! `binary_compressed` bodies, streamed.
//!
//! Fields `x y z` are the positions and `normal_x normal_y normal_z` the normals (all three
//! or none). A packed colour field `rgb` (or `rgba`), four bytes read as `0xAARRGGBB` in a
//! little-endian `u32` (PCL stores it in a float's bits), becomes the `u8` attributes
//! `red green blue` (and `alpha` for `rgba`). `_` fields are padding and skipped. Every
//! other field becomes an attribute of its type (8-byte integers as `f64`); a field with
//! `COUNT n > 1` becomes `n` attributes `name_0 .. name_{n-1}`. A `VIEWPOINT` other than the
//! default `0 0 0 1 0 0 0` is recorded as the cloud's scan origin (its translation); the
//! points are not moved, as in PCL.
//!
//! Binary bodies are little endian. A `binary_compressed` body is one LZF block holding the
//! fields one after another (all `x`, then all `y`, ...); it is decompressed as a stream
//! straight into the output columns, so it is never held whole in memory.

use std::io::{BufRead, Read};
use std::path::Path;

use crate::attributes::{Attribute, AttributeData, ScalarType};
use crate::error::Error;
use crate::points::{PointCloud, ScanOrigin};
use crate::Result;

use super::lzf::LzfReader;
use super::{io_err, parse_err};

/// Longest header line accepted.
const MAX_LINE: u64 = 1 << 16;
/// Most header lines accepted before `DATA`.
const MAX_HEADER_LINES: usize = 10_000;
/// Points decoded per chunk from binary bodies.
const CHUNK_POINTS: usize = 1 << 14;
/// Largest record accepted, in bytes.
const MAX_RECORD: usize = 1 << 20;
/// Largest decompression ratio LZF can reach (a 3-byte block expands to at most 264 bytes).
const LZF_MAX_RATIO: u64 = 88;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Data {
    Ascii,
    Binary,
    Compressed,
}

/// A field's element type: `I`, `U` or `F` and a size in bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Ty {
    kind: u8,
    size: usize,
}

impl Ty {
    fn scalar_type(self) -> ScalarType {
        match (self.kind, self.size) {
            (b'I', 1) => ScalarType::I8,
            (b'U', 1) => ScalarType::U8,
            (b'I', 2) => ScalarType::I16,
            (b'U', 2) => ScalarType::U16,
            (b'I', 4) => ScalarType::I32,
            (b'U', 4) => ScalarType::U32,
            (b'F', 4) => ScalarType::F32,
            _ => ScalarType::F64, // F 8 and 8-byte integers
        }
    }

    /// Decodes one little-endian value from the start of `b`.
    fn decode(self, b: &[u8]) -> f64 {
        let mut a = [0u8; 8];
        a[..self.size].copy_from_slice(&b[..self.size]);
        match (self.kind, self.size) {
            (b'I', 1) => a[0] as i8 as f64,
            (b'U', 1) => a[0] as f64,
            (b'I', 2) => i16::from_le_bytes([a[0], a[1]]) as f64,
            (b'U', 2) => u16::from_le_bytes([a[0], a[1]]) as f64,
            (b'I', 4) => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            (b'U', 4) => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            (b'F', 4) => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            (b'I', 8) => i64::from_le_bytes(a) as f64,
            (b'U', 8) => u64::from_le_bytes(a) as f64,
            _ => f64::from_le_bytes(a),
        }
    }

    /// The four bytes of a packed colour as a `u32`.
    fn packed(self, b: &[u8]) -> u32 {
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }

    /// Parses one ASCII value; packed colours give their bits as `f64`.
    fn parse(self, tok: &str, packed: bool) -> Option<f64> {
        if packed {
            let bits = match self.kind {
                b'F' => tok.parse::<f32>().ok()?.to_bits(),
                b'U' => tok.parse::<u32>().ok()?,
                _ => tok.parse::<i32>().ok()? as u32,
            };
            return Some(bits as f64);
        }
        let v = tok.parse::<f64>().ok()?;
        Some(if self.kind == b'F' && self.size == 4 {
            v as f32 as f64
        } else {
            v
        })
    }
}

/// Where the values of one field go.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    Position(usize),
    Normal(usize),
    /// Packed colour into attributes `first..first + 3` (`+ 4` with alpha).
    Color {
        first: usize,
        alpha: bool,
    },
    /// Attributes `first..first + count`, one per element.
    Attr(usize),
    Skip,
}

#[derive(Debug, Clone)]
struct Field {
    name: String,
    ty: Ty,
    count: usize,
    role: Role,
}

impl Field {
    fn bytes(&self) -> usize {
        self.ty.size * self.count
    }
}

struct Header {
    fields: Vec<Field>,
    points: u64,
    data: Data,
    viewpoint: Option<[f64; 7]>,
    has_normals: bool,
    /// Lines read, for ASCII error messages.
    lines: usize,
}

/// The output being filled: positions and normals are indexed (within the chunk), attributes
/// pushed in order. Streamed bodies hand it to `emit` each time it holds `chunk` points.
struct Sink<'e> {
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    attributes: Vec<Attribute>,
    has_normals: bool,
    chunk: usize,
    /// Points reserved per chunk.
    cap: usize,
    /// Each chunk's scan origins (the viewpoint, if any).
    scan_origins: Vec<ScanOrigin>,
    emitted: bool,
    emit: &'e mut dyn FnMut(PointCloud) -> Result<()>,
}

impl Sink<'_> {
    /// Stores element `k` of field `f` of point `i` (of the chunk), given as `f64` (packed
    /// colours as their bits).
    #[inline]
    fn put(&mut self, f: &Field, i: usize, k: usize, v: f64) {
        match f.role {
            Role::Position(a) => self.positions[i][a] = v,
            Role::Normal(a) => self.normals[i][a] = v,
            Role::Color { first, alpha } => {
                let c = v as u32;
                let rgb = [(c >> 16) & 255, (c >> 8) & 255, c & 255, c >> 24];
                for (j, &x) in rgb[..3 + usize::from(alpha)].iter().enumerate() {
                    if let AttributeData::U8(d) = &mut self.attributes[first + j].data {
                        d.push(x as u8);
                    }
                }
            }
            Role::Attr(first) => self.attributes[first + k].data.push_f64(v),
            Role::Skip => {}
        }
    }

    /// Starts a point; returns its index in the chunk.
    fn push_point(&mut self) -> usize {
        self.positions.push([0.0; 3]);
        if self.has_normals {
            self.normals.push([0.0; 3]);
        }
        self.positions.len() - 1
    }

    /// The chunk so far, leaving an empty one with the same attributes.
    fn take(&mut self) -> PointCloud {
        let cap = self.cap;
        let attributes = self
            .attributes
            .iter()
            .map(|a| {
                let mut data = AttributeData::new(a.data.scalar_type());
                data.reserve(cap);
                Attribute::new(a.name.clone(), data)
            })
            .collect();
        PointCloud {
            positions: std::mem::replace(&mut self.positions, Vec::with_capacity(cap)),
            normals: std::mem::replace(
                &mut self.normals,
                Vec::with_capacity(if self.has_normals { cap } else { 0 }),
            ),
            attributes: std::mem::replace(&mut self.attributes, attributes),
            scan_origins: self.scan_origins.clone(),
        }
    }

    /// After each point of a streamed body: hands the chunk over when it is full.
    fn point_done(&mut self) -> Result<()> {
        if self.positions.len() < self.chunk {
            return Ok(());
        }
        self.emitted = true;
        let full = self.take();
        (self.emit)(full)
    }

    /// Hands over the last chunk (also an empty one when nothing was handed over yet).
    fn finish(mut self) -> Result<()> {
        if self.positions.is_empty() && self.emitted {
            return Ok(());
        }
        let last = self.take();
        (self.emit)(last)
    }
}

fn read_line<R: BufRead>(path: &Path, r: &mut R, buf: &mut Vec<u8>) -> Result<usize> {
    buf.clear();
    let n = r
        .take(MAX_LINE)
        .read_until(b'\n', buf)
        .map_err(|e| io_err(path, e))?;
    if n as u64 == MAX_LINE && buf.last() != Some(&b'\n') {
        return Err(parse_err(
            path,
            format!("a header line is longer than {MAX_LINE} bytes; this is not a PCD header"),
        ));
    }
    Ok(n)
}

/// The header's lines as written, before they are checked against each other.
#[derive(Default)]
struct RawHeader {
    names: Option<Vec<String>>,
    sizes: Option<Vec<usize>>,
    types: Option<Vec<u8>>,
    counts: Option<Vec<usize>>,
    width: Option<u64>,
    height: Option<u64>,
    points: Option<u64>,
    viewpoint: Option<[f64; 7]>,
}

fn parse_header<R: BufRead>(path: &Path, r: &mut R) -> Result<(Header, u64)> {
    let mut buf = Vec::new();
    let mut consumed = 0u64;
    let mut raw = RawHeader::default();
    let mut line = 0usize;
    let data = loop {
        let n = read_line(path, r, &mut buf)?;
        consumed += n as u64;
        line += 1;
        if n == 0 {
            return Err(parse_err(
                path,
                format!("the PCD header has no DATA line (the file ends at line {line})"),
            ));
        }
        if line > MAX_HEADER_LINES {
            return Err(parse_err(
                path,
                format!(
                    "no DATA line in the first {MAX_HEADER_LINES} lines; this is not a PCD header"
                ),
            ));
        }
        let text = String::from_utf8_lossy(&buf);
        let t = text.trim();
        if t.is_empty() || t.starts_with('#') {
            continue;
        }
        let tok: Vec<&str> = t.split_whitespace().collect();
        if let Some(data) = header_line(path, line, &tok, &mut raw)? {
            break data;
        }
    };
    let names = raw
        .names
        .filter(|n| !n.is_empty())
        .ok_or_else(|| parse_err(path, "the PCD header has no FIELDS line".into()))?;
    let sizes = raw
        .sizes
        .ok_or_else(|| parse_err(path, "the PCD header has no SIZE line".into()))?;
    let types = raw
        .types
        .ok_or_else(|| parse_err(path, "the PCD header has no TYPE line".into()))?;
    let counts = raw.counts.unwrap_or_else(|| vec![1; names.len()]);
    let mut fields = header_fields(path, names, &sizes, &types, &counts)?;
    let points = point_count(path, raw.points, raw.width, raw.height)?;
    let has_normals = assign_roles(path, &mut fields)?;
    Ok((
        Header {
            fields,
            points,
            data,
            viewpoint: raw.viewpoint,
            has_normals,
            lines: line,
        },
        consumed,
    ))
}

/// Reads one header line (`tok`, split at white space) into `raw`; the DATA line ends the
/// header and gives the body's encoding.
fn header_line(
    path: &Path,
    line: usize,
    tok: &[&str],
    raw: &mut RawHeader,
) -> Result<Option<Data>> {
    let err = |what: String| parse_err(path, format!("header line {line}: {what}"));
    let numbers = |what: &str| -> Result<Vec<usize>> {
        tok[1..]
            .iter()
            .map(|s| {
                s.parse::<usize>().map_err(|_| {
                    err(format!(
                        "{what}: '{}' is not a non-negative integer",
                        short(s)
                    ))
                })
            })
            .collect()
    };
    let single = |what: &str| -> Result<u64> {
        match tok[1..] {
            [s] => s.parse::<u64>().map_err(|_| {
                err(format!(
                    "{what}: '{}' is not a non-negative integer",
                    short(s)
                ))
            }),
            _ => Err(err(format!("{what} needs exactly one number"))),
        }
    };
    match tok[0].to_ascii_uppercase().as_str() {
        "VERSION" => {}
        "FIELDS" | "COLUMNS" => raw.names = Some(tok[1..].iter().map(|s| s.to_string()).collect()),
        "SIZE" => raw.sizes = Some(numbers("SIZE")?),
        "COUNT" => raw.counts = Some(numbers("COUNT")?),
        "TYPE" => {
            let mut v = Vec::new();
            for s in &tok[1..] {
                match s.to_ascii_uppercase().as_str() {
                    "I" => v.push(b'I'),
                    "U" => v.push(b'U'),
                    "F" => v.push(b'F'),
                    _ => return Err(err(format!("TYPE '{}' is not I, U or F", short(s)))),
                }
            }
            raw.types = Some(v);
        }
        "WIDTH" => raw.width = Some(single("WIDTH")?),
        "HEIGHT" => raw.height = Some(single("HEIGHT")?),
        "POINTS" => raw.points = Some(single("POINTS")?),
        "VIEWPOINT" => {
            let v: Option<Vec<f64>> = tok[1..].iter().map(|s| s.parse().ok()).collect();
            match v.as_deref() {
                Some(&[a, b, c, d, e, f, g]) => raw.viewpoint = Some([a, b, c, d, e, f, g]),
                _ => {
                    return Err(err(
                        "VIEWPOINT needs seven numbers (tx ty tz qw qx qy qz)".into()
                    ))
                }
            }
        }
        "DATA" => {
            return match tok.get(1).map(|s| s.to_ascii_lowercase()).as_deref() {
                Some("ascii") => Ok(Some(Data::Ascii)),
                Some("binary") => Ok(Some(Data::Binary)),
                Some("binary_compressed") => Ok(Some(Data::Compressed)),
                other => Err(err(format!(
                    "unknown DATA '{}' (expected ascii, binary or binary_compressed)",
                    short(other.unwrap_or(""))
                ))),
            }
        }
        other => return Err(err(format!("unknown keyword '{}'", short(other)))),
    }
    Ok(None)
}

/// The number of points: POINTS, which must agree with WIDTH × HEIGHT when both are given.
fn point_count(
    path: &Path,
    points: Option<u64>,
    width: Option<u64>,
    height: Option<u64>,
) -> Result<u64> {
    match (points, width, height) {
        (Some(p), Some(w), Some(h)) if w.checked_mul(h) != Some(p) => Err(parse_err(
            path,
            format!("the PCD header says POINTS {p} but WIDTH × HEIGHT = {w} × {h}"),
        )),
        (Some(p), _, _) => Ok(p),
        (None, Some(w), h) => w
            .checked_mul(h.unwrap_or(1))
            .ok_or_else(|| parse_err(path, "WIDTH × HEIGHT is too large".into())),
        (None, None, _) => Err(parse_err(
            path,
            "the PCD header has neither POINTS nor WIDTH".into(),
        )),
    }
}

/// The fields of the header's FIELDS, SIZE, TYPE and COUNT lines, checked.
fn header_fields(
    path: &Path,
    names: Vec<String>,
    sizes: &[usize],
    types: &[u8],
    counts: &[usize],
) -> Result<Vec<Field>> {
    let nf = names.len();
    for (what, len) in [
        ("SIZE", sizes.len()),
        ("TYPE", types.len()),
        ("COUNT", counts.len()),
    ] {
        if len != nf {
            return Err(parse_err(
                path,
                format!("the PCD header has {nf} FIELDS but {len} {what} entries"),
            ));
        }
    }
    let mut fields = Vec::with_capacity(nf);
    for (i, name) in names.into_iter().enumerate() {
        let ty = Ty {
            kind: types[i],
            size: sizes[i],
        };
        let ok = match ty.kind {
            b'F' => matches!(ty.size, 4 | 8),
            _ => matches!(ty.size, 1 | 2 | 4 | 8),
        };
        if !ok {
            return Err(parse_err(
                path,
                format!(
                    "field '{}' has TYPE {} with SIZE {} (allowed: I and U with 1, 2, 4 or 8 bytes, F with 4 or 8)",
                    name, ty.kind as char, ty.size
                ),
            ));
        }
        if counts[i] == 0 || counts[i] > 100_000 {
            return Err(parse_err(
                path,
                format!(
                    "field '{}' has COUNT {} (expected 1 to 100000)",
                    name, counts[i]
                ),
            ));
        }
        fields.push(Field {
            name,
            ty,
            count: counts[i],
            role: Role::Skip,
        });
    }
    Ok(fields)
}

fn short(s: &str) -> String {
    s.chars().take(40).collect()
}

/// Gives every field its role; returns whether the normals are present.
fn assign_roles(path: &Path, fields: &mut [Field]) -> Result<bool> {
    let find = |fields: &[Field], n: &str| fields.iter().position(|f| f.name == n);
    let role_of =
        |fields: &mut [Field], names: [&str; 3], make: fn(usize) -> Role| -> Result<bool> {
            let idx: Vec<Option<usize>> = names.iter().map(|n| find(fields, n)).collect();
            match idx[..] {
                [Some(a), Some(b), Some(c)] => {
                    for (axis, i) in [a, b, c].into_iter().enumerate() {
                        if fields[i].count != 1 {
                            return Err(parse_err(
                                path,
                                format!(
                                    "field '{}' has COUNT {}, expected 1",
                                    fields[i].name, fields[i].count
                                ),
                            ));
                        }
                        fields[i].role = make(axis);
                    }
                    Ok(true)
                }
                [None, None, None] => Ok(false),
                _ => Err(parse_err(
                    path,
                    format!(
                        "the PCD file has only some of the fields {}",
                        names.join(" ")
                    ),
                )),
            }
        };
    if !role_of(fields, ["x", "y", "z"], Role::Position)? {
        return Err(parse_err(path, "the PCD file has no x y z fields".into()));
    }
    let has_normals = role_of(fields, ["normal_x", "normal_y", "normal_z"], Role::Normal)?;
    Ok(has_normals)
}

/// Creates the attribute columns and points the fields at them.
fn make_attributes(fields: &mut [Field], cap: usize) -> Vec<Attribute> {
    let mut attrs: Vec<Attribute> = Vec::new();
    let mut seen: Vec<String> = Vec::new();
    for f in fields.iter_mut() {
        if f.role != Role::Skip || f.name == "_" || seen.contains(&f.name) {
            continue;
        }
        seen.push(f.name.clone());
        let packed = f.count == 1 && f.ty.size == 4 && (f.name == "rgb" || f.name == "rgba");
        if packed {
            let alpha = f.name == "rgba";
            f.role = Role::Color {
                first: attrs.len(),
                alpha,
            };
            for n in &["red", "green", "blue", "alpha"][..3 + usize::from(alpha)] {
                attrs.push(Attribute::new(
                    *n,
                    AttributeData::with_capacity(ScalarType::U8, cap),
                ));
            }
        } else {
            f.role = Role::Attr(attrs.len());
            let ty = f.ty.scalar_type();
            for k in 0..f.count {
                let name = if f.count == 1 {
                    f.name.clone()
                } else {
                    format!("{}_{k}", f.name)
                };
                attrs.push(Attribute::new(name, AttributeData::with_capacity(ty, cap)));
            }
        }
    }
    attrs
}

pub(crate) fn read_pcd<R: BufRead>(
    path: &Path,
    reader: R,
    file_len: u64,
    need_normals: bool,
) -> Result<PointCloud> {
    super::whole_cloud(|emit| {
        read_pcd_chunks(path, reader, file_len, need_normals, usize::MAX, emit)
    })
}

/// [`read_pcd`] handed to `emit` in clouds of at most `chunk` points, in file order; each
/// carries the viewpoint's scan origin, if any. A `binary_compressed` body stores the fields
/// one after another, so its points are complete only at its end: it is handed over as one
/// cloud. With an unbounded `chunk`, one cloud: the whole file.
pub(crate) fn read_pcd_chunks<R: BufRead>(
    path: &Path,
    mut reader: R,
    file_len: u64,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let (mut h, header_len) = parse_header(path, &mut reader)?;
    if need_normals && !h.has_normals {
        return Err(Error::MissingNormals {
            path: path.to_path_buf(),
        });
    }
    let record: usize = h.fields.iter().map(Field::bytes).sum();
    if record > MAX_RECORD {
        return Err(parse_err(
            path,
            format!("a point takes {record} bytes; at most {MAX_RECORD} are supported"),
        ));
    }
    let body = file_len.saturating_sub(header_len);
    let n = h.points;
    let mut compressed = None;
    let fits = match h.data {
        Data::Ascii => body / (2 * h.fields.len() as u64).max(1) + 1,
        Data::Binary => body / record as u64 + 1,
        Data::Compressed => {
            let mut sz = [0u8; 8];
            reader
                .read_exact(&mut sz)
                .map_err(|e| body_err(path, e, "the compressed sizes"))?;
            let csize = u64::from(u32::from_le_bytes([sz[0], sz[1], sz[2], sz[3]]));
            let usize_ = u64::from(u32::from_le_bytes([sz[4], sz[5], sz[6], sz[7]]));
            if n.checked_mul(record as u64) != Some(usize_) {
                return Err(parse_err(
                    path,
                    format!(
                        "the compressed body decompresses to {usize_} bytes, but {n} points of {record} bytes need {}",
                        n as u128 * record as u128
                    ),
                ));
            }
            if csize > body.saturating_sub(8) {
                return Err(parse_err(
                    path,
                    format!(
                        "the file is truncated: the compressed body has {csize} bytes but only {} follow the header",
                        body.saturating_sub(8)
                    ),
                ));
            }
            if usize_ > csize.saturating_mul(LZF_MAX_RATIO) + 64 {
                return Err(parse_err(
                    path,
                    format!(
                        "the compressed body ({csize} bytes) cannot hold {usize_} bytes of data"
                    ),
                ));
            }
            compressed = Some(csize);
            n + 1
        }
    };
    let whole = n.min(fits).min(usize::MAX as u64) as usize;
    let cap = if compressed.is_some() {
        whole
    } else {
        whole.min(chunk)
    };
    let scan_origins = match h.viewpoint {
        Some(v) if v != [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0] => vec![ScanOrigin {
            first_point: 0,
            origin: [v[0], v[1], v[2]],
        }],
        _ => Vec::new(),
    };
    let mut sink = Sink {
        positions: Vec::with_capacity(cap),
        normals: Vec::with_capacity(if h.has_normals { cap } else { 0 }),
        attributes: make_attributes(&mut h.fields, cap),
        has_normals: h.has_normals,
        chunk,
        cap,
        scan_origins,
        emitted: false,
        emit,
    };
    match (h.data, compressed) {
        (Data::Ascii, _) => read_ascii(path, reader, &h, &mut sink)?,
        (Data::Binary, _) => read_binary(path, reader, &h, record, &mut sink)?,
        (_, Some(csize)) => read_compressed(path, reader.take(csize), &h, &mut sink)?,
        (Data::Compressed, None) => unreachable!("sizes are read above"),
    }
    sink.finish()
}

fn body_err(path: &Path, e: std::io::Error, what: &str) -> Error {
    if e.kind() == std::io::ErrorKind::UnexpectedEof {
        parse_err(path, format!("the file is truncated: it ends in {what}"))
    } else if e.kind() == std::io::ErrorKind::InvalidData {
        parse_err(path, format!("the compressed body is corrupt: {e}"))
    } else {
        io_err(path, e)
    }
}

fn read_ascii<R: BufRead>(path: &Path, mut reader: R, h: &Header, sink: &mut Sink) -> Result<()> {
    let mut raw = Vec::new();
    let mut line = h.lines;
    for i in 0..h.points as usize {
        let text = loop {
            raw.clear();
            let got = reader
                .read_until(b'\n', &mut raw)
                .map_err(|e| io_err(path, e))?;
            if got == 0 {
                return Err(parse_err(
                    path,
                    format!(
                        "the file is truncated: it ends after line {line}, at point {i} of {} (0-based)",
                        h.points
                    ),
                ));
            }
            line += 1;
            let t = std::str::from_utf8(&raw)
                .map_err(|_| parse_err(path, format!("line {line}: not valid text")))?;
            if !t.trim().is_empty() {
                break t;
            }
        };
        let at = sink.push_point();
        let mut tok = text.split_ascii_whitespace();
        for f in &h.fields {
            let packed = matches!(f.role, Role::Color { .. });
            for k in 0..f.count {
                let Some(t) = tok.next() else {
                    return Err(parse_err(
                        path,
                        format!("line {line} (point {i}): too few values, the line ends before field '{}'", f.name),
                    ));
                };
                let v = f.ty.parse(t, packed).ok_or_else(|| {
                    parse_err(
                        path,
                        format!(
                            "line {line} (point {i}): '{}' is not a valid value of field '{}'",
                            short(t),
                            f.name
                        ),
                    )
                })?;
                sink.put(f, at, k, v);
            }
        }
        if let Some(t) = tok.next() {
            return Err(parse_err(
                path,
                format!(
                    "line {line} (point {i}): too many values ('{}' after the last field)",
                    short(t)
                ),
            ));
        }
        sink.point_done()?;
    }
    Ok(())
}

/// Decodes element `k` of field `f` from `b`.
#[inline]
fn value(f: &Field, b: &[u8]) -> f64 {
    if matches!(f.role, Role::Color { .. }) {
        f.ty.packed(b) as f64
    } else {
        f.ty.decode(b)
    }
}

fn read_binary<R: BufRead>(
    path: &Path,
    mut reader: R,
    h: &Header,
    record: usize,
    sink: &mut Sink,
) -> Result<()> {
    let n = h.points as usize;
    let chunk = (CHUNK_POINTS * 64 / record).clamp(1, CHUNK_POINTS);
    let mut buf = vec![0u8; record * chunk.min(n)];
    let mut done = 0usize;
    while done < n {
        let m = chunk.min(n - done);
        let bytes = &mut buf[..m * record];
        reader.read_exact(bytes).map_err(|e| {
            body_err(
                path,
                e,
                &format!("points {done} to {} (0-based) of {n}", done + m - 1),
            )
        })?;
        for rec in bytes.chunks_exact(record) {
            let at = sink.push_point();
            let mut off = 0;
            for f in &h.fields {
                for k in 0..f.count {
                    sink.put(f, at, k, value(f, &rec[off..]));
                    off += f.ty.size;
                }
            }
            sink.point_done()?;
        }
        done += m;
    }
    Ok(())
}

fn read_compressed<R: Read>(path: &Path, input: R, h: &Header, sink: &mut Sink) -> Result<()> {
    let n = h.points as usize;
    sink.positions.resize(n, [0.0; 3]);
    if h.has_normals {
        sink.normals.resize(n, [0.0; 3]);
    }
    let mut lzf = LzfReader::new(input);
    let mut buf = Vec::new();
    for f in &h.fields {
        let size = f.ty.size;
        let chunk = (CHUNK_POINTS * 64 / f.bytes()).clamp(1, CHUNK_POINTS);
        let mut done = 0usize;
        while done < n {
            let m = chunk.min(n - done);
            buf.resize(m * f.bytes(), 0);
            lzf.read_exact(&mut buf).map_err(|e| {
                body_err(
                    path,
                    e,
                    &format!("field '{}' of the compressed body", f.name),
                )
            })?;
            for (r, el) in buf.chunks_exact(f.bytes()).enumerate() {
                for k in 0..f.count {
                    sink.put(f, done + r, k, value(f, &el[k * size..]));
                }
            }
            done += m;
        }
    }
    Ok(())
}
