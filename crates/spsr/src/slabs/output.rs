//! The mesh of a slab run written as the slabs produce it, so that it never has to be in
//! memory whole: each slab's vertices and triangles go to files in the work folder as soon as
//! the slab is polygonised, and the binary PLY is put together from them at the end. The
//! vertices on the shared faces are numbered by the slab that owns them; a triangle of the
//! other slab finds them by edge key. The checks of the result are made on the way: pieces by
//! union–find over the vertices, closedness by counting each edge's triangles (within a slab,
//! and across slabs for the edges that lie in a shared face).

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use rustc_hash::FxHashMap;

use super::spill::io_err;
use super::AttributeSchema;
use crate::attributes::{Attribute, AttributeData};
use crate::extract::{Part, FOREIGN};
use crate::io::Extent;
use crate::pipeline::prepare::Frame;
use crate::{Error, Result};

/// Counts of a written mesh and what its checks found.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Written {
    /// Vertices written.
    pub vertices: u64,
    /// Triangles written.
    pub triangles: u64,
    /// Connected pieces (triangles sharing a vertex).
    pub pieces: usize,
    /// Edges with one triangle, or more than two.
    pub open_edges: u64,
}

/// The slabs' meshes, gathered in files.
pub(crate) struct MeshFiles {
    dir: PathBuf,
    vertices: BufWriter<File>,
    triangles: BufWriter<File>,
    normals: Option<bool>,
    /// Whether the vertices carry their density (the parts must agree).
    density: Option<bool>,
    /// The attributes each vertex carries (name and type), written after the normals.
    attributes: AttributeSchema,
    /// One vertex's record, reused.
    record: Vec<u8>,
    vertex_count: u64,
    triangle_count: u64,
    /// The vertices' extent, which decides between `float` and `double` coordinates as for
    /// a mesh written in one piece (`io::write::needs_f64`).
    extent: Extent,
    /// The vertices on the shared faces: edge key → global index.
    face_vertices: FxHashMap<u64, u32>,
    /// Triangle counts of the edges that lie in a shared face, by their ends' edge keys.
    face_edges: FxHashMap<(u64, u64), u32>,
    /// x of the shared faces, in finest cells.
    planes: Vec<u32>,
    open_edges: u64,
}

fn edge_start_x(key: u64) -> u32 {
    (key & ((1 << 20) - 1)) as u32
}

fn edge_axis(key: u64) -> u64 {
    (key >> 60) & 3
}

impl MeshFiles {
    /// `planes`: x of the faces between slabs, in cells of the finest depth; `attributes`:
    /// what every vertex carries (each part gives one value per attribute and vertex).
    pub fn new(dir: &Path, planes: Vec<u32>, attributes: AttributeSchema) -> Result<MeshFiles> {
        let open = |name: &str| -> Result<BufWriter<File>> {
            let path = dir.join(name);
            Ok(BufWriter::with_capacity(
                1 << 16,
                File::create(&path).map_err(|e| io_err(&path, e))?,
            ))
        };
        Ok(MeshFiles {
            dir: dir.to_path_buf(),
            vertices: open("mesh.vertices")?,
            triangles: open("mesh.triangles")?,
            normals: None,
            density: None,
            attributes,
            record: Vec::new(),
            vertex_count: 0,
            triangle_count: 0,
            extent: Extent::default(),
            face_vertices: FxHashMap::default(),
            face_edges: FxHashMap::default(),
            planes,
            open_edges: 0,
        })
    }

    fn on_face(&self, key: u64) -> bool {
        key != u64::MAX && edge_axis(key) != 0 && self.planes.contains(&edge_start_x(key))
    }

