//! `spsr.reconstruct`: points and normals to a mesh, trimmed when asked.

use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::trim::TrimStats;
use spsr::Stats;

use crate::arrays::{cloud_in, mesh_out};
use crate::detach::{run_detached, threads_arg};
use crate::errors::{self, py_err, Call};
use crate::implicit::{grid_out, Implicit};
use crate::mesh_ops::trim_stats_out;
use crate::params::{threshold_arg, trim_params, MethodKeywords};

/// Reconstructs a mesh; see `spsr.reconstruct` for the arguments (the Python layer passes
/// every keyword, with its default; the method's as one dict, `params`).
#[pyfunction]
#[pyo3(signature = (
    points, normals, columns, *, params, threads, trim, min_island_area, hole_area, keep_implicit
))]
#[allow(clippy::too_many_arguments)]
pub fn reconstruct<'py>(
    py: Python<'py>,
    points: Bound<'py, PyAny>,
    normals: Bound<'py, PyAny>,
    columns: Vec<(String, Bound<'py, PyAny>)>,
    params: MethodKeywords,
    threads: Option<i64>,
    trim: Bound<'py, PyAny>,
    min_island_area: f64,
    hole_area: f64,
    keep_implicit: bool,
) -> PyResult<Bound<'py, PyDict>> {
    // Parameters first, before any array is converted.
    let params = params.params(py)?;
    let trim = match threshold_arg(&trim, "trim")? {
        None => None,
        Some(t) => Some(trim_params(
            py,
            t,
            min_island_area,
            hole_area,
            Call::Reconstruct,
        )?),
    };
    let threads = threads_arg(threads)?;
    let cloud = cloud_in(py, &points, Some(&normals), columns, Call::Reconstruct)?;
    let depth = params.depth;
    let (result, trimmed, implicit) =
        run_detached(py, threads, move |progress| match (&trim, keep_implicit) {
            (None, false) => {
                spsr::reconstruct_owned(cloud, &params, progress).map(|r| (r, None, None))
            }
            (None, true) => spsr::reconstruct_implicit(cloud, &params, progress)
                .map(|(r, f)| (r, None, Some(f))),
            (Some(t), false) => spsr::reconstruct_and_trim(cloud, &params, t, progress)
                .map(|(r, s)| (r, Some(s), None)),
            (Some(t), true) => spsr::reconstruct_and_trim_implicit(cloud, &params, t, progress)
                .map(|(r, s, f)| (r, Some(s), Some(f))),
        })?
        .map_err(py_err(py, Call::Reconstruct))?;
    let stats = stats_out(py, &result.stats, trimmed.as_ref())?;
    // The depth the run used: the one given, or the one a width or `"auto"` chose.
    let choice = result.stats.depth_choice.as_ref();
    stats.set_item("depth", choice.map_or(depth, |c| c.depth))?;
    stats.set_item(
        "depth_choice",
        choice.map(|c| c.message(&|field: &str| field.to_string())),
    )?;
    let out = mesh_out(py, result.mesh)?;
    out.set_item("stats", stats)?;
    match result.grid {
        Some(g) => out.set_item("grid", grid_out(py, g)?)?,
        None => out.set_item("grid", py.None())?,
    }
    match implicit {
        Some(f) => out.set_item("implicit", Py::new(py, Implicit::new(f))?)?,
        None => out.set_item("implicit", py.None())?,
    }
    Ok(out)
}

/// `Mesh.stats` of a reconstruction: counts, timings, warnings (in Python's words) and the
/// trimming's figures (or None).
fn stats_out<'py>(
    py: Python<'py>,
    s: &Stats,
    trimmed: Option<&TrimStats>,
) -> PyResult<Bound<'py, PyDict>> {
    let stats = PyDict::new(py);
    stats.set_item("points", s.points)?;
    stats.set_item("dropped", s.dropped)?;
    stats.set_item("samples", s.samples)?;
    stats.set_item("nodes_per_depth", s.nodes_per_depth.clone())?;
    stats.set_item("iso_value", s.iso_value)?;
    stats.set_item("mean_sample_depth", s.mean_sample_depth)?;
    let stages: Vec<(&str, f64)> = s
        .stages
        .iter()
        .map(|(name, d)| (name.as_str(), d.as_secs_f64()))
        .collect();
    stats.set_item("stages", &stages)?;
    stats.set_item("peak_memory", s.peak_memory.clone())?;
    let work: Vec<Option<(f64, f64)>> = s
        .work
        .iter()
        .map(|w| w.map(|w| (w.bytes, w.flops)))
        .collect();
    stats.set_item("work", work)?;
    stats.set_item("clusters_per_depth", s.clusters_per_depth.clone())?;
    let warnings: Vec<String> = s.warnings.iter().map(errors::warning).collect();
    stats.set_item("warnings", warnings)?;
    let d = &s.diagnosis;
    let diagnosis = PyDict::new(py);
    diagnosis.set_item("pieces", d.pieces)?;
    diagnosis.set_item("closed", d.closed)?;
    diagnosis.set_item("boundary_edges", d.boundary_edges)?;
    diagnosis.set_item("on_cube", d.on_cube)?;
    diagnosis.set_item("contradicted_normals", d.contradicted_normals)?;
    stats.set_item("diagnosis", diagnosis)?;
    match &s.noise {
        Some(n) => {
            let noise = PyDict::new(py);
            noise.set_item("median", n.median)?;
            noise.set_item("median_cells", n.median_cells)?;
            noise.set_item("measured", n.measured)?;
            noise.set_item("adapted", n.adapted)?;
            noise.set_item("mean_lowering", n.mean_lowering)?;
            stats.set_item("noise", noise)?
        }
        None => stats.set_item("noise", py.None())?,
    }
    match trimmed {
        Some(t) => {
            // `reconstruct_and_trim` times the trimming as its last stage.
            let seconds = stages
                .iter()
                .rev()
                .find(|(name, _)| *name == "trimming")
                .map_or(0.0, |&(_, secs)| secs);
            stats.set_item("trim", trim_stats_out(py, t, seconds)?)?
        }
        None => stats.set_item("trim", py.None())?,
    }
    Ok(stats)
}
