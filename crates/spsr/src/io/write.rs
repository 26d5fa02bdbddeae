//! Writing through a temporary file that is renamed into place only when complete, the checks
//! made before anything is written, the choice of format, and the up-front output path check.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::Error;
use crate::mesh::Mesh;
use crate::points::PointCloud;
use crate::Result;

use super::unfinished::Unfinished;
use super::{glb, obj, off, stl, text, write_ply, CloudFormat, MeshFormat, WriteOptions};

/// Encoded bytes collected before each `write_all`.
pub(crate) const FLUSH_BYTES: usize = 1 << 20;

/// Encodes records into a reusable byte buffer, handing it to `out` every [`FLUSH_BYTES`].
pub(crate) struct Encoder<'a, W: Write> {
    out: &'a mut W,
    pub(crate) buf: Vec<u8>,
}

impl<'a, W: Write> Encoder<'a, W> {
    pub(crate) fn new(out: &'a mut W) -> Self {
        Self {
            out,
            buf: Vec::with_capacity(FLUSH_BYTES + 4096),
        }
    }

    pub(crate) fn maybe_flush(&mut self) -> std::io::Result<()> {
        if self.buf.len() >= FLUSH_BYTES {
            self.out.write_all(&self.buf)?;
            self.buf.clear();
        }
        Ok(())
    }

    pub(crate) fn finish(mut self) -> std::io::Result<()> {
        self.out.write_all(&self.buf)?;
        self.buf.clear();
        Ok(())
    }
}

/// True when coordinates this far from the origin would lose more than a millionth of the
/// mesh's size in `f32` (the largest coordinate exceeds 16 times the bounding-box diagonal,
/// as `f32` keeps 24 bits): then formats that can write `f64` do.
pub(crate) fn needs_f64(vertices: &[[f64; 3]]) -> bool {
    let mut extent = Extent::default();
    for v in vertices {
        extent.add(*v);
    }
    extent.needs_f64()
}

/// The bounding box and largest coordinate of vertices seen one by one, for [`needs_f64`]'s
/// rule on a mesh written as it is produced (slab mode).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Extent {
    lo: [f64; 3],
    hi: [f64; 3],
    max_abs: f64,
}

impl Default for Extent {
    fn default() -> Self {
        Extent {
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            max_abs: 0.0,
        }
    }
}

impl Extent {
    /// Takes in one vertex (ignored unless finite).
    pub(crate) fn add(&mut self, v: [f64; 3]) {
        if v.iter().all(|c| c.is_finite()) {
            for k in 0..3 {
                self.lo[k] = self.lo[k].min(v[k]);
                self.hi[k] = self.hi[k].max(v[k]);
                self.max_abs = self.max_abs.max(v[k].abs());
            }
        }
    }

