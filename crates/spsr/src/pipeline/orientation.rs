//! Stage 2a (issue 16, beyond ALGORITHM.md): normals that contradict their neighbours.
//!
//! Merged scans often carry pieces whose normals point inward. The reference takes every
//! normal as given (ALGORITHM.md §12: "orient upstream"), and a flipped piece makes the
//! indicator function cancel there, leaving holes and open sheets. Here the samples' normals
//! are first checked: in the cells of the deepest depth (at most `D − 2`) whose cells hold
//! about 4 samples each, a sample whose normal points against the sum of its cell's normals
//! disagrees with its neighbours. Measured shares: under 0.2 % on the shared synthetic clouds,
//! clean or noisy, 0.06 % on the kitten scan, 1.1 % on the cube scan and 3.6 % on the sparse
//! `oni` scan (thin parts, whose two sides share cells, make most of them); 37 % on a sphere
//! with every second normal flipped. Above [`MAX_DISAGREEING`] the normals are made
//! consistent along the neighbour graph; each connected piece keeps the direction of the clear
//! majority of its given normals, or faces outward where there is none (half of them
//! flipped), see `crate::normals::make_consistent`.
//!
//! Known limit: a whole region flipped at once (half a bunny) disagrees only along its
//! border (0.4 %), below the threshold, so it is not detected here.

use rayon::prelude::*;

use crate::density::{cell_of, Sample};
use crate::error::Warning;
use crate::morton::encode;
use crate::vec3::dot;

/// The share of disagreeing samples above which the normals are re-oriented.
const MAX_DISAGREEING: f64 = 0.10;

/// Neighbours per sample in the graph the orientation is propagated along.
const NEIGHBOURS: usize = 10;

/// Fewest samples in a cell for its sum to be a fair majority.
const MIN_CELL_SAMPLES: usize = 3;

