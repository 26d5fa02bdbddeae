//! The steps of a slab run on a cluster (`spsr.distributed`), one Python function each: the
//! Python layer sends them to the workers as Dask tasks. Every step reads and writes the job
//! folder (`spsr::slabs::job`), so a task's arguments are a folder and a slab number, and its
//! result is nothing but files.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::slabs::job;
use spsr::trim::{Threshold, TrimParams};
use spsr::Params;

use crate::detach::{run_detached, threads_arg};
use crate::errors::{self, py_err, value_error, Call};
use crate::params::{threshold_arg, trim_params, MethodKeywords};

/// The parameters of `spsr.reconstruct`'s method keywords (one dict) as the job's JSON (the
/// form `job.json` keeps them in), checked.
#[pyfunction]
pub fn slab_params(py: Python<'_>, params: MethodKeywords) -> PyResult<String> {
    params_json(&params.params(py)?)
}

fn params_json(params: &Params) -> PyResult<String> {
    serde_json::to_string(params).map_err(|e| value_error(format!("parameters: {e}")))
}

fn params_from(json: &str) -> PyResult<Params> {
    serde_json::from_str(json).map_err(|e| value_error(format!("not spsr parameters: {e}")))
}

/// `spsr.reconstruct`'s trimming keywords as the job's JSON (`None` without `trim`), checked.
#[pyfunction]
#[pyo3(signature = (trim, min_island_area, hole_area))]
pub fn slab_trim(
    py: Python<'_>,
    trim: &Bound<'_, PyAny>,
    min_island_area: f64,
    hole_area: f64,
) -> PyResult<Option<String>> {
    let Some(threshold) = threshold_arg(trim, "trim")? else {
        return Ok(None);
    };
    let t = trim_params(py, threshold, min_island_area, hole_area, Call::Reconstruct)?;
    Ok(Some(trim_json(&t)))
}

fn trim_json(t: &TrimParams) -> String {
    let threshold = match t.threshold {
        Threshold::Auto => serde_json::Value::Null,
        Threshold::Value(v) => serde_json::json!(v),
    };
    serde_json::json!({
        "threshold": threshold,
        "min_island_area": t.min_island_area,
        "hole_area": t.hole_area,
    })
    .to_string()
}

fn trim_from(json: &str) -> PyResult<TrimParams> {
    let v: serde_json::Value = serde_json::from_str(json)
        .map_err(|e| value_error(format!("not spsr trimming parameters: {e}")))?;
    let area = |k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_f64)
            .ok_or_else(|| value_error(format!("trimming parameters without {k}")))
    };
    let threshold = match v.get("threshold") {
        None | Some(serde_json::Value::Null) => Threshold::Auto,
        Some(x) => Threshold::Value(
            x.as_f64()
                .ok_or_else(|| value_error("trimming threshold: not a number"))? as f32,
        ),
    };
    Ok(TrimParams {
        threshold,
        min_island_area: area("min_island_area")?,
        hole_area: area("hole_area")?,
    })
}

/// `python -m spsr.distributed`'s arguments after its own: `spsr reconstruct`'s flags, parsed
/// and checked by the command line's parser. Returns a dict (inputs, output, slabs or None,
/// work_dir, params as JSON, threads or None, verbose), or the exit code after printing the
/// usage error, `--help` or the refusal.
#[pyfunction]
pub fn slab_args<'py>(py: Python<'py>, argv: Vec<String>) -> PyResult<Bound<'py, PyAny>> {
    match spsr_cli::cluster_run(&argv) {
        Ok(run) => {
            let d = PyDict::new(py);
            d.set_item("inputs", run.inputs)?;
            d.set_item("output", run.output)?;
            d.set_item("slabs", run.slabs)?;
            d.set_item("work_dir", run.work_dir)?;
            d.set_item("params", params_json(&run.params)?)?;
            d.set_item("trim", run.trim.as_ref().map(trim_json))?;
            d.set_item("threads", run.threads)?;
            d.set_item("verbose", run.verbose)?;
            Ok(d.into_any())
        }
        Err(Ok(e)) => {
            // --help prints to stdout and succeeds; errors print usage, as `spsr` does.
            let _ = e.print();
            let code = if e.use_stderr() { e.exit_code() } else { 0 };
            Ok(code.into_pyobject(py)?.into_any())
        }
        Err(Err(failure)) => {
            eprintln!("spsr: error: {}", failure.error);
            Ok(failure.code.into_pyobject(py)?.into_any())
        }
    }
}

