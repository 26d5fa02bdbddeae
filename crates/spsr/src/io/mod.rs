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
//! * The vertices of a mesh file, in every mesh format below but PLY (whose `vertex`
//!   element is read as above): OBJ (`v`, with `vn` normals where each vertex has one), OFF
//!   (normals with `NOFF`), STL (the merged corners, no normals) and GLB (`POSITION`,
//!   `NORMAL`); colours as attributes. Vertices no face uses are points too.
//!
//! **Meshes in** ([`read_mesh`]), chosen by the first bytes, then by the extension
//! ([`MeshFormat::detect`]): PLY (any encoding), OBJ (polygons fan-triangulated, negative
//! indices), STL (binary or ASCII; identical corners merged into one vertex), OFF
//! (`OFF`/`COFF`/`NOFF`/`CNOFF`/`STOFF`), glTF binary (`.glb`: what spsr writes, and triangle
//! primitives of other files, placed by their nodes' transforms). **Meshes out**
//! ([`write_mesh`], by extension, [`MeshFormat::from_path`]; any other extension is an
//! error): PLY (binary little endian, or ASCII), OBJ, STL (binary, or ASCII), OFF, glTF
//! binary. Each writer's and reader's module says what the format keeps: PLY and GLB keep
//! normals, colours and density; OBJ and OFF normals and colours; STL positions only.
//! **Point clouds out** ([`write_cloud`], by extension): PLY (`.ply`) or text (`.xyz`,
//! `.txt`).
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
mod lines;
mod lzf;
mod npz;
mod obj;
mod off;
mod pcd;
mod ply;
mod read_glb;
mod read_ply;
mod stl;
mod text;
pub(crate) mod unfinished;
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
    /// The vertices of a mesh file other than PLY (OBJ, OFF, STL, GLB).
    Mesh(MeshFormat),
}

/// A path's extension in lower case, if it has one.
fn extension(path: &Path) -> Option<String> {
    Some(path.extension()?.to_str()?.to_ascii_lowercase())
}

impl CloudFormat {
    /// The format of a file from its first bytes (`ply`, `LASF`, `ASTM-E57`, `# .PCD` or
    /// `VERSION`, or a mesh format's: see [`MeshFormat::from_magic`]), if they identify one.
    pub fn from_magic(head: &[u8]) -> Option<Self> {
        if head.starts_with(b"LASF") {
            Some(CloudFormat::Las)
        } else if head.starts_with(b"ASTM-E57") {
            Some(CloudFormat::E57)
        } else if head.starts_with(b"# .PCD") || head.starts_with(b"VERSION") {
            Some(CloudFormat::Pcd)
        } else {
            MeshFormat::from_magic(head).map(Self::of_mesh)
        }
    }

    /// The format named by a file's extension (any case): `.ply`, `.las`, `.laz`, `.e57`,
    /// `.pcd`, and the mesh formats' `.obj`, `.off`, `.stl`, `.glb`; `None` for anything else.
    pub fn from_extension(path: &Path) -> Option<Self> {
        Some(match extension(path)?.as_str() {
            "las" | "laz" => CloudFormat::Las,
            "e57" => CloudFormat::E57,
            "pcd" => CloudFormat::Pcd,
            _ => return MeshFormat::from_extension(path).map(Self::of_mesh),
        })
    }

    fn of_mesh(format: MeshFormat) -> Self {
        match format {
            MeshFormat::Ply => CloudFormat::Ply,
            other => CloudFormat::Mesh(other),
        }
    }

