//! k nearest neighbours of every point, on an immutable k-d tree (the `kiddo` crate).
//!
//! Points with a non-finite coordinate are left out of the tree: they are nobody's neighbour
//! and have no neighbours themselves.

use std::num::NonZero;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

/// Marks an empty slot of a neighbour list.
pub(crate) const NONE: u32 = u32::MAX;

/// Points per k-d tree leaf (kiddo's default bucket size).
const BUCKET: usize = 32;

/// A k-d tree over the finite points of a cloud, answering queries in the cloud's indices.
pub(crate) struct Tree {
    tree: ImmutableKdTree<f64, u32, 3, BUCKET>,
    /// Cloud index of each tree item.
    index: Vec<u32>,
}

impl Tree {
    /// A tree over the points `keep` selects (indices into `positions`, increasing).
    pub fn new(positions: &[[f64; 3]], keep: Vec<u32>) -> Self {
        let pts: Vec<[f64; 3]> = keep.iter().map(|&i| positions[i as usize]).collect();
        Self {
            tree: ImmutableKdTree::new_from_slice(&pts),
            index: keep,
        }
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
        for r in self.tree.nearest_n::<SquaredEuclidean>(&q, n) {
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
    if k > 0 {
        idx.par_chunks_mut(k)
            .zip(radius.par_iter_mut())
            .enumerate()
            .for_each_init(Vec::new, |buf, (i, (slots, r))| {
                let p = positions[i];
                if !p.iter().all(|c| c.is_finite()) {
                    return;
                }
                tree.nearest(p, k + 1, buf);
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
