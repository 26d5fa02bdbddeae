//! A slab run as separate tasks, for a cluster (the Python package's `spsr.distributed` runs
//! them on Dask): every step reads and writes files in one job folder that all the machines
//! can reach, so a task needs nothing but the folder and its slab's number.
//!
//! The coordinator calls [`prepare`] (the two passes over the input: bounding cube and spill
//! files), then runs the slab tasks of each phase (in any order, anywhere, as often as a
//! scheduler likes) and its own steps between them:
//!
//! | step | who | reads | writes |
//! |---|---|---|---|
//! | [`prepare`] | coordinator | the input files | `job.json`, the column files |
//! | [`noise`] (adaptive noise only) | slab task | columns | `slab-s.noise`, `slab-s.measured` |
//! | [`smoothing`] | coordinator | every `slab-s.noise` | the smoothing depth in `job.json` |
//! | [`coarse`] | slab task | columns (or `slab-s.measured`) | `slab-s.samples`, `slab-s.coarse` (with the density, its density cells), `slab-s.constraints` |
//! | [`solve_coarse`] | coordinator | every `slab-s.coarse` | `slab-s.coarse-solution`, `density.coarse` (with the density), `data.coarse` (with attributes), `coarse-1.state` (with more than one solver cycle); deletes the columns and `.measured` |
//! | [`solve`] (cycle k) | slab task | `slab-s.samples`, `slab-s.coarse-solution`, `slab-s.constraints`, `slab-s.solution-(k−1)` | `slab-s.solution-k`, `slab-s.solved`; before the last cycle `slab-s.coupling-k` |
//! | [`cycle`] (with more than one solver cycle; then [`solve`] again) | coordinator | `coarse-k.state`, every `slab-s.coupling-k` | `coarse-(k+1).state`, `slab-s.coarse-solution`; deletes the files of the cycles before |
//! | [`iso`] | coordinator | every `slab-s.solved` | the iso-value in `job.json` |
//! | [`extract`] | slab task | `slab-s.samples`, `slab-s.coarse-solution`, `slab-s.solution-k` (the last cycle's), the neighbours' `.solved`, `density.coarse`, `data.coarse` | `slab-s.part` |
//! | [`finish`] | coordinator | every `slab-s.part` | the output mesh (trimmed a slab at a time when the job trims) |
//!
//! The tasks are pure functions of their inputs and write every file atomically (to a
//! temporary name, renamed when complete), so a task that dies half-way leaves nothing behind
//! and can simply be run again within its phase (once [`solve_coarse`] has deleted the
//! columns, the phases before it cannot); the mesh is the same bytes as the one-process run
//! of [`super::reconstruct_into`] with the same slab count.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::codec::{load, save, CoarseRecord, Histogram};
use super::output::MeshFiles;
use super::phases::{self, Coarse, CoarsePart, Solved};
use super::{spill_points, AttributeSchema, Found, Plan, Source, Spilled, WorkDir, Written};
use crate::extract::Part;
use crate::pipeline::{prepare::Frame, Stats};
use crate::trim::{Threshold, TrimParams};
use crate::{Error, Noise, Params, Result};

/// What [`prepare`] made: the job folder and its slabs.
#[derive(Debug, Clone)]
pub struct Job {
    /// The job folder (inside the work folder given to [`prepare`]); [`remove`] deletes it.
    pub dir: PathBuf,
    /// The slabs (fewer than asked when fewer columns hold points).
    pub slabs: usize,
    /// Whether the noise phase runs ([`noise`], then [`smoothing`]).
    pub noise: bool,
    /// The solver cycles: after [`solve`], each cycle after the first is the coordinator's
    /// [`cycle`], then [`solve`] again.
    pub cycles: u32,
}

