//! Point clouds and meshes from PLY files, on top of the streaming decoder of `ply.rs`.

use std::io::BufRead;
use std::path::Path;

use crate::attributes::{Attribute, AttributeData, ScalarType};
use crate::error::Error;
use crate::mesh::Mesh;
use crate::points::{PointCloud, ScanOrigin};
use crate::Result;

use super::parse_err;
use super::ply::{Element, Kind, PlyReader, Scalar};

/// Comment prefix under which [`super::write_cloud`] records scan origins in PLY headers.
pub(crate) const SCAN_ORIGIN_COMMENT: &str = "spsr scan_origin";

fn scalar_type(s: Scalar) -> ScalarType {
    match s {
        Scalar::I8 => ScalarType::I8,
        Scalar::U8 => ScalarType::U8,
        Scalar::I16 => ScalarType::I16,
        Scalar::U16 => ScalarType::U16,
        Scalar::I32 => ScalarType::I32,
        Scalar::U32 => ScalarType::U32,
        Scalar::F32 => ScalarType::F32,
        Scalar::F64 => ScalarType::F64,
    }
}

/// Index of the scalar property `name` of element `el`, with an error if it is a list.
fn scalar_prop(path: &Path, el: &Element, name: &str) -> Result<Option<usize>> {
    match el.find(name) {
        Some(p) if matches!(el.props[p].kind, Kind::List { .. }) => Err(parse_err(
            path,
            format!(
                "header line {}: property '{name}' of element '{}' is a list, expected a number",
                el.line, el.name
            ),
        )),
        other => Ok(other),
    }
}

/// Index of the `vertex` element and of its `x`, `y`, `z` properties.
fn vertex_xyz<R: BufRead>(path: &Path, ply: &PlyReader<R>) -> Result<(usize, [usize; 3])> {
    let Some(vi) = ply.header.find("vertex") else {
        return Err(parse_err(path, "the header has no 'vertex' element".into()));
    };
    let el = &ply.header.elements[vi];
    let mut xyz = [0; 3];
    for (k, name) in ["x", "y", "z"].into_iter().enumerate() {
        xyz[k] = scalar_prop(path, el, name)?.ok_or_else(|| {
            parse_err(
                path,
                format!(
                    "header line {}: element 'vertex' has no property '{name}'",
                    el.line
                ),
            )
        })?;
    }
    Ok((vi, xyz))
}

/// The `nx ny nz` properties of the vertex element: all three, or none.
fn vertex_normals(path: &Path, el: &Element) -> Result<Option<[usize; 3]>> {
    let n: Vec<Option<usize>> = ["nx", "ny", "nz"]
        .iter()
        .map(|name| scalar_prop(path, el, name))
        .collect::<Result<_>>()?;
    match n[..] {
        [Some(a), Some(b), Some(c)] => Ok(Some([a, b, c])),
        [None, None, None] => Ok(None),
        _ => Err(parse_err(
            path,
            format!(
                "header line {}: element 'vertex' has only some of the normal properties nx, ny, nz",
                el.line
            ),
        )),
    }
}

/// The scalar vertex properties other than `skip` (and other than earlier properties of
/// the same name), as (property index, empty attribute of the property's type).
fn extra_scalars(el: &Element, skip: &[usize], cap: usize) -> Vec<(usize, Attribute)> {
    let mut out: Vec<(usize, Attribute)> = Vec::new();
    for (p, prop) in el.props.iter().enumerate() {
        let Kind::Scalar(t) = prop.kind else { continue };
        if skip.contains(&p) || el.props[..p].iter().any(|q| q.name == prop.name) {
            continue;
        }
        out.push((
            p,
            Attribute::new(
                prop.name.clone(),
                AttributeData::with_capacity(scalar_type(t), cap),
            ),
        ));
    }
    out
}