    /// The format [`write_cloud`] writes to `path`, by its extension (any case): PLY for
    /// `.ply`, text for `.xyz` and `.txt`.
    ///
    /// # Errors
    /// [`Error::Output`] for any other extension, or none, naming the ones known.
    pub fn for_output(path: &Path) -> Result<Self> {
        match extension(path).as_deref() {
            Some("ply") => Ok(CloudFormat::Ply),
            Some("xyz" | "txt") => Ok(CloudFormat::Text),
            _ => Err(unknown_extension(path, "point cloud", ".ply, .xyz, .txt")),
        }
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

/// The mesh file formats [`read_mesh`] reads and [`write_mesh`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Stanford PLY (binary little endian, or ASCII).
    Ply,
    /// Wavefront OBJ.
    Obj,
    /// STL (binary, or ASCII).
    Stl,
    /// Object File Format (ASCII).
    Off,
    /// glTF 2.0 binary.
    Glb,
}

/// The mesh formats' extensions, as messages list them.
const MESH_EXTENSIONS: &str = ".ply, .obj, .stl, .off, .glb";

fn unknown_extension(path: &Path, what: &str, known: &str) -> Error {
    let found = match path.extension() {
        Some(e) => format!("extension '.{}' is not", e.to_string_lossy()),
        None => "a name without an extension is not".into(),
    };
    Error::Output {
        path: path.to_path_buf(),
        message: format!("{found} a {what} format spsr writes; use one of {known}"),
    }
}

impl MeshFormat {
    /// The format of a file from its first bytes: `ply`, `glTF`, an OFF header keyword
    /// (`OFF`, `COFF`, `NOFF`, ...) or `solid` (ASCII STL; binary STL has no magic).
    pub fn from_magic(head: &[u8]) -> Option<Self> {
        if head.starts_with(b"ply\n") || head.starts_with(b"ply\r\n") {
            Some(MeshFormat::Ply)
        } else if read_glb::is_glb(head) {
            Some(MeshFormat::Glb)
        } else if off::is_off(head) {
            Some(MeshFormat::Off)
        } else if stl::starts_solid(head) {
            Some(MeshFormat::Stl)
        } else {
            None
        }
    }

    /// The format named by a file's extension (any case): `.ply`, `.obj`, `.stl`, `.off`,
    /// `.glb`; `None` for anything else.
    pub fn from_extension(path: &Path) -> Option<Self> {
        Some(match extension(path)?.as_str() {
            "ply" => MeshFormat::Ply,
            "obj" => MeshFormat::Obj,
            "stl" => MeshFormat::Stl,
            "off" => MeshFormat::Off,
            "glb" => MeshFormat::Glb,
            _ => return None,
        })
    }

    /// The format for an output path, by its extension (any case): `.ply`, `.obj`, `.stl`,
    /// `.off` or `.glb`.
    ///
    /// # Errors
    /// [`Error::Output`] for any other extension, or none, naming the ones known (nothing is
    /// written under a name that says another format).
    pub fn from_path(path: &Path) -> Result<Self> {
        Self::from_extension(path).ok_or_else(|| unknown_extension(path, "mesh", MESH_EXTENSIONS))
    }

    /// The format [`read_mesh`] uses for `path`: from its first bytes, else from its
    /// extension.
    ///
    /// # Errors
    /// [`Error::Io`] if the file cannot be opened or read, or is a directory;
    /// [`Error::Parse`] if neither its first bytes nor its extension name a mesh format.
    pub fn detect(path: &Path) -> Result<Self> {
        let (mut reader, _) = open(path)?;
        let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
        Self::choose(path, head)
    }

