//! The `spsr` command line as a library: argument definitions ([`Cli`]), the commands ([`run`]),
//! and the mapping of failures to exit codes ([`Failure`], [`exit`]). `main.rs` only parses,
//! calls [`run`], and prints the one error line.

use std::ffi::OsString;
use std::path::Path;

use clap::parser::ValueSource;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

pub mod args;
mod eval;
mod files;
mod normals;
mod poissonrecon;
mod progress;
mod reconstruct;
mod render;
mod slabs;
mod trim;
pub mod words;

pub use eval::{run_eval, EvalArgs};
pub use files::{check_output_arg, is_std_stream, read_cloud_arg, read_mesh_arg, write_mesh_arg};
pub use normals::{NormalOptions, NormalsArgs, OrientArg};
pub use reconstruct::{BoundaryArg, ReconstructArgs};
pub use render::{run_render, RenderArgs};
pub use slabs::{cluster_run, ClusterRun};
pub use trim::{run_trim, TrimArgs};

/// Exit codes of the `spsr` binary (also listed in `--help` and the README).
pub mod exit {
    /// The input data cannot be used: unreadable or malformed file, too few points, a
    /// `--compare` reference without normals.
    pub const DATA: u8 = 1;
    /// Bad usage: bad flags or parameter values, or an output path that cannot be used.
    /// (clap exits with 2 on its own for command-line syntax errors.)
    pub const USAGE: u8 = 2;
    /// A resource limit: the run would need more memory than allowed (`--max-memory`, or the
    /// memory the machine has available), the disk is full, or the worker threads could not
    /// be started.
    pub const RESOURCE: u8 = 3;
}

const EXIT_CODES: &str = "\
Exit codes:
  0  success
  1  bad input data (unreadable or malformed file, too few or degenerate points, a --compare
     reference without normals)
  2  bad usage (unknown flag, invalid parameter value, unusable output path)
  3  resource limit (estimated memory above --max-memory or the available memory; a full
     disk; worker threads could not be started; no usable GPU with --gpu)";

/// Command-line arguments of `spsr`.
#[derive(Debug, Parser)]
#[command(
    name = "spsr",
    version,
    about = "Screened Poisson surface reconstruction: oriented point cloud to watertight mesh",
    after_help = EXIT_CODES,
    propagate_version = true
)]
pub struct Cli {
    /// The command to run.
    #[command(subcommand)]
    pub command: Command,
}

/// The commands of `spsr`.
#[derive(Debug, Subcommand)]
// Parsed once per process, so the size of the largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
pub enum Command {
    /// Reconstruct a mesh from an oriented point cloud.
    // INPUT may also be given as PoissonRecon's --in, which clap would show as `[INPUT]`.
    #[command(
        long_about = reconstruct::RECONSTRUCT_LONG_ABOUT,
        after_help = EXIT_CODES,
        override_usage = "spsr reconstruct [OPTIONS] --output <OUTPUT> <INPUT>"
    )]
    Reconstruct(ReconstructArgs),
    /// Remove the surface a reconstruction invented where there were no samples, by density.
    #[command(long_about = trim::TRIM_LONG_ABOUT, after_help = EXIT_CODES)]
    Trim(TrimArgs),
    /// Score a mesh against a ground-truth mesh or an analytic sphere.
    #[command(long_about = eval::EVAL_LONG_ABOUT, after_help = EXIT_CODES)]
    Eval(EvalArgs),
    /// Estimate and orient normals for a point cloud without (trustworthy) normals.
    #[command(long_about = normals::NORMALS_LONG_ABOUT, after_help = EXIT_CODES)]
    Normals(NormalsArgs),
    /// Draw a shaded picture of a mesh (PNG), from one side or four.
    #[command(long_about = render::RENDER_LONG_ABOUT, after_help = EXIT_CODES)]
    Render(RenderArgs),
}

/// A failed command: the error to print and the process exit code.
#[derive(Debug)]
pub struct Failure {
    /// Exit code, one of [`exit`].
    pub code: u8,
    /// The error; its `Display` (without the alternate flag) is the complete one-line message.
    pub error: anyhow::Error,
}

