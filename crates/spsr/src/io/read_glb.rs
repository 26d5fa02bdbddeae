//! Meshes from glTF 2.0 binary files (`.glb`): everything spsr writes, and the common subset
//! of other files.
//!
//! Read: the default scene's nodes (or, without scenes, every mesh once), each mesh placed by
//! its node's transform (`matrix`, or `translation`/`rotation`/`scale`, composed down the node
//! tree); of each primitive, triangle lists, strips and fans (points and lines are skipped),
//! with `POSITION`, indices (or none: consecutive vertices), and `NORMAL`, `COLOR_0` and
//! spsr's `_DENSITY` where *every* primitive has them. Accessors may be interleaved (a
//! `byteStride`) and of any component type the specification allows for them (normalised
//! integers included). Colours are converted from glTF's linear values back to sRGB bytes
//! (`red green blue`, and `alpha` when some vertex is not opaque). Refused, with an error:
//! buffers outside the file (a `uri`), sparse accessors, and a node reached twice.
//!
//! The binary chunk is read accessor by accessor through the file, never loaded whole, and
//! every accessor is checked to lie inside its buffer view, which lies inside the chunk, so
//! a count in the JSON cannot make the reader reserve more than the file holds.

use std::io::{BufRead, Seek, SeekFrom};
use std::path::Path;

use serde_json::Value;

use crate::attributes::{Attribute, AttributeData};
use crate::mesh::Mesh;
use crate::Result;

use super::{io_err, parse_err};

const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
/// Triangle modes: list, strip, fan.
const TRIANGLES: u64 = 4;
const TRIANGLE_STRIP: u64 = 5;
const TRIANGLE_FAN: u64 = 6;

/// True when `head` starts like a GLB file.
pub(crate) fn is_glb(head: &[u8]) -> bool {
    head.starts_with(MAGIC)
}

/// The file, its JSON, and where its binary chunk lies.
struct Glb<'p, R> {
    path: &'p Path,
    reader: R,
    json: Value,
    /// Offset and length of the binary chunk's data.
    bin: Option<(u64, u64)>,
    /// Bytes of accessor data still allowed to be read: a multiple of the file's size, so
    /// that nodes instancing one mesh many times cannot make the reader allocate without
    /// bound.
    budget: u64,
}

/// How many times its own size a file's meshes may be read, counting every instance.
const INSTANCING_LIMIT: u64 = 64;

/// A 4×4 transform, column-major as glTF stores it.
type Matrix = [f64; 16];

const IDENTITY: Matrix = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
];

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

pub(crate) fn read_glb<R: BufRead + Seek>(path: &Path, mut reader: R, len: u64) -> Result<Mesh> {
    let mut head = [0u8; 20];
    reader.read_exact(&mut head).map_err(|_| {
        parse_err(
            path,
            format!("the file is truncated: {len} bytes, less than a GLB header (20 bytes)"),
        )
    })?;
    if !is_glb(&head) {
        return Err(parse_err(path, "not a GLB file (no 'glTF' magic)".into()));
    }
    let version = u32_at(&head, 4);
    if version != 2 {
        return Err(parse_err(
            path,
            format!("glTF version {version}; only version 2 is read"),
        ));
    }
    let json_len = u64::from(u32_at(&head, 12));
    if u32_at(&head, 16) != CHUNK_JSON {
        return Err(parse_err(path, "the first chunk is not JSON".into()));
    }
    if 20 + json_len > len {
        return Err(parse_err(
            path,
            format!("the file is truncated: the JSON chunk declares {json_len} bytes, the file has {len}"),
        ));
    }
    let mut text = vec![0u8; json_len as usize];
    reader.read_exact(&mut text).map_err(|e| io_err(path, e))?;
    let json: Value = serde_json::from_slice(&text)
        .map_err(|e| parse_err(path, format!("the JSON chunk is malformed: {e}")))?;
    drop(text);
    let bin_at = 20 + json_len;
    let mut bin = None;
    if bin_at + 8 <= len {
        let mut chunk = [0u8; 8];
        reader.read_exact(&mut chunk).map_err(|e| io_err(path, e))?;
        let bin_len = u64::from(u32_at(&chunk, 0));
        if u32_at(&chunk, 4) == CHUNK_BIN {
            if bin_at + 8 + bin_len > len {
                return Err(parse_err(
                    path,
                    format!("the file is truncated: the binary chunk declares {bin_len} bytes at offset {}, the file has {len}", bin_at + 8),
                ));
            }
            bin = Some((bin_at + 8, bin_len));
        }
    }
    let mut glb = Glb {
        path,
        reader,
        json,
        bin,
        budget: INSTANCING_LIMIT * len,
    };
    glb.read_mesh()
}

