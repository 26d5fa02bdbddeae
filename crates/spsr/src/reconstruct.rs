//! The front door: the whole pipeline of ALGORITHM.md §2, stage by stage.

use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::attributes::{Attribute, AttributeData};
use crate::bspline::{Basis, Boundary};
use crate::data::DataField;
use crate::density::{cell_of, for_each_quadratic_neighbour, merge_samples_grouped, Density};
use crate::evaluate::{CornerField, Evaluator};
use crate::extract::{extract_blocks, Cells, ExtractOptions};
use crate::octree::{neighbor_in, window_index, Octree, TreeRequest, DEPTH_OFFSET, NONE};
use crate::points::{is_valid, normal_length};
use crate::solver::{solve, Problem};
use crate::system::{build_clusters, func_index, DepthTables};
use crate::{Error, Mesh, Params, PointCloud, Result};

/// Fewest usable points `reconstruct` accepts.
pub const MIN_POINTS: usize = 4;

/// The output of [`reconstruct`].
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// The mesh, in the input's frame and units.
    pub mesh: Mesh,
    /// Counts and timings of the run.
    pub stats: Stats,
}

/// Counts and timings gathered during a reconstruction.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Points given.
    pub points: usize,
    /// Points dropped (non-finite values or zero-length normals).
    pub dropped: usize,
    /// Samples after merging points that share a finest cell.
    pub samples: usize,
    /// Octree nodes per depth (index 0 is the unit cube).
    pub nodes_per_depth: Vec<usize>,
    /// The iso-value γ.
    pub iso_value: f64,
    /// Weighted mean of the samples' estimated depths.
    pub mean_sample_depth: f64,
    /// Wall time of each stage, in order.
    pub stages: Vec<(String, Duration)>,
    /// Warnings about the input that did not stop the reconstruction (e.g. far outliers).
    pub warnings: Vec<String>,
    /// The peak memory estimated before the octree was built (bytes), which
    /// [`Params::max_memory`] (or the available memory) was checked against.
    pub memory_estimate: u64,
    /// Peak resident memory of the process (bytes) at the end of each stage, where the
    /// platform reports it (Linux); same order as `stages`.
    pub peak_memory: Vec<Option<u64>>,
}

/// The process's peak resident set size so far, in bytes (Linux `VmHWM`).
pub fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Reconstructs a watertight surface from oriented points.
pub fn reconstruct(points: &PointCloud, params: &Params) -> Result<Reconstruction> {
    reconstruct_with_progress(points, params, &|_| {})
}

struct Timer<'a> {
    stats: Vec<(String, Duration)>,
    memory: Vec<Option<u64>>,
    last: Instant,
    progress: &'a (dyn Fn(&str) + Sync),
}

impl Timer<'_> {
    fn start(&mut self, name: &'static str) {
        (self.progress)(name);
        self.last = Instant::now();
    }
    fn stop(&mut self, name: &'static str) {
        self.stats.push((name.to_string(), self.last.elapsed()));
        self.memory.push(peak_rss());
    }
}

/// The solved implicit function, before extraction.
pub(crate) struct Implicit {
    pub tree: Octree,
    pub sol: crate::solver::Solution,
    pub fem: Basis,
    pub density: Density,
    pub iso: f64,
    pub width: f64,
    pub origin: [f64; 3],
    pub stats: Stats,
    /// The cloud's attributes summed up the tree, when they are carried onto the mesh.
    pub data: Option<DataField>,
    /// Name and type of each carried attribute (empty columns), in channel order.
    pub attribute_types: Vec<Attribute>,
}

impl Implicit {
    /// χ and its gradient at a world-space point.
    #[cfg(test)]
    pub fn value_grad_world(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let u: [f64; 3] = std::array::from_fn(|a| (p[a] - self.origin[a]) / self.width);
        let (v, g) = Evaluator::new(&self.tree, self.fem, &self.sol).value_grad(u);
        (v, [g[0] / self.width, g[1] / self.width, g[2] / self.width])
    }
}