impl Failure {
    /// Classifies a library error. `input` is the file whose content is at fault for errors
    /// that do not name one themselves (too few points, degenerate input, ...).
    fn from_spsr(e: spsr::Error, input: &Path) -> Self {
        use spsr::Error as E;
        let code = match &e {
            E::Io { source, .. } if words::disk_full(source) => exit::RESOURCE,
            E::Io { path, .. } if path == input => exit::DATA,
            E::Io { .. } | E::InvalidParameter { .. } | E::Output { .. } => exit::USAGE,
            E::Parse { .. }
            | E::MissingNormals { .. }
            | E::TooFewPoints { .. }
            | E::Degenerate(_)
            | E::InvalidMesh(_)
            | E::MissingDensity
            | E::LengthMismatch { .. } => exit::DATA,
            E::ResourceLimit { .. } | E::Gpu(_) => exit::RESOURCE,
            _ => exit::DATA,
        };
        let names_file = matches!(
            e,
            E::Io { .. } | E::Parse { .. } | E::MissingNormals { .. } | E::Output { .. }
        );
        // The context carries the whole message in the command line's words, so printing it
        // with `{}` gives one line; the library error stays reachable for downcasting.
        let message = words::error(&e).unwrap_or_else(|| e.to_string());
        let error = if names_file
            || matches!(
                e,
                E::InvalidParameter { .. } | E::ResourceLimit { .. } | E::Gpu(_)
            ) {
            anyhow::Error::new(e).context(message)
        } else {
            // Name the file whose content is at fault.
            let message = format!("{}: {message}", input.display());
            anyhow::Error::new(e).context(message)
        };
        Failure { code, error }
    }
}

/// Exit code of a run interrupted by Ctrl-C or a termination signal (128 + SIGINT).
pub const EXIT_INTERRUPTED: i32 = 130;

/// On Ctrl-C (SIGINT), SIGTERM or SIGHUP: deletes the temporary files of outputs being
/// written, so that no partial output is left, and ends the process with
/// [`EXIT_INTERRUPTED`]. An output already renamed into place is complete and stays.
pub fn install_interrupt_handler() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // Failing to install it (another handler exists) only loses the clean-up.
        let _ = ctrlc::set_handler(|| {
            let removed = spsr::io::remove_unfinished_files();
            eprintln!(
                "\nspsr: interrupted{}",
                if removed > 0 {
                    "; the unfinished output was deleted"
                } else {
                    ""
                }
            );
            std::process::exit(EXIT_INTERRUPTED);
        });
    });
}

/// Parses a command line (program name first) as `spsr` does: PoissonRecon options that
/// `spsr reconstruct` does not support are refused with a message naming them, and the
/// arguments given on the command line are recorded (`ReconstructArgs::given`, which `-v`
/// reports). Errors are clap's, to print and exit with (code 2 for usage errors).
pub fn try_parse_from<I, T>(argv: I) -> Result<Cli, clap::Error>
where
    I: IntoIterator<Item = T>,
    T: Into<OsString>,
{
    let argv: Vec<OsString> = argv.into_iter().map(Into::into).collect();
    poissonrecon::check(&argv)?;
    let matches = Cli::command().try_get_matches_from(&argv)?;
    let mut cli = Cli::from_arg_matches(&matches)?;
    if let (Command::Reconstruct(args), Some(m)) =
        (&mut cli.command, matches.subcommand_matches("reconstruct"))
    {
        args.given = m
            .ids()
            .filter(|id| m.value_source(id.as_str()) == Some(ValueSource::CommandLine))
            .map(|id| id.to_string())
            .collect();
    }
    Ok(cli)
}

/// Runs a parsed command line.
///
/// The `spsr` binary installs [`install_interrupt_handler`] first; an embedding process (the
/// Python package) keeps its own signal handling.
pub fn run(cli: &Cli) -> Result<(), Failure> {
    match &cli.command {
        Command::Reconstruct(args) => reconstruct::run_reconstruct(args),
        Command::Trim(args) => run_trim(args),
        Command::Eval(args) => run_eval(args),
        Command::Normals(args) => normals::run_normals(args),
        Command::Render(args) => run_render(args),
    }
}

/// Starts the global worker pool with `threads` threads (rayon's default when `None`).
fn start_threads(threads: Option<usize>) -> Result<(), Failure> {
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .map_err(|e| Failure {
                code: exit::RESOURCE,
                error: anyhow::anyhow!("cannot start {n} worker threads: {e}"),
            })?;
    }
    Ok(())
}

