//! glTF 2.0 binary (`.glb`) writing: one mesh of one indexed triangle primitive.
//!
//! The file is a 12-byte header, a JSON chunk (padded with spaces to 4 bytes) and a binary
//! chunk holding, one after another, `POSITION` (`f32` VEC3, with the `min`/`max` the
//! specification requires), `NORMAL` when the mesh has normals (unit `f32` VEC3; zero or
//! non-finite normals are written as `+Z`), `COLOR_0` when it has colours, `_DENSITY`
//! (`f32` SCALAR, an application-specific attribute) when it has density, and the indices
//! (`u32` SCALAR). Every section is a multiple of 4 bytes long, so every accessor is
//! aligned as the specification asks; everything is little endian.
//!
//! Colours: glTF vertex colours are *linear*, while point colours are sRGB-encoded (as
//! cameras and scanners store them), so each channel is converted from sRGB to linear and
//! stored as a normalised `u16` VEC4 (8-bit linear would band the dark tones); alpha is
//! copied. A mesh far from the origin (see `needs_f64`) is written relative to its bounding
//! box centre, with that centre as the node's translation, so `f32` keeps its precision.
//! A mesh without triangles gives a file with nothing but its `asset` description.

use std::fmt::Write as _;
use std::io::Write;

use crate::mesh::Mesh;

use super::write::{needs_f64, Encoder};

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Bytes per vertex and per triangle in the binary chunk.
fn strides(mesh: &Mesh) -> (u64, u64) {
    let mut v = 12;
    if mesh.normals.is_some() {
        v += 12;
    }
    if mesh.colors().is_some() {
        v += 8;
    }
    if mesh.density.is_some() {
        v += 4;
    }
    (v, 12)
}

fn has_geometry(mesh: &Mesh) -> bool {
    !mesh.vertices.is_empty() && !mesh.triangles.is_empty()
}

/// Refuses meshes whose file would exceed the 4 GiB that GLB lengths can express.
pub(crate) fn check_size(mesh: &Mesh) -> Result<(), String> {
    let (v, t) = strides(mesh);
    let bin = v * mesh.vertices.len() as u64 + t * mesh.triangles.len() as u64;
    // 4 KiB is far more than the JSON chunk takes.
    if bin + 4096 > u64::from(u32::MAX) {
        return Err(format!(
            "the mesh is too large for a .glb file ({} vertices, {} triangles: {bin} bytes of data; GLB files hold at most 4 GiB); write PLY instead",
            mesh.vertices.len(),
            mesh.triangles.len()
        ));
    }
    Ok(())
}

/// sRGB-encoded value in `[0, 1]` to linear.
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn unit_normal(n: [f32; 3]) -> [f32; 3] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len > 0.0 && len.is_finite() {
        n.map(|c| c / len)
    } else {
        [0.0, 0.0, 1.0]
    }
}

/// The bounding box centre, used as the node translation when `f32` needs it.
fn offset(mesh: &Mesh) -> Option<[f64; 3]> {
    if !needs_f64(&mesh.vertices) {
        return None;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for v in mesh
        .vertices
        .iter()
        .filter(|v| v.iter().all(|c| c.is_finite()))
    {
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    Some([0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k])))
}

fn position(v: &[f64; 3], shift: [f64; 3]) -> [f32; 3] {
    [0, 1, 2].map(|k| (v[k] - shift[k]) as f32)
}