/// The job's description, shared by every task.
#[derive(Serialize, Deserialize)]
struct JobFile {
    /// The format of the job folder (a task refuses another).
    version: u32,
    params: Params,
    origin: [f64; 3],
    width: f64,
    counts: Vec<u64>,
    slabs_wanted: usize,
    points: usize,
    dropped: usize,
    /// The depth at which the noise is smoothed, once [`smoothing`] has run.
    smooth: Option<u32>,
    /// The solver cycle whose coarse solution the slabs' parts of it hold: 1 once
    /// [`solve_coarse`] has run, one more after each [`cycle`] (0 before).
    cycle: u32,
    /// The iso-value, once [`iso`] has run.
    iso: Option<f64>,
    /// The trimming of the mesh, when asked for ([`finish`] trims).
    trim: Option<TrimSpec>,
    /// The attributes the points carry onto the mesh (name and type).
    attributes: AttributeSchema,
}

/// [`TrimParams`] as the job's description stores them.
#[derive(Serialize, Deserialize, Clone, Copy)]
struct TrimSpec {
    /// The density level; `None` for the automatic one.
    threshold: Option<f32>,
    min_island_area: f64,
    hole_area: f64,
}

impl From<&TrimParams> for TrimSpec {
    fn from(t: &TrimParams) -> TrimSpec {
        TrimSpec {
            threshold: match t.threshold {
                Threshold::Value(v) => Some(v),
                Threshold::Auto => None,
            },
            min_island_area: t.min_island_area,
            hole_area: t.hole_area,
        }
    }
}

impl From<TrimSpec> for TrimParams {
    fn from(t: TrimSpec) -> TrimParams {
        TrimParams {
            threshold: t.threshold.map_or(Threshold::Auto, Threshold::Value),
            min_island_area: t.min_island_area,
            hole_area: t.hole_area,
        }
    }
}

const VERSION: u32 = 4;

impl JobFile {
    fn read(dir: &Path) -> Result<JobFile> {
        let path = dir.join("job.json");
        let text = std::fs::read(&path).map_err(|e| super::spill::io_err(&path, e))?;
        let job: JobFile = serde_json::from_slice(&text).map_err(|e| Error::Parse {
            path: path.clone(),
            message: format!("not a slab job's description ({e})"),
        })?;
        if job.version != VERSION {
            return Err(Error::Parse {
                path,
                message: format!(
                    "a slab job of format {} (this spsr reads format {VERSION})",
                    job.version
                ),
            });
        }
        Ok(job)
    }

    fn write(&self, dir: &Path) -> Result<()> {
        let text = serde_json::to_vec_pretty(self).expect("plain data");
        crate::io::write_with(&dir.join("job.json"), |w| w.write_all(&text))
    }

    /// The parameters the phases run with (the density computed also for trimming).
    fn solving(&self) -> Params {
        super::solving(&self.params, self.trim.is_some())
    }

    fn plan(&self) -> Plan {
        let frame = Frame {
            origin: self.origin,
            width: self.width,
        };
        Plan::new(frame, &self.params, self.counts.clone(), self.slabs_wanted)
            .with_attributes(self.attributes.clone())
    }

    /// The smoothing depth, required once the noise phase is due.
    fn smooth(&self) -> Result<Option<u32>> {
        match (self.params.noise, self.smooth) {
            (Noise::Adaptive, None) => Err(out_of_order("smoothing")),
            (_, s) => Ok(s),
        }
    }

    fn slab(&self, s: usize) -> Result<Plan> {
        let plan = self.plan();
        if s >= plan.slabs.len() {
            return Err(Error::invalid(
                "slab",
                s,
                format!("below the job's {} slabs", plan.slabs.len()),
            ));
        }
        Ok(plan)
    }
}

fn out_of_order(step: &str) -> Error {
    Error::invalid(
        "job step",
        "run out of order",
        format!("after the coordinator's `{step}` step"),
    )
}

fn slab_file(dir: &Path, s: usize, kind: &str) -> PathBuf {
    dir.join(format!("slab-{s:04}.{kind}"))
}

