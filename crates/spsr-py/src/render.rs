//! `spsr.render`: a picture of a mesh as a NumPy array.

use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::render::{ColorBy, Highlight, RenderOptions, View};

use crate::arrays::{mesh_in, MeshArgs};
use crate::detach::{run_detached, threads_arg};
use crate::errors::{invalid, py_err, Call};

/// `view=`: a view name, in any case.
fn view_arg(s: &str) -> PyResult<View> {
    s.parse().map_err(|_| {
        invalid(
            "view",
            format!("'{s}'"),
            "one of 'front', 'side', 'top', 'iso', 'all'",
        )
    })
}

/// `color=`: `None` (the mesh's colours when it has them), `"plain"`, `"density"` or
/// `"attribute:NAME"`.
fn color_arg(s: Option<&str>) -> PyResult<ColorBy> {
    match s {
        None => Ok(ColorBy::Auto),
        Some(s) => s.parse().map_err(|_| {
            invalid(
                "color",
                format!("'{s}'"),
                "None, 'plain', 'density' or 'attribute:NAME'",
            )
        }),
    }
}

/// `highlight=`: `None` or `"pieces"`.
fn highlight_arg(s: Option<&str>) -> PyResult<Highlight> {
    match s {
        None => Ok(Highlight::None),
        Some(s) => s
            .parse()
            .map_err(|_| invalid("highlight", format!("'{s}'"), "None or 'pieces'")),
    }
}

/// Draws a mesh; returns an `(height, width, 4)` uint8 array (RGBA, rows from the top).
/// The library checks the size and the mesh.
#[pyfunction]
#[pyo3(signature = (mesh, view, width, height, highlight, color, threads))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    mesh: MeshArgs<'py>,
    view: &str,
    width: i64,
    height: i64,
    highlight: Option<&str>,
    color: Option<&str>,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyAny>> {
    // Out-of-range sizes become 0 or u32::MAX, which the library refuses with the others.
    let size = |n: i64| u32::try_from(n.max(0)).unwrap_or(u32::MAX);
    let opts = RenderOptions {
        view: view_arg(view)?,
        width: size(width),
        height: size(height),
        color: color_arg(color)?,
        highlight: highlight_arg(highlight)?,
        ..Default::default()
    };
    let threads = threads_arg(threads)?;
    let mesh = mesh_in(mesh)?;
    let image = run_detached(py, threads, move |_| spsr::render::render(&mesh, &opts))?
        .map_err(py_err(py, Call::Render))?;
    let (h, w) = (image.height as usize, image.width as usize);
    Ok(PyArray1::from_vec(py, image.rgba)
        .reshape([h, w, 4])?
        .into_any())
}

/// The defaults of `spsr.render`: `view` and `size`.
pub fn render_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let o = RenderOptions::default();
    let d = PyDict::new(py);
    let name = View::NAMES
        .iter()
        .find(|&&(_, v)| v == o.view)
        .map_or("iso", |&(n, _)| n);
    d.set_item("view", name)?;
    d.set_item("size", (o.width, o.height))?;
    Ok(d)
}
