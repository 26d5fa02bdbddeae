//! Before stage 1 (issue 18): the depth of a run whose resolution is given as a cell width
//! or left to the data ([`Resolution`]), resolved into a plain depth.
//!
//! - **Width** `w`, in the input's units, as PoissonRecon's `--width`: the depth is the
//!   smallest `D` with `2^D · w` at least the bounding cube's side, and the cube is widened,
//!   about the same centre, to exactly `2^D · w`, so that the finest cells are exactly `w`
//!   wide (through the scale: `scale · 2^D · w / cube`). The cube's side then lies between
//!   the usual one and twice it; the cells the user named are what they get, and clouds (or
//!   tiles) run at the same width share one cell size.
//! - **Auto**: the typical point spacing `s` is the median distance from a deterministic
//!   sample of [`SPACING_SAMPLES`] points to their nearest other point (a k-d tree over all
//!   usable points); the depth is `ceil(log2(cube / s))`: the shallowest whose finest cells
//!   are no wider than the spacing, which the Chamfer sweep of `bench/depth-auto` places
//!   within one depth of the most accurate one on 11 of the 16 shared sets, and within one
//!   of a depth within 2 % of it on 14 (the misses: `docs/design.md`). It is then lowered until
//!   the memory model of `tree.rs` fits the limit, with the octree's nodes predicted from the
//!   cells the points occupy at each depth.
//!
//! The full depth is kept no deeper than the chosen depth.

use rayon::prelude::*;

use super::prepare::{self, Frame, Selection};
use super::tree;
use crate::error::MemoryLimit;
use crate::normals::knn;
use crate::octree::DEPTH_OFFSET;
use crate::{Error, Params, PointCloud, Resolution, Result, MAX_DEPTH};

/// Points whose nearest-neighbour distance is measured for the spacing.
pub const SPACING_SAMPLES: usize = 4096;

/// Octree nodes per occupied cell of a depth above the base depth, in the memory prediction
/// of `--depth auto`: measured 7.9–10.3 at the depths where the shared clean sets splat
/// their samples (each occupied cell brings its brood and the 3 × 3 × 3 window the B-splines
/// need), rounded up. The finest depth, where the density puts few samples, and noisy clouds,
/// whose samples the noise stage lifts, hold far fewer: the prediction errs on the safe side.
const NODES_PER_OCCUPIED_CELL: f64 = 10.0;

/// How a run's depth was chosen, for the front ends to say.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthChoice {
    /// The depth chosen.
    pub depth: u32,
    /// The bounding cube's side, in the input's units (widened, for a width).
    pub cube: f64,
    /// The finest cells' width, `cube / 2^depth`.
    pub cell: f64,
    /// Why this depth.
    pub reason: DepthReason,
}

/// Why a depth was chosen.
#[derive(Debug, Clone, PartialEq)]
pub enum DepthReason {
    /// The smallest depth whose cells are no wider than the width asked for.
    Width {
        /// The width asked for.
        width: f64,
    },
    /// The shallowest depth whose cells are no wider than the point spacing; `limited` when
    /// the memory limit (or [`MAX_DEPTH`]) held it lower.
    Spacing {
        /// The median nearest-neighbour distance, in the input's units.
        spacing: f64,
        /// Points whose nearest-neighbour distance was measured.
        sampled: usize,
        /// The depth the spacing asked for.
        wanted: u32,
        /// What held the depth below `wanted`, if anything.
        limited: Option<DepthLimit>,
    },
}

/// What kept an automatic depth below the one the spacing asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepthLimit {
    /// The memory limit: the predicted peak memory at the next depth, and the limit.
    Memory {
        /// Predicted peak memory one depth deeper, in bytes.
        estimate: u64,
        /// The limit, in bytes.
        limit: u64,
        /// Where the limit came from.
        source: MemoryLimit,
    },
    /// The deepest depth spsr accepts.
    MaxDepth,
}

impl DepthChoice {
    /// One sentence: the depth, and why, naming parameters as a front end spells them
    /// (`spell("depth")` is `--depth` or `depth=`).
    pub fn message(&self, spell: &dyn Fn(&str) -> String) -> String {
        match &self.reason {
            DepthReason::Width { width } => format!(
                "{} {} gives {} {} (cells {} wide in a cube of {}, widened so that 2^{} \
                 cells span it exactly)",
                spell("width"),
                num(*width),
                spell("depth"),
                self.depth,
                num(self.cell),
                num(self.cube),
                self.depth
            ),
            DepthReason::Spacing {
                spacing,
                sampled,
                wanted,
                limited,
            } => {
                let mut s = format!(
                    "{} auto chose {} {}: the points are {} apart (median nearest-neighbour \
                     distance of {sampled} points), and cells of {} in a cube of {} are the \
                     first no wider",
                    spell("depth"),
                    spell("depth"),
                    self.depth,
                    num(*spacing),
                    num(self.cube / f64::from(1u32 << *wanted)),
                    num(self.cube),
                );
                match limited {
                    Some(DepthLimit::Memory {
                        estimate,
                        limit,
                        source,
                    }) => {
                        let what = match source {
                            MemoryLimit::Requested => format!("the {} limit", spell("max_memory")),
                            MemoryLimit::Available => "the memory available".into(),
                        };
                        s = format!(
                            "{s}; the spacing asked for {} {wanted}, lowered to fit {what} ({}; \
                             one depth deeper needs about {})",
                            spell("depth"),
                            crate::gib(*limit),
                            crate::gib(*estimate)
                        );
                    }
                    Some(DepthLimit::MaxDepth) => {
                        s = format!(
                            "{s}; the spacing asked for {} {wanted}, more than the deepest, \
                             {MAX_DEPTH}",
                            spell("depth")
                        );
                    }
                    None => {}
                }
                s
            }
        }
    }
}

