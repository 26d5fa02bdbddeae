//! The `spsr` command line as a library: argument definitions ([`Cli`]), the commands ([`run`]),
//! and the mapping of failures to exit codes ([`Failure`], [`exit`]). `main.rs` only parses,
//! calls [`run`], and prints the one error line.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use clap::{Args, Parser, Subcommand, ValueEnum};

mod normals;
pub mod words;
pub use normals::{NormalOptions, NormalsArgs, OrientArg};

/// Exit codes of the `spsr` binary (also listed in `--help` and the README).
pub mod exit {
    /// The input data cannot be used: unreadable or malformed file, no normals, too few points.
    pub const DATA: u8 = 1;
    /// Bad usage: bad flags or parameter values, or an output path that cannot be used.
    /// (clap exits with 2 on its own for command-line syntax errors.)
    pub const USAGE: u8 = 2;
    /// A resource limit: the run would need more memory than allowed (`--max-memory`, or the
    /// memory the machine has available), or the worker threads could not be started.
    pub const RESOURCE: u8 = 3;
}

const EXIT_CODES: &str = "\
Exit codes:
  0  success
  1  bad input data (unreadable or malformed file, no normals, too few or degenerate points)
  2  bad usage (unknown flag, invalid parameter value, unusable output path)
  3  resource limit (estimated memory above --max-memory or the available memory; worker
     threads could not be started)";

const RECONSTRUCT_LONG_ABOUT: &str = "\
Reconstruct a watertight triangle mesh from an oriented point cloud (Screened Poisson Surface \
Reconstruction, Kazhdan & Hoppe 2013).

Input: points with normals (nx ny nz) in one of these formats, recognised by their first bytes or \
else by extension: PLY (any encoding), LAS or LAZ (.las, .laz; normals as extra bytes such as \
NormalX/NormalY/NormalZ), E57 (.e57; every scan, moved by its pose; normals from the surface-normals \
extension), PCD (.pcd; ascii, binary or binary_compressed, fields normal_x normal_y normal_z), or \
text with one point per line: x y z nx ny nz, optionally followed by r g b. Normals must point \
outward. Points with non-finite coordinates or zero-length normals are dropped with a warning. A cloud without normals gets normals estimated and oriented first, as by `spsr normals` (with a note saying so); --estimate-normals does that for any cloud, replacing its normals.

Output, chosen by the output name's extension: .ply (binary little-endian, ASCII with --ascii; also \
used for any other extension), .obj (Wavefront OBJ), .stl (binary STL, ASCII with --ascii), .glb \
(glTF 2.0 binary). The output file appears only once it is complete; on any error no output file \
is left behind. The output must not be the input file.";

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
pub enum Command {
    /// Reconstruct a mesh from an oriented point cloud.
    #[command(long_about = RECONSTRUCT_LONG_ABOUT, after_help = EXIT_CODES)]
    Reconstruct(ReconstructArgs),
    /// Remove the surface a reconstruction invented where there were no samples, by density.
    #[command(long_about = TRIM_LONG_ABOUT, after_help = EXIT_CODES)]
    Trim(TrimArgs),
    /// Score a mesh against a ground-truth mesh or an analytic sphere.
    #[command(long_about = EVAL_LONG_ABOUT, after_help = EXIT_CODES)]
    Eval(EvalArgs),
    /// Estimate and orient normals for a point cloud without (trustworthy) normals.
    #[command(long_about = normals::NORMALS_LONG_ABOUT, after_help = EXIT_CODES)]
    Normals(NormalsArgs),
}

/// Boundary condition on the bounding cube, as spelled on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BoundaryArg {
    /// Zero normal derivative on the cube's faces.
    Neumann,
    /// Zero value on the cube's faces.
    Dirichlet,
    /// No condition; the basis is cut off at the cube.
    Free,
}

impl From<BoundaryArg> for spsr::Boundary {
    fn from(b: BoundaryArg) -> Self {
        match b {
            BoundaryArg::Neumann => spsr::Boundary::Neumann,
            BoundaryArg::Dirichlet => spsr::Boundary::Dirichlet,
            BoundaryArg::Free => spsr::Boundary::Free,
        }
    }
}

/// Arguments of `spsr reconstruct`. Defaults mirror [`spsr::Params::default`].
#[derive(Debug, Args)]
pub struct ReconstructArgs {
    /// Oriented point cloud: PLY, LAS/LAZ, E57, PCD, or text with `x y z nx ny nz` per line;
    /// `-` reads standard input.
    #[arg(value_name = "INPUT")]
    pub input: PathBuf,

    /// Output mesh, by extension: .ply (also any other name), .obj, .stl or .glb; `-` writes
    /// PLY to standard output.
    #[arg(short, long, value_name = "OUTPUT")]
    pub output: PathBuf,

