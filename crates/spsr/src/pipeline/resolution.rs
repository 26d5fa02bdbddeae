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
//!   usable points). The same sample's noise is the median scatter of each point's
//!   [`CURVATURE_NEIGHBOURS`] nearest about the quadratic height field fitted to them. Where
//!   it is under [`CLEAN_SHARE`] of the spacing (a clean cloud), the depth is the shallowest
//!   whose finest cells' face diagonals are no longer than the spacing,
//!   `ceil(log2(√2 · cube / s))`: the surface between the samples is then known, and a plane
//!   crossing a cell aslant spans its diagonal; a noisier cloud gets the shallowest whose
//!   cells are no wider than the spacing, `ceil(log2(cube / s))`, since finer cells would
//!   follow its noise. The Chamfer sweep of `bench/depth-auto` places the choice within one
//!   depth of the most accurate one on all 16 shared sets (`docs/design.md`). A smooth
//!   surface gets
//!   less: the same sample's curvature (a quadratic height field fitted to each point's
//!   [`CURVATURE_NEIGHBOURS`] nearest) bounds the depth where the finest cells reach
//!   1/[`CELLS_PER_RADIUS`] of the radius of curvature that all but 1 % of the points stay
//!   above; deeper cells only follow the sampling there (the analytic sphere's Chamfer
//!   distance grows by 50 % from depth 8 to 10). The bound lowers the spacing's depth by at
//!   most [`MAX_SMOOTH_LOWERING`]. The depth is then lowered until
//!   the memory model of `tree.rs` fits the limit, with the octree's nodes predicted from the
//!   cells the points occupy at each depth.
//!
//! The full depth is kept no deeper than the chosen depth.

use rayon::prelude::*;

use super::noise::QuadricFit;
use super::prepare::{self, Frame, Selection};
use super::tree;
use crate::error::MemoryLimit;
use crate::normals::estimate::eigen_sym3;
use crate::normals::knn;
use crate::octree::DEPTH_OFFSET;
use crate::{Error, Params, PointCloud, Resolution, Result, MAX_DEPTH};

/// Points whose nearest-neighbour distance is measured for the spacing.
pub const SPACING_SAMPLES: usize = 4096;

/// A cloud whose noise (the median scatter about the local quadratic fits) is under this
/// share of its spacing is clean, and gets cells whose face diagonals match the spacing;
/// a noisier one gets cells as wide as the spacing. Measured (`bench/depth-auto`): the clean
/// shared sets 0.00–0.10, the kitten scan 0.04, CGAL's oni scan 0.42, the noisy sets
/// (0.25 % and 0.5 % of the diagonal, and the ramp) 0.85–1.06. On the clean sets the most
/// accurate depth lies one or two deeper than the cells as wide as the spacing; on the noisy
/// ones at that depth or one shallower.
pub const CLEAN_SHARE: f64 = 0.25;

/// Neighbours (the point itself included) of each sampled point in the quadratic fit that
/// reads the surface's curvature there.
pub const CURVATURE_NEIGHBOURS: usize = 24;

/// The share of the sampled points whose curvature the depth must resolve: the rest (edges,
/// corners, the tips of small features) may be sharper. With 99 %, the fandisk's creases and
/// a box's edges keep their depth; only shapes smooth nearly everywhere are lowered.
const CURVATURE_SHARE: f64 = 0.99;

/// Finest cells of at most `1 / CELLS_PER_RADIUS` of the radius of curvature resolve a smooth
/// surface: on the analytic shapes (`bench/depth-auto`, Chamfer to the exact surface) the
/// most accurate cells were 1/116 of the radius on the sphere (depth 8 of `sphere_200k`; depth
/// 10, the spacing's, is 50 % farther from the sphere) and 1/30 of the tube's on the torus
/// (depth 8 of `torus_200k`); deeper ones only followed the sampling. 32, the coarser end,
/// keeps every depth a surface as curved as the torus can use.
pub const CELLS_PER_RADIUS: f64 = 32.0;

