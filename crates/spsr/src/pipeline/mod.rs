//! The front door: the pipeline of ALGORITHM.md §2, one stage per module, each taking the
//! previous stage's output and returning its own plain data.
//!
//! | stage | module | ALGORITHM.md | output |
//! |---|---|---|---|
//! | 1 preparing points | [`prepare`] | §3.1, §3.2, §3.4 | [`prepare::Prepared`] |
//! | 2 density | [`density`] | §3.3, §3.5 | [`density::Sampled`] |
//! | 2a orientation | [`orientation`] | (issue 16) | the samples' normals, made consistent |
//! | 2b noise | [`noise`] | (issue 16) | the samples' depths, lowered |
//! | 3 octree | [`tree`] | §3.6, §4.2 | [`tree::Refined`] |
//! | 4 splatting | [`splat`] | §3.6 | [`splat::VectorField`] |
//! | 5 clusters | [`system`] | §3.7 | [`system::Screening`] |
//! | 6 solving | [`solve`] | §6, §7 | [`crate::solver::Solution`] |
//! | 7 iso-value | [`iso`] | §1.5 | [`Implicit`] |
//! | 8 extraction | [`extract`] | §9 | [`Mesh`] |
//! | 9 fragments | [`fragments`] | (issue 16) | the [`Mesh`] without noise bubbles |
//! | 10 checking the mesh | [`diagnose`] | — | [`diagnose::Diagnosis`] and its warning |

use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::attributes::Attribute;
use crate::bspline::Basis;
use crate::data::DataField;
use crate::density::Density;
use crate::error::Warning;
use crate::evaluate::Evaluator;
use crate::octree::{Octree, DEPTH_OFFSET};
use crate::solver::Solution;
use crate::trim::{TrimParams, TrimStats};
use crate::{gpu, resources, Error, Gpu, Mesh, Noise, Params, PointCloud, Result};

pub mod density;
pub mod diagnose;
pub mod extract;
pub mod fragments;
pub mod grid;
pub mod iso;
pub mod noise;
pub mod orientation;
pub mod prepare;
pub mod resolution;
pub mod solve;
pub mod splat;
pub mod system;
pub mod tree;
pub mod work;

use diagnose::{Diagnosis, NormalProbe};
pub use grid::{Grid, ImplicitFunction};
pub use noise::NoiseSummary;
pub use prepare::Frame;
pub use resolution::{DepthChoice, DepthLimit, DepthReason};
pub use work::Work;

/// The output of [`reconstruct`].
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// The mesh, in the input's frame and units.
    pub mesh: Mesh,
    /// Counts and timings of the run.
    pub stats: Stats,
    /// The implicit function sampled on a grid, when [`Params::grid_res`] asks for one.
    pub grid: Option<Grid>,
}