    /// Appends one slab's mesh (unit-cube coordinates, mapped to the input's frame here).
    pub fn add(&mut self, part: Part, frame: Frame) -> Result<()> {
        let base = self.vertex_count;
        let has_normals = part.normals.is_some();
        if *self.normals.get_or_insert(has_normals) != has_normals {
            return Err(Error::InvalidMesh(
                "the slabs disagree on vertex normals".into(),
            ));
        }
        let has_density = part.density.is_some();
        if *self.density.get_or_insert(has_density) != has_density {
            return Err(Error::InvalidMesh(
                "the slabs disagree on vertex density".into(),
            ));
        }
        if part
            .density
            .as_ref()
            .is_some_and(|d| d.len() != part.vertices.len())
        {
            return Err(Error::InvalidMesh(
                "a slab's mesh has a density for some of its vertices only".into(),
            ));
        }
        let k = self.attributes.len();
        let values = part.attributes.as_deref().unwrap_or(&[]);
        if values.len() != part.vertices.len() * k {
            return Err(Error::InvalidMesh(
                "a slab's mesh does not give every vertex its attributes".into(),
            ));
        }
        let vpath = self.dir.join("mesh.vertices");
        for (i, p) in part.vertices.iter().enumerate() {
            let w = frame.to_world(*p);
            self.extent.add(w);
            let rec = &mut self.record;
            rec.clear();
            for c in w {
                rec.extend_from_slice(&c.to_le_bytes());
            }
            if let Some(n) = &part.normals {
                for c in n[i] {
                    rec.extend_from_slice(&c.to_le_bytes());
                }
            }
            for ((_, ty), &v) in self.attributes.iter().zip(&values[i * k..(i + 1) * k]) {
                ty.put_le(v, rec);
            }
            if let Some(d) = &part.density {
                rec.extend_from_slice(&d[i].to_le_bytes());
            }
            self.vertices
                .write_all(rec)
                .map_err(|e| io_err(&vpath, e))?;
        }
        for (i, &k) in part.keys.iter().enumerate() {
            if self.on_face(k) {
                self.face_vertices.insert(k, (base + i as u64) as u32);
            }
        }
        // Edges within the slab must have two triangles; edges in a shared face are counted
        // across slabs.
        // A closed surface has 3/2 edges per triangle: reserved at once, the table is not
        // rebuilt as it grows (which holds the old and the new table together).
        let mut edges: FxHashMap<(u64, u64), u32> = FxHashMap::default();
        edges.reserve(part.triangles.len() * 3 / 2);
        let tpath = self.dir.join("mesh.triangles");
        for t in &part.triangles {
            // A corner as (global index or foreign marker, edge key or none).
            let key_of = |r: u64| -> u64 {
                if r & FOREIGN != 0 {
                    r & !FOREIGN
                } else {
                    part.keys[r as usize]
                }
            };
            for e in 0..3 {
                let (a, b) = (t[e], t[(e + 1) % 3]);
                let (ka, kb) = (key_of(a), key_of(b));
                if self.on_face(ka) && self.on_face(kb) {
                    *self.face_edges.entry((ka.min(kb), ka.max(kb))).or_insert(0) += 1;
                } else {
                    *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
                }
            }
            let mut rec = [0u8; 24];
            for (c, &r) in t.iter().enumerate() {
                let g = if r & FOREIGN != 0 { r } else { r + base };
                rec[c * 8..c * 8 + 8].copy_from_slice(&g.to_le_bytes());
            }
            self.triangles
                .write_all(&rec)
                .map_err(|e| io_err(&tpath, e))?;
        }
        self.open_edges += edges.values().filter(|&&n| n != 2).count() as u64;
        self.vertex_count += part.vertices.len() as u64;
        self.triangle_count += part.triangles.len() as u64;
        if self.vertex_count >= u64::from(u32::MAX) {
            return Err(Error::InvalidMesh(
                "too many vertices for 32-bit indices".into(),
            ));
        }
        Ok(())
    }