/// Per-vertex columns, each kept only while every primitive has it.
struct Columns {
    mesh: Mesh,
    colours: Option<Vec<[f64; 4]>>,
}

impl<R: BufRead + Seek> Glb<'_, R> {
    fn err(&self, message: String) -> crate::Error {
        parse_err(self.path, message)
    }

    /// `json[key][index]`, or an error naming what is missing.
    fn item(&self, key: &str, index: &Value) -> Result<&Value> {
        let i = index
            .as_u64()
            .ok_or_else(|| self.err(format!("a {key} index is not a whole number: {index}")))?;
        self.json[key]
            .get(i as usize)
            .ok_or_else(|| self.err(format!("{key} {i} does not exist")))
    }

    fn read_mesh(&mut self) -> Result<Mesh> {
        let scene = self.json.get("scene").cloned().unwrap_or(Value::from(0));
        let instances = match self.json["scenes"].as_array().filter(|s| !s.is_empty()) {
            Some(_) => self.walk(&self.item("scenes", &scene)?["nodes"])?,
            None => {
                let n = self.json["meshes"].as_array().map_or(0, Vec::len);
                (0..n).map(|i| (Value::from(i), IDENTITY)).collect()
            }
        };
        let mut cols = Columns {
            mesh: Mesh {
                normals: Some(Vec::new()),
                density: Some(Vec::new()),
                ..Mesh::default()
            },
            colours: Some(Vec::new()),
        };
        for (mesh, matrix) in &instances {
            let primitives = self.item("meshes", mesh)?["primitives"].clone();
            for p in primitives.as_array().into_iter().flatten() {
                self.primitive(p, matrix, &mut cols)?;
            }
        }
        let mut mesh = cols.mesh;
        if mesh.vertices.is_empty() {
            mesh.normals = None;
            mesh.density = None;
        }
        if let Some(c) = cols.colours.filter(|c| !c.is_empty()) {
            mesh.attributes = srgb_bytes(&c);
        }
        Ok(mesh)
    }

    /// Collects the meshes under the root `nodes`, with their world transforms (a stack, not
    /// recursion, so a deep tree cannot overflow the call stack).
    fn walk(&self, nodes: &Value) -> Result<Vec<(Value, Matrix)>> {
        let mut out = Vec::new();
        let mut seen = vec![false; self.json["nodes"].as_array().map_or(0, Vec::len)];
        let mut stack: Vec<(Value, Matrix)> = nodes
            .as_array()
            .into_iter()
            .flatten()
            .rev()
            .map(|n| (n.clone(), IDENTITY))
            .collect();
        while let Some((node, parent)) = stack.pop() {
            let n = self.item("nodes", &node)?;
            let i = node.as_u64().unwrap_or_default() as usize;
            if std::mem::replace(&mut seen[i], true) {
                return Err(self.err(format!("node {i} is reached twice; glTF nodes form a tree")));
            }
            let m = mul(&parent, &self.local(n, i)?);
            if let Some(mesh) = n.get("mesh") {
                out.push((mesh.clone(), m));
            }
            let children = n["children"].as_array().into_iter().flatten().rev();
            stack.extend(children.map(|c| (c.clone(), m)));
        }
        Ok(out)
    }

    /// A node's own transform.
    fn local(&self, n: &Value, i: usize) -> Result<Matrix> {
        let floats = |key: &str, k: usize| -> Result<Option<Vec<f64>>> {
            let Some(v) = n.get(key) else { return Ok(None) };
            let v: Option<Vec<f64>> = v
                .as_array()
                .filter(|a| a.len() == k)
                .and_then(|a| a.iter().map(Value::as_f64).collect());
            v.filter(|v| v.iter().all(|x| x.is_finite()))
                .map(Some)
                .ok_or_else(|| self.err(format!("node {i}: '{key}' is not {k} finite numbers")))
        };
        if let Some(m) = floats("matrix", 16)? {
            return Ok(std::array::from_fn(|k| m[k]));
        }
        let t = floats("translation", 3)?.unwrap_or(vec![0.0; 3]);
        let q = floats("rotation", 4)?.unwrap_or(vec![0.0, 0.0, 0.0, 1.0]);
        let s = floats("scale", 3)?.unwrap_or(vec![1.0; 3]);
        let (x, y, z, w) = (q[0], q[1], q[2], q[3]);
        // Rotation matrix of the unit quaternion, columns scaled, then the translation.
        let r = [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y + z * w),
                2.0 * (x * z - y * w),
            ],
            [
                2.0 * (x * y - z * w),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z + x * w),
            ],
            [
                2.0 * (x * z + y * w),
                2.0 * (y * z - x * w),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ];
        let mut m = IDENTITY;
        for c in 0..3 {
            for row in 0..3 {
                m[4 * c + row] = r[c][row] * s[c];
            }
            m[12 + c] = t[c];
        }
        Ok(m)
    }

    fn primitive(&mut self, p: &Value, matrix: &Matrix, cols: &mut Columns) -> Result<()> {
        let mode = p.get("mode").map_or(Some(TRIANGLES), Value::as_u64);
        if !matches!(mode, Some(TRIANGLES | TRIANGLE_STRIP | TRIANGLE_FAN)) {
            return Ok(()); // points and lines
        }
        let attributes = &p["attributes"];
        let Some(position) = attributes.get("POSITION") else {
            return Err(self.err("a triangle primitive has no POSITION attribute".into()));
        };
        let positions = self.floats(position, 3, false)?;
        let base = cols.mesh.vertices.len();
        let count = positions.len() / 3;
        if u32::try_from(base + count).is_err() {
            return Err(self.err("more than 4294967295 vertices".into()));
        }
        cols.mesh
            .vertices
            .extend(positions.chunks_exact(3).map(|v| transform(matrix, v)));
        let normals = match attributes.get("NORMAL") {
            Some(a) => Some(self.floats(a, 3, false)?),
            None => None,
        };
        keep(&mut cols.mesh.normals, normals, count, |out, v| {
            out.extend(v.chunks_exact(3).map(|n| normal(matrix, n)));
        });
        let density = match attributes.get("_DENSITY") {
            Some(a) => Some(self.floats(a, 1, false)?),
            None => None,
        };
        keep(&mut cols.mesh.density, density, count, |out, v| {
            out.extend(v.iter().map(|&d| d as f32));
        });
        let colours = match attributes.get("COLOR_0") {
            Some(a) => Some(self.colours(a)?),
            None => None,
        };
        keep(&mut cols.colours, colours, count, |out, v| out.extend(v));
        let order: Vec<u64> = match p.get("indices") {
            Some(a) => self
                .floats(a, 1, true)?
                .into_iter()
                .map(|i| i as u64)
                .collect(),
            None => (0..count as u64).collect(),
        };
        if let Some(&bad) = order.iter().find(|&&i| i >= count as u64) {
            return Err(self.err(format!(
                "an index refers to vertex {bad}, but the primitive has {count} vertices"
            )));
        }
        let at = |k: usize| (base as u64 + order[k]) as u32;
        let tris = &mut cols.mesh.triangles;
        match mode {
            Some(TRIANGLES) => {
                tris.extend((0..order.len() / 3).map(|t| [at(3 * t), at(3 * t + 1), at(3 * t + 2)]))
            }
            Some(TRIANGLE_STRIP) => tris.extend((0..order.len().saturating_sub(2)).map(|k| {
                if k % 2 == 0 {
                    [at(k), at(k + 1), at(k + 2)]
                } else {
                    [at(k + 1), at(k), at(k + 2)]
                }
            })),
            _ => tris.extend((1..order.len().saturating_sub(1)).map(|k| [at(0), at(k), at(k + 1)])),
        }
        Ok(())
    }

    /// `COLOR_0` as linear `[r, g, b, a]` in `[0, 1]`.
    fn colours(&mut self, accessor: &Value) -> Result<Vec<[f64; 4]>> {
        let ty = self.item("accessors", accessor)?["type"]
            .as_str()
            .unwrap_or("");
        let k = if ty == "VEC3" { 3 } else { 4 };
        let v = self.floats(accessor, k, false)?;
        Ok(v.chunks_exact(k)
            .map(|c| [c[0], c[1], c[2], if k == 4 { c[3] } else { 1.0 }])
            .collect())
    }

    /// The values of an accessor of `k` components, as `f64` (normalised integers mapped to
    /// `[0, 1]` or `[-1, 1]`); `indices` asks for unsigned integers, not normalised.
    fn floats(&mut self, index: &Value, k: usize, indices: bool) -> Result<Vec<f64>> {
        let a = self.item("accessors", index)?.clone();
        let i = index.as_u64().unwrap_or_default();
        let ty = a["type"].as_str().unwrap_or("");
        let want = ["SCALAR", "VEC2", "VEC3", "VEC4"][k - 1];
        if ty != want {
            return Err(self.err(format!("accessor {i} is '{ty}', expected '{want}'")));
        }
        if a.get("sparse").is_some() {
            return Err(self.err(format!(
                "accessor {i} is sparse; sparse accessors are not read"
            )));
        }
        let component = a["componentType"].as_u64().unwrap_or(0);
        let size: u64 = match component {
            5120 | 5121 => 1,
            5122 | 5123 => 2,
            5125 | 5126 => 4,
            c => return Err(self.err(format!("accessor {i} has unknown componentType {c}"))),
        };
        if indices && !matches!(component, 5121 | 5123 | 5125) {
            return Err(self.err(format!(
                "accessor {i} holds indices but is not of an unsigned integer type"
            )));
        }
        let normalized = a["normalized"].as_bool().unwrap_or(false);
        let count = a["count"].as_u64().unwrap_or(0);
        let (start, stride) = self.span(&a, i, k as u64 * size, count)?;
        let bytes = count * k as u64 * size;
        self.budget = self.budget.checked_sub(bytes).ok_or_else(|| {
            self.err(format!(
                "the scene instances its meshes so often that more than {INSTANCING_LIMIT} \
                 times the file's size would be read"
            ))
        })?;
        let mut out = Vec::with_capacity(count as usize * k);
        let element = (k as u64 * size) as usize;
        let mut buf = vec![0u8; element];
        self.reader
            .seek(SeekFrom::Start(start))
            .map_err(|e| io_err(self.path, e))?;
        for e in 0..count {
            if e > 0 {
                self.reader
                    .seek_relative((stride - element as u64) as i64)
                    .map_err(|e| io_err(self.path, e))?;
            }
            self.reader
                .read_exact(&mut buf)
                .map_err(|e| io_err(self.path, e))?;
            out.extend(
                buf.chunks_exact(size as usize)
                    .map(|b| decode(component, normalized, b)),
            );
        }
        Ok(out)
    }

    /// Where an accessor's first element starts in the file, and its stride; errors unless
    /// all `count` elements of `element` bytes lie inside the view and the binary chunk.
    fn span(&self, a: &Value, i: u64, element: u64, count: u64) -> Result<(u64, u64)> {
        let Some(view_index) = a.get("bufferView") else {
            return Err(self.err(format!("accessor {i} has no bufferView")));
        };
        let view = self.item("bufferViews", view_index)?;
        let buffer = self.item("buffers", &view["buffer"])?;
        if buffer.get("uri").is_some() || view["buffer"].as_u64() != Some(0) {
            return Err(self.err(
                "a buffer lies outside the file (a 'uri'); only self-contained .glb files are read"
                    .into(),
            ));
        }
        let Some((bin_start, bin_len)) = self.bin else {
            return Err(self.err("the file has no binary chunk, but accessors refer to one".into()));
        };
        let num = |v: &Value, key: &str| v.get(key).and_then(Value::as_u64).unwrap_or(0);
        let view_offset = num(view, "byteOffset");
        let view_len = num(view, "byteLength");
        let stride = view
            .get("byteStride")
            .and_then(Value::as_u64)
            .unwrap_or(element);
        let offset = num(a, "byteOffset");
        let end = count.checked_sub(1).map_or(Some(0), |n| {
            n.checked_mul(stride)
                .and_then(|x| x.checked_add(offset))
                .and_then(|x| x.checked_add(element))
        });
        let fits = stride >= element
            && end.is_some_and(|end| end <= view_len)
            && view_offset
                .checked_add(view_len)
                .is_some_and(|e| e <= bin_len);
        if !fits {
            return Err(self.err(format!(
                "accessor {i} ({count} elements of {element} bytes, stride {stride}) does not \
                 fit in its buffer view ({view_len} bytes at {view_offset}) inside the binary \
                 chunk ({bin_len} bytes)"
            )));
        }
        Ok((bin_start + view_offset + offset, stride))
    }
}

