//! Reconstruction in slabs, for clouds whose tree does not fit in memory (issue 15).
//!
//! This follows the plan of Kazhdan & Hoppe, *Distributed Poisson Surface Reconstruction*
//! (2023) and of the reference's `PoissonReconServer`/`PoissonReconClient`, with our own
//! stages: the cube is cut along x into slabs of about equal point counts; every slab's
//! samples add their share to the coarse levels, which are solved once for the whole cloud;
//! each slab then solves its finer levels from that coarse solution on its own columns plus a
//! padding; the iso-value is summed over the slabs; each slab polygonises its own blocks, and
//! the blocks are numbered as one mesh, the vertices on shared faces once (they are keyed by
//! their finest edge, as in-core).
//!
//! Two things make the slabs' meshes one seamless surface that matches the in-core one:
//! - the slabs' samples are the in-core samples: the points are spilled per column in input
//!   order, and a slab reads enough padding for the density, the noise and the tree around its
//!   own samples to be the in-core ones;
//! - χ on a shared face is the same number in both slabs: after the finer levels are solved,
//!   the coefficients near a face are taken from the slab that owns each node, in both slabs,
//!   before extraction.
//!
//! The phases are in [`phases`]; they exchange plain data and files in a work folder, so that
//! they can run as separate tasks.
//!
//! Per-vertex density is the in-core estimator's at each vertex: a slab's own estimator at the
//! depths its padding covers, the whole cloud's (summed by the coordinator from the slabs'
//! cells, `phases::density_depth`) at the coarser ones. Trimming is that of one piece: its
//! threshold is a quantile of the whole mesh's densities and its islands and holes cross
//! slabs. A mesh written as it comes is trimmed from the work files a slab at a time
//! ([`reconstruct_and_trim_into`], `trim`); one assembled in memory is trimmed there
//! ([`reconstruct_and_trim`]).
//!
//! Attributes (colours and any other numeric property) are carried as in one piece
//! (`crate::data`): every point's values follow it into its column's spill file, the samples
//! average them, and a vertex's value pools the sums of the cells around it at every depth. A
//! slab holds every sample of the cells around its own vertices down to where its padding
//! reaches; the coarser depths' sums are the whole cloud's, added up by the coordinator from
//! each slab's own samples ([`phases::data_depth`]).
//!
//! Not yet in slab mode (refused with a message): weights from a property. The
//! orientation repair (stage 2a) and the far-outlier check are whole-cloud steps and are
//! skipped.

mod codec;
pub mod job;
mod output;
pub mod phases;
mod plan;
mod spill;
mod trim;

use std::path::{Path, PathBuf};

use crate::error::Warning;
use crate::pipeline::prepare::{self, Bounds, Frame, MIN_POINTS};
use crate::pipeline::{diagnose::Diagnosis, fragments, Reconstruction, Run, Stats};
use crate::trim::{TrimParams, TrimStats};
use crate::{io, Error, Noise, Params, PointCloud, PointWeights, Result};
use output::MeshFiles;
pub use output::Written;
pub use plan::{AttributeSchema, Plan};
use spill::ColumnWriter;

/// Where the points come from: files read one after another as one cloud (tiles), or a cloud
/// in memory.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// Point files in any format spsr reads.
    Files(&'a [PathBuf]),
    /// A cloud already in memory.
    Cloud(&'a PointCloud),
}

impl Source<'_> {
    /// Calls `f` with each tile in turn (in chunks), and the file it comes from.
    fn for_each(&self, mut f: impl FnMut(&PointCloud, &Path) -> Result<()>) -> Result<()> {
        match self {
            Source::Files(paths) => {
                for p in *paths {
                    io::read_points_chunks(p, READ_CHUNK, &mut |chunk| f(&chunk, p))?;
                }
                Ok(())
            }
            Source::Cloud(c) => f(c, Path::new("<points in memory>")),
        }
    }
}