    /// Maximum octree depth; the finest cells are 1/2^depth of the bounding cube. Default as
    /// PoissonRecon 6 and 18.
    #[arg(
        long,
        value_name = "D",
        default_value_t = 8,
        allow_negative_numbers = true
    )]
    pub depth: u32,

    /// Depth down to which the octree is complete; the coarse solve happens there. Default as
    /// PoissonRecon 6 and 18 [default: 5, or --depth when that is smaller]
    #[arg(long, value_name = "D")]
    pub full_depth: Option<u32>,

    /// Target number of samples per octree node (sets each sample's splat depth). Default as
    /// PoissonRecon 18 (version 6 used 1.0).
    #[arg(
        long,
        value_name = "N",
        default_value_t = 1.5,
        allow_negative_numbers = true
    )]
    pub samples_per_node: f64,

    /// Screening weight alpha; 0 gives the unscreened 2006 method. Default as PoissonRecon 18
    /// (4 for degree 2, the 2013 paper's value) [default: 2 × degree]
    #[arg(long, value_name = "ALPHA", allow_negative_numbers = true)]
    pub point_weight: Option<f64>,

    /// B-spline degree of the finite elements, 1 or 2. Default as PoissonRecon 18 (the 2013 paper
    /// and PoissonRecon 6 use 2).
    #[arg(long, value_name = "K", default_value = "1", value_parser = parse_degree)]
    pub degree: spsr::Degree,

    /// Boundary condition on the bounding cube. Default as PoissonRecon 6 and 18.
    #[arg(long, value_enum, default_value_t = BoundaryArg::Neumann)]
    pub boundary: BoundaryArg,

    /// The bounding cube's side is the points' bounding box's largest side times this factor.
    /// Default as PoissonRecon 6 and 18.
    #[arg(
        long,
        value_name = "S",
        default_value_t = 1.1,
        allow_negative_numbers = true
    )]
    pub scale: f64,

    /// Gauss-Seidel sweeps per depth. Default as PoissonRecon 6 and 18 and the 2013 paper.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 8,
        allow_negative_numbers = true
    )]
    pub iters: u32,

    /// Use each normal's length as the point's confidence weight. Off by default, as PoissonRecon
    /// 18 [default: off]
    #[arg(long)]
    pub confidence: bool,

    /// Use this per-point property (e.g. confidence or quality) as each point's weight
    /// instead; points whose value is not positive are dropped. spsr's own [default: none]
    #[arg(long, value_name = "NAME")]
    pub confidence_property: Option<String>,

    /// Write per-vertex normals (nx ny nz) computed from the gradient of the implicit
    /// function. Off by default, as PoissonRecon 18 (--normals) [default: off]
    #[arg(long)]
    pub normals: bool,

    /// Do not carry the points' attributes (colours and any other numeric property) onto the
    /// mesh. spsr carries them by default; PoissonRecon 18 only with --colors [default: off]
    #[arg(long)]
    pub no_attributes: bool,

    /// Pull factor of the attribute interpolation: larger values keep attributes sharper
    /// and stop them bleeding between nearby surfaces. Default as PoissonRecon 18 (--dataX)
    #[arg(
        long,
        value_name = "X",
        default_value_t = 32.0,
        allow_negative_numbers = true
    )]
    pub data_pull: f64,

    /// Compute per-vertex density (estimated sampling depth) and write it as the PLY vertex
    /// property `density`. Off by default, as PoissonRecon 18 [default: off]
    #[arg(long)]
    pub density: bool,

    /// Trim the mesh by density before writing it: remove the parts whose density (estimated
    /// sampling depth) is below V, cutting along the iso-line, or `auto` to derive V from the
    /// mesh's density distribution (see `spsr trim --help`). Computes the density; the file
    /// gets the density property only with --density [default: off]
    #[arg(long, value_name = "V|auto", value_parser = parse_trim, allow_negative_numbers = true)]
    pub trim: Option<spsr::trim::Threshold>,

    /// With --trim: kept pieces smaller than this fraction of the total area are removed.
    /// Default as PoissonRecon 18's SurfaceTrimmer (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.001,
        requires = "trim",
        allow_negative_numbers = true
    )]
    pub min_island_area: f64,

    /// With --trim: trimmed regions inside kept surface smaller than this fraction of the total
    /// area are restored (small holes closed again). Default as PoissonRecon 18's
    /// SurfaceTrimmer (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.001,
        requires = "trim",
        allow_negative_numbers = true
    )]
    pub hole_area: f64,

    /// Place mesh vertices by linear interpolation along cell edges instead of the quadratic fit
    /// through the end values and gradients. Off by default, as PoissonRecon 18 (--linearFit)
    /// [default: off]
    #[arg(long)]
    pub linear_fit: bool,

    /// Refuse the run, before the octree is built, when its estimated peak memory exceeds this
    /// size (bytes, or with a suffix K, M, G, T, powers of 1024; e.g. 8G) [default: the memory
    /// the machine has available]
    #[arg(long, value_name = "SIZE", value_parser = parse_size)]
    pub max_memory: Option<u64>,

    /// Split each sample's normal between the two depths around its estimated depth (2006 paper,
    /// PoissonRecon 6) instead of splatting it whole at the depth above (PoissonRecon 18):
    /// smoother, better on smooth surfaces, less detail on scans [default: off]
    #[arg(long)]
    pub two_level_splat: bool,

    /// Number of worker threads, at least 1. Default: rayon's, which honours RAYON_NUM_THREADS
    /// [default: all cores]
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<usize>,

    /// Write ASCII PLY or STL instead of binary (no effect on .obj and .glb) [default: off]
    #[arg(long)]
    pub ascii: bool,

    /// Print per-stage timings, point and octree counts, the iso-value and the mesh size to
    /// stderr [default: off]
    #[arg(short, long)]
    pub verbose: bool,

    /// Estimate and orient normals even when the input has them (they are replaced); inputs
    /// without normals get estimated normals anyway [default: off]
    #[arg(long)]
    pub estimate_normals: bool,

    /// How estimated normals are oriented (see `spsr normals --help`).
    #[command(flatten)]
    pub estimation: NormalOptions,
}