/// The implicit function at given points, from [`implicit_gradients`].
pub(crate) struct ImplicitSamples {
    /// χ at each point (χ ≈ 1 inside, 0 outside).
    pub values: Vec<f64>,
    /// ∇χ at each point, in world units; the outward normal is along −∇χ.
    #[allow(dead_code)]
    pub gradients: Vec<[f64; 3]>,
    /// The iso-value γ.
    #[allow(dead_code)]
    pub iso: f64,
}

/// The implicit function solved from `cloud` with `params`, sampled at the points `at`
/// (points outside the bounding cube are clamped to it). Used by the global orientation of
/// normals (`normals::orient`).
pub(crate) fn implicit_gradients(
    cloud: &PointCloud,
    params: &Params,
    at: &[[f64; 3]],
) -> Result<ImplicitSamples> {
    let imp = solve_implicit(cloud, params, &|_| {})?;
    let eval = Evaluator::new(&imp.tree, imp.fem, &imp.sol);
    let (values, gradients) = at
        .par_iter()
        .map(|p| {
            let u: [f64; 3] =
                std::array::from_fn(|a| ((p[a] - imp.origin[a]) / imp.width).clamp(0.0, 1.0));
            let (v, g) = eval.value_grad(u);
            (v, g.map(|c| c / imp.width))
        })
        .unzip();
    Ok(ImplicitSamples {
        values,
        gradients,
        iso: imp.iso,
    })
}

/// As [`reconstruct`], calling `progress` with the name of each stage as it starts.
pub fn reconstruct_with_progress(
    points: &PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    reconstruct_input(Input::Borrowed(points), params, progress)
}

/// As [`reconstruct_with_progress`], taking the cloud by value: it is released as soon as
/// the points are normalised, which lowers the peak memory of a large run by the cloud's size.
pub fn reconstruct_owned(
    points: PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    reconstruct_input(Input::Owned(points), params, progress)
}

fn reconstruct_input(
    input: Input,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    let imp = solve_implicit_from(input, params, progress)?;
    let Implicit {
        tree,
        sol,
        fem,
        density,
        iso,
        width,
        origin,
        mut stats,
        data,
        attribute_types,
    } = imp;
    let mut timer = Timer {
        stats: std::mem::take(&mut stats.stages),
        memory: std::mem::take(&mut stats.peak_memory),
        last: Instant::now(),
        progress,
    };
    let eval = Evaluator::new(&tree, fem, &sol);
    // 8. Extraction (§9), block by block.
    timer.start("extraction");
    let cells = TreeCells::new(&tree, params.base_depth());
    let field = CornerField {
        eval: &eval,
        depth: cells.max_depth,
    };
    let blocks = extract_blocks(
        &cells,
        &field,
        iso,
        &ExtractOptions {
            linear_fit: params.linear_fit,
            normals: params.normals,
        },
    )?;
    drop(cells);
    let mut mesh = if data.is_some() {
        // Per-vertex values that need the solution and the tree: computed before they go.
        let mut mesh = blocks.assemble()?;
        if let Some(data) = &data {
            let k = data.channels();
            let mut values = vec![0.0f64; mesh.vertices.len() * k];
            values
                .par_chunks_mut(k)
                .zip(&mesh.vertices)
                .for_each(|(out, p)| data.eval(&tree, *p, out));
            mesh.attributes = attribute_types
                .iter()
                .enumerate()
                .map(|(c, a)| {
                    Attribute::new(
                        a.name.clone(),
                        a.data
                            .like_from_f64(values.iter().skip(c).step_by(k).copied()),
                    )
                })
                .collect();
        }
        drop(data);
        drop(sol);
        drop(tree);
        mesh
    } else {
        // The tree and the solution are released before the vertices are numbered.
        drop(sol);
        drop(tree);
        blocks.assemble()?
    };
    if params.density {
        mesh.density = Some(
            mesh.vertices
                .par_iter()
                .map(|p| density.query(*p).depth as f32)
                .collect(),
        );
    }
    for p in &mut mesh.vertices {
        for a in 0..3 {
            p[a] = p[a] * width + origin[a];
        }
    }
    timer.stop("extraction");

    stats.stages = timer.stats;
    stats.peak_memory = timer.memory;
    Ok(Reconstruction { mesh, stats })
}

