//! Stage 1 (ALGORITHM.md §3.1, §3.2, §3.4): filter the points, weigh them, find the bounding
//! cube and map everything into the unit cube.

use rayon::prelude::*;

use crate::attributes::{Attribute, AttributeData};
use crate::error::{FarOutliers, Warning};
use crate::params::PointWeights;
use crate::points::{is_valid, normal_length};
use crate::{Error, Params, PointCloud, Result};

/// Fewest usable points `reconstruct` accepts.
pub const MIN_POINTS: usize = 4;

/// The map between the input's frame and the unit cube: `unit = (world − origin) / width`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// The cube's lowest corner, in input units.
    pub origin: [f64; 3],
    /// The cube's side, in input units.
    pub width: f64,
}

impl Frame {
    /// A world-space point in unit-cube coordinates, clamped to the cube.
    pub fn to_unit(self, p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| ((p[a] - self.origin[a]) / self.width).clamp(0.0, 1.0))
    }

    /// A unit-cube point in world space.
    pub fn to_world(self, u: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| u[a] * self.width + self.origin[a])
    }
}

/// One usable point in the unit cube: position, unit normal and weight.
pub type UnitPoint = ([f64; 3], [f64; 3], f64);

/// The attributes carried from the points onto the mesh.
#[derive(Debug, Clone, Default)]
pub struct Carried {
    /// Name and type of each carried attribute (empty columns), in channel order.
    pub types: Vec<Attribute>,
    /// One row of `types.len()` values per usable point.
    pub values: Vec<f64>,
}

impl Carried {
    /// Values per point.
    pub fn channels(&self) -> usize {
        self.types.len()
    }
}

/// The output of [`prepare`].
#[derive(Debug, Clone)]
pub struct Prepared {
    /// The usable points in the unit cube.
    pub points: Vec<UnitPoint>,
    /// Their attributes, when carried onto the mesh.
    pub carried: Carried,
    /// The unit cube in the input's frame.
    pub frame: Frame,
    /// Points given.
    pub input_points: usize,
    /// Points left out.
    pub dropped: usize,
    /// What the user should hear about the input.
    pub warnings: Vec<Warning>,
}

/// Filters, weighs and normalises the points (stage 1).
pub fn prepare(points: &PointCloud, params: &Params) -> Result<Prepared> {
    let weight_of = weights(points, &params.weights)?;
    let Selection {
        valid,
        frame,
        warnings,
    } = select(points, params)?;
    let dropped = points.len() - valid.len();
    let unit: Vec<UnitPoint> = valid
        .par_iter()
        .map(|&i| unit_point(frame, points.positions[i], points.normals[i], weight_of(i)))
        .collect();
    Ok(Prepared {
        points: unit,
        carried: carried(points, &valid, params.attributes),
        frame,
        input_points: points.len(),
        dropped,
        warnings,
    })
}

/// The points a run uses and their bounding cube: what stage 1 decides before it maps them.
pub(crate) struct Selection {
    /// Indices of the usable points, far outliers left out unless kept.
    pub valid: Vec<usize>,
    /// Their bounding cube.
    pub frame: Frame,
    /// What the user should hear about the input.
    pub warnings: Vec<Warning>,
}

/// The usable points (§3.1), without the far outliers unless `params.keep_outliers`, and
/// their bounding cube (§3.2).
pub(crate) fn select(points: &PointCloud, params: &Params) -> Result<Selection> {
    let weight_of = weights(points, &params.weights)?;
    let valid = usable(points, &weight_of);
    let dropped = points.len() - valid.len();
    if valid.len() < MIN_POINTS {
        return Err(Error::TooFewPoints {
            usable: valid.len(),
            dropped,
            required: MIN_POINTS,
        });
    }
    let (mut frame, side) = bounding_cube(points, &valid, params.scale)?;
    let mut warnings = Vec::new();
    if dropped > 0 {
        warnings.push(Warning::DroppedPoints {
            dropped,
            total: points.len(),
        });
    }
    let mut valid = valid;
    if let Some(w) = far_outliers(points, &valid, side, params.depth) {
        if params.keep_outliers {
            warnings.push(Warning::FarOutliers(w));
        } else {
            valid.retain(|&i| !w.is_far(points.positions[i]));
            frame = bounding_cube(points, &valid, params.scale)?.0;
            warnings.push(Warning::OutliersDropped(w));
        }
    }
    Ok(Selection {
        valid,
        frame,
        warnings,
    })
}

/// A usable point in the unit cube: its position mapped by `frame`, its normal scaled to
/// unit length.
pub(crate) fn unit_point(frame: Frame, p: [f64; 3], n: [f64; 3], w: f64) -> UnitPoint {
    let len = normal_length(&n);
    (frame.to_unit(p), [n[0] / len, n[1] / len, n[2] / len], w)
}

/// The indices of the usable points (§3.1): finite positions, finite non-zero normals and a
/// finite positive weight.
pub(crate) fn usable(
    points: &PointCloud,
    weight_of: &(impl Fn(usize) -> f64 + Sync),
) -> Vec<usize> {
    (0..points.len())
        .filter(|&i| {
            is_valid(&points.positions[i], &points.normals[i]) && {
                let w = weight_of(i);
                w.is_finite() && w > 0.0
            }
        })
        .collect()
}