/// Parses a memory size: a number of bytes, optionally with a binary suffix (K, M, G, T, with
/// or without a trailing `B`/`iB`).
fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let upper = t.to_ascii_uppercase();
    let body = upper.trim_end_matches("IB").trim_end_matches('B');
    let (num, mul) = match body.chars().last() {
        Some('K') => (&body[..body.len() - 1], 1u64 << 10),
        Some('M') => (&body[..body.len() - 1], 1 << 20),
        Some('G') => (&body[..body.len() - 1], 1 << 30),
        Some('T') => (&body[..body.len() - 1], 1 << 40),
        _ => (body, 1),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{t}' is not a size such as 512M or 8G"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err("must be a positive size".into());
    }
    Ok((v * mul as f64) as u64)
}

fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s.parse().map_err(|e| format!("{e}"))?;
    if n == 0 {
        return Err("must be at least 1".into());
    }
    Ok(n)
}

impl ReconstructArgs {
    /// The library parameters these arguments describe (not yet validated).
    pub fn params(&self) -> spsr::Params {
        // An explicit --full-depth deeper than --depth is an error; the default follows --depth.
        let full_depth = self
            .full_depth
            .unwrap_or_else(|| spsr::Params::default().full_depth.min(self.depth));
        spsr::Params {
            depth: self.depth,
            full_depth,
            samples_per_node: self.samples_per_node,
            point_weight: self.point_weight,
            degree: self.degree,
            boundary: self.boundary.into(),
            scale: self.scale,
            iters: self.iters,
            weights: match (&self.confidence_property, self.confidence) {
                (Some(name), _) => spsr::PointWeights::Property(name.clone()),
                (None, true) => spsr::PointWeights::NormalLength,
                (None, false) => spsr::PointWeights::Uniform,
            },
            density: self.density || self.trim.is_some(),
            linear_fit: self.linear_fit,
            max_memory: self.max_memory,
            two_level_splat: self.two_level_splat,
            attributes: !self.no_attributes,
            data_pull: self.data_pull,
            normals: self.normals,
        }
    }
}

/// Parses `--degree`: 1 or 2.
fn parse_degree(s: &str) -> Result<spsr::Degree, String> {
    s.trim()
        .parse::<u8>()
        .ok()
        .and_then(spsr::Degree::from_number)
        .ok_or_else(|| format!("'{s}' is not a supported degree; use 1 or 2"))
}

/// Parses `--trim`: `auto` (any case) or a finite density value.
fn parse_trim(s: &str) -> Result<spsr::trim::Threshold, String> {
    let t = s.trim();
    if t.eq_ignore_ascii_case("auto") {
        return Ok(spsr::trim::Threshold::Auto);
    }
    match t.parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(spsr::trim::Threshold::Value(v)),
        _ => Err(format!(
            "'{t}' is neither a density value (a finite number such as 6.5) nor 'auto'"
        )),
    }
}

