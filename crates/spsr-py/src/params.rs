//! Python keywords as the library's parameters, and the library's defaults as Python values.
//!
//! The library checks every value it has a field for (`Params::validate`,
//! `TrimParams::validate`), so that its rules and wording are the only ones; this module only
//! converts, and checks what has no library field (a degree that is not 1 or 2, an unknown
//! boundary name, a trimming threshold that is not a number or `"auto"`).

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::normals::NormalParams;
use spsr::trim::{Threshold, TrimParams};
use spsr::{Boundary, Degree, Error, Params, PointWeights, Resolution};

use crate::errors::{invalid, py_err, value_error, Call};

/// The boundary conditions by their Python names.
const BOUNDARIES: [(&str, Boundary); 3] = [
    ("neumann", Boundary::Neumann),
    ("dirichlet", Boundary::Dirichlet),
    ("free", Boundary::Free),
];

/// `boundary=`: a name of [`BOUNDARIES`], in any case.
pub fn boundary_arg(s: &str) -> PyResult<Boundary> {
    let lower = s.to_ascii_lowercase();
    BOUNDARIES
        .iter()
        .find(|(name, _)| *name == lower)
        .map(|&(_, b)| b)
        .ok_or_else(|| {
            invalid(
                "boundary",
                format!("'{s}'"),
                "one of 'neumann', 'dirichlet', 'free'",
            )
        })
}

fn boundary_name(b: Boundary) -> &'static str {
    BOUNDARIES
        .iter()
        .find(|&&(_, v)| v == b)
        .map_or("neumann", |&(name, _)| name)
}

/// `degree=`: 1 or 2.
pub fn degree_arg(d: i64) -> PyResult<Degree> {
    u8::try_from(d)
        .ok()
        .and_then(Degree::from_number)
        .ok_or_else(|| invalid("degree", d, "1 or 2"))
}

/// `confidence=` and `confidence_property=` as the points' weights; a property wins, as on
/// the command line.
pub fn weights_arg(confidence: bool, property: Option<String>) -> PointWeights {
    match (property, confidence) {
        (Some(name), _) => PointWeights::Property(name),
        (None, true) => PointWeights::NormalLength,
        (None, false) => PointWeights::Uniform,
    }
}

/// The keywords of `spsr.reconstruct` that are the method's parameters (the `Params`
/// fields), passed by the Python layer as one dict: the one description of them on the
/// native side, shared by `reconstruct` and `spsr.distributed` (`slab_params`).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
pub struct MethodKeywords {
    /// An integer, `"auto"` or None (the library's depth, or the one `width` sets).
    depth: Py<PyAny>,
    width: Option<f64>,
    grid_res: Option<i64>,
    full_depth: Option<i64>,
    samples_per_node: Option<f64>,
    point_weight: Option<f64>,
    degree: i64,
    boundary: String,
    scale: f64,
    iters: Option<i64>,
    confidence: bool,
    density: bool,
    linear_fit: bool,
    max_memory: Option<i64>,
    two_level_splat: bool,
    attributes: bool,
    data_pull: f64,
    vertex_normals: bool,
    confidence_property: Option<String>,
    noise: Option<String>,
    keep_outliers: bool,
    keep_normals: bool,
    solver: String,
    cycles: Option<i64>,
    /// False, True or `"auto"` (also `"off"` and `"on"`).
    gpu: Py<PyAny>,
}