    fn choose(path: &Path, head: &[u8]) -> Result<Self> {
        Self::from_magic(head)
            .or_else(|| Self::from_extension(path))
            .ok_or_else(|| {
                parse_err(
                    path,
                    format!(
                        "not a mesh format spsr reads: neither its first bytes nor its \
                         extension say PLY, OBJ, STL, OFF or GLB ({MESH_EXTENSIONS})"
                    ),
                )
            })
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
        CloudFormat::Mesh(format) => {
            let mesh = read_mesh_as(path, reader, len, format)?;
            mesh_vertices(path, mesh, need_normals)
        }
    }
}

/// A mesh's vertices as a point cloud: positions, normals where the mesh has them, and its
/// attributes (colours); the density is not a property of points and is left out.
fn mesh_vertices(path: &Path, mesh: Mesh, need_normals: bool) -> Result<PointCloud> {
    let normals: Vec<[f64; 3]> = mesh
        .normals
        .into_iter()
        .flatten()
        .map(|n| n.map(f64::from))
        .collect();
    if need_normals && normals.is_empty() && !mesh.vertices.is_empty() {
        return Err(Error::MissingNormals {
            path: path.to_path_buf(),
        });
    }
    Ok(PointCloud {
        positions: mesh.vertices,
        normals,
        attributes: mesh.attributes,
        scan_origins: Vec::new(),
    })
}

fn read_mesh_as(
    path: &Path,
    reader: BufReader<File>,
    len: u64,
    format: MeshFormat,
) -> Result<Mesh> {
    match format {
        MeshFormat::Ply => read_ply::read_mesh(path, reader, len),
        MeshFormat::Obj => obj::read_obj(path, reader),
        MeshFormat::Stl => stl::read_stl(path, reader, len),
        MeshFormat::Off => off::read_off(path, reader, len),
        MeshFormat::Glb => read_glb::read_glb(path, reader, len),
    }
}

/// Reads a point cloud in any supported format (see the [module documentation](self)),
/// with or without normals.
///
/// The format comes from the file's first bytes (`ply`, `LASF`, `ASTM-E57`, `# .PCD` or
/// `VERSION`, `glTF`, an OFF keyword, `solid`), else from its extension (`.ply`, `.las`,
/// `.laz`, `.e57`, `.pcd`, `.obj`, `.off`, `.stl`, `.glb`, any case); anything else is read as
/// text. A mesh file gives its vertices (see the [module documentation](self)). Normals are read when the file has them
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

/// Reads several files as one cloud (tiles of one survey): their points one after another,
/// each file read by `read` (e.g. [`read_cloud`]). The tiles must all have normals or none, and
/// the same attributes; the first tile's scan origins are kept.
///
/// # Errors
/// The first error of `read`; [`Error::Parse`] naming the tile whose properties differ from
/// the first's; [`Error::InvalidParameter`] for an empty list.
pub fn read_tiles<P: AsRef<Path>>(
    paths: &[P],
    mut read: impl FnMut(&Path) -> Result<PointCloud>,
) -> Result<PointCloud> {
    let Some((first, rest)) = paths.split_first() else {
        return Err(Error::invalid("inputs", "none", "at least one file"));
    };
    let mut cloud = read(first.as_ref())?;
    for path in rest {
        let path = path.as_ref();
        cloud.append(read(path)?).map_err(|message| Error::Parse {
            path: path.to_path_buf(),
            message,
        })?;
    }
    Ok(cloud)
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

/// The one cloud a chunked reader hands over when its chunk is unbounded (a file read whole;
/// an empty file gives an empty cloud).
pub(crate) fn whole_cloud(
    read: impl FnOnce(&mut dyn FnMut(PointCloud) -> Result<()>) -> Result<()>,
) -> Result<PointCloud> {
    let mut whole = None;
    read(&mut |c| {
        whole = Some(c);
        Ok(())
    })?;
    Ok(whole.unwrap_or_default())
}

/// Reads an oriented point cloud as [`read_points`] does, but hands it to `emit` in clouds of
/// at most `chunk` points, in file order, so that a file larger than memory can be passed
/// over: PLY, text, LAS/LAZ, E57 and PCD are read chunk by chunk (LAS/LAZ in whole decoder
/// chunks of 65,536 points, so its chunks may be up to that much longer); a PCD
/// `binary_compressed` body (its fields stored one after another) and mesh files are read
/// whole and handed over as one cloud. An empty file gives one empty cloud. Each chunk's
/// scan origins count its points from its own first (the origin in force at its start comes
/// first). Whether a text file's colours are bytes is decided per chunk. Slab runs read their
/// inputs so.
///
/// # Errors
/// As [`read_points`], as soon as the chunk with the fault is reached (earlier chunks have
/// been handed over); an error from `emit` stops the reading and is returned;
/// [`Error::InvalidParameter`] for a `chunk` of 0.
pub fn read_points_chunks(
    path: &Path,
    chunk: usize,
    emit: &mut dyn FnMut(PointCloud) -> Result<()>,
) -> Result<()> {
    if chunk == 0 {
        return Err(Error::invalid("chunk", 0, "at least 1 point"));
    }
    let (mut reader, len) = open(path)?;
    let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
    match CloudFormat::choose(path, head) {
        CloudFormat::Ply => read_ply::read_cloud_chunks(path, reader, len, true, chunk, emit),
        CloudFormat::Text => text::read_text_chunks(reader, path, true, chunk, emit),
        CloudFormat::Las => las_file::read_las_chunks(path, reader, len, true, chunk, emit),
        CloudFormat::E57 => e57_file::read_e57_chunks(path, reader, len, true, chunk, emit),
        CloudFormat::Pcd => pcd::read_pcd_chunks(path, reader, len, true, chunk, emit),
        _ => emit(read_points(path)?),
    }
}

/// Reads a triangle mesh: PLY, OBJ, STL, OFF or GLB, chosen by the file's first bytes, then
/// by its extension ([`MeshFormat::detect`]). Polygons are fan-triangulated; faces with
/// fewer than three vertices are skipped.
///
/// PLY needs a `vertex` element with `x y z` and a `face` element with a list property named
/// `vertex_indices` or `vertex_index` (any integer types); a vertex property `density` (or
/// else `value`) fills [`Mesh::density`], `nx ny nz` fill [`Mesh::normals`], and every other
/// scalar vertex property becomes an attribute. GLB fills the density from spsr's
/// `_DENSITY`; OBJ, STL and OFF have none. What each other format gives is in its module's
/// documentation (see the [module documentation](self)).
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::Parse`] if its format cannot be told,
/// it is malformed, or a face refers to a vertex that does not exist (the message names the
/// face or line).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let (mut reader, len) = open(path)?;
    let head = reader.fill_buf().map_err(|e| io_err(path, e))?;
    let format = MeshFormat::choose(path, head)?;
    read_mesh_as(path, reader, len, format)
}

/// Writes a mesh in the format its extension names ([`MeshFormat::from_path`]): `.ply` PLY,
/// `.obj` OBJ, `.stl` STL, `.off` OFF, `.glb` glTF binary; any other extension is an error.
/// The file appears only when complete (temporary file in the same folder, then rename).
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
/// * **OFF**: ASCII; `NOFF` with normals, `COFF`/`CNOFF` with colours (bytes, alpha when
///   the mesh has it), triangles `3 a b c`. No density, no other attributes.
/// * **GLB**: glTF 2.0 binary with `POSITION`, `NORMAL`, `COLOR_0` (sRGB colours converted
///   to glTF's linear colours) and `_DENSITY` when present, and `u32` indices.
///
/// Coordinates are written as `f32`, except that PLY, OBJ and OFF write `f64` when the mesh lies
/// so far from the origin that `f32` would lose more than a millionth of its size (the
/// largest coordinate exceeds 16 times the bounding-box diagonal, as with georeferenced
/// lidar); GLB then stores positions relative to the bounding-box centre, which becomes the
/// node's translation; STL, which can only hold `f32`, loses that precision.
///
/// On any error no file at `path` is created or changed, and the temporary file is removed.
/// The file is not `fsync`ed.
///
/// # Errors
/// [`Error::Output`] if the extension names no mesh format, the directory is missing or not
/// writable, the path is a directory, or the mesh is inconsistent (an index out of range, a per-vertex array of the wrong
/// length, more than `i32::MAX` vertices or triangles, attribute names that PLY cannot
/// hold or that repeat, a GLB over 4 GiB); [`Error::Io`] if a write fails.
pub fn write_mesh(path: &Path, mesh: &Mesh, opts: &WriteOptions) -> Result<()> {
    write::write_mesh(path, mesh, opts)
}

pub(crate) use write::{write_with, Extent};

/// Writes a point cloud in the format its extension names ([`CloudFormat::for_output`]),
/// the same points in the same order. Written atomically, like [`write_mesh`].
///
/// * **PLY** (`.ply`; binary little endian unless `opts.ascii`): `x y z`, `nx ny nz` when
///   the cloud has normals, then every attribute in its own type and order. Positions (and
///   normals) are `float` when every value is exactly representable in `f32`, `double`
///   otherwise, so nothing is lost. [`PointCloud::scan_origins`] are kept as header comments
///   `comment spsr scan_origin <first point> <x> <y> <z>`, which [`read_cloud`] reads back.
/// * **Text** (`.xyz`, `.txt`): one point per line, `x y z`, then `nx ny nz` when the cloud
///   has normals, then `r g b` (bytes) when it also has colours — the layout the text
///   reader reads; numbers written exactly (the shortest text that reads back the same
///   `f64`). Other attributes and scan origins are not kept, nor colours without normals
///   (the layout has no place for them).
///
/// # Errors
/// [`Error::Output`] if the extension names no cloud format, the path cannot be used, the
/// normals or an attribute do not have
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

pub use npz::write_grid;
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

/// [`read_mesh`] from a reader; see [`read_points_from`]. Only formats with magic bytes (PLY,
/// GLB, OFF, ASCII STL) can be told apart this way.
///
/// # Errors
/// As [`read_mesh`].
pub fn read_mesh_from(input: impl std::io::Read, name: &Path) -> Result<Mesh> {
    read_spooled(input, name, read_mesh)
}
