//! Files: `spsr.read_points`, `spsr.read_mesh`, `spsr.write_mesh`, `spsr.write_points`.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::arrays::{attributes_out, cloud_in, mesh_in, mesh_out, rows_out, MeshArgs};
use crate::detach::run_detached;
use crate::errors::{py_err, Call};

/// Reads a point cloud of any supported format (mesh files give their vertices), from one
/// file or several (tiles, one cloud): a dict with `positions`, `normals` (or None),
/// `attributes` (a list of (name, array)) and `scan_origins` (a list of (first point,
/// (x, y, z))).
#[pyfunction]
pub fn read_cloud(py: Python<'_>, paths: Vec<PathBuf>) -> PyResult<Bound<'_, PyDict>> {
    let cloud = run_detached(py, None, move |_| {
        spsr::io::read_tiles(&paths, spsr::io::read_cloud)
    })?
    .map_err(py_err(py, Call::Files))?;
    let d = PyDict::new(py);
    let has_normals = cloud.has_normals();
    d.set_item("positions", rows_out(py, cloud.positions)?)?;
    if has_normals {
        d.set_item("normals", rows_out(py, cloud.normals)?)?;
    } else {
        d.set_item("normals", py.None())?;
    }
    d.set_item("attributes", attributes_out(py, cloud.attributes)?)?;
    let origins: Vec<(usize, [f64; 3])> = cloud
        .scan_origins
        .iter()
        .map(|s| (s.first_point, s.origin))
        .collect();
    d.set_item("scan_origins", origins)?;
    Ok(d)
}

/// Reads a mesh (PLY, OBJ, STL, OFF or GLB, by first bytes then extension): the dict of
/// `mesh_out`.
#[pyfunction]
pub fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let mesh = run_detached(py, None, move |_| spsr::io::read_mesh(&path))?
        .map_err(py_err(py, Call::Files))?;
    mesh_out(py, mesh)
}

/// Writes a mesh, format by extension (.ply, .obj, .stl, .off, .glb; any other is an
/// `OSError`), atomically.
#[pyfunction]
#[pyo3(signature = (path, mesh, ascii))]
pub fn write_mesh(py: Python<'_>, path: PathBuf, mesh: MeshArgs<'_>, ascii: bool) -> PyResult<()> {
    let mesh = mesh_in(mesh)?;
    run_detached(py, None, move |_| {
        spsr::io::write_mesh(&path, &mesh, &spsr::io::WriteOptions { ascii })
    })?
    .map_err(py_err(py, Call::Files))
}

/// Writes a point cloud, format by extension (.ply, or text .xyz/.txt; any other is an
/// `OSError`), atomically.
#[pyfunction]
#[pyo3(signature = (path, points, normals, attributes, ascii))]
pub fn write_points(
    py: Python<'_>,
    path: PathBuf,
    points: Bound<'_, PyAny>,
    normals: Option<Bound<'_, PyAny>>,
    attributes: Vec<(String, Bound<'_, PyAny>)>,
    ascii: bool,
) -> PyResult<()> {
    let cloud = cloud_in(py, &points, normals.as_ref(), attributes, Call::Files)?;
    run_detached(py, None, move |_| {
        spsr::io::write_cloud(&path, &cloud, &spsr::io::WriteOptions { ascii })
    })?
    .map_err(py_err(py, Call::Files))
}
