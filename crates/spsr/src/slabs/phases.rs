//! The phases of a slab run. The first phase reads the slab's points (its columns and the
//! padding) from the spill files and makes its samples, which are kept in the work folder for
//! the later phases; each phase rebuilds the slab's tree from them (deterministic, so the
//! same in every phase) and returns plain data for the coordinator, which combines the slabs'
//! parts between phases:
//!
//! 1. `noise`: where each owned sample's noise was measured (a histogram), so that all slabs
//!    smooth the noise at one depth (only with [`Noise::Adaptive`]); the samples and their
//!    measurements are kept;
//! 2. `coarse`: the samples at their final splat depths (kept for the phases after it), and
//!    what the slab's own samples add to the coarse levels — the tree's refined nodes,
//!    divergence constraints, V and screening clusters, keyed by node;
//! 3. (coordinator) `solve_coarse`: the coarse levels solved once for the whole cloud, and
//!    each slab's part of that solution cut out for it ([`crop`]);
//! 4. `solve`: the finer levels of the slab, from the coarse solution, and the slab's share of
//!    the iso-value; the coefficients go to a file, and those near the slab's faces to the
//!    neighbours;
//! 5. `extract`: the neighbours' coefficients near the shared faces replace the slab's own
//!    (so that χ on a shared face is the same number in both slabs), and the slab's blocks
//!    are polygonised.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::codec::{load as load_record, save, CoarseData, CoarseDensity, CoarseState, Coupling};
use super::plan::Plan;
use super::spill::{io_err, read_columns};
use crate::bspline::Basis;
use crate::data::{DataField, KeyedSums};
use crate::density::{Density, DepthAndArea, Sample};
use crate::evaluate::Evaluator;
use crate::extract::Blocks;
use crate::octree::{Octree, TreeRequest, DEPTH_OFFSET};
use crate::pipeline::density::{self, Sampled};
use crate::pipeline::prepare::Carried;
use crate::pipeline::solve::{base_level, problem as in_core_problem, tables as level_tables};
use crate::pipeline::{extract, noise, splat, system, tree};
use crate::solver::{self, Carry, Laps, Problem, Solution};
use crate::system::{
    for_each_cluster_sum, level_clusters, merge_cluster_sums, ClusterSum, Clusters, DepthTables,
};
use crate::{Noise, Params, Result};

/// A screening cluster's sums from one slab: the node's key, `W`, `W·p`.
pub type KeyedCluster = ([u32; 3], f64, [f64; 3]);

/// A node's coarse sums from one slab: key, divergence constraint, V.
pub type NodeSums = ([u32; 3], f32, [f32; 3]);

/// What one slab's own samples add to the coarse levels (phase 2).
#[derive(Debug, Clone, Default)]
pub struct CoarsePart {
    /// Per tree depth below the coarse level: the refined nodes of the slab's own samples'
    /// closed request (packed keys).
    pub refined: Vec<Vec<u64>>,
    /// Per tree depth from the base level to the coarse level (index 0 is the base level):
    /// the nodes with a constraint or V.
    pub nodes: Vec<Vec<NodeSums>>,
    /// Per tree depth from the base level: the screening clusters' sums `(key, W, W·p)`.
    pub clusters: Vec<Vec<KeyedCluster>>,
    /// `Σ w·area`, `Σ w` and `Σ w·depth` over the slab's own samples with a splat.
    pub sums: [f64; 3],
    /// The slab's own samples.
    pub samples: usize,
    /// With per-vertex density: the density estimator's occupied cells in the slab's own
    /// columns at `density_depth` (`cell, Σw, Σw·p`), for the whole cloud's coarse depths
    /// of the estimator (`save_coarse_density`); empty otherwise.
    pub density: Vec<DensityCell>,
    /// With attributes: the slab's own samples' attribute sums at the unit depths up to
    /// [`data_depth`] (index 0 is the unit cube), for the whole cloud's
    /// (`save_coarse_data`); empty otherwise.
    pub data: Vec<KeyedSums>,
}

/// An occupied cell of the density estimator: the cell, `Σ w`, `Σ w·p`.
pub type DensityCell = crate::density::Cell;

/// A coefficient near a slab's face: tree depth, node key, value.
pub type FaceCoefficient = (u32, [u32; 3], f32);

/// The coarse levels solved for the whole cloud (phase 3).
pub struct Coarse {
    /// The tree's levels up to the coarse level.
    pub tree: Octree,
    /// Its refined nodes per tree depth below the coarse level (packed keys): every slab's
    /// tree takes them in, so that the slabs' trees agree with each other (and with the
    /// in-core tree) on the coarse levels, wherever their own samples are.
    pub refined: Vec<Vec<u64>>,
    /// The coefficients and cumulative solutions of those levels.
    pub solution: Solution,
    /// The cumulative solution and V at the coarse level, for the slabs' finer levels.
    pub carry: Carry,
    /// The samples' mean area weight Ā (scales the screening).
    pub mean_area: f64,
    /// The samples' weighted mean depth.
    pub mean_depth: f64,
}

/// A slab's finer levels (phase 4).
#[derive(Debug, Clone, Default)]
pub struct Solved {
    /// `Σ w·χ(p)` and `Σ w` over the slab's own samples (for γ).
    pub iso_sums: [f64; 2],
    /// The coefficients of the slab's own nodes near its low and high faces: `(tree depth,
    /// key, x)`.
    pub faces: [Vec<FaceCoefficient>; 2],
}

/// Width, in cells of their own depth, of the band of coefficients on either side of a shared
/// face that both slabs take from the face's owner: χ and its gradient on the face read
/// coefficients within two cells, and cumulative solutions within two cells of the parents'.
const FACE_BAND: f64 = 4.0;

/// A slab's samples as its phases keep them between each other (`slab-s.measured` after the
/// noise phase, with the noise measured; `slab-s.samples` after the coarse phase, with the
/// final splat depths), so that only the first phases read the points and measure the noise.
#[derive(Debug, Default)]
pub(crate) struct SlabSamples {
    pub samples: Vec<Sample>,
    /// Each sample's splat depth and area weight.
    pub depths: Vec<DepthAndArea>,
    /// Each sample's measured noise (the noise phase's file only; empty otherwise).
    pub measured: noise::Measured,
    /// Each sample's attribute values (the plan's channels per sample; empty without).
    pub values: Vec<f64>,
}

impl SlabSamples {
    fn of(sampled: Sampled, measured: noise::Measured) -> SlabSamples {
        SlabSamples {
            samples: sampled.samples,
            depths: sampled.depths,
            measured,
            values: sampled.values,
        }
    }