/// The most depths the curvature may take off the spacing's depth: a flat surface has no
/// curvature to resolve, but its outline and holes still need cells near the spacing.
pub const MAX_SMOOTH_LOWERING: u32 = 2;

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
    /// The shallowest depth whose cells are no wider than the point spacing, or shallower
    /// on a smooth surface (`smooth`); `limited` when the memory limit (or [`MAX_DEPTH`])
    /// held it lower.
    Spacing {
        /// The median nearest-neighbour distance, in the input's units.
        spacing: f64,
        /// Points whose nearest-neighbour distance was measured.
        sampled: usize,
        /// The points' median scatter about their local quadratic fits (input units), when
        /// enough could be measured.
        noise: Option<f64>,
        /// Whether the noise is under [`CLEAN_SHARE`] of the spacing, so that the cells'
        /// face diagonals, not their sides, match the spacing.
        clean: bool,
        /// The depth the spacing asked for.
        wanted: u32,
        /// When the surface is smooth enough to need fewer depths: the radius of curvature
        /// all but 1 % of the sampled points stay above (input units), and the depth it
        /// allowed (at least `wanted − MAX_SMOOTH_LOWERING`).
        smooth: Option<(f64, u32)>,
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
                noise,
                clean,
                wanted,
                smooth,
                limited,
            } => {
                let cells = num(self.cube / f64::from(1u32 << *wanted));
                let scatter = noise.map_or("an unmeasured distance".into(), num);
                let why = if *clean {
                    format!(
                        "they scatter {scatter} about a smooth surface (median of local \
                         quadratic fits), under a quarter of that, so cells of {cells} in a \
                         cube of {} are the first whose face diagonals are no longer",
                        num(self.cube)
                    )
                } else {
                    format!(
                        "they scatter {scatter} about a smooth surface (median of local \
                         quadratic fits), a quarter of that or more, so cells of {cells} in a \
                         cube of {} are the first no wider (finer cells would follow the noise)",
                        num(self.cube)
                    )
                };
                let mut s = format!(
                    "{} auto chose {} {}: the points are {} apart (median nearest-neighbour \
                     distance of {sampled} points); {why}",
                    spell("depth"),
                    spell("depth"),
                    self.depth,
                    num(*spacing),
                );
                if let Some((radius, smooth)) = smooth {
                    s = format!(
                        "{s}; but the surface is smooth (99 % of the points lie where its \
                         radius of curvature is {} or more), and cells of {} at {} {smooth} \
                         resolve it: deeper cells would only follow the sampling",
                        num(*radius),
                        num(self.cube / f64::from(1u32 << *smooth)),
                        spell("depth"),
                    );
                }
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
    let survey = survey(&points.positions, valid);
    let (spacing, sampled) = (survey.spacing, survey.sampled);
    let clean = survey.noise.is_some_and(|r| r < CLEAN_SHARE * spacing);
    let ratio = frame.width / spacing * if clean { std::f64::consts::SQRT_2 } else { 1.0 };
    let wanted = if ratio.is_finite() && ratio > 1.0 {
        ratio.log2().ceil().min(f64::from(MAX_DEPTH) + 1.0) as u32
    } else if ratio.is_finite() {
        1
    } else {
        // Every sampled point has a twin: no spacing to go by.
        MAX_DEPTH + 1
    };
    let smooth = survey
        .curvature
        .map(|k| (1.0 / k, smooth_depth(frame.width * k, wanted)))
        .filter(|&(_, d)| d < wanted);
    let mut depth = smooth.map_or(wanted, |s| s.1).clamp(1, MAX_DEPTH);
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
            noise: survey.noise,
            clean,
            wanted,
            smooth,
            limited,
        },
    )
}

/// The depth a surface of curvature `k_cube` (per cube side) needs, given the spacing's
/// depth `wanted`: the first whose cells are at most 1/[`CELLS_PER_RADIUS`] of the radius of
/// curvature, and no more than [`MAX_SMOOTH_LOWERING`] below `wanted`.
fn smooth_depth(k_cube: f64, wanted: u32) -> u32 {
    let floor = wanted.saturating_sub(MAX_SMOOTH_LOWERING).max(1);
    let need = k_cube * CELLS_PER_RADIUS;
    if !need.is_finite() {
        return wanted;
    }
    let d = if need > 1.0 { need.log2().ceil() } else { 0.0 };
    (d.min(f64::from(u32::MAX)) as u32).max(floor)
}

/// What `--depth auto` reads from a sample of the points.
struct Survey {
    /// The median nearest-neighbour distance (infinite when every sampled point has only
    /// twins nearby).
    spacing: f64,
    /// Points sampled.
    sampled: usize,
    /// The curvature (1 / input units) that [`CURVATURE_SHARE`] of the sampled points stay
    /// at or below; `None` when too few could be measured.
    curvature: Option<f64>,
    /// The median scatter of the sampled points' neighbourhoods about their quadratic fits
    /// (input units); `None` when too few could be measured.
    noise: Option<f64>,
}

/// [`SPACING_SAMPLES`] of the points (every `n / samples`-th): the median distance to their
/// nearest other point at a positive distance (twins do not count), their curvature and
/// their noise.
fn survey(positions: &[[f64; 3]], valid: &[usize]) -> Survey {
    let tree = knn::Tree::new(positions, valid.iter().map(|&i| i as u32).collect());
    let m = SPACING_SAMPLES.min(valid.len());
    let (mut d, shape): (Vec<f64>, Vec<Option<(f64, f64)>>) = (0..m)
        .into_par_iter()
        .map_init(Vec::new, |buf, s| {
            let i = valid[s * valid.len() / m];
            tree.nearest(positions[i], CURVATURE_NEIGHBOURS, buf);
            // The first positive distance, so that a duplicate or two does not hide the
            // spacing.
            let near = buf
                .iter()
                .map(|&(_, d2)| d2)
                .find(|&d2| d2 > 0.0)
                .map_or(f64::INFINITY, f64::sqrt);
            (near, local_shape(positions, positions[i], buf))
        })
        .unzip();
    d.sort_unstable_by(f64::total_cmp);
    let (mut k, mut r): (Vec<f64>, Vec<f64>) = shape.into_iter().flatten().unzip();
    // Quantiles of a few hundred values at least.
    let enough = k.len() >= 256 && k.len() * 2 >= m;
    let quantile = |v: &mut Vec<f64>, share: f64| {
        v.sort_unstable_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * share).round() as usize]
    };
    Survey {
        spacing: d[m / 2],
        sampled: m,
        curvature: enough.then(|| quantile(&mut k, CURVATURE_SHARE)),
        noise: enough.then(|| quantile(&mut r, 0.5)),
    }
}

