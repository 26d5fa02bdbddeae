//! Operations on meshes: `spsr.trim` and `spsr.eval`.

use std::time::Instant;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::metrics::{EvalOptions, Reference};
use spsr::trim::TrimStats;

use crate::arrays::{mesh_in, mesh_out, MeshArgs};
use crate::detach::{run_detached, threads_arg};
use crate::errors::{invalid, py_err, to_py_err, value_error, Call};
use crate::params::{shown_as_given, threshold_arg, trim_params};

/// Trims a mesh with a density; see `spsr.trim`.
#[pyfunction]
#[pyo3(signature = (mesh, threshold, min_island_area, hole_area, threads))]
pub fn trim<'py>(
    py: Python<'py>,
    mesh: MeshArgs<'py>,
    threshold: Bound<'py, PyAny>,
    min_island_area: f64,
    hole_area: f64,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let threshold = threshold_arg(&threshold, "threshold")?.ok_or_else(|| {
        invalid(
            "threshold",
            "None",
            "a density value (a finite number such as 6.5) or 'auto'",
        )
    })?;
    let params = trim_params(py, threshold, min_island_area, hole_area, Call::Trim)?;
    let threads = threads_arg(threads)?;
    let mesh = mesh_in(mesh)?;
    let (trimmed, stats, secs) = run_detached(py, threads, move |_| {
        let t = Instant::now();
        spsr::trim::trim(&mesh, &params).map(|(m, s)| (m, s, t.elapsed().as_secs_f64()))
    })?
    .map_err(py_err(py, Call::Trim))?;
    let out = mesh_out(py, trimmed)?;
    out.set_item("trim", trim_stats_out(py, &stats, secs)?)?;
    Ok(out)
}

/// The trimming's figures: `Mesh.stats["trim"]`.
pub fn trim_stats_out<'py>(
    py: Python<'py>,
    s: &TrimStats,
    seconds: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("threshold", s.threshold)?;
    match &s.auto {
        Some(a) => {
            let auto = PyDict::new(py);
            auto.set_item("threshold", a.threshold)?;
            auto.set_item("median", a.median)?;
            auto.set_item("mad", a.mad)?;
            auto.set_item("area_below", a.area_below)?;
            d.set_item("auto", auto)?;
        }
        None => d.set_item("auto", py.None())?,
    }
    d.set_item("total_area", s.total_area)?;
    d.set_item("kept_area", s.kept_area)?;
    d.set_item("cut_vertices", s.cut_vertices)?;
    d.set_item("islands_removed", s.islands_removed)?;
    d.set_item("holes_filled", s.holes_filled)?;
    d.set_item("triangles_in", s.triangles_in)?;
    d.set_item("triangles_out", s.triangles_out)?;
    d.set_item("seconds", seconds)?;
    Ok(d)
}

/// Scores a mesh against a reference mesh or sphere; returns the JSON of `spsr eval --json`.
/// The library checks the sample count, the sphere and both meshes.
#[pyfunction]
#[pyo3(signature = (mesh, reference, sphere, samples, seed, threads))]
pub fn evaluate(
    py: Python<'_>,
    mesh: MeshArgs<'_>,
    reference: Option<MeshArgs<'_>>,
    sphere: Option<([f64; 3], f64)>,
    samples: i64,
    seed: u64,
    threads: Option<i64>,
) -> PyResult<String> {
    let reference = match (reference, sphere) {
        (None, None) => {
            return Err(value_error(
                "no reference: give reference= (a mesh) or sphere=(cx, cy, cz, r)",
            ))
        }
        (Some(_), Some(_)) => {
            return Err(value_error(
                "reference= and sphere= cannot be used together; give one",
            ))
        }
        (None, Some((center, radius))) => Reference::Sphere { center, radius },
        (Some(r), None) => Reference::Mesh(mesh_in(r)?),
    };
    let threads = threads_arg(threads)?;
    let mesh = mesh_in(mesh)?;
    // A negative count becomes 0, which the library refuses.
    let opts = EvalOptions {
        samples: usize::try_from(samples).unwrap_or(0),
        seed,
    };
    run_detached(py, threads, move |_| {
        spsr::metrics::evaluate(&mesh, &reference, &opts).map(|e| e.to_json())
    })?
    .map_err(|e| {
        to_py_err(
            py,
            shown_as_given(e, &[("samples", Some(samples))]),
            Call::Eval,
        )
    })
}
