//! `spsr reconstruct --slabs K`: the run cut into slabs that are solved one after another in
//! bounded memory (`spsr::slabs`), the points streamed from the input files (tiles) to spill
//! files in the work folder.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::files::input_name;
use crate::progress::Progress;
use crate::reconstruct::ReconstructArgs;
use crate::{usage, Failure};

/// Runs the reconstruction in `k` slabs; returns the result, the time spent reading (within
/// the run: the inputs are read as the run goes) and the progress bar for writing.
pub(crate) fn run(
    args: &ReconstructArgs,
    params: &spsr::Params,
    k: usize,
    trimming: bool,
) -> Result<(spsr::Reconstruction, Duration, Progress), Failure> {
    if trimming {
        return Err(usage(
            "--trim is not supported with --slabs yet (slab runs do not compute the per-vertex \
             density it needs); run without --slabs to trim"
                .into(),
        ));
    }
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
    let plan = spsr::slabs::stage_plan(params);
    let progress = Progress::new(plan.len() + 1, std::io::stderr().is_terminal());
    let options = spsr::slabs::SlabOptions { slabs: k, work_dir };
    let input = args.input();
    let result = spsr::slabs::reconstruct(
        spsr::slabs::Source::Files(&inputs),
        params,
        &options,
        &|s| progress.stage(s),
    )
    .map_err(|e| Failure::from_spsr(e, input_name(input)))?;
    let reading = result
        .stats
        .stages
        .iter()
        .filter(|(n, _)| n == "reading points")
        .map(|s| s.1)
        .sum();
    Ok((result, reading, progress))
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

/// Slabs for a run whose one-piece estimate is over the limit: the estimate over the limit,
/// doubled for the padding each slab reads and the coarse levels every slab holds.
pub(crate) fn enough(short: &spsr::MemoryShortfall) -> usize {
    let ratio = short.estimate as f64 / short.limit.max(1) as f64;
    ((2.0 * ratio).ceil() as usize).clamp(2, 64)
}
