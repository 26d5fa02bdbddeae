//! `spsr reconstruct --slabs K`: the run cut into slabs that are solved one after another in
//! bounded memory (`spsr::slabs`), the points streamed from the input files (tiles) to spill
//! files in the work folder.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::files::{input_name, report};
use crate::progress::Progress;
use crate::reconstruct::ReconstructArgs;
use crate::{usage, words, Failure};

/// Whether the slab run writes its mesh as it goes (trimmed on the way with `--trim`): a
/// binary PLY file.
pub(crate) fn streams(args: &ReconstructArgs) -> bool {
    writes_binary_ply(args)
}

/// Whether the output is a binary PLY file.
fn writes_binary_ply(args: &ReconstructArgs) -> bool {
    let out = &args.output;
    out.as_os_str() != "-"
        && !args.common.ascii
        && out
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
}

/// Runs the reconstruction in `k` slabs, writing the mesh (binary PLY) as the slabs produce
/// it, trimmed on the way with `trim`; then the warnings, `-v`'s stage table and the summary
/// line.
pub(crate) fn run_streamed(
    args: &ReconstructArgs,
    params: &spsr::Params,
    k: usize,
    trim: Option<&spsr::trim::TrimParams>,
    start: std::time::Instant,
) -> Result<(), Failure> {
    let (inputs, options) = check(args)?;
    let plan = spsr::slabs::stage_plan(params, true, trim.is_some());
    let progress = Progress::new(plan.len(), std::io::stderr().is_terminal());
    let input = args.input();
    let source = spsr::slabs::Source::Files(&inputs);
    let options = spsr::slabs::SlabOptions {
        slabs: k,
        ..options
    };
    let stage = |s: &str| progress.stage(s);
    let (stats, written, trimmed) = match trim {
        Some(t) => spsr::slabs::reconstruct_and_trim_into(
            source,
            params,
            &options,
            t,
            &args.output,
            &stage,
        )
        .map(|(s, w, t)| (s, w, Some(t))),
        None => spsr::slabs::reconstruct_into(source, params, &options, &args.output, &stage)
            .map(|(s, w)| (s, w, None)),
    }
    .map_err(|e| Failure::from_spsr(e, input_name(input)))?;
    drop(progress);
    if let Some(p) = &args.preview {
        // The mesh was never whole in memory; the picture reads it back.
        let mesh = spsr::io::read_mesh(&args.output)
            .map_err(|e| Failure::from_spsr(e, input_name(input)))?;
        crate::render::write_preview(&mesh, p, input)?;
    }
    for w in &stats.warnings {
        eprintln!(
            "spsr: warning: {}: {}",
            args.inputs_label(),
            words::warning(w)
        );
    }
    if args.common.verbose {
        eprintln!(
            "slabs       {}\npoints      {} read, {} dropped\nsamples     {}\niso-value   {}\ntimings:",
            stats.slabs, stats.points, stats.dropped, stats.samples, stats.iso_value
        );
        for ((name, time), peak) in stats.stages.iter().zip(&stats.peak_memory) {
            let peak = peak.map_or(String::new(), |b| {
                format!("   peak {:>8.0} MiB", b as f64 / (1024.0 * 1024.0))
            });
            eprintln!("  {name:<34} {:>8.3} s{peak}", time.as_secs_f64());
        }
        if let Some(t) = &trimmed {
            // Trimmed while writing: the writing stage's time includes the trimming.
            let writing = stats.stages.iter().find(|(n, _)| n == "writing");
            crate::trim::print_trim(t, writing.map_or(Duration::ZERO, |s| s.1));
        }
    }
    let d = &stats.diagnosis;
    let closed = if d.closed {
        "closed".to_string()
    } else {
        format!("open ({} edges without a partner)", d.boundary_edges)
    };
    let mut line = format!(
        "{} vertices, {} faces, {} piece{}, {closed}, in {k} slabs, in {:.2} s",
        written.vertices,
        written.triangles,
        d.pieces,
        if d.pieces == 1 { "" } else { "s" },
        start.elapsed().as_secs_f64()
    );
    if let Some(bytes) = spsr::peak_rss() {
        line += &format!(", peak memory {:.0} MiB", bytes as f64 / (1024.0 * 1024.0));
    }
    report(&args.output, &line);
    Ok(())
}