/// Reads the points of `source` (two passes: the bounding cube, then the spill files) into a
/// new job folder inside `work_dir`, cut into at most `slabs` slabs. With `trim`, [`finish`]
/// trims the mesh as [`super::reconstruct_and_trim_into`] does.
pub fn prepare(
    source: Source,
    params: &Params,
    trim: Option<&TrimParams>,
    slabs: usize,
    work_dir: &Path,
) -> Result<Job> {
    params.validate()?;
    super::check_supported(params)?;
    if let Some(t) = trim {
        t.validate()?;
    }
    if slabs == 0 {
        return Err(Error::invalid("slabs", 0, "at least 1"));
    }
    let work = WorkDir::new(work_dir)?;
    let Spilled {
        frame,
        counts,
        found,
        attributes,
    } = spill_points(source, params, &work.0)?;
    let job = JobFile {
        version: VERSION,
        params: params.clone(),
        origin: frame.origin,
        width: frame.width,
        counts,
        slabs_wanted: slabs,
        points: found.points,
        dropped: found.dropped,
        smooth: None,
        cycle: 0,
        iso: None,
        trim: trim.map(TrimSpec::from),
        attributes,
    };
    let k = job.plan().slabs.len();
    job.write(&work.0)?;
    Ok(Job {
        dir: work.keep(),
        slabs: k,
        noise: params.noise == Noise::Adaptive,
        cycles: params.cycles(),
    })
}

/// Slab task: the histogram of the depths at which the slab's noise was measured.
pub fn noise(dir: &Path, s: usize) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let job = JobFile::read(dir)?;
    let plan = job.slab(s)?;
    let h = phases::noise_depths(dir, &plan, s, &job.solving())?;
    save(&slab_file(dir, s, "noise"), &Histogram(h))
}

/// Coordinator: the depth at which all slabs smooth the noise, from the slabs' histograms.
pub fn smoothing(dir: &Path) -> Result<()> {
    let mut job = JobFile::read(dir)?;
    let k = job.plan().slabs.len();
    let histograms = (0..k)
        .map(|s| load::<Histogram>(&slab_file(dir, s, "noise")).map(|h| h.0))
        .collect::<Result<Vec<_>>>()?;
    job.smooth = Some(super::smoothing_depth(&histograms, &job.params));
    job.write(dir)
}

/// Slab task: what the slab's own samples add to the coarse levels.
pub fn coarse(dir: &Path, s: usize) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let job = JobFile::read(dir)?;
    let plan = job.slab(s)?;
    let part = phases::coarse(dir, &plan, s, &job.solving(), job.smooth()?)?;
    save(&slab_file(dir, s, "coarse"), &part)
}

/// Coordinator: the coarse levels solved for the whole cloud.
pub fn solve_coarse(dir: &Path) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let job = JobFile::read(dir)?;
    let plan = job.plan();
    let params = job.solving();
    let mut parts = (0..plan.slabs.len())
        .map(|s| load::<CoarsePart>(&slab_file(dir, s, "coarse")))
        .collect::<Result<Vec<_>>>()?;
    let samples = parts.iter().map(|p| p.samples as u64).sum();
    // Every coarse task has ended (a barrier before this step).
    super::remove_spent_files(dir, &plan)?;
    if params.density {
        let cells = parts
            .iter_mut()
            .map(|p| std::mem::take(&mut p.density))
            .collect();
        phases::save_coarse_density(dir, &plan, &params, cells)?;
    }
    if plan.channels() > 0 {
        let sums = parts
            .iter_mut()
            .map(|p| std::mem::take(&mut p.data))
            .collect();
        phases::save_coarse_data(dir, &plan, sums)?;
    }
    let c = phases::solve_coarse(dir, parts, &plan, &params)?;
    save_crops(dir, &plan, &params, &c, samples)?;
    drop(c);
    let mut job = job;
    job.cycle = 1;
    job.write(dir)
}