    /// As the stages take them, with the plan's attributes; no density estimator (the
    /// extraction builds the slab's own, [`slab_density`]; the depths are kept).
    fn sampled(self, plan: &Plan, path: &Path) -> Result<Sampled> {
        if self.values.len() != self.samples.len() * plan.channels() {
            return Err(crate::Error::Parse {
                path: path.to_path_buf(),
                message: "the slab's samples lack their attribute values".into(),
            });
        }
        Ok(Sampled {
            samples: self.samples,
            values: self.values,
            attribute_types: plan.attribute_types(),
            density: Default::default(),
            depths: self.depths,
        })
    }
}

fn measured_path(dir: &Path, s: usize) -> PathBuf {
    dir.join(format!("slab-{s:04}.measured"))
}

fn samples_path(dir: &Path, s: usize) -> PathBuf {
    dir.join(format!("slab-{s:04}.samples"))
}

/// The files of a slab's samples that the phases after the coarse one no longer need: its
/// noise measurements (the spill files go too, see [`super::spill::remove_columns`]).
pub(crate) fn remove_measured(dir: &Path, slabs: usize) -> Result<()> {
    (0..slabs).try_for_each(|s| super::spill::remove_file(&measured_path(dir, s)))
}

/// One slab's samples, with whether each lies in the slab's own columns.
struct Loaded {
    sampled: Sampled,
    /// Whether each sample lies in the slab's own columns.
    owned: Vec<bool>,
}

impl Loaded {
    fn new(sampled: Sampled, plan: &Plan, s: usize) -> Loaded {
        let range = &plan.slabs[s];
        let owned = sampled
            .samples
            .iter()
            .map(|x| range.contains(&plan.column_of(x.pos[0])))
            .collect();
        Loaded { sampled, owned }
    }
}

/// The slab's samples from its points (its columns and the padding), at the density's splat
/// depths.
fn sample_points(dir: &Path, plan: &Plan, s: usize, params: &Params) -> Result<Sampled> {
    let (lo, hi) = plan.extent(s);
    let (lo, hi) = (lo - plan.pad, hi + plan.pad);
    let first = plan.column_of(lo) as usize;
    let last = plan.column_of(hi) as usize;
    let channels = plan.channels();
    let (points, values) = read_columns(dir, first..last + 1, &plan.counts, channels, (lo, hi))?;
    let carried = Carried {
        types: plan.attribute_types(),
        values,
    };
    Ok(density::sample(points, carried, params))
}

/// The slab's samples at their final splat depths, as the coarse phase makes them: with
/// adaptive noise, from the noise phase's measurements, smoothed at the whole cloud's depth
/// `smooth`.
fn final_samples(
    dir: &Path,
    plan: &Plan,
    s: usize,
    params: &Params,
    smooth: Option<u32>,
) -> Result<Sampled> {
    match (params.noise, smooth) {
        (Noise::Adaptive, Some(smooth)) => {
            let mut kept: SlabSamples = load_record(&measured_path(dir, s))?;
            if kept.measured.len() != kept.samples.len() {
                return Err(crate::Error::Parse {
                    path: measured_path(dir, s),
                    message: "the slab's samples lack their noise measurements".into(),
                });
            }
            let measured = std::mem::take(&mut kept.measured);
            let mut sampled = kept.sampled(plan, &measured_path(dir, s))?;
            // The noise phase's estimator, rebuilt from the same samples (it is not kept):
            // the adaptation queries it at each noisy sample's own samples per node.
            let density = density::estimator(&sampled.samples, params);
            noise::adapt_measured(
                &sampled.samples,
                &density,
                &mut sampled.depths,
                &measured,
                params.depth,
                Some(smooth),
            );
            Ok(sampled)
        }
        _ => sample_points(dir, plan, s, params),
    }
}

/// The slab's samples as the coarse phase kept them.
fn load_slab(dir: &Path, plan: &Plan, s: usize) -> Result<Loaded> {
    let kept: SlabSamples = load_record(&samples_path(dir, s))?;
    Ok(Loaded::new(
        kept.sampled(plan, &samples_path(dir, s))?,
        plan,
        s,
    ))
}

/// Phase 1: the histogram of the depths at which the slab's own samples' noise is measured;
/// the samples and their measurements are kept for the coarse phase.
pub fn noise_depths(dir: &Path, plan: &Plan, s: usize, params: &Params) -> Result<Vec<u64>> {
    crate::resources::release_free_memory();
    let sampled = sample_points(dir, plan, s, params)?;
    let measured = noise::measure(&sampled.samples, params.depth);
    let range = &plan.slabs[s];
    let histogram = noise::measured_depths(&sampled.samples, &measured, params.depth, |x| {
        range.contains(&plan.column_of(x.pos[0]))
    });
    save(&measured_path(dir, s), &SlabSamples::of(sampled, measured))?;
    Ok(histogram)
}

/// The per-level tables of a tree, from the base level on.
fn tables(tree: &Octree, params: &Params) -> (Basis, Vec<Option<DepthTables>>) {
    let fem = Basis::new(params.degree, params.boundary);
    (fem, level_tables(tree, fem, params))
}

/// The in-core problem ([`in_core_problem`]) as the phases solve it: one cycle at a time
/// (cascadic cycles and V-cycles run across the slabs, [`cycle_coarse`], [`solve`];
/// W-cycles and residual reports are refused by `check_supported`), on the CPU (`check_supported`
/// refuses `Gpu::On`).
fn problem<'a>(
    tree: &'a Octree,
    fem: Basis,
    tables: &'a [Option<DepthTables>],
    clusters: &'a [Clusters],
    params: &Params,
) -> Problem<'a> {
    Problem {
        cycles: 1,
        report: false,
        // The coarse levels' problems stop above the deepest level; a slab's own finer
        // levels ([`solve`]) name theirs.
        deepest_level: u32::MAX,
        ..in_core_problem(tree, fem, tables, clusters, params, None, &|_| {})
    }
}