/// The checks of a slab run's arguments; the inputs and the work folder.
fn check(args: &ReconstructArgs) -> Result<(Vec<PathBuf>, spsr::slabs::SlabOptions), Failure> {
    let inputs = args.inputs();
    if inputs.iter().any(|p| p.as_os_str() == "-") {
        return Err(usage(
            "--slabs reads its inputs twice, so it needs files, not standard input (-)".into(),
        ));
    }
    if args.estimate_normals {
        return Err(usage(
            "--estimate-normals is not supported with --slabs yet: estimate normals with \
             `spsr normals` first"
                .into(),
        ));
    }
    let work_dir = work_dir(args.work_dir.as_deref(), &args.output);
    Ok((inputs, spsr::slabs::SlabOptions { slabs: 0, work_dir }))
}

/// The result of a slab run whose mesh is whole in memory, with its trimming.
pub(crate) type InMemory = (
    spsr::Reconstruction,
    Option<spsr::trim::TrimStats>,
    Duration,
    Progress,
);

/// Runs the reconstruction in `k` slabs, the mesh assembled in memory (and trimmed with
/// `trim`); returns the result, the trimming's figures, the time spent reading (within the
/// run: the inputs are read as the run goes) and the progress bar for writing.
pub(crate) fn run(
    args: &ReconstructArgs,
    params: &spsr::Params,
    k: usize,
    trim: Option<&spsr::trim::TrimParams>,
) -> Result<InMemory, Failure> {
    let (inputs, options) = check(args)?;
    let options = spsr::slabs::SlabOptions {
        slabs: k,
        ..options
    };
    let plan = spsr::slabs::stage_plan(params, false, trim.is_some());
    let progress = Progress::new(plan.len() + 1, std::io::stderr().is_terminal());
    let input = args.input();
    let source = spsr::slabs::Source::Files(&inputs);
    let stage = |s: &str| progress.stage(s);
    let (result, trimmed) = match trim {
        Some(t) => {
            let (r, t) = spsr::slabs::reconstruct_and_trim(source, params, &options, t, &stage)
                .map_err(|e| Failure::from_spsr(e, input_name(input)))?;
            (r, Some(t))
        }
        None => (
            spsr::slabs::reconstruct(source, params, &options, &stage)
                .map_err(|e| Failure::from_spsr(e, input_name(input)))?,
            None,
        ),
    };
    let reading = result
        .stats
        .stages
        .iter()
        .filter(|(n, _)| n == "reading points")
        .map(|s| s.1)
        .sum();
    Ok((result, trimmed, reading, progress))
}

