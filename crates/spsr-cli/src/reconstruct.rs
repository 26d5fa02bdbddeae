//! `spsr reconstruct`: read a cloud, estimate normals where missing, reconstruct (and trim),
//! write the mesh.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::{Args, ValueEnum};

use crate::args::{parse_size, CommonArgs};
use crate::files::{check_output_arg, input_name, read_cloud_arg, report, write_mesh_arg};
use crate::normals::{self, NormalOptions};
use crate::progress::Progress;
use crate::trim::{parse_trim, print_trim};
use crate::{slabs, start_threads, usage, words, Failure};

pub(crate) const RECONSTRUCT_LONG_ABOUT: &str = "\
Reconstruct a watertight triangle mesh from an oriented point cloud (Screened Poisson Surface \
Reconstruction, Kazhdan & Hoppe 2013).

Input: points with normals (nx ny nz) in one of these formats, recognised by their first bytes or \
else by extension: PLY (any encoding), LAS or LAZ (.las, .laz; normals as extra bytes such as \
NormalX/NormalY/NormalZ), E57 (.e57; every scan, moved by its pose; normals from the surface-normals \
extension), PCD (.pcd; ascii, binary or binary_compressed, fields normal_x normal_y normal_z), or \
text with one point per line: x y z nx ny nz, optionally followed by r g b. Normals must point \
outward. Points with non-finite coordinates or zero-length normals are dropped with a warning. A cloud without normals gets normals estimated and oriented first, as by `spsr normals` (with a note saying so); --estimate-normals does that for any cloud, replacing its normals.

Output, chosen by the output name's extension: .ply (binary little-endian, ASCII with --ascii), \
.obj (Wavefront OBJ), .stl (binary STL, ASCII with --ascii), .off (OFF), .glb (glTF 2.0 binary); \
any other extension is refused before the work. The output file appears only once it is complete; on any error no output file \
is left behind. The output must not be the input file.";

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

impl From<spsr::Boundary> for BoundaryArg {
    fn from(b: spsr::Boundary) -> Self {
        match b {
            spsr::Boundary::Neumann => BoundaryArg::Neumann,
            spsr::Boundary::Dirichlet => BoundaryArg::Dirichlet,
            spsr::Boundary::Free => BoundaryArg::Free,
        }
    }
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

/// `--slabs`: a number, or `auto`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Slabs {
    /// In one piece when it fits in memory, else in the fewest slabs that fit.
    Auto,
    /// This many slabs.
    Count(usize),
}

fn parse_slabs(s: &str) -> Result<Slabs, String> {
    if s == "auto" {
        return Ok(Slabs::Auto);
    }
    match s.parse::<usize>() {
        Ok(k) if (1..=MAX_SLABS).contains(&k) => Ok(Slabs::Count(k)),
        _ => Err(format!(
            "expected `auto` or a number of slabs from 1 to {MAX_SLABS}"
        )),
    }
}

/// Most slabs `--slabs` takes (the columns of the base depth are the finest cut).
const MAX_SLABS: usize = 256;

/// Arguments of `spsr reconstruct`. Defaults mirror [`spsr::Params::default`].
#[derive(Debug, Args)]
pub struct ReconstructArgs {
    /// Oriented point cloud: PLY, LAS/LAZ, E57, PCD, or text with `x y z nx ny nz` per line;
    /// `-` reads standard input. Several files (tiles) are read as one cloud.
    #[arg(value_name = "INPUT", num_args = 1.., required_unless_present = "reference_in")]
    pub input: Vec<PathBuf>,

