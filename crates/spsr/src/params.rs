//! Reconstruction parameters. Each default says where it comes from (ALGORITHM.md §14).

use crate::bspline::{Boundary, Degree};
use crate::{Error, Result};

/// Deepest octree depth spsr accepts. Node keys are 64-bit Morton codes over a tree two levels
/// deeper than the unit cube (the outer ring of ALGORITHM.md §4.2), so 3 × (depth + 2) bits must
/// fit in 63 bits; 18 leaves headroom.
pub const MAX_DEPTH: u32 = 18;

/// Parameters of [`crate::reconstruct`]. Build with `Params::default()` and change fields.
/// (Serialisable, for the job file of a slab run as tasks: `slabs::job`.)
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Params {
    /// Maximum octree depth `D`; the finest cells are `1/2^D` of the bounding cube.
    /// Default 8, as PoissonRecon 6 and 18.
    pub depth: u32,
    /// The octree is complete (all cells present) down to this depth, and the coarse
    /// multigrid solve happens there. Default 5, as PoissonRecon 6 and 18.
    pub full_depth: u32,
    /// Target number of samples per octree node, which sets the splat depth of each sample
    /// (ALGORITHM.md §3.5). Default 1.5, as PoissonRecon 18 (1.0 in version 6).
    pub samples_per_node: f64,
    /// Screening weight α; 0 gives the unscreened 2006 method. `None` means 2 × degree, the
    /// PoissonRecon 18 default (4 for degree 2, the paper's value).
    pub point_weight: Option<f64>,
    /// B-spline degree of the finite elements. Default linear, as PoissonRecon 18
    /// (the paper and PoissonRecon 6 use quadratic).
    pub degree: Degree,
    /// Boundary condition on the bounding cube. Default Neumann, as PoissonRecon 6 and 18.
    pub boundary: Boundary,
    /// The bounding cube is the points' bounding box's largest side times this factor.
    /// Default 1.1, as PoissonRecon 6 and 18.
    pub scale: f64,
    /// Gauss–Seidel sweeps per depth in each of the solver's cycles. `None` (default): 8
    /// with one cycle, as PoissonRecon 6 and 18 and the paper, and 4 with more; see
    /// [`Params::iters`]. With more than one cycle the deepest depth's first relaxation
    /// makes half as many ([`Params::first_deepest_iters`]).
    pub iters: Option<u32>,
    /// Each point's weight in the fit (ALGORITHM.md §3.4). Default uniform.
    pub weights: PointWeights,
    /// Compute per-vertex density (estimated sampling depth, ALGORITHM.md §9.5). Default off.
    pub density: bool,
    /// Place iso-vertices by linear interpolation along cell edges instead of the quadratic
    /// fit through the end values and gradients (PoissonRecon 18 `--linearFit`). Default off.
    pub linear_fit: bool,
    /// Refuse the run, before building the octree, when its estimated peak memory exceeds this
    /// many bytes. `None` (default) uses the memory the machine has available, where the
    /// platform reports it (Linux); elsewhere there is no limit.
    pub max_memory: Option<u64>,
    /// Split each sample's normal between the two depths around its estimated (fractional)
    /// depth, as the 2006 paper and PoissonRecon 6 do, instead of splatting it whole at the
    /// depth above, as PoissonRecon 18 does (ALGORITHM.md §3.6). The split gives smoother
    /// fields: measured more accurate on smooth analytic surfaces, less on detailed scans.
    /// Default off (PoissonRecon 18).
    pub two_level_splat: bool,
    /// Interpolate every per-point attribute of the cloud (colours and any other numeric
    /// property) onto the mesh vertices, each in its own type. Default on.
    pub attributes: bool,
    /// Pull factor of the attribute interpolation: the data of each depth is weighted by
    /// this factor to the power of the depth, so the finest depth with samples near a vertex
    /// decides its value and coarser depths only fill in where there are none, which keeps
    /// colour from bleeding between nearby surfaces. Default 32, as PoissonRecon 18
    /// (`--dataX`).
    pub data_pull: f64,
    /// Compute per-vertex normals from the gradient of the implicit function (`−∇χ`,
    /// unit length). Default off.
    pub normals: bool,
    /// Adapt the splat depth and the screening weight to the noise measured around each
    /// sample (default), or splat where the density alone says and screen every sample
    /// alike, as PoissonRecon does.
    pub noise: Noise,
    /// Keep the far outliers (points far outside the box that holds the bulk of the cloud)
    /// instead of leaving them out, as PoissonRecon does. Default off: they are left out,
    /// with a warning.
    pub keep_outliers: bool,
    /// Keep the normals as given even when many contradict their neighbours. Default off:
    /// such normals are made consistent, with a warning.
    pub keep_normals: bool,
    /// Shape of the solver's cycles over the depths (ALGORITHM.md §7.1, §7.4). Default
    /// cascadic, as PoissonRecon 18.
    pub solver: Solver,
    /// Cycles of the solver; the first is always the coarse-to-fine cascade. `None`
    /// (default): 2 at degree 1 and 1 at degree 2 ([`Params::cycles`]). At degree 1 one
    /// cycle of 8 sweeps (PoissonRecon 18's cascade) is 2–5 % less accurate than PoissonRecon
    /// 18.74 at its defaults; two cycles of 4 sweeps are at least as accurate, for about a
    /// tenth more time. At degree 2 the cascade already matches the reference, and a second
    /// cycle would cost a tenth more time and memory for 1–3 % (`docs/solver.md`).
    pub cycles: Option<u32>,
    /// Measure the solver's residuals, per depth and per cycle, into
    /// [`crate::Stats::solve`] (what the command line's `-v` prints). Costs about one
    /// more sweep per depth and cycle; the mesh is the same. Default off.
    pub report_residuals: bool,
    /// How the depth is set: `depth` as given (default), from a cell width in the input's
    /// units, or from the cloud's point spacing (`crate::pipeline::resolution`, issue 18).
    #[serde(default)]
    pub resolution: Resolution,
    /// Also sample the implicit function minus the iso-value on an `R³` grid over the
    /// bounding cube ([`crate::Reconstruction::grid`]; negative inside). Default none.
    #[serde(default)]
    pub grid_res: Option<u32>,
    /// Where the solver solves the depths above the base: on the CPU (default), on an NVIDIA
    /// GPU (an error where none can be used), or on a GPU where one can be used (issue 17;
    /// the build needs the cargo feature `gpu`). The mesh is the same bit for bit.
    #[serde(default)]
    pub gpu: Gpu,
}

