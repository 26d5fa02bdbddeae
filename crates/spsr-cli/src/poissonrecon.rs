//! The habits of PoissonRecon users: the reference's flag spellings on `spsr reconstruct`.
//!
//! The reference's flags that spsr has are hidden aliases of its own (`--samplesPerNode` is
//! `--samples-per-node`; see [`crate::ReconstructArgs`]), so a PoissonRecon command line runs
//! unchanged. Those spsr does not have are listed here: each is refused with a message that
//! names it and says what to use instead, before clap would guess a "similar argument".
//!
//! The list is PoissonRecon's options over its versions (6 to 18), read from its
//! `PoissonRecon.cpp`.

use std::ffi::OsString;

use clap::error::ErrorKind;
use clap::CommandFactory;

/// The reference's options that `spsr reconstruct` does not support, with what to use
/// instead (or why there is no need), completing "… does not support".
const UNSUPPORTED: &[(&str, &str)] = &[
    ("adaptiveExp", "spsr has no adaptive exponent"),
    ("alignDir", "spsr writes no voxel grid"),
    ("baseDepth", "the coarse solve happens at --full-depth"),
    (
        "baseVCycles",
        "spsr solves the coarse depth by conjugate gradients",
    ),
    (
        "cgAccuracy",
        "spsr solves the coarse depth by conjugate gradients to 1e-7",
    ),
    ("cgDepth", "the coarse solve happens at --full-depth"),
    ("chunkSize", "use --threads"),
    (
        "color",
        "spsr carries colours by default; --data-pull sets the pull factor",
    ),
    ("complete", "spsr adapts the octree to the points"),
    (
        "confidenceBias",
        "use --confidence or --confidence-property",
    ),
    ("double", "spsr always computes in double precision"),
    ("envelope", "spsr has no envelope constraint"),
    ("envelopeDepth", "spsr has no envelope constraint"),
    ("exact", "spsr has no exact interpolation"),
    (
        "gradients",
        "use --normals for per-vertex normals from the gradient",
    ),
    ("gridCoordinates", "spsr writes no voxel grid"),
    ("inCore", "spsr always works in memory (see --max-memory)"),
    (
        "kernelDepth",
        "the density estimate's depth is --depth minus 2",
    ),
    ("lowDepthCutOff", "spsr has no low-depth cut-off"),
    ("maxSolveDepth", "use --depth"),
    ("minDepth", "the coarse solve happens at --full-depth"),
    ("noComments", "spsr writes no comments"),
    ("noErode", "spsr has no Dirichlet erosion"),
    ("nonManifold", "spsr's meshes are always manifold"),
    ("nWeights", "use --confidence"),
    ("parallel", "use --threads"),
    ("performance", "use -v for the timings and peak memory"),
    ("polygonMesh", "spsr writes triangles only"),
    ("primalGrid", "spsr writes no voxel grid"),
    ("schedule", "use --threads"),
    ("solveDepth", "use --depth"),
    ("tempDir", "spsr always works in memory (see --max-memory)"),
    ("tree", "spsr writes no octree file"),
    ("voxel", "spsr writes no voxel grid"),
    ("voxelDepth", "spsr writes no voxel grid"),
    ("xForm", "transform the points before reconstructing"),
];

/// Refuses a `spsr reconstruct` command line that uses one of PoissonRecon's options spsr
/// does not support, with clap's usage error (exit code 2) naming the option and what to
/// use instead.
pub(crate) fn check(argv: &[OsString]) -> Result<(), clap::Error> {
    if argv.get(1).is_none_or(|a| a != "reconstruct") {
        return Ok(());
    }
    let flags = argv[2..]
        .iter()
        .take_while(|a| *a != "--")
        .filter_map(|a| a.to_str()?.strip_prefix("--"));
    for flag in flags {
        let name = flag.split('=').next().unwrap_or(flag);
        if let Some((_, instead)) = UNSUPPORTED.iter().find(|(n, _)| *n == name) {
            let message = format!(
                "--{name} is a PoissonRecon option that spsr reconstruct does not support: \
                 {instead}"
            );
            let mut cli = crate::Cli::command();
            cli.build();
            let cmd = cli.find_subcommand_mut("reconstruct");
            return Err(match cmd {
                Some(cmd) => cmd.error(ErrorKind::UnknownArgument, message),
                None => clap::Error::raw(ErrorKind::UnknownArgument, message),
            });
        }
    }
    Ok(())
}

/// Parses `--bType`: PoissonRecon's boundary numbers, 1 free, 2 Dirichlet, 3 Neumann.
pub(crate) fn parse_boundary(s: &str) -> Result<crate::BoundaryArg, String> {
    use crate::BoundaryArg as B;
    match s.trim() {
        "1" => Ok(B::Free),
        "2" => Ok(B::Dirichlet),
        "3" => Ok(B::Neumann),
        _ => Err(format!(
            "'{s}' is not a boundary type; use 1 (free), 2 (Dirichlet) or 3 (Neumann), or \
             --boundary free|dirichlet|neumann"
        )),
    }
}

/// Parses `--maxMemory`: PoissonRecon's limit in GB (taken as GiB), in bytes; 0 is the
/// reference's "no limit", which leaves spsr's default (the memory available).
pub(crate) fn parse_max_memory_gb(s: &str) -> Result<u64, String> {
    let gb: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number of GB"))?;
    if !(gb.is_finite() && gb >= 0.0) {
        return Err("must be a number of GB, at least 0".into());
    }
    Ok((gb * f64::from(1u32 << 30)) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_unsupported_list_is_sorted_and_names_no_supported_flag() {
        use clap::CommandFactory;
        let names: Vec<&str> = UNSUPPORTED.iter().map(|(n, _)| *n).collect();
        let mut sorted = names.clone();
        sorted.sort_unstable_by_key(|n| n.to_ascii_lowercase());
        assert_eq!(names, sorted);
        let cli = crate::Cli::command();
        let reconstruct = cli.find_subcommand("reconstruct").unwrap();
        for arg in reconstruct.get_arguments() {
            for long in arg.get_long_and_visible_aliases().into_iter().flatten() {
                assert!(!names.contains(&long), "--{long} is supported");
            }
            for alias in arg.get_all_aliases().into_iter().flatten() {
                assert!(!names.contains(&alias), "--{alias} is supported");
            }
        }
    }

    #[test]
    fn reference_values_map_to_spsr_values() {
        use crate::BoundaryArg as B;
        assert_eq!(parse_boundary("1"), Ok(B::Free));
        assert_eq!(parse_boundary("2"), Ok(B::Dirichlet));
        assert_eq!(parse_boundary("3"), Ok(B::Neumann));
        assert!(parse_boundary("0").is_err());
        assert_eq!(parse_max_memory_gb("2"), Ok(2 << 30));
        assert_eq!(parse_max_memory_gb("0"), Ok(0));
        assert!(parse_max_memory_gb("-1").is_err());
    }
}
