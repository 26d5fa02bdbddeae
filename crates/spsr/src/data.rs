//! Per-point attributes carried onto the mesh: colours and any other numeric property.
//!
//! This follows PoissonRecon 18's "extrapolated data field" (its `--colors` with
//! `--dataX`): every sample adds its weight `W` and its weighted values `W·a` to the node that
//! contains it at every depth, from its deepest node up to the unit cube (a degree-0 splat,
//! PoissonRecon's `DATA_DEGREE 0`). At a mesh vertex the value of an attribute is
//!
//! ```text
//!     a(v) = Σ_d X^d Σ(W·a)_d(v) / Σ_d X^d ΣW_d(v)
//! ```
//!
//! where `(…)_d(v)` are the sums of the node of depth `d` containing `v` and `X` is the pull
//! factor ([`crate::Params::data_pull`], 32 by default). With a large `X` the finest node
//! near the vertex that holds samples decides its value, so colour does not bleed between
//! surfaces that are close but not touching; coarser depths only fill in where the finest
//! nodes hold nothing (for example across a hole the reconstruction closed).

use crate::octree::{NodeRank, Octree, DEPTH_OFFSET, NONE};

/// The sums of one tree level: which nodes hold samples, and per such node `K + 1` numbers
/// (`ΣW`, then `Σ W·a_k`).
#[derive(Debug)]
struct LevelData {
    members: NodeRank,
    sums: Vec<f64>,
}

/// Attribute sums of the samples on every level of the tree.
#[derive(Debug)]
pub(crate) struct DataField {
    channels: usize,
    pull: f64,
    levels: Vec<LevelData>,
    /// The tree level whose cells locate a point in [`DataField::eval`]: the tree's deepest.
    finest: u32,
}

/// The sums of one tree level's nodes that hold samples, keyed by node: a slab's share of the
/// whole cloud's coarse levels (`crate::slabs`), which do not depend on a tree's numbering.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KeyedSums {
    /// The nodes' keys, in increasing order.
    pub keys: Vec<[u32; 3]>,
    /// Per node `K + 1` numbers (`ΣW`, then `Σ W·a_k`).
    pub sums: Vec<f64>,
}

impl KeyedSums {
    /// The slabs' sums of one level added up (equal keys summed in the order of `parts`, so
    /// that the result does not depend on anything but that order). `width` is `K + 1`.
    pub(crate) fn merge(parts: Vec<KeyedSums>, width: usize) -> KeyedSums {
        let mut rows: Vec<([u32; 3], usize, usize)> = Vec::new();
        for (p, part) in parts.iter().enumerate() {
            rows.extend(part.keys.iter().enumerate().map(|(i, &k)| (k, p, i)));
        }
        // Key, then part, then row: the sums of a key are added in slab order.
        rows.sort_unstable();
        let mut out = KeyedSums::default();
        for (k, p, i) in rows {
            let row = &parts[p].sums[i * width..(i + 1) * width];
            if out.keys.last() == Some(&k) {
                let at = out.sums.len() - width;
                for (m, v) in out.sums[at..].iter_mut().zip(row) {
                    *m += v;
                }
            } else {
                out.keys.push(k);
                out.sums.extend_from_slice(row);
            }
        }
        out
    }
}

