//! Stage 3 (ALGORITHM.md §3.6, §4.2): choose each sample's splat depths and build the octree
//! that holds them, complete down to the base depth and closed for the finite elements. The
//! run is refused here, before the tree is allocated, when it would not fit in memory.

use super::density::Sampled;
use crate::density::{cell_of, Sample};
use crate::error::{MemoryLimit, MemoryShortfall};
use crate::octree::{Octree, TreeRequest, DEPTH_OFFSET};
use crate::{resources, Error, Params, Result};
use rayon::prelude::*;

/// Where one sample's normal is splatted: `(depth, fraction)` at two depths; and how deep
/// the tree is refined around it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Splat {
    /// The depth at or above the sample's estimated depth, with the fraction splatted there,
    /// and the depth above it with the rest.
    pub levels: [(u32, f64); 2],
    /// The finest depth the tree is refined to around the sample: the first splat depth,
    /// except for a noisy sample held to coarser screening clusters (`pipeline::noise`),
    /// around which the tree goes [`REFINE_BELOW_NOISY_SPLAT`] depths finer.
    pub finest: u32,
}

/// How many depths below a noisy sample's splat the tree is refined around it (at most to
/// the tree's depth): the splat and the screening are coarse there, so χ is smooth, and the
/// finer functions and cells represent and extract that smooth surface more closely than
/// cells of the splat's width would (`pipeline::noise`, *Screening depth*).
pub const REFINE_BELOW_NOISY_SPLAT: u32 = 1;

/// The output of [`build`].
#[derive(Debug)]
pub struct Refined {
    /// The octree.
    pub tree: Octree,
    /// Each sample's splat, `None` for samples whose normals cancel.
    pub splats: Vec<Option<Splat>>,
    /// The peak memory estimated for the run, in bytes.
    pub memory_estimate: u64,
}

/// Chooses the splat depths and builds the octree (stage 3).
pub fn build(sampled: &Sampled, params: &Params, input_points: usize) -> Result<Refined> {
    build_with(sampled, params, input_points, |_| {})
}

/// As [`build`], with more nodes required by `extra` (a slab's tree takes in the whole
/// cloud's coarse levels).
pub fn build_with(
    sampled: &Sampled,
    params: &Params,
    input_points: usize,
    extra: impl FnOnce(&mut TreeRequest),
) -> Result<Refined> {
    let depth = params.depth;
    // The base depth must be at least 1 so that it has a parent for prolongation tables.
    let base = params.base_depth().max(1).min(depth);
    let splats = splats_of(sampled, params);
    let mut req = request(&sampled.samples, &splats, params);
    extra(&mut req);
    let closed = req.close(base, base);
    let memory_estimate = check_memory(&closed.level_counts(), input_points, params)?;
    Ok(Refined {
        tree: Octree::materialize(closed),
        splats,
        memory_estimate,
    })
}

/// Each sample's splat depths, `None` for samples whose normals cancel.
pub fn splats_of(sampled: &Sampled, params: &Params) -> Vec<Option<Splat>> {
    let depth = params.depth;
    let base = params.base_depth().max(1).min(depth);
    sampled
        .samples
        .par_iter()
        .zip(&sampled.depths)
        .map(|(s, q)| {
            (s.normal != [0.0; 3]).then(|| {
                let mut sp = splat_depths(q.depth, base, depth, params);
                if q.screened_coarser() {
                    sp.finest = (sp.levels[0].0 + REFINE_BELOW_NOISY_SPLAT).min(depth);
                }
                sp
            })
        })
        .collect()
}

/// The nodes the samples' splats need (the B-spline windows around their cells), before the
/// tree is closed: requested over runs of samples in parallel, each run's request compacted
/// (neighbouring samples, in Morton order, share most nodes), then joined.
pub fn request(samples: &[Sample], splats: &[Option<Splat>], params: &Params) -> TreeRequest {
    let max_t = params.depth + DEPTH_OFFSET;
    let parts = samples
        .par_chunks(REQUEST_RUN)
        .zip(splats.par_chunks(REQUEST_RUN))
        .map(|(samples, splats)| {
            let mut req = TreeRequest::new(max_t);
            for (s, sp) in samples.iter().zip(splats) {
                if let Some(sp) = sp {
                    require_splat(&mut req, s, sp);
                }
            }
            req.compact();
            req
        })
        .collect();
    TreeRequest::union(parts, max_t)
}

/// Samples per run of [`request`].
const REQUEST_RUN: usize = 1 << 14;

/// Requires the nodes of one sample's splat: the window around its cell at each depth that
/// receives a part of it, and at its finest depth ([`Splat::finest`]) where that is finer.
fn require_splat(req: &mut TreeRequest, s: &Sample, sp: &Splat) {
    for &(d, f) in &sp.levels {
        if f > 0.0 {
            require_window_at(req, s.pos, d);
        }
    }
    if sp.finest > sp.levels[0].0 {
        require_window_at(req, s.pos, sp.finest);
    }
}

