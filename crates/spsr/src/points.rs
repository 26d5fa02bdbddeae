//! Oriented input points, and the validity filter of ALGORITHM.md §3.1.

/// An oriented point cloud: one position and one normal per point.
///
/// Normals need not be unit length; with [`crate::Params::confidence`] their length is the
/// per-point weight. Normals point **outward** (away from the solid).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions, in the input's own frame and units.
    pub positions: Vec<[f64; 3]>,
    /// Per-point normals, pointing outward.
    pub normals: Vec<[f64; 3]>,
}

impl PointCloud {
    /// Builds a cloud from positions and normals of equal length.
    pub fn new(positions: Vec<[f64; 3]>, normals: Vec<[f64; 3]>) -> crate::Result<Self> {
        if positions.len() != normals.len() {
            return Err(crate::Error::LengthMismatch {
                positions: positions.len(),
                normals: normals.len(),
            });
        }
        Ok(Self { positions, normals })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// True when the cloud holds no point.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// True when a point can be used: finite position, finite normal of non-zero length
/// (PR18 `IsValid`, ALGORITHM.md §3.1).
pub fn is_valid(position: &[f64; 3], normal: &[f64; 3]) -> bool {
    let n2 = normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2];
    position.iter().all(|c| c.is_finite()) && n2.is_finite() && n2 > 0.0
}
