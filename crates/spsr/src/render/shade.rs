//! Surface colours: the fixed palette, the colour map of per-vertex values, the pieces to
//! highlight, and the shading of a face.

use rayon::prelude::*;

use super::ColorBy;
use crate::error::Error;
use crate::mesh::Mesh;
use crate::vec3::{dot, norm};
use crate::Result;

/// Colour of the front of faces when nothing else colours them (a light blue-grey).
pub const FRONT: [f32; 3] = [0.78, 0.80, 0.84];
/// Colour of faces seen from behind (terracotta): flipped or inside surface.
pub const BACK: [f32; 3] = [0.80, 0.38, 0.25];
/// Colour of the highlighted pieces (magenta), front or back.
pub const HIGHLIGHT: [f32; 3] = [0.95, 0.10, 0.85];
/// Colour of a vertex whose value is not a number.
const NO_VALUE: [f32; 3] = [0.5, 0.5, 0.5];
/// Light that reaches a face seen edge-on; a face facing the camera gets all of it.
const AMBIENT: f32 = 0.3;

/// Viridis (matplotlib's perceptually uniform colour map, CC0), sampled at ten evenly
/// spaced points.
const VIRIDIS: [[u8; 3]; 10] = [
    [0x44, 0x01, 0x54],
    [0x48, 0x28, 0x78],
    [0x3e, 0x4a, 0x89],
    [0x31, 0x68, 0x8e],
    [0x26, 0x82, 0x8e],
    [0x1f, 0x9e, 0x89],
    [0x35, 0xb7, 0x79],
    [0x6d, 0xcd, 0x59],
    [0xb4, 0xde, 0x2c],
    [0xfd, 0xe7, 0x25],
];

/// The colour map at `t` in `[0, 1]` (clamped; NaN gives grey), as RGB in `[0, 1]`:
/// viridis, from dark purple at 0 through blue and green to yellow at 1.
pub fn colormap(t: f64) -> [f32; 3] {
    if t.is_nan() {
        return NO_VALUE;
    }
    let x = t.clamp(0.0, 1.0) * (VIRIDIS.len() - 1) as f64;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = (x - i as f64) as f32;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    std::array::from_fn(|k| ((1.0 - f) * a[k] as f32 + f * b[k] as f32) / 255.0)
}

/// The value at fraction `q` of the sorted finite `values` (nearest rank), reordering them.
fn percentile(values: &mut [f64], q: f64) -> f64 {
    let k = (q * (values.len() - 1) as f64).round() as usize;
    *values.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// The range mapped onto the colour map: the 2nd to the 98th percentile of the finite
/// values (so that a few extreme values do not wash the map out), or their whole range
/// when those coincide; `None` when no value is finite.
fn value_range(values: &[f64]) -> Option<[f64; 2]> {
    let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return None;
    }
    let (lo, hi) = (percentile(&mut finite, 0.02), percentile(&mut finite, 0.98));
    if lo < hi {
        return Some([lo, hi]);
    }
    let min = finite.iter().copied().fold(f64::INFINITY, f64::min);
    let max = finite.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    Some([min, max])
}

/// Values as positions on the colour map, 0 to 1 over their [`value_range`] (NaN where
/// there is no value); a constant maps to the middle.
fn positions(values: &[f64]) -> (Vec<f32>, Option<[f64; 2]>) {
    let range = value_range(values);
    let t = |v: f64| match range {
        Some([lo, hi]) if hi > lo => ((v - lo) / (hi - lo)) as f32,
        Some(_) if v.is_finite() => 0.5,
        _ => f32::NAN,
    };
    (values.par_iter().map(|&v| t(v)).collect(), range)
}

/// What colours the vertices.
pub(crate) enum VertexColors {
    /// Nothing: the plain [`FRONT`].
    Plain,
    /// A colour per vertex, RGB in `[0, 1]`, interpolated across faces.
    Rgb(Vec<[f32; 3]>),
    /// A position on the colour map per vertex, interpolated across faces and then mapped
    /// (so that the middle of a large face gets the colour of the middle value).
    Mapped(Vec<f32>),
}

