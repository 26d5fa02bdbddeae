//! Reading point clouds and meshes, writing meshes (atomically).
//!
//! * Points: PLY (`ascii`, `binary_little_endian`, `binary_big_endian`; any property order,
//!   extra properties and elements skipped) or text with `x y z nx ny nz` per line.
//! * Meshes: read from PLY (`vertex` + `face` lists, polygons fan-triangulated); written as
//!   PLY (binary little endian or ASCII) or Wavefront OBJ.
//!
//! Readers stream the file through a buffered reader; nothing is loaded whole. They do not
//! filter invalid points (non-finite values, zero normals): that is the caller's job
//! ([`crate::points::is_valid`]).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use crate::error::Error;
use crate::mesh::Mesh;
use crate::points::PointCloud;
use crate::Result;

mod ply;
mod text;
mod write;

use ply::{Kind, PlyReader};

/// Read buffer size: large, so binary bodies are decoded from big contiguous chunks.
const READ_BUFFER: usize = 1 << 20;

/// How to write a mesh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// ASCII PLY instead of binary little-endian PLY (ignored for OBJ).
    pub ascii: bool,
}

fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn parse_err(path: &Path, message: String) -> Error {
    Error::Parse {
        path: path.to_path_buf(),
        message,
    }
}

/// Opens `path` for reading; directories are refused with [`Error::Io`].
fn open(path: &Path) -> Result<(BufReader<File>, u64)> {
    let file = File::open(path).map_err(|e| io_err(path, e))?;
    let meta = file.metadata().map_err(|e| io_err(path, e))?;
    if meta.is_dir() {
        return Err(io_err(
            path,
            std::io::Error::other("is a directory, not a file"),
        ));
    }
    Ok((BufReader::with_capacity(READ_BUFFER, file), meta.len()))
}

fn has_ply_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
}

