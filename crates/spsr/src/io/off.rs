//! Object File Format (OFF, from Geomview; read and written by MeshLab and CGAL), ASCII.
//!
//! A header keyword `[ST][C][N]OFF`, the counts `vertices faces edges` (on the keyword's line
//! or the next), one vertex per line — `x y z`, then `nx ny nz` with `N`, then a colour
//! `r g b [a]` with `C`, then `s t` with `ST` — and one face per line: `n i1 … in`, optionally
//! followed by a face colour. `#` starts a comment anywhere.
//!
//! Reading: normals with `N`; colours with `C` (whole numbers up to 255 as bytes, otherwise
//! as `[0, 1]`; see [`super::lines::colour_attributes`]); texture coordinates and face colours
//! are skipped; polygons are fan-triangulated, faces of fewer than three vertices skipped.
//! The 4-dimensional (`4OFF`) and n-dimensional (`nOFF`) variants are refused.
//!
//! Writing: `OFF`, `NOFF` when the mesh has normals, `COFF`/`CNOFF` when it has colours
//! (bytes `0..=255`, alpha when the mesh has it), and triangles `3 a b c`. Coordinates are
//! `f32` unless the mesh needs `f64` (see `needs_f64`). Density and other attributes are not
//! kept (OFF has no place for them).

use std::io::{BufRead, Write};
use std::path::Path;

use crate::mesh::Mesh;
use crate::Result;

use super::lines::{colour_attributes, Lines};
use super::write::{needs_f64, Encoder};

/// What the header keyword announces for each vertex line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Layout {
    texture: bool,
    colour: bool,
    normal: bool,
}

/// The layout of a header keyword `[ST][C][N][4][n]OFF`, `None` if it is not one, or an error
/// message for the variants not read.
fn keyword(word: &str) -> Option<std::result::Result<Layout, String>> {
    let mut rest = word.strip_suffix("OFF")?;
    let mut take = |prefix: &str| match rest.strip_prefix(prefix) {
        Some(r) => {
            rest = r;
            true
        }
        None => false,
    };
    let layout = Layout {
        texture: take("ST"),
        colour: take("C"),
        normal: take("N"),
    };
    let four = take("4");
    let n_dim = take("n");
    if !rest.is_empty() {
        return None;
    }
    Some(if four || n_dim {
        Err(format!(
            "'{word}' is a {} OFF file; only 3-dimensional OFF is read",
            if n_dim {
                "n-dimensional"
            } else {
                "4-dimensional"
            }
        ))
    } else {
        Ok(layout)
    })
}

/// True when the file's first word is an OFF header keyword (its magic).
pub(crate) fn is_off(head: &[u8]) -> bool {
    let start = head.iter().position(|b| !b.is_ascii_whitespace());
    let Some(start) = start else { return false };
    let word: Vec<u8> = head[start..]
        .iter()
        .copied()
        .take_while(|b| !b.is_ascii_whitespace() && *b != b'#')
        .collect();
    std::str::from_utf8(&word).is_ok_and(|w| keyword(w).is_some())
}

/// Smallest number of bytes a vertex line (`0 0 0\n`) and a face line (`3 0 0 0\n`) take.
const MIN_VERTEX_BYTES: u64 = 6;
const MIN_FACE_BYTES: u64 = 8;

pub(crate) fn read_off<R: BufRead>(path: &Path, reader: R, len: u64) -> Result<Mesh> {
    let mut lines = Lines::new(reader, path);
    if !lines.advance_to_data(Some('#'))? {
        return Err(super::parse_err(
            path,
            "the file is empty; expected an OFF header (OFF, COFF, NOFF, ...)".into(),
        ));
    }
    let mut words = lines.text().split_whitespace();
    let word = words.next().unwrap_or_default();
    let layout = match keyword(word) {
        Some(Ok(l)) => l,
        Some(Err(m)) => return Err(lines.error(m)),
        None => {
            return Err(lines.error(format!(
                "'{word}' is not an OFF header keyword (OFF, COFF, NOFF, CNOFF, STOFF, ...)"
            )))
        }
    };
    let mut counts: Vec<String> = words.map(str::to_owned).collect();
    if counts.is_empty() {
        if !lines.advance_to_data(Some('#'))? {
            return Err(lines.error("the file ends before the counts `vertices faces edges`"));
        }
        counts = lines.text().split_whitespace().map(str::to_owned).collect();
    }
    if counts.len() < 2 {
        return Err(lines.error(format!(
            "expected the counts `vertices faces edges`, found '{}'",
            counts.join(" ")
        )));
    }
    let count_line = lines.number();
    let nv: u32 = lines.number_in(&counts[0], "a vertex count (a whole number)")?;
    let nf: u64 = lines.number_in(&counts[1], "a face count (a whole number)")?;
    let mut mesh = Mesh {
        vertices: Vec::with_capacity(u64::from(nv).min(len / MIN_VERTEX_BYTES + 1) as usize),
        triangles: Vec::with_capacity(nf.min(len / MIN_FACE_BYTES + 1) as usize),
        ..Mesh::default()
    };
    let mut normals = Vec::new();
    let mut colours = Vec::new();
    for i in 0..nv {
        if !lines.advance_to_data(Some('#'))? {
            return Err(truncated(path, count_line, "vertices", nv.into(), i.into()));
        }
        read_vertex(&lines, layout, &mut mesh, &mut normals, &mut colours)?;
    }
    let mut corners: Vec<u32> = Vec::new();
    for i in 0..nf {
        if !lines.advance_to_data(Some('#'))? {
            return Err(truncated(path, count_line, "faces", nf, i));
        }
        read_face(&lines, nv, &mut corners)?;
        for k in 1..corners.len().saturating_sub(1) {
            mesh.triangles
                .push([corners[0], corners[k], corners[k + 1]]);
        }
    }
    if layout.normal {
        mesh.normals = Some(normals);
    }
    if layout.colour {
        mesh.attributes = colour_attributes(&colours);
    }
    Ok(mesh)
}