/// Counts and timings gathered during a reconstruction.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Points given.
    pub points: usize,
    /// Points dropped (non-finite values, zero-length normals, unusable weights, or far
    /// outliers left out).
    pub dropped: usize,
    /// Samples after merging points that share a finest cell.
    pub samples: usize,
    /// Octree nodes per depth (index 0 is the unit cube).
    pub nodes_per_depth: Vec<usize>,
    /// Screening clusters per depth (same indexing; 0 below the base depth).
    pub clusters_per_depth: Vec<usize>,
    /// The iso-value γ.
    pub iso_value: f64,
    /// Weighted mean of the samples' estimated depths.
    pub mean_sample_depth: f64,
    /// Wall time of each stage, in order.
    pub stages: Vec<(String, Duration)>,
    /// The bytes each stage must move and the flops it does, by the floor model of
    /// [`work`]; same order as `stages`, `None` for a stage without a model.
    pub work: Vec<Option<Work>>,
    /// What the user should hear about the input (dropped points, far outliers).
    pub warnings: Vec<Warning>,
    /// The peak memory estimated before the octree was built (bytes), which
    /// [`Params::max_memory`] (or the available memory) was checked against.
    pub memory_estimate: u64,
    /// Peak resident memory of the process (bytes) at the end of each stage, where the
    /// platform reports it (Linux); same order as `stages`.
    pub peak_memory: Vec<Option<u64>>,
    /// What the noise stage measured and changed (`None` with [`Noise::Off`]).
    pub noise: Option<NoiseSummary>,
    /// The checks of the result (stage 9): pieces, closedness, surface along the bounding
    /// cube, normals against χ. A warning in `warnings` when they look wrong.
    pub diagnosis: Diagnosis,
    /// Slabs the run was cut into (`crate::slabs`); 0 for a run in one piece.
    pub slabs: usize,
    /// The solver's residuals per depth and per cycle, with
    /// [`Params::report_residuals`](crate::Params::report_residuals).
    pub solve: Option<crate::SolveReport>,
    /// How the depth was chosen, when it was not given ([`crate::Resolution`]).
    pub depth_choice: Option<DepthChoice>,
    /// The GPU that relaxed the depths, when one did ([`Params::gpu`]).
    pub gpu: Option<String>,
    /// Each relaxation the GPU ran, in order, with its times.
    pub gpu_relaxations: Vec<crate::GpuRelaxation>,
}

/// The solved implicit function χ and what extraction needs besides: the output of stages
/// 1–7.
#[derive(Debug)]
pub struct Implicit {
    /// The octree.
    pub tree: Octree,
    /// χ's coefficients.
    pub solution: Solution,
    /// The finite elements.
    pub fem: Basis,
    /// The sampling density, for the per-vertex density (`None` unless `params.density`).
    pub density: Option<Density>,
    /// The iso-value γ.
    pub iso: f64,
    /// The unit cube in the input's frame.
    pub frame: Frame,
    /// The cloud's attributes summed up the tree, when they are carried onto the mesh.
    pub data: Option<DataField>,
    /// Name and type of each carried attribute (empty columns), in channel order.
    pub attribute_types: Vec<Attribute>,
}

impl Implicit {
    /// χ and its gradient (in world units) at a world-space point; points outside the
    /// bounding cube are clamped to it.
    #[cfg(test)]
    pub fn value_grad(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let (v, g) =
            Evaluator::new(&self.tree, self.fem, &self.solution).value_grad(self.frame.to_unit(p));
        (v, g.map(|c| c / self.frame.width))
    }
}

/// Reconstructs a watertight surface from oriented points.
pub fn reconstruct(points: &PointCloud, params: &Params) -> Result<Reconstruction> {
    reconstruct_with_progress(points, params, &|_| {})
}

/// As [`reconstruct`], calling `progress` with the name of each stage as it starts.
pub fn reconstruct_with_progress(
    points: &PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    reconstruct_input(Input::Borrowed(points), params, None, false, progress).map(|(r, _, _)| r)
}

/// As [`reconstruct_with_progress`], taking the cloud by value: it is released as soon as
/// the points are normalised, which lowers the peak memory of a large run by the cloud's size.
pub fn reconstruct_owned(
    points: PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    reconstruct_input(Input::Owned(points), params, None, false, progress).map(|(r, _, _)| r)
}

/// As [`reconstruct_owned`], keeping the solved implicit function, which answers
/// [`ImplicitFunction::values`] and [`ImplicitFunction::values_and_gradients`] at any point afterwards (it
/// holds the octree and the solution: about the run's peak memory).
pub fn reconstruct_implicit(
    points: PointCloud,
    params: &Params,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Reconstruction, ImplicitFunction)> {
    match reconstruct_input(Input::Owned(points), params, None, true, progress)? {
        (out, _, Some(implicit)) => Ok((out, ImplicitFunction(implicit))),
        (_, _, None) => unreachable!("reconstruct_input keeps the function when asked"),
    }
}