impl DataField {
    /// Sums the samples' attributes up the tree. `leaf_of[s]` is the deepest node `(level,
    /// node)` containing sample `s`, `weights[s]` its weight and `values[s·K..(s+1)·K]` its
    /// (weighted mean) attribute values.
    pub(crate) fn build(
        tree: &Octree,
        leaf_of: &[(u32, u32)],
        weights: &[f64],
        values: &[f64],
        channels: usize,
        pull: f64,
    ) -> Self {
        let width = channels + 1;
        let nlev = tree.levels.len();
        // Entries waiting at each level: node and its sums (flat, `width` numbers each).
        let mut pending: Vec<(Vec<u32>, Vec<f64>)> =
            (0..nlev).map(|_| Default::default()).collect();
        for (s, &(t, n)) in leaf_of.iter().enumerate() {
            let w = weights[s];
            let (nodes, sums) = &mut pending[t as usize];
            nodes.push(n);
            sums.push(w);
            sums.extend(
                values[s * channels..(s + 1) * channels]
                    .iter()
                    .map(|a| w * a),
            );
        }
        let mut levels: Vec<LevelData> = (0..nlev)
            .map(|_| LevelData {
                members: NodeRank::default(),
                sums: Vec::new(),
            })
            .collect();
        for t in (DEPTH_OFFSET as usize..nlev).rev() {
            let (nodes, sums) = std::mem::take(&mut pending[t]);
            let mut order: Vec<u32> = (0..nodes.len() as u32).collect();
            order.sort_by_key(|&k| (nodes[k as usize], k));
            let mut members: Vec<u32> = Vec::new();
            let mut merged: Vec<f64> = Vec::new();
            for &k in &order {
                let k = k as usize;
                let row = &sums[k * width..(k + 1) * width];
                if members.last() == Some(&nodes[k]) {
                    let at = merged.len() - width;
                    for (m, v) in merged[at..].iter_mut().zip(row) {
                        *m += v;
                    }
                } else {
                    members.push(nodes[k]);
                    merged.extend_from_slice(row);
                }
            }
            if t > DEPTH_OFFSET as usize {
                let (up_nodes, up_sums) = &mut pending[t - 1];
                for (i, &n) in members.iter().enumerate() {
                    up_nodes.push(tree.parent(t as u32, n));
                    up_sums.extend_from_slice(&merged[i * width..(i + 1) * width]);
                }
            }
            levels[t] = LevelData {
                members: NodeRank::new(tree.levels[t].len(), members.iter().copied()),
                sums: merged,
            };
        }
        Self {
            channels,
            pull,
            levels,
            finest: tree.depth_count() - 1,
        }
    }

    /// Number of attribute channels.
    pub(crate) fn channels(&self) -> usize {
        self.channels
    }

    /// The sums of tree levels `DEPTH_OFFSET..=last` (index 0 is the unit cube), keyed.
    pub(crate) fn keyed_levels(&self, tree: &Octree, last: u32) -> Vec<KeyedSums> {
        let width = self.channels + 1;
        (DEPTH_OFFSET..=last.min(self.levels.len() as u32 - 1))
            .map(|t| {
                let level = &self.levels[t as usize];
                let nodes = &tree.levels[t as usize];
                let mut rows: Vec<([u32; 3], usize)> = (0..nodes.len() as u32)
                    .filter_map(|n| {
                        let r = level.members.get(n);
                        (r != NONE).then(|| (nodes.key(n), r as usize))
                    })
                    .collect();
                rows.sort_unstable();
                KeyedSums {
                    keys: rows.iter().map(|r| r.0).collect(),
                    sums: rows
                        .iter()
                        .flat_map(|&(_, r)| level.sums[r * width..(r + 1) * width].iter().copied())
                        .collect(),
                }
            })
            .collect()
    }

    /// Replaces the sums of tree levels `DEPTH_OFFSET..DEPTH_OFFSET + coarse.len()` with
    /// `coarse` (from [`DataField::keyed_levels`], e.g. the whole cloud's, merged from the
    /// slabs'); keys that `tree` lacks are left out. Returns how many were.
    pub(crate) fn replace_coarse(&mut self, tree: &Octree, coarse: &[KeyedSums]) -> usize {
        let width = self.channels + 1;
        let mut missing = 0;
        for (d, level) in coarse.iter().enumerate() {
            let t = DEPTH_OFFSET + d as u32;
            if t as usize >= self.levels.len() {
                missing += level.keys.len();
                continue;
            }
            let mut rows: Vec<(u32, usize)> = Vec::with_capacity(level.keys.len());
            for (i, &key) in level.keys.iter().enumerate() {
                let (reached, n) = tree.descend(key.map(u64::from), t, t);
                if reached == t {
                    rows.push((n, i));
                } else {
                    missing += 1;
                }
            }
            rows.sort_unstable();
            self.levels[t as usize] = LevelData {
                members: NodeRank::new(tree.levels[t as usize].len(), rows.iter().map(|r| r.0)),
                sums: rows
                    .iter()
                    .flat_map(|&(_, i)| level.sums[i * width..(i + 1) * width].iter().copied())
                    .collect(),
            };
        }
        missing
    }