    /// PoissonRecon's spelling of INPUT.
    #[arg(
        long = "in",
        value_name = "INPUT",
        hide = true,
        conflicts_with = "input"
    )]
    pub reference_in: Option<PathBuf>,

    /// Output mesh, by extension: .ply, .obj, .stl, .off or .glb; `-` writes
    /// PLY to standard output.
    #[arg(short, long, value_name = "OUTPUT", alias = "out")]
    pub output: PathBuf,

    /// Maximum octree depth; the finest cells are 1/2^depth of the bounding cube. Default as
    /// PoissonRecon 6 and 18. `auto` chooses it from the data: the first depth whose finest
    /// cells are no wider than the points' typical spacing (median nearest-neighbour distance),
    /// or on a clean cloud whose cells' face diagonals are no longer, fewer on a smooth
    /// surface, lowered to fit --max-memory, and says which in a note
    #[arg(
        long,
        value_name = "D",
        default_value_t = DepthArg::Fixed(spsr::Params::default().depth),
        value_parser = parse_depth,
        allow_negative_numbers = true
    )]
    pub depth: DepthArg,

    /// The finest cells' width, in the input's units: sets the depth to the smallest whose
    /// cells are no wider, and widens the bounding cube so that they are exactly W wide, as
    /// PoissonRecon's --width. Not with --depth [default: none]
    #[arg(
        long,
        value_name = "W",
        conflicts_with = "depth",
        allow_negative_numbers = true
    )]
    pub width: Option<f64>,

    /// Depth down to which the octree is complete; the coarse solve happens there. Default as
    /// PoissonRecon 6 and 18 [default: 5, or --depth when that is smaller]
    #[arg(
        long,
        value_name = "D",
        alias = "fullDepth",
        allow_negative_numbers = true
    )]
    pub full_depth: Option<u32>,

    /// Target number of samples per octree node (sets each sample's splat depth). Default as
    /// PoissonRecon 18 (version 6 used 1.0). Giving it turns the noise adaptation off unless
    /// --noise adaptive is given too [default: 1.5]
    #[arg(
        long,
        value_name = "N",
        allow_negative_numbers = true,
        alias = "samplesPerNode"
    )]
    pub samples_per_node: Option<f64>,

    /// Screening weight alpha; 0 gives the unscreened 2006 method. Default as PoissonRecon 18
    /// (4 for degree 2, the 2013 paper's value). Giving it turns the noise adaptation off
    /// unless --noise adaptive is given too [default: 2 × degree]
    #[arg(
        long,
        value_name = "ALPHA",
        allow_negative_numbers = true,
        alias = "pointWeight"
    )]
    pub point_weight: Option<f64>,

    /// Adapt the reconstruction to the noise measured around each point (adaptive: noisy
    /// regions are splatted coarser and their points screened less, clean ones keep full
    /// detail), or not (off: exactly
    /// PoissonRecon's behaviour) [default: adaptive, or off when --samples-per-node or
    /// --point-weight is given]
    #[arg(long, value_enum, value_name = "MODE")]
    pub noise: Option<NoiseArg>,

    /// Keep the far outliers (a few points far outside the box that holds the rest, which
    /// waste depth) instead of leaving them out with a warning [default: off]
    #[arg(long)]
    pub keep_outliers: bool,

    /// Keep the normals as given even when many point against their neighbours' (by
    /// default such normals are made consistent, each connected piece following the
    /// majority of its normals, with a warning) [default: off]
    #[arg(long)]
    pub keep_normals: bool,

    /// B-spline degree of the finite elements, 1 or 2. Default as PoissonRecon 18 (the 2013 paper
    /// and PoissonRecon 6 use 2).
    #[arg(long, value_name = "K", default_value_t = spsr::Params::default().degree, value_parser = parse_degree)]
    pub degree: spsr::Degree,

    /// Boundary condition on the bounding cube. Default as PoissonRecon 6 and 18.
    #[arg(long, value_enum, default_value_t = spsr::Params::default().boundary.into())]
    pub boundary: BoundaryArg,

    /// PoissonRecon's --bType: 1 free, 2 Dirichlet, 3 Neumann.
    #[arg(
        long = "bType",
        value_name = "N",
        hide = true,
        value_parser = crate::poissonrecon::parse_boundary,
        conflicts_with = "boundary"
    )]
    pub reference_boundary: Option<BoundaryArg>,

    /// The bounding cube's side is the points' bounding box's largest side times this factor.
    /// Default as PoissonRecon 6 and 18.
    #[arg(
        long,
        value_name = "S",
        default_value_t = spsr::Params::default().scale,
        allow_negative_numbers = true
    )]
    pub scale: f64,

    /// Gauss-Seidel sweeps per depth in each solver cycle: 8 with one cycle as PoissonRecon 6
    /// and 18 and the 2013 paper, 4 with more. With more than one cycle the deepest depth's
    /// first relaxation makes half as many (rounded up): the last cycle relaxes it again
    /// [default: 8 for one cycle, 4 for more]
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    pub iters: Option<u32>,

    /// Shape of the solver's cycles over the depths: cascadic (coarse to fine, as
    /// PoissonRecon), vcycle (also relaxing each depth going down and passing its residual to
    /// the coarser depths) or wcycle (as vcycle, visiting the coarser depths twice). spsr's own
    #[arg(long, value_enum, value_name = "SHAPE", default_value = spsr::Params::default().solver.name())]
    pub solver: SolverArg,

    /// Solver cycles; the first is the cascade, each further one passes the finer depths'
    /// solution back to the coarser ones and relaxes every depth again (--iters sweeps per
    /// depth, twice per depth for vcycle): 2 at degree 1, at least as accurate as PoissonRecon
    /// at its defaults; 1 at degree 2, PoissonRecon's cascade, already as accurate.
    /// --cycles 1 --iters 8 is PoissonRecon's solve. spsr's own [default: 2 at degree 1, 1 at
    /// degree 2]
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    pub cycles: Option<u32>,

    /// Measure the solver's relative residuals and print them to stderr: each depth's before
    /// and after each relaxation, the whole system's after each cycle. Costs about one sweep
    /// per relaxation (so -v's timings are a plain run's without it); the mesh is the same.
    /// PoissonRecon's --showResidual [default: off]
    #[arg(long, alias = "showResidual")]
    pub residuals: bool,

    /// Solve the depths above the base (right-hand sides and relaxations) on an NVIDIA GPU,
    /// with the same mesh bit for bit: `--gpu` (or `--gpu on`) fails with exit code 3 where no
    /// GPU can be used, `--gpu auto` falls back to the CPU with a note. Needs a build with the
    /// cargo feature `gpu` and the CUDA driver and NVRTC at run time. spsr's own
    #[arg(
        long,
        value_enum,
        value_name = "WHEN",
        num_args = 0..=1,
        default_value = "off",
        default_missing_value = "on"
    )]
    pub gpu: GpuArg,

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

    /// PoissonRecon's --colors: spsr carries colours (and every other attribute) anyway.
    #[arg(long = "colors", hide = true, conflicts_with = "no_attributes")]
    pub reference_colors: bool,

    /// Pull factor of the attribute interpolation: larger values keep attributes sharper
    /// and stop them bleeding between nearby surfaces. Default as PoissonRecon 18 (--dataX)
    #[arg(
        long,
        value_name = "X",
        default_value_t = spsr::Params::default().data_pull,
        allow_negative_numbers = true,
        alias = "data"
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
        default_value_t = spsr::trim::TrimParams::default().min_island_area,
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
        default_value_t = spsr::trim::TrimParams::default().hole_area,
        requires = "trim",
        allow_negative_numbers = true
    )]
    pub hole_area: f64,

    /// Place mesh vertices by linear interpolation along cell edges instead of the quadratic fit
    /// through the end values and gradients. Off by default, as PoissonRecon 18 (--linearFit)
    /// [default: off]
    #[arg(long, alias = "linearFit")]
    pub linear_fit: bool,

    /// Refuse the run, before the octree is built, when its estimated peak memory exceeds this
    /// size (bytes, or with a suffix K, M, G, T, powers of 1024; e.g. 8G) [default: the memory
    /// the machine has available]
    #[arg(long, value_name = "SIZE", value_parser = parse_size, allow_negative_numbers = true)]
    pub max_memory: Option<u64>,

    /// PoissonRecon's --maxMemory, in GB; 0 (no limit) keeps the default.
    #[arg(
        long = "maxMemory",
        value_name = "GB",
        hide = true,
        value_parser = crate::poissonrecon::parse_max_memory_gb,
        conflicts_with = "max_memory",
        allow_negative_numbers = true
    )]
    pub reference_max_memory: Option<u64>,

    /// Cut the run into K slabs along x, solved one after another in bounded memory with the
    /// points spilled to --work-dir; the mesh is one seamless surface. `auto` runs in one piece
    /// when the memory estimate fits --max-memory, and otherwise in the fewest slabs that fit
    /// [default: auto]
    #[arg(long, value_name = "K", default_value = "auto", value_parser = parse_slabs)]
    pub slabs: Slabs,

    /// Folder for a slab run's spill files: a subfolder is made in it and removed afterwards,
    /// also on Ctrl-C [default: the output's folder]
    #[arg(long, value_name = "DIR")]
    pub work_dir: Option<PathBuf>,

    /// Split each sample's normal between the two depths around its estimated depth (2006 paper,
    /// PoissonRecon 6) instead of splatting it whole at the depth above (PoissonRecon 18):
    /// smoother, better on smooth surfaces, less detail on scans [default: off]
    #[arg(long)]
    pub two_level_splat: bool,

    #[command(flatten)]
    pub common: CommonArgs,

    /// Estimate and orient normals even when the input has them (they are replaced); inputs
    /// without normals get estimated normals anyway [default: off]
    #[arg(long)]
    pub estimate_normals: bool,

    /// How estimated normals are oriented (see `spsr normals --help`).
    #[command(flatten)]
    pub estimation: NormalOptions,

    /// Also write a picture of the mesh to this .png file (as `spsr render`: iso view,
    /// 800x800) [default: none]
    #[arg(long, value_name = "PNG")]
    pub preview: Option<PathBuf>,

    /// Also write the implicit function minus the iso-value (negative inside, positive
    /// outside), sampled at the centres of an R x R x R grid of cells over the bounding cube, to
    /// this NumPy .npz file: arrays `values` (float32, shape (R, R, R), indexed x, y, z),
    /// `origin` (the centre of cell (0, 0, 0)) and `spacing`, in the input's units. Needs
    /// --grid-res [default: none]
    #[arg(long, value_name = "FILE.npz", requires = "grid_res")]
    pub grid: Option<PathBuf>,

    /// Samples along each axis of --grid's grid, at least 2; refused when R^3 float32 values
    /// exceed --max-memory. Needs --grid [default: none]
    #[arg(
        long,
        value_name = "R",
        requires = "grid",
        allow_negative_numbers = true
    )]
    pub grid_res: Option<u32>,

    /// The ids of the arguments given on the command line (filled by
    /// [`crate::try_parse_from`]), which `-v` reports as set by a flag.
    #[arg(skip)]
    pub given: Vec<String>,
}

