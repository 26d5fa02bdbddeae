//! Normals for unoriented point clouds: estimation, orientation and comparison.
//!
//! - [`estimate`] fits a plane to each point's k nearest neighbours (principal component
//!   analysis on a k-d tree), which gives each point a normal *line*; k is chosen from the
//!   cloud's noise unless given.
//! - [`orient`] picks the sign of every normal so that the normals point outward:
//!   towards a viewpoint or per-scan sensor origins, by propagation over a minimum spanning tree
//!   of the neighbour graph ([`Orientation::Mst`], Hoppe et al. 1992), or by a global method
//!   that corrects the propagation with the indicator function of a Poisson reconstruction
//!   ([`Orientation::Global`]).
//! - [`compare`] measures normals against reference normals.
//!
//! ```
//! use spsr::normals::{compare, estimate, orient, NormalParams, Orientation};
//! // A sphere of 2000 points, without normals.
//! let ga = std::f64::consts::PI * (3.0 - 5f64.sqrt());
//! let pts: Vec<[f64; 3]> = (0..2000)
//!     .map(|i| {
//!         let z = 1.0 - 2.0 * (i as f64 + 0.5) / 2000.0;
//!         let r = (1.0 - z * z).sqrt();
//!         [r * (ga * i as f64).cos(), r * (ga * i as f64).sin(), z]
//!     })
//!     .collect();
//! let mut normals = estimate(&pts, &NormalParams::default())?.normals;
//! orient(&pts, &mut normals, &Orientation::mst())?;
//! let c = compare(&normals, &pts)?; // on the unit sphere the position is the outward normal
//! assert!(c.flipped_fraction == 0.0 && c.mean_angle_deg < 2.0);
//! # Ok::<(), spsr::Error>(())
//! ```
//!
//! Everything here works on plain slices of positions and normals, so that it is independent of
//! file formats. Results do not depend on the number of threads: every parallel loop writes
//! its own outputs, sorts use total orders, and sums run in a fixed order.
//!
//! ## How it works
//!
//! **Neighbours.** An immutable k-d tree (`kiddo`) over the finite points; queries run in
//! Z-order (Morton order) of the points, which keeps consecutive queries in the same part of
//! the tree. Ties in distance are ordered by point index.
//!
//! **Estimation.** The normal line of a point is the eigenvector of the smallest eigenvalue of
//! the covariance of the point and its k nearest neighbours (cyclic Jacobi rotations). The
//! size k is chosen from the noise ([`NormalParams::neighbours`]). On clean clouds the fit is
//! refined by iteratively reweighted least squares, the weights falling with the distance of
//! each neighbour from the plane through the point (Gaussian, width twice the robust scale
//! of those distances), so that a point near a crease fits its own side. A neighbourhood whose
//! points all coincide or lie on one line has no such direction: its point takes the normal
//! of the nearest point whose neighbourhood is a proper plane fit.
//!
//! **Propagation ([`Orientation::Mst`]).** The graph joins every point to its 10 nearest
//! neighbours (symmetrised). Its minimum spanning forest under the weights `1 − |n_i · n_j|`
//! (Kruskal: one parallel sort of the edges by weight and index, then a union–find) hands the
//! orientation from point to point along the edges whose normals are most nearly parallel.
//! Each connected piece is then turned so that `Σ a_i (p_i − g) · n_i > 0`, with `a_i` the
//! area a point stands for and `g` the centroid of the cloud: for a closed surface this sum
//! is three times the enclosed volume when the normals point out (the divergence theorem),
//! whatever `g`. Memory is linear in the number of points (the graph holds about 6 edges per
//! point); no step is quadratic.
//!
//! **Global correction ([`Orientation::Global`]).** Propagation cannot tell two nearby sheets
//! apart when the neighbour graph joins them (or when each is a piece of its own): the two
//! sides of a thin part, nested surfaces. The correction reconstructs the indicator
//! function χ from the current normals by the Poisson solver of this crate, without screening
//! and with χ = 0 on the boundary of the cube, so that χ is a smoothed winding-number field
//! of the oriented points (about A inside, 0 outside). It samples χ just behind and just in
//! front of every point and flips the normals whose neighbourhood mostly finds the indicator
//! stepping the wrong way, the front inside a region counted twice, or the back outside a
//! region counted negatively (see `orient::correct`). This repeats, with a fresh
//! reconstruction each round, until a round flips at most one normal in 10,000, or for
//! `rounds` rounds; each normal flips at most once.