/// As [`reconstruct_and_trim`], keeping the solved implicit function as
/// [`reconstruct_implicit`] does (the function is not trimmed: it is defined over the whole
/// bounding cube).
pub fn reconstruct_and_trim_implicit(
    points: PointCloud,
    params: &Params,
    trim: &TrimParams,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Reconstruction, TrimStats, ImplicitFunction)> {
    params.validate()?;
    trim.validate()?;
    match reconstruct_input(Input::Owned(points), params, Some(trim), true, progress)? {
        (out, Some(trimmed), Some(implicit)) => Ok((out, trimmed, ImplicitFunction(implicit))),
        _ => unreachable!("reconstruct_input trims and keeps the function when asked"),
    }
}

/// Reconstructs, then trims the mesh where its density is low (ALGORITHM.md §10): the one
/// call behind the front ends' `trim` option. Both sets of parameters are checked before any
/// work; the density is computed for the trimming and kept on the mesh only when
/// `params.density` asks for it. The trimming is timed as the last stage.
pub fn reconstruct_and_trim(
    points: PointCloud,
    params: &Params,
    trim: &TrimParams,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Reconstruction, TrimStats)> {
    params.validate()?;
    trim.validate()?;
    match reconstruct_input(Input::Owned(points), params, Some(trim), false, progress)? {
        (out, Some(trimmed), _) => Ok((out, trimmed)),
        (_, None, _) => {
            unreachable!("reconstruct_input trims when it is given trimming parameters")
        }
    }
}

/// The names [`reconstruct_with_progress`] (and [`reconstruct_and_trim`], with `trimming`)
/// reports to its progress callback, in order: the stages, with the solver's steps after
/// "solving". A front end shows them as `[k/N]`.
pub fn stage_plan(params: &Params, trimming: bool) -> Vec<String> {
    let base = params.base_depth().max(1).min(params.depth);
    let solver = std::iter::once("solving base depth".to_string())
        .chain((base + 1..=params.depth).map(|d| format!("solving depth {d}")))
        // Each further cycle of the solver (`solver::cycles`), when there are depths above
        // the base to cycle over.
        .chain(
            (2..=params.cycles())
                .filter(|_| base < params.depth)
                .map(|k| format!("solver cycle {k}")),
        );
    let adaptive = params.noise == Noise::Adaptive;
    ["preparing points", "density"]
        .iter()
        .map(|s| s.to_string())
        .chain((!params.keep_normals).then(|| ORIENTATION.to_string()))
        .chain(adaptive.then(|| NOISE.to_string()))
        .chain(
            [
                "octree",
                "splatting",
                "divergence constraints",
                "clusters",
                "solving",
            ]
            .iter()
            .map(|s| s.to_string()),
        )
        .chain(solver)
        .chain(std::iter::once("iso-value".to_string()))
        .chain(params.grid_res.map(|_| GRID.to_string()))
        .chain(std::iter::once("extraction".to_string()))
        .chain(adaptive.then(|| FRAGMENTS.to_string()))
        .chain(trimming.then(|| "trimming".to_string()))
        .chain(std::iter::once(CHECKING.to_string()))
        .collect()
}

/// The name of the grid's sampling (issue 18), after the iso-value.
const GRID: &str = "grid";

/// The name of stage 10.
const CHECKING: &str = "checking the mesh";

/// The names of the stages of issue 16.
const ORIENTATION: &str = "orientation";
const NOISE: &str = "noise";
const FRAGMENTS: &str = "fragments";

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

