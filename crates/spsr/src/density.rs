//! Samples and the sampling-density estimator (ALGORITHM.md §3.3 and §3.5).
//!
//! Points falling into the same finest cell are merged into one *sample* (§3.3). The density
//! estimator splats every occupied cell of each depth `0..=K` into the 3×3×3 cells around it
//! with quadratic B-spline weights; the splatted value at a position, `spn`, is the number of
//! samples per node there, which gives each sample its splat depth and its area weight.

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::shared_slice::SharedSlice;

/// A sample: the weighted merge of the points in one finest cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Weighted mean position, unit-cube coordinates.
    pub pos: [f64; 3],
    /// Total weight `W_s`.
    pub weight: f64,
    /// Unit normal direction of the summed normals; zero when they cancel.
    pub normal: [f64; 3],
}

/// Cell of depth `d` containing unit-cube point `p` (clamped to the cube).
#[inline]
pub fn cell_of(p: [f64; 3], d: u32) -> [i64; 3] {
    let n = (1i64 << d) as f64;
    std::array::from_fn(|a| ((p[a] * n).floor() as i64).clamp(0, (1i64 << d) - 1))
}

/// Quadratic B-spline weights of the cells `o−1, o, o+1` at relative position `t ∈ [0,1]`.
#[inline]
pub fn quadratic_weights(t: f64) -> [f64; 3] {
    [0.5 * (1.0 - t) * (1.0 - t), 0.5 + t - t * t, 0.5 * t * t]
}

/// Calls `f(offset, weight)` for the 3×3×3 cells around a cell, with the product of the
/// quadratic B-spline weights at relative position `t ∈ [0,1]^3` (offsets in `{−1,0,1}^3`).
#[inline]
pub fn for_each_quadratic_neighbour(t: [f64; 3], mut f: impl FnMut([i64; 3], f64)) {
    let wx = quadratic_weights(t[0]);
    let wy = quadratic_weights(t[1]);
    let wz = quadratic_weights(t[2]);
    for (k, wzk) in wz.iter().enumerate() {
        for (j, wyj) in wy.iter().enumerate() {
            for (i, wxi) in wx.iter().enumerate() {
                f([i as i64 - 1, j as i64 - 1, k as i64 - 1], wxi * wyj * wzk);
            }
        }
    }
}

/// The normaliser σ that makes a planar layer of one sample per cell read as one sample
/// per node: the mean of `1 / Σ β_j(t)²` over `t = 0.05, 0.15, …, 0.95` (ALGORITHM.md §3.5).
pub fn sigma() -> f64 {
    (0..10)
        .map(|i| {
            let w = quadratic_weights(0.05 + 0.1 * f64::from(i));
            1.0 / (w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        })
        .sum::<f64>()
        / 10.0
}

#[inline]
fn pack(c: [i64; 3]) -> u64 {
    // Offsets run from -1; shift by one so they are non-negative.
    ((c[0] + 1) as u64) | (((c[1] + 1) as u64) << 21) | (((c[2] + 1) as u64) << 42)
}

/// Merges points into samples, one per occupied cell at `depth` (ALGORITHM.md §3.3).
/// `points` are unit-cube positions with unit normals and weights. Samples come out in the
/// Morton order of their cells, whatever the thread count.
#[cfg(test)]
pub fn merge_samples(points: &[([f64; 3], [f64; 3], f64)], depth: u32) -> Vec<Sample> {
    merge_samples_grouped(points, depth, false).0
}

/// As [`merge_samples`]; with `groups`, also the sample each point went into (`u32::MAX`
/// for points of a cell whose total weight is not positive).
pub fn merge_samples_grouped(
    points: &[([f64; 3], [f64; 3], f64)],
    depth: u32,
    groups: bool,
) -> (Vec<Sample>, Vec<u32>) {
    let mut sample_of = if groups {
        vec![u32::MAX; points.len()]
    } else {
        Vec::new()
    };
    let mut keyed: Vec<(u64, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, (p, _, _))| (morton_cell(cell_of(*p, depth)), i as u32))
        .collect();
    keyed.par_sort_unstable();
    // The runs of equal cells, each summed in its sorted order by one task (the points are
    // gathered at random, which a single thread waited on for seconds at 20 M points).
    let starts: Vec<usize> = (0..keyed.len())
        .into_par_iter()
        .filter(|&i| i == 0 || keyed[i].0 != keyed[i - 1].0)
        .collect();
    let run = |r: usize| starts[r]..starts.get(r + 1).copied().unwrap_or(keyed.len());
    let merged: Vec<Option<Sample>> = (0..starts.len())
        .into_par_iter()
        .map(|r| merge_run(points, &keyed[run(r)]))
        .collect();
    let mut samples = Vec::with_capacity(merged.len());
    let mut index = vec![u32::MAX; merged.len()];
    for (r, sample) in merged.into_iter().enumerate() {
        if let Some(sample) = sample {
            index[r] = samples.len() as u32;
            samples.push(sample);
        }
    }
    if groups {
        let out = SharedSlice::new(&mut sample_of);
        (0..starts.len()).into_par_iter().for_each(|r| {
            for k in &keyed[run(r)] {
                // SAFETY: every point is in exactly one run, so each entry is written once.
                unsafe { out.set(k.1 as usize, index[r]) };
            }
        });
    }
    (samples, sample_of)
}

