//! `Mesh.implicit`: the solved implicit function that a reconstruction kept
//! (`keep_implicit=True`), evaluated at any points, and the grid of `grid_res=`.

use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use spsr::{Grid, ImplicitFunction};

use crate::arrays::{rows3, rows_out};
use crate::detach::{run_detached, threads_arg};

/// The implicit function of one reconstruction: its octree and coefficients, kept for
/// `Mesh.implicit` (about the run's peak memory, freed with the mesh).
#[pyclass(frozen, module = "spsr._spsr", name = "ImplicitFunction")]
pub struct Implicit(ImplicitFunction);

impl Implicit {
    pub fn new(f: ImplicitFunction) -> Implicit {
        Implicit(f)
    }
}

#[pymethods]
impl Implicit {
    /// `γ − χ` at `points` ((N, 3), input units; negative inside), and with `gradients` its
    /// gradient ((N, 3), per input unit, pointing outward) as a tuple. A point with a
    /// non-finite coordinate gets NaN.
    #[pyo3(signature = (points, gradients, threads=None))]
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        points: Bound<'py, PyAny>,
        gradients: bool,
        threads: Option<i64>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let threads = threads_arg(threads)?;
        let mut points = rows3(&points, "points")?;
        // The library clamps points outside the cube to it; a NaN has no nearest point.
        let finite: Vec<bool> = points
            .iter()
            .map(|p| p.iter().all(|c| c.is_finite()))
            .collect();
        let (corner, _) = self.0.cube();
        for (p, ok) in points.iter_mut().zip(&finite) {
            if !ok {
                *p = corner;
            }
        }
        let f = &self.0;
        let (mut values, mut grads) = run_detached(py, threads, move |_| {
            if gradients {
                let (v, g) = f.values_and_gradients(&points);
                (v, Some(g))
            } else {
                (f.values(&points), None)
            }
        })?;
        for (k, ok) in finite.iter().enumerate() {
            if !ok {
                values[k] = f64::NAN;
                if let Some(g) = &mut grads {
                    g[k] = [f64::NAN; 3];
                }
            }
        }
        let values = PyArray1::from_vec(py, values).into_any();
        match grads {
            None => Ok(values),
            Some(g) => Ok((values, rows_out(py, g)?).into_pyobject(py)?.into_any()),
        }
    }

    /// The iso-value γ.
    #[getter]
    fn iso_value(&self) -> f64 {
        self.0.iso_value()
    }

    /// The bounding cube: its lowest corner and its side, in input units.
    #[getter]
    fn cube(&self) -> ([f64; 3], f64) {
        self.0.cube()
    }
}

/// `grid_res=`'s grid as a dict: `values` (float32, (R, R, R), indexed x, y, z), `origin`
/// (float64, (3,)) and `spacing`.
pub fn grid_out(py: Python<'_>, g: Grid) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    let r = g.res;
    let values = PyArray1::from_vec(py, g.values).reshape([r, r, r])?;
    d.set_item("values", values)?;
    d.set_item("origin", PyArray1::from_vec(py, g.origin.to_vec()))?;
    d.set_item("spacing", g.spacing)?;
    Ok(d)
}
