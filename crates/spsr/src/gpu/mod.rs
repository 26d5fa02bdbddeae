//! The GPU back end (issue 17), behind the cargo feature `gpu`: the divergence constraints and
//! the solver's depths above the base (right-hand sides, relaxations, prolongations, coupling)
//! on an NVIDIA card, giving the CPU's coefficients bit for bit.
//!
//! The binding is `cudarc`, chosen because it loads the CUDA driver and NVRTC when the program
//! runs (`dlopen`), so that the crate builds, and a build with the feature runs on the CPU, on
//! machines without CUDA; the kernels are CUDA C compiled by NVRTC when a device is opened
//! for the card at hand, with floating-point contraction off so that every product and sum
//! rounds as the CPU's does. Without the feature, [`Device::open`] says that this build has no
//! GPU support, and [`crate::Params::gpu`] set to `On` is an error.
//!
//! Each depth's system is copied to the card once per solve ([`LevelSystem`], `Resident`) and
//! read there by every right-hand side and relaxation of the depth. The divergence constraints
//! run there too, depth by depth from the finest ([`ConstraintLevel`]), each depth's V and `G`
//! kept on the card for the next. The coarser solution at the clusters, the prolongations and the
//! finer depths' coupling of the later cycles run there too ([`CouplingLevel`]); the base depth,
//! the other stages and the extraction stay on the CPU (`docs/gpu.md` gives the measured profile
//! and what is left).

#[cfg(feature = "gpu")]
use crate::octree::WINDOW;

#[cfg(feature = "gpu")]
mod cuda;
#[cfg(feature = "gpu")]
mod staging;
#[cfg(feature = "gpu")]
pub use cuda::{Device, Resident};

/// A GPU that cannot be opened in a build without the cargo feature `gpu`.
#[cfg(not(feature = "gpu"))]
#[derive(Debug)]
pub struct Device {
    never: std::convert::Infallible,
}

#[cfg(not(feature = "gpu"))]
impl Device {
    /// Always an error: this build has no GPU support.
    pub fn open(_degree: u8) -> Result<Device, String> {
        Err(
            "this spsr was built without GPU support (build it with the cargo feature `gpu`)"
                .into(),
        )
    }

    /// The card's name.
    pub fn name(&self) -> &str {
        match self.never {}
    }

    /// Why a level fell back to the CPU, if one did.
    pub fn take_failure(&self) -> Option<String> {
        match self.never {}
    }

    /// The relaxations run so far.
    pub fn take_timings(&self) -> Vec<GpuRelaxation> {
        match self.never {}
    }
}

/// What a step on the GPU did ([`GpuRelaxation::kind`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GpuKernel {
    /// A depth's system copied to the card (once per solve).
    Upload,
    /// A depth's right-hand side.
    RightHandSide,
    /// Gauss–Seidel sweeps over a depth.
    Relaxation,
    /// A depth's divergence constraints.
    Constraints,
    /// The finer depths' coupling of a depth's parent depth (cycles after the first).
    Coupling,
    /// A depth's cumulative solution or V, prolonged from its parent depth's.
    Prolongation,
}

impl GpuKernel {
    /// The step's name in the `-v` report.
    pub fn name(self) -> &'static str {
        match self {
            GpuKernel::Upload => "copy in",
            GpuKernel::RightHandSide => "right-hand side",
            GpuKernel::Relaxation => "relaxation",
            GpuKernel::Constraints => "constraints",
            GpuKernel::Coupling => "finer coupling",
            GpuKernel::Prolongation => "prolongation",
        }
    }
}

/// What one step of a depth on the GPU cost ([`crate::Stats::gpu`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GpuRelaxation {
    /// What the step did.
    pub kind: GpuKernel,
    /// The unit depth.
    pub depth: u32,
    /// Nodes relaxed per sweep, or the depth's nodes.
    pub nodes: usize,
    /// Sweeps (1 for a right-hand side, 0 for a copy).
    pub sweeps: u32,
    /// Copying the step's inputs to the card and its results back.
    pub transfer: std::time::Duration,
    /// The step's kernels.
    pub kernels: std::time::Duration,
    /// The bytes one sweep (or the right-hand side) must read or write at least: each array
    /// the kernel reads once, its results written once. Over `kernels / sweeps`, the
    /// bandwidth the kernels reach.
    pub bytes_per_sweep: u64,
}