/// The octree's leaves inside the unit cube, as extraction sees them. Blocks are the cells of
/// a depth at most the base depth (complete, so every leaf lies in one), chosen so that a
/// block spans about 32 finest cells per axis.
struct TreeCells<'a> {
    tree: &'a Octree,
    max_depth: u32,
    block_level: u32,
    blocks: Vec<u32>,
}

impl<'a> TreeCells<'a> {
    /// `base_depth`: a unit depth down to which the tree is complete.
    fn new(tree: &'a Octree, base_depth: u32) -> Self {
        let max_depth = tree.depth_count() - 1 - DEPTH_OFFSET;
        let block_level = max_depth.saturating_sub(5).min(base_depth) + DEPTH_OFFSET;
        let d = block_level - DEPTH_OFFSET;
        let level = &tree.levels[block_level as usize];
        let n = 1i64 << d;
        let blocks = (0..level.len() as u32)
            .filter(|&b| {
                func_index(level.key(b), d)
                    .iter()
                    .all(|&c| (0..n).contains(&c))
            })
            .collect();
        Self {
            tree,
            max_depth,
            block_level,
            blocks,
        }
    }
}

impl Cells for TreeCells<'_> {
    type Handle = (u32, u32);

    fn max_depth(&self) -> u32 {
        self.max_depth
    }

    fn block_count(&self) -> usize {
        self.blocks.len()
    }

    fn for_each_leaf(&self, b: usize, f: &mut dyn FnMut((u32, u32), u32, [u32; 3])) {
        // Depth-first, children in order: Morton order within the block.
        let mut stack = vec![(self.block_level, self.blocks[b])];
        while let Some((t, n)) = stack.pop() {
            let level = &self.tree.levels[t as usize];
            let c = level.child(n);
            if c == NONE {
                let d = t - DEPTH_OFFSET;
                let o = func_index(level.key(n), d);
                f((t, n), d, [o[0] as u32, o[1] as u32, o[2] as u32]);
            } else {
                for k in (0..8).rev() {
                    stack.push((t + 1, c * 8 + k));
                }
            }
        }
    }

    fn refined_around(&self, (t, n): (u32, u32), _depth: u32, _offset: [u32; 3]) -> u32 {
        let level = &self.tree.levels[t as usize];
        let next = self.tree.levels.get(t as usize + 1);
        let mut mask = 0;
        if next.is_none() {
            return 0;
        }
        for s in 0..27u32 {
            let o = [
                i64::from(s % 3) - 1,
                i64::from((s / 3) % 3) - 1,
                i64::from(s / 9) - 1,
            ];
            let m = neighbor_in(level, n, window_index(o));
            if m != NONE && level.child(m) != NONE {
                mask |= 1 << s;
            }
        }
        mask
    }

    fn refined(&self, (t, n): (u32, u32), depth: u32, offset: [u32; 3]) -> bool {
        let d = t - DEPTH_OFFSET;
        let levels = &self.tree.levels;
        let own = func_index(levels[t as usize].key(n), d);
        // The cell's ancestor at the leaf's depth is a neighbour of the leaf.
        let shift = depth.saturating_sub(d);
        let rel: [i64; 3] = std::array::from_fn(|a| i64::from(offset[a] >> shift) - own[a]);
        let (mut tt, mut m) = if depth >= d && rel.iter().all(|&r| (-2..=2).contains(&r)) {
            (t, neighbor_in(&levels[t as usize], n, window_index(rel)))
        } else {
            // Not expected (the cell touches the leaf and is no coarser); look it up from the
            // root.
            let key: [u64; 3] = std::array::from_fn(|a| u64::from(offset[a]) + (1u64 << depth));
            let tk = depth + DEPTH_OFFSET;
            let (reached, node) = self.tree.descend(key, tk, tk);
            if reached != tk {
                return false;
            }
            (tk, node)
        };
        if m == NONE {
            return false;
        }
        while tt < depth + DEPTH_OFFSET {
            let b = levels[tt as usize].child(m);
            if b == NONE {
                return false;
            }
            tt += 1;
            let s = depth + DEPTH_OFFSET - tt;
            let bits = ((offset[0] >> s) & 1)
                | (((offset[1] >> s) & 1) << 1)
                | (((offset[2] >> s) & 1) << 2);
            m = b * 8 + bits;
        }
        levels[tt as usize].child(m) != NONE
    }
}

