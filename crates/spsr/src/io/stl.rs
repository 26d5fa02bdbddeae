//! STL, binary (the default) or ASCII. STL has no shared vertices, no vertex normals,
//! colours or other attributes: each triangle is written with its three corners and its
//! geometric unit normal (zero for a degenerate triangle), all in `f32`.
//!
//! Reading merges corners at identical positions into one vertex (bit for bit, `-0` equal to
//! `0`), so the mesh is indexed again and its topology can be checked: an spsr mesh written
//! as STL reads back closed when it was closed, unless two of its vertices round to the same
//! `f32` position. Facet normals are ignored (the triangles' order of corners gives their
//! orientation). A file is binary when its size is the 84-byte header plus 50 bytes per
//! triangle it declares, else ASCII when it starts with `solid` (keywords in any case); ASCII facets with more than
//! three corners are fan-triangulated.

use std::io::{BufRead, Write};
use std::path::Path;

use rustc_hash::FxHashMap;

use crate::mesh::Mesh;
use crate::Result;

use super::lines::Lines;
use super::write::Encoder;
use super::{io_err, parse_err};

/// The unit normal of a triangle from its corners (right-hand rule), zero when degenerate.
fn facet_normal(p: &[[f64; 3]; 3]) -> [f32; 3] {
    let u = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
    let v = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len > 0.0 && len.is_finite() {
        n.map(|c| (c / len) as f32)
    } else {
        [0.0; 3]
    }
}

fn corners(mesh: &Mesh, t: &[u32; 3]) -> [[f64; 3]; 3] {
    t.map(|i| mesh.vertices[i as usize])
}