#[cfg(feature = "gpu")]
/// One octree depth's nodes as every kernel reads them: their depth and count, where they lie
/// and who their neighbours are, and the range of their function indices.
#[derive(Clone)]
pub struct LevelShape<'a> {
    /// Unit-cube depth of the level (a node's function index is its key minus `2^depth`).
    pub depth: u32,
    /// Nodes of the level.
    pub nodes: usize,
    /// The 27 broods around each brood (`octree::Level::brood_rows`: made for the copy
    /// where the level derives them).
    pub brood_nbrs: std::borrow::Cow<'a, [[u32; 27]]>,
    /// What the rows are made from (`octree::Level::brood_rows_identity`), which names the
    /// card's copy.
    pub brood_nbrs_id: (usize, usize),
    /// The key of each brood's parent (`octree::Level::key`).
    pub brood_key: &'a [[u32; 3]],
    /// Lowest function index per axis.
    pub lo: i64,
    /// Highest function index per axis.
    pub hi: i64,
}

#[cfg(feature = "gpu")]
/// One octree depth's system as the relaxation kernel reads it: the level's neighbour
/// tables, the stiffness stencil and 1-D tables, the screening clusters, and the order in
/// which its nodes are relaxed.
pub struct LevelSystem<'a> {
    /// Degree of the finite elements (1 or 2).
    pub degree: u8,
    /// The level's nodes.
    pub shape: LevelShape<'a>,
    /// The interior stiffness stencil, by window index.
    pub stencil: &'a [f64; 125],
    /// The same stencil by neighbouring brood (`system::BroodStencil`), as the CPU sums an
    /// interior row: where each child position's entries start in `brood_slot` (nine values),
    /// each entry's brood slot, and its eight coefficients in `brood_coef`.
    pub brood_start: Vec<u32>,
    /// See `brood_start`.
    pub brood_slot: Vec<u32>,
    /// See `brood_start`.
    pub brood_coef: Vec<f64>,
    /// The same-depth 1-D mass table, five offsets per index `lo..=hi`.
    pub mass: Vec<f64>,
    /// The same-depth 1-D stiffness table, laid out as `mass`.
    pub stiff: Vec<f64>,
    /// The cluster of each node: a bitmap and the members before each word.
    pub rank_bits: &'a [u64],
    /// See `rank_bits`.
    pub rank_before: &'a [u32],
    /// Screening weight per cluster.
    pub omega: &'a [f64],
    /// First function index per axis of each cluster's window.
    pub first: std::borrow::Cow<'a, [[i32; 3]]>,
    /// Basis values per axis of each cluster.
    pub vals: std::borrow::Cow<'a, [[[f32; 3]; 3]]>,
    /// The node of each cluster.
    pub cl_node: &'a [u32],
    /// The position of each cluster, in the unit cube.
    pub pos: Vec<[f64; 3]>,
    /// The boundary condition: 0 free, 1 Neumann, 2 Dirichlet.
    pub boundary: i32,
    /// The parent node of each brood.
    pub brood_parent: &'a [u32],
    /// The parent level's 27 broods around each brood.
    pub parent_nbrs: std::borrow::Cow<'a, [[u32; 27]]>,
    /// What the parent level's rows are made from (`octree::Level::brood_rows_identity`).
    pub parent_nbrs_id: (usize, usize),
    /// The key of each of the parent level's broods' parent (`octree::Level::key`).
    pub parent_keys: &'a [[u32; 3]],
    /// Interior parent stiffness stencils by child parity (`DepthTables::pstencil`).
    pub pstencil: &'a [[f64; 125]; 8],
    /// Interior parent V stencils by child parity and component.
    pub pvstencil: &'a [[[f64; 125]; 3]; 8],
    /// Where each child parity's list in `nonzero` starts (nine entries).
    pub nonzero_start: Vec<u32>,
    /// The parent window indices where the parent stencils are nonzero, parity by parity.
    pub nonzero: Vec<u32>,
    /// 1-D tables against the parent depth (`pmass`, `pstiff`, `pvmass`, `pvderiv`), laid
    /// out as `mass`.
    pub pmass: Vec<f64>,
    /// See `pmass`.
    pub pstiff: Vec<f64>,
    /// See `pmass`.
    pub pvmass: Vec<f64>,
    /// See `pmass`.
    pub pvderiv: Vec<f64>,
    /// The two-scale weights of the level's functions (`system::Prolong::rows`): the first
    /// index and three weights per index.
    pub prolong: (i64, &'a [[f64; 3]]),
    /// The same for the V basis.
    pub vprolong: (i64, &'a [[f64; 3]]),
    /// The V basis's index range (`lo`, `hi`).
    pub vrange: (i64, i64),
    /// The nodes to relax, class after class: nodes of one class are relaxed at once.
    pub order: Vec<u32>,
    /// Where each class of `order` ends.
    pub class_ends: Vec<usize>,
}

#[cfg(feature = "gpu")]
/// One octree depth's divergence constraints as the kernels `push_finer_v` and
/// `constraint_rows` read them (`system::divergence_constraints`): the depth's neighbour tables
/// and 1-D tables, the V of the depth and of the next, and the next depth's `G`.
pub struct ConstraintLevel<'a> {
    /// The level's nodes.
    pub shape: LevelShape<'a>,
    /// FEM values against same-depth V, five offsets per index `lo..=hi`.
    pub vmass: Vec<f64>,
    /// FEM derivatives against same-depth V, laid out as `vmass`.
    pub vderiv: Vec<f64>,
    /// Each node's children brood at the next level (empty: none has children).
    pub children: &'a [u32],
    /// Per index `lo..=hi`, how many two-scale children it has (`Basis::children`) ...
    pub child_count: Vec<u32>,
    /// ... their indices, four slots per index ...
    pub child_index: Vec<i64>,
    /// ... and their weights, laid out as `child_index`.
    pub child_weight: Vec<f64>,
    /// The first coarse index of `cvmass` and `cvderiv` (`system::CoarseFine`).
    pub coarse_lo: i64,
    /// FEM values against V one depth finer, eight offsets per coarse index.
    pub cvmass: &'a [[f64; 8]],
    /// FEM derivatives against V one depth finer, laid out as `cvmass`.
    pub cvderiv: &'a [[f64; 8]],
    /// The parent node of each brood of the next level (empty without one).
    pub next_parent: &'a [u32],
    /// The next level's broods in tiles, colour after colour (`system::brood_tiles`): each
    /// tile's first brood and the one after its last.
    pub push_runs: Vec<[u32; 2]>,
    /// Where each colour of `push_runs` ends.
    pub push_run_ends: Vec<usize>,
    /// Whether the next level's V is pushed (the CPU's `pushed` is not empty).
    pub push: bool,
    /// V of the level's nodes (empty: none).
    pub v: &'a [[f32; 3]],
    /// V of the next level's nodes (empty: none).
    pub v_finer: &'a [[f32; 3]],
    /// `G` of the next level (`None`: none).
    pub g_finer: Option<&'a [f64]>,
}