// The memory model: peak resident memory ≈ BYTES_PER_NODE × octree nodes + BYTES_PER_POINT ×
// input points + BASE_BYTES. Fitted to peak RSS measured with `/usr/bin/time -v` (2 threads)
// and rounded up (README, "Hostile input, resource limits and interruption"): bunny_100k
// depth 8 and 10, sphere_200k depth 10, spot_1m depth 8 and 10 and bunny_1m depth 11 land
// 5–46 % above it. Known gap: few points at a large depth (bunny_20k at depth 12 peaks 41 %
// above the estimate), where the density estimator and the complete base level dominate.

/// Peak memory per octree node over the whole run (solve and extraction; 55–70 bytes measured).
const BYTES_PER_NODE: u64 = 70;

/// Memory per input point (the cloud, its unit-cube copy, samples and density).
const BYTES_PER_POINT: u64 = 80;

/// The program, thread stacks, read and write buffers.
const BASE_BYTES: u64 = 32 << 20;

/// Memory the machine can still give this process: available memory plus what the process
/// already holds (Linux; `None` elsewhere).
fn memory_budget() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kb = |key: &str, text: &str| -> Option<u64> {
        let line = text.lines().find(|l| l.starts_with(key))?;
        line.split_whitespace().nth(1)?.parse::<u64>().ok()
    };
    let available = kb("MemAvailable:", &meminfo)? * 1024;
    let status = std::fs::read_to_string("/proc/self/status").ok();
    let own = status.and_then(|s| kb("VmRSS:", &s)).unwrap_or(0) * 1024;
    Some(available + own)
}

fn gib(bytes: u64) -> String {
    format!("{:.2} GiB", bytes as f64 / (1u64 << 30) as f64)
}

/// Refuses a run whose estimated peak memory exceeds the limit. The suggested depth is the
/// deepest whose levels of this tree fit: a shallower run keeps the same coarse levels.
fn check_memory(level_counts: &[usize], points: usize, params: &Params) -> Result<u64> {
    let estimate_to = |levels: usize| {
        let nodes: usize = level_counts.iter().take(levels).sum();
        BYTES_PER_NODE * nodes as u64 + BYTES_PER_POINT * points as u64 + BASE_BYTES
    };
    let estimate = estimate_to(level_counts.len());
    let (limit, what) = match params.max_memory {
        Some(m) => (m, "the --max-memory limit"),
        None => match memory_budget() {
            Some(m) => (m, "the memory this machine has available"),
            None => return Ok(estimate),
        },
    };
    if estimate <= limit {
        return Ok(estimate);
    }
    let nodes: usize = level_counts.iter().sum();
    let fits = (1..params.depth)
        .rev()
        .find(|&d| estimate_to((d + DEPTH_OFFSET + 1) as usize) <= limit);
    let advice = match fits {
        Some(d) => {
            format!("use --depth {d} or less, a larger --samples-per-node, or raise --max-memory")
        }
        None => {
            "even the coarsest depth does not fit: raise --max-memory or use fewer points".into()
        }
    };
    Err(Error::ResourceLimit {
        estimate,
        limit,
        suggested_depth: fits.unwrap_or(1),
        message: format!(
            "this reconstruction needs about {} ({nodes} octree nodes at --depth {}), more than \
             {what} ({}); {advice}",
            gib(estimate),
            params.depth,
            gib(limit)
        ),
    })
}

/// Fraction of points at each end of every axis left out of the robust extent.
const OUTLIER_QUANTILE: f64 = 0.001;

/// Bounding boxes larger than this many times the robust extent get a warning.
const OUTLIER_RATIO: f64 = 20.0;

/// Fewest usable points for which the outlier check is made (below, the quantiles mean
/// little).
const OUTLIER_MIN_POINTS: usize = 20;