pub(crate) mod estimate;
mod graph;
pub(crate) mod knn;
mod orient;

use rayon::prelude::*;

use crate::vec3::{dot, norm};
use crate::{Error, Result};
use knn::{finite_points, Tree};

/// Parameters of [`estimate`].
#[derive(Debug, Clone, PartialEq)]
pub struct NormalParams {
    /// Neighbours in each plane fit (the point itself is added). `None` (default) chooses it
    /// from the cloud, on a sample of 2048 points: 16 when the 16-point neighbourhoods are
    /// flat (clean data: Hoppe et al. used 15–20 neighbours, Open3D's and CGAL's examples
    /// 18–30, and fewer follow detail more closely); for noisy clouds, whose small
    /// neighbourhoods are thick blobs rather than discs, the smallest of 24, 32, 48, 64, 96,
    /// 128, 192 whose plane fits have a median estimated angular error of at most
    /// [`NormalParams::target_error`]. k-nearest neighbourhoods adapt their radius to the
    /// local density by themselves.
    pub neighbours: Option<usize>,
    /// The angular error (radians) of the plane fits that the automatic neighbourhood size
    /// aims at on noisy clouds, as estimated from the spread of the points: noise σ across a
    /// disc of radius r and k points tilts the fitted plane by about `2σ / (r √k)`. Default
    /// 0.03. Measured on the bunny with noise of 0.25 % and 0.5 % of its diagonal, it picks
    /// 128 and 192 neighbours, whose normals give the reconstructions closest to the true
    /// surface (4 % and 3 % closer than with 64 and 128 neighbours, which are the sizes of
    /// smallest angle to the sets' own, perturbed, normals).
    pub target_error: f64,
}

impl Default for NormalParams {
    fn default() -> Self {
        Self {
            neighbours: None,
            target_error: 0.03,
        }
    }
}

/// The output of [`estimate`].
#[derive(Debug, Clone, PartialEq)]
pub struct Estimated {
    /// One unit normal per input point, in input order, with an arbitrary sign (see
    /// [`orient`]). Points with a non-finite coordinate get the zero vector.
    pub normals: Vec<[f64; 3]>,
    /// Neighbours used in each plane fit.
    pub neighbours: usize,
    /// Whether the cloud was classified as noisy (its smallest neighbourhoods are thick; see
    /// [`NormalParams::neighbours`]); the fits of noisy clouds are not refined.
    pub noisy: bool,
    /// Points whose neighbourhood was degenerate (all neighbours coincident or on one line);
    /// each took the normal of the nearest point whose neighbourhood was not.
    pub degenerate: usize,
    /// Points skipped because a coordinate is not finite.
    pub non_finite: usize,
}

/// Fewest finite points [`estimate`] accepts: three points span a plane.
pub const MIN_POINTS: usize = 3;