/// The sample of one run of points in one cell (`(cell key, point)` pairs), summed in the
/// run's order; `None` when its weight is not positive and finite.
fn merge_run(points: &[([f64; 3], [f64; 3], f64)], run: &[(u64, u32)]) -> Option<Sample> {
    let mut w = 0.0;
    let mut wp = [0.0; 3];
    let mut wn = [0.0; 3];
    for &(_, i) in run {
        let (p, n, pw) = points[i as usize];
        w += pw;
        for a in 0..3 {
            wp[a] += pw * p[a];
            wn[a] += pw * n[a];
        }
    }
    if w <= 0.0 || !w.is_finite() {
        return None;
    }
    let len = (wn[0] * wn[0] + wn[1] * wn[1] + wn[2] * wn[2]).sqrt();
    let normal = if len > 1e-12 * w {
        [wn[0] / len, wn[1] / len, wn[2] / len]
    } else {
        [0.0; 3]
    };
    Some(Sample {
        pos: [wp[0] / w, wp[1] / w, wp[2] / w],
        weight: w,
        normal,
    })
}

/// Morton code of a cell (the low 21 bits of each coordinate, as two's complement).
fn morton_cell(c: [i64; 3]) -> u64 {
    crate::morton::encode(c.map(|v| v as u64))
}

/// The density estimator: splatted sample weights at every depth `0..=K`.
#[derive(Debug, Default)]
pub struct Density {
    kernel_depth: u32,
    samples_per_node: f64,
    rho: Vec<FxHashMap<u64, f64>>,
}

/// An occupied cell of the estimator at some depth: the cell, `Σ w` and `Σ w·p` of the
/// samples in it.
pub type Cell = ([i64; 3], f64, [f64; 3]);

/// Where a sample sits in the hierarchy: its fractional depth and its area weight, the share
/// of its weight its screening keeps, and the finest depth its screening reaches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthAndArea {
    /// Estimated splat depth (may be fractional).
    pub depth: f64,
    /// Area of surface represented by one unit of sample weight, unit-cube units.
    pub area: f64,
    /// The factor on the sample's weight in the screening term, the iso-value and the
    /// attributes' field: 1, except for samples the noise stage finds noisy
    /// (`pipeline::noise`).
    pub screen: f64,
    /// The finest depth whose screening clusters take the sample ([`ALL_DEPTHS`]: every
    /// depth). Only a sample the noise stage finds noisy is held coarser: finer clusters
    /// would average too few samples to hold its noise (`pipeline::noise`, *Screening
    /// depth*).
    pub screen_depth: u32,
}

/// [`DepthAndArea::screen_depth`] of a sample screened at every depth of the tree.
pub const ALL_DEPTHS: u32 = u32::MAX;