/// Stages 1–9, with the trimming between extraction and the checks when `trim` is given;
/// with `keep`, the implicit function is handed back too.
fn reconstruct_input(
    input: Input,
    params: &Params,
    trim: Option<&TrimParams>,
    keep: bool,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Reconstruction, Option<TrimStats>, Option<Implicit>)> {
    let mut run = Run::new(progress);
    let resolution::Resolved {
        params,
        choice: depth_choice,
    } = resolution::resolve(input.cloud(), params)?;
    let params = &params;
    if let Some(res) = params.grid_res {
        grid::check_res(res, params)?;
    }
    // Trimming needs the per-vertex density, kept on the mesh only when asked for.
    let solved = Params {
        density: params.density || trim.is_some(),
        ..params.clone()
    };
    let (implicit, mut stats) = solve_implicit(input, &solved, &mut run)?;
    stats.depth_choice = depth_choice;
    let frame = implicit.frame;
    let grid = params
        .grid_res
        .map(|res| run.stage(GRID, || implicit.grid(res)));
    let (mut mesh, kept) = run.stage("extraction", || extract::extract(implicit, &solved, keep))?;
    // The extraction's scratch, many blocks under the size that glibc unmaps when freed,
    // stays in its heap when freed, and the mesh check's large arrays are mapped beside it:
    // handed back here, it no longer adds to the peak the check reaches (issue 20: the
    // resident set after extraction went from 1.57 to 0.56 GB on 4 M points at depth 11).
    crate::resources::release_free_memory();
    let extracted = (mesh.vertices.len(), mesh.triangles.len());
    if params.noise == Noise::Adaptive {
        let removed = run.stage(FRAGMENTS, || fragments::remove_fragments(&mut mesh));
        if removed > 0 {
            stats
                .warnings
                .push(Warning::FragmentsRemoved { pieces: removed });
        }
    }
    let trimmed = match trim {
        Some(t) => {
            let (cut, trimmed) = run.stage("trimming", || crate::trim::trim(&mesh, t))?;
            mesh = cut;
            if !params.density {
                mesh.density = None;
            }
            Some(trimmed)
        }
        None => None,
    };
    let contradicted = stats.diagnosis.contradicted_normals;
    stats.diagnosis = run.stage(CHECKING, || Diagnosis {
        trimmed: trim.is_some(),
        ..Diagnosis::of(&mesh, frame, params.depth, contradicted)
    });
    // Far outliers coarsen every cell, so their warning already names the likely cause of a
    // poor mesh.
    if !stats
        .warnings
        .iter()
        .any(|w| matches!(w, Warning::FarOutliers(_)))
    {
        stats.warnings.extend(stats.diagnosis.warning());
    }
    (stats.stages, stats.peak_memory) = run.finish();
    let sizes = work::Sizes {
        points: stats.points,
        samples: stats.samples,
        nodes_per_depth: stats.nodes_per_depth.clone(),
        clusters_per_depth: stats.clusters_per_depth.clone(),
        base_depth: params.base_depth().max(1).min(params.depth),
        degree: params.degree.get(),
        iters: params.iters(),
        first_deepest_iters: params.first_deepest_iters(),
        splat_levels: if params.two_level_splat { 2 } else { 1 },
        vertices: extracted.0,
        faces: extracted.1,
    };
    stats.work = work::of_stages(stats.stages.iter().map(|(n, _)| n.as_str()), &sizes);
    Ok((Reconstruction { mesh, stats, grid }, trimmed, kept))
}

/// The GPU [`Params::gpu`] asks for: none for `Off`; for `On`, the device or the error that
/// says why none can be used; for `Auto`, the device or a warning that says why not.
fn open_gpu(params: &Params) -> Result<(Option<gpu::Device>, Option<Warning>)> {
    let open = || gpu::Device::open(params.degree.get());
    match params.gpu {
        Gpu::Off => Ok((None, None)),
        Gpu::On => open().map(|d| (Some(d), None)).map_err(Error::Gpu),
        Gpu::Auto => Ok(match open() {
            Ok(d) => (Some(d), None),
            Err(reason) => (None, Some(Warning::GpuNotUsed { reason })),
        }),
    }
}