/// The quadratic height field fitted over the plane of `p`'s neighbours `near` (cloud indices
/// and squared distances, from the tree): its larger principal curvature in absolute value
/// (1 / input units) at `p`, and the neighbours' scatter about it (input units); `None` when
/// they are too few, coincide or do not span a plane.
fn local_shape(positions: &[[f64; 3]], p: [f64; 3], near: &[(u32, f64)]) -> Option<(f64, f64)> {
    let reach = near.last()?.1.sqrt();
    if near.len() < CURVATURE_NEIGHBOURS || reach <= 0.0 {
        return None;
    }
    // Offsets in units of the neighbourhood's reach, so that the fit is conditioned alike
    // at every scale.
    let q: Vec<[f64; 3]> = near
        .iter()
        .map(|&(j, _)| std::array::from_fn(|a| (positions[j as usize][a] - p[a]) / reach))
        .collect();
    let n = q.len() as f64;
    let mean: [f64; 3] = std::array::from_fn(|a| q.iter().map(|x| x[a]).sum::<f64>() / n);
    let idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];
    let cov = idx.map(|(a, b)| {
        q.iter()
            .map(|x| (x[a] - mean[a]) * (x[b] - mean[b]))
            .sum::<f64>()
            / n
    });
    let (_, v) = eigen_sym3(&cov);
    let dot = |x: &[f64; 3], y: &[f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let mut fit = QuadricFit::default();
    for x in &q {
        fit.add(dot(x, &v[1]), dot(x, &v[2]), dot(x, &v[0]));
    }
    let b = fit.coefficients()?;
    // The height field's Hessian [[2 b3, b4], [b4, 2 b5]]: its larger eigenvalue in size.
    let (mid, half) = (b[3] + b[5], ((b[3] - b[5]).powi(2) + b[4] * b[4]).sqrt());
    let k = (mid.abs() + half) / reach;
    let scatter = fit.residual()? * reach;
    (k.is_finite() && scatter.is_finite()).then_some((k, scatter))
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
    fn the_survey_reads_a_spheres_curvature_and_a_planes_absence_of_it() {
        for r in [0.5, 2.0, 300.0] {
            let p = crate::pipeline::tests::sphere(20_000, [0.5, -1.0, 2.0], r).positions;
            let all: Vec<usize> = (0..p.len()).collect();
            let s = survey(&p, &all);
            let k = s.curvature.expect("a sphere's curvature");
            assert!((k * r - 1.0).abs() < 0.03, "radius {r}: curvature {k}");
            // The spacing of n points on the area 4πr²: about √(4πr²/n) · 0.95.
            let even = (4.0 * std::f64::consts::PI * r * r / p.len() as f64).sqrt();
            assert!((s.spacing / even - 1.0).abs() < 0.2, "{} {even}", s.spacing);
        }
        let plane: Vec<[f64; 3]> = (0..10_000)
            .map(|i| [(i % 100) as f64 * 0.01, (i / 100) as f64 * 0.01, 0.5])
            .collect();
        let all: Vec<usize> = (0..plane.len()).collect();
        let k = survey(&plane, &all).curvature.expect("a plane's curvature");
        assert!(k < 1e-6, "{k}");
    }

    #[test]
    fn a_smooth_surface_takes_the_depth_its_curvature_needs_and_at_most_two_less() {
        // The unit sphere in a cube of 2.2: cells of a 32nd of the radius need depth 7.
        assert_eq!(smooth_depth(2.2, 9), 7);
        assert_eq!(smooth_depth(2.2, 8), 7);
        assert_eq!(smooth_depth(2.2, 7), 7);
        // Never more than two below the spacing's depth (a plane has no curvature at all).
        assert_eq!(smooth_depth(2.2, 10), 8);
        assert_eq!(smooth_depth(0.0, 9), 7);
        assert_eq!(smooth_depth(0.0, 2), 1);
        // A curvature the spacing's depth cannot resolve leaves it alone.
        assert_eq!(smooth_depth(1000.0, 9), 15);
        assert_eq!(smooth_depth(f64::INFINITY, 9), 9);
    }

    #[test]
    fn lengths_read_with_four_significant_digits() {
        assert_eq!(num(0.0012344), "0.001234");
        assert_eq!(num(2.5), "2.500");
        assert_eq!(num(1234.4), "1234");
        assert_eq!(num(1.5e-6), "1.500e-6");
    }
}