fn usage(message: String) -> Failure {
    Failure {
        code: exit::USAGE,
        error: anyhow::anyhow!(message),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(extra: &[&str]) -> ReconstructArgs {
        let mut argv = vec!["spsr", "reconstruct", "in.ply", "-o", "out.ply"];
        argv.extend_from_slice(extra);
        match Cli::try_parse_from(argv).unwrap().command {
            Command::Reconstruct(a) => a,
            other => panic!("not reconstruct: {other:?}"),
        }
    }

    #[test]
    fn defaults_match_the_library() {
        assert_eq!(args(&[]).params(), spsr::Params::default());
        let trim = args(&["--trim", "auto"]).trim_params().unwrap();
        assert_eq!(trim, spsr::trim::TrimParams::default());
        let argv = ["spsr", "trim", "m.ply", "--trim", "auto", "-o", "o.ply"];
        match Cli::try_parse_from(argv).unwrap().command {
            Command::Trim(t) => {
                let lib = spsr::trim::TrimParams::default();
                assert_eq!(
                    (t.min_island_area, t.hole_area),
                    (lib.min_island_area, lib.hole_area)
                );
            }
            other => panic!("not trim: {other:?}"),
        }
        match Cli::try_parse_from(["spsr", "eval", "m.ply"])
            .unwrap()
            .command
        {
            Command::Eval(e) => assert_eq!(
                e.samples as usize,
                spsr::metrics::EvalOptions::default().samples
            ),
            other => panic!("not eval: {other:?}"),
        }
    }

    #[test]
    fn the_arguments_given_are_recorded_by_any_spelling() {
        let argv = [
            "spsr",
            "reconstruct",
            "--in",
            "in.ply",
            "--out",
            "o.ply",
            "--samplesPerNode",
            "2",
            "--bType",
            "1",
            "--depth",
            "8",
        ];
        let Command::Reconstruct(a) = try_parse_from(argv).unwrap().command else {
            panic!("not reconstruct");
        };
        let mut given = a.given.clone();
        given.sort();
        assert_eq!(
            given,
            [
                "depth",
                "output",
                "reference_boundary",
                "reference_in",
                "samples_per_node"
            ]
        );
        assert_eq!(a.input(), Path::new("in.ply"));
        let p = a.params();
        assert_eq!(
            (p.samples_per_node, p.boundary),
            (2.0, spsr::Boundary::Free)
        );
        // Other subcommands do not look at PoissonRecon's options.
        let e = try_parse_from(["spsr", "trim", "m.ply", "--tempDir", "x"]).unwrap_err();
        assert!(!e.to_string().contains("PoissonRecon"), "{e}");
    }

    #[test]
    fn default_full_depth_follows_a_smaller_depth() {
        assert_eq!(args(&["--depth", "3"]).params().full_depth, 3);
        assert_eq!(
            args(&["--depth", "3", "--full-depth", "4"])
                .params()
                .full_depth,
            4
        );
        assert!(args(&["--depth", "3", "--full-depth", "4"])
            .params()
            .validate()
            .is_err());
    }

    #[test]
    fn flags_reach_the_params() {
        let p = args(&[
            "--point-weight",
            "0",
            "--degree",
            "2",
            "--boundary",
            "dirichlet",
            "--confidence",
            "--density",
        ])
        .params();
        assert_eq!(p.point_weight, Some(0.0));
        assert_eq!(p.degree, spsr::Degree::Quadratic);
        assert_eq!(p.boundary, spsr::Boundary::Dirichlet);
        assert!(p.weights == spsr::PointWeights::NormalLength && p.density);
    }

    #[test]
    fn errors_map_to_exit_codes_and_name_the_file() {
        let input = Path::new("cloud.ply");
        let io = |path: &str| spsr::Error::Io {
            path: path.into(),
            source: std::io::Error::from(std::io::ErrorKind::NotFound),
        };
        let f = Failure::from_spsr(io("cloud.ply"), input);
        assert_eq!(f.code, exit::DATA);
        assert!(f.error.to_string().starts_with("cloud.ply: "));

        let f = Failure::from_spsr(io("out/mesh.ply"), input);
        assert_eq!(f.code, exit::USAGE);

        let few = spsr::Error::TooFewPoints {
            usable: 2,
            dropped: 0,
            required: 4,
        };
        let f = Failure::from_spsr(few, input);
        assert_eq!(f.code, exit::DATA);
        let msg = f.error.to_string();
        assert!(msg.starts_with("cloud.ply: too few usable points"), "{msg}");
        assert!(f.error.downcast_ref::<spsr::Error>().is_some());

        let bad = spsr::Error::invalid("depth", 40, "an integer from 1 to 18");
        let f = Failure::from_spsr(bad, input);
        assert_eq!(f.code, exit::USAGE);
        assert!(!f.error.to_string().contains("cloud.ply"));
    }
}