/// Estimates a normal line at every point from a plane fitted to its nearest neighbours.
///
/// On clouds classified as clean (see [`NormalParams::neighbours`]) each fit is then
/// refined by reweighting the neighbours by their distance to the plane through the point,
/// which keeps creases and facets from being averaged away; on noisy clouds that would follow
/// the noise, so the plain fit stands.
///
/// Points with a non-finite coordinate are skipped: they are nobody's neighbour and get the
/// zero normal (which the reconstruction then drops). A point whose neighbourhood spans no
/// plane (all its neighbours coincide with it or lie on one line) takes the normal of the
/// nearest point whose neighbourhood does; such points are counted in
/// [`Estimated::degenerate`]. With fewer points than neighbours, all points are used.
///
/// # Errors
/// [`Error::TooFewPoints`] with fewer than [`MIN_POINTS`] finite points;
/// [`Error::Degenerate`] when no neighbourhood spans a plane (all points on one line);
/// [`Error::InvalidParameter`] for 0 neighbours or a non-positive target error.
pub fn estimate(positions: &[[f64; 3]], params: &NormalParams) -> Result<Estimated> {
    if params.neighbours == Some(0) {
        return Err(Error::invalid("neighbours", 0, "at least 1"));
    }
    if !(params.target_error > 0.0 && params.target_error.is_finite()) {
        return Err(Error::invalid(
            "target_error",
            params.target_error,
            "a positive number",
        ));
    }
    check_len(positions.len())?;
    let finite = finite_points(positions);
    let non_finite = positions.len() - finite.len();
    if finite.len() < MIN_POINTS {
        return Err(Error::TooFewPoints {
            usable: finite.len(),
            dropped: non_finite,
            required: MIN_POINTS,
        });
    }
    let tree = Tree::new(positions, finite.clone());
    let (auto_k, clean) = estimate::choose_k(positions, &tree, &finite, params.target_error);
    let k = params.neighbours.unwrap_or(auto_k).min(finite.len() - 1);
    let refine = clean;
    // Fits computed in the tree's spatial order, then put in place.
    let order = tree.points();
    let fits: Vec<[f64; 3]> = order
        .par_iter()
        .map_init(Vec::new, |buf, &i| {
            let p = positions[i as usize];
            tree.nearest(p, k + 1, buf);
            if let Some(s) = buf.iter().position(|&(j, _)| j == i) {
                buf.remove(s);
            }
            buf.truncate(k);
            let fit = estimate::fit_plane(positions, p, buf);
            if refine {
                estimate::refine(positions, p, buf, fit)
            } else {
                fit.normal
            }
        })
        .collect();
    let mut normals = vec![[0.0; 3]; positions.len()];
    for (&i, n) in order.iter().zip(fits) {
        normals[i as usize] = n;
    }
    let good: Vec<u32> = finite
        .iter()
        .copied()
        .filter(|&i| normals[i as usize] != [0.0; 3])
        .collect();
    let degenerate = finite.len() - good.len();
    if good.is_empty() {
        return Err(Error::Degenerate(
            "no neighbourhood spans a plane: the points lie on one line or coincide".into(),
        ));
    }
    if degenerate > 0 {
        let good_tree = Tree::new(positions, good);
        let fixes: Vec<(usize, [f64; 3])> = finite
            .par_iter()
            .filter(|&&i| normals[i as usize] == [0.0; 3])
            .map_init(Vec::new, |buf, &i| {
                good_tree.nearest(positions[i as usize], 1, buf);
                (i as usize, normals[buf[0].0 as usize])
            })
            .collect();
        for (i, n) in fixes {
            normals[i] = n;
        }
    }
    Ok(Estimated {
        normals,
        neighbours: k,
        noisy: !clean,
        degenerate,
        non_finite,
    })
}

/// How [`orient`] chooses the sign of each normal.
#[derive(Debug, Clone, PartialEq)]
pub enum Orientation {
    /// Every normal points towards this sensor position (its half-space).
    Viewpoint([f64; 3]),
    /// Per-scan sensor positions: `(first point, origin)` pairs in increasing order of first
    /// point, the first at point 0; each scan runs to the next one's first point. Each normal
    /// points towards its scan's origin.
    ScanOrigins(Vec<(usize, [f64; 3])>),
    /// Propagation along a minimum spanning tree of the neighbour graph, then each connected
    /// piece turned to point outward.
    Mst {
        /// Neighbours of each point in the graph (the graph is the union of every point's
        /// nearest neighbours, so a point can have more). Default 10: enough to connect the
        /// surface around sharp features and across small gaps, few enough that the graph
        /// rarely links nearby but separate sheets.
        neighbours: usize,
    },
    /// Propagation as [`Orientation::Mst`], then corrected by the indicator function of
    /// Poisson reconstructions from the current normals, repeatedly.
    Global {
        /// Neighbours of each point in the graph, as for [`Orientation::Mst`]. Default 10.
        neighbours: usize,
        /// Octree depth of the reconstructions; `None` (default) picks it from the number of
        /// points (see [`default_global_depth`]), and on noisy clouds one level coarser for
        /// each halving until the finest cells are at least as wide as the typical distance of
        /// the points from their neighbours' tangent planes (measured on the bunny with noise
        /// of 0.5 % of its diagonal: depth 7 corrects, depth 8 and 9 follow the noise).
        depth: Option<u32>,
        /// Most correction rounds; a round that flips at most one normal in 10,000 ends the
        /// correction earlier. Default 4: measured, later rounds flip next to nothing.
        rounds: u32,
    },
}

impl Orientation {
    /// [`Orientation::Mst`] with its defaults.
    pub fn mst() -> Self {
        Orientation::Mst { neighbours: 10 }
    }

    /// [`Orientation::Global`] with its defaults.
    pub fn global() -> Self {
        Orientation::Global {
            neighbours: 10,
            depth: None,
            rounds: 4,
        }
    }
}