impl ReconstructArgs {
    /// The (first) input file, given as INPUT or as PoissonRecon's --in.
    pub fn input(&self) -> &Path {
        self.input
            .first()
            .map(PathBuf::as_path)
            .or(self.reference_in.as_deref())
            .unwrap_or(Path::new("-"))
    }

    /// How the warnings name the input: its path, or with tiles (several files read as one
    /// cloud) the first one's and how many more, since a warning is about the whole cloud.
    pub fn inputs_label(&self) -> String {
        let first = input_name(self.input()).display();
        match self.input.len() {
            0 | 1 => first.to_string(),
            2 => format!("{first} and 1 more file"),
            n => format!("{first} and {} more files", n - 1),
        }
    }

    /// Every input file, in order.
    pub fn inputs(&self) -> Vec<PathBuf> {
        if self.input.is_empty() {
            vec![self.input().to_path_buf()]
        } else {
            self.input.clone()
        }
    }

    /// The boundary condition, from --boundary or PoissonRecon's --bType.
    fn boundary(&self) -> BoundaryArg {
        self.reference_boundary.unwrap_or(self.boundary)
    }

    /// Whether the argument with this id was given on the command line (by any of its
    /// spellings).
    fn given(&self, id: &str) -> bool {
        self.given.iter().any(|g| g == id)
    }