impl DepthAndArea {
    /// Whether the noise stage held the sample's screening coarser than the tree's depth.
    pub fn screened_coarser(&self) -> bool {
        self.screen_depth != ALL_DEPTHS
    }
}

impl Density {
    /// Splats the samples at depths `0..=kernel_depth` (ALGORITHM.md §3.5).
    pub fn build(samples: &[Sample], kernel_depth: u32, samples_per_node: f64) -> Self {
        let level = kernel_cells(keyed_samples(samples, kernel_depth));
        Self {
            kernel_depth,
            samples_per_node,
            rho: splat_levels(level, kernel_depth),
        }
    }

    /// Replaces the splatted values at depths `0..rho.len()` by `rho` (from
    /// [`coarse_levels`]): a slab's estimator with the whole cloud's coarse depths, whose
    /// cells are wider than the slab's padding.
    pub(crate) fn replace_coarse(&mut self, rho: Vec<FxHashMap<u64, f64>>) {
        for (d, map) in rho.into_iter().enumerate() {
            if let Some(slot) = self.rho.get_mut(d) {
                *slot = map;
            }
        }
    }

    /// The estimator's occupied cells at unit depth `depth` (at most the kernel depth):
    /// the cell, `Σ w` and `Σ w·p`, in Morton order, summed exactly as [`Density::build`]
    /// sums them (the samples into the kernel depth's cells, then child by child).
    pub(crate) fn cells_at(samples: &[Sample], kernel_depth: u32, depth: u32) -> Vec<Cell> {
        let mut level = kernel_cells(keyed_samples(samples, kernel_depth));
        for _ in depth..kernel_depth {
            level = merge_up(level);
        }
        level
    }
    /// Samples per node around `p`, evaluated with the 3×3×3 cells around `p`'s cell at `d`.
    fn spn(&self, d: u32, p: [f64; 3]) -> f64 {
        let c = cell_of(p, d);
        let h = (1i64 << d) as f64;
        let t: [f64; 3] = std::array::from_fn(|a| (p[a] * h - c[a] as f64).clamp(0.0, 1.0));
        let map = &self.rho[d as usize];
        let mut s = 0.0;
        for_each_quadratic_neighbour(t, |o, wt| {
            if let Some(r) = map.get(&pack([c[0] + o[0], c[1] + o[1], c[2] + o[2]])) {
                s += r * wt;
            }
        });
        s
    }

    /// The estimated sampling depth and area weight at `p` (ALGORITHM.md §3.5). The query
    /// descends to the kernel depth, or to the deepest depth whose cell at `p` received
    /// density, and walks up while the density is below the target.
    pub fn query(&self, p: [f64; 3]) -> DepthAndArea {
        self.query_from(p, self.kernel_depth)
    }

    /// As [`Density::query`], starting no deeper than `max_depth`.
    pub fn query_from(&self, p: [f64; 3], max_depth: u32) -> DepthAndArea {
        self.query_for(p, max_depth, self.samples_per_node)
    }

    /// The samples per node the estimator targets (`--samples-per-node`).
    pub fn samples_per_node(&self) -> f64 {
        self.samples_per_node
    }

    /// As [`Density::query`], for `factor` times the samples per node: the depth and area
    /// weight an explicit `--samples-per-node` that much larger would give the sample (the
    /// noise stage's per-sample choice, `pipeline::noise`).
    pub fn query_scaled(&self, p: [f64; 3], factor: f64) -> DepthAndArea {
        self.query_for(p, self.kernel_depth, self.samples_per_node * factor)
    }

