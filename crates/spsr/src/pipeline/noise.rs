//! Stage 2b (issue 16, beyond ALGORITHM.md): the local noise of the samples, and the finest
//! splat depth it allows.
//!
//! The reference splats every sample at the depth where the density estimator counts `S`
//! samples per node (§3.5), whatever the noise; on a noisy scan the finest cells are then
//! smaller than the noise and the surface follows it. Here the noise is measured where it is,
//! and each sample's splat depth is lowered so that its cells are wider than the noise
//! around it: clean regions keep the density's depth (full detail), noisy ones are splatted
//! coarser, as a larger `S` would do, but only there.
//!
//! **Measuring.** The samples' moments (weight, weighted sums of `p` and `p pᵀ`) are summed
//! into the cells of every depth. For a sample, the 3×3×3 cells around it are examined from
//! the finest depth upwards; the first depth at which that neighbourhood is *flat* (its
//! covariance's smallest eigenvalue below `FLAT²` times the middle one, with at least
//! `MIN_SAMPLES` samples) gives a plane, and the sample its offset from it. Over a clean
//! surface the offsets vary smoothly (curvature, a crease nearby); noise makes them vary from
//! sample to sample. So the noise `σ` is the spread of the offsets among the samples sharing
//! a cell one depth finer, where the smooth part hardly varies. (The plane's own residual
//! √λ_min measures noise as well, and more exactly, but also the curvature and creases of
//! clean shapes: on the rocker arm and the fandisk it cost 6–18 % in accuracy.) Where no
//! depth is flat or too few samples share the cell, nothing is measured.
//!
//! **Choosing.** A sample whose density gives cells of width `h` (depth `d`) and whose noise
//! is `σ` is splatted at depth `d' = d − ½ log2(1 + r²)`, `r = (κσ/h)^p`, the same as
//! multiplying its samples per node by `1 + r²`: where the noise is well below the spacing
//! nothing changes, where it is larger the cells grow with it. `κ = 3.5` and `p = 1.3` were
//! fitted at depth 9 on the bunny with noise of 0.25 % and 0.5 % of its diagonal and the noise
//! ramp, against the accuracy on the clean rocker arm and fandisk (bench/noise/run.py). The
//! noise is smoothed first: each sample takes the median noise of the measured samples in the
//! 3×3×3 cells around it one level above the typical measuring depth, so that a chance
//! arrangement does not change the depth of a few samples alone.

use rayon::prelude::*;
use rustc_hash::FxHashMap;

use crate::density::{cell_of, DepthAndArea, Sample};
use crate::normals::estimate::{eigen_sym3, Sym3};

/// A neighbourhood is flat when `√(λ_min / λ_mid)` is at most this.
const FLAT: f64 = 0.5;

/// Fewest samples in a neighbourhood for its plane fit to count.
const MIN_SAMPLES: f64 = 20.0;

/// Splat cells grow with `(CELLS_PER_NOISE σ / h)^NOISE_POWER` (see the module docs).
const CELLS_PER_NOISE: f64 = 3.5;

/// See [`CELLS_PER_NOISE`].
const NOISE_POWER: f64 = 1.3;

/// What the noise stage found, for the user.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NoiseSummary {
    /// Median noise over the samples where it was measured, in unit-cube units: the spread of
    /// the samples' offsets within cells, which reads about half the standard deviation of
    /// Gaussian noise (the cells cut off its tails).
    pub median: f64,
    /// Share of the samples where it was measured.
    pub measured: f64,
    /// Share of the samples whose splat depth was lowered.
    pub adapted: f64,
    /// Mean lowering of the splat depth over the adapted samples, in levels.
    pub mean_lowering: f64,
}

/// One cell's moments.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    w: f64,
    s: [f64; 3],
    ss: Sym3,
}

impl Moments {
    fn of(s: &Sample) -> Self {
        let p = s.pos;
        let w = s.weight;
        Moments {
            w,
            s: p.map(|c| w * c),
            ss: [
                w * p[0] * p[0],
                w * p[1] * p[1],
                w * p[2] * p[2],
                w * p[0] * p[1],
                w * p[0] * p[2],
                w * p[1] * p[2],
            ],
        }
    }

    fn add(&mut self, o: &Moments) {
        self.w += o.w;
        for a in 0..3 {
            self.s[a] += o.s[a];
        }
        for k in 0..6 {
            self.ss[k] += o.ss[k];
        }
    }