/// A length with four significant digits.
fn num(x: f64) -> String {
    let s = format!("{x:.3e}");
    match s.split_once('e') {
        Some((m, e)) => {
            let e: i32 = e.parse().unwrap_or(0);
            if (-3..=4).contains(&e) {
                let decimals = (3 - e).max(0) as usize;
                format!("{x:.decimals$}")
            } else {
                format!("{m}e{e}")
            }
        }
        None => s,
    }
}

/// Parameters with the depth made plain, and how it was chosen.
#[derive(Debug, Clone)]
pub struct Resolved {
    /// The parameters to run with: [`Resolution::Depth`], the depth (and for a width, the
    /// scale) set.
    pub params: Params,
    /// How the depth was chosen; `None` when it was given.
    pub choice: Option<DepthChoice>,
}

/// Resolves `params.resolution` into a depth for `points`. Parameters with a given depth come
/// back unchanged.
pub fn resolve(points: &PointCloud, params: &Params) -> Result<Resolved> {
    if params.resolution == Resolution::Depth {
        return Ok(Resolved {
            params: params.clone(),
            choice: None,
        });
    }
    params.validate()?;
    if points.positions.len() != points.normals.len() {
        return Err(Error::LengthMismatch {
            positions: points.positions.len(),
            normals: points.normals.len(),
        });
    }
    let Selection { valid, frame, .. } = prepare::select(points, params)?;
    let (depth, scale, choice) = match params.resolution {
        Resolution::Width(width) => {
            let depth = depth_for_width(frame.width, width)?;
            let cube = width * f64::from(1u32 << depth);
            let choice = DepthChoice {
                depth,
                cube,
                cell: width,
                reason: DepthReason::Width { width },
            };
            (depth, params.scale * cube / frame.width, choice)
        }
        Resolution::Auto => {
            let (depth, reason) = auto_depth(points, &valid, frame, params);
            let choice = DepthChoice {
                depth,
                cube: frame.width,
                cell: frame.width / f64::from(1u32 << depth),
                reason,
            };
            (depth, params.scale, choice)
        }
        Resolution::Depth => unreachable!("handled above"),
    };
    Ok(Resolved {
        params: Params {
            depth,
            full_depth: params.full_depth.min(depth),
            scale,
            resolution: Resolution::Depth,
            ..params.clone()
        },
        choice: Some(choice),
    })
}

/// The smallest depth whose cells, `2^depth` to a cube at least `cube` wide, are `width`
/// wide; refused beyond [`MAX_DEPTH`].
fn depth_for_width(cube: f64, width: f64) -> Result<u32> {
    let depth = (0..=MAX_DEPTH).find(|&d| width * f64::from(1u32 << d) >= cube);
    match depth {
        Some(d) => Ok(d.max(1)),
        None => Err(Error::invalid(
            "width",
            width,
            format!(
                "at least {} for this cloud: its bounding cube is {} wide, and depth \
                 {MAX_DEPTH} (the deepest) makes cells of cube / 2^{MAX_DEPTH}",
                num(cube / f64::from(1u32 << MAX_DEPTH)),
                num(cube)
            ),
        )),
    }
}

/// The depth the spacing of the points asks for, lowered to fit the memory limit.
fn auto_depth(
    points: &PointCloud,
    valid: &[usize],
    frame: Frame,
    params: &Params,
) -> (u32, DepthReason) {
    let (spacing, sampled) = spacing(&points.positions, valid);
    let ratio = frame.width / spacing;
    let wanted = if ratio.is_finite() && ratio > 1.0 {
        ratio.log2().ceil().min(f64::from(MAX_DEPTH) + 1.0) as u32
    } else if ratio.is_finite() {
        1
    } else {
        // Every sampled point has a twin: no spacing to go by.
        MAX_DEPTH + 1
    };
    let mut depth = wanted.clamp(1, MAX_DEPTH);
    let mut limited = (wanted > MAX_DEPTH).then_some(DepthLimit::MaxDepth);
    if let Some((limit, source)) = tree::memory_limit(params) {
        let nodes = predicted_nodes(&points.positions, valid, frame, depth, params);
        let bytes = |d: u32| {
            tree::estimate_bytes(nodes[..=d as usize].iter().sum(), points.len(), params, d)
        };
        while depth > 1 && bytes(depth) > limit {
            limited = Some(DepthLimit::Memory {
                estimate: bytes(depth),
                limit,
                source,
            });
            depth -= 1;
        }
    }
    (
        depth,
        DepthReason::Spacing {
            spacing,
            sampled,
            wanted,
            limited,
        },
    )
}

