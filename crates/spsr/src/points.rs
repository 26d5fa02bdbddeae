//! Input points, and the validity filter of ALGORITHM.md §3.1.

use crate::attributes::{self, Attribute, Colors};

/// A point cloud: positions, normals when the source has them, and any other per-point
/// properties as typed [`Attribute`]s.
///
/// Normals need not be unit length; with [`crate::Params::confidence`] their length is the
/// per-point weight. Normals point **outward** (away from the solid). The reconstruction
/// needs normals: a cloud without them ([`PointCloud::has_normals`] false) must get them
/// first.
///
/// Invalid points (non-finite coordinates, zero normals) may be present: readers keep them
/// so that the cloud matches its file point for point; the reconstruction filters them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions, in the input's own frame and units.
    pub positions: Vec<[f64; 3]>,
    /// Per-point normals, pointing outward; **empty** when the source has no normals,
    /// otherwise exactly one per position.
    pub normals: Vec<[f64; 3]>,
    /// Other per-point properties (colours, intensity, confidence, ...), each with one value
    /// per position, in the order of the source file.
    pub attributes: Vec<Attribute>,
    /// Where the scanner stood for each scan, for files that record it (E57 scan poses,
    /// a PCD `VIEWPOINT`); empty otherwise. Sorted by `first_point`.
    pub scan_origins: Vec<ScanOrigin>,
}

/// The sensor position of one scan within a [`PointCloud`]: points
/// `first_point..next.first_point` (or to the end, for the last scan) were seen from
/// `origin`, in the cloud's frame. Useful to orient normals towards the scanner.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ScanOrigin {
    /// Index of the scan's first point.
    pub first_point: usize,
    /// Sensor position in the cloud's frame (the translation of the scan's pose).
    pub origin: [f64; 3],
}

impl PointCloud {
    /// Appends another cloud's points (a tile of the same scan): both must have normals, or
    /// neither, and the same attributes (names and types, in order). The other cloud's scan
    /// origins are dropped. The error says what differs.
    pub fn append(&mut self, other: PointCloud) -> std::result::Result<(), String> {
        if self.normals.is_empty() != other.normals.is_empty() {
            return Err("one tile has normals and another has none".into());
        }
        let names = |c: &PointCloud| -> Vec<String> {
            c.attributes
                .iter()
                .map(|a| format!("{} ({:?})", a.name, a.data.scalar_type()))
                .collect()
        };
        if names(self) != names(&other) {
            return Err(format!(
                "the tiles' properties differ: [{}] here, [{}] before",
                names(&other).join(", "),
                names(self).join(", ")
            ));
        }
        self.positions.extend(other.positions);
        self.normals.extend(other.normals);
        for (a, b) in self.attributes.iter_mut().zip(other.attributes) {
            a.data.append(b.data);
        }
        Ok(())
    }

    /// Builds a cloud from positions and normals of equal length.
    pub fn new(positions: Vec<[f64; 3]>, normals: Vec<[f64; 3]>) -> crate::Result<Self> {
        if positions.len() != normals.len() {
            return Err(crate::Error::LengthMismatch {
                positions: positions.len(),
                normals: normals.len(),
            });
        }
        Ok(Self {
            positions,
            normals,
            ..Self::default()
        })
    }

    /// Builds a cloud of positions without normals.
    pub fn from_positions(positions: Vec<[f64; 3]>) -> Self {
        Self {
            positions,
            ..Self::default()
        }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when the cloud holds no point.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// True when every point has a normal (`normals` is not empty and as long as
    /// `positions`). An empty cloud has no normals.
    pub fn has_normals(&self) -> bool {
        !self.normals.is_empty() && self.normals.len() == self.positions.len()
    }

    /// The attribute called `name` (ASCII case ignored), if any.
    pub fn attribute(&self, name: &str) -> Option<&Attribute> {
        attributes::find(&self.attributes, name)
    }

    /// The colour channels, if the cloud has them (see [`attributes::find_colors`]).
    pub fn colors(&self) -> Option<Colors<'_>> {
        attributes::find_colors(&self.attributes)
    }

    /// The first attribute found under one of `names`, tried in order: e.g.
    /// `cloud.find_scalar(spsr::attributes::CONFIDENCE_NAMES)` or
    /// `cloud.find_scalar(&["intensity"])`.
    pub fn find_scalar(&self, names: &[&str]) -> Option<&Attribute> {
        attributes::find_any(&self.attributes, names)
    }
}

/// True when a point can be used: finite position, finite normal of non-zero length
/// (PR18 `IsValid`, ALGORITHM.md §3.1). The length is computed without overflow or
/// underflow ([`normal_length`]), so normals of any finite non-zero length count.
pub fn is_valid(position: &[f64; 3], normal: &[f64; 3]) -> bool {
    let len = normal_length(normal);
    position.iter().all(|c| c.is_finite()) && len.is_finite() && len > 0.0
}

/// The Euclidean length of a vector, scaled so that the squares neither overflow (lengths
/// near `f64::MAX`) nor underflow (lengths near `f64::MIN_POSITIVE`); NaN or infinite when a
/// component is.
pub fn normal_length(v: &[f64; 3]) -> f64 {
    let m = v[0].abs().max(v[1].abs()).max(v[2].abs());
    if !(m.is_finite() && m > 0.0) {
        // 0, infinity, or NaN (`max` skips NaN, so look again).
        return if v.iter().any(|c| c.is_nan()) {
            f64::NAN
        } else {
            m
        };
    }
    let (x, y, z) = (v[0] / m, v[1] / m, v[2] / m);
    m * (x * x + y * y + z * z).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_of_any_scale() {
        assert_eq!(normal_length(&[3.0, 4.0, 0.0]), 5.0);
        for s in [1e-300, 1e-170, 1e170, 1e300] {
            let l = normal_length(&[3.0 * s, 0.0, -4.0 * s]);
            assert!((l / (5.0 * s) - 1.0).abs() < 1e-15, "{s}: {l}");
            assert!(is_valid(&[0.0; 3], &[3.0 * s, 0.0, -4.0 * s]));
        }
        assert_eq!(normal_length(&[0.0; 3]), 0.0);
        assert!(normal_length(&[f64::NAN, 1.0, 0.0]).is_nan());
        assert!(normal_length(&[1.0, f64::INFINITY, 0.0]).is_infinite());
        assert!(!is_valid(&[0.0; 3], &[0.0; 3]));
        assert!(!is_valid(&[0.0; 3], &[f64::NAN, 1.0, 0.0]));
        assert!(!is_valid(&[f64::INFINITY, 0.0, 0.0], &[1.0, 0.0, 0.0]));
    }
}