/// One component as `f64`.
fn decode(component: u64, normalized: bool, b: &[u8]) -> f64 {
    let (v, max) = match component {
        5120 => (f64::from(b[0] as i8), 127.0),
        5121 => (f64::from(b[0]), 255.0),
        5122 => (f64::from(i16::from_le_bytes([b[0], b[1]])), 32767.0),
        5123 => (f64::from(u16::from_le_bytes([b[0], b[1]])), 65535.0),
        5125 => (f64::from(u32_at(b, 0)), 1.0),
        _ => return f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
    };
    if normalized {
        (v / max).max(-1.0)
    } else {
        v
    }
}

/// Appends a primitive's values to a column while every primitive has them; drops the column
/// for good at the first primitive without.
fn keep<T, V>(
    column: &mut Option<Vec<T>>,
    values: Option<V>,
    count: usize,
    add: impl FnOnce(&mut Vec<T>, V),
) {
    match (column.as_mut(), values) {
        (Some(out), Some(v)) => {
            let before = out.len();
            add(out, v);
            debug_assert_eq!(out.len(), before + count);
        }
        _ => *column = None,
    }
}

fn mul(a: &Matrix, b: &Matrix) -> Matrix {
    std::array::from_fn(|k| {
        let (col, row) = (k / 4, k % 4);
        (0..4).map(|j| a[4 * j + row] * b[4 * col + j]).sum()
    })
}