/// A warning when a few far points make the bounding cube much larger than the bulk of the
/// cloud: the cube sets the finest cell size, so such outliers silently waste depth. Names
/// how many points lie outside the bulk, the box that holds the bulk, and the two fixes.
fn outlier_warning(points: &PointCloud, valid: &[usize], side: f64, depth: u32) -> Option<String> {
    let n = valid.len();
    if n < OUTLIER_MIN_POINTS {
        return None;
    }
    // The bulk: on each axis, the range without the 0.1 % of points at either end (at least
    // one point each side).
    let k = ((n as f64 * OUTLIER_QUANTILE) as usize).max(1);
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    for a in 0..3 {
        let mut c: Vec<f64> = valid.iter().map(|&i| points.positions[i][a]).collect();
        lo[a] = *c.select_nth_unstable_by(k, f64::total_cmp).1;
        hi[a] = *c.select_nth_unstable_by(n - 1 - k, f64::total_cmp).1;
    }
    let robust = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    // Positions are finite here, so `robust` is a finite number, not NaN.
    if robust <= 0.0 || side <= OUTLIER_RATIO * robust {
        return None;
    }
    // Points far from the bulk: outside its box grown by its own size on every side.
    let far = valid
        .iter()
        .filter(|&&i| {
            let p = points.positions[i];
            (0..3).any(|a| p[a] < lo[a] - robust || p[a] > hi[a] + robust)
        })
        .count();
    let ratio = side / robust;
    let lost = ratio.log2().floor() as u32;
    let fmt = |v: [f64; 3]| format!("({:.6e}, {:.6e}, {:.6e})", v[0], v[1], v[2]);
    let deeper = depth + lost;
    Some(format!(
        "{far} of {n} points ({:.3} %) lie far outside the box {} to {} that holds the \
         others; they make the points span {side:.4e} units instead of {robust:.4e}, so the \
         finest cells are about {ratio:.0} times coarser (--depth {depth} resolves the \
         surface like --depth {}); remove those points (crop the input to that box){}",
        100.0 * far as f64 / n as f64,
        fmt(lo),
        fmt(hi),
        depth.saturating_sub(lost),
        if deeper <= crate::MAX_DEPTH {
            format!(", or raise --depth to {deeper}")
        } else {
            String::new()
        }
    ))
}

/// Stages 1–7 of the pipeline: everything up to and including the iso-value.
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn solve_implicit(
    points: &PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Implicit> {
    solve_implicit_from(Input::Borrowed(points), params, progress)
}

/// The points handed to the pipeline: an owned cloud is released as soon as its unit-cube
/// copy exists, which lowers the peak memory by the cloud's size.
pub(crate) enum Input<'a> {
    Borrowed(&'a PointCloud),
    Owned(PointCloud),
}

impl Input<'_> {
    fn cloud(&self) -> &PointCloud {
        match self {
            Input::Borrowed(c) => c,
            Input::Owned(c) => c,
        }
    }
}