/// Stages 1–7: the implicit function χ and its iso-value, with the run's counts (the timings
/// so far stay in `run`).
pub(crate) fn solve_implicit(
    input: Input,
    params: &Params,
    run: &mut Run,
) -> Result<(Implicit, Stats)> {
    params.validate()?;
    // The stages build and free arrays of tens of MiB one after another: without this, glibc
    // keeps the freed ones for reuse and the run's peak is a fifth above what it holds.
    resources::return_large_blocks_when_freed();
    // Opened before any heavy stage, so that a GPU that cannot be used fails the run at once.
    let (gpu, gpu_warning) = open_gpu(params)?;
    let cloud = input.cloud();
    if cloud.positions.len() != cloud.normals.len() {
        return Err(Error::LengthMismatch {
            positions: cloud.positions.len(),
            normals: cloud.normals.len(),
        });
    }
    let prepared = run.stage("preparing points", || prepare::prepare(cloud, params))?;
    drop(input);
    let prepare::Prepared {
        points,
        carried,
        frame,
        input_points,
        dropped,
        warnings,
    } = prepared;
    let mut sampled = run.stage("density", || density::sample(points, carried, params));
    let mut warnings = warnings;
    if !params.keep_normals {
        let flips = run.stage(ORIENTATION, || {
            orientation::repair(&mut sampled.samples, params.depth)
        });
        warnings.extend(flips);
    }
    let noise = (params.noise == Noise::Adaptive).then(|| {
        run.stage(NOISE, || {
            noise::adapt(
                &sampled.samples,
                &sampled.density,
                &mut sampled.depths,
                params.depth,
            )
        })
        .in_units(frame.width)
    });
    let refined = run.stage("octree", || tree::build(&sampled, params, input_points))?;
    let field = run.stage("splatting", || splat::splat(&refined, &sampled, params))?;
    let weights = sampled.screening_weights();
    let density::Sampled {
        samples,
        values,
        attribute_types,
        density,
        depths,
    } = sampled;
    let screen_depths = system::screen_depths(&depths);
    drop(depths);
    // Only the per-vertex density reads the density after the splatting.
    let density = params.density.then_some(density);
    let tree::Refined {
        tree,
        memory_estimate,
        splats,
    } = refined;
    drop(splats);
    // From here on only the samples' positions and weights are needed, and a few normals to
    // check χ against (stage 9).
    let probe = NormalProbe::take(&samples);
    let samples_len = samples.len();
    let points = system::SamplePoints {
        positions: samples.iter().map(|s| s.pos).collect(),
        weights,
        screen_depths,
    };
    drop(samples);
    let fem = Basis::new(params.degree, params.boundary);
    let constrained = run.stage("divergence constraints", || {
        solve::constraints(&tree, fem, field.v, params, gpu.as_ref())
    });
    let channels = attribute_types.len();
    let screening = run.stage("clusters", || {
        system::screening(
            &tree,
            fem,
            &points,
            values,
            channels,
            field.mean_area,
            params,
        )
    });
    let system::Screening { clusters, data } = screening;
    let mut solution = run.stage("solving", || {
        solve::solve(
            &tree,
            fem,
            constrained,
            &clusters,
            params,
            gpu.as_ref(),
            run.progress,
        )
    });
    warnings.extend(gpu_warning);
    if let Some(reason) = gpu.as_ref().and_then(|g| g.take_failure()) {
        warnings.push(Warning::GpuNotUsed {
            reason: format!(
                "{reason}; that step, and any other the card could not do, ran on the CPU, \
                 with the same result"
            ),
        });
    }
    let solve_report = solution.report.take();
    let clusters_per_depth = clusters[DEPTH_OFFSET as usize..]
        .iter()
        .map(|c| c.node.len())
        .collect();
    drop(clusters);
    run.add_parts(&solution.timings);
    let eval = Evaluator::new(&tree, fem, &solution);
    let iso = run.stage("iso-value", || iso::iso_value(&eval, &points));
    let contradicted_normals = probe.contradicted(&eval);
    drop(probe);
    let stats = Stats {
        points: input_points,
        dropped,
        samples: samples_len,
        nodes_per_depth: tree.levels[DEPTH_OFFSET as usize..]
            .iter()
            .map(|l| l.len())
            .collect(),
        clusters_per_depth,
        iso_value: iso,
        mean_sample_depth: field.mean_depth,
        warnings,
        memory_estimate,
        noise,
        diagnosis: Diagnosis {
            contradicted_normals,
            ..Diagnosis::default()
        },
        solve: solve_report,
        gpu: gpu.as_ref().map(|g| g.name().to_string()),
        gpu_relaxations: gpu.as_ref().map(|g| g.take_timings()).unwrap_or_default(),
        ..Stats::default()
    };
    let implicit = Implicit {
        tree,
        solution,
        fem,
        density,
        iso,
        frame,
        data,
        attribute_types,
    };
    Ok((implicit, stats))
}