/// Whether the solver uses a GPU ([`Params::gpu`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Gpu {
    /// The CPU only (default).
    #[default]
    Off,
    /// A GPU; the run fails ([`crate::Error::Gpu`]) where none can be used.
    On,
    /// A GPU where one can be used, else the CPU with a warning ([`crate::Warning::GpuNotUsed`]).
    Auto,
}

/// The shape of the solver's cycles over the depths (issue 18). Each cycle relaxes every depth
/// with [`Params::iters`] Gauss–Seidel sweeps; they differ in what happens going down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Solver {
    /// Coarse to fine only: after the first, each cycle first passes the finer depths'
    /// solution into the coarser depths' constraints (no relaxation going down), then
    /// relaxes the depths coarse to fine (default, with two cycles; with one, PoissonRecon
    /// 18's cascade).
    #[default]
    Cascadic,
    /// V-cycles: going down, each depth is relaxed and the finer depths' residual restricted
    /// into the coarser depths' constraints; then the base is solved and the depths relaxed
    /// coarse to fine.
    VCycle,
    /// W-cycles: as V-cycles, but every depth above the base's next visits the coarser ones
    /// twice.
    WCycle,
}

impl Solver {
    /// The solver named `cascadic`, `vcycle` or `wcycle`.
    pub fn from_name(name: &str) -> Option<Solver> {
        match name {
            "cascadic" => Some(Solver::Cascadic),
            "vcycle" => Some(Solver::VCycle),
            "wcycle" => Some(Solver::WCycle),
            _ => None,
        }
    }