pub(crate) fn write_binary<W: Write>(out: &mut W, mesh: &Mesh) -> std::io::Result<()> {
    // The 80-byte header must not start with "solid", which marks ASCII STL.
    let mut head = [b' '; 80];
    let text = b"binary STL written by spsr";
    head[..text.len()].copy_from_slice(text);
    out.write_all(&head)?;
    out.write_all(&(mesh.triangles.len() as u32).to_le_bytes())?;
    let mut enc = Encoder::new(out);
    for t in &mesh.triangles {
        let p = corners(mesh, t);
        for c in facet_normal(&p) {
            enc.buf.extend_from_slice(&c.to_le_bytes());
        }
        for v in &p {
            for &c in v {
                enc.buf.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        enc.buf.extend_from_slice(&[0, 0]);
        enc.maybe_flush()?;
    }
    enc.finish()
}

pub(crate) fn write_ascii<W: Write>(out: &mut W, mesh: &Mesh) -> std::io::Result<()> {
    out.write_all(b"solid spsr\n")?;
    let mut enc = Encoder::new(out);
    for t in &mesh.triangles {
        let p = corners(mesh, t);
        let n = facet_normal(&p);
        writeln!(
            enc.buf,
            "  facet normal {:e} {:e} {:e}\n    outer loop",
            n[0], n[1], n[2]
        )?;
        for v in &p {
            writeln!(
                enc.buf,
                "      vertex {:e} {:e} {:e}",
                v[0] as f32, v[1] as f32, v[2] as f32
            )?;
        }
        enc.buf.extend_from_slice(b"    endloop\n  endfacet\n");
        enc.maybe_flush()?;
    }
    enc.buf.extend_from_slice(b"endsolid spsr\n");
    enc.finish()
}

/// Binary STL: the header, then 50 bytes per triangle.
const HEADER_BYTES: u64 = 84;
const TRIANGLE_BYTES: u64 = 50;

/// Corners merged into indexed vertices by exact position.
#[derive(Default)]
struct Merger {
    index: FxHashMap<[u64; 3], u32>,
    mesh: Mesh,
}

impl Merger {
    fn vertex(&mut self, p: [f64; 3]) -> Option<u32> {
        // `+ 0.0` turns -0 into +0, so the two zeros merge.
        let key = p.map(|c| (c + 0.0).to_bits());
        let next = u32::try_from(self.mesh.vertices.len()).ok()?;
        Some(*self.index.entry(key).or_insert_with(|| {
            self.mesh.vertices.push(p);
            next
        }))
    }

    fn polygon(&mut self, path: &Path, corners: &[[f64; 3]]) -> Result<()> {
        let mut ids = Vec::with_capacity(corners.len());
        for &p in corners {
            let id = self
                .vertex(p)
                .ok_or_else(|| parse_err(path, "more than 4294967295 vertices".into()))?;
            ids.push(id);
        }
        for k in 1..ids.len().saturating_sub(1) {
            self.mesh.triangles.push([ids[0], ids[k], ids[k + 1]]);
        }
        Ok(())
    }
}

/// True when the file starts with `solid` (any case), as ASCII STL does.
pub(crate) fn starts_solid(head: &[u8]) -> bool {
    head.get(..5)
        .is_some_and(|w| w.eq_ignore_ascii_case(b"solid"))
}

pub(crate) fn read_stl<R: BufRead>(path: &Path, mut reader: R, len: u64) -> Result<Mesh> {
    let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
    let declared = (head.len() >= HEADER_BYTES as usize)
        .then(|| u64::from(u32::from_le_bytes([head[80], head[81], head[82], head[83]])));
    let binary_size = declared.map(|n| HEADER_BYTES + TRIANGLE_BYTES * n);
    if binary_size != Some(len) && starts_solid(head) {
        return read_ascii(path, reader);
    }
    let Some(count) = declared else {
        return Err(parse_err(
            path,
            format!(
                "not an STL file: {len} bytes is too short for binary STL (an 84-byte header), \
                 and it does not start with 'solid' as ASCII STL does"
            ),
        ));
    };
    if binary_size.is_some_and(|size| size > len) {
        return Err(parse_err(
            path,
            format!(
                "the file is truncated: its header declares {count} triangles ({} bytes), but \
                 the file has {len} bytes",
                binary_size.unwrap_or_default()
            ),
        ));
    }
    read_binary(path, reader, count)
}

fn read_binary<R: BufRead>(path: &Path, mut reader: R, count: u64) -> Result<Mesh> {
    let mut header = [0u8; HEADER_BYTES as usize];
    reader
        .read_exact(&mut header)
        .map_err(|e| io_err(path, e))?;
    let mut m = Merger::default();
    // The size was checked against the count, so the count is bounded by the file.
    m.mesh.triangles.reserve(count as usize);
    let mut rec = [0u8; TRIANGLE_BYTES as usize];
    for t in 0..count {
        reader.read_exact(&mut rec).map_err(|e| {
            parse_err(
                path,
                format!("cannot read triangle {t} (0-based) of {count}: {e}"),
            )
        })?;
        let f = |k: usize| {
            f64::from(f32::from_le_bytes([
                rec[k],
                rec[k + 1],
                rec[k + 2],
                rec[k + 3],
            ]))
        };
        let corners: [[f64; 3]; 3] =
            std::array::from_fn(|c| std::array::from_fn(|a| f(12 + 12 * c + 4 * a)));
        m.polygon(path, &corners)?;
    }
    Ok(m.mesh)
}

fn read_ascii<R: BufRead>(path: &Path, reader: R) -> Result<Mesh> {
    let mut lines = Lines::new(reader, path);
    let mut m = Merger::default();
    let mut corners: Vec<[f64; 3]> = Vec::new();
    let mut in_loop = false;
    while lines.advance_to_data(None)? {
        let mut words = lines.text().split_whitespace();
        match words
            .next()
            .unwrap_or_default()
            .to_ascii_lowercase()
            .as_str()
        {
            "solid" | "endsolid" | "facet" | "endfacet" => {}
            "outer" => {
                corners.clear();
                in_loop = true;
            }
            "vertex" if in_loop => {
                let mut p = [0.0; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    let w = words.next().ok_or_else(|| {
                        lines.error(format!("'vertex' has {k} coordinates, expected 3"))
                    })?;
                    *c = lines.number_in(w, "a number")?;
                }
                corners.push(p);
            }
            "endloop" if in_loop => {
                if corners.len() < 3 {
                    return Err(lines.error(format!(
                        "a facet's loop has {} vertices, expected 3",
                        corners.len()
                    )));
                }
                m.polygon(path, &corners)?;
                in_loop = false;
            }
            word => {
                let word: String = word.chars().take(40).collect();
                return Err(lines.error(format!(
                    "unexpected '{word}'; ASCII STL has solid, facet normal, outer loop, \
                     vertex x y z, endloop, endfacet and endsolid"
                )));
            }
        }
    }
    if in_loop {
        return Err(lines.error("the file ends inside a facet's loop"));
    }
    Ok(m.mesh)
}
