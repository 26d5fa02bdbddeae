//! Reading point clouds and meshes, writing meshes and point clouds (atomically).
//!
//! **Point clouds in** ([`read_cloud`], [`read_points`]), chosen by the file's first bytes,
//! then by its extension ([`CloudFormat::detect`]):
//!
//! * PLY (`ascii`, `binary_little_endian`, `binary_big_endian`; any property order): the
//!   `vertex` element's `x y z`, `nx ny nz` when present, and every other scalar property
//!   as an attribute of its own type (list properties and other elements skipped).
//! * Text (any other extension, e.g. `.xyz`, `.txt`, `.csv`): `x y z [nx ny nz [r g b]]` per
//!   line (see the layout rules below).
//! * LAS and LAZ (`.las`, `.laz`): lidar points with their standard fields as attributes,
//!   normals from extra bytes when present.
//! * E57 (`.e57`): every scan, moved by its pose into one frame; colours, intensity and
//!   other fields as attributes; normals from the E57 surface-normals extension.
//! * PCD (`.pcd`): `ascii`, `binary` and `binary_compressed` bodies.
//!
//! **Meshes in** ([`read_mesh`]): PLY. **Meshes out** ([`write_mesh`], by extension,
//! [`MeshFormat::from_path`]): PLY (binary little endian, or ASCII), OBJ, STL (binary, or
//! ASCII), glTF binary (`.glb`). **Point clouds out** ([`write_cloud`]): PLY.
//!
//! Readers stream the file (through a buffered reader, or in chunks of points) and append
//! to the output columns; no file is loaded whole. Output columns are reserved from the point count in the header, bounded by
//! what the file's size can hold, so a bogus count cannot cause a huge allocation. Readers
//! keep invalid points (non-finite values, zero normals) so that the cloud matches the
//! file point for point; the reconstruction filters them ([`crate::points::is_valid`]).
//! Writers write to a temporary file in the destination folder and rename it when
//! complete.
//!
//! ## Text layout
//!
//! One point per line, values separated by whitespace and/or commas; blank lines and lines
//! starting with `#` are ignored. The first data line's number of values fixes the layout:
//! 3–5 values `x y z`, 6–8 values `x y z nx ny nz`, 9 or more `x y z nx ny nz r g b`. Extra
//! values are ignored on every line. Six values are always position and normal, never
//! position and colour. Colours that are all integers in 0–255 become `u8` attributes,
//! otherwise `f32` (taken to be in `[0, 1]`).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use crate::error::Error;
use crate::mesh::Mesh;
use crate::points::PointCloud;
use crate::Result;

mod e57_file;
mod glb;
mod las_file;
mod lzf;
mod obj;
mod pcd;
mod ply;
mod read_ply;
mod stl;
mod text;
mod unfinished;
mod write;
mod write_ply;

/// Read buffer size: large, so binary bodies are decoded from big contiguous chunks.
const READ_BUFFER: usize = 1 << 20;

/// How to write a mesh or point cloud.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// ASCII PLY instead of binary little-endian PLY, ASCII STL instead of binary STL
    /// (ignored for OBJ and GLB).
    pub ascii: bool,
}

pub(crate) fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

pub(crate) fn parse_err(path: &Path, message: String) -> Error {
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

/// The point-cloud file formats [`read_cloud`] reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloudFormat {
    /// Stanford PLY, any encoding.
    Ply,
    /// Plain text, one point per line.
    Text,
    /// ASPRS LAS, or LAZ (compressed LAS).
    Las,
    /// ASTM E57.
    E57,
    /// Point Cloud Library PCD.
    Pcd,
}

impl CloudFormat {
    /// The format of a file from its first bytes (`ply`, `LASF`, `ASTM-E57`, `# .PCD` or
    /// `VERSION`), if they identify one.
    pub fn from_magic(head: &[u8]) -> Option<Self> {
        if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
            Some(CloudFormat::Ply)
        } else if head.starts_with(b"LASF") {
            Some(CloudFormat::Las)
        } else if head.starts_with(b"ASTM-E57") {
            Some(CloudFormat::E57)
        } else if head.starts_with(b"# .PCD") || head.starts_with(b"VERSION") {
            Some(CloudFormat::Pcd)
        } else {
            None
        }
    }

    /// The format named by a file's extension (any case): `.ply`, `.las`, `.laz`, `.e57`,
    /// `.pcd`; `None` for anything else.
    pub fn from_extension(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "ply" => CloudFormat::Ply,
            "las" | "laz" => CloudFormat::Las,
            "e57" => CloudFormat::E57,
            "pcd" => CloudFormat::Pcd,
            _ => return None,
        })
    }

    /// The format [`read_cloud`] uses for `path`: from its first bytes, else from its
    /// extension, else text.
    ///
    /// # Errors
    /// [`Error::Io`] if the file cannot be opened or read, or is a directory.
    pub fn detect(path: &Path) -> Result<Self> {
        let (mut reader, _) = open(path)?;
        let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
        Ok(Self::choose(path, head))
    }

    fn choose(path: &Path, head: &[u8]) -> Self {
        Self::from_magic(head)
            .or_else(|| Self::from_extension(path))
            .unwrap_or(CloudFormat::Text)
    }
}