/// Scan origins recorded as `comment spsr scan_origin <first point> <x> <y> <z>`.
fn scan_origins<R: BufRead>(ply: &PlyReader<R>) -> Vec<ScanOrigin> {
    let mut out: Vec<ScanOrigin> = ply
        .header
        .comments
        .iter()
        .filter_map(|c| {
            let rest = c.trim().strip_prefix(SCAN_ORIGIN_COMMENT)?;
            let v: Vec<&str> = rest.split_whitespace().collect();
            if v.len() != 4 {
                return None;
            }
            Some(ScanOrigin {
                first_point: v[0].parse().ok()?,
                origin: [v[1].parse().ok()?, v[2].parse().ok()?, v[3].parse().ok()?],
            })
        })
        .collect();
    out.sort_by_key(|s| s.first_point);
    out
}

pub(crate) fn read_cloud<R: BufRead>(
    path: &Path,
    reader: R,
    len: u64,
    need_normals: bool,
) -> Result<PointCloud> {
    super::whole_cloud(|emit| read_cloud_chunks(path, reader, len, need_normals, usize::MAX, emit))
}

/// Reads the points in clouds of at most `chunk` points (the last one shorter, none for an
/// empty file), handed to `emit` in file order; each chunk's scan origins count its points
/// from its own first.
pub(crate) fn read_cloud_chunks<R: BufRead>(
    path: &Path,
    reader: R,
    len: u64,
    need_normals: bool,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    let mut ply = PlyReader::new(reader, path, len)?;
    let (vi, xyz) = vertex_xyz(path, &ply)?;
    let el = &ply.header.elements[vi];
    let nxyz = vertex_normals(path, el)?;
    if need_normals && nxyz.is_none() {
        return Err(Error::MissingNormals {
            path: path.to_path_buf(),
        });
    }
    let cap = ply.capacity_hint(vi).min(chunk);
    let mut skip = xyz.to_vec();
    skip.extend(nxyz.iter().flatten());
    let extras = extra_scalars(el, &skip, 0);
    let mut wanted = skip.clone();
    wanted.extend(extras.iter().map(|(p, _)| *p));
    let columns: Vec<(String, ScalarType)> = extras
        .iter()
        .map(|(_, a)| (a.name.clone(), a.data.scalar_type()))
        .collect();
    let mut out = Chunk::new(cap, nxyz.is_some(), &columns);
    let nn = if nxyz.is_some() { 6 } else { 3 };
    let origins = scan_origins(&ply);
    let mut first = 0usize;
    for i in 0..=vi {
        if i < vi {
            ply.read_element(i, &[], None, |_, _, _| Ok(()))?;
        } else {
            ply.read_element(i, &wanted, None, |_, v, _| {
                out.positions.push([v[0], v[1], v[2]]);
                if nn == 6 {
                    out.normals.push([v[3], v[4], v[5]]);
                }
                for (a, &x) in out.attributes.iter_mut().zip(&v[nn..]) {
                    a.data.push_f64(x);
                }
                if out.positions.len() == chunk {
                    let full = std::mem::replace(&mut out, Chunk::new(cap, nn == 6, &columns));
                    let n = full.positions.len();
                    emit(full.into_cloud(&origins, first, false))?;
                    first += n;
                }
                Ok(())
            })?;
        }
    }
    if !out.positions.is_empty() || first == 0 {
        emit(out.into_cloud(&origins, first, first == 0))?;
    }
    Ok(())
}

/// The points of one chunk, as they are read.
struct Chunk {
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    attributes: Vec<Attribute>,
}

impl Chunk {
    fn new(cap: usize, normals: bool, columns: &[(String, ScalarType)]) -> Chunk {
        Chunk {
            positions: Vec::with_capacity(cap),
            normals: Vec::with_capacity(if normals { cap } else { 0 }),
            attributes: columns
                .iter()
                .map(|(name, ty)| {
                    Attribute::new(name.clone(), AttributeData::with_capacity(*ty, cap))
                })
                .collect(),
        }
    }

    /// The chunk as a cloud whose first point is the file's point `first`; the scan origin in
    /// force there starts it. The `whole` file keeps its origins as they are.
    fn into_cloud(self, origins: &[ScanOrigin], first: usize, whole: bool) -> PointCloud {
        if whole {
            return PointCloud {
                positions: self.positions,
                normals: self.normals,
                attributes: self.attributes,
                scan_origins: origins.to_vec(),
            };
        }
        let end = first + self.positions.len();
        let in_force = origins.iter().rposition(|o| o.first_point <= first);
        let scan_origins = origins
            .iter()
            .enumerate()
            .filter(|&(k, o)| Some(k) == in_force || (o.first_point > first && o.first_point < end))
            .map(|(_, o)| ScanOrigin {
                first_point: o.first_point.saturating_sub(first),
                origin: o.origin,
            })
            .collect();
        PointCloud {
            positions: self.positions,
            normals: self.normals,
            attributes: self.attributes,
            scan_origins,
        }
    }
}