/// Points read at a time from an input file (48 MiB of positions and normals): the files are
/// streamed, never whole in memory (except the formats `io::read_points_chunks` reads whole).
const READ_CHUNK: usize = 1 << 20;

/// The memory every slab needs whatever the slab count: its tree holds the complete levels
/// down to the full depth over the whole cube (so that the slabs' trees agree there), and the
/// coarse levels. A limit below it cannot be met by cutting the run into more slabs.
pub fn memory_floor(params: &Params) -> u64 {
    crate::pipeline::tree::full_grid_bytes(params.base_depth())
}

/// How a slab run is cut and where it spills.
#[derive(Debug, Clone)]
pub struct SlabOptions {
    /// Slabs wanted (fewer are used when fewer columns of the base depth hold points).
    pub slabs: usize,
    /// The folder for the spill files: a subfolder is made in it and removed afterwards.
    pub work_dir: PathBuf,
}

/// The names [`reconstruct`] (or, with `streamed`, [`reconstruct_into`]; with `trimming`,
/// [`reconstruct_and_trim`]) reports to its progress callback, in order.
pub fn stage_plan(params: &Params, streamed: bool, trimming: bool) -> Vec<String> {
    let adaptive = params.noise == Noise::Adaptive;
    let in_memory = !streamed;
    let trimming = in_memory && trimming;
    let first = ["reading points", "spilling points"]
        .into_iter()
        .chain(adaptive.then_some("noise"))
        .chain([
            "coarse constraints",
            "solving coarse depths",
            "solving slabs",
        ])
        .map(String::from);
    let cycles = (2..=params.cycles()).flat_map(|k| cycle_stages(k).map(String::from));
    let last = ["extraction"]
        .into_iter()
        .chain(streamed.then_some("writing"))
        .chain(in_memory.then_some("numbering vertices"))
        .chain((in_memory && adaptive).then_some("fragments"))
        .chain(trimming.then_some("trimming"))
        .chain(in_memory.then_some("checking the mesh"))
        .map(String::from);
    first.chain(cycles).chain(last).collect()
}

/// The stages of solver cycle `k` (from 2): the whole cloud's coarse depths, then the slabs.
fn cycle_stages(k: u32) -> [String; 2] {
    [
        format!("cycle {k}: coarse depths"),
        format!("cycle {k}: slabs"),
    ]
}

/// A work folder removed when dropped (also after an error), and by the front ends'
/// interrupt handlers (`io::remove_unfinished_files`) while it exists.
struct WorkDir(
    PathBuf,
    #[allow(dead_code)] crate::io::unfinished::Unfinished,
);