/// Requires the window of B-spline support around the cell holding `p` at depth `d`.
fn require_window_at(req: &mut TreeRequest, p: [f64; 3], d: u32) {
    let c = cell_of(p, d);
    let n = 1i64 << d;
    req.require_window(d + DEPTH_OFFSET, [c[0] + n, c[1] + n, c[2] + n], 1);
}

/// The two depths around a sample's estimated depth `ds` (§3.6), clamped to `base..=depth`.
fn splat_depths(ds: f64, base: u32, depth: u32, params: &Params) -> Splat {
    let ds = ds.clamp(f64::from(base), f64::from(depth));
    let mut dp = ds.ceil() as u32;
    let mut f = 1.0 - (f64::from(dp) - ds);
    if dp <= base {
        dp = base;
        f = 1.0;
    }
    if dp > depth {
        dp = depth;
        f = 1.0;
    }
    if !params.two_level_splat {
        // PoissonRecon 18 splats the whole sample at the ceiling depth.
        f = 1.0;
    }
    Splat {
        levels: [(dp, f), (dp - 1, 1.0 - f)],
        finest: dp,
    }
}

// The memory model: peak resident memory ≈ BYTES_PER_NODE × octree nodes + BYTES_PER_POINT ×
// input points + BASE_BYTES + the base level's assembled matrix. Fitted to peak RSS measured
// with GNU time (2 threads, degrees 1 and 2, November 2026, after issue 20's memory work) and
// rounded up (docs/memory.md): on bunny_100k at depths 8 and 10, sphere_200k at 10, spot_1m
// at 8 and 10, bunny_1m at 10 and 11, bunny_20k and bunny_small_10k at 12, torus_200k at 11
// and a 4 M-point bunny at 11 it lands 4–100 % above the peak, 16–40 % on the million-point
// clouds.

/// Peak memory per octree node over the whole run (the tree's neighbour table, the screening
/// clusters, the levels' solutions and right-hand sides; 35–40 bytes measured on large trees).
const BYTES_PER_NODE: u64 = 44;

/// Memory per input point (the cloud, its unit-cube copy, samples and density).
const BYTES_PER_POINT: u64 = 80;

/// The program, thread stacks, read and write buffers, and what small runs hold whatever their
/// size (the density estimator, the extraction's per-thread caches).
const BASE_BYTES: u64 = 64 << 20;

/// The base level's matrix, assembled for its conjugate gradients: the complete grid of the
/// base depth, one row of the stiffness window's `(2·degree + 1)³` slots per node, 12 bytes a
/// slot (49 MB at degree 2 and base depth 5), for a run of `params` at `depth`.
fn base_matrix_bytes(params: &Params, depth: u32) -> u64 {
    let base = params.full_depth.max(1).min(depth).min(20);
    let width = (2 * u64::from(params.degree.get()) + 1).pow(3);
    (1u64 << (3 * base)).saturating_mul(width * 12)
}

/// The memory of a complete tree down to `depth` (every cell of the unit cube at every depth,
/// as the levels up to the full depth are) with the program's base: what any part of a run
/// holds, however the cloud is cut.
pub fn full_grid_bytes(depth: u32) -> u64 {
    let nodes: u64 = (0..=depth.min(20)).map(|d| 1u64 << (3 * d)).sum();
    BYTES_PER_NODE.saturating_mul(nodes) + BASE_BYTES
}

/// The peak memory the model gives for a run of `params` at `depth` with `nodes` octree nodes
/// and `points` input points, in bytes.
pub(crate) fn estimate_bytes(nodes: u64, points: usize, params: &Params, depth: u32) -> u64 {
    BYTES_PER_NODE * nodes
        + BYTES_PER_POINT * points as u64
        + BASE_BYTES
        + base_matrix_bytes(params, depth)
}

/// The limit a run's memory estimate is checked against and where it comes from: the
/// caller's `max_memory`, else the memory available (none where the platform does not say).
pub(crate) fn memory_limit(params: &Params) -> Option<(u64, MemoryLimit)> {
    match params.max_memory {
        Some(m) => Some((m, MemoryLimit::Requested)),
        None => resources::memory_budget().map(|m| (m, MemoryLimit::Available)),
    }
}

/// Refuses a run whose estimated peak memory exceeds the limit. The suggested depth is the
/// deepest whose levels of this tree fit: a shallower run keeps the same coarse levels.
fn check_memory(level_counts: &[usize], points: usize, params: &Params) -> Result<u64> {
    // The levels down to depth `d` (tree depth `d + DEPTH_OFFSET`).
    let estimate_at = |d: u32| {
        let nodes: usize = level_counts
            .iter()
            .take((d + DEPTH_OFFSET + 1) as usize)
            .sum();
        estimate_bytes(nodes as u64, points, params, d)
    };
    let estimate = estimate_at(params.depth);
    let Some((limit, source)) = memory_limit(params) else {
        return Ok(estimate);
    };
    if estimate <= limit {
        return Ok(estimate);
    }
    let suggested_depth = (1..params.depth).rev().find(|&d| estimate_at(d) <= limit);
    Err(Error::ResourceLimit(MemoryShortfall {
        estimate,
        limit,
        source,
        nodes: level_counts.iter().sum(),
        depth: params.depth,
        suggested_depth,
    }))
}