/// Phase 2: what the slab's own samples add to the coarse levels.
pub fn coarse(
    dir: &Path,
    plan: &Plan,
    s: usize,
    params: &Params,
    smooth: Option<u32>,
) -> Result<CoarsePart> {
    crate::resources::release_free_memory();
    let sampled = final_samples(dir, plan, s, params, smooth)?;
    let kept = SlabSamples::of(sampled, Vec::new());
    save(&samples_path(dir, s), &kept)?;
    let Loaded { sampled, owned } =
        Loaded::new(kept.sampled(plan, &samples_path(dir, s))?, plan, s);
    let tb = base_level(params);
    let tc = plan.coarse_level();
    let mut refined = tree::build(&sampled, params, sampled.samples.len())?;
    // The coarse tree is the union of the slabs' own samples' closed requests.
    let own_splats: Vec<_> = refined
        .splats
        .iter()
        .zip(&owned)
        .map(|(sp, &o)| if o { *sp } else { None })
        .collect();
    let closed = tree::request(&sampled.samples, &own_splats, params)
        .close(tb - DEPTH_OFFSET, tb - DEPTH_OFFSET);
    let refined_keys = (0..tc).map(|t| closed.refined_keys(t)).collect();
    drop(closed);
    let samples = owned.iter().filter(|&&o| o).count();
    let density = if params.density {
        density_cells(&sampled, &owned, plan, s, params)
    } else {
        Vec::new()
    };
    // V of the slab's own samples, and of its padding's, on the slab's tree (which holds
    // every node that the own samples' V touches, as the in-core tree does).
    let pad_splats: Vec<_> = refined
        .splats
        .iter()
        .zip(&owned)
        .map(|(sp, &o)| if o { None } else { *sp })
        .collect();
    let any = |sp: &[Option<tree::Splat>]| sp.iter().any(Option::is_some);
    let (has_own, has_pad) = (any(&own_splats), any(&pad_splats));
    let all = std::mem::replace(&mut refined.splats, own_splats);
    let own_field = has_own
        .then(|| splat::splat(&refined, &sampled, params))
        .transpose()?;
    refined.splats = pad_splats;
    let pad_field = has_pad
        .then(|| splat::splat(&refined, &sampled, params))
        .transpose()?;
    refined.splats = all;
    let tree = refined.tree;
    let (fem, tabs) = tables(&tree, params);
    let no_clusters: Vec<Clusters> = (0..tree.levels.len())
        .map(|_| Clusters::default())
        .collect();
    let p = problem(&tree, fem, &tabs, &no_clusters, params);
    // The finer levels' constraints of all the slab's samples, for its solve (phase 4): the
    // own samples' (needed down to the coarse levels anyway) plus the padding's.
    let own_tcons = own_field
        .as_ref()
        .map(|f| solver::constraints(&p, &f.v, tb));
    let pad_tcons = pad_field
        .as_ref()
        .map(|f| solver::constraints(&p, &f.v, tc + 1));
    let fine: Vec<Vec<f32>> = (0..tree.levels.len())
        .map(|t| {
            if t <= tc as usize {
                return Vec::new();
            }
            (0..tree.levels[t].len())
                .map(|n| {
                    own_tcons.as_ref().map_or(0.0, |c| c[t][n])
                        + pad_tcons.as_ref().map_or(0.0, |c| c[t][n])
                })
                .collect()
        })
        .collect();
    write_levels(&constraints_path(dir, s), &fine, tc + 1)?;
    drop(fine);
    let (Some(field), Some(tcons)) = (own_field, own_tcons) else {
        return Ok(CoarsePart {
            refined: refined_keys,
            samples,
            density,
            ..CoarsePart::default()
        });
    };
    let nodes = (tb..=tc.min(tree.depth_count() - 1))
        .map(|t| {
            let level = &tree.levels[t as usize];
            (0..level.len() as u32)
                .filter_map(|n| {
                    let b = tcons[t as usize][n as usize];
                    let v = field.v[t as usize][n as usize];
                    (b != 0.0 || v != [0.0; 3]).then(|| (level.key(n), b, v))
                })
                .collect()
        })
        .collect();
    // Screening clusters of the own samples, at their deepest nodes of the slab's tree.
    let positions: Vec<[f64; 3]> = sampled
        .samples
        .iter()
        .zip(&owned)
        .filter(|(_, &o)| o)
        .map(|(x, _)| x.pos)
        .collect();
    let weights: Vec<f64> = (sampled.screening_weights().into_iter().zip(&owned))
        .filter(|(_, &o)| o)
        .map(|(w, _)| w)
        .collect();
    let leaf_of = system::deepest_nodes(&tree, &positions);
    let data = own_data(&tree, &sampled, &owned, &leaf_of, &weights, plan, params);
    let own_depths: Vec<_> = (sampled.depths.iter().zip(&owned))
        .filter(|(_, &o)| o)
        .map(|(q, _)| *q)
        .collect();
    let screened_at = system::screened_nodes(&tree, leaf_of, &system::screen_depths(&own_depths));
    let mut clusters = vec![Vec::new(); (tc.min(tree.depth_count() - 1) + 1 - tb) as usize];
    for_each_cluster_sum(
        &tree,
        tb,
        &screened_at,
        &positions,
        &weights,
        |t, merged| {
            if t <= tc {
                let level = &tree.levels[t as usize];
                clusters[(t - tb) as usize] = merged
                    .iter()
                    .map(|&(n, w, wp)| (level.key(n), w, wp))
                    .collect();
            }
        },
    );
    Ok(CoarsePart {
        refined: refined_keys,
        nodes,
        clusters,
        sums: [
            field.mean_area * field.weight,
            field.weight,
            field.mean_depth * field.weight,
        ],
        samples,
        density,
        data,
    })
}

/// The deepest unit depth at which a vertex's attribute sums are the whole cloud's (summed by
/// the coordinator from the slabs' own samples); `None` when the slabs' own sums serve at
/// every depth. A vertex pools the cells of each depth whose closure holds it
/// ([`DataField::eval`]): at the depths finer than this one, those of a vertex in a slab's
/// own columns lie within four cells of the coarse depth of the columns, inside the slab's
/// padding (six such cells), so the slab holds all their samples.
pub(crate) fn data_depth(plan: &Plan) -> Option<u32> {
    plan.coarse_depth.checked_sub(3)
}

/// The slab's own samples' attribute sums at the depths up to [`data_depth`] (a slab with
/// attributes only).
fn own_data(
    tree: &Octree,
    sampled: &Sampled,
    owned: &[bool],
    leaf_of: &[(u32, u32)],
    weights: &[f64],
    plan: &Plan,
    params: &Params,
) -> Vec<KeyedSums> {
    let k = plan.channels();
    let Some(depth) = data_depth(plan).filter(|_| k > 0) else {
        return Vec::new();
    };
    let values: Vec<f64> = sampled
        .values
        .chunks_exact(k)
        .zip(owned)
        .filter(|(_, &o)| o)
        .flat_map(|(v, _)| v.iter().copied())
        .collect();
    DataField::build(tree, leaf_of, weights, &values, k, params.data_pull)
        .keyed_levels(tree, depth + DEPTH_OFFSET)
}

fn coarse_data_path(dir: &Path) -> PathBuf {
    dir.join("data.coarse")
}

