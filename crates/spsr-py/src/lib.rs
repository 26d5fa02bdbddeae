//! `spsr._spsr`, the native half of the Python package `spsr`.
//!
//! The public Python API (keyword arguments, docstrings, dtype handling) lives in
//! `python/spsr/__init__.py`; this module converts NumPy arrays to and from the library's
//! types, maps `spsr::Error` to Python exceptions, releases the GIL while the library works
//! and stops a reconstruction when Python has a pending signal (Ctrl-C).
//!
//! Arrays passed to these functions have already been checked by the Python layer for shape
//! and dtype; the checks here repeat the essentials so that misuse of the private module gives
//! an exception, never a panic.

use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use numpy::ndarray::{ArrayView1, ArrayView2};
use numpy::{Element, PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{
    PyFileExistsError, PyFileNotFoundError, PyMemoryError, PyOSError, PyPermissionError,
    PyRuntimeError, PyValueError,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use spsr::attributes::{Attribute, AttributeData};
use spsr::trim::{Threshold, TrimParams};
use spsr::{Boundary, Mesh, Params, PointCloud};

/// How often the waiting thread looks for pending Python signals.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

// ---------------------------------------------------------------------------------------
// Errors

/// Maps a library error to the Python exception of its kind, with the library's message
/// (the one the command line prints after `spsr: error:`).
fn to_py_err(py: Python<'_>, e: spsr::Error) -> PyErr {
    use spsr::Error as E;
    let message = e.to_string();
    match e {
        E::Io { source, .. } => {
            // The subclass Python itself would raise; the message stays the library's (the
            // `errno` attribute is set, `filename` is not, which would change the message).
            use std::io::ErrorKind as K;
            let err = match source.kind() {
                K::NotFound => PyFileNotFoundError::new_err(message),
                K::PermissionDenied => PyPermissionError::new_err(message),
                K::AlreadyExists => PyFileExistsError::new_err(message),
                _ => PyOSError::new_err(message),
            };
            if let Some(code) = source.raw_os_error() {
                let _ = err.value(py).setattr("errno", code);
            }
            err
        }
        E::Output { .. } => PyOSError::new_err(message),
        E::Parse { .. } | E::MissingNormals { .. } => {
            // Malformed file content: both an OSError (a file problem) and a ValueError
            // (bad data), like io.UnsupportedOperation.
            match py
                .import("spsr")
                .and_then(|m| m.getattr("FileFormatError"))
                .and_then(|class| class.call1((message.clone(),)))
            {
                Ok(value) => PyErr::from_value(value),
                Err(_) => PyValueError::new_err(message),
            }
        }
        E::ResourceLimit { .. } => PyMemoryError::new_err(message),
        E::InvalidParameter { .. }
        | E::LengthMismatch { .. }
        | E::TooFewPoints { .. }
        | E::Degenerate(_)
        | E::InvalidMesh(_) => PyValueError::new_err(message),
        _ => PyRuntimeError::new_err(message),
    }
}

fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// An integer parameter as `u32`, with the library's message for values it cannot hold.
fn param_u32(name: &'static str, v: i64, range: &str) -> PyResult<u32> {
    u32::try_from(v).map_err(|_| {
        to_py_err_static(spsr::Error::InvalidParameter {
            name,
            message: format!("{v} is outside {range}"),
        })
    })
}

fn to_py_err_static(e: spsr::Error) -> PyErr {
    Python::attach(|py| to_py_err(py, e))
}

// ---------------------------------------------------------------------------------------
// Running library code with the GIL released, interruptibly

/// The payload of the unwind that stops library code at a pending signal.
struct Interrupted;

/// Runs `work` on a worker thread with the GIL released; `work` gets a progress callback that
/// the library calls at each stage (and solver depth). Meanwhile this thread checks every
/// 50 ms for pending Python signals; when a handler raises (Ctrl-C: `KeyboardInterrupt`),
/// the next progress call unwinds the library's stack, every buffer is freed, and the
/// handler's exception is returned once the worker has stopped.
fn run_detached<T, F>(py: Python<'_>, threads: Option<usize>, work: F) -> PyResult<T>
where
    T: Send,
    F: FnOnce(&(dyn Fn(&str) + Sync)) -> T + Send,
{
    let pool = match threads {
        None => None,
        Some(n) => Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| {
                    PyRuntimeError::new_err(format!("cannot start {n} worker threads: {e}"))
                })?,
        ),
    };
    let cancel = AtomicBool::new(false);
    let (outcome, interrupt) = py.detach(|| {
        std::thread::scope(|scope| {
            let (done_tx, done_rx) = mpsc::channel::<()>();
            let cancel = &cancel;
            let pool = &pool;
            let worker = std::thread::Builder::new()
                .name("spsr".into())
                .stack_size(8 << 20)
                .spawn_scoped(scope, move || {
                    let check = move |_stage: &str| {
                        if cancel.load(Ordering::Relaxed) {
                            // resume_unwind skips the panic hook: nothing is printed.
                            resume_unwind(Box::new(Interrupted));
                        }
                    };
                    let result = catch_unwind(AssertUnwindSafe(|| match pool {
                        Some(pool) => pool.install(|| work(&check)),
                        None => work(&check),
                    }));
                    let _ = done_tx.send(());
                    result
                });
            let worker = match worker {
                Ok(w) => w,
                Err(e) => {
                    let err = PyRuntimeError::new_err(format!("cannot start a thread: {e}"));
                    return (None, Some(err));
                }
            };
            let mut interrupt: Option<PyErr> = None;
            loop {
                match done_rx.recv_timeout(SIGNAL_POLL) {
                    Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    Err(mpsc::RecvTimeoutError::Timeout) => {
                        if interrupt.is_none() {
                            if let Err(e) = Python::attach(|py| py.check_signals()) {
                                cancel.store(true, Ordering::Relaxed);
                                interrupt = Some(e);
                            }
                        }
                    }
                }
            }
            (Some(worker.join()), interrupt)
        })
    });
    if let Some(err) = interrupt {
        // The exception raised by the signal handler wins, whether the work had finished or
        // was stopped.
        return Err(err);
    }
    match outcome {
        Some(Ok(Ok(value))) => Ok(value),
        Some(Ok(Err(payload))) | Some(Err(payload)) => {
            if payload.is::<Interrupted>() {
                Err(PyRuntimeError::new_err("interrupted"))
            } else {
                // A bug in the library: let PyO3 turn it into a PanicException.
                resume_unwind(payload)
            }
        }
        None => Err(PyRuntimeError::new_err("the worker thread did not start")),
    }
}

// ---------------------------------------------------------------------------------------
// Arrays in

/// Rows of an `(N, 3)` float64 or float32 array, as the library's `[f64; 3]`s. A C-contiguous
/// float64 array is copied in one pass; other layouts and float32 are converted row by row.
fn rows3(array: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    fn from_view<T: Copy + Into<f64>>(view: ArrayView2<'_, T>) -> Vec<[f64; 3]> {
        if let Some(flat) = view.as_slice() {
            flat.chunks_exact(3)
                .map(|c| [c[0].into(), c[1].into(), c[2].into()])
                .collect()
        } else {
            view.rows()
                .into_iter()
                .map(|r| [r[0].into(), r[1].into(), r[2].into()])
                .collect()
        }
    }
    let check = |shape: &[usize]| {
        if shape.len() != 2 || shape[1] != 3 {
            Err(value_error(format!(
                "{what} must be an array of shape (N, 3), got shape {shape:?}"
            )))
        } else {
            Ok(())
        }
    };
    if let Ok(a) = array.cast::<PyArray2<f64>>() {
        check(a.shape())?;
        let ro = a.readonly();
        return Ok(from_view(ro.as_array()));
    }
    if let Ok(a) = array.cast::<PyArray2<f32>>() {
        check(a.shape())?;
        let ro = a.readonly();
        return Ok(from_view(ro.as_array()));
    }
    Err(value_error(format!(
        "{what} must be a float32 or float64 array of shape (N, 3)"
    )))
}

/// Triangles of an `(M, 3)` integer array, each index checked against `vertices`.
fn faces3(array: &Bound<'_, PyAny>, vertices: usize) -> PyResult<Vec<[u32; 3]>> {
    fn from_view<T: Copy + Into<i128>>(
        view: ArrayView2<'_, T>,
        vertices: usize,
    ) -> PyResult<Vec<[u32; 3]>> {
        let mut out = Vec::with_capacity(view.nrows());
        for (f, row) in view.rows().into_iter().enumerate() {
            let mut t = [0u32; 3];
            for k in 0..3 {
                let v: i128 = row[k].into();
                if v < 0 || v >= vertices as i128 {
                    return Err(value_error(format!(
                        "faces: face {f} refers to vertex {v}, but there are {vertices} vertices"
                    )));
                }
                t[k] = v as u32;
            }
            out.push(t);
        }
        Ok(out)
    }
    let shape = array
        .cast::<numpy::PyUntypedArray>()
        .map(|a| a.shape().to_vec())
        .unwrap_or_default();
    if shape.len() != 2 || shape[1] != 3 {
        return Err(value_error(format!(
            "faces must be an integer array of shape (M, 3), got shape {shape:?}"
        )));
    }
    macro_rules! try_int {
        ($t:ty) => {
            if let Ok(a) = array.cast::<PyArray2<$t>>() {
                return from_view(a.readonly().as_array(), vertices);
            }
        };
    }
    try_int!(i32);
    try_int!(u32);
    try_int!(i64);
    try_int!(u64);
    try_int!(i16);
    try_int!(u16);
    try_int!(i8);
    try_int!(u8);
    Err(value_error("faces must be an array of integers"))
}

/// A 1-D array as a typed attribute column.
fn column(name: &str, array: &Bound<'_, PyAny>) -> PyResult<AttributeData> {
    fn vec<T: Element + Copy>(a: &Bound<'_, PyArray1<T>>) -> Vec<T> {
        a.readonly().as_array().iter().copied().collect()
    }
    macro_rules! try_type {
        ($t:ty, $variant:ident) => {
            if let Ok(a) = array.cast::<PyArray1<$t>>() {
                return Ok(AttributeData::$variant(vec(a)));
            }
        };
    }
    try_type!(u8, U8);
    try_type!(i8, I8);
    try_type!(u16, U16);
    try_type!(i16, I16);
    try_type!(u32, U32);
    try_type!(i32, I32);
    try_type!(f32, F32);
    try_type!(f64, F64);
    Err(value_error(format!(
        "attribute '{name}' must be a 1-D array of uint8, int8, uint16, int16, uint32, int32, \
         float32 or float64 values"
    )))
}

fn attributes_in(list: Vec<(String, Bound<'_, PyAny>)>, n: usize) -> PyResult<Vec<Attribute>> {
    let mut out = Vec::with_capacity(list.len());
    for (name, array) in list {
        let data = column(&name, &array)?;
        if data.len() != n {
            return Err(value_error(format!(
                "attribute '{name}' has {} values but there are {n} points or vertices",
                data.len()
            )));
        }
        out.push(Attribute::new(name, data));
    }
    Ok(out)
}

fn vector1<T: Element + Copy>(array: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<T>> {
    let a = array.cast::<PyArray1<T>>().map_err(|_| {
        value_error(format!(
            "{what} must be a 1-D array of {}",
            T::get_dtype(array.py())
        ))
    })?;
    let ro = a.readonly();
    let view: ArrayView1<'_, T> = ro.as_array();
    Ok(view.iter().copied().collect())
}

/// A mesh from the Python layer's tuple `(vertices, faces, normals, density, attributes)`.
type MeshArgs<'py> = (
    Bound<'py, PyAny>,
    Bound<'py, PyAny>,
    Option<Bound<'py, PyAny>>,
    Option<Bound<'py, PyAny>>,
    Vec<(String, Bound<'py, PyAny>)>,
);

fn mesh_in(args: MeshArgs<'_>) -> PyResult<Mesh> {
    let (vertices, faces, normals, density, attributes) = args;
    let vertices = rows3(&vertices, "vertices")?;
    let n = vertices.len();
    let triangles = faces3(&faces, n)?;
    let normals = match normals {
        None => None,
        Some(a) => {
            let rows = rows3(&a, "normals")?;
            if rows.len() != n {
                return Err(value_error(format!(
                    "normals has {} rows but there are {n} vertices",
                    rows.len()
                )));
            }
            Some(
                rows.into_iter()
                    .map(|r| [r[0] as f32, r[1] as f32, r[2] as f32])
                    .collect(),
            )
        }
    };
    let density = match density {
        None => None,
        Some(a) => {
            let d: Vec<f32> = vector1(&a, "density")?;
            if d.len() != n {
                return Err(value_error(format!(
                    "density has {} values but there are {n} vertices",
                    d.len()
                )));
            }
            Some(d)
        }
    };
    Ok(Mesh {
        vertices,
        triangles,
        density,
        normals,
        attributes: attributes_in(attributes, n)?,
    })
}

// ---------------------------------------------------------------------------------------
// Arrays out (the library's buffers handed to NumPy without copying)

fn rows_out<'py, T: Element>(py: Python<'py>, rows: Vec<[T; 3]>) -> PyResult<Bound<'py, PyAny>> {
    let n = rows.len();
    let flat = PyArray1::from_vec(py, rows.into_flattened());
    Ok(flat.reshape([n, 3])?.into_any())
}

fn column_out(py: Python<'_>, data: AttributeData) -> Bound<'_, PyAny> {
    match data {
        AttributeData::U8(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::I8(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::U16(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::I16(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::U32(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::I32(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::F32(v) => PyArray1::from_vec(py, v).into_any(),
        AttributeData::F64(v) => PyArray1::from_vec(py, v).into_any(),
    }
}

fn attributes_out(py: Python<'_>, attributes: Vec<Attribute>) -> PyResult<Bound<'_, PyList>> {
    let list = PyList::empty(py);
    for a in attributes {
        list.append((a.name, column_out(py, a.data)))?;
    }
    Ok(list)
}

fn mesh_out(py: Python<'_>, mesh: Mesh) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    let nv = mesh.vertices.len();
    d.set_item("vertices", rows_out(py, mesh.vertices)?)?;
    // int32 indices, as Open3D's triangles; the library's u32 indices are below the vertex
    // count, which the writers already cap at i32::MAX.
    let faces: Vec<[i32; 3]> = if nv <= i32::MAX as usize {
        mesh.triangles
            .into_iter()
            .map(|t| [t[0] as i32, t[1] as i32, t[2] as i32])
            .collect()
    } else {
        return Err(value_error(format!(
            "the mesh has {nv} vertices, more than int32 indices can address"
        )));
    };
    d.set_item("faces", rows_out(py, faces)?)?;
    match mesh.normals {
        Some(n) => d.set_item("normals", rows_out(py, n)?)?,
        None => d.set_item("normals", py.None())?,
    }
    match mesh.density {
        Some(v) => d.set_item("density", PyArray1::from_vec(py, v))?,
        None => d.set_item("density", py.None())?,
    }
    d.set_item("attributes", attributes_out(py, mesh.attributes)?)?;
    Ok(d)
}

fn trim_stats_out<'py>(
    py: Python<'py>,
    s: &spsr::trim::TrimStats,
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

// ---------------------------------------------------------------------------------------
// Parameters

fn threads_arg(threads: Option<i64>) -> PyResult<Option<usize>> {
    match threads {
        None => Ok(None),
        Some(n) if n >= 1 => Ok(Some(usize::try_from(n).unwrap_or(usize::MAX))),
        Some(n) => Err(value_error(format!(
            "invalid parameter threads: must be at least 1, got {n}"
        ))),
    }
}

fn boundary_arg(s: &str) -> PyResult<Boundary> {
    match s.to_ascii_lowercase().as_str() {
        "neumann" => Ok(Boundary::Neumann),
        "dirichlet" => Ok(Boundary::Dirichlet),
        "free" => Ok(Boundary::Free),
        _ => Err(value_error(format!(
            "invalid parameter --boundary: '{s}' is not one of neumann, dirichlet, free"
        ))),
    }
}

/// `--trim`: `None`, `"auto"` or a finite number.
fn threshold_arg(trim: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Threshold>> {
    let Some(t) = trim else { return Ok(None) };
    if t.is_none() {
        return Ok(None);
    }
    if let Ok(s) = t.extract::<String>() {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok(Some(Threshold::Auto));
        }
        return Err(value_error(format!(
            "invalid parameter --trim: '{s}' is neither a density value (a finite number such as 6.5) nor 'auto'"
        )));
    }
    match t.extract::<f64>() {
        Ok(v) => Ok(Some(Threshold::Value(v as f32))),
        Err(_) => Err(value_error(
            "invalid parameter --trim: give a density value (a number such as 6.5) or 'auto'",
        )),
    }
}

// ---------------------------------------------------------------------------------------
// Functions

/// Reconstructs a mesh; see `spsr.reconstruct` for the arguments.
#[pyfunction]
#[pyo3(signature = (
    points, normals, columns, *, depth, full_depth, samples_per_node, point_weight, degree,
    boundary, scale, iters, confidence, density, linear_fit, max_memory, two_level_splat,
    attributes, data_pull, vertex_normals, confidence_property, threads, trim,
    min_island_area, hole_area
))]
#[allow(clippy::too_many_arguments)]
fn reconstruct<'py>(
    py: Python<'py>,
    points: Bound<'py, PyAny>,
    normals: Bound<'py, PyAny>,
    columns: Vec<(String, Bound<'py, PyAny>)>,
    depth: i64,
    full_depth: Option<i64>,
    samples_per_node: f64,
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
    trim: Option<Bound<'py, PyAny>>,
    min_island_area: f64,
    hole_area: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let max = spsr::MAX_DEPTH;
    // Parameters first, before any array is converted.
    let depth = param_u32("--depth", depth, &format!("1..={max}"))?;
    let full_depth = match full_depth {
        // As the command line: 5, or the depth when that is smaller.
        None => Params::default().full_depth.min(depth),
        Some(v) => param_u32("--full-depth", v, &format!("0..={depth}"))?,
    };
    let degree = u8::try_from(degree).map_err(|_| {
        to_py_err(
            py,
            spsr::Error::InvalidParameter {
                name: "--degree",
                message: format!("{degree} is not supported; use 1 or 2"),
            },
        )
    })?;
    let iters = param_u32("--iters", iters, "1..=10000")?;
    let max_memory = match max_memory {
        None => None,
        Some(v) if v > 0 => Some(v as u64),
        Some(0) => Some(0), // validate() explains why 0 cannot work
        Some(v) => {
            return Err(value_error(format!(
                "invalid parameter --max-memory: must be a positive size, got {v}"
            )))
        }
    };
    let trim_threshold = threshold_arg(trim.as_ref())?;
    let params = Params {
        depth,
        full_depth,
        samples_per_node,
        point_weight,
        degree,
        boundary: boundary_arg(boundary)?,
        scale,
        iters,
        confidence,
        density: density || trim_threshold.is_some(),
        linear_fit,
        max_memory,
        two_level_splat,
        attributes,
        data_pull,
        normals: vertex_normals,
        confidence_property,
    };
    params.validate().map_err(|e| to_py_err(py, e))?;
    let trim_params = trim_threshold.map(|threshold| TrimParams {
        threshold,
        min_island_area,
        hole_area,
    });
    if let Some(p) = &trim_params {
        p.validate().map_err(|e| to_py_err(py, e))?;
    }
    let threads = threads_arg(threads)?;

    let positions = rows3(&points, "points")?;
    let normals = rows3(&normals, "normals")?;
    let n = positions.len();
    let mut cloud = PointCloud::new(positions, normals).map_err(|e| to_py_err(py, e))?;
    cloud.attributes = attributes_in(columns, n)?;

    let outcome = run_detached(py, threads, move |progress| {
        let mut result = spsr::reconstruct_owned(cloud, &params, progress)?;
        let mut trimmed = None;
        if let Some(p) = &trim_params {
            progress("trimming");
            let t = std::time::Instant::now();
            let (mesh, stats) = spsr::trim::trim(&result.mesh, p)?;
            result.mesh = mesh;
            trimmed = Some((stats, t.elapsed().as_secs_f64()));
        }
        if !density {
            // Computed for trimming only, as the command line does.
            result.mesh.density = None;
        }
        Ok::<_, spsr::Error>((result, trimmed))
    })?;
    let (result, trimmed) = outcome.map_err(|e| to_py_err(py, e))?;

    let s = &result.stats;
    let stats = PyDict::new(py);
    stats.set_item("points", s.points)?;
    stats.set_item("dropped", s.dropped)?;
    stats.set_item("samples", s.samples)?;
    stats.set_item("nodes_per_depth", s.nodes_per_depth.clone())?;
    stats.set_item("iso_value", s.iso_value)?;
    stats.set_item("mean_sample_depth", s.mean_sample_depth)?;
    let stages: Vec<(String, f64)> = s
        .stages
        .iter()
        .map(|(name, d)| (name.clone(), d.as_secs_f64()))
        .collect();
    stats.set_item("stages", stages)?;
    stats.set_item("peak_memory", s.peak_memory.clone())?;
    stats.set_item("warnings", s.warnings.clone())?;
    match &trimmed {
        Some((t, secs)) => stats.set_item("trim", trim_stats_out(py, t, *secs)?)?,
        None => stats.set_item("trim", py.None())?,
    }
    let out = mesh_out(py, result.mesh)?;
    out.set_item("stats", stats)?;
    Ok(out)
}

/// Trims a mesh with a density; see `spsr.trim`.
#[pyfunction]
#[pyo3(signature = (mesh, threshold, min_island_area, hole_area, threads))]
fn trim<'py>(
    py: Python<'py>,
    mesh: MeshArgs<'py>,
    threshold: Bound<'py, PyAny>,
    min_island_area: f64,
    hole_area: f64,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let threshold = threshold_arg(Some(&threshold))?.ok_or_else(|| {
        value_error(
            "invalid parameter --trim: give a density value (a number such as 6.5) or 'auto'",
        )
    })?;
    let params = TrimParams {
        threshold,
        min_island_area,
        hole_area,
    };
    params.validate().map_err(|e| to_py_err(py, e))?;
    let threads = threads_arg(threads)?;
    let mesh = mesh_in(mesh)?;
    let (trimmed, stats, secs) = run_detached(py, threads, move |_| {
        let t = std::time::Instant::now();
        spsr::trim::trim(&mesh, &params).map(|(m, s)| (m, s, t.elapsed().as_secs_f64()))
    })?
    .map_err(|e| to_py_err(py, e))?;
    let out = mesh_out(py, trimmed)?;
    out.set_item("trim", trim_stats_out(py, &stats, secs)?)?;
    Ok(out)
}

/// Checks that a mesh has area to sample, as `spsr eval` does.
fn check_eval_mesh(mesh: &Mesh, what: &str) -> PyResult<()> {
    let area = mesh.area();
    if mesh.triangles.is_empty() || !(area > 0.0 && area.is_finite()) {
        let why = if mesh.triangles.is_empty() {
            "no faces"
        } else {
            "no surface area (non-finite or degenerate faces)"
        };
        return Err(value_error(format!("{what}: the mesh has {why}")));
    }
    Ok(())
}

/// Scores a mesh against a reference mesh or sphere; returns the JSON of `spsr eval --json`.
#[pyfunction]
#[pyo3(signature = (mesh, reference, sphere, samples, seed, threads))]
fn evaluate(
    py: Python<'_>,
    mesh: MeshArgs<'_>,
    reference: Option<MeshArgs<'_>>,
    sphere: Option<([f64; 3], f64)>,
    samples: i64,
    seed: u64,
    threads: Option<i64>,
) -> PyResult<String> {
    let samples = usize::try_from(samples)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| {
            value_error(format!(
                "invalid parameter --samples: must be at least 1, got {samples}"
            ))
        })?;
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
        (None, Some((center, radius))) => {
            if !(center.iter().all(|c| c.is_finite()) && radius.is_finite() && radius > 0.0) {
                return Err(value_error(format!(
                    "invalid sphere ({}, {}, {}, {radius}): finite centre and positive radius needed",
                    center[0], center[1], center[2]
                )));
            }
            spsr::metrics::Reference::Sphere { center, radius }
        }
        (Some(r), None) => {
            let r = mesh_in(r)?;
            check_eval_mesh(&r, "reference")?;
            spsr::metrics::Reference::Mesh(r)
        }
    };
    let threads = threads_arg(threads)?;
    let mesh = mesh_in(mesh)?;
    check_eval_mesh(&mesh, "mesh")?;
    let opts = spsr::metrics::EvalOptions { samples, seed };
    run_detached(py, threads, move |_| {
        spsr::metrics::evaluate(&mesh, &reference, &opts).map(|e| e.to_json())
    })?
    .map_err(|e| to_py_err(py, e))
}

/// Reads a point cloud of any supported format: a dict with `positions`, `normals` (or
/// None), `attributes` (a list of (name, array)) and `scan_origins` (a list of (first point,
/// (x, y, z))).
#[pyfunction]
fn read_cloud(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let cloud = run_detached(py, None, move |_| spsr::io::read_cloud(&path))?
        .map_err(|e| to_py_err(py, e))?;
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

/// Reads a PLY mesh: the dict of `mesh_out`.
#[pyfunction]
fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyDict>> {
    let mesh = run_detached(py, None, move |_| spsr::io::read_mesh(&path))?
        .map_err(|e| to_py_err(py, e))?;
    mesh_out(py, mesh)
}

/// Writes a mesh, format by extension, atomically.
#[pyfunction]
#[pyo3(signature = (path, mesh, ascii))]
fn write_mesh(py: Python<'_>, path: PathBuf, mesh: MeshArgs<'_>, ascii: bool) -> PyResult<()> {
    let mesh = mesh_in(mesh)?;
    run_detached(py, None, move |_| {
        spsr::io::write_mesh(&path, &mesh, &spsr::io::WriteOptions { ascii })
    })?
    .map_err(|e| to_py_err(py, e))
}

/// Writes a point cloud as PLY, atomically.
#[pyfunction]
#[pyo3(signature = (path, points, normals, attributes, ascii))]
fn write_points(
    py: Python<'_>,
    path: PathBuf,
    points: Bound<'_, PyAny>,
    normals: Option<Bound<'_, PyAny>>,
    attributes: Vec<(String, Bound<'_, PyAny>)>,
    ascii: bool,
) -> PyResult<()> {
    let positions = rows3(&points, "points")?;
    let n = positions.len();
    let mut cloud = match normals {
        Some(a) => {
            PointCloud::new(positions, rows3(&a, "normals")?).map_err(|e| to_py_err(py, e))?
        }
        None => PointCloud::from_positions(positions),
    };
    cloud.attributes = attributes_in(attributes, n)?;
    run_detached(py, None, move |_| {
        spsr::io::write_cloud(&path, &cloud, &spsr::io::WriteOptions { ascii })
    })?
    .map_err(|e| to_py_err(py, e))
}

/// Estimates and orients normals, as `spsr normals`; see `spsr.estimate_normals`.
#[pyfunction]
#[pyo3(signature = (points, *, neighbours, orient, viewpoint, scan_origins, threads))]
fn estimate_normals<'py>(
    py: Python<'py>,
    points: Bound<'py, PyAny>,
    neighbours: Option<i64>,
    orient: Option<&str>,
    viewpoint: Option<[f64; 3]>,
    scan_origins: Option<Vec<(i64, [f64; 3])>>,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    use spsr::normals::{NormalParams, Orientation};
    let neighbours =
        match neighbours {
            None => None,
            Some(k) if k >= 3 => Some(usize::try_from(k).unwrap_or(usize::MAX)),
            Some(_) => return Err(value_error(
                "invalid parameter --neighbours: must be at least 3 (a plane needs three points)",
            )),
        };
    let scans = scan_origins.unwrap_or_default();
    let mode = orient.unwrap_or(if viewpoint.is_some() || !scans.is_empty() {
        "viewpoint"
    } else {
        "mst"
    });
    if viewpoint.is_some() && mode != "viewpoint" {
        return Err(value_error(
            "viewpoint= is only used by orient=\"viewpoint\"; leave out one of them",
        ));
    }
    let how =
        match mode {
            "mst" => Some(Orientation::mst()),
            "global" => Some(Orientation::global()),
            "none" => None,
            "viewpoint" => match viewpoint {
                Some(v) => Some(Orientation::Viewpoint(v)),
                None if !scans.is_empty() => {
                    let mut list = Vec::with_capacity(scans.len());
                    for (i, (first, origin)) in scans.into_iter().enumerate() {
                        let first = usize::try_from(first).map_err(|_| {
                            value_error(format!("scan_origins: {first} is not a point index"))
                        })?;
                        // Points before the first scan are counted with it, as the CLI does.
                        list.push((if i == 0 { 0 } else { first }, origin));
                    }
                    Some(Orientation::ScanOrigins(list))
                }
                None => return Err(value_error(
                    "orient=\"viewpoint\" needs viewpoint=(x, y, z): no scan positions are known",
                )),
            },
            other => {
                return Err(value_error(format!(
                "invalid parameter --orient: '{other}' is not one of mst, viewpoint, global, none"
            )))
            }
        };
    let threads = threads_arg(threads)?;
    let positions = rows3(&points, "points")?;
    let params = NormalParams {
        neighbours,
        ..Default::default()
    };
    let (estimated, stats) = run_detached(py, threads, move |_| {
        let mut estimated = spsr::normals::estimate(&positions, &params)?;
        let stats = match &how {
            Some(how) => Some(spsr::normals::orient(
                &positions,
                &mut estimated.normals,
                how,
            )?),
            None => None,
        };
        Ok::<_, spsr::Error>((estimated, stats))
    })?
    .map_err(|e| to_py_err(py, e))?;
    let d = PyDict::new(py);
    d.set_item("orientation", mode)?;
    d.set_item("neighbours", estimated.neighbours)?;
    d.set_item("noisy", estimated.noisy)?;
    d.set_item("degenerate", estimated.degenerate)?;
    d.set_item("non_finite", estimated.non_finite)?;
    if let Some(s) = stats {
        d.set_item("flipped", s.flipped)?;
        d.set_item("components", s.components)?;
        d.set_item("skipped", s.skipped)?;
        d.set_item("corrections", s.corrections)?;
    }
    d.set_item("normals", rows_out(py, estimated.normals)?)?;
    Ok(d)
}

/// Runs the command line `spsr` with `argv` (program name first); returns the exit code.
/// This is the wheel's `spsr` console script.
#[pyfunction]
fn cli_main(py: Python<'_>, argv: Vec<String>) -> PyResult<u8> {
    use clap::Parser;
    let cli = match spsr_cli::Cli::try_parse_from(&argv) {
        Ok(cli) => cli,
        Err(e) => {
            // --help and --version print to stdout and succeed; errors print usage.
            let _ = e.print();
            return Ok(if e.use_stderr() {
                e.exit_code() as u8
            } else {
                0
            });
        }
    };
    let code = py.detach(move || match spsr_cli::run(&cli) {
        Ok(()) => 0,
        Err(failure) => {
            eprintln!("spsr: error: {}", failure.error);
            failure.code
        }
    });
    Ok(code)
}

/// The native module of the `spsr` Python package.
#[pymodule]
fn _spsr(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(trim, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(read_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(write_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(write_points, m)?)?;
    m.add_function(wrap_pyfunction!(estimate_normals, m)?)?;
    m.add_function(wrap_pyfunction!(cli_main, m)?)?;
    m.add("MAX_DEPTH", spsr::MAX_DEPTH)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