    /// The name [`Solver::from_name`] reads.
    pub fn name(self) -> &'static str {
        match self {
            Solver::Cascadic => "cascadic",
            Solver::VCycle => "vcycle",
            Solver::WCycle => "wcycle",
        }
    }
}

/// How the octree depth is chosen (issue 18). Resolved into a plain `depth` by
/// [`crate::pipeline::resolution::resolve`] before the pipeline's stages run.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub enum Resolution {
    /// [`Params::depth`] as given (default).
    #[default]
    Depth,
    /// The finest cells this wide, in the input's units: the depth is the smallest whose
    /// cells are no wider, and the bounding cube is widened so that they are exactly this
    /// wide, as PoissonRecon's `--width`.
    Width(f64),
    /// The depth whose finest cells match the cloud's typical point spacing, no deeper than
    /// the memory limit allows.
    Auto,
}

/// Whether the reconstruction adapts to the local noise of the points (issue 16).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum Noise {
    /// Measure the noise around every sample, splat it no finer than the noise allows and
    /// lower a noisy sample's screening weight with it (default).
    #[default]
    Adaptive,
    /// Splat every sample at the depth its density gives, as PoissonRecon.
    Off,
}

impl Noise {
    /// The mode the front ends use: the one `given`, else off when the user set the samples
    /// per node or the point weight by hand (their values then mean what they mean in
    /// PoissonRecon), else adaptive.
    pub fn unless_tuned(given: Option<Noise>, tuned_by_hand: bool) -> Noise {
        match given {
            Some(mode) => mode,
            None if tuned_by_hand => Noise::Off,
            None => Noise::Adaptive,
        }
    }

    /// The mode named `adaptive` or `off`.
    pub fn from_name(name: &str) -> Option<Noise> {
        match name {
            "adaptive" => Some(Noise::Adaptive),
            "off" => Some(Noise::Off),
            _ => None,
        }
    }
}

/// How much each point counts in the fit (ALGORITHM.md §3.4).
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum PointWeights {
    /// Every point weighs 1 (default).
    #[default]
    Uniform,
    /// Each point weighs the length of its normal, as PoissonRecon's `--confidence`.
    NormalLength,
    /// Each point weighs the value of this per-point property (for example `confidence` or
    /// `quality`). Points whose value is not a positive finite number are dropped.
    Property(String),
}

impl Default for Params {
    fn default() -> Self {
        Self {
            depth: 8,
            full_depth: 5,
            samples_per_node: 1.5,
            point_weight: None,
            degree: Degree::Linear,
            boundary: Boundary::Neumann,
            scale: 1.1,
            iters: None,
            weights: PointWeights::Uniform,
            density: false,
            linear_fit: false,
            max_memory: None,
            two_level_splat: false,
            attributes: true,
            data_pull: 32.0,
            normals: false,
            noise: Noise::Adaptive,
            keep_outliers: false,
            keep_normals: false,
            solver: Solver::Cascadic,
            cycles: None,
            report_residuals: false,
            resolution: Resolution::Depth,
            grid_res: None,
            gpu: Gpu::Off,
        }
    }
}

impl Params {
    /// The solver's cycles actually made: [`Params::cycles`], else 2 at degree 1 (one more
    /// pass than PoissonRecon 18's cascade, which closes its accuracy gap to the reference)
    /// and 1 at degree 2 (the cascade, already as accurate as the reference).
    pub fn cycles(&self) -> u32 {
        self.cycles.unwrap_or(match self.degree {
            Degree::Linear => 2,
            Degree::Quadratic => 1,
        })
    }