    /// As [`Density::query_from`], for `s` samples per node.
    fn query_for(&self, p: [f64; 3], max_depth: u32, s: f64) -> DepthAndArea {
        let top = max_depth.min(self.kernel_depth);
        let mut d = 0;
        while d < top && self.rho[d as usize + 1].contains_key(&pack(cell_of(p, d + 1))) {
            d += 1;
        }
        let width2 = |d: u32| {
            let h = 1.0 / (1i64 << d) as f64;
            h * h
        };
        let mut fine = self.spn(d, p);
        if fine >= s {
            return DepthAndArea {
                depth: f64::from(d) + 0.5 * (fine / s).log2(),
                area: width2(d) / fine,
                screen: 1.0,
                screen_depth: ALL_DEPTHS,
            };
        }
        while d > 0 {
            d -= 1;
            let coarse = self.spn(d, p);
            if coarse >= s || d == 0 {
                let depth = f64::from(d) + (coarse / s).ln() / (coarse / fine).ln();
                let depth = if depth.is_finite() {
                    depth
                } else {
                    f64::from(d)
                };
                let area = if coarse > 0.0 {
                    width2(d) / coarse
                } else {
                    width2(d)
                };
                return DepthAndArea {
                    depth,
                    area,
                    screen: 1.0,
                    screen_depth: ALL_DEPTHS,
                };
            }
            fine = coarse;
        }
        // Only reached with d == 0 from the start and too little density: far from the data.
        DepthAndArea {
            depth: 0.0,
            area: if fine > 0.0 { 1.0 / fine } else { 1.0 },
            screen: 1.0,
            screen_depth: ALL_DEPTHS,
        }
    }
}

/// Each sample with its cell at `depth` (and that cell's Morton code), `w` and `w·p`.
fn keyed_samples(samples: &[Sample], depth: u32) -> Vec<(u64, [i64; 3], f64, [f64; 3])> {
    samples
        .par_iter()
        .map(|s| {
            let c = cell_of(s.pos, depth);
            (
                morton_cell(c),
                c,
                s.weight,
                [
                    s.weight * s.pos[0],
                    s.weight * s.pos[1],
                    s.weight * s.pos[2],
                ],
            )
        })
        .collect()
}

/// The occupied cells of `(Morton code, cell, w, w·p)` entries in the order of the samples
/// (or finer cells) they come from: `Σ w` and `Σ w·p` per cell, in Morton order. The sort is
/// stable, so each cell's sums run in the entries' order.
fn kernel_cells(mut cells: Vec<(u64, [i64; 3], f64, [f64; 3])>) -> Vec<Cell> {
    cells.par_sort_by_key(|e| e.0);
    let mut level: Vec<Cell> = Vec::new();
    for (key, c, w, wp) in cells.iter().copied() {
        match level.last_mut() {
            Some(last) if morton_cell(last.0) == key => {
                last.1 += w;
                for a in 0..3 {
                    last.2[a] += wp[a];
                }
            }
            _ => level.push((c, w, wp)),
        }
    }
    level
}

/// The cells of the next coarser depth: siblings, adjacent in Morton order, summed in order.
fn merge_up(level: Vec<Cell>) -> Vec<Cell> {
    let mut up: Vec<Cell> = Vec::with_capacity(level.len() / 2);
    for (c, w, wp) in level {
        let pc = [c[0] >> 1, c[1] >> 1, c[2] >> 1];
        match up.last_mut() {
            Some(last) if last.0 == pc => {
                last.1 += w;
                for a in 0..3 {
                    last.2[a] += wp[a];
                }
            }
            _ => up.push((pc, w, wp)),
        }
    }
    up
}

/// The splatted values of depths `0..=top` from the occupied cells of depth `top`.
fn splat_levels(mut level: Vec<Cell>, top: u32) -> Vec<FxHashMap<u64, f64>> {
    let sigma = sigma();
    let mut rho: Vec<FxHashMap<u64, f64>> = (0..=top).map(|_| FxHashMap::default()).collect();
    let mut d = top;
    loop {
        let h = (1i64 << d) as f64;
        let map = &mut rho[d as usize];
        for &(c, w, wp) in &level {
            let t: [f64; 3] =
                std::array::from_fn(|a| (wp[a] / w * h - c[a] as f64).clamp(0.0, 1.0));
            for_each_quadratic_neighbour(t, |o, wt| {
                let key = pack([c[0] + o[0], c[1] + o[1], c[2] + o[2]]);
                *map.entry(key).or_insert(0.0) += sigma * w * wt;
            });
        }
        if d == 0 {
            break;
        }
        level = merge_up(level);
        d -= 1;
    }
    rho
}

