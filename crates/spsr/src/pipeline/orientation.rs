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
use rustc_hash::FxHashMap;

use crate::density::{cell_of, Sample};
use crate::error::Warning;
use crate::vec3::dot;

/// The share of disagreeing samples above which the normals are re-oriented.
const MAX_DISAGREEING: f64 = 0.10;

/// Neighbours per sample in the graph the orientation is propagated along.
const NEIGHBOURS: usize = 10;

/// Fewest samples in a cell for its sum to be a fair majority.
const MIN_CELL_SAMPLES: usize = 3;

/// The share of samples whose normal points against the sum of their cell's normals at
/// depth `d`, among the samples of cells with at least [`MIN_CELL_SAMPLES`].
pub fn disagreeing(samples: &[Sample], d: u32) -> f64 {
    let mut cells: FxHashMap<[i64; 3], ([f64; 3], usize)> = FxHashMap::default();
    for s in samples {
        let e = cells.entry(cell_of(s.pos, d)).or_insert(([0.0; 3], 0));
        for a in 0..3 {
            e.0[a] += s.weight * s.normal[a];
        }
        e.1 += 1;
    }
    let (against, counted) = samples
        .par_iter()
        .map(|s| {
            let (sum, n) = cells[&cell_of(s.pos, d)];
            if n < MIN_CELL_SAMPLES {
                (0usize, 0usize)
            } else {
                (usize::from(dot(s.normal, sum) < 0.0), 1)
            }
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if counted == 0 {
        0.0
    } else {
        against as f64 / counted as f64
    }
}

/// Samples per occupied cell the check aims at.
const CELL_SAMPLES: f64 = 4.0;

/// The deepest depth (at most `depth − 2`) whose occupied cells hold [`CELL_SAMPLES`]
/// samples on average.
fn check_depth(samples: &[Sample], depth: u32) -> u32 {
    let mut d = depth.saturating_sub(2).max(1);
    while d > 1 {
        let cells: rustc_hash::FxHashSet<[i64; 3]> =
            samples.iter().map(|s| cell_of(s.pos, d)).collect();
        if samples.len() as f64 >= CELL_SAMPLES * cells.len() as f64 {
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