    /// Writes the binary PLY at `path` (through a temporary file beside it, renamed into
    /// place when complete) and removes the parts' files.
    pub fn finish(mut self, path: &Path) -> Result<Written> {
        let vpath = self.dir.join("mesh.vertices");
        let tpath = self.dir.join("mesh.triangles");
        for (w, p) in [(&mut self.vertices, &vpath), (&mut self.triangles, &tpath)] {
            w.flush().map_err(|e| io_err(p, e))?;
        }
        drop(self.vertices);
        drop(self.triangles);
        self.open_edges += self.face_edges.values().filter(|&&n| n != 2).count() as u64;
        let normals = self.normals.unwrap_or(false);
        let density = self.density.unwrap_or(false);
        let nv = self.vertex_count;
        let nt = self.triangle_count;
        let faces = &self.face_vertices;
        let mut parent: Vec<u32> = (0..nv as u32).collect();
        let fits_f32 = !self.extent.needs_f64();
        crate::io::write_with(path, |out| {
            let ty = if fits_f32 { "float" } else { "double" };
            let mut h = format!(
                "ply\nformat binary_little_endian 1.0\ncomment generated by spsr\nelement vertex {nv}\n\
                 property {ty} x\nproperty {ty} y\nproperty {ty} z\n"
            );
            if normals {
                h.push_str("property float nx\nproperty float ny\nproperty float nz\n");
            }
            // The columns of a mesh written in one piece, in its order (`io::write_ply`).
            for (name, t) in &self.attributes {
                h.push_str(&format!("property {} {name}\n", t.ply_name()));
            }
            if density {
                h.push_str("property float density\n");
            }
            h.push_str(&format!(
                "element face {nt}\nproperty list uchar int vertex_indices\nend_header\n"
            ));
            out.write_all(h.as_bytes())?;
            let mut r = BufReader::with_capacity(1 << 16, File::open(&vpath)?);
            let len = vertex_record(normals, density, &self.attributes);
            let mut rec = vec![0u8; len];
            for _ in 0..nv {
                r.read_exact(&mut rec[..len])?;
                for a in 0..3 {
                    let c = f64::from_le_bytes(rec[a * 8..a * 8 + 8].try_into().expect("8"));
                    if fits_f32 {
                        out.write_all(&(c as f32).to_le_bytes())?;
                    } else {
                        out.write_all(&c.to_le_bytes())?;
                    }
                }
                // Normals, attributes and density, as they were written.
                out.write_all(&rec[24..len])?;
            }
            let mut r = BufReader::with_capacity(1 << 16, File::open(&tpath)?);
            let mut rec = [0u8; 24];
            for _ in 0..nt {
                r.read_exact(&mut rec)?;
                let mut t = [0u32; 3];
                for (c, ti) in t.iter_mut().enumerate() {
                    let g = u64::from_le_bytes(rec[c * 8..c * 8 + 8].try_into().expect("8"));
                    *ti = if g & FOREIGN != 0 {
                        *faces.get(&(g & !FOREIGN)).ok_or_else(|| {
                            std::io::Error::other(
                                "a triangle refers to a vertex no slab owns (a crack between slabs)",
                            )
                        })?
                    } else {
                        g as u32
                    };
                }
                union(&mut parent, t[0], t[1]);
                union(&mut parent, t[1], t[2]);
                out.write_all(&[3])?;
                for i in t {
                    out.write_all(&(i as i32).to_le_bytes())?;
                }
            }
            Ok(())
        })?;
        let _ = std::fs::remove_file(&vpath);
        let _ = std::fs::remove_file(&tpath);
        // Pieces: the roots of vertices that some triangle uses.
        let mut used = vec![false; nv as usize];
        let pieces = {
            // A vertex is in a piece when it is its own root and some triangle reached it;
            // isolated vertices (no triangle) are their own roots too, so count roots of
            // vertices that were united with something or that a triangle names.
            let mut roots = 0usize;
            for v in 0..nv as u32 {
                let r = find(&mut parent, v);
                if r != v {
                    used[r as usize] = true;
                }
            }
            for v in 0..nv as usize {
                if used[v] && parent[v] == v as u32 {
                    roots += 1;
                }
            }
            roots
        };
        Ok(Written {
            vertices: nv,
            triangles: nt,
            pieces,
            open_edges: self.open_edges,
        })
    }
}