/// Coordinator: the whole cloud's attribute sums at the depths up to [`data_depth`], from
/// every slab's own ([`CoarsePart::data`], in slab order), written for the extraction phase.
pub(crate) fn save_coarse_data(dir: &Path, plan: &Plan, parts: Vec<Vec<KeyedSums>>) -> Result<()> {
    let width = plan.channels() + 1;
    let depths = data_depth(plan).map_or(0, |d| d as usize + 1);
    let mut by_depth: Vec<Vec<KeyedSums>> = (0..depths).map(|_| Vec::new()).collect();
    for part in parts {
        for (d, level) in part.into_iter().enumerate().take(depths) {
            by_depth[d].push(level);
        }
    }
    let merged = by_depth
        .into_iter()
        .map(|levels| KeyedSums::merge(levels, width))
        .collect();
    save(&coarse_data_path(dir), &CoarseData(merged))
}

/// The attribute field of a slab's vertices: its own and its padding's samples' sums at the
/// finer depths, the whole cloud's at the coarser ones ([`data_depth`]), locating vertices at
/// the run's depth, so that every vertex of the slab's own columns reads the sums it reads
/// in one piece.
fn slab_data(
    dir: &Path,
    tree: &Octree,
    sampled: &Sampled,
    plan: &Plan,
    params: &Params,
) -> Result<DataField> {
    let positions: Vec<[f64; 3]> = sampled.samples.iter().map(|x| x.pos).collect();
    let weights = sampled.screening_weights();
    let leaf_of = system::deepest_nodes(tree, &positions);
    let k = plan.channels();
    let mut data = DataField::build(
        tree,
        &leaf_of,
        &weights,
        &sampled.values,
        k,
        params.data_pull,
    );
    if data_depth(plan).is_some() {
        let coarse: CoarseData = load_record(&coarse_data_path(dir))?;
        let width = k + 1;
        if coarse
            .0
            .iter()
            .any(|l| l.sums.len() != l.keys.len() * width)
        {
            return Err(crate::Error::Parse {
                path: coarse_data_path(dir),
                message: "the coarse attribute sums do not fit the run's attributes".into(),
            });
        }
        // Every key is a node of the whole cloud's coarse tree, which each slab's tree holds.
        data.replace_coarse(tree, &coarse.0);
    }
    data.locate_at(params.depth + DEPTH_OFFSET);
    Ok(data)
}

/// The unit depth whose occupied cells the slabs hand in for the whole cloud's density
/// estimator ([`DensityCell`]). A vertex's density reads the estimator at each depth within
/// three cells of the vertex; a slab's padding (six cells of the coarse depth, which is the
/// kernel depth here) covers that down to one depth above the kernel depth, so the depths
/// from the kernel depth − 2 up are taken from the whole cloud, from cells within one column
/// each (hence at least the block depth), which one slab owns whole. When the kernel depth
/// is above the block depth (shallow runs), no depth is within one column: the slabs hand
/// in their samples (one per cell of the finest depth) and every depth of the estimator is
/// the whole cloud's.
pub(crate) fn density_depth(plan: &Plan, params: &Params) -> u32 {
    let kernel = params.kernel_depth();
    if plan.block_depth <= kernel {
        kernel.saturating_sub(2).max(plan.block_depth)
    } else {
        params.depth
    }
}

/// The slab's share of the whole cloud's coarse density ([`density_depth`]): the estimator's
/// cells at that depth within the slab's own columns, or its own samples.
fn density_cells(
    sampled: &Sampled,
    owned: &[bool],
    plan: &Plan,
    s: usize,
    params: &Params,
) -> Vec<DensityCell> {
    let depth = density_depth(plan, params);
    let kernel = params.kernel_depth();
    if depth > kernel {
        return (sampled.samples.iter().zip(owned))
            .filter(|(_, &o)| o)
            .map(|(x, _)| {
                let wp = [
                    x.weight * x.pos[0],
                    x.weight * x.pos[1],
                    x.weight * x.pos[2],
                ];
                (crate::density::cell_of(x.pos, depth), x.weight, wp)
            })
            .collect();
    }
    let range = &plan.slabs[s];
    let shift = depth - plan.block_depth;
    crate::density::Density::cells_at(&sampled.samples, kernel, depth)
        .into_iter()
        .filter(|(c, _, _)| range.contains(&(c[0] >> shift)))
        .collect()
}

fn coarse_density_path(dir: &Path) -> PathBuf {
    dir.join("density.coarse")
}

/// Coordinator: the whole cloud's density estimator at the depths up to [`density_depth`],
/// from every slab's cells ([`CoarsePart::density`]), written for the extraction phase.
pub(crate) fn save_coarse_density(
    dir: &Path,
    plan: &Plan,
    params: &Params,
    parts: Vec<Vec<DensityCell>>,
) -> Result<()> {
    let depth = density_depth(plan, params);
    let rho = crate::density::coarse_levels(parts, depth, params.kernel_depth());
    save(&coarse_density_path(dir), &CoarseDensity(rho))
}

/// The slab's density estimator for its vertices: its own samples' (with the padding's) at
/// the finer depths, the whole cloud's at the coarser ones, so that every vertex of the
/// slab's own columns reads the in-core estimator.
fn slab_density(dir: &Path, sampled: &Sampled, params: &Params) -> Result<Density> {
    let coarse: CoarseDensity = load_record(&coarse_density_path(dir))?;
    let kernel = params.kernel_depth();
    if coarse.0.len() > kernel as usize + 1 {
        return Err(crate::Error::Parse {
            path: coarse_density_path(dir),
            message: "the coarse density has more depths than the run's estimator".into(),
        });
    }
    let mut density = Density::build(&sampled.samples, kernel, params.samples_per_node);
    density.replace_coarse(coarse.0);
    Ok(density)
}

/// The node of `tree` at tree depth `t` with key `key`, if the tree has it.
fn find(tree: &Octree, t: u32, key: [u32; 3]) -> Option<u32> {
    if t as usize >= tree.levels.len() {
        return None;
    }
    let (reached, n) = tree.descend(key.map(u64::from), t, t);
    (reached == t).then_some(n)
}

/// The coarse levels' tree: the closure of the nodes that the slabs' own samples refine (per
/// slab, per tree depth below the coarse level, packed keys), and its own refined nodes.
fn coarse_tree_of(
    refined: &[&[Vec<u64>]],
    plan: &Plan,
    params: &Params,
) -> (Octree, Vec<Vec<u64>>) {
    let tb = base_level(params);
    let tc = plan.coarse_level();
    let mut req = TreeRequest::new(tc);
    for levels in refined {
        for (t, keys) in levels.iter().enumerate() {
            req.refine_keys(t as u32, keys.iter().copied());
        }
    }
    let closed = req.close(tb - DEPTH_OFFSET, tb - DEPTH_OFFSET);
    let refined_keys = (0..tc).map(|t| closed.refined_keys(t)).collect();
    (Octree::materialize(closed), refined_keys)
}

