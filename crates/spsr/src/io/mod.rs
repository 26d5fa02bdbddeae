//! Reading point clouds and meshes, writing meshes (atomically). (Being implemented; the
//! signatures are the contract.)

use std::path::Path;

use crate::mesh::Mesh;
use crate::points::PointCloud;
use crate::Result;

/// How to write a mesh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriteOptions {
    /// ASCII PLY instead of binary little-endian PLY (ignored for OBJ).
    pub ascii: bool,
}

/// Reads an oriented point cloud: PLY (any encoding) or text with `x y z nx ny nz` per line.
pub fn read_points(path: &Path) -> Result<PointCloud> {
    let _ = path;
    unimplemented!()
}

/// Reads a triangle mesh from PLY (faces as lists; polygons fan-triangulated).
pub fn read_mesh(path: &Path) -> Result<Mesh> {
    let _ = path;
    unimplemented!()
}

/// Writes a mesh: OBJ when the name ends in `.obj`, PLY otherwise. The file appears only when
/// complete (temporary file in the same folder, then rename).
pub fn write_mesh(path: &Path, mesh: &Mesh, opts: &WriteOptions) -> Result<()> {
    let _ = (path, mesh, opts);
    unimplemented!()
}

/// Checks, before any long computation, that `output` can be written and is not `input`.
pub fn check_output_path(output: &Path, input: &Path) -> Result<()> {
    let _ = (output, input);
    unimplemented!()
}