fn transform(m: &Matrix, v: &[f64]) -> [f64; 3] {
    if *m == IDENTITY {
        return [v[0], v[1], v[2]];
    }
    std::array::from_fn(|r| m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r])
}

/// A normal moved by the inverse transpose of the transform's linear part (its cofactor
/// matrix, up to a scale), renormalised.
fn normal(m: &Matrix, n: &[f64]) -> [f32; 3] {
    if *m == IDENTITY {
        return [n[0] as f32, n[1] as f32, n[2] as f32];
    }
    let a = |r: usize, c: usize| m[4 * c + r];
    let cof = |r: usize, c: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (c1, c2) = ((c + 1) % 3, (c + 2) % 3);
        a(r1, c1) * a(r2, c2) - a(r1, c2) * a(r2, c1)
    };
    let v: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| cof(r, c) * n[c]).sum());
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if len > 0.0 && len.is_finite() {
        v.map(|c| (c / len) as f32)
    } else {
        [0.0; 3]
    }
}

/// Linear value in `[0, 1]` to sRGB-encoded.
fn linear_to_srgb(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// Linear colours as sRGB byte attributes; alpha (not converted) only when some vertex is
/// not opaque.
fn srgb_bytes(colours: &[[f64; 4]]) -> Vec<Attribute> {
    let byte = |x: f64| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    let opaque = colours.iter().all(|c| byte(c[3]) == 255);
    let names = ["red", "green", "blue", "alpha"];
    (0..if opaque { 3 } else { 4 })
        .map(|k| {
            let data = colours
                .iter()
                .map(|c| byte(if k < 3 { linear_to_srgb(c[k]) } else { c[k] }))
                .collect();
            Attribute::new(names[k], AttributeData::U8(data))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_and_normals_follow_the_node() {
        // A quarter turn about z, scale 2 along x (before the turn), then a shift.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let node = serde_json::json!({
            "translation": [1.0, 2.0, 3.0], "rotation": [0.0, 0.0, s, s], "scale": [2.0, 1.0, 1.0]
        });
        let glb = Glb {
            path: Path::new("t.glb"),
            reader: std::io::Cursor::new(Vec::new()),
            json: Value::Null,
            bin: None,
            budget: 0,
        };
        let m = glb.local(&node, 0).unwrap();
        let p = transform(&m, &[1.0, 0.0, 0.0]);
        for (a, b) in p.iter().zip([1.0, 4.0, 3.0]) {
            assert!((a - b).abs() < 1e-12, "{p:?}");
        }
        let n = normal(&m, &[0.0, 1.0, 0.0]);
        assert!((n[0] + 1.0).abs() < 1e-6 && n[1].abs() < 1e-6, "{n:?}");
    }

    #[test]
    fn srgb_round_trip_of_bytes() {
        for b in 0..=255u8 {
            let s = f64::from(b) / 255.0;
            let lin = if s <= 0.04045 {
                s / 12.92
            } else {
                ((s + 0.055) / 1.055).powf(2.4)
            };
            let q = (lin * 65535.0).round() / 65535.0;
            let a = srgb_bytes(&[[q, q, q, 1.0]]);
            assert_eq!(a.len(), 3);
            assert_eq!(a[0].data, AttributeData::U8(vec![b]));
        }
    }
}