impl WorkDir {
    fn new(parent: &Path) -> Result<WorkDir> {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let path = parent.join(format!("spsr-slabs-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&path).map_err(|e| spill::io_err(&path, e))?;
        let guard = crate::io::unfinished::Unfinished::register(&path);
        Ok(WorkDir(path, guard))
    }
}

impl WorkDir {
    /// The folder, kept (for a job run as tasks, removed by `job::remove`).
    fn keep(mut self) -> PathBuf {
        std::mem::take(&mut self.0)
    }
}

impl Drop for WorkDir {
    fn drop(&mut self) {
        // Removed before the guard unregisters it (fields drop after this).
        if !self.0.as_os_str().is_empty() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Checks the parameters slab mode does not support yet.
fn check_supported(params: &Params) -> Result<()> {
    let refuse = |field: &'static str, value: &str| {
        Err(Error::invalid(
            field,
            value.to_string(),
            "its default in slab mode (not supported there yet)".to_string(),
        ))
    };
    if let PointWeights::Property(name) = &params.weights {
        return refuse("weights", name);
    }
    // Cascadic and V-cycles run across the slabs (the coarse depths once for the whole
    // cloud, the finer ones slab by slab, `phases::cycle_coarse`). A W-cycle visits the
    // coarser depths twice from each finer one: one exchange between the slabs and the
    // coordinator per visit (not done).
    if params.solver == crate::Solver::WCycle {
        return refuse("solver", params.solver.name());
    }
    // The residuals are measured over one level's whole system; a slab holds a part of it.
    if params.report_residuals {
        return refuse("report_residuals", "true");
    }
    // The slabs relax on the CPU; `Gpu::Auto` falls back to it as it does without a GPU.
    if params.gpu == crate::Gpu::On {
        return refuse("gpu", "on");
    }
    // The depth of a width or of the spacing is resolved over the whole cloud in memory
    // (`pipeline::resolution::resolve`); a slab run takes a plain depth.
    if let Some(res) = params.grid_res {
        return Err(Error::invalid(
            "grid_res",
            res,
            "none in slab mode (not supported there yet)",
        ));
    }
    let whole = "a fixed depth in slab mode (a width or auto is resolved over the whole cloud \
                 in memory)";
    match params.resolution {
        crate::Resolution::Depth => Ok(()),
        crate::Resolution::Width(w) => Err(Error::invalid("width", w, whole)),
        crate::Resolution::Auto => Err(Error::invalid("depth", "auto", whole)),
    }
}

/// Reconstructs the cloud of `source` in slabs: one pass for the bounding cube, one that
/// spills the points per column, then the phases of [`phases`] slab after slab. The mesh is
/// assembled in memory; [`reconstruct_into`] writes it as the slabs produce it instead.
pub fn reconstruct(
    source: Source,
    params: &Params,
    options: &SlabOptions,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Reconstruction> {
    let out = run(source, params, options, None, None, progress)?;
    Ok(Reconstruction {
        mesh: out.mesh.expect("assembled in memory"),
        stats: out.stats,
        grid: None,
    })
}

/// As [`reconstruct`], then the mesh trimmed by density as the run in one piece trims it
/// (`crate::reconstruct_and_trim`): the density is computed for the trimming and kept on the
/// mesh only when `params.density` asks for it. The mesh is assembled in memory;
/// [`reconstruct_and_trim_into`] trims it on its way to a file instead.
pub fn reconstruct_and_trim(
    source: Source,
    params: &Params,
    options: &SlabOptions,
    trim: &TrimParams,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Reconstruction, TrimStats)> {
    trim.validate()?;
    let out = run(source, params, options, None, Some(trim), progress)?;
    let reconstruction = Reconstruction {
        mesh: out.mesh.expect("assembled in memory"),
        stats: out.stats,
        grid: None,
    };
    Ok((reconstruction, out.trimmed.expect("trimmed")))
}

/// As [`reconstruct`], writing the mesh to `output` (binary PLY) slab by slab, so that it
/// never has to be in memory whole. The checks of the result count pieces and open edges
/// only (`Stats::diagnosis`). With adaptive noise the small pieces are removed (stage 9) from
/// the files, as in one piece.
pub fn reconstruct_into(
    source: Source,
    params: &Params,
    options: &SlabOptions,
    output: &Path,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Stats, Written)> {
    let out = run(source, params, options, Some(output), None, progress)?;
    Ok((out.stats, out.written.expect("written")))
}

/// As [`reconstruct_into`], the mesh trimmed by density on its way to `output`, a slab at a
/// time (`trim`: the same mesh as [`reconstruct_and_trim`] gives, written as
/// `io::write_mesh` writes it, without the whole mesh in memory).
pub fn reconstruct_and_trim_into(
    source: Source,
    params: &Params,
    options: &SlabOptions,
    trim: &TrimParams,
    output: &Path,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<(Stats, Written, TrimStats)> {
    trim.validate()?;
    let out = run(source, params, options, Some(output), Some(trim), progress)?;
    let trimmed = out.trimmed.expect("trimmed");
    Ok((out.stats, out.written.expect("written"), trimmed))
}

/// What [`run`] made.
struct Outcome {
    /// The mesh, when assembled in memory (without an output).
    mesh: Option<crate::Mesh>,
    stats: Stats,
    /// The counts of the mesh written as it was produced (with an output).
    written: Option<Written>,
    /// The trimming's figures (with trimming).
    trimmed: Option<TrimStats>,
}

/// The slab run; with `output`, the mesh goes to that file as it is produced; with `trim`,
/// the mesh is trimmed (in memory, or on its way to `output`).
fn run(
    source: Source,
    params: &Params,
    options: &SlabOptions,
    output: Option<&Path>,
    trim: Option<&TrimParams>,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Outcome> {
    params.validate()?;
    check_supported(params)?;
    let asked = params;
    // Trimming needs the per-vertex density, kept on the mesh only when asked for.
    let solved = solving(params, trim.is_some());
    let params = &solved;
    if options.slabs == 0 {
        return Err(Error::invalid("slabs", 0, "at least 1"));
    }
    crate::resources::return_large_blocks_when_freed();
    let mut run = Run::new(progress);
    let work = WorkDir::new(&options.work_dir)?;
    let dir = work.0.as_path();

    let (found, frame, attributes) = run.stage("reading points", || bounds_pass(source, params))?;
    let counts = run.stage("spilling points", || {
        spill_pass(source, params, frame, &attributes, dir)
    })?;
    let plan = Plan::new(frame, params, counts, options.slabs).with_attributes(attributes);
    let k = plan.slabs.len();

    let smooth = if params.noise == Noise::Adaptive {
        let histograms = run.stage("noise", || {
            (0..k)
                .map(|s| phases::noise_depths(dir, &plan, s, params))
                .collect::<Result<Vec<_>>>()
        })?;
        Some(smoothing_depth(&histograms, params))
    } else {
        None
    };
    let mut parts = run.stage("coarse constraints", || {
        (0..k)
            .map(|s| phases::coarse(dir, &plan, s, params, smooth))
            .collect::<Result<Vec<_>>>()
    })?;
    let samples: usize = parts.iter().map(|p| p.samples).sum();
    let density_cells: Vec<_> = parts
        .iter_mut()
        .map(|p| std::mem::take(&mut p.density))
        .collect();
    let data_sums: Vec<_> = parts
        .iter_mut()
        .map(|p| std::mem::take(&mut p.data))
        .collect();
    // The later phases read the slabs' samples as the coarse phase kept them.
    remove_spent_files(dir, &plan)?;
    // Each slab reads only its part of the coarse solve: the whole of it is not kept.
    let mean_depth = run.stage("solving coarse depths", || -> Result<f64> {
        if params.density {
            phases::save_coarse_density(dir, &plan, params, density_cells)?;
        }
        if plan.channels() > 0 {
            phases::save_coarse_data(dir, &plan, data_sums)?;
        }
        let coarse = phases::solve_coarse(dir, parts, &plan, params)?;
        job::save_crops(dir, &plan, params, &coarse, samples as u64)?;
        Ok(coarse.mean_depth)
    })?;
    let coarse_of = |s| job::read_crop(dir, &plan, s, params).map(|c| c.0);
    let solve_slabs = |cycle| {
        (0..k)
            .map(|s| phases::solve(dir, &plan, s, params, &coarse_of(s)?, cycle))
            .collect::<Result<Vec<_>>>()
    };
    let mut solved = run.stage("solving slabs", || solve_slabs(1))?;
    for cycle in 2..=params.cycles() {
        let [coarse_stage, slabs_stage] = cycle_stages(cycle);
        run.stage(&coarse_stage, || {
            job::cycle_coarse_in(dir, &plan, params, cycle)
        })?;
        solved = run.stage(&slabs_stage, || solve_slabs(cycle))?;
    }
    let iso = iso_value(&solved);
    let mut sink = match output {
        Some(_) => Sink::Files(Box::new(MeshFiles::new(
            dir,
            face_planes(&plan, params),
            plan.attributes.clone(),
        )?)),
        None => Sink::Memory(Vec::with_capacity(k), Vec::new(), Vec::new()),
    };
    run.stage("extraction", || -> Result<()> {
        for s in 0..k {
            let before: &[_] = if s > 0 { &solved[s - 1].faces[1] } else { &[] };
            let after: &[_] = if s + 1 < k {
                &solved[s + 1].faces[0]
            } else {
                &[]
            };
            let coarse = coarse_of(s)?;
            let extracted = phases::extract(dir, &plan, s, params, &coarse, iso, [before, after])?;
            match &mut sink {
                Sink::Memory(all, density, values) => {
                    density.extend(extracted.density.iter().flatten());
                    values.extend(extracted.attributes.iter().flatten());
                    all.push(extracted.blocks);
                }
                Sink::Files(files) => files.add(extracted.into_part(), frame)?,
            }
        }
        Ok(())
    })?;
    let mut warnings = Vec::new();
    let trimmed;
    let (mesh, written, diagnosis) = match (sink, output) {
        (Sink::Files(files), Some(path)) => {
            let adaptive = params.noise == Noise::Adaptive;
            let done = run.stage("writing", || {
                trim::finish(files.close()?, path, adaptive, trim, asked.density)
            })?;
            if done.fragments > 0 {
                warnings.push(Warning::FragmentsRemoved {
                    pieces: done.fragments,
                });
            }
            trimmed = done.trimmed;
            let diagnosis = Diagnosis {
                trimmed: trimmed.is_some(),
                ..written_diagnosis(&done.written)
            };
            (None, Some(done.written), diagnosis)
        }
        (Sink::Memory(blocks, density, values), _) => {
            drop(work);
            let mut mesh = run.stage("numbering vertices", || {
                crate::extract::Blocks::concat(blocks).assemble()
            })?;
            if params.density {
                mesh.density = Some(density);
            }
            mesh.attributes = output::attribute_columns(&plan.attributes, &values);
            for p in &mut mesh.vertices {
                *p = frame.to_world(*p);
            }
            let (mesh, more, diagnosis, cut) =
                finish_in_memory(mesh, asked, trim, frame, &mut run)?;
            warnings = more;
            trimmed = cut;
            (Some(mesh), None, diagnosis)
        }
        (Sink::Files(_), None) => unreachable!("files only with an output"),
    };
    let (stages, peak_memory) = run.finish();
    let stats = Stats {
        stages,
        peak_memory,
        ..slab_stats(found, samples, iso, mean_depth, k, diagnosis, warnings)
    };
    Ok(Outcome {
        mesh,
        stats,
        written,
        trimmed,
    })
}

/// The end of a run whose mesh is whole in memory (in the input's frame), as in one piece:
/// small pieces removed (with adaptive noise), the trimming (with `trim`; the density is
/// dropped afterwards unless `params` asks for it) and the checks of the result.
#[allow(clippy::type_complexity)]
fn finish_in_memory(
    mut mesh: crate::Mesh,
    params: &Params,
    trim: Option<&TrimParams>,
    frame: Frame,
    run: &mut Run,
) -> Result<(crate::Mesh, Vec<Warning>, Diagnosis, Option<TrimStats>)> {
    let mut warnings = Vec::new();
    if params.noise == Noise::Adaptive {
        let removed = run.stage("fragments", || fragments::remove_fragments(&mut mesh));
        if removed > 0 {
            warnings.push(Warning::FragmentsRemoved { pieces: removed });
        }
    }
    let mut trimmed = None;
    if let Some(t) = trim {
        let (cut, stats) = run.stage("trimming", || crate::trim::trim(&mesh, t))?;
        mesh = cut;
        if !params.density {
            mesh.density = None;
        }
        trimmed = Some(stats);
    }
    let diagnosis = run.stage("checking the mesh", || Diagnosis {
        trimmed: trim.is_some(),
        ..Diagnosis::of(&mesh, frame, params.depth, 0.0)
    });
    Ok((mesh, warnings, diagnosis, trimmed))
}

/// The parameters the phases run with: the density computed also for trimming.
fn solving(params: &Params, trimming: bool) -> Params {
    Params {
        density: params.density || trimming,
        ..params.clone()
    }
}

/// What the first pass found: the points read and those left out as unusable.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Found {
    pub points: usize,
    pub dropped: usize,
}

/// The attributes a tile carries onto the mesh (name and type, in order), by the rule of a
/// run in one piece (`prepare::carried_columns`).
fn carried_attributes(cloud: &PointCloud, params: &Params) -> AttributeSchema {
    prepare::carried_columns(cloud, params.attributes)
        .into_iter()
        .map(|a| (a.name.clone(), a.data.scalar_type()))
        .collect()
}

/// Checks that a tile carries the attributes the first one did (as `PointCloud::append` does
/// for tiles read into memory).
fn check_attributes(first: &AttributeSchema, tile: &AttributeSchema, path: &Path) -> Result<()> {
    if first == tile {
        return Ok(());
    }
    let names = |a: &AttributeSchema| -> String {
        a.iter()
            .map(|(n, t)| format!("{n} ({})", t.ply_name()))
            .collect::<Vec<_>>()
            .join(", ")
    };
    Err(Error::Parse {
        path: path.to_path_buf(),
        message: format!(
            "the tiles' properties differ: [{}] here, [{}] before",
            names(tile),
            names(first)
        ),
    })
}

/// Pass 1: the points' count, the bounding cube of the usable ones and the attributes they
/// carry onto the mesh.
fn bounds_pass(source: Source, params: &Params) -> Result<(Found, Frame, AttributeSchema)> {
    let mut bounds = Bounds::default();
    let (mut points, mut usable_points) = (0usize, 0usize);
    let mut attributes: Option<AttributeSchema> = None;
    source.for_each(|cloud, path| {
        check_cloud(cloud)?;
        let carried = carried_attributes(cloud, params);
        check_attributes(
            attributes.get_or_insert_with(|| carried.clone()),
            &carried,
            path,
        )?;
        let weight_of = prepare::weights(cloud, &params.weights)?;
        let usable = prepare::usable(cloud, &weight_of);
        points += cloud.len();
        usable_points += usable.len();
        for &i in &usable {
            bounds.add(cloud.positions[i]);
        }
        Ok(())
    })?;
    let dropped = points - usable_points;
    if usable_points < MIN_POINTS {
        return Err(Error::TooFewPoints {
            usable: usable_points,
            dropped,
            required: MIN_POINTS,
        });
    }
    let (frame, _) = bounds.cube(params.scale)?;
    Ok((
        Found { points, dropped },
        frame,
        attributes.unwrap_or_default(),
    ))
}

/// Pass 2: the usable points in the unit cube, with the values of `attributes`, spilled per
/// column into `dir`; the points per column.
fn spill_pass(
    source: Source,
    params: &Params,
    frame: Frame,
    attributes: &AttributeSchema,
    dir: &Path,
) -> Result<Vec<u64>> {
    let columns = 1usize << Plan::block_depth(params);
    let mut writer = ColumnWriter::new(dir, columns, attributes.len());
    let n = columns as f64;
    let mut values = vec![0.0; attributes.len()];
    source.for_each(|cloud, path| {
        // Pass 1 checked the tiles; a file changed since is caught here.
        check_attributes(attributes, &carried_attributes(cloud, params), path)?;
        let carried = prepare::carried_columns(cloud, params.attributes);
        let weight_of = prepare::weights(cloud, &params.weights)?;
        for i in prepare::usable(cloud, &weight_of) {
            let p = prepare::unit_point(frame, cloud.positions[i], cloud.normals[i], weight_of(i));
            let c = ((p.0[0] * n).floor() as i64).clamp(0, columns as i64 - 1);
            for (v, a) in values.iter_mut().zip(&carried) {
                *v = a.data.get(i).unwrap_or(0.0);
            }
            writer.push(c as usize, &p, &values)?;
        }
        Ok(())
    })?;
    writer.finish()
}

/// Both passes over the input, for a job run as tasks.
pub(crate) struct Spilled {
    pub frame: Frame,
    pub counts: Vec<u64>,
    pub found: Found,
    pub attributes: AttributeSchema,
}

fn spill_points(source: Source, params: &Params, dir: &Path) -> Result<Spilled> {
    let (found, frame, attributes) = bounds_pass(source, params)?;
    let counts = spill_pass(source, params, frame, &attributes, dir)?;
    Ok(Spilled {
        frame,
        counts,
        found,
        attributes,
    })
}

/// Deletes the files no phase after the coarse one reads: the spilled points and the noise
/// measurements (the slabs' samples are kept instead), so that a run needs the disk for
/// about one copy of the cloud at a time.
fn remove_spent_files(dir: &Path, plan: &Plan) -> Result<()> {
    spill::remove_columns(dir, &plan.counts)?;
    phases::remove_measured(dir, plan.slabs.len())
}

/// The depth at which all slabs smooth the noise, from the slabs' histograms of measured
/// depths.
fn smoothing_depth(histograms: &[Vec<u64>], params: &Params) -> u32 {
    let mut sum = vec![0u64; params.depth as usize + 1];
    for h in histograms {
        for (a, b) in sum.iter_mut().zip(h) {
            *a += b;
        }
    }
    crate::pipeline::noise::smoothing_depth(&sum, params.depth)
}

/// γ: the weighted mean of χ over all slabs' own samples (summed in slab order).
fn iso_value(solved: &[phases::Solved]) -> f64 {
    let sums = solved.iter().fold([0.0; 2], |a, s| {
        [a[0] + s.iso_sums[0], a[1] + s.iso_sums[1]]
    });
    sums[0] / sums[1]
}

/// x of the faces between slabs, in cells of the finest depth.
fn face_planes(plan: &Plan, params: &Params) -> Vec<u32> {
    let cells = 1u32 << params.depth;
    plan.slabs[1..]
        .iter()
        .map(|r| (r.start as u32) << (params.depth - plan.block_depth))
        .filter(|&x| x < cells)
        .collect()
}

/// The checks of a mesh written slab by slab: pieces and open edges.
fn written_diagnosis(w: &Written) -> Diagnosis {
    Diagnosis {
        pieces: w.pieces,
        closed: w.open_edges == 0,
        boundary_edges: w.open_edges as usize,
        ..Diagnosis::default()
    }
}

/// The statistics of a slab run, stage timings and peak memory aside; `warnings` are those
/// of the run's end (removed fragments).
#[allow(clippy::too_many_arguments)]
fn slab_stats(
    found: Found,
    samples: usize,
    iso: f64,
    mean_depth: f64,
    slabs: usize,
    diagnosis: Diagnosis,
    warnings: Vec<Warning>,
) -> Stats {
    let dropped = (found.dropped > 0).then_some(Warning::DroppedPoints {
        dropped: found.dropped,
        total: found.points,
    });
    let warnings = dropped
        .into_iter()
        .chain(warnings)
        .chain(diagnosis.warning())
        .collect();
    Stats {
        points: found.points,
        dropped: found.dropped,
        samples,
        iso_value: iso,
        mean_sample_depth: mean_depth,
        warnings,
        diagnosis,
        slabs,
        ..Stats::default()
    }
}

/// Where the slabs' meshes go.
enum Sink {
    /// Kept, to be numbered as one mesh in memory, with the vertices' density (when asked
    /// for) and attribute values (each vertex's, one per attribute) in the order the blocks
    /// number them.
    Memory(Vec<crate::extract::Blocks>, Vec<f32>, Vec<f64>),
    /// Written to the work folder as they come.
    Files(Box<MeshFiles>),
}

/// A tile's normals must match its positions.
fn check_cloud(cloud: &PointCloud) -> Result<()> {
    if cloud.positions.len() != cloud.normals.len() {
        return Err(Error::LengthMismatch {
            positions: cloud.positions.len(),
            normals: cloud.normals.len(),
        });
    }
    Ok(())
}