    /// The library parameters these arguments describe (not yet validated).
    pub fn params(&self) -> spsr::Params {
        let default = spsr::Params::default();
        let (depth, resolution) = match (self.depth, self.width) {
            (_, Some(w)) => (default.depth, spsr::Resolution::Width(w)),
            (DepthArg::Auto, None) => (default.depth, spsr::Resolution::Auto),
            (DepthArg::Fixed(d), None) => (d, spsr::Resolution::Depth),
        };
        // An explicit --full-depth deeper than --depth is an error; the default follows --depth
        // (and a chosen depth, when the library resolves it).
        let full_depth = self
            .full_depth
            .unwrap_or_else(|| default.full_depth.min(depth));
        spsr::Params {
            depth,
            resolution,
            grid_res: self.grid_res,
            full_depth,
            samples_per_node: self
                .samples_per_node
                .unwrap_or(spsr::Params::default().samples_per_node),
            point_weight: self.point_weight,
            degree: self.degree,
            boundary: self.boundary().into(),
            scale: self.scale,
            iters: self.iters,
            weights: match (&self.confidence_property, self.confidence) {
                (Some(name), _) => spsr::PointWeights::Property(name.clone()),
                (None, true) => spsr::PointWeights::NormalLength,
                (None, false) => spsr::PointWeights::Uniform,
            },
            density: self.density,
            linear_fit: self.linear_fit,
            max_memory: self
                .max_memory
                .or(self.reference_max_memory.filter(|&bytes| bytes > 0)),
            two_level_splat: self.two_level_splat,
            attributes: !self.no_attributes,
            data_pull: self.data_pull,
            normals: self.normals,
            noise: self.noise(),
            keep_outliers: self.keep_outliers,
            keep_normals: self.keep_normals,
            solver: match self.solver {
                SolverArg::Cascadic => spsr::Solver::Cascadic,
                SolverArg::Vcycle => spsr::Solver::VCycle,
                SolverArg::Wcycle => spsr::Solver::WCycle,
            },
            cycles: self.cycles,
            report_residuals: self.residuals,
            gpu: match self.gpu {
                GpuArg::Off => spsr::Gpu::Off,
                GpuArg::On => spsr::Gpu::On,
                GpuArg::Auto => spsr::Gpu::Auto,
            },
        }
    }

    /// The noise mode (see [`spsr::Noise::unless_tuned`]).
    fn noise(&self) -> spsr::Noise {
        let given = self.noise.map(|n| match n {
            NoiseArg::Adaptive => spsr::Noise::Adaptive,
            NoiseArg::Off => spsr::Noise::Off,
        });
        let tuned = self.samples_per_node.is_some() || self.point_weight.is_some();
        spsr::Noise::unless_tuned(given, tuned)
    }
}

/// `--solver`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SolverArg {
    /// Coarse to fine (PoissonRecon's cascade).
    Cascadic,
    /// V-cycles.
    Vcycle,
    /// W-cycles.
    Wcycle,
}

/// `--gpu`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum GpuArg {
    /// The CPU only.
    Off,
    /// An NVIDIA GPU, or an error.
    On,
    /// An NVIDIA GPU where one can be used, else the CPU.
    Auto,
}

/// `--noise`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum NoiseArg {
    /// Adapt the splat depth and the screening to the local noise.
    Adaptive,
    /// PoissonRecon's behaviour.
    Off,
}

/// `--depth`: a number, or `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthArg {
    /// This depth.
    Fixed(u32),
    /// Chosen from the points' spacing.
    Auto,
}

impl std::fmt::Display for DepthArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DepthArg::Fixed(d) => write!(f, "{d}"),
            DepthArg::Auto => f.write_str("auto"),
        }
    }
}

/// Parses `--depth`: a non-negative integer (the library checks the range) or `auto`.
fn parse_depth(s: &str) -> Result<DepthArg, String> {
    let t = s.trim();
    if t.eq_ignore_ascii_case("auto") {
        return Ok(DepthArg::Auto);
    }
    t.parse::<u32>().map(DepthArg::Fixed).map_err(|_| {
        format!(
            "'{s}' is neither a depth (an integer from 1 to {}) nor auto",
            spsr::MAX_DEPTH
        )
    })
}

