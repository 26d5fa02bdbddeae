//! `spsr._spsr`, the native half of the Python package `spsr`.
//!
//! The public Python API (keyword arguments, docstrings, dtype handling) lives in
//! `python/spsr/__init__.py`; this crate converts NumPy arrays to and from the library's
//! types, passes the keywords on as the library's parameters, maps `spsr::Error` to Python
//! exceptions in Python's words, releases the GIL while the library works and stops a
//! reconstruction when Python has a pending signal (Ctrl-C).
//!
//! | module | concern |
//! |---|---|
//! | [`arrays`] | NumPy arrays ↔ the library's points, meshes and attributes |
//! | [`errors`] | library errors and warnings → Python exceptions and text |
//! | [`params`] | keywords → `Params` / `TrimParams`; the library's defaults (`_defaults`) |
//! | [`detach`] | running library code without the GIL, interruptibly |
//! | [`reconstruct`] | `spsr.reconstruct` |
//! | [`implicit`] | the kept implicit function (`Mesh.implicit`) and the grid |
//! | [`mesh_ops`] | `spsr.trim`, `spsr.eval` |
//! | [`normals`] | `spsr.estimate_normals` |
//! | [`render`] | `spsr.render` |
//! | [`files`] | reading and writing files |
//! | [`cli`] | the `spsr` console script |
//! | [`slabs`] | the steps of a slab run on a cluster (`spsr.distributed`) |

use pyo3::prelude::*;

mod arrays;
mod cli;
mod detach;
mod errors;
mod files;
mod implicit;
mod mesh_ops;
mod normals;
mod params;
mod reconstruct;
mod render;
mod slabs;

/// The native module of the `spsr` Python package.
#[pymodule]
fn _spsr(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(reconstruct::reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_ops::trim, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_ops::evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(files::read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(files::write_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(files::write_points, m)?)?;
    m.add_function(wrap_pyfunction!(normals::estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(cli::cli_main, m)?)?;
    m.add_function(wrap_pyfunction!(params::defaults, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_params, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_args, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_trim, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_prepare, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_step, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_finish, m)?)?;
    m.add_function(wrap_pyfunction!(slabs::slab_remove, m)?)?;
    m.add_class::<implicit::Implicit>()?;
    m.add("MAX_DEPTH", spsr::MAX_DEPTH)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