/// Coordinator, with more than one solver cycle: the next cycle of the whole cloud's coarse
/// levels, from the slabs' couplings of the cycle before ([`phases::cycle_coarse`]).
pub fn cycle(dir: &Path) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let mut job = JobFile::read(dir)?;
    let params = job.solving();
    if job.cycle == 0 {
        return Err(out_of_order("solve_coarse"));
    }
    if job.cycle >= params.cycles() {
        return Err(Error::invalid(
            "job step",
            "cycle",
            format!("at most {} solver cycles in all", params.cycles()),
        ));
    }
    let next = job.cycle + 1;
    cycle_coarse_in(dir, &job.plan(), &params, next)?;
    job.cycle = next;
    job.write(dir)
}

/// Cycle `cycle` (from 2) of the whole cloud's coarse levels ([`phases::cycle_coarse`]), each
/// slab's part of it written as [`save_crops`] writes the first, and the files the cycles
/// before no longer need deleted.
pub(super) fn cycle_coarse_in(dir: &Path, plan: &Plan, params: &Params, cycle: u32) -> Result<()> {
    let (coarse, samples) = phases::cycle_coarse(dir, plan, params, cycle)?;
    save_crops(dir, plan, params, &coarse, samples)?;
    drop(coarse);
    phases::remove_spent_cycle(dir, plan.slabs.len(), cycle)
}

/// Writes each slab's part of the coarse solve ([`phases::crop`]) to `slab-s.coarse-solution`,
/// so that a slab task reads only what it needs.
pub(super) fn save_crops(
    dir: &Path,
    plan: &Plan,
    params: &Params,
    coarse: &Coarse,
    samples: u64,
) -> Result<()> {
    for s in 0..plan.slabs.len() {
        let c = phases::crop(coarse, plan, s, params);
        let record = CoarseRecord {
            refined: c.refined,
            x: c.solution.x,
            p: c.solution.p,
            base_level: c.solution.base_level,
            carry: c.carry,
            mean_area: c.mean_area,
            mean_depth: c.mean_depth,
            samples,
        };
        save(&slab_file(dir, s, "coarse-solution"), &record)?;
    }
    Ok(())
}

/// Slab `s`'s part of the coarse solve written by [`save_crops`], with its tree rebuilt, and
/// the samples of all slabs.
pub(super) fn read_crop(
    dir: &Path,
    plan: &Plan,
    s: usize,
    params: &Params,
) -> Result<(Coarse, u64)> {
    let path = slab_file(dir, s, "coarse-solution");
    let r: CoarseRecord = load(&path)?;
    let tree = phases::coarse_tree(&r.refined, plan, params).0;
    let levels_ok = r.x.len() == tree.levels.len()
        && r.x
            .iter()
            .zip(&tree.levels)
            .all(|(x, l)| x.is_empty() || x.len() == l.len())
        && tree
            .levels
            .get(r.carry.level as usize)
            .is_some_and(|l| l.len() == r.carry.p.len() && l.len() == r.carry.vc.len());
    if !levels_ok {
        return Err(Error::Parse {
            path,
            message: "the coarse solution does not fit the coarse tree".into(),
        });
    }
    let coarse = Coarse {
        tree,
        refined: r.refined,
        solution: crate::solver::Solution {
            x: r.x,
            p: r.p,
            base_level: r.base_level,
            timings: Vec::new(),
            report: None,
        },
        carry: r.carry,
        mean_area: r.mean_area,
        mean_depth: r.mean_depth,
    };
    Ok((coarse, r.samples))
}

/// Slab task: the slab's finer levels, its share of the iso-value and its face bands.
pub fn solve(dir: &Path, s: usize) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let job = JobFile::read(dir)?;
    let plan = job.slab(s)?;
    let params = job.solving();
    if job.cycle == 0 {
        return Err(out_of_order("solve_coarse"));
    }
    let (coarse, _) = read_crop(dir, &plan, s, &params)?;
    let solved = phases::solve(dir, &plan, s, &params, &coarse, job.cycle)?;
    save(&slab_file(dir, s, "solved"), &solved)
}