impl MethodKeywords {
    /// The library's parameters, checked by the library (errors in Python's words).
    pub fn params(self, py: Python<'_>) -> PyResult<Params> {
        let solver = spsr::Solver::from_name(&self.solver).ok_or_else(|| {
            invalid(
                "solver",
                format!("'{}'", self.solver),
                "'cascadic', 'vcycle' or 'wcycle'",
            )
        })?;
        let given_noise = match &self.noise {
            None => None,
            Some(name) => Some(
                spsr::Noise::from_name(name)
                    .ok_or_else(|| invalid("noise", format!("'{name}'"), "'adaptive' or 'off'"))?,
            ),
        };
        let (depth, resolution) = resolution_arg(self.depth.bind(py), self.width)?;
        let given_depth = match resolution {
            Resolution::Depth => Some(depth),
            _ => None,
        };
        let depth = given_depth.map_or(Params::default().depth, int_arg);
        let params = Params {
            depth,
            resolution,
            grid_res: grid_res_arg(self.grid_res)?,
            // As the command line: the library's 5, or the depth when that is smaller (a
            // depth the library chooses keeps the full depth no deeper).
            full_depth: self
                .full_depth
                .map_or(Params::default().full_depth.min(depth), int_arg),
            samples_per_node: self
                .samples_per_node
                .unwrap_or(Params::default().samples_per_node),
            point_weight: self.point_weight,
            degree: degree_arg(self.degree)?,
            boundary: boundary_arg(&self.boundary)?,
            scale: self.scale,
            iters: self.iters.map(int_arg),
            weights: weights_arg(self.confidence, self.confidence_property),
            density: self.density,
            linear_fit: self.linear_fit,
            // A negative size becomes 0, which the library refuses.
            max_memory: self.max_memory.map(|m| u64::try_from(m).unwrap_or(0)),
            two_level_splat: self.two_level_splat,
            attributes: self.attributes,
            data_pull: self.data_pull,
            normals: self.vertex_normals,
            noise: spsr::Noise::unless_tuned(
                given_noise,
                self.samples_per_node.is_some() || self.point_weight.is_some(),
            ),
            keep_outliers: self.keep_outliers,
            keep_normals: self.keep_normals,
            solver,
            cycles: self.cycles.map(int_arg),
            report_residuals: false,
            gpu: gpu_arg(self.gpu.bind(py))?,
        };
        let given = [
            ("depth", given_depth),
            ("grid_res", self.grid_res),
            ("full_depth", self.full_depth),
            ("iters", self.iters),
            ("cycles", self.cycles),
            ("max_memory", self.max_memory),
        ];
        params.validate().map_err(|e| {
            crate::errors::to_py_err(py, shown_as_given(e, &given), Call::Reconstruct)
        })?;
        Ok(params)
    }
}

/// `gpu=`: False or None (the CPU), True (a GPU or an error), `"auto"`; `"off"` and `"on"`
/// too, in any case.
fn gpu_arg(gpu: &Bound<'_, PyAny>) -> PyResult<spsr::Gpu> {
    let expected = "False, True or 'auto'";
    if gpu.is_none() {
        return Ok(spsr::Gpu::Off);
    }
    if let Ok(on) = gpu.extract::<bool>() {
        return Ok(if on { spsr::Gpu::On } else { spsr::Gpu::Off });
    }
    let shown = gpu.repr().map_or_else(|_| "?".into(), |r| r.to_string());
    match gpu.extract::<String>() {
        Ok(s) => match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(spsr::Gpu::Auto),
            "on" => Ok(spsr::Gpu::On),
            "off" => Ok(spsr::Gpu::Off),
            _ => Err(invalid("gpu", shown, expected)),
        },
        Err(_) => Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "gpu must be {expected}, not {shown}"
        ))),
    }
}