    /// The Gauss–Seidel sweeps per depth and cycle actually made: [`Params::iters`], else 8
    /// for one cycle (PoissonRecon 18's) and 4 for more.
    pub fn iters(&self) -> u32 {
        self.iters.unwrap_or(if self.cycles() > 1 { 4 } else { 8 })
    }

    /// The sweeps of the deepest depth's first relaxation: [`Params::iters`] with one cycle;
    /// with more, half of it (rounded up). That relaxation only sets up the coupling the
    /// deepest depth hands down to the coarser depths; the last cycle relaxes it again from
    /// there, and its sweeps are the ones the mesh keeps (docs/solver.md, *The deepest
    /// depth's first relaxation*).
    pub fn first_deepest_iters(&self) -> u32 {
        if self.cycles() > 1 {
            self.iters().div_ceil(2)
        } else {
            self.iters()
        }
    }

    /// The screening weight α actually used.
    pub fn alpha(&self) -> f64 {
        self.point_weight
            .unwrap_or(2.0 * f64::from(self.degree.get()))
    }

    /// Kernel depth of the density estimator, `max(D − 2, 0)` as PoissonRecon.
    pub fn kernel_depth(&self) -> u32 {
        self.depth.saturating_sub(2)
    }

    /// Depth of the coarse (base) solve: the full depth, clamped to the maximum depth.
    pub fn base_depth(&self) -> u32 {
        self.full_depth.min(self.depth)
    }

    /// Checks every parameter. An error names the field (`depth`), the value and what is
    /// allowed; each front end spells the field its own way.
    pub fn validate(&self) -> Result<()> {
        if self.depth == 0 || self.depth > MAX_DEPTH {
            return Err(Error::invalid(
                "depth",
                self.depth,
                format!("an integer from 1 to {MAX_DEPTH}"),
            ));
        }
        if self.full_depth > self.depth {
            return Err(Error::invalid(
                "full_depth",
                self.full_depth,
                format!("at most the depth, {}", self.depth),
            ));
        }
        if !(self.samples_per_node.is_finite() && self.samples_per_node > 0.0) {
            return Err(Error::invalid(
                "samples_per_node",
                self.samples_per_node,
                "a positive number",
            ));
        }
        if let Some(a) = self.point_weight {
            if !(a.is_finite() && a >= 0.0) {
                return Err(Error::invalid(
                    "point_weight",
                    a,
                    "zero or a positive number",
                ));
            }
        }
        if !(self.scale.is_finite() && self.scale >= 1.0 && self.scale <= 1000.0) {
            return Err(Error::invalid(
                "scale",
                self.scale,
                "a number from 1 to 1000 (the points must lie inside the cube)",
            ));
        }
        if self.max_memory == Some(0) {
            return Err(Error::invalid(
                "max_memory",
                0,
                "a positive number of bytes",
            ));
        }
        if !(self.data_pull.is_finite() && self.data_pull > 0.0) {
            return Err(Error::invalid(
                "data_pull",
                self.data_pull,
                "a positive number",
            ));
        }
        if self.weights == PointWeights::Property(String::new()) {
            return Err(Error::invalid(
                "weights",
                "an empty property name",
                "the name of a per-point property",
            ));
        }
        if let Resolution::Width(w) = self.resolution {
            if !(w.is_finite() && w > 0.0) {
                return Err(Error::invalid(
                    "width",
                    w,
                    "a positive cell width in the input's units",
                ));
            }
        }
        if let Some(res) = self.grid_res {
            let limited = Params {
                max_memory: self.max_memory.or(Some(u64::MAX)),
                ..Params::default()
            };
            crate::pipeline::grid::check_res(res, &limited)?;
        }
        if let Some(iters @ (0 | 10_001..)) = self.iters {
            return Err(Error::invalid("iters", iters, "an integer from 1 to 10000"));
        }
        if let Some(cycles @ (0 | 101..)) = self.cycles {
            return Err(Error::invalid("cycles", cycles, "an integer from 1 to 100"));
        }
        Ok(())
    }
}