/// Coordinator: the iso-value from all slabs' shares.
pub fn iso(dir: &Path) -> Result<()> {
    let mut job = JobFile::read(dir)?;
    if job.cycle < job.params.cycles() {
        return Err(out_of_order("cycle"));
    }
    let k = job.plan().slabs.len();
    let solved = (0..k)
        .map(|s| load::<Solved>(&slab_file(dir, s, "solved")))
        .collect::<Result<Vec<_>>>()?;
    job.iso = Some(super::iso_value(&solved));
    job.write(dir)
}

/// Slab task: the slab's part of the mesh.
pub fn extract(dir: &Path, s: usize) -> Result<()> {
    crate::resources::return_large_blocks_when_freed();
    let job = JobFile::read(dir)?;
    let plan = job.slab(s)?;
    let iso = job.iso.ok_or_else(|| out_of_order("iso"))?;
    let k = plan.slabs.len();
    let params = job.solving();
    let (coarse, _) = read_crop(dir, &plan, s, &params)?;
    let neighbour = |n: Option<usize>, face: usize| -> Result<Vec<_>> {
        match n {
            Some(n) => {
                let mut solved: Solved = load(&slab_file(dir, n, "solved"))?;
                Ok(std::mem::take(&mut solved.faces[face]))
            }
            None => Ok(Vec::new()),
        }
    };
    let before = neighbour(s.checked_sub(1), 1)?;
    let after = neighbour((s + 1 < k).then_some(s + 1), 0)?;
    let extracted = phases::extract(dir, &plan, s, &params, &coarse, iso, [&before, &after])?;
    save(&slab_file(dir, s, "part"), &extracted.into_part())
}

/// Coordinator: the slabs' parts stitched into one mesh, written to `output` (binary PLY),
/// with the run's statistics (no stage timings: the tasks ran elsewhere), trimmed when the
/// job trims, a slab at a time (`super::trim`).
pub fn finish(dir: &Path, output: &Path) -> Result<(Stats, Written)> {
    let job = JobFile::read(dir)?;
    let plan = job.plan();
    let iso = job.iso.ok_or_else(|| out_of_order("iso"))?;
    // Every slab's part of the coarse solve carries the whole cloud's sample count and depth.
    let (coarse, samples) = read_crop(dir, &plan, 0, &job.solving())?;
    let found = Found {
        points: job.points,
        dropped: job.dropped,
    };
    let mut files = MeshFiles::new(
        dir,
        super::face_planes(&plan, &job.params),
        plan.attributes.clone(),
    )?;
    for s in 0..plan.slabs.len() {
        let part: Part = load(&slab_file(dir, s, "part"))?;
        files.add(part, plan.frame)?;
    }
    let trim = job.trim.map(TrimParams::from);
    let adaptive = job.params.noise == crate::Noise::Adaptive;
    let done = super::trim::finish(
        files.close()?,
        output,
        adaptive,
        trim.as_ref(),
        job.params.density,
    )?;
    let warnings = (done.fragments > 0)
        .then_some(crate::error::Warning::FragmentsRemoved {
            pieces: done.fragments,
        })
        .into_iter()
        .collect();
    let diagnosis = crate::pipeline::diagnose::Diagnosis {
        trimmed: trim.is_some(),
        ..super::written_diagnosis(&done.written)
    };
    let stats = super::slab_stats(
        found,
        samples as usize,
        iso,
        coarse.mean_depth,
        plan.slabs.len(),
        diagnosis,
        warnings,
    );
    let written = done.written;
    Ok((stats, written))
}

/// Deletes the job folder (after [`finish`], or to give up).
pub fn remove(dir: &Path) -> Result<()> {
    // Only a folder that holds a job: never a folder the caller pointed at by mistake.
    if !dir.join("job.json").is_file() {
        return Err(Error::invalid(
            "job folder",
            dir.display().to_string(),
            "a folder made by slabs::job::prepare (it has a job.json)",
        ));
    }
    std::fs::remove_dir_all(dir).map_err(|e| super::spill::io_err(dir, e))
}