/// Each point's weight (§3.4); NaN where a weight property has no value.
pub(crate) fn weights<'a>(
    points: &'a PointCloud,
    how: &'a PointWeights,
) -> Result<impl Fn(usize) -> f64 + Sync + 'a> {
    let property = match how {
        PointWeights::Property(name) => Some(points.attribute(name).ok_or_else(|| {
            let have: Vec<&str> = points.attributes.iter().map(|a| a.name.as_str()).collect();
            Error::invalid(
                "weights",
                format!("the property '{name}'"),
                format!(
                    "a property the points have (they have: {})",
                    if have.is_empty() {
                        "none".to_string()
                    } else {
                        have.join(", ")
                    }
                ),
            )
        })?),
        _ => None,
    };
    let by_length = *how == PointWeights::NormalLength;
    Ok(move |i: usize| -> f64 {
        match property {
            Some(a) => a.data.get(i).unwrap_or(f64::NAN),
            None if by_length => normal_length(&points.normals[i]),
            None => 1.0,
        }
    })
}

/// The bounding cube (§3.2): the bounding box's largest side times `scale`, centred on the
/// box. Also returns the box's largest side.
fn bounding_cube(points: &PointCloud, valid: &[usize], scale: f64) -> Result<(Frame, f64)> {
    let mut bounds = Bounds::default();
    for &i in valid {
        bounds.add(points.positions[i]);
    }
    bounds.cube(scale)
}

/// A bounding box, grown point by point (a slab run grows it file by file).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Bounds {
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds {
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
        }
    }
}

impl Bounds {
    pub fn add(&mut self, p: [f64; 3]) {
        for a in 0..3 {
            self.lo[a] = self.lo[a].min(p[a]);
            self.hi[a] = self.hi[a].max(p[a]);
        }
    }

    /// The bounding cube (§3.2): the box's largest side times `scale`, centred on the box.
    /// Also returns the box's largest side.
    pub fn cube(&self, scale: f64) -> Result<(Frame, f64)> {
        let (lo, hi) = (self.lo, self.hi);
        let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        if !(side.is_finite() && side > 0.0) {
            return Err(Error::Degenerate(if side == 0.0 {
                "all usable points are identical; there is no surface to reconstruct".into()
            } else {
                "the points' extent is not finite (coordinates too large)".into()
            }));
        }
        let width = side * scale;
        let origin: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]) - 0.5 * width);
        if !(width.is_finite() && origin.iter().all(|o| o.is_finite())) {
            return Err(Error::Degenerate("the bounding cube is not finite".into()));
        }
        Ok((Frame { origin, width }, side))
    }
}

/// The attributes a cloud carries onto the mesh when `enabled`: every property with one value
/// per point, in the cloud's order (also slab mode's rule, for each tile).
pub(crate) fn carried_columns(points: &PointCloud, enabled: bool) -> Vec<&Attribute> {
    if !enabled {
        return Vec::new();
    }
    points
        .attributes
        .iter()
        .filter(|a| a.data.len() == points.len())
        .collect()
}

/// The attributes carried onto the mesh: one f64 channel per attribute, per usable point.
fn carried(points: &PointCloud, valid: &[usize], enabled: bool) -> Carried {
    let columns = carried_columns(points, enabled);
    let types = columns
        .iter()
        .map(|a| Attribute::new(a.name.clone(), AttributeData::new(a.data.scalar_type())))
        .collect();
    let values = if columns.is_empty() {
        Vec::new()
    } else {
        valid
            .iter()
            .flat_map(|&i| columns.iter().map(move |a| a.data.get(i).unwrap_or(0.0)))
            .collect()
    };
    Carried { types, values }
}

/// Fraction of points at each end of every axis left out of the robust extent.
const OUTLIER_QUANTILE: f64 = 0.001;

/// Bounding boxes larger than this many times the robust extent get a warning.
const OUTLIER_RATIO: f64 = 20.0;

/// Fewest usable points for which the outlier check is made (below, the quantiles mean
/// little).
const OUTLIER_MIN_POINTS: usize = 20;

/// A few far points that make the bounding cube much larger than the bulk of the cloud, if
/// there are such: the cube sets the finest cell size, so they silently waste depth.
fn far_outliers(
    points: &PointCloud,
    valid: &[usize],
    side: f64,
    depth: u32,
) -> Option<FarOutliers> {
    let n = valid.len();
    if n < OUTLIER_MIN_POINTS {
        return None;
    }
    // The bulk: on each axis, the range without the 0.1 % of points at either end (at least
    // one point each side).
    let k = ((n as f64 * OUTLIER_QUANTILE) as usize).max(1);
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    for a in 0..3 {
        let mut c: Vec<f64> = valid.iter().map(|&i| points.positions[i][a]).collect();
        lo[a] = *c.select_nth_unstable_by(k, f64::total_cmp).1;
        hi[a] = *c.select_nth_unstable_by(n - 1 - k, f64::total_cmp).1;
    }
    let robust = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    // Positions are finite here, so `robust` is a finite number, not NaN.
    if robust <= 0.0 || side <= OUTLIER_RATIO * robust {
        return None;
    }
    let far = valid
        .iter()
        .filter(|&&i| FarOutliers::far_from(lo, hi, robust, points.positions[i]))
        .count();
    let lost = (side / robust).log2().floor() as u32;
    let deeper = depth + lost;
    Some(FarOutliers {
        far,
        total: n,
        bulk_min: lo,
        bulk_max: hi,
        extent: side,
        bulk_extent: robust,
        depth,
        effective_depth: depth.saturating_sub(lost),
        compensating_depth: (deeper <= crate::MAX_DEPTH).then_some(deeper),
    })
}