/// What [`orient`] did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OrientStats {
    /// Normals whose sign changed.
    pub flipped: usize,
    /// Connected pieces of the neighbour graph (propagating modes).
    pub components: usize,
    /// Normals that could not be oriented: zero or non-finite normals, or non-finite positions.
    pub skipped: usize,
    /// Normals the global correction flipped, per round.
    pub corrections: Vec<usize>,
}

/// The default depth of the [`Orientation::Global`] reconstructions for `n` points on a clean
/// surface: enough that a reconstruction's finest cells are about as wide as the spacing of
/// the points on a compact surface (`n ≈ 1.5 × 4^depth`), between 6 and 9 (deeper costs
/// more time than it corrects).
pub fn default_global_depth(n: usize) -> u32 {
    let d = ((n as f64 / 1.5).max(1.0).log2() / 2.0).round() as u32;
    d.clamp(6, 9)
}

/// Chooses the sign of every normal (in place) so that the normals point outward, or towards
/// the sensor. Only signs change; zero or non-finite normals and points with a non-finite
/// coordinate are left as they are.
///
/// # Errors
/// [`Error::LengthMismatch`] when `normals` and `positions` differ in length;
/// [`Error::InvalidParameter`] for a non-finite viewpoint, scan origins out of order or not
/// starting at point 0, or 0 neighbours; errors of the Poisson reconstruction for
/// [`Orientation::Global`].
pub fn orient(
    positions: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    how: &Orientation,
) -> Result<OrientStats> {
    if normals.len() != positions.len() {
        return Err(Error::LengthMismatch {
            positions: positions.len(),
            normals: normals.len(),
        });
    }
    check_len(positions.len())?;
    let skipped = positions.len() - orient::usable_points(positions, normals).len();
    let mut stats = OrientStats {
        skipped,
        ..OrientStats::default()
    };
    match how {
        Orientation::Viewpoint(v) => {
            check_origin(*v, "viewpoint")?;
            stats.flipped = orient::towards(positions, normals, |_| *v);
        }
        Orientation::ScanOrigins(scans) => {
            if let Some(s) = scans.first().filter(|s| s.0 != 0) {
                return Err(Error::invalid(
                    "scan_origins",
                    format!("a first scan starting at point {}", s.0),
                    "a first scan starting at point 0",
                ));
            }
            if scans.is_empty() {
                return Err(Error::invalid("scan_origins", "none", "at least one scan"));
            }
            for w in scans.windows(2) {
                if w[1].0 <= w[0].0 {
                    return Err(Error::invalid(
                        "scan_origins",
                        format!("a scan starting at point {} after {}", w[1].0, w[0].0),
                        "scans starting at increasing points",
                    ));
                }
            }
            for s in scans {
                check_origin(s.1, "scan_origins")?;
            }
            let origin_of = |i: usize| scans[scans.partition_point(|s| s.0 <= i) - 1].1;
            stats.flipped = orient::towards(positions, normals, origin_of);
        }
        Orientation::Mst { neighbours } | Orientation::Global { neighbours, .. } => {
            if *neighbours == 0 {
                return Err(Error::invalid("orient_neighbours", 0, "at least 1"));
            }
            let before: Vec<[f64; 3]> = normals.to_vec();
            let graph = orient::Graph::new(positions, normals, *neighbours);
            let prop = orient::propagate(positions, normals, &graph);
            orient::outward(positions, normals, &graph, &prop.component, prop.components);
            stats.components = prop.components;
            if let Orientation::Global { depth, rounds, .. } = how {
                stats.corrections = orient::correct(positions, normals, &graph, *depth, *rounds)?;
            }
            stats.flipped = before
                .iter()
                .zip(normals.iter())
                .filter(|(a, b)| dot(**a, **b) < 0.0)
                .count();
        }
    }
    Ok(stats)
}

fn check_origin(o: [f64; 3], name: &'static str) -> Result<()> {
    if o.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(Error::invalid(
            name,
            format!("{o:?}"),
            "a finite sensor position",
        ))
    }
}

/// How closely normals match reference normals, from [`compare`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Comparison {
    /// Pairs compared: both normals finite and non-zero.
    pub compared: usize,
    /// Pairs skipped because either normal is zero or not finite.
    pub skipped: usize,
    /// Fraction of the compared pairs whose normals point to opposite sides
    /// (`n · r < 0`): orientation errors. 0 is perfect.
    pub flipped_fraction: f64,
    /// Mean angle, in degrees, between the normal *lines* (`acos |n · r| / (|n| |r|)`, 0 to
    /// 90°): the estimation error, whatever the orientation.
    pub mean_angle_deg: f64,
    /// Median of the same line angles.
    pub median_angle_deg: f64,
    /// 95th percentile of the same line angles.
    pub p95_angle_deg: f64,
    /// Mean angle, in degrees, between the oriented normals (0 to 180°): estimation and
    /// orientation errors together.
    pub mean_oriented_angle_deg: f64,
}