/// The slabs' parts (in slab order) numbered as one mesh in memory, in the input's frame:
/// the vertices and triangles [`MeshFiles`] writes, in the same order (and so the mesh
/// [`crate::extract::Blocks::assemble`] gives for the slabs' blocks), with `attributes`.
pub(crate) fn assemble(
    parts: Vec<Part>,
    frame: Frame,
    attributes: &AttributeSchema,
) -> Result<crate::Mesh> {
    let nv: usize = parts.iter().map(|p| p.vertices.len()).sum();
    if nv >= u32::MAX as usize {
        return Err(Error::InvalidMesh(
            "too many vertices for 32-bit indices".into(),
        ));
    }
    let mut owners: FxHashMap<u64, u32> = FxHashMap::default();
    let mut base = 0u64;
    for p in &parts {
        for (i, &k) in p.keys.iter().enumerate() {
            if k != u64::MAX {
                owners.insert(k, (base + i as u64) as u32);
            }
        }
        base += p.vertices.len() as u64;
    }
    let with_normals = parts.first().is_some_and(|p| p.normals.is_some());
    let with_density = parts.first().is_some_and(|p| p.density.is_some());
    let k = attributes.len();
    let values_fit = |p: &Part| p.attributes.as_ref().map_or(0, Vec::len) == p.vertices.len() * k;
    if parts.iter().any(|p| {
        p.normals.is_some() != with_normals || p.density.is_some() != with_density || !values_fit(p)
    }) {
        return Err(Error::InvalidMesh(
            "the slabs disagree on vertex normals, density or attributes".into(),
        ));
    }
    let mut mesh = crate::Mesh {
        vertices: Vec::with_capacity(nv),
        normals: with_normals.then(|| Vec::with_capacity(nv)),
        density: with_density.then(|| Vec::with_capacity(nv)),
        ..crate::Mesh::default()
    };
    let mut values = Vec::with_capacity(nv * k);
    let mut base = 0u64;
    for p in parts {
        for t in &p.triangles {
            let mut tri = [0u32; 3];
            for (c, &r) in t.iter().enumerate() {
                tri[c] = if r & FOREIGN != 0 {
                    *owners.get(&(r & !FOREIGN)).ok_or_else(|| {
                        Error::InvalidMesh(
                            "a triangle refers to a vertex no slab owns (a crack between slabs)"
                                .into(),
                        )
                    })?
                } else {
                    (base + r) as u32
                };
            }
            mesh.triangles.push(tri);
        }
        base += p.vertices.len() as u64;
        mesh.vertices
            .extend(p.vertices.iter().map(|&v| frame.to_world(v)));
        if let (Some(all), Some(n)) = (&mut mesh.normals, p.normals) {
            all.extend(n);
        }
        if let (Some(all), Some(d)) = (&mut mesh.density, p.density) {
            all.extend(d);
        }
        values.extend(p.attributes.into_iter().flatten());
    }
    mesh.attributes = attribute_columns(attributes, &values);
    Ok(mesh)
}

/// Bytes of a vertex in the work file: x y z (f64), then nx ny nz (f32), the attributes (each
/// in its type) and density (f32) when present.
fn vertex_record(normals: bool, density: bool, attributes: &AttributeSchema) -> usize {
    let attributes: usize = attributes.iter().map(|(_, t)| t.size()).sum();
    24 + if normals { 12 } else { 0 } + attributes + if density { 4 } else { 0 }
}

/// The mesh's attribute columns from its vertices' values (one per attribute and vertex,
/// vertex after vertex), each converted to its type as in one piece.
pub(crate) fn attribute_columns(types: &AttributeSchema, values: &[f64]) -> Vec<Attribute> {
    let k = types.len();
    types
        .iter()
        .enumerate()
        .map(|(c, (name, ty))| {
            Attribute::new(
                name.clone(),
                AttributeData::from_f64(*ty, values.iter().skip(c).step_by(k).copied()),
            )
        })
        .collect()
}

fn find(parent: &mut [u32], mut v: u32) -> u32 {
    while parent[v as usize] != v {
        let p = parent[v as usize];
        parent[v as usize] = parent[p as usize];
        v = p;
    }
    v
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // The smaller index becomes the root, so the result does not depend on the order.
        let (lo, hi) = (ra.min(rb), ra.max(rb));
        parent[hi as usize] = lo;
    }
}