/// Parses `--degree`: 1 or 2.
fn parse_degree(s: &str) -> Result<spsr::Degree, String> {
    s.trim()
        .parse::<u8>()
        .ok()
        .and_then(spsr::Degree::from_number)
        .ok_or_else(|| format!("'{s}' is not a supported degree; use 1 or 2"))
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

pub(crate) fn run_reconstruct(args: &ReconstructArgs) -> Result<(), Failure> {
    let start = Instant::now();
    let input = args.input();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));

    // Cheap checks first, so mistakes surface before any reading or computing.
    let params = args.params();
    params.validate().map_err(fail)?;
    let trim_params = args.trim_params();
    if let Some(p) = &trim_params {
        p.validate().map_err(fail)?;
    }
    start_threads(args.common.threads.threads)?;
    check_output_arg(output, input).map_err(fail)?;
    if let Some(p) = &args.preview {
        crate::render::check_picture_path(p, input)?;
    }
    if let Some(g) = &args.grid {
        if !g.extension().is_some_and(|e| e.eq_ignore_ascii_case("npz")) {
            return Err(usage(format!(
                "--grid {}: the grid is written as NumPy .npz; name a file ending in .npz",
                g.display()
            )));
        }
    }
    if args.common.verbose {
        print_parameters(args, &params);
    }

    if let Slabs::Count(k) = args.slabs {
        if slabs::streams(args) {
            return slabs::run_streamed(args, &params, k, trim_params.as_ref(), start);
        }
        let (result, trimmed, reading, progress) =
            slabs::run(args, &params, k, trim_params.as_ref())?;
        return finish(args, result, trimmed, None, reading, start, progress);
    }

    // Reading, the library's stages, writing; estimating normals is added when it happens.
    let plan = spsr::stage_plan(&params, trim_params.is_some());
    let progress = Progress::new(plan.len() + 2, std::io::stderr().is_terminal());
    progress.stage("reading");
    let t = Instant::now();
    let mut cloud = read_clouds(&args.inputs()).map_err(fail)?;
    let reading = t.elapsed();

    let mut estimated = None;
    if args.estimate_normals || !cloud.has_normals() {
        if !args.estimate_normals {
            progress.note(&format!(
                "spsr: note: {} has no normals; estimating and orienting them (see --orient)",
                input.display()
            ));
        }
        progress.add_stages(1);
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

    // A depth from --width or `auto` is resolved over the cloud now, so that the progress
    // counts the stages of that depth and a fallback to slabs runs at it.
    let params = if params.resolution == spsr::Resolution::Depth {
        params
    } else {
        let resolved = spsr::resolve(&cloud, &params).map_err(fail)?;
        if let Some(c) = &resolved.choice {
            progress.note(&format!("spsr: note: {}", words::depth_choice(c)));
        }
        let trimming = trim_params.is_some();
        progress.add_stages(
            spsr::stage_plan(&resolved.params, trimming)
                .len()
                .saturating_sub(plan.len()),
        );
        resolved.params
    };

    // The cloud is handed over so that it is released once the points are normalised.
    let attempt = match &trim_params {
        Some(p) => spsr::reconstruct_and_trim(cloud, &params, p, &|s| progress.stage(s))
            .map(|(result, stats)| (result, Some(stats))),
        None => spsr::reconstruct_owned(cloud, &params, &|s| progress.stage(s))
            .map(|result| (result, None)),
    };
    let (result, trimmed) = match attempt {
        Err(spsr::Error::ResourceLimit(short))
            if args.slabs == Slabs::Auto && slabs::can_help(&short, &params) =>
        {
            drop(progress);
            let k = slabs::enough(&short, &params);
            eprintln!(
                "spsr: note: the run needs about {} in one piece, over the limit of {}; \
                 running it in {k} slabs (--slabs)",
                spsr::gib(short.estimate),
                spsr::gib(short.limit)
            );
            if slabs::streams(args) {
                return slabs::run_streamed(args, &params, k, trim_params.as_ref(), start);
            }
            let (result, trimmed, more, progress) =
                slabs::run(args, &params, k, trim_params.as_ref())?;
            return finish(
                args,
                result,
                trimmed,
                estimated,
                reading + more,
                start,
                progress,
            );
        }
        r => r.map_err(fail)?,
    };
    finish(args, result, trimmed, estimated, reading, start, progress)
}

/// Reads the inputs as one cloud: the tiles' points one after another. Tiles must have the
/// same properties.
fn read_clouds(inputs: &[PathBuf]) -> spsr::Result<spsr::PointCloud> {
    spsr::io::read_tiles(inputs, read_cloud_arg)
}

/// Writes the mesh, the warnings, `-v`'s details and the summary line.
fn finish(
    args: &ReconstructArgs,
    result: spsr::Reconstruction,
    trimmed: Option<spsr::trim::TrimStats>,
    estimated: Option<normals::NormalReport>,
    reading: Duration,
    start: Instant,
    progress: Progress,
) -> Result<(), Failure> {
    let input = args.input();
    let output = args.output.as_path();
    let fail = |e: spsr::Error| Failure::from_spsr(e, input_name(input));
    progress.stage("writing");
    let t = Instant::now();
    let opts = spsr::io::WriteOptions {
        ascii: args.common.ascii,
    };
    write_mesh_arg(output, &result.mesh, &opts).map_err(fail)?;
    let writing = t.elapsed();
    if let Some(p) = &args.preview {
        crate::render::write_preview(&result.mesh, p, input)?;
    }
    if let (Some(path), Some(grid)) = (&args.grid, &result.grid) {
        spsr::io::write_grid(path, grid).map_err(fail)?;
    }
    drop(progress);

    for w in &result.stats.warnings {
        eprintln!(
            "spsr: warning: {}: {}",
            args.inputs_label(),
            words::warning(w)
        );
    }
    if args.common.verbose {
        print_details(args, &result, reading, writing, start.elapsed());
        if let Some(report) = &estimated {
            report.print();
        }
        if let Some(stats) = &trimmed {
            print_trim(stats, stage_time(&result.stats, "trimming"));
        }
    }
    if let Some(report) = &result.stats.solve {
        print_solve_report(&mut std::io::stderr().lock(), report);
    }
    report(output, &summary(&result, start.elapsed(), spsr::peak_rss()));
    Ok(())
}