impl VertexColors {
    /// The colour at barycentric coordinates `l` of the triangle with vertices `tri`.
    pub fn at(&self, tri: [u32; 3], l: [f32; 3]) -> [f32; 3] {
        let mix = |v: [f32; 3]| l[0] * v[0] + l[1] * v[1] + l[2] * v[2];
        match self {
            VertexColors::Plain => FRONT,
            VertexColors::Rgb(rgb) => {
                let [a, b, c] = tri.map(|i| rgb[i as usize]);
                std::array::from_fn(|k| mix([a[k], b[k], c[k]]))
            }
            VertexColors::Mapped(t) => colormap(mix(tri.map(|i| t[i as usize])) as f64),
        }
    }
}

/// Checks that a per-vertex array has one value per vertex.
fn check_len(what: &str, len: usize, mesh: &Mesh) -> Result<()> {
    let nv = mesh.vertices.len();
    if len == nv {
        Ok(())
    } else {
        Err(Error::InvalidMesh(format!(
            "{what} has {len} values for {nv} vertices"
        )))
    }
}

/// The colours of the vertices as `color` asks, and the range
/// of values mapped onto the colour map.
pub(crate) fn vertex_colors(
    mesh: &Mesh,
    color: &ColorBy,
) -> Result<(VertexColors, Option<[f64; 2]>)> {
    let mapped = |values: &[f64]| {
        let (t, range) = positions(values);
        (VertexColors::Mapped(t), range)
    };
    match color {
        ColorBy::Plain => Ok((VertexColors::Plain, None)),
        ColorBy::Auto => match mesh.colors() {
            Some(c) => {
                check_len("the colour attribute", c.len(), mesh)?;
                let rgb = (0..c.len())
                    .into_par_iter()
                    .map(|i| {
                        let [r, g, b, _] = c.unit(i);
                        [r, g, b]
                    })
                    .collect();
                Ok((VertexColors::Rgb(rgb), None))
            }
            None => Ok((VertexColors::Plain, None)),
        },
        ColorBy::Density => {
            let d = mesh.density.as_ref().ok_or(Error::MissingDensity)?;
            check_len("the density", d.len(), mesh)?;
            let values: Vec<f64> = d.iter().map(|&v| v as f64).collect();
            Ok(mapped(&values))
        }
        ColorBy::Attribute(name) => {
            let a = mesh.attribute(name).ok_or_else(|| {
                let have: Vec<&str> = mesh.attributes.iter().map(|a| a.name.as_str()).collect();
                Error::invalid(
                    "color",
                    format!("the attribute '{name}'"),
                    format!(
                        "a per-vertex attribute the mesh has (it has: {})",
                        if have.is_empty() {
                            "none".to_string()
                        } else {
                            have.join(", ")
                        }
                    ),
                )
            })?;
            check_len(&format!("attribute '{}'", a.name), a.len(), mesh)?;
            let values: Vec<f64> = a.data.iter_f64().collect();
            Ok(mapped(&values))
        }
    }
}

/// Which triangles lie outside the largest piece, and the number of pieces. Pieces are
/// [`Mesh::pieces`] (triangles sharing a vertex, as [`Mesh::topology`] counts them); the
/// largest has the largest area, the first in triangle order on a tie.
pub(crate) fn minor_pieces(mesh: &Mesh) -> (Vec<bool>, usize) {
    let (piece_of, areas) = mesh.pieces();
    let mut largest = 0;
    for (p, &a) in areas.iter().enumerate() {
        if a > areas[largest] {
            largest = p;
        }
    }
    let minor = piece_of.iter().map(|&p| p as usize != largest).collect();
    (minor, areas.len())
}

/// The shaded colour of a face: `base` under a headlight looking along `forward`, with
/// [`AMBIENT`] light. `normal` is the face's (unnormalised) normal.
pub(crate) fn lit(base: [f32; 3], normal: [f64; 3], forward: [f64; 3]) -> [f32; 3] {
    let n = norm(normal);
    let cos = if n > 0.0 {
        (dot(normal, forward) / n).abs() as f32
    } else {
        1.0
    };
    let light = AMBIENT + (1.0 - AMBIENT) * cos;
    base.map(|c| c * light)
}
