//! NumPy arrays in and out: the library's types from the arrays the Python layer passes, and
//! its results as arrays (handed over without copying).
//!
//! The Python layer has already checked shapes and dtypes; the checks here repeat the
//! essentials so that misuse of the private module gives an exception, never a panic.

use numpy::ndarray::{ArrayView1, ArrayView2};
use numpy::{Element, PyArray1, PyArray2, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use spsr::attributes::{Attribute, AttributeData};
use spsr::{Mesh, PointCloud};

use crate::errors::{py_err, value_error, Call};

/// Rows of an `(N, 3)` float64 or float32 array, as the library's `[f64; 3]`s. A C-contiguous
/// float64 array is copied in one pass; other layouts and float32 are converted row by row.
pub fn rows3(array: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
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
pub fn faces3(array: &Bound<'_, PyAny>, vertices: usize) -> PyResult<Vec<[u32; 3]>> {
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

/// Named 1-D arrays as attribute columns of `n` values each.
pub fn attributes_in(list: Vec<(String, Bound<'_, PyAny>)>, n: usize) -> PyResult<Vec<Attribute>> {
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
pub type MeshArgs<'py> = (
    Bound<'py, PyAny>,
    Bound<'py, PyAny>,
    Option<Bound<'py, PyAny>>,
    Option<Bound<'py, PyAny>>,
    Vec<(String, Bound<'py, PyAny>)>,
);

/// The library's mesh from the Python layer's tuple.
pub fn mesh_in(args: MeshArgs<'_>) -> PyResult<Mesh> {
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

/// A point cloud from `(N, 3)` positions, optional normals of the same length and per-point
/// columns.
pub fn cloud_in(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    columns: Vec<(String, Bound<'_, PyAny>)>,
    call: Call,
) -> PyResult<PointCloud> {
    let positions = rows3(points, "points")?;
    let n = positions.len();
    let mut cloud = match normals {
        Some(a) => PointCloud::new(positions, rows3(a, "normals")?).map_err(py_err(py, call))?,
        None => PointCloud::from_positions(positions),
    };
    cloud.attributes = attributes_in(columns, n)?;
    Ok(cloud)
}

// Arrays out: the library's buffers handed to NumPy without copying.

pub fn rows_out<'py, T: Element>(
    py: Python<'py>,
    rows: Vec<[T; 3]>,
) -> PyResult<Bound<'py, PyAny>> {
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

pub fn attributes_out(py: Python<'_>, attributes: Vec<Attribute>) -> PyResult<Bound<'_, PyList>> {
    let list = PyList::empty(py);
    for a in attributes {
        list.append((a.name, column_out(py, a.data)))?;
    }
    Ok(list)
}

pub fn mesh_out(py: Python<'_>, mesh: Mesh) -> PyResult<Bound<'_, PyDict>> {
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