/// The share of samples whose normal points against the sum of their cell's normals at
/// depth `d`, among the samples of cells with at least [`MIN_CELL_SAMPLES`]. Each cell's sum
/// is taken in sample order (the samples of a cell are adjacent in [`sorted_cells`]).
pub fn disagreeing(samples: &[Sample], d: u32) -> f64 {
    let keys = sorted_cells(samples, d);
    let starts = run_starts(&keys, 0);
    let (against, counted) = (0..starts.len())
        .into_par_iter()
        .map(|r| {
            let run = &keys[starts[r]..starts.get(r + 1).copied().unwrap_or(keys.len())];
            if run.len() < MIN_CELL_SAMPLES {
                return (0usize, 0usize);
            }
            let mut sum = [0.0; 3];
            for &(_, i) in run {
                let s = &samples[i as usize];
                for a in 0..3 {
                    sum[a] += s.weight * s.normal[a];
                }
            }
            let against = run
                .iter()
                .filter(|&&(_, i)| dot(samples[i as usize].normal, sum) < 0.0);
            (against.count(), run.len())
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if counted == 0 {
        0.0
    } else {
        against as f64 / counted as f64
    }
}

/// Each sample's cell at depth `d` (its Morton code) with the sample's index, sorted: the
/// samples of a cell are adjacent, in sample order, and the cells of any coarser depth are
/// runs too (a parent's code is its child's shifted right by 3 bits).
fn sorted_cells(samples: &[Sample], d: u32) -> Vec<(u64, u32)> {
    let mut keys: Vec<(u64, u32)> = samples
        .par_iter()
        .enumerate()
        .map(|(i, s)| (encode(cell_of(s.pos, d).map(|c| c as u64)), i as u32))
        .collect();
    keys.par_sort_unstable();
    keys
}

/// Where each run of equal codes shifted right by `shift` bits starts in `keys`.
fn run_starts(keys: &[(u64, u32)], shift: u32) -> Vec<usize> {
    (0..keys.len())
        .into_par_iter()
        .filter(|&i| i == 0 || keys[i].0 >> shift != keys[i - 1].0 >> shift)
        .collect()
}

/// Samples per occupied cell the check aims at.
const CELL_SAMPLES: f64 = 4.0;

/// The deepest depth (at most `depth − 2`) whose occupied cells hold [`CELL_SAMPLES`]
/// samples on average. The cells of every depth are counted from one sort at the deepest.
fn check_depth(samples: &[Sample], depth: u32) -> u32 {
    let top = depth.saturating_sub(2).max(1);
    let keys = sorted_cells(samples, top);
    let mut d = top;
    while d > 1 {
        let cells = run_starts(&keys, 3 * (top - d)).len();
        if samples.len() as f64 >= CELL_SAMPLES * cells as f64 {
            break;
        }
        d -= 1;
    }
    d
}

/// Re-orients the samples' normals when too many disagree with their neighbours (stage 2a);
/// returns the warning that says so.
pub fn repair(samples: &mut [Sample], depth: u32) -> Option<Warning> {
    let share = disagreeing(samples, check_depth(samples, depth));
    if share <= MAX_DISAGREEING {
        return None;
    }
    let positions: Vec<[f64; 3]> = samples.iter().map(|s| s.pos).collect();
    let mut normals: Vec<[f64; 3]> = samples.iter().map(|s| s.normal).collect();
    let flipped = crate::normals::make_consistent(&positions, &mut normals, NEIGHBOURS);
    for (s, n) in samples.iter_mut().zip(normals) {
        s.normal = n;
    }
    Some(Warning::NormalsReoriented {
        flipped,
        samples: samples.len(),
        disagreeing: share,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustc_hash::{FxHashMap, FxHashSet};

    /// Samples on a noisy sphere with a fifth of the normals flipped, in scattered order.
    fn samples(n: usize) -> Vec<Sample> {
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|i| {
                let (z, th) = (2.0 * next() - 1.0, std::f64::consts::TAU * next());
                let r = (1.0 - z * z).sqrt();
                let u = [r * th.cos(), r * th.sin(), z];
                let sign = if i % 5 == 0 { -1.0 } else { 1.0 };
                Sample {
                    pos: u.map(|c| 0.5 + (0.3 + 0.01 * next()) * c),
                    normal: u.map(|c| sign * c),
                    weight: 0.5 + next(),
                }
            })
            .collect()
    }

    /// The share and the depth as a hash map of cells gives them, summing in sample order.
    #[test]
    fn sorted_cells_give_the_hash_maps_share_and_depth() {
        let samples = samples(30_000);
        for d in 2..8 {
            let mut cells: FxHashMap<[i64; 3], ([f64; 3], usize)> = FxHashMap::default();
            for s in &samples {
                let e = cells.entry(cell_of(s.pos, d)).or_insert(([0.0; 3], 0));
                for a in 0..3 {
                    e.0[a] += s.weight * s.normal[a];
                }
                e.1 += 1;
            }
            let (mut against, mut counted) = (0, 0);
            for s in &samples {
                let (sum, n) = cells[&cell_of(s.pos, d)];
                if n >= MIN_CELL_SAMPLES {
                    against += usize::from(dot(s.normal, sum) < 0.0);
                    counted += 1;
                }
            }
            let want = against as f64 / counted as f64;
            assert_eq!(
                disagreeing(&samples, d).to_bits(),
                want.to_bits(),
                "depth {d}"
            );
            assert!(want > 0.1 && want < 0.3, "depth {d}: {want}");
        }
        for depth in 3..12u32 {
            let mut d = depth.saturating_sub(2).max(1);
            while d > 1 {
                let cells: FxHashSet<[i64; 3]> =
                    samples.iter().map(|s| cell_of(s.pos, d)).collect();
                if samples.len() as f64 >= CELL_SAMPLES * cells.len() as f64 {
                    break;
                }
                d -= 1;
            }
            assert_eq!(check_depth(&samples, depth), d, "depth {depth}");
        }
    }
}