/// Index of the scalar property `name` of element `el`, with an error if it is a list.
fn scalar_prop(path: &Path, el: &ply::Element, name: &str) -> Result<Option<usize>> {
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

fn read_ply_points<R: BufRead>(path: &Path, reader: R, len: u64) -> Result<PointCloud> {
    let mut ply = PlyReader::new(reader, path, len)?;
    let (vi, xyz) = vertex_xyz(path, &ply)?;
    let el = &ply.header.elements[vi];
    let n: Vec<Option<usize>> = ["nx", "ny", "nz"]
        .iter()
        .map(|name| scalar_prop(path, el, name))
        .collect::<Result<_>>()?;
    let nxyz = match n[..] {
        [Some(a), Some(b), Some(c)] => [a, b, c],
        [None, None, None] => {
            return Err(Error::MissingNormals {
                path: path.to_path_buf(),
            })
        }
        _ => {
            return Err(parse_err(
                path,
                format!(
                    "header line {}: element 'vertex' has only some of the normal properties nx, ny, nz",
                    el.line
                ),
            ))
        }
    };
    let cap = ply.capacity_hint(vi);
    let mut positions = Vec::with_capacity(cap);
    let mut normals = Vec::with_capacity(cap);
    let wanted = [xyz[0], xyz[1], xyz[2], nxyz[0], nxyz[1], nxyz[2]];
    for i in 0..=vi {
        if i < vi {
            ply.read_element(i, &[], None, |_, _, _| Ok(()))?;
        } else {
            ply.read_element(i, &wanted, None, |_, v, _| {
                positions.push([v[0], v[1], v[2]]);
                normals.push([v[3], v[4], v[5]]);
                Ok(())
            })?;
        }
    }
    Ok(PointCloud { positions, normals })
}

/// Reads an oriented point cloud: PLY (any encoding) or text with `x y z nx ny nz` per line.
///
/// The file is PLY when its extension is `.ply` (any case) or it starts with `ply` and a line
/// break; anything else is read as text (whitespace and/or commas between values, blank lines
/// and `#` lines ignored, columns after the sixth ignored). In PLY, the `vertex` element must
/// have `x y z` and `nx ny nz` (any scalar type, any order); other properties and elements are
/// skipped. Values are converted to `f64`; invalid points (NaN, zero normals) are kept.
///
/// # Errors
/// [`Error::Io`] if the file cannot be opened or read (or is a directory),
/// [`Error::MissingNormals`] if the points have positions but no normals, and
/// [`Error::Parse`] for anything malformed, naming the line (text, ASCII PLY, header) or the
/// record and byte offset (binary PLY).
pub fn read_points(path: &Path) -> Result<PointCloud> {
    let (mut reader, len) = open(path)?;
    let is_ply = has_ply_extension(path) || {
        let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
        head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n")
    };
    if is_ply {
        read_ply_points(path, reader, len)
    } else {
        text::read_text_points(reader, path)
    }
}

/// Reads a triangle mesh from PLY (faces as lists; polygons fan-triangulated).
///
/// Needs a `vertex` element with `x y z` and a `face` element with a list property named
/// `vertex_indices` or `vertex_index` (any integer types). Faces with fewer than three
/// indices are skipped. A vertex property `density` (or else `value`) fills
/// [`Mesh::density`].
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::Parse`] if it is malformed or a face
/// refers to a vertex that does not exist (the message names the face).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let (reader, len) = open(path)?;
    let mut ply = PlyReader::new(reader, path, len)?;
    let (vi, xyz) = vertex_xyz(path, &ply)?;
    let vel = &ply.header.elements[vi];
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
    let mut vertices = Vec::with_capacity(ply.capacity_hint(vi));
    let mut density: Option<Vec<f32>> = dens.map(|_| Vec::with_capacity(ply.capacity_hint(vi)));
    let mut triangles = Vec::with_capacity(ply.capacity_hint(fi));
    let vwanted: Vec<usize> = xyz.iter().copied().chain(dens).collect();
    let mut idx: Vec<u32> = Vec::new();
    for i in 0..=vi.max(fi) {
        if i == vi {
            ply.read_element(i, &vwanted, None, |_, v, _| {
                vertices.push([v[0], v[1], v[2]]);
                if let Some(d) = density.as_mut() {
                    d.push(v[3] as f32);
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
    })
}

/// Writes a mesh: OBJ when the name ends in `.obj`, PLY otherwise. The file appears only when
/// complete (temporary file in the same folder, then rename).
///
/// PLY is binary little endian unless `opts.ascii`; it has `float x y z` (plus
/// `float density` when [`Mesh::density`] is set) and faces as `list uchar int
/// vertex_indices`. OBJ has `v x y z` and 1-based `f a b c` lines (no density). Coordinates
/// are written as `f32` in every format: `f64` input coordinates are rounded to the nearest
/// `f32`.
///
/// On any error no file at `path` is created or changed, and the temporary file is removed.
/// The file is not `fsync`ed.
///
/// # Errors
/// [`Error::Output`] if the directory is missing or not writable, the path is a directory,
/// or the mesh is inconsistent (an index out of range, a density array of the wrong length,
/// more than `i32::MAX` vertices or triangles); [`Error::Io`] if a write fails.
pub fn write_mesh(path: &Path, mesh: &Mesh, opts: &WriteOptions) -> Result<()> {
    write::write_mesh(path, mesh, opts)
}

/// Checks, before any long computation, that `output` can be written and is not `input`.
///
/// Fails with [`Error::Output`] if `output` is the same file as `input` (whatever the
/// spelling: `./a.ply`, `a.ply`, symbolic or hard links), is an existing directory, lies in
/// a directory that does not exist, or lies in a directory where no file can be created
/// (tested by creating and removing a temporary file there). A bare file name means the
/// current directory.
pub fn check_output_path(output: &Path, input: &Path) -> Result<()> {
    write::check_output_path(output, input)
}