/// The coarse tree again from [`Coarse::refined`] (a closed request closes to itself).
pub(crate) fn coarse_tree(
    refined: &[Vec<u64>],
    plan: &Plan,
    params: &Params,
) -> (Octree, Vec<Vec<u64>>) {
    coarse_tree_of(&[refined], plan, params)
}

/// Phase 3 (coordinator): the coarse levels solved for the whole cloud from the slabs' parts.
/// The parts are consumed as they are added up, so that they and the sums are not all held
/// at once.
///
/// With more than one cycle ([`Params::cycles`]), the coarse levels' system and the cycles'
/// state are kept in the work folder `dir` for the cycles after the first ([`cycle_coarse`]).
pub fn solve_coarse(
    dir: &Path,
    mut parts: Vec<CoarsePart>,
    plan: &Plan,
    params: &Params,
) -> Result<Coarse> {
    crate::resources::release_free_memory();
    let samples: u64 = parts.iter().map(|p| p.samples as u64).sum();
    let tb = base_level(params);
    let tc = plan.coarse_level();
    let refined: Vec<&[Vec<u64>]> = parts.iter().map(|p| p.refined.as_slice()).collect();
    let (tree, refined_keys) = coarse_tree_of(&refined, plan, params);
    if tree.levels.len() as u32 <= tc {
        // So sparse a cloud has nothing finer than the coarse depths for the slabs to solve
        // apart, and is small: it runs in one piece.
        return Err(crate::Error::invalid(
            "slabs",
            plan.slabs.len(),
            format!(
                "one piece for this cloud: its octree stops at depth {}, above depth {}, where \
                 the slabs part; leave out --slabs (it is small enough to run in one piece)",
                (tree.levels.len() as u32).saturating_sub(1 + crate::octree::DEPTH_OFFSET),
                plan.coarse_depth
            ),
        ));
    }
    for part in &mut parts {
        part.refined = Vec::new();
    }
    let sums = parts.iter().fold([0.0; 3], |acc, p| {
        [acc[0] + p.sums[0], acc[1] + p.sums[1], acc[2] + p.sums[2]]
    });
    if sums[1] <= 0.0 {
        return Err(crate::Error::Degenerate(
            "the normals cancel everywhere (opposite normals at the same places)".into(),
        ));
    }
    let mean_area = sums[0] / sums[1];
    let nlev = tree.levels.len();
    let mut tcons: Vec<Vec<f64>> = vec![Vec::new(); nlev];
    let mut v: Vec<Vec<[f64; 3]>> = vec![Vec::new(); nlev];
    let mut cluster_sums: Vec<Vec<ClusterSum>> = vec![Vec::new(); nlev];
    for t in tb..=tc {
        tcons[t as usize] = vec![0.0; tree.levels[t as usize].len()];
        v[t as usize] = vec![[0.0; 3]; tree.levels[t as usize].len()];
    }
    for part in parts {
        // Each part is dropped once it is added.
        for (k, nodes) in part.nodes.iter().enumerate() {
            let t = tb + k as u32;
            for &(key, b, vv) in nodes {
                // A node the union lacks gets nothing from the slab's own samples.
                if let Some(n) = find(&tree, t, key) {
                    tcons[t as usize][n as usize] += f64::from(b);
                    for a in 0..3 {
                        v[t as usize][n as usize][a] += f64::from(vv[a]);
                    }
                }
            }
        }
        for (k, cl) in part.clusters.iter().enumerate() {
            let t = tb + k as u32;
            for &(key, w, wp) in cl {
                if let Some(n) = find(&tree, t, key) {
                    cluster_sums[t as usize].push((n, w, wp));
                }
            }
        }
    }
    let alpha = params.alpha();
    let merged: Vec<Vec<ClusterSum>> = cluster_sums
        .into_iter()
        .map(|entries| {
            if alpha <= 0.0 || entries.is_empty() {
                return Vec::new();
            }
            merge_cluster_sums(entries)
        })
        .collect();
    let (fem, tabs) = tables(&tree, params);
    let clusters = coarse_clusters(&tree, fem, &merged, params, mean_area);
    let p = problem(&tree, fem, &tabs, &clusters, params);
    // The sums in single precision, each level's double-precision sums freed as it goes.
    let tcons32 = tcons
        .into_iter()
        .map(|c| c.into_iter().map(|x| x as f32).collect())
        .collect();
    let v32 = v
        .into_iter()
        .map(|l| l.into_iter().map(|x| x.map(|c| c as f32)).collect())
        .collect();
    let mean_depth = sums[2] / sums[1];
    if params.cycles() <= 1 {
        let (solution, carry) = solver::cascade(&p, tcons32, v32, None, true, None, Laps::new());
        return Ok(Coarse {
            carry: carry.expect("kept"),
            solution,
            mean_area,
            mean_depth,
            tree,
            refined: refined_keys,
        });
    }
    let (solution, carry, cycles) = solver::cascade_for_cycles(&p, tcons32, v32);
    drop(clusters);
    let state = CoarseState {
        refined: refined_keys,
        clusters: merged,
        mean_area,
        mean_depth,
        samples,
        cycles,
    };
    save(&coarse_state_path(dir, 1), &state)?;
    Ok(Coarse {
        carry,
        solution,
        mean_area,
        mean_depth,
        tree,
        refined: state.refined,
    })
}

/// The coarse levels' screening clusters from their merged sums (per tree depth).
fn coarse_clusters(
    tree: &Octree,
    fem: Basis,
    merged: &[Vec<ClusterSum>],
    params: &Params,
    mean_area: f64,
) -> Vec<Clusters> {
    let alpha = params.alpha();
    (0..tree.levels.len())
        .map(|t| match merged.get(t) {
            Some(m) if alpha > 0.0 && !m.is_empty() => {
                level_clusters(tree, fem, t as u32, m, alpha * mean_area)
            }
            _ => Clusters::default(),
        })
        .collect()
}

/// The coarse levels' state after cycle `cycle` (with more than one cycle).
fn coarse_state_path(dir: &Path, cycle: u32) -> PathBuf {
    dir.join(format!("coarse-{cycle}.state"))
}

/// What slab `s`'s own finer nodes add to the coarse level's `U` after cycle `cycle`.
fn coupling_path(dir: &Path, s: usize, cycle: u32) -> PathBuf {
    dir.join(format!("slab-{s:04}.coupling-{cycle}"))
}