/// The folder for the spill files: `--work-dir`, else the output's folder (the system's
/// temporary folder when the output is standard output).
fn work_dir(given: Option<&Path>, output: &Path) -> PathBuf {
    if let Some(dir) = given {
        return dir.to_path_buf();
    }
    if output.as_os_str() == "-" {
        return std::env::temp_dir();
    }
    match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Whether slabs can bring a run over the limit under it: not below [`SLAB_FLOOR`] (the
/// coarse levels, one slab's buffers) nor below the complete levels down to the full depth,
/// which every slab holds over the whole cube (`spsr::slabs::memory_floor`).
pub(crate) fn can_help(short: &spsr::MemoryShortfall, params: &spsr::Params) -> bool {
    short.limit >= SLAB_FLOOR && short.limit > floor(params).saturating_add(SLAB_FLOOR / 2)
}

/// See [`can_help`].
const SLAB_FLOOR: u64 = 256 << 20;

fn floor(params: &spsr::Params) -> u64 {
    spsr::slabs::memory_floor(params)
}

/// Slabs for a run whose one-piece estimate is over the limit: what is over the floor that
/// every slab holds, over what the limit leaves above it, doubled for the padding each slab
/// reads and the coarse levels every slab holds.
pub(crate) fn enough(short: &spsr::MemoryShortfall, params: &spsr::Params) -> usize {
    let f = floor(params);
    let over = short.estimate.saturating_sub(f) as f64;
    let room = short.limit.saturating_sub(f).max(1) as f64;
    ((2.0 * over / room).ceil() as usize).clamp(2, 64)
}

/// A slab run on a cluster (`python -m spsr.distributed`), from `spsr reconstruct`'s flags:
/// the same parameters as the command line's, so that both front ends share one description.
#[derive(Debug)]
pub struct ClusterRun {
    /// The input files (tiles), read as one cloud.
    pub inputs: Vec<PathBuf>,
    /// The mesh to write (binary PLY).
    pub output: PathBuf,
    /// `--slabs K`, or `None` for `auto` (the coordinator picks a count for its workers).
    pub slabs: Option<usize>,
    /// The folder for the job's files (`--work-dir`, else the output's folder).
    pub work_dir: PathBuf,
    /// The reconstruction's parameters, checked.
    pub params: spsr::Params,
    /// `--trim` and its areas, checked: the mesh is trimmed by density.
    pub trim: Option<spsr::trim::TrimParams>,
    /// `--threads`: the threads of each task (`None`: all the worker's cores).
    pub threads: Option<usize>,
    /// `-v`: print the run's figures.
    pub verbose: bool,
}

/// Parses `argv` (program name first, then `reconstruct`'s arguments) for a run on a cluster;
/// `Err(Ok(_))` is clap's (usage or `--help`), `Err(Err(_))` a refusal with its exit code.
pub fn cluster_run(argv: &[String]) -> Result<ClusterRun, Result<clap::Error, Failure>> {
    let mut full = vec![argv.first().cloned().unwrap_or_else(|| "spsr".into())];
    full.push("reconstruct".into());
    full.extend(argv.iter().skip(1).cloned());
    let cli = crate::try_parse_from(&full).map_err(Ok)?;
    let crate::Command::Reconstruct(args) = cli.command else {
        unreachable!("parsed as reconstruct")
    };
    let refuse = |m: &str| Err(Err(usage(m.into())));
    if !writes_binary_ply(&args) {
        return refuse(
            "a cluster run writes binary PLY: give an output file ending in .ply (not -), \
             without --ascii",
        );
    }
    if args.preview.is_some() {
        return refuse("--preview is not supported on a cluster; run `spsr render` on the mesh");
    }
    let (inputs, options) = check(&args).map_err(Err)?;
    let params = args.params();
    params
        .validate()
        .map_err(|e| Err(Failure::from_spsr(e, input_name(args.input()))))?;
    let trim = args.trim_params();
    if let Some(t) = &trim {
        t.validate()
            .map_err(|e| Err(Failure::from_spsr(e, input_name(args.input()))))?;
    }
    Ok(ClusterRun {
        inputs,
        output: args.output.clone(),
        slabs: match args.slabs {
            crate::reconstruct::Slabs::Auto => None,
            crate::reconstruct::Slabs::Count(k) => Some(k),
        },
        work_dir: options.work_dir,
        params,
        trim,
        threads: args.common.threads.threads,
        verbose: args.common.verbose,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn short(estimate_mib: u64, limit_mib: u64) -> spsr::MemoryShortfall {
        spsr::MemoryShortfall {
            estimate: estimate_mib << 20,
            limit: limit_mib << 20,
            source: spsr::MemoryLimit::Requested,
            nodes: 0,
            depth: 10,
            suggested_depth: None,
        }
    }

    #[test]
    fn slabs_are_offered_only_where_they_can_fit() {
        let params = spsr::Params::default();
        // The default full depth (5) leaves almost all of the limit to the slabs.
        assert!(can_help(&short(470, 280), &params));
        assert_eq!(enough(&short(470, 280), &params), 4);
        assert_eq!(enough(&short(100_000, 1024), &params), 64);
        // Below the floor of a slab run, or a full depth whose complete levels alone
        // (44 bytes × 19 M nodes at depth 8, with the program's 64 MiB: 870 MiB) leave less
        // than half a slab's floor under the limit: the one-piece error stands.
        assert!(!can_help(&short(470, 200), &params));
        let deep = spsr::Params {
            full_depth: 8,
            ..params
        };
        assert!(!can_help(&short(1660, 960), &deep));
        assert!(can_help(&short(4000, 3000), &deep));
        assert!(enough(&short(4000, 3000), &deep) >= 2);
    }
}