pub(crate) fn read_mesh<R: BufRead>(path: &Path, reader: R, len: u64) -> Result<Mesh> {
    let mut ply = PlyReader::new(reader, path, len)?;
    let (vi, xyz) = vertex_xyz(path, &ply)?;
    let vel = &ply.header.elements[vi];
    let nxyz = vertex_normals(path, vel)?;
    let dens = match scalar_prop(path, vel, "density")? {
        Some(p) => Some(p),
        None => scalar_prop(path, vel, "value")?,
    };
    let nverts = vel.count;
    let Some(fi) = ply.header.find("face") else {
        return Err(parse_err(path, "the header has no 'face' element".into()));
    };
    let fel = &ply.header.elements[fi];
    let Some(li) = fel
        .find("vertex_indices")
        .or_else(|| fel.find("vertex_index"))
    else {
        return Err(parse_err(
            path,
            format!(
                "header line {}: element 'face' has no list property 'vertex_indices' or 'vertex_index'",
                fel.line
            ),
        ));
    };
    if !matches!(fel.props[li].kind, Kind::List { .. }) {
        return Err(parse_err(
            path,
            format!(
                "header line {}: property '{}' of element 'face' is not a list",
                fel.line, fel.props[li].name
            ),
        ));
    }
    let vcap = ply.capacity_hint(vi);
    let mut skip = xyz.to_vec();
    skip.extend(nxyz.iter().flatten());
    skip.extend(dens);
    let mut extras = extra_scalars(vel, &skip, vcap);
    let mut vwanted = skip.clone();
    vwanted.extend(extras.iter().map(|(p, _)| *p));
    let has_n = nxyz.is_some();
    let dslot = if has_n { 6 } else { 3 };
    let first_extra = dslot + usize::from(dens.is_some());
    let mut vertices = Vec::with_capacity(vcap);
    let mut normals: Option<Vec<[f32; 3]>> = nxyz.map(|_| Vec::with_capacity(vcap));
    let mut density: Option<Vec<f32>> = dens.map(|_| Vec::with_capacity(vcap));
    let mut triangles = Vec::with_capacity(ply.capacity_hint(fi));
    let mut idx: Vec<u32> = Vec::new();
    for i in 0..=vi.max(fi) {
        if i == vi {
            ply.read_element(i, &vwanted, None, |_, v, _| {
                vertices.push([v[0], v[1], v[2]]);
                if let Some(n) = normals.as_mut() {
                    n.push([v[3] as f32, v[4] as f32, v[5] as f32]);
                }
                if let Some(d) = density.as_mut() {
                    d.push(v[dslot] as f32);
                }
                for ((_, a), &x) in extras.iter_mut().zip(&v[first_extra..]) {
                    a.data.push_f64(x);
                }
                Ok(())
            })?;
        } else if i == fi {
            ply.read_element(i, &[], Some(li), |r, _, items| {
                idx.clear();
                for &x in items {
                    if !(x >= 0.0 && x.fract() == 0.0 && x < nverts as f64) {
                        return Err(parse_err(
                            path,
                            format!(
                                "face {r} (0-based) refers to vertex {x}, but there are {nverts} vertices (valid indices 0 to {})",
                                nverts as i128 - 1
                            ),
                        ));
                    }
                    idx.push(x as u32);
                }
                for k in 1..idx.len().saturating_sub(1) {
                    triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
                Ok(())
            })?;
        } else {
            ply.read_element(i, &[], None, |_, _, _| Ok(()))?;
        }
    }
    Ok(Mesh {
        vertices,
        triangles,
        density,
        normals,
        attributes: extras.into_iter().map(|(_, a)| a).collect(),
    })
}
