//! k nearest neighbours of every point, on an immutable k-d tree (the `kiddo` crate).
//!
//! Points with a non-finite coordinate are left out of the tree: they are nobody's neighbour
//! and have no neighbours themselves.

use std::num::NonZero;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use crate::morton::BoxKeys;

/// Marks an empty slot of a neighbour list.
pub(crate) const NONE: u32 = u32::MAX;

/// Points per k-d tree leaf (kiddo's default bucket size).
const BUCKET: usize = 32;

/// A k-d tree over the finite points of a cloud, answering queries in the cloud's indices.
pub(crate) struct Tree {
    tree: ImmutableKdTree<f64, u32, 3, BUCKET>,
    /// Cloud index of each tree item, in Morton (Z-curve) order of the points.
    index: Vec<u32>,
}

/// The points `keep` (indices into `positions`) sorted along a Z-order curve of their bounding
/// box, ties by index: neighbouring queries then visit the same parts of the tree, which is
/// several times faster on large clouds stored in random order.
fn morton_order(positions: &[[f64; 3]], mut keep: Vec<u32>) -> Vec<u32> {
    let keys = BoxKeys::around(keep.iter().map(|&i| positions[i as usize]));
    let mut keyed: Vec<(u64, u32)> = keep
        .par_iter()
        .map(|&i| (keys.key(positions[i as usize]), i))
        .collect();
    keyed.par_sort_unstable();
    keep.clear();
    keep.extend(keyed.iter().map(|e| e.1));
    keep
}

impl Tree {
    /// A tree over the points `keep` selects (indices into `positions`).
    pub fn new(positions: &[[f64; 3]], keep: Vec<u32>) -> Self {
        let index = morton_order(positions, keep);
        let pts: Vec<[f64; 3]> = index.iter().map(|&i| positions[i as usize]).collect();
        Self {
            tree: ImmutableKdTree::new_from_slice(&pts),
            index,
        }
    }

    /// The points of the tree, in an order that keeps consecutive points close in space
    /// (query in this order for speed).
    pub fn points(&self) -> &[u32] {
        &self.index
    }

    /// Number of points in the tree.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Up to `n` nearest points of `q` as (cloud index, squared distance), nearest first;
    /// equal distances are ordered by index so the result is fully determined.
    pub fn nearest(&self, q: [f64; 3], n: usize, out: &mut Vec<(u32, f64)>) {
        out.clear();
        let Some(n) = NonZero::new(n.min(self.len())) else {
            return;
        };
        // Unsorted results come from a binary heap, which is faster than kiddo's sorted
        // vector for these sizes; they are sorted below anyway.
        let found = self
            .tree
            .nearest_n_within::<SquaredEuclidean>(&q, f64::INFINITY, n, false);
        for r in found {
            out.push((self.index[r.item as usize], r.distance));
        }
        out.sort_unstable_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    }
}

/// The `k` nearest other points of every point, in a flat array (`k` slots per point,
/// nearest first, [`NONE`] where a point has fewer neighbours).
pub(crate) struct Neighbours {
    /// Slots per point.
    pub k: usize,
    /// Neighbour indices, `k` per point.
    pub idx: Vec<u32>,
    /// Distance to the farthest neighbour found (0 when none).
    pub radius: Vec<f64>,
}

impl Neighbours {
    /// The neighbours of point `i`.
    pub fn of(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        self.idx[i * self.k..(i + 1) * self.k]
            .iter()
            .take_while(|&&j| j != NONE)
            .map(|&j| j as usize)
    }
}

/// The `k` nearest neighbours of every finite point (the point itself excluded; coincident
/// duplicates count as neighbours).
pub(crate) fn k_nearest(positions: &[[f64; 3]], tree: &Tree, k: usize) -> Neighbours {
    let n = positions.len();
    let mut idx = vec![NONE; n * k];
    let mut radius = vec![0.0; n];
    if k == 0 {
        return Neighbours { k, idx, radius };
    }
    // Rows computed in the tree's spatial order, then put in place.
    let order = tree.points();
    let mut rows = vec![NONE; order.len() * k];
    let mut rad = vec![0.0; order.len()];
    rows.par_chunks_mut(k)
        .zip(rad.par_iter_mut())
        .zip(order.par_iter())
        .for_each_init(Vec::new, |buf, ((slots, r), &i)| {
            let i = i as usize;
            tree.nearest(positions[i], k + 1, buf);
            let mut m = 0;
            for &(j, d2) in buf.iter() {
                if j as usize == i || m == k {
                    continue;
                }
                slots[m] = j;
                *r = d2.sqrt();
                m += 1;
            }
        });
    for (o, &i) in order.iter().enumerate() {
        let i = i as usize;
        idx[i * k..(i + 1) * k].copy_from_slice(&rows[o * k..(o + 1) * k]);
        radius[i] = rad[o];
    }
    Neighbours { k, idx, radius }
}

/// Indices of the points whose coordinates are all finite.
pub(crate) fn finite_points(positions: &[[f64; 3]]) -> Vec<u32> {
    positions
        .iter()
        .enumerate()
        .filter(|(_, p)| p.iter().all(|c| c.is_finite()))
        .map(|(i, _)| i as u32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_are_nearest_first_symmetric_in_ties_and_skip_non_finite_points() {
        // A 1-D lattice with a duplicate and a NaN point.
        let mut pts: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 0.0, 0.0]).collect();
        pts.push([3.0, 0.0, 0.0]);
        pts.push([f64::NAN, 0.0, 0.0]);
        let tree = Tree::new(&pts, finite_points(&pts));
        assert_eq!(tree.len(), 11);
        let nb = k_nearest(&pts, &tree, 3);
        // Point 3: its duplicate (10) at 0, then 2 and 4 at distance 1, ordered by index.
        assert_eq!(nb.of(3).collect::<Vec<_>>(), vec![10, 2, 4]);
        assert_eq!(nb.radius[3], 1.0);
        assert_eq!(nb.of(0).collect::<Vec<_>>(), vec![1, 2, 3]);
        assert_eq!(nb.of(11).count(), 0);
    }
}
