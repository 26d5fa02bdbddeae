//! The plan of a slab run: the unit cube cut along x into columns (the cells of the block
//! depth), columns grouped into slabs of about equal point counts, the depth solved for the
//! whole cloud at once, the padding each slab reads beyond its own columns, and the
//! attributes the points carry onto the mesh.

use std::ops::Range;

use crate::attributes::{Attribute, AttributeData, ScalarType};
use crate::octree::{func_index, DEPTH_OFFSET};
use crate::pipeline::prepare::Frame;
use crate::Params;

/// Levels below the maximal depth that the coordinator still solves for the whole cloud: the
/// slabs solve only the finest `COARSE_BELOW` depths.
const COARSE_BELOW: u32 = 2;

/// Padding on each side of a slab, in cells of the coarse depth. The finer depths of a slab
/// are solved on its own columns plus this margin; the solution near the margin's outer edge
/// differs from the in-core one (missing neighbours), so the margin must be wide enough for
/// that difference to fade before the slab's own columns.
const PAD_CELLS: f64 = 6.0;

/// The attributes the points carry onto the mesh: each one's name and type, in channel order.
pub type AttributeSchema = Vec<(String, ScalarType)>;

/// How the cube is cut and solved.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The unit cube in the input's frame (from all tiles).
    pub frame: Frame,
    /// The unit depth of the columns (the extraction's blocks, at most the base depth).
    pub block_depth: u32,
    /// The unit depth up to which the coordinator solves the whole cloud.
    pub coarse_depth: u32,
    /// Unit-cube width each slab reads beyond its columns on either side.
    pub pad: f64,
    /// Points per column.
    pub counts: Vec<u64>,
    /// Each slab's columns; together they cover every column, in order.
    pub slabs: Vec<Range<i64>>,
    /// The attributes carried onto the mesh (name and type), one spilled value each per point.
    pub attributes: AttributeSchema,
}

impl Plan {
    /// The columns (cells of the base depth along x) of a run at `params`.
    pub fn block_depth(params: &Params) -> u32 {
        params.base_depth().max(1).min(params.depth)
    }

    /// Cuts the columns into at most `wanted` slabs of about equal point counts (fewer when
    /// fewer columns hold points).
    pub fn new(frame: Frame, params: &Params, counts: Vec<u64>, wanted: usize) -> Plan {
        let block_depth = Self::block_depth(params);
        let base = block_depth;
        let coarse_depth = params.depth.saturating_sub(COARSE_BELOW).max(base);
        let pad = PAD_CELLS / (1u64 << coarse_depth) as f64;
        let slabs = cut(&counts, wanted.max(1));
        Plan {
            frame,
            block_depth,
            coarse_depth,
            pad,
            counts,
            slabs,
            attributes: Vec::new(),
        }
    }

    /// The plan carrying `attributes` onto the mesh.
    pub fn with_attributes(self, attributes: AttributeSchema) -> Plan {
        Plan { attributes, ..self }
    }

    /// The attribute values each point and sample carries.
    pub fn channels(&self) -> usize {
        self.attributes.len()
    }

    /// The carried attributes as empty columns of their types, in channel order.
    pub fn attribute_types(&self) -> Vec<Attribute> {
        self.attributes
            .iter()
            .map(|(name, ty)| Attribute::new(name.clone(), AttributeData::new(*ty)))
            .collect()
    }

    /// Number of columns.
    pub fn columns(&self) -> usize {
        1 << self.block_depth
    }

    /// The column of a unit-cube x coordinate.
    pub fn column_of(&self, x: f64) -> i64 {
        let n = self.columns() as i64;
        ((x * n as f64).floor() as i64).clamp(0, n - 1)
    }

    /// The column of a node at tree depth `t` (at or below the block depth) with key `key`.
    pub fn column_of_node(&self, t: u32, key: [u32; 3]) -> i64 {
        let d = t - DEPTH_OFFSET;
        let i = func_index(key, d)[0];
        let n = self.columns() as i64;
        (i >> (d - self.block_depth)).clamp(0, n - 1)
    }

    /// The slab's x range in the unit cube, without padding.
    pub fn extent(&self, s: usize) -> (f64, f64) {
        let w = 1.0 / self.columns() as f64;
        let r = &self.slabs[s];
        (r.start as f64 * w, r.end as f64 * w)
    }

    /// The tree depth of the coarse solve.
    pub fn coarse_level(&self) -> u32 {
        self.coarse_depth + DEPTH_OFFSET
    }
}

/// Groups consecutive columns into at most `wanted` slabs, cutting where the running count
/// passes each `k/wanted` of the total; every slab holds points, and the first and last
/// slabs reach the cube's faces.
fn cut(counts: &[u64], wanted: usize) -> Vec<Range<i64>> {
    let total: u64 = counts.iter().sum();
    let n = counts.len() as i64;
    let mut starts = vec![0i64];
    let mut seen = 0u64;
    let mut k = 1u64;
    let mut since = 0u64;
    for (c, &count) in counts.iter().enumerate() {
        // A cut before column c when the points so far reach the next share and the slab
        // being closed holds points.
        while k < wanted as u64 && since > 0 && seen * wanted as u64 >= k * total {
            if *starts.last().expect("non-empty") < c as i64 {
                starts.push(c as i64);
                since = 0;
            }
            k += 1;
        }
        seen += count;
        since += count;
    }
    // A last slab without points joins the one before.
    if since == 0 && starts.len() > 1 {
        starts.pop();
    }
    let mut slabs: Vec<Range<i64>> = starts.windows(2).map(|w| w[0]..w[1]).collect();
    slabs.push(*starts.last().expect("non-empty")..n);
    slabs
}

#[cfg(test)]
mod tests {
    use super::cut;

    #[test]
    fn slabs_cover_the_columns_with_balanced_counts() {
        let counts = [0, 0, 10, 10, 10, 10, 10, 10, 0, 0];
        let s = cut(&counts, 3);
        assert_eq!(s, vec![0..4, 4..6, 6..10]);
        assert_eq!(cut(&counts, 1), vec![0..10]);
        // More slabs than columns with points: one slab per such column.
        let s = cut(&[0, 5, 0, 5, 0], 8);
        assert_eq!(s, vec![0..2, 2..5]);
        for s in [cut(&counts, 5), cut(&counts, 6)] {
            assert_eq!(s.first().unwrap().start, 0);
            assert_eq!(s.last().unwrap().end, 10);
            for w in s.windows(2) {
                assert_eq!(w[0].end, w[1].start);
            }
        }
    }
}