impl ReconstructArgs {
    /// The trimming parameters, when --trim was given (not yet validated).
    pub fn trim_params(&self) -> Option<spsr::trim::TrimParams> {
        self.trim.map(|threshold| spsr::trim::TrimParams {
            threshold,
            min_island_area: self.min_island_area,
            hole_area: self.hole_area,
        })
    }
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
            E::Io { path, .. } if path == input => exit::DATA,
            E::Io { .. } | E::InvalidParameter { .. } | E::Output { .. } => exit::USAGE,
            E::Parse { .. }
            | E::MissingNormals { .. }
            | E::TooFewPoints { .. }
            | E::Degenerate(_)
            | E::InvalidMesh(_)
            | E::MissingDensity
            | E::LengthMismatch { .. } => exit::DATA,
            E::ResourceLimit { .. } => exit::RESOURCE,
            _ => exit::DATA,
        };
        let names_file = matches!(
            e,
            E::Io { .. } | E::Parse { .. } | E::MissingNormals { .. } | E::Output { .. }
        );
        // The context carries the whole message in the command line's words, so printing it
        // with `{}` gives one line; the library error stays reachable for downcasting.
        let message = words::error(&e).unwrap_or_else(|| e.to_string());
        let error =
            if names_file || matches!(e, E::InvalidParameter { .. } | E::ResourceLimit { .. }) {
                anyhow::Error::new(e).context(message)
            } else {
                // Name the file whose content is at fault.
                let message = format!("{}: {message}", input.display());
                anyhow::Error::new(e).context(message)
            };
        Failure { code, error }
    }
}

