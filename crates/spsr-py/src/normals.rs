//! `spsr.estimate_normals`: normals for points that have none, as `spsr normals`.

use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::normals::{Estimated, NormalParams, OrientStats, Orientation};

use crate::arrays::{rows3, rows_out};
use crate::detach::{run_detached, threads_arg};
use crate::errors::{invalid, py_err, value_error, Call};

/// A scan's first point and the sensor position, as the Python layer passes them.
type ScanOrigin = (i64, [f64; 3]);

/// Estimates and orients normals; see `spsr.estimate_normals`.
#[pyfunction]
#[pyo3(signature = (points, *, neighbours, orient, viewpoint, scan_origins, threads))]
pub fn estimate_normals<'py>(
    py: Python<'py>,
    points: Bound<'py, PyAny>,
    neighbours: Option<i64>,
    orient: Option<&str>,
    viewpoint: Option<[f64; 3]>,
    scan_origins: Option<Vec<ScanOrigin>>,
    threads: Option<i64>,
) -> PyResult<Bound<'py, PyDict>> {
    let neighbours = match neighbours {
        None => None,
        Some(k) if k >= 3 => Some(usize::try_from(k).unwrap_or(usize::MAX)),
        Some(k) => {
            return Err(invalid(
                "neighbours",
                k,
                "at least 3 (a plane needs three points)",
            ))
        }
    };
    let scans = scan_origins.unwrap_or_default();
    let mode = orient.unwrap_or(if viewpoint.is_some() || !scans.is_empty() {
        "viewpoint"
    } else {
        "mst"
    });
    let how = orientation(mode, viewpoint, scans)?;
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
    .map_err(py_err(py, Call::Normals))?;
    info_out(py, mode, estimated, stats)
}

/// The orientation `orient=` names (`None` for `"none"`).
fn orientation(
    mode: &str,
    viewpoint: Option<[f64; 3]>,
    scans: Vec<ScanOrigin>,
) -> PyResult<Option<Orientation>> {
    if viewpoint.is_some() && mode != "viewpoint" {
        return Err(value_error(
            "viewpoint= is only used by orient=\"viewpoint\"; leave out one of them",
        ));
    }
    Ok(match mode {
        "mst" => Some(Orientation::mst()),
        "global" => Some(Orientation::global()),
        "none" => None,
        "viewpoint" => {
            Some(match viewpoint {
                Some(v) => Orientation::Viewpoint(v),
                None if !scans.is_empty() => scan_origins(scans)?,
                None => return Err(value_error(
                    "orient=\"viewpoint\" needs viewpoint=(x, y, z): no scan positions are known",
                )),
            })
        }
        other => {
            return Err(invalid(
                "orient",
                format!("'{other}'"),
                "one of 'mst', 'viewpoint', 'global', 'none'",
            ))
        }
    })
}

fn scan_origins(scans: Vec<ScanOrigin>) -> PyResult<Orientation> {
    let mut list = Vec::with_capacity(scans.len());
    for (i, (first, origin)) in scans.into_iter().enumerate() {
        let first = usize::try_from(first)
            .map_err(|_| value_error(format!("scan_origins: {first} is not a point index")))?;
        // Points before the first scan are counted with it, as the CLI does.
        list.push((if i == 0 { 0 } else { first }, origin));
    }
    Ok(Orientation::ScanOrigins(list))
}

/// The normals and the figures of `return_info=True`.
fn info_out<'py>(
    py: Python<'py>,
    mode: &str,
    estimated: Estimated,
    stats: Option<OrientStats>,
) -> PyResult<Bound<'py, PyDict>> {
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