/// Phase 4b (coordinator, with more than one cycle): cycle `cycle` (from 2) of the whole
/// cloud's coarse levels, under the slabs' finer levels as cycle `cycle − 1` left them: the
/// gradient coupling `U` that the finer levels' coefficients put on the coarse level is the
/// sum of what each slab's own nodes put there (`slab-s.coupling-(cycle − 1)`, written by
/// [`solve`]), since every finer node is some slab's own. From it the cycle goes down the
/// coarse levels, solves the base level and relaxes the levels going up, as the cycles in
/// one piece do ([`crate::solver::cycle_below`]); the slabs then relax their finer levels
/// against the new coarse solution ([`solve`] with `cycle`). Returns the coarse solution and
/// the samples of all slabs.
pub fn cycle_coarse(dir: &Path, plan: &Plan, params: &Params, cycle: u32) -> Result<(Coarse, u64)> {
    crate::resources::release_free_memory();
    let CoarseState {
        refined,
        clusters: merged,
        mean_area,
        mean_depth,
        samples,
        cycles: mut state,
    } = load_record(&coarse_state_path(dir, cycle - 1))?;
    let (tree, _) = coarse_tree(&refined, plan, params);
    let tc = plan.coarse_level();
    let top = tree.levels.len() as u32 - 1;
    let mut u_top = vec![0.0f64; tree.levels[top as usize].len()];
    for s in 0..plan.slabs.len() {
        let Coupling(entries) = load_record(&coupling_path(dir, s, cycle - 1))?;
        for (key, u) in entries {
            // A node the coarse tree lacks has no function in the coarse system.
            if let Some(n) = find(&tree, tc.min(top), key) {
                u_top[n as usize] += u;
            }
        }
    }
    let (fem, tabs) = tables(&tree, params);
    let clusters = coarse_clusters(&tree, fem, &merged, params, mean_area);
    let p = problem(&tree, fem, &tabs, &clusters, params);
    let (solution, carry) = solver::cycle_below(&p, &mut state, u_top);
    drop(clusters);
    let record = CoarseState {
        refined,
        clusters: merged,
        mean_area,
        mean_depth,
        samples,
        cycles: state,
    };
    save(&coarse_state_path(dir, cycle), &record)?;
    let coarse = Coarse {
        tree,
        refined: record.refined,
        solution,
        carry,
        mean_area,
        mean_depth,
    };
    Ok((coarse, samples))
}

/// Deletes what the cycles before `cycle` left that no step reads any more, once every slab's
/// part of cycle `cycle`'s coarse solution is written: the coarse state and the slabs'
/// couplings of cycle `cycle − 1`, and the slabs' coefficients of cycle `cycle − 2`.
pub(crate) fn remove_spent_cycle(dir: &Path, slabs: usize, cycle: u32) -> Result<()> {
    let spent = cycle - 1;
    super::spill::remove_file(&coarse_state_path(dir, spent))?;
    for s in 0..slabs {
        super::spill::remove_file(&coupling_path(dir, s, spent))?;
        if spent > 1 {
            super::spill::remove_file(&solution_path(dir, s, spent - 1))?;
        }
    }
    Ok(())
}

/// How far beyond its padding a slab reads the coarse solve, in cells of the coarse depth, and
/// beyond that in cells of each coarse depth: a slab's finer nodes lie within a couple of
/// coarse cells of its padded points and couple only to coarse nodes within two cells, and χ
/// at a point reads each depth's nodes within two cells of it.
const CROP_COARSE_CELLS: f64 = 8.0;
const CROP_LEVEL_CELLS: f64 = 4.0;

/// The part of the coarse solve that slab `s` reads: the refined nodes whose cells come
/// within reach of its padded columns (a subset of a closed set, so its closure holds every
/// node of the whole coarse tree there, and nothing the whole tree lacks), with their
/// solution. A slab then neither holds nor builds the whole cloud's coarse levels, which at
/// depth 12 and beyond are gigabytes; its tree and its numbers near its columns are the same.
pub fn crop(coarse: &Coarse, plan: &Plan, s: usize, params: &Params) -> Coarse {
    let (lo, hi) = plan.extent(s);
    let reach = plan.pad + CROP_COARSE_CELLS / (1u64 << plan.coarse_depth) as f64;
    let near = |t: u32, packed: u64| {
        if t < DEPTH_OFFSET {
            return true;
        }
        let d = t - DEPTH_OFFSET;
        let cells = (1u64 << d) as f64;
        let margin = reach + CROP_LEVEL_CELLS / cells;
        let i = crate::octree::func_index(crate::octree::unpack(packed), d)[0] as f64;
        (i + 1.0) / cells >= lo - margin && i / cells <= hi + margin
    };
    let kept: Vec<Vec<u64>> = (coarse.refined.iter().enumerate())
        .map(|(t, keys)| {
            keys.iter()
                .copied()
                .filter(|&k| near(t as u32, k))
                .collect()
        })
        .collect();
    let (tree, refined) = coarse_tree_of(&[&kept], plan, params);
    let copy = |t: usize, from: &[f32]| -> Vec<f32> {
        if from.is_empty() {
            return Vec::new();
        }
        let level = &tree.levels[t];
        (0..level.len() as u32)
            .map(|n| find(&coarse.tree, t as u32, level.key(n)).map_or(0.0, |m| from[m as usize]))
            .collect()
    };
    let x = (coarse.solution.x.iter().enumerate())
        .map(|(t, v)| copy(t, v))
        .collect();
    let p = (coarse.solution.p.iter().enumerate())
        .map(|(t, v)| copy(t, v))
        .collect();
    let carry = carry_onto(&tree, coarse, coarse.carry.level);
    Coarse {
        tree,
        refined,
        solution: Solution {
            x,
            p,
            base_level: coarse.solution.base_level,
            timings: Vec::new(),
            report: None,
        },
        carry,
        mean_area: coarse.mean_area,
        mean_depth: coarse.mean_depth,
    }
}

/// The slab's tree with the coarse solution copied onto its coarse levels: the solution with
/// `x` and `p` up to the coarse level, and the carry on the slab's coarse level.
fn coarse_onto(tree: &Octree, coarse: &Coarse, params: &Params, tc: u32) -> (Solution, Carry) {
    let nlev = tree.levels.len();
    let tb = base_level(params);
    let mut sol = Solution {
        x: vec![Vec::new(); nlev],
        p: vec![Vec::new(); nlev],
        base_level: tb,
        timings: Vec::new(),
        report: None,
    };
    let map = |t: u32, from: &dyn Fn(u32) -> f32| -> Vec<f32> {
        let level = &tree.levels[t as usize];
        (0..level.len() as u32)
            .map(|n| find(&coarse.tree, t, level.key(n)).map_or(0.0, from))
            .collect()
    };
    let tc = tc.min(nlev as u32 - 1);
    for t in tb..=tc {
        sol.x[t as usize] = map(t, &|m| coarse.solution.x[t as usize][m as usize]);
        if t < tc {
            sol.p[t as usize] = map(t, &|m| coarse.solution.p[t as usize][m as usize]);
        }
    }
    let carry = carry_onto(tree, coarse, tc);
    sol.p[tc as usize] = carry.p.iter().map(|&x| x as f32).collect();
    (sol, carry)
}