/// `-` as a file name: standard input (for an input) or standard output (for an output).
pub fn is_std_stream(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// What messages call standard input and output.
const STDIN_NAME: &str = "<stdin>";
const STDOUT_NAME: &str = "<stdout>";

/// The name errors about an input give it: `<stdin>` for `-`.
fn input_name(path: &Path) -> &Path {
    if is_std_stream(path) {
        Path::new(STDIN_NAME)
    } else {
        path
    }
}

/// Reads a cloud with or without normals from a file, or from standard input for `-`.
pub fn read_cloud_arg(path: &Path) -> spsr::Result<spsr::PointCloud> {
    if is_std_stream(path) {
        spsr::io::read_cloud_from(std::io::stdin().lock(), Path::new(STDIN_NAME))
    } else {
        spsr::io::read_cloud(path)
    }
}

/// Reads a mesh from a file, or from standard input for `-`.
pub fn read_mesh_arg(path: &Path) -> spsr::Result<spsr::Mesh> {
    if is_std_stream(path) {
        spsr::io::read_mesh_from(std::io::stdin().lock(), Path::new(STDIN_NAME))
    } else {
        spsr::io::read_mesh(path)
    }
}

/// The up-front output check; standard output (`-`) needs none.
pub fn check_output_arg(output: &Path, input: &Path) -> spsr::Result<()> {
    if is_std_stream(output) {
        Ok(())
    } else {
        spsr::io::check_output_path(output, input)
    }
}

/// Writes a mesh to a file (atomically), or as PLY to standard output for `-`.
pub fn write_mesh_arg(
    output: &Path,
    mesh: &spsr::Mesh,
    opts: &spsr::io::WriteOptions,
) -> spsr::Result<()> {
    if is_std_stream(output) {
        let mut out = std::io::stdout().lock();
        spsr::io::write_mesh_to(
            &mut out,
            Path::new(STDOUT_NAME),
            spsr::io::MeshFormat::Ply,
            mesh,
            opts,
        )
    } else {
        spsr::io::write_mesh(output, mesh, opts)
    }
}

/// The closing summary line: on stdout, or on stderr when stdout carries the mesh.
fn report_written(output: &Path, mesh: &spsr::Mesh, start: Instant) {
    let line = format!(
        "spsr: wrote {}: {} vertices, {} faces in {:.2} s",
        if is_std_stream(output) {
            Path::new(STDOUT_NAME)
        } else {
            output
        }
        .display(),
        mesh.vertices.len(),
        mesh.triangles.len(),
        start.elapsed().as_secs_f64()
    );
    if is_std_stream(output) {
        eprintln!("{line}");
    } else {
        println!("{line}");
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

/// Runs a parsed command line.
///
/// The `spsr` binary installs [`install_interrupt_handler`] first; an embedding process (the
/// Python package) keeps its own signal handling.
pub fn run(cli: &Cli) -> Result<(), Failure> {
    match &cli.command {
        Command::Reconstruct(args) => reconstruct(args),
        Command::Trim(args) => run_trim(args),
        Command::Eval(args) => run_eval(args),
        Command::Normals(args) => normals::run_normals(args),
    }
}

/// Shows the current stage on one rewritten line of stderr (only on a terminal).
struct Progress {
    enabled: bool,
    step: AtomicUsize,
}

impl Progress {
    fn new(enabled: bool) -> Self {
        Progress {
            enabled,
            step: AtomicUsize::new(0),
        }
    }

    fn stage(&self, name: &str) {
        if !self.enabled {
            return;
        }
        let n = self.step.fetch_add(1, Ordering::Relaxed) + 1;
        let mut err = std::io::stderr().lock();
        // \x1b[K erases the rest of the previous, possibly longer, line.
        let _ = write!(err, "\r[{n}] {name} ...\x1b[K");
        let _ = err.flush();
    }
}

impl Progress {
    /// Prints a line to stderr, first erasing the stage line when there is one.
    fn note(&self, line: &str) {
        let mut err = std::io::stderr().lock();
        if self.enabled && self.step.load(Ordering::Relaxed) > 0 {
            let _ = write!(err, "\r\x1b[K");
        }
        let _ = writeln!(err, "{line}");
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if self.enabled && self.step.load(Ordering::Relaxed) > 0 {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[K");
            let _ = err.flush();
        }
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

fn reconstruct(args: &ReconstructArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.input.as_path();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));

    // Cheap checks first, so mistakes surface before any reading or computing.
    let params = args.params();
    params.validate().map_err(fail)?;
    let trim_params = args.trim_params();
    if let Some(p) = &trim_params {
        p.validate().map_err(fail)?;
    }
    start_threads(args.threads)?;
    check_output_arg(output, input).map_err(fail)?;

    let progress = Progress::new(std::io::stderr().is_terminal() && !args.verbose);
    progress.stage("reading");
    let t = Instant::now();
    let mut cloud = read_cloud_arg(input).map_err(fail)?;
    let reading = t.elapsed();

    let mut estimated = None;
    if args.estimate_normals || !cloud.has_normals() {
        if !args.estimate_normals {
            progress.note(&format!(
                "spsr: note: {} has no normals; estimating and orienting them (see --orient)",
                input.display()
            ));
        }
        progress.stage("estimating normals");
        estimated = Some(normals::estimate_normals(
            &mut cloud,
            &args.estimation,
            input,
        )?);
    } else if args.estimation.any_given() {
        return Err(usage(format!(
            "{} has normals, which --orient, --viewpoint and --neighbours do not change: add \
             --estimate-normals to replace them",
            input.display()
        )));
    }

    // The cloud is handed over so that it is released once the points are normalised.
    let mut result =
        spsr::reconstruct_owned(cloud, &params, &|s| progress.stage(s)).map_err(fail)?;

    let mut trimmed = None;
    if let Some(p) = &trim_params {
        progress.stage("trimming");
        let t = Instant::now();
        let (mesh, stats) = spsr::trim::trim(&result.mesh, p).map_err(fail)?;
        result.mesh = mesh;
        trimmed = Some((stats, t.elapsed()));
    }
    if !args.density {
        // Computed for trimming only.
        result.mesh.density = None;
    }

    progress.stage("writing");
    let t = Instant::now();
    let opts = spsr::io::WriteOptions { ascii: args.ascii };
    write_mesh_arg(output, &result.mesh, &opts).map_err(fail)?;
    let writing = t.elapsed();
    drop(progress);

    for w in &result.stats.warnings {
        eprintln!("spsr: warning: {}: {}", input.display(), words::warning(w));
    }
    let mesh = &result.mesh;
    if args.verbose {
        print_details(args, &result, reading, writing, start.elapsed());
        if let Some(report) = &estimated {
            report.print();
        }
        if let Some((stats, time)) = &trimmed {
            print_trim(stats, *time);
        }
    }
    report_written(output, mesh, start);
    Ok(())
}

fn print_details(
    args: &ReconstructArgs,
    result: &spsr::Reconstruction,
    reading: Duration,
    writing: Duration,
    total: Duration,
) {
    let stats = &result.stats;
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "input       {}", args.input.display());
    let _ = writeln!(
        err,
        "points      {} read, {} dropped",
        stats.points, stats.dropped
    );
    let _ = writeln!(err, "samples     {}", stats.samples);
    let nodes: usize = stats.nodes_per_depth.iter().sum();
    let _ = writeln!(err, "octree      {nodes} nodes; per depth:");
    for (depth, n) in stats.nodes_per_depth.iter().enumerate() {
        let _ = writeln!(err, "  {depth:>2}  {n:>12}");
    }
    let _ = writeln!(
        err,
        "memory      {:.0} MiB estimated before the octree was built",
        stats.memory_estimate as f64 / (1024.0 * 1024.0)
    );
    let _ = writeln!(err, "iso-value   {}", stats.iso_value);
    let _ = writeln!(
        err,
        "mesh        {} vertices, {} faces",
        result.mesh.vertices.len(),
        result.mesh.triangles.len()
    );
    let _ = writeln!(err, "output      {}", args.output.display());
    let _ = writeln!(err, "timings:");
    let stages = std::iter::once(("reading", reading))
        .chain(stats.stages.iter().map(|(n, d)| (n.as_str(), *d)))
        .chain(std::iter::once(("writing", writing)));
    let memory = std::iter::once(None)
        .chain(stats.peak_memory.iter().copied())
        .chain(std::iter::once(None));
    for ((name, d), mem) in stages.zip(memory) {
        match mem {
            Some(bytes) => {
                let mib = bytes as f64 / (1024.0 * 1024.0);
                let _ = writeln!(
                    err,
                    "  {name:<32} {:>9.3} s   peak {mib:>8.0} MiB",
                    d.as_secs_f64()
                );
            }
            None => {
                let _ = writeln!(err, "  {name:<32} {:>9.3} s", d.as_secs_f64());
            }
        }
    }
    let _ = writeln!(err, "  {:<32} {:>9.3} s", "total", total.as_secs_f64());
}

const TRIM_LONG_ABOUT: &str = "\
Remove the surface a reconstruction invented where there were no samples. Screened Poisson \
reconstruction closes every opening of the scanned surface (the floor under a statue, the open \
side of a room); the per-vertex density written by `spsr reconstruct --density` (the estimated \
sampling depth: one unit more means 4 times more samples per area) is low there.

The mesh is cut along the line where the density equals V (new vertices on the crossing edges, \
with every per-vertex value interpolated), and the part below V is removed. Then kept pieces \
smaller than --min-island-area of the total area are removed, and removed regions inside kept \
surface smaller than --hole-area are restored, as PoissonRecon's SurfaceTrimmer does.

--trim auto sets V = median - max(1, 4 x MAD) of the area-weighted vertex densities (MAD: the \
median absolute deviation): it removes surface with fewer than a quarter of the typical samples \
per area (further below for unevenly sampled scans), which keeps everything that was sampled, \
including the rims of real openings. A gap in a scan of a surface that continues looks like an \
opening; auto removes the fill of a large gap too. To keep it, give a lower V (-v prints the \
median density; e.g. median - 3.5 keeps the fill of a gap a fifth of the object's size).

Input: a PLY mesh with a vertex property `density`, as written by `spsr reconstruct --density`. \
Output, by extension: .ply (binary, ASCII with --ascii; also any other name), .obj, .stl, .glb. The \
output must not be the input; it appears only once complete.";

/// Arguments of `spsr trim`.
#[derive(Debug, Args)]
pub struct TrimArgs {
    /// Mesh with a per-vertex `density` property (from `spsr reconstruct --density`), PLY;
    /// `-` reads standard input.
    #[arg(value_name = "MESH")]
    pub mesh: PathBuf,

    /// Output mesh, by extension: .ply (also any other name), .obj, .stl or .glb; `-` writes
    /// PLY to standard output.
    #[arg(short, long, value_name = "OUTPUT")]
    pub output: PathBuf,

    /// Density below which the surface is removed, or `auto` to derive it from the mesh's
    /// density distribution. Required: no default, as in PoissonRecon 18's SurfaceTrimmer.
    #[arg(long, value_name = "V|auto", value_parser = parse_trim, allow_negative_numbers = true)]
    pub trim: spsr::trim::Threshold,

    /// Kept pieces smaller than this fraction of the total area are removed. Default as
    /// PoissonRecon 18's SurfaceTrimmer (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.001,
        allow_negative_numbers = true
    )]
    pub min_island_area: f64,

    /// Removed regions inside kept surface smaller than this fraction of the total area are
    /// restored (small holes closed again). Default as PoissonRecon 18's SurfaceTrimmer
    /// (--aRatio).
    #[arg(
        long,
        value_name = "F",
        default_value_t = 0.001,
        allow_negative_numbers = true
    )]
    pub hole_area: f64,

    /// Write ASCII PLY or STL instead of binary (no effect on .obj and .glb) [default: off]
    #[arg(long)]
    pub ascii: bool,

    /// Print the threshold (and how `auto` derived it), the areas and the counts of removed
    /// islands and restored holes to stderr [default: off]
    #[arg(short, long)]
    pub verbose: bool,
}