    /// The fitted plane (centroid and unit normal), when the moments look like a flat patch.
    fn flat_plane(&self, count: f64) -> Option<Plane> {
        if count < MIN_SAMPLES || self.w <= 0.0 {
            return None;
        }
        let m = self.s.map(|c| c / self.w);
        let idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];
        let cov: Sym3 = std::array::from_fn(|k| {
            let (i, j) = idx[k];
            self.ss[k] / self.w - m[i] * m[j]
        });
        let (l, v) = eigen_sym3(&cov);
        let lo = l[0].max(0.0);
        (l[1] > 0.0 && lo <= FLAT * FLAT * l[1]).then_some(Plane {
            centre: m,
            normal: v[0],
        })
    }
}

/// A plane fitted to a flat neighbourhood.
#[derive(Debug, Clone, Copy)]
struct Plane {
    centre: [f64; 3],
    normal: [f64; 3],
}

impl Plane {
    fn offset(&self, p: [f64; 3]) -> f64 {
        (0..3)
            .map(|a| (p[a] - self.centre[a]) * self.normal[a])
            .sum()
    }
}

fn pack(c: [i64; 3]) -> u64 {
    (c[0] as u64) | ((c[1] as u64) << 21) | ((c[2] as u64) << 42)
}

/// The moments and sample counts of the occupied cells of one depth.
type Level = FxHashMap<u64, (Moments, f64)>;

/// Sums the samples' moments into the cells of every depth `0..=top`.
fn levels(samples: &[Sample], top: u32) -> Vec<Level> {
    let mut out: Vec<Level> = Vec::with_capacity(top as usize + 1);
    let mut fine = Level::default();
    for s in samples {
        let e = fine
            .entry(pack(cell_of(s.pos, top)))
            .or_insert((Moments::default(), 0.0));
        e.0.add(&Moments::of(s));
        e.1 += 1.0;
    }
    out.push(fine);
    for _ in 0..top {
        let mut up = Level::default();
        for (&k, (m, n)) in out.last().expect("one level") {
            let c = unpack(k).map(|v| v >> 1);
            let e = up.entry(pack(c)).or_insert((Moments::default(), 0.0));
            e.0.add(m);
            e.1 += n;
        }
        out.push(up);
    }
    out.reverse();
    out
}

fn unpack(k: u64) -> [i64; 3] {
    let m = (1u64 << 21) - 1;
    [
        (k & m) as i64,
        ((k >> 21) & m) as i64,
        ((k >> 42) & m) as i64,
    ]
}

/// The noise of each occupied cell's 3×3×3 neighbourhood, where it is flat.
fn flat_cells(level: &Level) -> FxHashMap<u64, Plane> {
    let keys: Vec<u64> = level.keys().copied().collect();
    keys.par_iter()
        .filter_map(|&k| {
            let c = unpack(k);
            let mut m = Moments::default();
            let mut n = 0.0;
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if q.iter().any(|&v| v < 0) {
                            continue;
                        }
                        if let Some((qm, qn)) = level.get(&pack(q)) {
                            m.add(qm);
                            n += qn;
                        }
                    }
                }
            }
            m.flat_plane(n).map(|s| (k, s))
        })
        .collect()
}

/// Each sample's noise `σ` and the depth its plane was fitted at, `None` where no depth is
/// flat or too few samples share its fine cell.
///
/// The plane of the finest flat neighbourhood leaves each sample an offset `r`. Over a
/// smooth clean surface the offsets vary smoothly (curvature, a crease nearby); noise makes
/// them vary from sample to sample. So the noise is the spread of the offsets among the
/// samples of one cell of the next finer depth, where the smooth part hardly varies.
fn measure(samples: &[Sample], top: u32) -> Vec<Option<(f64, u32)>> {
    let levels = levels(samples, top);
    let flat: Vec<FxHashMap<u64, Plane>> = levels.iter().map(flat_cells).collect();
    drop(levels);
    // Each sample's plane depth and offset.
    let offsets: Vec<Option<(u32, f64)>> = samples
        .par_iter()
        .map(|s| {
            (1..top).rev().find_map(|d| {
                flat[d as usize]
                    .get(&pack(cell_of(s.pos, d)))
                    .map(|plane| (d, plane.offset(s.pos)))
            })
        })
        .collect();
    // Offsets' sums per (plane depth, fine cell).
    let mut spread: FxHashMap<(u32, u64), (f64, f64, f64)> = FxHashMap::default();
    for (s, o) in samples.iter().zip(&offsets) {
        if let Some((d, r)) = *o {
            let e = spread
                .entry((d, pack(cell_of(s.pos, d + 1))))
                .or_insert((0.0, 0.0, 0.0));
            e.0 += 1.0;
            e.1 += r;
            e.2 += r * r;
        }
    }
    samples
        .par_iter()
        .zip(&offsets)
        .map(|(s, o)| {
            let (d, _) = (*o)?;
            let (n, sum, sum2) = spread[&(d, pack(cell_of(s.pos, d + 1)))];
            (n >= FINE_SAMPLES).then(|| {
                let var = (sum2 - sum * sum / n).max(0.0) / (n - 1.0);
                (var.sqrt(), d)
            })
        })
        .collect()
}

