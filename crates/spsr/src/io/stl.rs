//! STL writing, binary (the default) or ASCII. STL has no shared vertices, no vertex
//! normals, colours or other attributes: each triangle is written with its three corners
//! and its geometric unit normal (zero for a degenerate triangle), all in `f32`.

use std::io::Write;

use crate::mesh::Mesh;

use super::write::Encoder;

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