/// Runs `spsr trim`: reads the mesh, trims it, writes the result.
pub fn run_trim(args: &TrimArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.mesh.as_path();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));
    let params = spsr::trim::TrimParams {
        threshold: args.trim,
        min_island_area: args.min_island_area,
        hole_area: args.hole_area,
    };
    params.validate().map_err(fail)?;
    check_output_arg(output, input).map_err(fail)?;
    let mesh = read_mesh_arg(input).map_err(fail)?;
    let t = Instant::now();
    let (trimmed, stats) = spsr::trim::trim(&mesh, &params).map_err(fail)?;
    let time = t.elapsed();
    drop(mesh);
    let opts = spsr::io::WriteOptions { ascii: args.ascii };
    write_mesh_arg(output, &trimmed, &opts).map_err(fail)?;
    if args.verbose {
        print_trim(&stats, time);
    }
    report_written(output, &trimmed, start);
    Ok(())
}

fn print_trim(stats: &spsr::trim::TrimStats, time: Duration) {
    let mut err = std::io::stderr().lock();
    match &stats.auto {
        Some(a) => {
            let _ = writeln!(
                err,
                "trim        V = {} (auto: area-weighted median density {:.4}, MAD {:.4}; \
                 {:.3} % of the area below V)",
                stats.threshold,
                a.median,
                a.mad,
                100.0 * a.area_below
            );
        }
        None => {
            let _ = writeln!(err, "trim        V = {}", stats.threshold);
        }
    }
    let _ = writeln!(
        err,
        "            kept {:.3} % of the area ({:.6e} of {:.6e}); {} triangles of {}, \
         {} cut vertices, {} islands removed, {} holes restored; {:.3} s",
        100.0 * stats.kept_area / stats.total_area,
        stats.kept_area,
        stats.total_area,
        stats.triangles_out,
        stats.triangles_in,
        stats.cut_vertices,
        stats.islands_removed,
        stats.holes_filled,
        time.as_secs_f64()
    );
}