/// `depth=` and `width=` as the library's depth and [`Resolution`]: a width, `"auto"` (in
/// any case), an integer (returned as given, for [`int_arg`]), or None (the library's depth).
/// A depth and a width together are refused, as on the command line; another string is a
/// bad value (`ValueError`), another type a `TypeError`.
fn resolution_arg(depth: &Bound<'_, PyAny>, width: Option<f64>) -> PyResult<(i64, Resolution)> {
    let default = i64::from(Params::default().depth);
    let expected = format!("an integer from 1 to {}, or 'auto'", spsr::MAX_DEPTH);
    let shown = || depth.repr().map_or_else(|_| "?".into(), |r| r.to_string());
    if let Some(w) = width {
        if !depth.is_none() {
            return Err(value_error(format!(
                "depth={} and width={w} cannot be used together: a width sets the depth (the \
                 smallest whose cells are no wider); give one",
                shown()
            )));
        }
        return Ok((default, Resolution::Width(w)));
    }
    if depth.is_none() {
        return Ok((default, Resolution::Depth));
    }
    if let Ok(s) = depth.extract::<String>() {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok((default, Resolution::Auto));
        }
        return Err(invalid("depth", shown(), &expected));
    }
    match depth.extract::<i64>() {
        Ok(d) => Ok((d, Resolution::Depth)),
        // Another type, as for the other keywords: a TypeError.
        Err(_) => Err(PyTypeError::new_err(format!(
            "depth must be an integer or 'auto', got {}",
            depth
                .get_type()
                .name()
                .map_or_else(|_| "?".into(), |n| n.to_string())
        ))),
    }
}

/// `grid_res=` as the library's `u32`: a negative value becomes 0, which the library refuses
/// as too small ([`shown_as_given`] shows the value given); one beyond `u32` is refused here.
fn grid_res_arg(res: Option<i64>) -> PyResult<Option<u32>> {
    match res {
        None => Ok(None),
        Some(r) => match u32::try_from(r.max(0)) {
            Ok(r) => Ok(Some(r)),
            Err(_) => Err(invalid(
                "grid_res",
                r,
                "a grid that fits in memory (R³ float32 values)",
            )),
        },
    }
}

/// An integer keyword as the library's `u32`. A value that type cannot hold (a negative
/// one) becomes `u32::MAX`, which every such field rejects; [`shown_as_given`] then puts the
/// value given back into the message.
pub fn int_arg(v: i64) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// `e` showing the values the caller gave, for the integer fields in `given` that
/// [`int_arg`] (or a similar conversion) had to replace.
pub fn shown_as_given(e: Error, given: &[(&str, Option<i64>)]) -> Error {
    match e {
        Error::InvalidParameter {
            field,
            value,
            expected,
        } => {
            let value = given
                .iter()
                .find(|(f, _)| *f == field)
                .and_then(|(_, v)| v.map(|v| v.to_string()))
                .unwrap_or(value);
            Error::InvalidParameter {
                field,
                value,
                expected,
            }
        }
        e => e,
    }
}

/// The trimming threshold: `None`, `"auto"` or a number (`keyword` is `trim` or
/// `threshold`, for the message).
pub fn threshold_arg(t: &Bound<'_, PyAny>, keyword: &str) -> PyResult<Option<Threshold>> {
    if t.is_none() {
        return Ok(None);
    }
    if let Ok(s) = t.extract::<String>() {
        if s.trim().eq_ignore_ascii_case("auto") {
            return Ok(Some(Threshold::Auto));
        }
    } else if let Ok(v) = t.extract::<f64>() {
        return Ok(Some(Threshold::Value(v as f32)));
    }
    let shown = t.repr().map_or_else(|_| "?".into(), |r| r.to_string());
    Err(invalid(
        keyword,
        shown,
        "a density value (a finite number such as 6.5) or 'auto'",
    ))
}

/// The trimming's parameters, checked by the library (`call` says which keyword the
/// threshold has).
pub fn trim_params(
    py: Python<'_>,
    threshold: Threshold,
    min_island_area: f64,
    hole_area: f64,
    call: Call,
) -> PyResult<TrimParams> {
    let params = TrimParams {
        threshold,
        min_island_area,
        hole_area,
    };
    params.validate().map_err(py_err(py, call))?;
    Ok(params)
}