    /// Locates points in cells of tree level `finest` (at least the tree's deepest) in
    /// [`DataField::eval`]. A slab's tree may stop short of the whole cloud's depth; locating
    /// in finer cells than the tree has pools the same nodes, so every slab can locate at the
    /// run's depth and agree with the tree in one piece.
    pub(crate) fn locate_at(&mut self, finest: u32) {
        self.finest = self.finest.max(finest);
    }

    /// The attribute values at unit-cube point `p` into `out` (`channels` long). At every
    /// depth, the sums of all the cells whose closure contains `p` are pooled (one cell for a
    /// point inside a cell, two or four for a mesh vertex on a cell face or edge), so a
    /// vertex sees the samples on both sides of the edge it lies on.
    pub(crate) fn eval(&self, tree: &Octree, p: [f64; 3], out: &mut [f64]) {
        let t_max = self.finest.max(tree.depth_count() - 1);
        let cells = 1i64 << (t_max - DEPTH_OFFSET);
        // Finest cells (tree coordinates) whose closure contains p: per axis the cell below,
        // and the cell above when p lies exactly on their common face.
        let mut choices = [[0u64; 2]; 3];
        let mut count = [1usize; 3];
        for a in 0..3 {
            let x = p[a] * cells as f64;
            let f = x.floor();
            let i = (f as i64).clamp(0, cells - 1);
            choices[a][0] = (i + cells) as u64;
            if x == f && i > 0 && f as i64 == i {
                choices[a][1] = (i - 1 + cells) as u64;
                count[a] = 2;
            }
        }
        let width = self.channels + 1;
        let mut acc = vec![0.0f64; width];
        // Nodes already pooled at each level (at most 8 distinct ones).
        let mut seen: Vec<[u32; 8]> = vec![[NONE; 8]; tree.levels.len()];
        for z in 0..count[2] {
            for y in 0..count[1] {
                for x in 0..count[0] {
                    let key = [choices[0][x], choices[1][y], choices[2][z]];
                    let mut n = 0u32;
                    let mut t = 0u32;
                    let mut scale = 1.0;
                    loop {
                        if t >= DEPTH_OFFSET {
                            let s = &mut seen[t as usize];
                            if !s.contains(&n) {
                                if let Some(slot) = s.iter_mut().find(|v| **v == NONE) {
                                    *slot = n;
                                }
                                let level = &self.levels[t as usize];
                                let r = level.members.get(n);
                                if r != NONE {
                                    let row =
                                        &level.sums[r as usize * width..(r as usize + 1) * width];
                                    for (a, v) in acc.iter_mut().zip(row) {
                                        *a += scale * v;
                                    }
                                }
                            }
                            scale *= self.pull;
                        }
                        let b = tree.levels[t as usize].child(n);
                        if b == NONE || t == t_max {
                            break;
                        }
                        let shift = t_max - (t + 1);
                        let c = ((key[0] >> shift) & 1)
                            | (((key[1] >> shift) & 1) << 1)
                            | (((key[2] >> shift) & 1) << 2);
                        n = b * 8 + c as u32;
                        t += 1;
                    }
                }
            }
        }
        let w = acc[0];
        for (o, a) in out.iter_mut().zip(&acc[1..]) {
            *o = if w > 0.0 { a / w } else { 0.0 };
        }
    }
}