const EVAL_LONG_ABOUT: &str = "\
Score a mesh against a ground truth: a mesh (--reference) or an analytic sphere \
(--reference-sphere cx,cy,cz,r).

Both surfaces get the same number of area-uniform samples (fixed seed, so the numbers are \
reproducible and independent of the thread count); every sample is measured against the other \
surface with exact point-to-triangle distances. Reported: the symmetric Chamfer distance (mean \
of the two directions' mean distances) and the Hausdorff distance (largest sampled distance), \
both also relative to the reference's bounding-box diagonal, each direction's mean and maximum, \
the F-score at 0.5 % and 1 % of that diagonal, the normal consistency (mean |n · n'| at the \
closest points, both directions), and the mesh's topology (vertices, faces, closed, edge- and \
vertex-manifold, components, Euler characteristic, consistent orientation).

Input meshes: PLY (any encoding) with vertex x, y, z and face vertex_indices.";

/// Arguments of `spsr eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Mesh to score: PLY (any encoding).
    #[arg(value_name = "MESH")]
    pub mesh: PathBuf,

    /// Ground-truth mesh (PLY). Exactly one of --reference and --reference-sphere is needed.
    #[arg(long, value_name = "GT_MESH")]
    pub reference: Option<PathBuf>,

    /// Analytic sphere as ground truth: centre and radius, comma-separated.
    #[arg(long, value_name = "CX,CY,CZ,R", allow_hyphen_values = true)]
    pub reference_sphere: Option<String>,

    /// Samples drawn on each surface, at least 1.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 1_000_000,
        allow_negative_numbers = true
    )]
    pub samples: i64,

    /// Print one JSON object (on the last line of stdout) instead of the table [default: off]
    #[arg(long)]
    pub json: bool,

    /// Number of worker threads, at least 1; the numbers do not depend on it. Default: rayon's,
    /// which honours RAYON_NUM_THREADS [default: all cores]
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    pub threads: Option<usize>,
}

fn usage(message: String) -> Failure {
    Failure {
        code: exit::USAGE,
        error: anyhow::anyhow!(message),
    }
}

/// Parses `cx,cy,cz,r` (spaces allowed around the commas): finite numbers, positive radius.
fn parse_sphere(spec: &str) -> Result<([f64; 3], f64), Failure> {
    let bad = |why: &str| {
        usage(format!(
            "invalid --reference-sphere '{spec}': {why} (expected cx,cy,cz,r, e.g. 0,0,0,1)"
        ))
    };
    let parts: Vec<&str> = spec.split(',').map(str::trim).collect();
    if parts.len() != 4 {
        return Err(bad(&format!("{} values instead of 4", parts.len())));
    }
    let mut v = [0.0; 4];
    for (x, p) in v.iter_mut().zip(&parts) {
        *x = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| bad(&format!("'{p}' is not a finite number")))?;
    }
    if v[3] <= 0.0 {
        return Err(bad("the radius must be positive"));
    }
    Ok(([v[0], v[1], v[2]], v[3]))
}

/// Reads a mesh for `spsr eval`, refusing one without area; errors name the file.
fn read_eval_mesh(path: &Path) -> Result<spsr::Mesh, Failure> {
    let mesh = spsr::io::read_mesh(path).map_err(|e| Failure::from_spsr(e, path))?;
    let area = mesh.area();
    if mesh.triangles.is_empty() || !(area > 0.0 && area.is_finite()) {
        let what = if mesh.triangles.is_empty() {
            "no faces"
        } else {
            "no surface area (non-finite or degenerate faces)"
        };
        return Err(Failure {
            code: exit::DATA,
            error: anyhow::anyhow!("{}: the mesh has {what}", path.display()),
        });
    }
    Ok(mesh)
}