/// The wall time of the stage called `name` (zero if it did not run).
fn stage_time(stats: &spsr::Stats, name: &str) -> Duration {
    stats
        .stages
        .iter()
        .find(|(n, _)| n == name)
        .map_or(Duration::ZERO, |s| s.1)
}

/// The summary line's facts: `V vertices, F faces, P pieces, closed, in T s, peak M MiB`.
fn summary(result: &spsr::Reconstruction, time: Duration, peak: Option<u64>) -> String {
    let d = &result.stats.diagnosis;
    let plural =
        |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
    let closed = if d.closed {
        "closed".to_string()
    } else {
        format!(
            "open ({})",
            plural(d.boundary_edges, "boundary edge", "boundary edges")
        )
    };
    let mut line = format!(
        "{}, {}, {}, {closed}, in {:.2} s",
        plural(result.mesh.vertices.len(), "vertex", "vertices"),
        plural(result.mesh.triangles.len(), "face", "faces"),
        plural(d.pieces, "piece", "pieces"),
        time.as_secs_f64()
    );
    if let Some(bytes) = peak {
        line += &format!(", peak memory {}", mib(bytes));
    }
    line
}

fn mib(bytes: u64) -> String {
    format!("{:.0} MiB", bytes as f64 / (1024.0 * 1024.0))
}

/// Where a parameter's value comes from, as `-v` reports it.
#[derive(Debug, Clone, PartialEq)]
enum Source {
    /// The flag's default (the library's).
    Default,
    /// Given on the command line.
    Flag,
    /// Computed from other values or from the machine, as the text says.
    Derived(String),
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Source::Default => f.write_str("default"),
            Source::Flag => f.write_str("flag"),
            Source::Derived(how) => write!(f, "derived: {how}"),
        }
    }
}