/// The coarse solve's carry (cumulative solution and V) on level `tc` of `tree`; zero at the
/// nodes the coarse tree lacks.
fn carry_onto(tree: &Octree, coarse: &Coarse, tc: u32) -> Carry {
    let level = &tree.levels[tc as usize];
    let mut carry = Carry {
        level: tc,
        p: Vec::with_capacity(level.len()),
        vc: Vec::with_capacity(level.len()),
    };
    for n in 0..level.len() as u32 {
        match find(&coarse.tree, tc, level.key(n)) {
            Some(m) => {
                carry.p.push(coarse.carry.p[m as usize]);
                carry.vc.push(coarse.carry.vc[m as usize]);
            }
            None => {
                carry.p.push(0.0);
                carry.vc.push([0.0; 3]);
            }
        }
    }
    carry
}

/// The slab's tree: its samples' nodes and its part of the whole cloud's coarse levels.
fn slab_tree(sampled: &Sampled, params: &Params, coarse: &Coarse) -> Result<tree::Refined> {
    tree::build_with(sampled, params, sampled.samples.len(), |req| {
        for (t, keys) in coarse.refined.iter().enumerate() {
            req.refine_keys(t as u32, keys.iter().copied());
        }
    })
}

fn constraints_path(dir: &Path, s: usize) -> PathBuf {
    dir.join(format!("slab-{s:04}.constraints"))
}

/// Slab `s`'s coefficients of its finer levels after cycle `cycle`.
fn solution_path(dir: &Path, s: usize, cycle: u32) -> PathBuf {
    dir.join(format!("slab-{s:04}.solution-{cycle}"))
}

/// Phase 4: cycle `cycle` (from 1) of the slab's finer levels, from the coarse solution of
/// that cycle. The first cycle is the cascade from the coarse solution; a later one relaxes
/// each level from the slab's coefficients of the cycle before, against the new coarse
/// solution and the coupling of those coefficients ([`solver::cascade`] with `previous`).
/// Before the last cycle (after a V-cycle's down pass of the finer levels,
/// [`solver::relax_down`]), the slab's own nodes' share of the coarse level's coupling `U` goes
/// to the coordinator ([`cycle_coarse`]); after it, the slab's share of γ and its
/// coefficients near its faces for the neighbours (empty before).
pub fn solve(
    dir: &Path,
    plan: &Plan,
    s: usize,
    params: &Params,
    coarse: &Coarse,
    cycle: u32,
) -> Result<Solved> {
    crate::resources::release_free_memory();
    let Loaded { sampled, owned } = load_slab(dir, plan, s)?;
    let tc = plan.coarse_level();
    let refined = slab_tree(&sampled, params, coarse)?;
    let field = splat::splat(&refined, &sampled, params)?;
    let tree = refined.tree;
    let points = system::SamplePoints {
        positions: sampled.samples.iter().map(|x| x.pos).collect(),
        weights: sampled.screening_weights(),
        screen_depths: system::screen_depths(&sampled.depths),
    };
    drop(sampled);
    let fem = Basis::new(params.degree, params.boundary);
    let screening = system::screening(&tree, fem, &points, Vec::new(), 0, coarse.mean_area, params);
    let (_, tabs) = tables(&tree, params);
    let max_level = tree.depth_count() - 1;
    // The slab's deepest level is the whole cloud's but where the slab's samples stop
    // shallower; there its first relaxation makes fewer sweeps than the one-piece run's.
    let p = Problem {
        deepest_level: max_level,
        ..problem(&tree, fem, &tabs, &screening.clusters, params)
    };
    let (mut sol, carry) = coarse_onto(&tree, coarse, params, tc);
    if tc < max_level {
        // The finer levels' constraints, from phase 2 (the same tree there: the whole
        // cloud's coarse levels add no finer node).
        let mut tcons = vec![Vec::new(); tree.levels.len()];
        read_levels(&constraints_path(dir, s), &mut tcons, tc + 1, &tree)?;
        let previous = (cycle > 1)
            .then(|| -> Result<Vec<Vec<f32>>> {
                let mut x = vec![Vec::new(); tree.levels.len()];
                read_levels(&solution_path(dir, s, cycle - 1), &mut x, tc + 1, &tree)?;
                Ok(x)
            })
            .transpose()?;
        // A V-cycle goes down the finer levels again before the next cycle's coarse levels:
        // it reads the constraints and V the cascade consumes (V but the deepest level's).
        let down = (params.solver == crate::Solver::VCycle && cycle < params.cycles()).then(|| {
            let v: Vec<Vec<[f32; 3]>> = (field.v.iter().enumerate())
                .map(|(t, v)| {
                    if t < max_level as usize {
                        v.clone()
                    } else {
                        Vec::new()
                    }
                })
                .collect();
            (tcons.clone(), v, carry.clone())
        });
        let (mut fine, _) = solver::cascade(
            &p,
            tcons,
            field.v,
            Some(carry),
            false,
            previous,
            Laps::new(),
        );
        for t in tc as usize + 1..=max_level as usize {
            sol.x[t] = std::mem::take(&mut fine.x[t]);
            sol.p[t] = std::mem::take(&mut fine.p[t]);
        }
        if let Some((tcons, v, carry)) = down {
            solver::relax_down(&p, &tcons, &v, &carry, &mut sol.x);
        }
    }
    write_levels(&solution_path(dir, s, cycle), &sol.x, tc + 1)?;
    if cycle < params.cycles() {
        let u = own_coupling(&p, &sol.x, plan, s);
        save(&coupling_path(dir, s, cycle), &u)?;
        return Ok(Solved::default());
    }
    let eval = Evaluator::new(&tree, fem, &sol);
    let mut iso_sums = [0.0; 2];
    for ((pos, w), &o) in points.positions.iter().zip(&points.weights).zip(&owned) {
        if o {
            iso_sums[0] += w * eval.value(*pos);
            iso_sums[1] += w;
        }
    }
    let faces = face_bands(&tree, &sol, plan, s);
    Ok(Solved { iso_sums, faces })
}

/// The gradient coupling `U` that the slab's own nodes of the finer levels (coefficients `x`)
/// put on the coarse level's nodes, keyed by node.
fn own_coupling(p: &Problem, x: &[Vec<f32>], plan: &Plan, s: usize) -> Coupling {
    let tc = plan.coarse_level();
    let tree = p.tree;
    if tree.levels.len() as u32 <= tc + 1 {
        return Coupling(Vec::new());
    }
    let range = &plan.slabs[s];
    let own =
        |t: usize, n: u32| range.contains(&plan.column_of_node(t as u32, tree.levels[t].key(n)));
    let u = solver::finer_couplings(p, x, tc as usize, own);
    let level = &tree.levels[tc as usize];
    let entries = (u[tc as usize].iter().enumerate())
        .filter(|(_, &v)| v != 0.0)
        .map(|(n, &v)| (level.key(n as u32), v))
        .collect();
    Coupling(entries)
}