    /// [`needs_f64`] for the vertices taken in so far.
    pub(crate) fn needs_f64(&self) -> bool {
        if self.max_abs == 0.0 {
            return false;
        }
        let diag = (0..3)
            .map(|k| (self.hi[k] - self.lo[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        self.max_abs > 16.0 * diag
    }
}

fn output_err(path: &Path, message: String) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        message,
    }
}

fn io_err(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// The directory a path lives in; a bare file name lives in the current directory.
fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Checks that every attribute has `n` values.
fn check_attributes(
    path: &Path,
    attributes: &[crate::attributes::Attribute],
    n: usize,
    what: &str,
) -> Result<()> {
    for a in attributes {
        if a.len() != n {
            return Err(output_err(
                path,
                format!(
                    "cannot write the {what}: attribute '{}' has {} values for {n} {}",
                    a.name,
                    a.len(),
                    if what == "mesh" { "vertices" } else { "points" }
                ),
            ));
        }
    }
    Ok(())
}

/// Checks the mesh can be written as is (indices in range, per-vertex array lengths, 32-bit
/// counts).
fn validate(path: &Path, mesh: &Mesh) -> Result<()> {
    let nv = mesh.vertices.len();
    if nv > i32::MAX as usize || mesh.triangles.len() > i32::MAX as usize {
        return Err(output_err(
            path,
            format!(
                "the mesh is too large to write ({} vertices, {} triangles; at most {} each)",
                nv,
                mesh.triangles.len(),
                i32::MAX
            ),
        ));
    }
    if let Some(d) = &mesh.density {
        if d.len() != nv {
            return Err(output_err(
                path,
                format!(
                    "cannot write the mesh: {} density values for {nv} vertices",
                    d.len()
                ),
            ));
        }
    }
    if let Some(n) = &mesh.normals {
        if n.len() != nv {
            return Err(output_err(
                path,
                format!(
                    "cannot write the mesh: {} normals for {nv} vertices",
                    n.len()
                ),
            ));
        }
    }
    check_attributes(path, &mesh.attributes, nv, "mesh")?;
    if let Some((t, tri)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, tri)| tri.iter().any(|&i| i as usize >= nv))
    {
        return Err(output_err(
            path,
            format!(
                "cannot write the mesh: triangle {t} refers to vertex {:?} but there are only {nv} vertices",
                tri
            ),
        ));
    }
    Ok(())
}

/// Creates the temporary file next to `path`, with the permissions a new file would get
/// (0666 minus the umask on Unix) rather than tempfile's private 0600.
fn temp_file_in(dir: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    let mut b = tempfile::Builder::new();
    b.prefix(".spsr-").suffix(".tmp");
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b.tempfile_in(dir)
}

/// Writes a mesh in `format` to any writer (standard output, say); `name` is what errors
/// call the destination.
pub(crate) fn write_mesh_to(
    out: &mut dyn Write,
    name: &Path,
    format: MeshFormat,
    mesh: &Mesh,
    opts: &WriteOptions,
) -> Result<()> {
    validate(name, mesh)?;
    check_format(name, format, mesh)?;
    let mut w = BufWriter::with_capacity(1 << 16, out);
    encode_mesh(&mut w, format, mesh, opts)
        .and_then(|()| w.flush())
        .map_err(|e| io_err(name, e))
}

/// The one place that maps a mesh format to its writer.
fn encode_mesh<W: Write>(
    w: &mut W,
    format: MeshFormat,
    mesh: &Mesh,
    opts: &WriteOptions,
) -> std::io::Result<()> {
    match format {
        MeshFormat::Ply => write_ply::write_mesh(w, mesh, opts.ascii),
        MeshFormat::Obj => obj::write_obj(w, mesh),
        MeshFormat::Stl if opts.ascii => stl::write_ascii(w, mesh),
        MeshFormat::Stl => stl::write_binary(w, mesh),
        MeshFormat::Off => off::write_off(w, mesh),
        MeshFormat::Glb => glb::write_glb(w, mesh),
    }
}

fn check_format(path: &Path, format: MeshFormat, mesh: &Mesh) -> Result<()> {
    match format {
        MeshFormat::Ply => write_ply::check_mesh_names(mesh).map_err(|m| output_err(path, m)),
        MeshFormat::Glb => glb::check_size(mesh).map_err(|m| output_err(path, m)),
        MeshFormat::Obj | MeshFormat::Stl | MeshFormat::Off => Ok(()),
    }
}

/// Writes `path` through a temporary file in the same directory, renamed into place once
/// `write` has succeeded; on any error the temporary file is removed and `path` untouched.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<tempfile::NamedTempFile>) -> std::io::Result<()>,
) -> Result<()> {
    if path.is_dir() {
        return Err(output_err(
            path,
            "is a directory; choose a file name for the output".into(),
        ));
    }
    let dir = parent_dir(path);
    let tmp = temp_file_in(&dir).map_err(|e| {
        output_err(
            path,
            if dir.is_dir() {
                format!(
                    "cannot create a file in directory {} ({e}); choose a writable location",
                    dir.display()
                )
            } else {
                format!(
                    "directory {} does not exist ({e}); create the directory first",
                    dir.display()
                )
            },
        )
    })?;
    // On error `tmp` is dropped, which deletes the temporary file; an interrupted process
    // deletes it through `remove_unfinished_files`.
    let _unfinished = Unfinished::register(tmp.path());
    let mut w = BufWriter::with_capacity(1 << 16, tmp);
    write(&mut w).map_err(|e| io_err(path, e))?;
    let tmp = w.into_inner().map_err(|e| io_err(path, e.into_error()))?;
    tmp.persist(path).map_err(|e| {
        output_err(
            path,
            format!("cannot move the finished file into place: {}", e.error),
        )
    })?;
    Ok(())
}