fn solve_implicit_from(
    input: Input,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Implicit> {
    let points = input.cloud();
    params.validate()?;
    if points.positions.len() != points.normals.len() {
        return Err(Error::LengthMismatch {
            positions: points.positions.len(),
            normals: points.normals.len(),
        });
    }
    let mut timer = Timer {
        stats: Vec::new(),
        memory: Vec::new(),
        last: Instant::now(),
        progress,
    };
    let depth = params.depth;
    // The base depth must be at least 1 so that it has a parent for prolongation tables.
    let base = params.base_depth().max(1).min(depth);
    let fem = Basis::new(params.degree, params.boundary);
    let vb = Basis::new(2, params.boundary.derivative());

    // 1. Filter, bounding cube, unit-cube transform (§3.1, §3.2).
    timer.start("preparing points");
    // Per-point weights from a named property, when asked for.
    let confidence = match &params.confidence_property {
        Some(name) => Some(points.attribute(name).ok_or_else(|| {
            let have: Vec<&str> = points.attributes.iter().map(|a| a.name.as_str()).collect();
            Error::InvalidParameter {
                name: "--confidence-property",
                message: format!(
                    "the points have no property '{name}' (they have: {})",
                    if have.is_empty() {
                        "none".to_string()
                    } else {
                        have.join(", ")
                    }
                ),
            }
        })?),
        None => None,
    };
    let weight_of = |i: usize| -> f64 {
        match confidence {
            Some(a) => a.data.get(i).unwrap_or(f64::NAN),
            None if params.confidence => normal_length(&points.normals[i]),
            None => 1.0,
        }
    };
    let valid: Vec<usize> = (0..points.len())
        .filter(|&i| {
            is_valid(&points.positions[i], &points.normals[i]) && {
                let w = weight_of(i);
                w.is_finite() && w > 0.0
            }
        })
        .collect();
    let dropped = points.len() - valid.len();
    if valid.len() < MIN_POINTS {
        return Err(Error::TooFewPoints {
            usable: valid.len(),
            dropped,
            required: MIN_POINTS,
        });
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in &valid {
        for a in 0..3 {
            lo[a] = lo[a].min(points.positions[i][a]);
            hi[a] = hi[a].max(points.positions[i][a]);
        }
    }
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    if !(side.is_finite() && side > 0.0) {
        return Err(Error::Degenerate(if side == 0.0 {
            "all usable points are identical; there is no surface to reconstruct".into()
        } else {
            "the points' extent is not finite (coordinates too large)".into()
        }));
    }
    let mut warnings = Vec::new();
    if let Some(w) = outlier_warning(points, &valid, side, params.depth) {
        warnings.push(w);
    }
    let width = side * params.scale;
    let origin: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]) - 0.5 * width);
    if !(width.is_finite() && origin.iter().all(|o| o.is_finite())) {
        return Err(Error::Degenerate("the bounding cube is not finite".into()));
    }
    let unit: Vec<([f64; 3], [f64; 3], f64)> = valid
        .par_iter()
        .map(|&i| {
            let p = points.positions[i];
            let n = points.normals[i];
            let len = normal_length(&n);
            let w = weight_of(i);
            (
                std::array::from_fn(|a| ((p[a] - origin[a]) / width).clamp(0.0, 1.0)),
                [n[0] / len, n[1] / len, n[2] / len],
                w,
            )
        })
        .collect();
    // Attributes carried onto the mesh: one f64 channel per attribute, per valid point.
    let columns: Vec<&Attribute> = if params.attributes {
        points
            .attributes
            .iter()
            .filter(|a| a.data.len() == points.len())
            .collect()
    } else {
        Vec::new()
    };
    let attribute_types: Vec<Attribute> = columns
        .iter()
        .map(|a| Attribute::new(a.name.clone(), AttributeData::new(a.data.scalar_type())))
        .collect();
    let channels = attribute_types.len();
    let point_values: Vec<f64> = if channels > 0 {
        valid
            .iter()
            .flat_map(|&i| columns.iter().map(move |a| a.data.get(i).unwrap_or(0.0)))
            .collect()
    } else {
        Vec::new()
    };
    let n_points = points.len();
    drop(input);
    timer.stop("preparing points");

    // 2. Samples and density (§3.3, §3.5).
    timer.start("density");
    let (samples, sample_of) = merge_samples_grouped(&unit, depth, channels > 0);
    // Each sample's attributes: the weighted mean over its points.
    let mut sample_values = vec![0.0f64; samples.len() * channels];
    for (p, &s) in sample_of.iter().enumerate() {
        if s == u32::MAX {
            continue;
        }
        let w = unit[p].2 / samples[s as usize].weight;
        let row = &mut sample_values[s as usize * channels..(s as usize + 1) * channels];
        for (o, v) in row
            .iter_mut()
            .zip(&point_values[p * channels..(p + 1) * channels])
        {
            *o += w * v;
        }
    }
    drop(sample_of);
    drop(point_values);
    drop(unit);
    let density = Density::build(&samples, params.kernel_depth(), params.samples_per_node);
    let queries: Vec<_> = samples.par_iter().map(|s| density.query(s.pos)).collect();
    timer.stop("density");

    // 3. Splat depths, tree (§3.6, §4.2).
    timer.start("octree");
    struct Splat {
        levels: [(u32, f64); 2],
    }
    let splats: Vec<Option<Splat>> = samples
        .iter()
        .zip(&queries)
        .map(|(s, q)| {
            if s.normal == [0.0; 3] {
                return None;
            }
            let ds = q.depth.clamp(f64::from(base), f64::from(depth));
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
            Some(Splat {
                levels: [(dp, f), (dp - 1, 1.0 - f)],
            })
        })
        .collect();
    let max_t = depth + DEPTH_OFFSET;
    let mut req = TreeRequest::new(max_t);
    for (s, sp) in samples.iter().zip(&splats) {
        let Some(sp) = sp else { continue };
        for &(d, f) in &sp.levels {
            if f > 0.0 {
                let c = cell_of(s.pos, d);
                let n = 1i64 << d;
                req.require_window(d + DEPTH_OFFSET, [c[0] + n, c[1] + n, c[2] + n], 1);
            }
        }
    }
    let closed = req.close(base, base);
    let memory_estimate = check_memory(&closed.level_counts(), n_points, params)?;
    let tree = Octree::materialize(closed);
    timer.stop("octree");

    // 4. Splat V and measure Ā (§3.6).
    timer.start("splatting");
    let nlev = tree.levels.len();
    let tb = (base + DEPTH_OFFSET) as usize;
    let mut v: Vec<Vec<[f32; 3]>> = (0..nlev)
        .map(|t| {
            if t >= tb {
                vec![[0.0; 3]; tree.levels[t].len()]
            } else {
                Vec::new()
            }
        })
        .collect();
    let mut sum_wa = 0.0;
    let mut sum_w = 0.0;
    let mut sum_depth = 0.0;
    for ((s, sp), q) in samples.iter().zip(&splats).zip(&queries) {
        let Some(sp) = sp else { continue };
        sum_wa += s.weight * q.area;
        sum_w += s.weight;
        sum_depth += s.weight * q.depth;
        for &(d, f) in &sp.levels {
            if f <= 0.0 {
                continue;
            }
            let t = d + DEPTH_OFFSET;
            let h = 1.0 / (1i64 << d) as f64;
            let c = cell_of(s.pos, d);
            let n = 1u64 << d;
            let key = [c[0] as u64 + n, c[1] as u64 + n, c[2] as u64 + n];
            let (tt, node) = tree.descend(key, t, t);
            debug_assert_eq!(tt, t);
            let scale = -s.weight * q.area / (h * h * h) * f;
            let rel: [f64; 3] =
                std::array::from_fn(|a| (s.pos[a] / h - c[a] as f64).clamp(0.0, 1.0));
            for_each_quadratic_neighbour(rel, |o, wt| {
                let m = tree.neighbor(t, node, o);
                if m == NONE {
                    return;
                }
                let w = scale * wt;
                let cell = &mut v[t as usize][m as usize];
                for a in 0..3 {
                    cell[a] += (w * s.normal[a]) as f32;
                }
            });
        }
    }
    if sum_w <= 0.0 {
        return Err(Error::Degenerate(
            "the normals cancel everywhere (opposite normals at the same places)".into(),
        ));
    }
    let mean_area = sum_wa / sum_w;
    // From here on only the samples' positions and weights are needed.
    let n_samples = samples.len();
    let positions: Vec<[f64; 3]> = samples.iter().map(|s| s.pos).collect();
    let weights: Vec<f64> = samples.iter().map(|s| s.weight).collect();
    drop(splats);
    drop(queries);
    drop(samples);
    timer.stop("splatting");

    // 5. Screening clusters (§3.7).
    timer.start("clusters");
    let t_max = tree.depth_count() - 1;
    let leaf_of: Vec<(u32, u32)> = positions
        .par_iter()
        .map(|p| {
            let dm = t_max - DEPTH_OFFSET;
            let c = cell_of(*p, dm);
            let n = 1i64 << dm;
            tree.descend(
                [(c[0] + n) as u64, (c[1] + n) as u64, (c[2] + n) as u64],
                t_max,
                t_max,
            )
        })
        .collect();
    let data = (channels > 0).then(|| {
        DataField::build(
            &tree,
            &leaf_of,
            &weights,
            &sample_values,
            channels,
            params.data_pull,
        )
    });
    drop(sample_values);
    let alpha = params.alpha();
    let clusters = if alpha > 0.0 {
        build_clusters(
            &tree,
            fem,
            tb as u32,
            &leaf_of,
            &positions,
            &weights,
            alpha * mean_area,
        )
    } else {
        (0..nlev).map(|_| Default::default()).collect()
    };
    timer.stop("clusters");

    // 6. Solve (§6, §7).
    timer.start("solving");
    let tables: Vec<Option<DepthTables>> = (0..nlev)
        .into_par_iter()
        .map(|t| (t >= tb).then(|| DepthTables::new(fem, vb, t as u32 - DEPTH_OFFSET)))
        .collect();
    let singular = alpha == 0.0 && params.boundary != Boundary::Dirichlet;
    let sol = solve(
        &Problem {
            tree: &tree,
            fem,
            tables: &tables,
            clusters: &clusters,
            base_level: tb as u32,
            iters: params.iters,
            singular,
            progress,
        },
        v,
    );
    drop(clusters);
    timer.stop("solving");
    for (n, d, m) in &sol.timings {
        timer.stats.push((format!("  {n}"), *d));
        timer.memory.push(*m);
    }

    // 7. Iso-value (§1.5).
    timer.start("iso-value");
    let eval = Evaluator::new(&tree, fem, &sol);
    let values: Vec<f64> = positions.par_iter().map(|p| eval.value(*p)).collect();
    let iso =
        values.iter().zip(&weights).map(|(v, w)| v * w).sum::<f64>() / weights.iter().sum::<f64>();
    timer.stop("iso-value");
    let nodes_per_depth = tree.levels[DEPTH_OFFSET as usize..]
        .iter()
        .map(|l| l.len())
        .collect();
    Ok(Implicit {
        tree,
        sol,
        fem,
        density,
        iso,
        width,
        origin,
        stats: Stats {
            points: n_points,
            dropped,
            samples: n_samples,
            nodes_per_depth,
            iso_value: iso,
            mean_sample_depth: sum_depth / sum_w,
            warnings,
            memory_estimate,
            stages: timer.stats,
            peak_memory: timer.memory,
        },
        data,
        attribute_types,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a sphere by the golden-angle spiral, with exact outward normals.
    fn sphere(n: usize, c: [f64; 3], r: f64) -> PointCloud {
        let mut pos = Vec::with_capacity(n);
        let mut nor = Vec::with_capacity(n);
        let ga = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rho = (1.0 - z * z).sqrt();
            let th = ga * i as f64;
            let u = [rho * th.cos(), rho * th.sin(), z];
            pos.push([c[0] + r * u[0], c[1] + r * u[1], c[2] + r * u[2]]);
            nor.push(u);
        }
        PointCloud::new(pos, nor).unwrap()
    }

    fn radial_crossing(imp: &Implicit, c: [f64; 3], r: f64, dir: [f64; 3]) -> f64 {
        // Bisection on χ − γ along the ray, between 0.5 r and 1.05 r.
        let f = |s: f64| {
            imp.value_grad_world([c[0] + s * dir[0], c[1] + s * dir[1], c[2] + s * dir[2]])
                .0
                - imp.iso
        };
        let (mut a, mut b) = (0.5 * r, 1.05 * r);
        assert!(
            f(a) > 0.0 && f(b) < 0.0,
            "no sign change: {} {}",
            f(a),
            f(b)
        );
        for _ in 0..60 {
            let m = 0.5 * (a + b);
            if f(m) > 0.0 {
                a = m
            } else {
                b = m
            }
        }
        0.5 * (a + b)
    }

    #[test]
    fn sphere_implicit_function_crosses_the_iso_value_on_the_sphere() {
        for degree in [1u8, 2] {
            let c = [0.1, -0.2, 0.3];
            let cloud = sphere(60_000, c, 1.0);
            let params = Params {
                depth: 7,
                degree,
                ..Params::default()
            };
            let imp = solve_implicit(&cloud, &params, &|_| {}).unwrap();
            let cell = 2.2 / 128.0;
            assert!((imp.iso - 0.5).abs() < 0.05, "iso {}", imp.iso);
            let mut worst: f64 = 0.0;
            for k in 0..50 {
                let z = 1.0 - 2.0 * (k as f64 + 0.5) / 50.0;
                let rho = (1.0 - z * z).sqrt();
                let th = 2.39996 * k as f64;
                let dir = [rho * th.cos(), rho * th.sin(), z];
                let s = radial_crossing(&imp, c, 1.0, dir);
                worst = worst.max((s - 1.0).abs());
            }
            eprintln!(
                "degree {degree}: iso {} worst radial error {worst} ({} cells)",
                imp.iso,
                worst / cell
            );
            assert!(worst < 0.1 * cell, "degree {degree}: radial error {worst}");
        }
    }
}