/// The slab's own coefficients within [`FACE_BAND`] cells of its low and high faces, at the
/// levels below the coarse level.
fn face_bands(tree: &Octree, sol: &Solution, plan: &Plan, s: usize) -> [Vec<FaceCoefficient>; 2] {
    let (lo, hi) = plan.extent(s);
    let range = &plan.slabs[s];
    let mut faces = [Vec::new(), Vec::new()];
    for t in plan.coarse_level() + 1..tree.depth_count() {
        let level = &tree.levels[t as usize];
        let d = t - DEPTH_OFFSET;
        let cells = (1u64 << d) as f64;
        for n in 0..level.len() as u32 {
            let key = level.key(n);
            if !range.contains(&plan.column_of_node(t, key)) {
                continue;
            }
            let centre = (crate::octree::func_index(key, d)[0] as f64 + 0.5) / cells;
            let x = sol.x[t as usize][n as usize];
            if (centre - lo).abs() * cells <= FACE_BAND {
                faces[0].push((t, key, x));
            }
            if (centre - hi).abs() * cells <= FACE_BAND {
                faces[1].push((t, key, x));
            }
        }
    }
    faces
}

/// Phase 5: the slab's blocks polygonised at `iso`, with the neighbours' coefficients near the
/// shared faces (`before`: the high face of slab `s − 1`; `after`: the low face of `s + 1`).
#[allow(clippy::too_many_arguments)]
pub fn extract(
    dir: &Path,
    plan: &Plan,
    s: usize,
    params: &Params,
    coarse: &Coarse,
    iso: f64,
    neighbours: [&[FaceCoefficient]; 2],
) -> Result<Extracted> {
    crate::resources::release_free_memory();
    let Loaded { sampled, .. } = load_slab(dir, plan, s)?;
    let tc = plan.coarse_level();
    let refined = slab_tree(&sampled, params, coarse)?;
    let density = params
        .density
        .then(|| slab_density(dir, &sampled, params))
        .transpose()?;
    let tree = refined.tree;
    let data = (plan.channels() > 0)
        .then(|| slab_data(dir, &tree, &sampled, plan, params))
        .transpose()?;
    drop(sampled);
    let (fem, tabs) = tables(&tree, params);
    let (mut sol, carry) = coarse_onto(&tree, coarse, params, tc);
    read_levels(
        &solution_path(dir, s, params.cycles()),
        &mut sol.x,
        tc + 1,
        &tree,
    )?;
    let mut missing = 0;
    for band in neighbours {
        for &(t, key, x) in band {
            match find(&tree, t, key) {
                Some(n) => sol.x[t as usize][n as usize] = x,
                None => missing += 1,
            }
        }
    }
    let no_clusters: Vec<Clusters> = (0..tree.levels.len())
        .map(|_| Clusters::default())
        .collect();
    let p = problem(&tree, fem, &tabs, &no_clusters, params);
    let cum = solver::cumulate(&p, &carry, &sol.x);
    for (t, c) in cum.into_iter().enumerate() {
        if t > tc as usize {
            sol.p[t] = c;
        }
    }
    let range = plan.slabs[s].clone();
    let blocks = extract::slab_blocks(&tree, fem, &sol, iso, params, plan.block_depth, range)?;
    drop(sol);
    // Each vertex's attributes, as the in-core extraction interpolates them (unit-cube
    // position).
    let attributes = data.map(|data| {
        let k = data.channels();
        let positions: Vec<[f64; 3]> = blocks.vertices().copied().collect();
        let mut values = vec![0.0f64; positions.len() * k];
        values
            .par_chunks_mut(k)
            .zip(&positions)
            .for_each(|(out, p)| data.eval(&tree, *p, out));
        values
    });
    drop(tree);
    // Each vertex's density, as the in-core extraction computes it (unit-cube position).
    let density = density.map(|d| {
        let positions: Vec<[f64; 3]> = blocks.vertices().copied().collect();
        positions
            .par_iter()
            .map(|p| d.query(*p).depth as f32)
            .collect()
    });
    Ok(Extracted {
        blocks,
        density,
        attributes,
        missing,
    })
}

/// A slab's part of the mesh (phase 5).
pub struct Extracted {
    /// The slab's polygonised blocks.
    pub blocks: Blocks,
    /// Each vertex's density (in the order [`Blocks::vertices`] gives them), when asked for.
    pub density: Option<Vec<f32>>,
    /// Each vertex's attribute values (one per carried attribute, in the same order), when
    /// the points carry attributes.
    pub attributes: Option<Vec<f64>>,
    /// Coefficients of the neighbours' face bands that the slab's tree lacks.
    pub missing: usize,
}

impl Extracted {
    /// The slab's mesh as a part of the whole, with its density.
    pub fn into_part(self) -> crate::extract::Part {
        crate::extract::Part {
            density: self.density,
            attributes: self.attributes,
            ..self.blocks.into_part()
        }
    }
}

/// Writes per-node values of the levels from `from` on (none where a sparse slab's tree
/// stops above `from`), atomically (a task that dies leaves no half file).
fn write_levels(path: &Path, levels: &[Vec<f32>], from: u32) -> Result<()> {
    crate::io::write_with(path, |w| {
        for x in levels.get(from as usize..).unwrap_or_default() {
            w.write_all(&(x.len() as u64).to_le_bytes())?;
            for v in x {
                w.write_all(&v.to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Reads what [`write_levels`] wrote, checking each level's length against `tree`.
fn read_levels(path: &Path, levels: &mut [Vec<f32>], from: u32, tree: &Octree) -> Result<()> {
    let f = File::open(path).map_err(|e| io_err(path, e))?;
    let mut r = BufReader::new(f);
    for t in from as usize..tree.levels.len() {
        let mut len = [0u8; 8];
        r.read_exact(&mut len).map_err(|e| io_err(path, e))?;
        let len = u64::from_le_bytes(len) as usize;
        if len != tree.levels[t].len() {
            return Err(crate::Error::Parse {
                path: path.to_path_buf(),
                message: format!(
                    "the slab's file has {len} values at level {t}, its tree {} nodes",
                    tree.levels[t].len()
                ),
            });
        }
        let mut bytes = vec![0u8; len * 4];
        r.read_exact(&mut bytes).map_err(|e| io_err(path, e))?;
        levels[t] = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
            .collect();
    }
    Ok(())
}