/// Writes `path` atomically (see [`write_atomically`]) with `write`: for outputs produced piece
/// by piece (a slab run's mesh).
pub(crate) fn write_with(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<()> {
    write_atomically(path, |w| write(w))
}

pub(crate) fn write_mesh(path: &Path, mesh: &Mesh, opts: &WriteOptions) -> Result<()> {
    let format = MeshFormat::from_path(path)?;
    validate(path, mesh)?;
    check_format(path, format, mesh)?;
    write_atomically(path, |w| encode_mesh(w, format, mesh, opts))
}

pub(crate) fn write_cloud(path: &Path, cloud: &PointCloud, opts: &WriteOptions) -> Result<()> {
    let format = CloudFormat::for_output(path)?;
    let n = cloud.len();
    if !cloud.normals.is_empty() && cloud.normals.len() != n {
        return Err(output_err(
            path,
            format!(
                "cannot write the point cloud: {} normals for {n} points",
                cloud.normals.len()
            ),
        ));
    }
    check_attributes(path, &cloud.attributes, n, "point cloud")?;
    if format == CloudFormat::Text {
        return write_atomically(path, |w| text::write_text(w, cloud));
    }
    write_ply::check_cloud_names(cloud).map_err(|m| output_err(path, m))?;
    write_atomically(path, |w| write_ply::write_cloud(w, cloud, opts.ascii))
}

/// True when two existing paths name the same file (same device and inode on Unix).
fn same_existing_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(ma), Ok(mb)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return ma.dev() == mb.dev() && ma.ino() == mb.ino();
        }
    }
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(ca), Ok(cb)) => ca == cb,
        _ => false,
    }
}

pub(crate) fn check_output_path(output: &Path, input: &Path) -> Result<()> {
    if output.as_os_str().is_empty() {
        return Err(output_err(output, "the output file name is empty".into()));
    }
    if output.is_dir() {
        return Err(output_err(
            output,
            "is a directory; choose a file name for the output".into(),
        ));
    }
    if output.file_name().is_none() {
        return Err(output_err(
            output,
            "does not name a file; choose a file name for the output".into(),
        ));
    }
    let dir = parent_dir(output);
    if !dir.exists() {
        return Err(output_err(
            output,
            format!(
                "directory {} does not exist; create the directory first",
                dir.display()
            ),
        ));
    }
    if !dir.is_dir() {
        return Err(output_err(
            output,
            format!(
                "{} is not a directory; choose a different output file",
                dir.display()
            ),
        ));
    }
    let same = if output.exists() {
        same_existing_file(output, input)
    } else {
        // Output does not exist yet, so it cannot be the (existing) input; compare spellings
        // in case the input is missing too.
        match (dir.canonicalize(), output.file_name()) {
            (Ok(d), Some(name)) => {
                let o = d.join(name);
                let i = input.canonicalize().ok().or_else(|| {
                    let idir = parent_dir(input).canonicalize().ok()?;
                    Some(idir.join(input.file_name()?))
                });
                i.is_some_and(|i| i == o)
            }
            _ => false,
        }
    };
    if same {
        return Err(output_err(
            output,
            format!(
                "is the input file {}; choose a different output file",
                input.display()
            ),
        ));
    }
    temp_file_in(&dir).map(drop).map_err(|e| {
        output_err(
            output,
            format!(
                "directory {} is not writable ({e}); choose a different output location",
                dir.display()
            ),
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parent_of_bare_name_is_current_dir() {
        assert_eq!(parent_dir(Path::new("a.ply")), PathBuf::from("."));
        assert_eq!(parent_dir(Path::new("x/a.ply")), PathBuf::from("x"));
    }

    #[test]
    fn far_meshes_need_double_precision() {
        assert!(!needs_f64(&[[0.0; 3], [1.0, 2.0, 3.0]]));
        assert!(!needs_f64(&[]));
        assert!(needs_f64(&[
            [500_000.0, 5_000_000.0, 10.0],
            [500_100.0, 5_000_100.0, 20.0]
        ]));
        assert!(needs_f64(&[[7.0, 0.0, 0.0]]));
    }

    #[test]
    fn invalid_meshes_are_rejected_before_writing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.ply");
        let m = Mesh {
            vertices: vec![[0.0; 3]; 2],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        };
        let e = write_mesh(&p, &m, &WriteOptions::default()).unwrap_err();
        assert!(matches!(e, Error::Output { .. }), "{e}");
        assert!(e.to_string().contains("triangle 0"), "{e}");
        let m = Mesh {
            vertices: vec![[0.0; 3]; 2],
            triangles: vec![],
            density: Some(vec![1.0]),
            ..Default::default()
        };
        assert!(write_mesh(&p, &m, &WriteOptions::default()).is_err());
        let m = Mesh {
            vertices: vec![[0.0; 3]; 2],
            normals: Some(vec![[0.0; 3]]),
            ..Default::default()
        };
        assert!(write_mesh(&p, &m, &WriteOptions::default()).is_err());
        let m = Mesh {
            vertices: vec![[0.0; 3]; 2],
            attributes: vec![crate::attributes::Attribute::new(
                "red",
                crate::attributes::AttributeData::U8(vec![1, 2, 3]),
            )],
            ..Default::default()
        };
        let e = write_mesh(&p.with_extension("glb"), &m, &WriteOptions::default()).unwrap_err();
        assert!(
            e.to_string()
                .contains("attribute 'red' has 3 values for 2 vertices"),
            "{e}"
        );
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
