//! Library errors and warnings as Python sees them: the exception class of each kind, and
//! the wording. The library names its fields (`depth`, `weights`, `threshold`); a Python user
//! reads the keyword they passed (`depth=`, `confidence_property=`, `trim=`).

use pyo3::exceptions::{
    PyFileExistsError, PyFileNotFoundError, PyMemoryError, PyOSError, PyPermissionError,
    PyRuntimeError, PyValueError,
};
use pyo3::prelude::*;

use spsr::{Error, MemoryShortfall, Remedy, Warning};

/// The Python function an error comes from: a library field can have a different keyword in
/// each (the trimming's `threshold` is `trim=` in `reconstruct`, `threshold=` in `trim`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Call {
    Reconstruct,
    Trim,
    Normals,
    Eval,
    Files,
    Render,
}

/// The keyword of `spsr.<call>` that sets the library field `field`.
pub fn keyword(field: &str, call: Call) -> &str {
    match (field, call) {
        ("threshold", Call::Reconstruct) => "trim",
        ("weights", _) => "confidence_property",
        ("normals", Call::Reconstruct) => "vertex_normals",
        ("reference_sphere", _) => "sphere",
        (f, _) => f,
    }
}

/// "invalid parameter depth=0: expected an integer from 1 to 18". A value that is a phrase
/// rather than a value ("the property 'quality'") goes in parentheses.
pub fn invalid_message(keyword: &str, value: &str, expected: &str) -> String {
    if value.contains(char::is_whitespace) {
        format!("invalid parameter {keyword} ({value}): expected {expected}")
    } else {
        format!("invalid parameter {keyword}={value}: expected {expected}")
    }
}

/// A `ValueError` for a keyword the Python layer checks itself, worded as the library's.
pub fn invalid(keyword: &str, value: impl std::fmt::Display, expected: &str) -> PyErr {
    PyValueError::new_err(invalid_message(keyword, &value.to_string(), expected))
}

/// A plain `ValueError`.
pub fn value_error(message: impl Into<String>) -> PyErr {
    PyValueError::new_err(message.into())
}

/// The message of a library error in Python's words.
pub fn message(e: &Error, call: Call) -> String {
    match e {
        Error::InvalidParameter {
            field,
            value,
            expected,
        } => invalid_message(keyword(field, call), value, expected),
        Error::ResourceLimit(m) => shortfall(m),
        Error::MissingDensity => "the mesh has no per-vertex density; reconstruct it with \
                                  density=True to get one"
            .into(),
        e => e.to_string(),
    }
}

fn shortfall(m: &MemoryShortfall) -> String {
    m.message(&|field, value| match value {
        Some(v) => format!("{field}={v}"),
        None => field.to_string(),
    })
}

/// A warning of the reconstruction in Python's words (the text of its `RuntimeWarning`).
pub fn warning(w: &Warning) -> String {
    match w {
        Warning::FarOutliers(o) => {
            let mut s = format!(
                "{}; remove those points (crop the input to that box)",
                o.describe("depth=")
            );
            if let Some(d) = o.compensating_depth {
                s += &format!(", or use depth={d}");
            }
            s
        }
        other => other.advice(&remedy).unwrap_or_else(|| other.to_string()),
    }
}

/// A remedy a warning of `spsr.reconstruct` advises, in Python's words: `samples_per_node=5`,
/// `trim="auto"`.
fn remedy(r: Remedy) -> String {
    match r {
        Remedy::Field(field) => keyword(field, Call::Reconstruct).to_string(),
        Remedy::Set(field, value) if value.parse::<f64>().is_ok() => {
            format!("{}={value}", keyword(field, Call::Reconstruct))
        }
        Remedy::Set(field, value) => format!("{}=\"{value}\"", keyword(field, Call::Reconstruct)),
        Remedy::ReorientNormals => "re-estimate and orient the normals with \
                                    spsr.estimate_normals(points, orient=\"global\")"
            .into(),
    }
}

/// Maps a library error to the Python exception of its kind, with its message in Python's
/// words.
pub fn to_py_err(py: Python<'_>, e: Error, call: Call) -> PyErr {
    let text = message(&e, call);
    match e {
        Error::Io { source, .. } => os_error(py, &source, text),
        Error::Output { .. } => PyOSError::new_err(text),
        Error::Parse { .. } | Error::MissingNormals { .. } => file_format_error(py, text),
        Error::ResourceLimit(_) => PyMemoryError::new_err(text),
        Error::InvalidParameter { .. }
        | Error::LengthMismatch { .. }
        | Error::TooFewPoints { .. }
        | Error::Degenerate(_)
        | Error::InvalidMesh(_)
        | Error::MissingDensity => PyValueError::new_err(text),
        _ => PyRuntimeError::new_err(text),
    }
}

/// The `OSError` subclass Python itself would raise; the message stays the library's (the
/// `errno` attribute is set, `filename` is not, which would change the message).
fn os_error(py: Python<'_>, source: &std::io::Error, text: String) -> PyErr {
    use std::io::ErrorKind as K;
    let err = match source.kind() {
        K::NotFound => PyFileNotFoundError::new_err(text),
        K::PermissionDenied => PyPermissionError::new_err(text),
        K::AlreadyExists => PyFileExistsError::new_err(text),
        _ => PyOSError::new_err(text),
    };
    if let Some(code) = source.raw_os_error() {
        let _ = err.value(py).setattr("errno", code);
    }
    err
}

/// Malformed file content: `spsr.FileFormatError`, both an `OSError` (a file problem) and a
/// `ValueError` (bad data), like `io.UnsupportedOperation`.
fn file_format_error(py: Python<'_>, text: String) -> PyErr {
    match py
        .import("spsr")
        .and_then(|m| m.getattr("FileFormatError"))
        .and_then(|class| class.call1((text.clone(),)))
    {
        Ok(value) => PyErr::from_value(value),
        Err(_) => PyValueError::new_err(text),
    }
}

/// `to_py_err` for results: `.map_err(py_err(py, call))`.
pub fn py_err(py: Python<'_>, call: Call) -> impl FnOnce(Error) -> PyErr + '_ {
    move |e| to_py_err(py, e, call)
}