/// Every parameter in effect, as `(flag, value, source)`, in the order of `--help`.
fn parameters(args: &ReconstructArgs, params: &spsr::Params) -> Vec<(String, String, Source)> {
    let src = |id: &str| {
        if args.given(id) {
            Source::Flag
        } else {
            Source::Default
        }
    };
    // A value the flag gave, or the default derived as `why` says.
    let given_or = |id: &str, why: &str| {
        if args.given(id) {
            Source::Flag
        } else {
            Source::Derived(why.into())
        }
    };
    let on = |b: bool| if b { "on" } else { "off" }.to_string();
    let mut rows: Vec<(&str, String, Source)> = vec![
        match params.resolution {
            spsr::Resolution::Depth => ("depth", params.depth.to_string(), src("depth")),
            spsr::Resolution::Auto => (
                "depth",
                "auto".into(),
                Source::Derived("from the points' spacing, once read".into()),
            ),
            spsr::Resolution::Width(_) => (
                "depth",
                "from --width".into(),
                Source::Derived("the smallest whose cells are no wider".into()),
            ),
        },
        match params.resolution {
            spsr::Resolution::Width(w) => ("width", w.to_string(), Source::Flag),
            _ => ("width", "none".into(), Source::Default),
        },
        (
            "full_depth",
            params.full_depth.to_string(),
            if args.given("full_depth") {
                Source::Flag
            } else if params.full_depth != spsr::Params::default().full_depth {
                Source::Derived("no deeper than --depth".into())
            } else {
                Source::Default
            },
        ),
        (
            "samples_per_node",
            params.samples_per_node.to_string(),
            src("samples_per_node"),
        ),
        (
            "point_weight",
            params.alpha().to_string(),
            given_or("point_weight", "2 × --degree"),
        ),
        (
            "noise",
            match params.noise {
                spsr::Noise::Adaptive => "adaptive",
                spsr::Noise::Off => "off",
            }
            .to_string(),
            if args.given("noise") {
                Source::Flag
            } else if args.samples_per_node.is_some() || args.point_weight.is_some() {
                Source::Derived("--samples-per-node or --point-weight given".into())
            } else {
                Source::Default
            },
        ),
        (
            "keep_outliers",
            on(params.keep_outliers),
            src("keep_outliers"),
        ),
        ("keep_normals", on(params.keep_normals), src("keep_normals")),
        ("degree", params.degree.to_string(), src("degree")),
        (
            "boundary",
            args.boundary()
                .to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_string()),
            if args.given("boundary") || args.given("reference_boundary") {
                Source::Flag
            } else {
                Source::Default
            },
        ),
        ("scale", params.scale.to_string(), src("scale")),
        (
            "iters",
            params.iters().to_string(),
            given_or("iters", "8 for one cycle, 4 for more"),
        ),
        ("solver", params.solver.name().to_string(), src("solver")),
        (
            "cycles",
            params.cycles().to_string(),
            given_or("cycles", "2 at --degree 1, 1 at --degree 2"),
        ),
        ("residuals", on(args.residuals), src("residuals")),
        (
            "gpu",
            args.gpu
                .to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_string()),
            src("gpu"),
        ),
        ("confidence", on(args.confidence), src("confidence")),
        (
            "confidence_property",
            args.confidence_property
                .clone()
                .unwrap_or_else(|| "none".into()),
            src("confidence_property"),
        ),
        ("normals", on(params.normals), src("normals")),
        (
            "no_attributes",
            on(!params.attributes),
            src("no_attributes"),
        ),
        ("data_pull", params.data_pull.to_string(), src("data_pull")),
        ("density", on(params.density), src("density")),
        (
            "trim",
            match args.trim {
                None => "off".into(),
                Some(spsr::trim::Threshold::Auto) => "auto".into(),
                Some(spsr::trim::Threshold::Value(v)) => v.to_string(),
            },
            src("trim"),
        ),
    ];
    if args.trim.is_some() {
        rows.push((
            "min_island_area",
            args.min_island_area.to_string(),
            src("min_island_area"),
        ));
        rows.push(("hole_area", args.hole_area.to_string(), src("hole_area")));
    }
    rows.extend([
        ("linear_fit", on(params.linear_fit), src("linear_fit")),
        match params.max_memory {
            Some(bytes) => ("max_memory", spsr::gib(bytes), Source::Flag),
            None => (
                "max_memory",
                spsr::memory_budget().map_or_else(|| "none".into(), spsr::gib),
                Source::Derived("the memory available".into()),
            ),
        },
        (
            "two_level_splat",
            on(params.two_level_splat),
            src("two_level_splat"),
        ),
        (
            "threads",
            rayon::current_num_threads().to_string(),
            if args.given("threads") {
                Source::Flag
            } else {
                Source::Derived("all cores, or RAYON_NUM_THREADS".into())
            },
        ),
        ("ascii", on(args.common.ascii), src("ascii")),
        (
            "estimate_normals",
            on(args.estimate_normals),
            src("estimate_normals"),
        ),
    ]);
    // These three apply only when normals are estimated (no normals in the input, or
    // --estimate-normals), which is known once the input is read.
    let est = &args.estimation;
    rows.push(match (est.orient, est.viewpoint) {
        (Some(o), _) => (
            "orient",
            o.to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_string()),
            Source::Flag,
        ),
        (None, Some(_)) => (
            "orient",
            "viewpoint".into(),
            Source::Derived("--viewpoint is given".into()),
        ),
        (None, None) => (
            "orient",
            "mst".into(),
            Source::Derived("viewpoint instead when the file records scan positions".into()),
        ),
    });
    rows.push(match est.viewpoint {
        Some([x, y, z]) => ("viewpoint", format!("{x},{y},{z}"), Source::Flag),
        None => ("viewpoint", "none".into(), Source::Default),
    });
    rows.push(match est.neighbours {
        Some(k) => ("neighbours", k.to_string(), Source::Flag),
        None => (
            "neighbours",
            "auto".into(),
            Source::Derived("from the noise, 16 to 192".into()),
        ),
    });
    rows.push(match params.grid_res {
        Some(r) => ("grid_res", r.to_string(), Source::Flag),
        None => ("grid_res", "none".into(), Source::Default),
    });
    rows.push((
        "grid",
        args.grid
            .as_ref()
            .map_or_else(|| "none".into(), |p| p.display().to_string()),
        src("grid"),
    ));
    rows.push((
        "preview",
        args.preview
            .as_ref()
            .map_or_else(|| "none".into(), |p| p.display().to_string()),
        src("preview"),
    ));
    rows.into_iter()
        .map(|(field, value, source)| (words::flag(field), value, source))
        .collect()
}