/// The implicit function at given points, from [`implicit_gradients`].
pub(crate) struct ImplicitSamples {
    /// χ at each point (χ ≈ 1 inside, 0 outside).
    pub values: Vec<f64>,
}

/// The implicit function solved from `cloud` with `params`, sampled at the points `at`
/// (points outside the bounding cube are clamped to it). Used by the global orientation of
/// normals (`normals::orient`).
pub(crate) fn implicit_gradients(
    cloud: &PointCloud,
    params: &Params,
    at: &[[f64; 3]],
) -> Result<ImplicitSamples> {
    let (imp, _) = solve_implicit(Input::Borrowed(cloud), params, &mut Run::new(&|_| {}))?;
    let eval = Evaluator::new(&imp.tree, imp.fem, &imp.solution);
    let values = at
        .par_iter()
        .map(|p| eval.value(imp.frame.to_unit(*p)))
        .collect();
    Ok(ImplicitSamples { values })
}

/// Times the stages of a run and reports each as it starts.
pub(crate) struct Run<'a> {
    stages: Vec<(String, Duration)>,
    memory: Vec<Option<u64>>,
    progress: &'a (dyn Fn(&str) + Sync),
}

impl<'a> Run<'a> {
    pub(crate) fn new(progress: &'a (dyn Fn(&str) + Sync)) -> Self {
        Self {
            stages: Vec::new(),
            memory: Vec::new(),
            progress,
        }
    }

    /// Runs one stage: reports its name, then records its wall time and the peak memory.
    pub(crate) fn stage<T>(&mut self, name: &str, f: impl FnOnce() -> T) -> T {
        (self.progress)(name);
        let start = Instant::now();
        let out = f();
        self.stages.push((name.to_string(), start.elapsed()));
        self.memory.push(resources::peak_rss());
        out
    }

    /// Records the parts of the last stage (indented under it).
    fn add_parts(&mut self, parts: &[(String, Duration, Option<u64>)]) {
        for (n, d, m) in parts {
            self.stages.push((format!("  {n}"), *d));
            self.memory.push(*m);
        }
    }

    pub(crate) fn finish(self) -> (Vec<(String, Duration)>, Vec<Option<u64>>) {
        (self.stages, self.memory)
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Points on a sphere by the golden-angle spiral, with exact outward normals.
    pub(super) fn sphere(n: usize, c: [f64; 3], r: f64) -> PointCloud {
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
            imp.value_grad([c[0] + s * dir[0], c[1] + s * dir[1], c[2] + s * dir[2]])
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
        for degree in [crate::Degree::Linear, crate::Degree::Quadratic] {
            let c = [0.1, -0.2, 0.3];
            let cloud = sphere(60_000, c, 1.0);
            let params = Params {
                depth: 7,
                degree,
                ..Params::default()
            };
            let (imp, _) =
                solve_implicit(Input::Borrowed(&cloud), &params, &mut Run::new(&|_| {})).unwrap();
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