fn truncated(path: &Path, line: usize, what: &str, declared: u64, found: u64) -> crate::Error {
    super::parse_err(
        path,
        format!(
            "the file is truncated: line {line} declares {declared} {what}, but the file ends after {found}"
        ),
    )
}

/// One vertex line: position, then normal, colour and texture coordinates as `layout` says.
fn read_vertex<R: BufRead>(
    lines: &Lines<'_, R>,
    layout: Layout,
    mesh: &mut Mesh,
    normals: &mut Vec<[f32; 3]>,
    colours: &mut Vec<[f64; 4]>,
) -> Result<()> {
    let mut v = [0.0f64; 12];
    let mut n = 0;
    for word in lines.text().split_whitespace().take(v.len()) {
        v[n] = lines.number_in(word, "a number")?;
        n += 1;
    }
    let fixed = 3 + if layout.normal { 3 } else { 0 } + if layout.texture { 2 } else { 0 };
    let colour_values = n.saturating_sub(fixed);
    let expected = if layout.colour { fixed + 3 } else { fixed };
    if n < expected {
        return Err(lines.error(format!(
            "found {n} numbers for a vertex, expected {expected} (x y z{}{}{})",
            if layout.normal { " nx ny nz" } else { "" },
            if layout.colour { " r g b [a]" } else { "" },
            if layout.texture { " s t" } else { "" }
        )));
    }
    mesh.vertices.push([v[0], v[1], v[2]]);
    let mut at = 3;
    if layout.normal {
        normals.push([v[3] as f32, v[4] as f32, v[5] as f32]);
        at = 6;
    }
    if layout.colour {
        let alpha = if colour_values >= 4 {
            v[at + 3]
        } else {
            f64::NAN
        };
        colours.push([v[at], v[at + 1], v[at + 2], alpha]);
    }
    Ok(())
}

/// One face line `n i1 … in [colour]` into `corners` (left empty for fewer than 3 vertices).
fn read_face<R: BufRead>(lines: &Lines<'_, R>, nv: u32, corners: &mut Vec<u32>) -> Result<()> {
    corners.clear();
    let mut words = lines.text().split_whitespace();
    let k: usize = lines.number_in(
        words.next().unwrap_or_default(),
        "a face's vertex count (a whole number)",
    )?;
    for j in 0..k {
        let Some(word) = words.next() else {
            return Err(lines.error(format!(
                "the face has {j} vertex indices, but its count says {k}"
            )));
        };
        let i: u32 = lines.number_in(word, "a vertex index (a whole number)")?;
        if i >= nv {
            return Err(lines.error(format!(
                "the face refers to vertex {i}, but there are {nv} vertices (valid indices 0 to {})",
                i64::from(nv) - 1
            )));
        }
        corners.push(i);
    }
    if corners.len() < 3 {
        corners.clear();
    }
    Ok(())
}

pub(crate) fn write_off<W: Write>(out: &mut W, mesh: &Mesh) -> std::io::Result<()> {
    let colours = mesh.colors();
    let alpha = colours.is_some_and(|c| c.alpha.is_some());
    writeln!(
        out,
        "{}{}OFF\n{} {} 0",
        if colours.is_some() { "C" } else { "" },
        if mesh.normals.is_some() { "N" } else { "" },
        mesh.vertices.len(),
        mesh.triangles.len()
    )?;
    let double = needs_f64(&mesh.vertices);
    let mut enc = Encoder::new(out);
    for (i, v) in mesh.vertices.iter().enumerate() {
        if double {
            write!(enc.buf, "{} {} {}", v[0], v[1], v[2])?;
        } else {
            write!(enc.buf, "{} {} {}", v[0] as f32, v[1] as f32, v[2] as f32)?;
        }
        if let Some(n) = mesh.normals.as_ref().map(|n| n[i]) {
            write!(enc.buf, " {} {} {}", n[0], n[1], n[2])?;
        }
        if let Some(c) = &colours {
            let [r, g, b, a] = c.unit(i).map(|x| (x * 255.0).round() as u8);
            write!(enc.buf, " {r} {g} {b}")?;
            if alpha {
                write!(enc.buf, " {a}")?;
            }
        }
        enc.buf.push(b'\n');
        enc.maybe_flush()?;
    }
    for [a, b, c] in &mesh.triangles {
        writeln!(enc.buf, "3 {a} {b} {c}")?;
        enc.maybe_flush()?;
    }
    enc.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_keywords() {
        assert_eq!(keyword("OFF"), Some(Ok(Layout::default())));
        let all = Layout {
            texture: true,
            colour: true,
            normal: true,
        };
        assert_eq!(keyword("STCNOFF"), Some(Ok(all)));
        assert!(matches!(keyword("4OFF"), Some(Err(_))));
        assert!(matches!(keyword("nOFF"), Some(Err(_))));
        assert_eq!(keyword("NCOFF"), None);
        assert_eq!(keyword("off"), None);
        assert!(is_off(b"  COFF\n3 1 0"));
        assert!(is_off(b"OFF# comment"));
        assert!(!is_off(b"OFFICE 1 2 3"));
    }
}