/// `-v`'s first part: every parameter in effect and where its value comes from.
fn print_parameters(args: &ReconstructArgs, params: &spsr::Params) {
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "parameters:");
    for (flag, value, source) in parameters(args, params) {
        let _ = writeln!(err, "  {flag:<22} {value:<12} {source}");
    }
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
    let _ = writeln!(err, "input       {}", args.input().display());
    let _ = writeln!(
        err,
        "points      {} read, {} dropped",
        stats.points, stats.dropped
    );
    let _ = writeln!(err, "samples     {}", stats.samples);
    if let Some(n) = &stats.noise {
        let _ = writeln!(
            err,
            "noise       {:.3e} ({:.2} finest cells), measured on {:.0} % of the samples; \
             splat depth lowered on {:.0} % of them, by {:.2} levels on average",
            n.median,
            n.median_cells,
            100.0 * n.measured,
            100.0 * n.adapted,
            n.mean_lowering
        );
    }
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
    if let Some(gpu) = &stats.gpu {
        let _ = writeln!(
            err,
            "gpu         {gpu} ran these steps of the depths above the base (copies, kernels, \
             bandwidth):"
        );
        for g in &stats.gpu_relaxations {
            let secs = g.kernels.as_secs_f64();
            let rate = if g.sweeps == 0 {
                String::new()
            } else {
                let r = g.bytes_per_sweep as f64 * f64::from(g.sweeps) / secs.max(1e-9) / 1e9;
                format!("{r:>7.0} GB/s")
            };
            let _ = writeln!(
                err,
                "  {:>2}  {:<15} {:>12} nodes x {}  {:>8.3} s {:>8.3} s  {rate}",
                g.depth,
                g.kind.name(),
                g.nodes,
                g.sweeps,
                g.transfer.as_secs_f64(),
                secs
            );
        }
        let total = |f: fn(&spsr::GpuRelaxation) -> std::time::Duration| -> f64 {
            stats
                .gpu_relaxations
                .iter()
                .map(|g| f(g).as_secs_f64())
                .sum()
        };
        let _ = writeln!(
            err,
            "      in all: {:.3} s of copies, {:.3} s of kernels",
            total(|g| g.transfer),
            total(|g| g.kernels)
        );
    }
    let _ = writeln!(err, "iso-value   {}", stats.iso_value);
    let _ = writeln!(
        err,
        "mesh        {} vertices, {} faces",
        result.mesh.vertices.len(),
        result.mesh.triangles.len()
    );
    let d = &stats.diagnosis;
    let _ = writeln!(
        err,
        "check       {} pieces, {}, {} vertices on the bounding cube, {:.1} % of the normals \
         against the surface",
        d.pieces,
        if d.closed { "closed" } else { "open" },
        d.on_cube,
        100.0 * d.contradicted_normals
    );
    let _ = writeln!(err, "output      {}", args.output.display());
    // Bytes moved at the least and flops, by the library's floor model (`spsr::Work`); the
    // files count at their size on disk.
    let file_size = |p: &std::path::Path| std::fs::metadata(p).map_or(0, |m| m.len());
    let read_bytes: u64 = args.inputs().iter().map(|p| file_size(p)).sum();
    let mesh = &result.mesh;
    let _ = writeln!(
        err,
        "timings:{:>38}{:>20}{:>24}",
        "", "floor: moved", "done      rate"
    );
    let stages = std::iter::once(("reading", reading))
        .chain(stats.stages.iter().map(|(n, d)| (n.as_str(), *d)))
        .chain(std::iter::once(("writing", writing)));
    let memory = std::iter::once(None)
        .chain(stats.peak_memory.iter().copied())
        .chain(std::iter::once(None));
    let work = std::iter::once(Some(spsr::work::reading(read_bytes, stats.points)))
        .chain((0..stats.stages.len()).map(|k| stats.work.get(k).copied().flatten()))
        .chain(std::iter::once(Some(spsr::work::writing(
            file_size(&args.output),
            mesh.vertices.len(),
            mesh.triangles.len(),
        ))));
    for (((name, d), mem), work) in stages.zip(memory).zip(work) {
        let mem = match mem {
            Some(bytes) => format!("peak {:>8.0} MiB", bytes as f64 / (1024.0 * 1024.0)),
            None => String::new(),
        };
        let work = match work {
            Some(w) => format!(
                "{:>9.3} GB {:>9.3} Gflop {:>7.2} GB/s",
                w.bytes / 1e9,
                w.flops / 1e9,
                w.rate_gbs(d)
            ),
            None => String::new(),
        };
        let line = format!(
            "  {name:<32} {:>9.3} s   {mem:<17}   {work}",
            d.as_secs_f64()
        );
        let _ = writeln!(err, "{}", line.trim_end());
    }
    let _ = writeln!(err, "  {:<32} {:>9.3} s", "total", total.as_secs_f64());
}

/// The solver's residuals (`--residuals`): each depth's relative residual before and after each
/// relaxation, and the whole system's after each cycle.
fn print_solve_report(err: &mut impl std::io::Write, report: &spsr::SolveReport) {
    let first = if report.first_deepest_iters == report.iters {
        String::new()
    } else {
        format!(
            " ({} in the deepest depth's first)",
            report.first_deepest_iters
        )
    };
    let _ = writeln!(
        err,
        "solver      {}, {} sweeps per relaxation{first}; relative residual per depth (before -> after):",
        report.solver.name(),
        report.iters
    );
    let mut cycle = 0;
    for (k, r) in report.depths.iter().enumerate() {
        if r.cycle != cycle {
            cycle = r.cycle;
            let _ = write!(err, "  cycle {cycle}:");
        }
        let _ = write!(
            err,
            " {}{} {:.1e}->{:.1e}",
            r.depth,
            match r.phase {
                "down" => "v",
                "up" => "^",
                _ => "=",
            },
            r.before,
            r.after
        );
        if report.depths.get(k + 1).is_none_or(|n| n.cycle != cycle) {
            let k = (cycle - 1) as usize;
            let _ = writeln!(
                err,
                "\n    whole system after cycle {cycle}: {:.3e} (work {:.3e} sweeps x nodes, {:.3} s)",
                report.after_cycle.get(k).copied().unwrap_or(f64::NAN),
                report.work.get(k).copied().unwrap_or(f64::NAN),
                report.seconds.get(k).copied().unwrap_or(f64::NAN),
            );
        }
    }
}