#[cfg(feature = "gpu")]
/// The finer depths' gradient coupling of a depth's parent depth as the kernels
/// `push_to_parents` and `coupling_rows` read it (`solver::cycles::coupling_below_of`): the
/// depth's coefficients and its tiles, and the parent depth's nodes, children and two-scale
/// tables, with the coupling of the depths below.
pub struct CouplingLevel<'a> {
    /// The depth's broods in tiles, colour after colour (`solver::cycles::push_tiles`): each
    /// tile's first brood and the one after its last.
    pub runs: Vec<[u32; 2]>,
    /// Where each colour of `runs` ends.
    pub run_ends: Vec<usize>,
    /// The depth's coefficients.
    pub x: &'a [f32],
    /// The parent depth's nodes.
    pub parent: LevelShape<'a>,
    /// The parent depth's nodes' children broods (empty: none has children).
    pub children: &'a [u32],
    /// Per parent index, its two-scale children: how many (`Basis::children`) ...
    pub child_count: Vec<u32>,
    /// ... their indices, four slots per index ...
    pub child_index: Vec<i64>,
    /// ... and their weights, laid out as `child_index`.
    pub child_weight: Vec<f64>,
    /// The coupling of the depths finer than this one, per node of this depth (empty: none).
    pub u: &'a [f64],
}

