//! `spsr.reconstruct`: points and normals to a mesh, trimmed when asked.

use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::trim::TrimStats;
use spsr::{Params, Stats};

use crate::arrays::{cloud_in, mesh_out};
use crate::detach::{run_detached, threads_arg};
use crate::errors::{self, invalid, py_err, Call};
use crate::mesh_ops::trim_stats_out;
use crate::params::{
    boundary_arg, degree_arg, int_arg, shown_as_given, threshold_arg, trim_params, weights_arg,
};

/// Reconstructs a mesh; see `spsr.reconstruct` for the arguments (the Python layer passes
/// every keyword, with its default).
#[pyfunction]
#[pyo3(signature = (
    points, normals, columns, *, depth, full_depth, samples_per_node, point_weight, degree,
    boundary, scale, iters, confidence, density, linear_fit, max_memory, two_level_splat,
    attributes, data_pull, vertex_normals, confidence_property, threads, trim,
    min_island_area, hole_area, noise, keep_outliers, keep_normals
))]
#[allow(clippy::too_many_arguments)]
pub fn reconstruct<'py>(
    py: Python<'py>,
    points: Bound<'py, PyAny>,
    normals: Bound<'py, PyAny>,
    columns: Vec<(String, Bound<'py, PyAny>)>,
    depth: i64,
    full_depth: Option<i64>,
    samples_per_node: Option<f64>,
    point_weight: Option<f64>,
    degree: i64,
    boundary: &str,
    scale: f64,
    iters: i64,
    confidence: bool,
    density: bool,
    linear_fit: bool,
    max_memory: Option<i64>,
    two_level_splat: bool,
    attributes: bool,
    data_pull: f64,
    vertex_normals: bool,
    confidence_property: Option<String>,
    threads: Option<i64>,
    trim: Bound<'py, PyAny>,
    min_island_area: f64,
    hole_area: f64,
    noise: Option<&str>,
    keep_outliers: bool,
    keep_normals: bool,
) -> PyResult<Bound<'py, PyDict>> {
    // Parameters first, before any array is converted.
    let params = reconstruct_params(
        py,
        depth,
        full_depth,
        samples_per_node,
        point_weight,
        degree,
        boundary,
        scale,
        iters,
        confidence,
        density,
        linear_fit,
        max_memory,
        two_level_splat,
        attributes,
        data_pull,
        vertex_normals,
        confidence_property,
        noise,
        keep_outliers,
        keep_normals,
    )?;
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
    let (result, trimmed) = run_detached(py, threads, move |progress| match &trim {
        None => spsr::reconstruct_owned(cloud, &params, progress).map(|r| (r, None)),
        Some(t) => {
            spsr::reconstruct_and_trim(cloud, &params, t, progress).map(|(r, s)| (r, Some(s)))
        }
    })?
    .map_err(py_err(py, Call::Reconstruct))?;
    let stats = stats_out(py, &result.stats, trimmed.as_ref())?;
    let out = mesh_out(py, result.mesh)?;
    out.set_item("stats", stats)?;
    Ok(out)
}

/// The library's parameters from `spsr.reconstruct`'s keywords (those that are `Params`
/// fields), checked by the library; shared with `spsr.distributed` (`slabs.rs`).
#[allow(clippy::too_many_arguments)]
pub fn reconstruct_params(
    py: Python<'_>,
    depth: i64,
    full_depth: Option<i64>,
    samples_per_node: Option<f64>,
    point_weight: Option<f64>,
    degree: i64,
    boundary: &str,
    scale: f64,
    iters: i64,
    confidence: bool,
    density: bool,
    linear_fit: bool,
    max_memory: Option<i64>,
    two_level_splat: bool,
    attributes: bool,
    data_pull: f64,
    vertex_normals: bool,
    confidence_property: Option<String>,
    noise: Option<&str>,
    keep_outliers: bool,
    keep_normals: bool,
) -> PyResult<Params> {
    let given_noise = match noise {
        None => None,
        Some(name) => Some(
            spsr::Noise::from_name(name)
                .ok_or_else(|| invalid("noise", format!("'{name}'"), "'adaptive' or 'off'"))?,
        ),
    };
    let params = Params {
        depth: int_arg(depth),
        // As the command line: the library's 5, or the depth when that is smaller.
        full_depth: full_depth.map_or(Params::default().full_depth.min(int_arg(depth)), int_arg),
        samples_per_node: samples_per_node.unwrap_or(Params::default().samples_per_node),
        point_weight,
        degree: degree_arg(degree)?,
        boundary: boundary_arg(boundary)?,
        scale,
        iters: int_arg(iters),
        weights: weights_arg(confidence, confidence_property),
        density,
        linear_fit,
        // A negative size becomes 0, which the library refuses.
        max_memory: max_memory.map(|m| u64::try_from(m).unwrap_or(0)),
        two_level_splat,
        attributes,
        data_pull,
        normals: vertex_normals,
        noise: spsr::Noise::unless_tuned(
            given_noise,
            samples_per_node.is_some() || point_weight.is_some(),
        ),
        keep_outliers,
        keep_normals,
        resolution: spsr::Resolution::Depth,
        grid_res: None,
    };
    let given = [
        ("depth", Some(depth)),
        ("full_depth", full_depth),
        ("iters", Some(iters)),
        ("max_memory", max_memory),
    ];
    params
        .validate()
        .map_err(|e| errors::to_py_err(py, shown_as_given(e, &given), Call::Reconstruct))?;
    Ok(params)
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