/// The mesh file formats [`write_mesh`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Stanford PLY (binary little endian, or ASCII).
    Ply,
    /// Wavefront OBJ.
    Obj,
    /// STL (binary, or ASCII).
    Stl,
    /// glTF 2.0 binary.
    Glb,
}

impl MeshFormat {
    /// The format for an output path, by extension (any case): `.obj`, `.stl`, `.glb`, and
    /// PLY for `.ply` and for every other name (including none).
    pub fn from_path(path: &Path) -> Self {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("obj") => MeshFormat::Obj,
            Some("stl") => MeshFormat::Stl,
            Some("glb") => MeshFormat::Glb,
            _ => MeshFormat::Ply,
        }
    }
}

fn read_cloud_as(path: &Path, need_normals: bool) -> Result<PointCloud> {
    let (mut reader, len) = open(path)?;
    let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
    match CloudFormat::choose(path, head) {
        CloudFormat::Ply => read_ply::read_cloud(path, reader, len, need_normals),
        CloudFormat::Text => text::read_text_points(reader, path, need_normals),
        CloudFormat::Las => las_file::read_las(path, reader, len, need_normals),
        CloudFormat::E57 => e57_file::read_e57(path, reader, len, need_normals),
        CloudFormat::Pcd => pcd::read_pcd(path, reader, len, need_normals),
    }
}

/// Reads a point cloud in any supported format (see the [module documentation](self)),
/// with or without normals.
///
/// The format comes from the file's first bytes (`ply`, `LASF`, `ASTM-E57`, `# .PCD` or
/// `VERSION`), else from its extension (`.ply`, `.las`, `.laz`, `.e57`, `.pcd`, any case);
/// anything else is read as text. Normals are read when the file has them
/// ([`PointCloud::normals`] is empty otherwise); every other numeric per-point property
/// becomes an [`crate::attributes::Attribute`] in its own type, in file order. Invalid
/// points (NaN, zero normals) are kept.
///
/// # Errors
/// [`Error::Io`] if the file cannot be opened or read (or is a directory), and
/// [`Error::Parse`] for anything malformed, naming what is wrong and where (line, record,
/// byte offset, header field).
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    read_cloud_as(path, false)
}

/// Reads an oriented point cloud: [`read_cloud`], but a file without normals is an error
/// (reported from the header, before the points are read).
///
/// # Errors
/// As [`read_cloud`], and [`Error::MissingNormals`] if the points have positions but no
/// normals (an empty text file is an empty cloud, not an error).
pub fn read_points(path: &Path) -> Result<PointCloud> {
    read_cloud_as(path, true)
}

/// Reads a triangle mesh from PLY (faces as lists; polygons fan-triangulated).
///
/// Needs a `vertex` element with `x y z` and a `face` element with a list property named
/// `vertex_indices` or `vertex_index` (any integer types). Faces with fewer than three
/// indices are skipped. A vertex property `density` (or else `value`) fills
/// [`Mesh::density`], `nx ny nz` fill [`Mesh::normals`], and every other scalar vertex
/// property becomes an attribute.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::Parse`] if it is malformed or a face
/// refers to a vertex that does not exist (the message names the face).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let (reader, len) = open(path)?;
    read_ply::read_mesh(path, reader, len)
}

/// Writes a mesh in the format its extension names ([`MeshFormat::from_path`]): `.obj`
/// OBJ, `.stl` STL, `.glb` glTF binary, anything else (`.ply`, another extension, none)
/// PLY. The file appears only when complete (temporary file in the same folder, then
/// rename).
///
/// * **PLY**: binary little endian unless `opts.ascii`. Vertex properties `x y z`, then
///   `nx ny nz` (`float`) when [`Mesh::normals`] is set, then every attribute in its own
///   type, then `float density` when [`Mesh::density`] is set; faces as `list uchar int
///   vertex_indices`.
/// * **OBJ**: `v x y z` (followed by `r g b` in `[0, 1]` when the mesh has colour
///   attributes: the vertex-colour extension MeshLab and others read), `vn` lines when it
///   has normals, and 1-based faces (`f a//a b//b c//c` with normals). No density, no other
///   attributes.
/// * **STL**: binary unless `opts.ascii`; each triangle with its geometric unit normal.
///   Positions only (STL has no vertex attributes).
/// * **GLB**: glTF 2.0 binary with `POSITION`, `NORMAL`, `COLOR_0` (sRGB colours converted
///   to glTF's linear colours) and `_DENSITY` when present, and `u32` indices.
///
/// Coordinates are written as `f32`, except that PLY and OBJ write `f64` when the mesh lies
/// so far from the origin that `f32` would lose more than a millionth of its size (the
/// largest coordinate exceeds 16 times the bounding-box diagonal, as with georeferenced
/// lidar); GLB then stores positions relative to the bounding-box centre, which becomes the
/// node's translation; STL, which can only hold `f32`, loses that precision.
///
/// On any error no file at `path` is created or changed, and the temporary file is removed.
/// The file is not `fsync`ed.
///
/// # Errors
/// [`Error::Output`] if the directory is missing or not writable, the path is a directory,
/// or the mesh is inconsistent (an index out of range, a per-vertex array of the wrong
/// length, more than `i32::MAX` vertices or triangles, attribute names that PLY cannot
/// hold or that repeat, a GLB over 4 GiB); [`Error::Io`] if a write fails.
pub fn write_mesh(path: &Path, mesh: &Mesh, opts: &WriteOptions) -> Result<()> {
    write::write_mesh(path, mesh, opts)
}