/// Fewest samples in a fine cell for the spread of their offsets to count.
const FINE_SAMPLES: f64 = 3.0;

/// Smooths the noise: each sample takes the median noise of the measured samples (those
/// not NaN) in the 3×3×3 cells around it at depth `d`; 0 where none was measured.
fn smooth(samples: &[Sample], sigma: &[f64], d: u32) -> Vec<f64> {
    let mut by_cell: FxHashMap<u64, Vec<f64>> = FxHashMap::default();
    for (s, &c) in samples.iter().zip(sigma) {
        let e = by_cell.entry(pack(cell_of(s.pos, d))).or_default();
        if !c.is_nan() {
            e.push(c);
        }
    }
    let keys: Vec<u64> = by_cell.keys().copied().collect();
    let medians: FxHashMap<u64, f64> = keys
        .par_iter()
        .map_init(Vec::new, |buf: &mut Vec<f64>, &k| {
            buf.clear();
            let c = unpack(k);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                        if q.iter().any(|&v| v < 0) {
                            continue;
                        }
                        if let Some(v) = by_cell.get(&pack(q)) {
                            buf.extend_from_slice(v);
                        }
                    }
                }
            }
            if buf.is_empty() {
                return (k, 0.0);
            }
            let m = buf.len() / 2;
            (k, *buf.select_nth_unstable_by(m, f64::total_cmp).1)
        })
        .collect();
    samples
        .par_iter()
        .map(|s| medians[&pack(cell_of(s.pos, d))])
        .collect()
}

/// Lowers each sample's splat depth as far as its local noise needs (stage 2b) and says what
/// it found. `max_depth` is the tree's depth `D`.
pub fn adapt(samples: &[Sample], depths: &mut [DepthAndArea], max_depth: u32) -> NoiseSummary {
    let n = samples.len();
    if n == 0 {
        return NoiseSummary::default();
    }
    let measured = measure(samples, max_depth);
    let raw: Vec<f64> = measured
        .iter()
        .map(|m| m.map_or(f64::NAN, |(s, _)| s))
        .collect();
    let mut at: Vec<u32> = measured.iter().filter_map(|m| m.map(|(_, d)| d)).collect();
    let smooth_depth = median_by(&mut at, u32::cmp)
        .unwrap_or(max_depth)
        .saturating_sub(1)
        .max(1);
    let sigma = smooth(samples, &raw, smooth_depth);
    let mut sigmas: Vec<f64> = raw.into_iter().filter(|s| !s.is_nan()).collect();
    let median = median_by(&mut sigmas, f64::total_cmp).unwrap_or(0.0);
    let lowered: Vec<f64> = depths
        .par_iter_mut()
        .zip(&sigma)
        .map(|(q, &s)| {
            let d0 = q.depth.min(f64::from(max_depth));
            let r = (CELLS_PER_NOISE * s * d0.exp2()).powf(NOISE_POWER);
            let d = d0 - 0.5 * (1.0 + r * r).log2();
            let drop = (d0 - d).max(0.0);
            if drop > 0.0 {
                q.depth = d;
            }
            drop
        })
        .collect();
    let adapted = lowered.iter().filter(|&&l| l > ADAPTED).count();
    NoiseSummary {
        median,
        measured: at.len() as f64 / n as f64,
        adapted: adapted as f64 / n as f64,
        mean_lowering: if adapted > 0 {
            lowered.iter().filter(|&&l| l > ADAPTED).sum::<f64>() / adapted as f64
        } else {
            0.0
        },
    }
}

/// A sample counts as adapted when its depth was lowered by more than this (in levels).
const ADAPTED: f64 = 0.05;

/// The median of `v` (reordered), `None` when it is empty.
fn median_by<T: Copy>(v: &mut [T], cmp: impl FnMut(&T, &T) -> std::cmp::Ordering) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    let m = v.len() / 2;
    Some(*v.select_nth_unstable_by(m, cmp).1)
}