/// Compares `normals` with `reference` normals, pair by pair (neither needs unit length).
///
/// # Errors
/// [`Error::LengthMismatch`] when the two differ in length.
pub fn compare(normals: &[[f64; 3]], reference: &[[f64; 3]]) -> Result<Comparison> {
    if normals.len() != reference.len() {
        return Err(Error::LengthMismatch {
            positions: reference.len(),
            normals: normals.len(),
        });
    }
    // (cosine) per usable pair, in order; reductions below are sequential (deterministic).
    let cos: Vec<Option<f64>> = normals
        .par_iter()
        .zip(reference.par_iter())
        .map(|(a, b)| {
            let (la, lb) = (norm(*a), norm(*b));
            let ok = la > 0.0 && lb > 0.0 && la.is_finite() && lb.is_finite();
            ok.then(|| (dot(*a, *b) / (la * lb)).clamp(-1.0, 1.0))
        })
        .collect();
    let mut line: Vec<f64> = cos
        .iter()
        .flatten()
        .map(|c| c.abs().acos().to_degrees())
        .collect();
    let compared = line.len();
    let mut c = Comparison {
        compared,
        skipped: normals.len() - compared,
        ..Comparison::default()
    };
    if compared == 0 {
        return Ok(c);
    }
    let n = compared as f64;
    c.flipped_fraction = cos.iter().flatten().filter(|&&x| x < 0.0).count() as f64 / n;
    c.mean_angle_deg = line.iter().sum::<f64>() / n;
    c.mean_oriented_angle_deg = cos
        .iter()
        .flatten()
        .map(|x| x.acos().to_degrees())
        .sum::<f64>()
        / n;
    line.sort_unstable_by(f64::total_cmp);
    let q = |f: f64| line[((f * (n - 1.0)).round() as usize).min(compared - 1)];
    c.median_angle_deg = q(0.5);
    c.p95_angle_deg = q(0.95);
    Ok(c)
}

/// Point indices are stored in 32 bits.
fn check_len(n: usize) -> Result<()> {
    if n >= knn::NONE as usize {
        return Err(Error::invalid(
            "points",
            n,
            format!("at most {} points", knn::NONE - 1),
        ));
    }
    Ok(())
}

/// Re-orients normals that disagree with their neighbours (issue 16): the normals are made
/// consistent along the minimum spanning forest of the `k`-nearest-neighbour graph (as
/// [`Orientation::Mst`]), then each connected piece takes the direction the clear majority
/// (over 60 %) of its given normals had; a piece without a clear majority is turned outward
/// (as [`Orientation::Mst`] does). Returns how many normals changed sign.
pub(crate) fn make_consistent(positions: &[[f64; 3]], normals: &mut [[f64; 3]], k: usize) -> usize {
    let given: Vec<[f64; 3]> = normals.to_vec();
    let graph = orient::Graph::new(positions, normals, k);
    let prop = orient::propagate(positions, normals, &graph);
    let mut outward = normals.to_vec();
    orient::outward(
        positions,
        &mut outward,
        &graph,
        &prop.component,
        prop.components,
    );
    // Per piece: how many of its normals now point against the given ones.
    let mut against = vec![0usize; prop.components];
    let mut size = vec![0usize; prop.components];
    for (i, &c) in prop.component.iter().enumerate() {
        if c == u32::MAX {
            continue;
        }
        size[c as usize] += 1;
        if dot(given[i], normals[i]) < 0.0 {
            against[c as usize] += 1;
        }
    }
    let mut flipped = 0;
    for (i, &c) in prop.component.iter().enumerate() {
        if c == u32::MAX {
            continue;
        }
        let share = against[c as usize] as f64 / size[c as usize] as f64;
        if share > CLEAR_MAJORITY {
            normals[i] = normals[i].map(|x| -x);
        } else if share >= 1.0 - CLEAR_MAJORITY {
            normals[i] = outward[i];
        }
        if dot(given[i], normals[i]) < 0.0 {
            flipped += 1;
        }
    }
    flipped
}

/// The share of a piece's given normals that decides its direction in [`make_consistent`].
const CLEAR_MAJORITY: f64 = 0.6;