/// Reads the inputs into a new job folder inside `work_dir`, cut into at most `slabs` slabs,
/// the mesh to be trimmed with `trim` (from `slab_trim`); returns (the job folder, the slab
/// count, whether the noise phase runs, the solver cycles).
#[pyfunction]
#[pyo3(signature = (inputs, work_dir, slabs, params, threads=None, trim=None))]
pub fn slab_prepare(
    py: Python<'_>,
    inputs: Vec<PathBuf>,
    work_dir: PathBuf,
    slabs: i64,
    params: &str,
    threads: Option<i64>,
    trim: Option<&str>,
) -> PyResult<(PathBuf, usize, bool, u32)> {
    let params = params_from(params)?;
    let trim = trim.map(trim_from).transpose()?;
    if slabs < 1 {
        return Err(errors::invalid("slabs", slabs, "an integer of at least 1"));
    }
    if inputs.is_empty() {
        return Err(value_error("no input files"));
    }
    let slabs = usize::try_from(slabs).unwrap_or(usize::MAX);
    let threads = threads_arg(threads)?;
    let made = run_detached(py, threads, move |_| {
        job::prepare(
            spsr::slabs::Source::Files(&inputs),
            &params,
            trim.as_ref(),
            slabs,
            &work_dir,
        )
    })?
    .map_err(py_err(py, Call::Reconstruct))?;
    Ok((made.dir, made.slabs, made.noise, made.cycles))
}

/// Runs one step of the job in `dir`: a slab task (`noise`, `coarse`, `solve`, `extract`,
/// with `slab`) or a coordinator step (`smoothing`, `solve_coarse`, `cycle`, `iso`, without).
#[pyfunction]
#[pyo3(signature = (step, dir, slab=None, threads=None))]
pub fn slab_step(
    py: Python<'_>,
    step: &str,
    dir: PathBuf,
    slab: Option<usize>,
    threads: Option<i64>,
) -> PyResult<()> {
    type Task = fn(&std::path::Path, usize) -> spsr::Result<()>;
    type Step = fn(&std::path::Path) -> spsr::Result<()>;
    let task: Option<Task> = match step {
        "noise" => Some(job::noise),
        "coarse" => Some(job::coarse),
        "solve" => Some(job::solve),
        "extract" => Some(job::extract),
        _ => None,
    };
    let coordinator: Option<Step> = match step {
        "smoothing" => Some(job::smoothing),
        "solve_coarse" => Some(job::solve_coarse),
        "cycle" => Some(job::cycle),
        "iso" => Some(job::iso),
        _ => None,
    };
    let threads = threads_arg(threads)?;
    let outcome = match (task, coordinator, slab) {
        (Some(f), _, Some(s)) => run_detached(py, threads, move |_| f(&dir, s))?,
        (_, Some(f), None) => run_detached(py, threads, move |_| f(&dir))?,
        (Some(_), _, None) => return Err(value_error(format!("step '{step}' needs a slab"))),
        (_, Some(_), Some(_)) => return Err(value_error(format!("step '{step}' takes no slab"))),
        (None, None, _) => return Err(value_error(format!("no step '{step}'"))),
    };
    outcome.map_err(py_err(py, Call::Reconstruct))
}

/// Stitches the slabs' parts into the mesh at `output` (binary PLY); returns the run's
/// figures.
#[pyfunction]
pub fn slab_finish<'py>(
    py: Python<'py>,
    dir: PathBuf,
    output: PathBuf,
) -> PyResult<Bound<'py, PyDict>> {
    let (stats, written) = run_detached(py, None, move |_| job::finish(&dir, &output))?
        .map_err(py_err(py, Call::Reconstruct))?;
    let d = PyDict::new(py);
    d.set_item("vertices", written.vertices)?;
    d.set_item("faces", written.triangles)?;
    d.set_item("pieces", written.pieces)?;
    d.set_item("open_edges", written.open_edges)?;
    d.set_item("closed", stats.diagnosis.closed)?;
    d.set_item("slabs", stats.slabs)?;
    d.set_item("points", stats.points)?;
    d.set_item("dropped", stats.dropped)?;
    d.set_item("samples", stats.samples)?;
    d.set_item("iso_value", stats.iso_value)?;
    d.set_item("mean_sample_depth", stats.mean_sample_depth)?;
    let warnings: Vec<String> = stats.warnings.iter().map(errors::warning).collect();
    d.set_item("warnings", warnings)?;
    Ok(d)
}

/// Deletes a job folder (one with a `job.json`; any other folder is refused).
#[pyfunction]
pub fn slab_remove(py: Python<'_>, dir: PathBuf) -> PyResult<()> {
    py.detach(|| job::remove(&dir))
        .map_err(py_err(py, Call::Reconstruct))
}