fn json(mesh: &Mesh, shift: Option<[f64; 3]>) -> String {
    let mut j = String::from(r#"{"asset":{"version":"2.0","generator":"spsr"}"#);
    if !has_geometry(mesh) {
        // Scenes are optional, and a scene without nodes trips some readers.
        j.push('}');
        return j;
    }
    j.push_str(r#","scene":0,"#);
    let nv = mesh.vertices.len();
    let s = shift.unwrap_or([0.0; 3]);
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for v in &mesh.vertices {
        let p = position(v, s);
        for k in 0..3 {
            if p[k].is_finite() {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    for k in 0..3 {
        if lo[k] > hi[k] {
            (lo[k], hi[k]) = (0.0, 0.0);
        }
    }
    // (name, component type, normalized, type, bytes per element, target, extra accessor JSON)
    let mut parts: Vec<(&str, u32, bool, &str, usize, u32, String)> = vec![(
        "POSITION",
        FLOAT,
        false,
        "VEC3",
        12,
        ARRAY_BUFFER,
        format!(
            r#","min":[{},{},{}],"max":[{},{},{}]"#,
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
        ),
    )];
    if mesh.normals.is_some() {
        parts.push((
            "NORMAL",
            FLOAT,
            false,
            "VEC3",
            12,
            ARRAY_BUFFER,
            String::new(),
        ));
    }
    if mesh.colors().is_some() {
        parts.push((
            "COLOR_0",
            UNSIGNED_SHORT,
            true,
            "VEC4",
            8,
            ARRAY_BUFFER,
            String::new(),
        ));
    }
    if mesh.density.is_some() {
        parts.push((
            "_DENSITY",
            FLOAT,
            false,
            "SCALAR",
            4,
            ARRAY_BUFFER,
            String::new(),
        ));
    }
    let mut views = String::new();
    let mut accessors = String::new();
    let mut attributes = String::new();
    let mut offset = 0usize;
    for (i, (name, ctype, norm, ty, size, target, extra)) in parts.iter().enumerate() {
        let len = size * nv;
        let sep = if i > 0 { "," } else { "" };
        let _ = write!(
            views,
            r#"{sep}{{"buffer":0,"byteOffset":{offset},"byteLength":{len},"target":{target}}}"#
        );
        let normalized = if *norm { r#","normalized":true"# } else { "" };
        let _ = write!(
            accessors,
            r#"{sep}{{"bufferView":{i},"componentType":{ctype}{normalized},"count":{nv},"type":"{ty}"{extra}}}"#
        );
        let _ = write!(attributes, r#"{sep}"{name}":{i}"#);
        offset += len;
    }
    let k = parts.len();
    let idx_len = 12 * mesh.triangles.len();
    let _ = write!(
        views,
        r#",{{"buffer":0,"byteOffset":{offset},"byteLength":{idx_len},"target":{ELEMENT_ARRAY_BUFFER}}}"#
    );
    let _ = write!(
        accessors,
        r#",{{"bufferView":{k},"componentType":{UNSIGNED_INT},"count":{},"type":"SCALAR"}}"#,
        3 * mesh.triangles.len()
    );
    let translation = match shift {
        Some(t) => format!(r#","translation":[{},{},{}]"#, t[0], t[1], t[2]),
        None => String::new(),
    };
    let _ = write!(
        j,
        r#""scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0{translation}}}],"meshes":[{{"primitives":[{{"attributes":{{{attributes}}},"indices":{k},"mode":4}}]}}],"buffers":[{{"byteLength":{}}}],"bufferViews":[{views}],"accessors":[{accessors}]}}"#,
        offset + idx_len
    );
    j
}

pub(crate) fn write_glb<W: Write>(out: &mut W, mesh: &Mesh) -> std::io::Result<()> {
    let shift = offset(mesh);
    let mut j = json(mesh, shift).into_bytes();
    while !j.len().is_multiple_of(4) {
        j.push(b' ');
    }
    let geometry = has_geometry(mesh);
    let (v, t) = strides(mesh);
    let bin = if geometry {
        v as usize * mesh.vertices.len() + t as usize * mesh.triangles.len()
    } else {
        0
    };
    let total = 12 + 8 + j.len() + if geometry { 8 + bin } else { 0 };
    out.write_all(&MAGIC.to_le_bytes())?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&(total as u32).to_le_bytes())?;
    out.write_all(&(j.len() as u32).to_le_bytes())?;
    out.write_all(&CHUNK_JSON.to_le_bytes())?;
    out.write_all(&j)?;
    if !geometry {
        return Ok(());
    }
    out.write_all(&(bin as u32).to_le_bytes())?;
    out.write_all(&CHUNK_BIN.to_le_bytes())?;
    let mut enc = Encoder::new(out);
    let s = shift.unwrap_or([0.0; 3]);
    for p in &mesh.vertices {
        for c in position(p, s) {
            enc.buf.extend_from_slice(&c.to_le_bytes());
        }
        enc.maybe_flush()?;
    }
    if let Some(normals) = &mesh.normals {
        for n in normals {
            for c in unit_normal(*n) {
                enc.buf.extend_from_slice(&c.to_le_bytes());
            }
            enc.maybe_flush()?;
        }
    }
    if let Some(colors) = mesh.colors() {
        for i in 0..mesh.vertices.len() {
            let [r, g, b, a] = colors.unit(i);
            for c in [srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), a] {
                let q = (c * 65535.0).round() as u16;
                enc.buf.extend_from_slice(&q.to_le_bytes());
            }
            enc.maybe_flush()?;
        }
    }
    if let Some(d) = &mesh.density {
        for x in d {
            enc.buf.extend_from_slice(&x.to_le_bytes());
            enc.maybe_flush()?;
        }
    }
    for tri in &mesh.triangles {
        for i in tri {
            enc.buf.extend_from_slice(&i.to_le_bytes());
        }
        enc.maybe_flush()?;
    }
    enc.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_conversion_fixes_the_ends_and_darkens_the_middle() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.214).abs() < 1e-3);
    }

    #[test]
    fn empty_meshes_have_no_scene() {
        let j = json(&Mesh::default(), None);
        assert_eq!(j, r#"{"asset":{"version":"2.0","generator":"spsr"}}"#);
    }
}