/// Writes a point cloud as PLY (binary little endian unless `opts.ascii`), whatever the
/// extension: the same points in the same order, with `x y z`, `nx ny nz` when the cloud
/// has normals, then every attribute in its own type and order. Positions (and normals) are
/// `float` when every value is exactly representable in `f32`, `double` otherwise, so
/// nothing is lost. [`PointCloud::scan_origins`] are kept as header comments
/// `comment spsr scan_origin <first point> <x> <y> <z>`, which [`read_cloud`] reads back.
/// Written atomically, like [`write_mesh`].
///
/// # Errors
/// [`Error::Output`] if the path cannot be used, the normals or an attribute do not have
/// one value per point, or attribute names are not usable PLY property names (empty, with
/// spaces, repeated, or `x`, `y`, `z`, `nx`, `ny`, `nz`); [`Error::Io`] if a write fails.
pub fn write_cloud(path: &Path, cloud: &PointCloud, opts: &WriteOptions) -> Result<()> {
    write::write_cloud(path, cloud, opts)
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

/// Writes a mesh in `format` to a writer, such as standard output; `name` is what error
/// messages call the destination (e.g. `<stdout>`). Unlike [`write_mesh`] this cannot be
/// atomic: a failure part way leaves part of the mesh written.
///
/// # Errors
/// As [`write_mesh`].
pub fn write_mesh_to(
    out: &mut dyn std::io::Write,
    name: &Path,
    format: MeshFormat,
    mesh: &Mesh,
    opts: &WriteOptions,
) -> Result<()> {
    write::write_mesh_to(out, name, format, mesh, opts)
}

pub use unfinished::remove_unfinished_files;
pub(crate) use write::write_atomically;

/// Copies `input` into a temporary file (deleted afterwards, and by
/// [`remove_unfinished_files`]) and reads it with `read`; errors name `name` instead of the
/// temporary file. Standard input cannot seek, which LAS and E57 need, and the readers bound
/// their reservations by the file's size, so every format is read this way.
fn read_spooled<T>(
    mut input: impl std::io::Read,
    name: &Path,
    read: impl FnOnce(&Path) -> Result<T>,
) -> Result<T> {
    let tmp = tempfile::Builder::new()
        .prefix(".spsr-stdin-")
        .tempfile()
        .map_err(|e| io_err(name, e))?;
    let _unfinished = unfinished::Unfinished::register(tmp.path());
    {
        let mut w = std::io::BufWriter::with_capacity(READ_BUFFER, tmp.as_file());
        std::io::copy(&mut input, &mut w).map_err(|e| io_err(name, e))?;
        std::io::Write::flush(&mut w).map_err(|e| io_err(name, e))?;
    }
    read(tmp.path()).map_err(|e| e.with_path(tmp.path(), name))
}

/// [`read_points`] from a reader, such as standard input, in any format [`read_cloud`]
/// recognises by its first bytes (anything else is read as text); `name` is what error
/// messages call the source (e.g. `<stdin>`).
///
/// # Errors
/// As [`read_points`].
pub fn read_points_from(input: impl std::io::Read, name: &Path) -> Result<PointCloud> {
    read_spooled(input, name, read_points)
}

/// [`read_cloud`] from a reader; see [`read_points_from`].
///
/// # Errors
/// As [`read_cloud`].
pub fn read_cloud_from(input: impl std::io::Read, name: &Path) -> Result<PointCloud> {
    read_spooled(input, name, read_cloud)
}

/// [`read_mesh`] from a reader (PLY); see [`read_points_from`].
///
/// # Errors
/// As [`read_mesh`].
pub fn read_mesh_from(input: impl std::io::Read, name: &Path) -> Result<Mesh> {
    read_spooled(input, name, read_mesh)
}