/// The whole cloud's splatted values at depths `0..=min(depth, kernel_depth)`, from the
/// occupied cells of unit depth `depth` of every part of the cloud (slabs), each part's in
/// Morton order and the parts' cells disjoint: what [`Density::build`] computes at those
/// depths over all the samples, bit for bit. A `depth` below the kernel depth gives cells
/// as [`Density::cells_at`] sums them; a deeper one, samples (one per finest cell), which are
/// summed into the kernel depth's cells here in Morton order of their finest cells.
pub(crate) fn coarse_levels(
    parts: Vec<Vec<Cell>>,
    depth: u32,
    kernel_depth: u32,
) -> Vec<FxHashMap<u64, f64>> {
    let mut all: Vec<Cell> = parts.into_iter().flatten().collect();
    all.par_sort_by_key(|e| morton_cell(e.0));
    if depth > kernel_depth {
        let shift = depth - kernel_depth;
        // Each entry is one sample: its cell at `depth` (whose ancestor is the sample's
        // kernel cell, as `cell_of` gives it), w and w·p.
        let level = kernel_cells(
            all.into_iter()
                .map(|(c, w, wp)| {
                    let k = c.map(|x| x >> shift);
                    (morton_cell(k), k, w, wp)
                })
                .collect(),
        );
        splat_levels(level, kernel_depth)
    } else {
        splat_levels(all, depth)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigma_matches_the_specification() {
        assert!((sigma() - 1.82469).abs() < 1e-4, "{}", sigma());
    }

    #[test]
    fn quadratic_weights_are_a_partition_of_unity() {
        for i in 0..=20 {
            let w = quadratic_weights(f64::from(i) / 20.0);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn a_planar_layer_of_one_sample_per_cell_reads_one_sample_per_node() {
        // One sample per depth-K cell on the plane z = 0.5 + small offset.
        let k = 6u32;
        let n = 1 << k;
        let h = 1.0 / f64::from(n);
        let mut samples = Vec::new();
        for j in 8..n - 8 {
            for i in 8..n - 8 {
                samples.push(Sample {
                    pos: [
                        (f64::from(i) + 0.37) * h,
                        (f64::from(j) + 0.61) * h,
                        0.5 + 0.3 * h,
                    ],
                    weight: 1.0,
                    normal: [0.0, 0.0, 1.0],
                });
            }
        }
        let s = 1.5;
        let density = Density::build(&samples, k, s);
        let q = density.query([0.5 + 0.37 * h, 0.5 + 0.61 * h, 0.5 + 0.3 * h]);
        let spn = (h * h) / q.area;
        assert!((spn - 1.0).abs() < 0.1, "spn = {spn}");
        // depth ≈ K − ½ log2(S) (interpolated between levels).
        let expect = f64::from(k) - 0.5 * s.log2();
        assert!(
            (q.depth - expect).abs() < 0.35,
            "depth {} vs {expect}",
            q.depth
        );
    }

    #[test]
    fn duplicates_merge_into_one_sample() {
        let pts = vec![
            ([0.5, 0.5, 0.5], [0.0, 0.0, 1.0], 1.0),
            ([0.5, 0.5, 0.5], [0.0, 0.0, 1.0], 1.0),
            ([0.5, 0.5, 0.5], [0.0, 0.0, -1.0], 1.0),
            ([0.1, 0.5, 0.5], [1.0, 0.0, 0.0], 2.0),
        ];
        let s = merge_samples(&pts, 8);
        assert_eq!(s.len(), 2);
        let total: f64 = s.iter().map(|s| s.weight).sum();
        assert_eq!(total, 5.0);
        let centre = s.iter().find(|s| s.weight == 3.0).unwrap();
        assert_eq!(centre.normal, [0.0, 0.0, 1.0]);
    }
}