/// Runs `spsr eval`: reads the mesh and the reference, scores, prints a table or JSON.
pub fn run_eval(args: &EvalArgs) -> Result<(), Failure> {
    // Usage checks first, before any reading.
    let samples = usize::try_from(args.samples)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| {
            usage(format!(
                "invalid parameter --samples: must be at least 1, got {}",
                args.samples
            ))
        })?;
    let sphere = match (&args.reference, &args.reference_sphere) {
        (None, None) => {
            return Err(usage(
                "no reference: give --reference GT_MESH or --reference-sphere cx,cy,cz,r".into(),
            ))
        }
        (Some(_), Some(_)) => {
            return Err(usage(
                "--reference and --reference-sphere cannot be used together; give one".into(),
            ))
        }
        (None, Some(spec)) => Some(parse_sphere(spec)?),
        (Some(_), None) => None,
    };
    start_threads(args.threads)?;
    let start = Instant::now();
    let mesh = read_eval_mesh(&args.mesh)?;
    let (reference, reference_name) = match (sphere, &args.reference) {
        (Some((center, radius)), _) => (
            spsr::metrics::Reference::Sphere { center, radius },
            format!(
                "sphere, centre ({}, {}, {}), radius {radius}",
                center[0], center[1], center[2]
            ),
        ),
        (None, Some(path)) => (
            spsr::metrics::Reference::Mesh(read_eval_mesh(path)?),
            path.display().to_string(),
        ),
        (None, None) => unreachable!("checked above"),
    };
    let opts = spsr::metrics::EvalOptions {
        samples,
        ..Default::default()
    };
    let e = spsr::metrics::evaluate(&mesh, &reference, &opts)
        .map_err(|e| Failure::from_spsr(e, &args.mesh))?;
    if args.json {
        println!("{}", e.to_json());
    } else {
        print_evaluation(&args.mesh, &reference_name, &e, start.elapsed());
    }
    Ok(())
}

fn print_evaluation(
    mesh: &Path,
    reference: &str,
    e: &spsr::metrics::Evaluation,
    elapsed: Duration,
) {
    let t = &e.topology;
    let yes = |b: bool| if b { "yes" } else { "no" };
    let pct = |x: f64| format!("{:.3} %", 100.0 * x);
    let rows: Vec<(String, String)> = vec![
        ("mesh".into(), mesh.display().to_string()),
        ("reference".into(), reference.to_string()),
        ("samples per surface".into(), e.samples.to_string()),
        (
            "reference bbox diagonal".into(),
            format!("{:.6e}", e.diagonal),
        ),
        (
            "chamfer".into(),
            format!("{:.6e}  ({} of diagonal)", e.chamfer, pct(e.chamfer_rel)),
        ),
        (
            "hausdorff".into(),
            format!(
                "{:.6e}  ({} of diagonal)",
                e.hausdorff,
                pct(e.hausdorff_rel)
            ),
        ),
        (
            "mesh -> reference".into(),
            format!(
                "mean {:.6e}, max {:.6e}",
                e.mesh_to_reference.mean, e.mesh_to_reference.max
            ),
        ),
        (
            "reference -> mesh".into(),
            format!(
                "mean {:.6e}, max {:.6e}",
                e.reference_to_mesh.mean, e.reference_to_mesh.max
            ),
        ),
        (
            "f-score @ 0.5 %".into(),
            format!(
                "{:.4}  (precision {:.4}, recall {:.4}, tau {:.4e})",
                e.fscore_0_5.fscore,
                e.fscore_0_5.precision,
                e.fscore_0_5.recall,
                e.fscore_0_5.threshold
            ),
        ),
        (
            "f-score @ 1 %".into(),
            format!(
                "{:.4}  (precision {:.4}, recall {:.4}, tau {:.4e})",
                e.fscore_1.fscore, e.fscore_1.precision, e.fscore_1.recall, e.fscore_1.threshold
            ),
        ),
        (
            "normal consistency".into(),
            format!(
                "{:.6}  (mesh -> reference {:.6}, reference -> mesh {:.6})",
                e.normal_consistency,
                e.mesh_to_reference.normal_consistency,
                e.reference_to_mesh.normal_consistency
            ),
        ),
        ("vertices".into(), t.vertices.to_string()),
        ("faces".into(), t.faces.to_string()),
        (
            "closed".into(),
            format!("{}  ({} boundary edges)", yes(t.closed), t.boundary_edges),
        ),
        (
            "edge-manifold".into(),
            format!(
                "{}  ({} non-manifold edges)",
                yes(t.edge_manifold),
                t.non_manifold_edges
            ),
        ),
        (
            "vertex-manifold".into(),
            format!(
                "{}  ({} non-manifold vertices)",
                yes(t.vertex_manifold),
                t.non_manifold_vertices
            ),
        ),
        ("oriented".into(), yes(t.oriented).into()),
        ("components".into(), t.components.to_string()),
        ("euler characteristic".into(), t.euler.to_string()),
        ("time".into(), format!("{:.2} s", elapsed.as_secs_f64())),
    ];
    let mut out = std::io::stdout().lock();
    for (k, v) in rows {
        let _ = writeln!(out, "{k:<24} {v}");
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