#[cfg(feature = "gpu")]
impl CouplingLevel<'_> {
    /// The bytes the two kernels must read or write at least: per node its coefficient and
    /// finer coupling, per brood its key and parent, per parent node its coupling read and
    /// written and its children, per parent brood its neighbours and key.
    pub fn bytes(&self) -> u64 {
        (self.x.len() * 4
            + self.u.len() * 8
            + self.x.len() / 8 * (12 + 4)
            + self.parent.nodes * (16 + 4)
            + self.parent.nodes / 8 * (27 * 4 + 12)) as u64
    }
}

#[cfg(feature = "gpu")]
impl ConstraintLevel<'_> {
    /// The bytes the two kernels must read or write at least: per node its neighbours (per
    /// brood), key, children, V and results; per next node its V and `G`.
    pub fn bytes(&self) -> u64 {
        let broods = self.shape.nodes / 8;
        (broods * (27 * 4 + 12)
            + self.shape.nodes * (4 + 12 + 8 + 4)
            + self.v_finer.len() * 12
            + self.g_finer.map_or(0, |g| g.len() * 8)) as u64
    }
}

#[cfg(feature = "gpu")]
impl LevelSystem<'_> {
    /// See [`GpuRelaxation::bytes_per_sweep`].
    pub fn bytes_per_sweep(&self) -> u64 {
        let size = |n: usize, each: usize| (n * each) as u64;
        let nodes = self.order.len();
        // Per node relaxed: its place in the order, right-hand side, coefficient read and
        // written; per brood: neighbours and key; per cluster: ω, window, values, χ read and
        // written; the rank bitmap.
        size(nodes, 4 + 8 + 4 + 4)
            + size(self.shape.brood_nbrs.len(), 27 * 4 + 3 * 4)
            + size(self.omega.len(), 8 + 12 + 36 + 8 + 8)
            + size(self.rank_bits.len(), 8 + 4)
    }
}

#[cfg(feature = "gpu")]
/// The kernels' source for elements of degree `degree`, with the tables they read: the window
/// tables (`octree::WINDOW`) and, per child position, the neighbouring broods whose nodes'
/// clusters can touch a function, in the CPU's order (`solver::cluster_broods`).
pub fn kernel_source(degree: u8) -> String {
    let join = |v: &mut dyn Iterator<Item = u32>| v.map(|x| x.to_string()).collect::<Vec<_>>();
    let list = |rows: &[[u8; 125]; 8]| {
        join(&mut rows.iter().flat_map(|r| r.iter()).map(|&v| u32::from(v))).join(",")
    };
    let broods = crate::solver::cluster_broods(degree);
    let mut start = vec![0u32];
    for b in &broods {
        start.push(start[start.len() - 1] + b.len() as u32);
    }
    let all = || broods.iter().flatten();
    format!(
        "#define DEGREE {degree}\n\
         __constant__ unsigned char WSLOT[1000] = {{{}}};\n\
         __constant__ unsigned char WBITS[1000] = {{{}}};\n\
         __constant__ unsigned int CBROOD_START[9] = {{{}}};\n\
         __constant__ unsigned char CBROOD_SLOT[{n}] = {{{}}};\n\
         __constant__ unsigned char CBROOD_MASK[{n}] = {{{}}};\n{}",
        list(WINDOW.slots()),
        list(WINDOW.child_bits()),
        join(&mut start.iter().copied()).join(","),
        join(&mut all().map(|&(slot, _)| u32::from(slot))).join(","),
        join(&mut all().map(|&(_, mask)| u32::from(mask))).join(","),
        include_str!("kernels.cu"),
        n = start[8],
    )
}

#[cfg(all(test, feature = "gpu"))]
mod tests {
    use super::kernel_source;
    use cudarc::nvrtc::{compile_ptx_with_opts, CompileOptions};

    /// The kernels compile for both degrees wherever NVRTC can be loaded (it needs no GPU);
    /// skipped, with a message, where it cannot.
    #[test]
    fn the_kernels_compile() {
        // SAFETY: only probes whether the shared library can be loaded.
        if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
            eprintln!("skipped: NVRTC (libnvrtc) cannot be loaded here");
            return;
        }
        for degree in [1, 2] {
            let opts = CompileOptions {
                fmad: Some(false),
                options: vec!["--gpu-architecture=compute_90".into()],
                ..Default::default()
            };
            if let Err(e) = compile_ptx_with_opts(kernel_source(degree), opts) {
                panic!("degree {degree}: {e:?}");
            }
        }
    }
}