fn threshold_value(py: Python<'_>, t: Threshold) -> PyResult<Bound<'_, PyAny>> {
    Ok(match t {
        Threshold::Auto => "auto".into_pyobject(py)?.into_any(),
        Threshold::Value(v) => f64::from(v).into_pyobject(py)?.into_any(),
    })
}

/// `spsr._spsr._defaults()`: the library's defaults (`Params`, `TrimParams`,
/// `NormalParams`, `EvalOptions`) by function and keyword, as the Python values that mean
/// them. The keyword defaults of `spsr.reconstruct`, `spsr.trim`, `spsr.estimate_normals`
/// and `spsr.eval` are tested against it.
#[pyfunction]
#[pyo3(name = "_defaults")]
pub fn defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    let trim = TrimParams::default();
    let out = PyDict::new(py);
    out.set_item("reconstruct", reconstruct_defaults(py, &trim)?)?;
    let d = PyDict::new(py);
    d.set_item("threshold", threshold_value(py, trim.threshold)?)?;
    d.set_item("min_island_area", trim.min_island_area)?;
    d.set_item("hole_area", trim.hole_area)?;
    out.set_item("trim", d)?;
    let d = PyDict::new(py);
    d.set_item("neighbours", NormalParams::default().neighbours)?;
    out.set_item("estimate_normals", d)?;
    let eval = spsr::metrics::EvalOptions::default();
    let d = PyDict::new(py);
    d.set_item("samples", eval.samples)?;
    d.set_item("seed", eval.seed)?;
    out.set_item("eval", d)?;
    out.set_item("render", crate::render::render_defaults(py)?)?;
    Ok(out)
}

fn reconstruct_defaults<'py>(py: Python<'py>, trim: &TrimParams) -> PyResult<Bound<'py, PyDict>> {
    let p = Params::default();
    let d = PyDict::new(py);
    d.set_item("depth", p.depth)?;
    // `Resolution::Depth`: no width (a width is `Resolution::Width`).
    let width = match p.resolution {
        Resolution::Width(w) => Some(w),
        _ => None,
    };
    d.set_item("width", width)?;
    d.set_item("grid_res", p.grid_res)?;
    d.set_item("full_depth", p.full_depth)?;
    d.set_item("samples_per_node", p.samples_per_node)?;
    d.set_item(
        "noise",
        match p.noise {
            spsr::Noise::Adaptive => "adaptive",
            spsr::Noise::Off => "off",
        },
    )?;
    d.set_item("keep_outliers", p.keep_outliers)?;
    d.set_item("keep_normals", p.keep_normals)?;
    d.set_item("point_weight", p.point_weight)?;
    d.set_item("degree", p.degree.get())?;
    d.set_item("boundary", boundary_name(p.boundary))?;
    d.set_item("scale", p.scale)?;
    d.set_item("iters", p.iters)?;
    d.set_item("solver", p.solver.name())?;
    d.set_item("cycles", p.cycles)?;
    // The Python spelling: False for the CPU (the library's default).
    d.set_item(
        "gpu",
        match p.gpu {
            spsr::Gpu::Off => false.into_pyobject(py)?.to_owned().into_any(),
            spsr::Gpu::On => true.into_pyobject(py)?.to_owned().into_any(),
            spsr::Gpu::Auto => "auto".into_pyobject(py)?.into_any(),
        },
    )?;
    d.set_item("confidence", p.weights == PointWeights::NormalLength)?;
    let property = match &p.weights {
        PointWeights::Property(name) => Some(name.as_str()),
        _ => None,
    };
    d.set_item("confidence_property", property)?;
    d.set_item("density", p.density)?;
    d.set_item("linear_fit", p.linear_fit)?;
    d.set_item("max_memory", p.max_memory)?;
    d.set_item("two_level_splat", p.two_level_splat)?;
    d.set_item("attributes", p.attributes)?;
    d.set_item("data_pull", p.data_pull)?;
    d.set_item("vertex_normals", p.normals)?;
    // No trimming unless asked (`spsr::reconstruct`; `reconstruct_and_trim` is the opt-in).
    d.set_item("trim", py.None())?;
    d.set_item("min_island_area", trim.min_island_area)?;
    d.set_item("hole_area", trim.hole_area)?;
    Ok(d)
}