/// The median distance from [`SPACING_SAMPLES`] of the points (every `n / samples`-th) to
/// their nearest other point at a positive distance (twins do not count), and how many were
/// measured. Infinite when every sampled point has only twins nearby.
fn spacing(positions: &[[f64; 3]], valid: &[usize]) -> (f64, usize) {
    let tree = knn::Tree::new(positions, valid.iter().map(|&i| i as u32).collect());
    let m = SPACING_SAMPLES.min(valid.len());
    let mut d: Vec<f64> = (0..m)
        .into_par_iter()
        .map_init(Vec::new, |buf, k| {
            let i = valid[k * valid.len() / m];
            // A few neighbours, so that a duplicate or two does not hide the spacing.
            tree.nearest(positions[i], 8, buf);
            buf.iter()
                .map(|&(_, d2)| d2)
                .find(|&d2| d2 > 0.0)
                .map_or(f64::INFINITY, f64::sqrt)
        })
        .collect();
    d.sort_unstable_by(f64::total_cmp);
    (d[m / 2], m)
}

/// The octree nodes predicted at each unit depth `0..=depth`: complete levels down to the
/// base depth, and below it [`NODES_PER_OCCUPIED_CELL`] per cell the points occupy.
fn predicted_nodes(
    positions: &[[f64; 3]],
    valid: &[usize],
    frame: Frame,
    depth: u32,
    params: &Params,
) -> Vec<u64> {
    let occupied = occupied_cells(positions, valid, frame, depth);
    let base = params.full_depth.min(depth).max(1);
    (0..=depth)
        .map(|d| {
            if d <= base {
                // The complete level with its ring of outside nodes.
                let side = (1u64 << d) + 2 * u64::from(DEPTH_OFFSET);
                side * side * side
            } else {
                (NODES_PER_OCCUPIED_CELL * occupied[d as usize] as f64).ceil() as u64
            }
        })
        .collect()
}

/// The number of cells at each depth `0..=depth` that hold at least one of the points: the
/// points' Morton codes at `depth`, sorted; two neighbours in that order first differ at the
/// depth of the highest bit in which their codes differ.
fn occupied_cells(positions: &[[f64; 3]], valid: &[usize], frame: Frame, depth: u32) -> Vec<u64> {
    let n = 1u64 << depth;
    let mut codes: Vec<u64> = valid
        .par_iter()
        .map(|&i| {
            let u = frame.to_unit(positions[i]);
            crate::morton::encode(std::array::from_fn(|a| {
                ((u[a] * n as f64) as u64).min(n - 1)
            }))
        })
        .collect();
    codes.par_sort_unstable();
    // first[d]: neighbours that first differ at depth d (1-based: the cell of depth d).
    let mut first = vec![0u64; depth as usize + 1];
    for w in codes.windows(2) {
        let x = w[0] ^ w[1];
        if x != 0 {
            let bit = 63 - x.leading_zeros();
            // Bits 3(depth − d) .. 3(depth − d) + 2 hold depth d's choice of child.
            let d = depth - bit / 3;
            first[d as usize] += 1;
        }
    }
    let mut counts = vec![0u64; depth as usize + 1];
    let mut acc = u64::from(!codes.is_empty());
    for d in 0..=depth as usize {
        acc += first[d];
        counts[d] = acc;
    }
    counts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_width_gives_the_smallest_depth_whose_cells_are_no_wider() {
        assert_eq!(depth_for_width(1.0, 1.0 / 256.0).unwrap(), 8);
        assert_eq!(depth_for_width(1.0, 1.0 / 255.0).unwrap(), 8);
        assert_eq!(depth_for_width(1.0, 1.0 / 257.0).unwrap(), 9);
        assert_eq!(depth_for_width(1.0, 10.0).unwrap(), 1);
        let e = depth_for_width(1.0, 1e-7).unwrap_err();
        assert!(e.to_string().contains("width"), "{e}");
    }

    #[test]
    fn occupied_cells_count_the_distinct_cells_of_each_depth() {
        let frame = Frame {
            origin: [0.0; 3],
            width: 1.0,
        };
        // Three points: two share the cell of depth 1 and differ at depth 3.
        let p = [[0.1, 0.1, 0.1], [0.2, 0.1, 0.1], [0.9, 0.9, 0.9]];
        let c = occupied_cells(&p, &[0, 1, 2], frame, 3);
        assert_eq!(c, vec![1, 2, 2, 3]);
    }

    #[test]
    fn lengths_read_with_four_significant_digits() {
        assert_eq!(num(0.0012344), "0.001234");
        assert_eq!(num(2.5), "2.500");
        assert_eq!(num(1234.4), "1234");
        assert_eq!(num(1.5e-6), "1.500e-6");
    }
}
