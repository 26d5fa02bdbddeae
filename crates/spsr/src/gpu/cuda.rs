//! The CUDA device: opening it (driver, card, NVRTC, kernels), keeping a depth's system on
//! it, and running the solver's kernels there.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use cudarc::driver::{
    CudaContext, CudaFunction, CudaSlice, CudaStream, DriverError, LaunchArgs, LaunchConfig,
    PushKernelArg,
};
use cudarc::nvrtc::{compile_ptx_with_opts, CompileOptions};

use super::staging::Staging;
use super::{
    kernel_source, ConstraintLevel, CouplingLevel, GpuKernel, GpuRelaxation, LevelShape,
    LevelSystem,
};

/// Threads per block of every kernel.
const BLOCK: u32 = 256;

/// An opened NVIDIA GPU with the solver's kernels compiled for it.
pub struct Device {
    stream: Arc<CudaStream>,
    relax: CudaFunction,
    cluster_values: CudaFunction,
    first_right_hand_sides: CudaFunction,
    cycle_right_hand_side: CudaFunction,
    push_finer_v: CudaFunction,
    constraint_rows: CudaFunction,
    push_to_parents: CudaFunction,
    coupling_rows: CudaFunction,
    coarse_cluster_values: CudaFunction,
    prolong_solution: CudaFunction,
    prolong_field: CudaFunction,
    /// Degree of the elements the kernels were compiled for.
    degree: u8,
    name: String,
    /// Why a step fell back to the CPU, if one did (the first reason).
    failure: Mutex<Option<String>>,
    /// The steps run so far.
    timings: Mutex<Vec<GpuRelaxation>>,
    /// The page-locked buffers large copies pass through.
    staging: Staging,
    /// The neighbour tables and keys copied so far, by depth (see [`Device::tables`]).
    tables: Mutex<Vec<OnCardTable>>,
}

/// A level's table on the card, and the host array it is a copy of.
struct OnCardTable {
    depth: u32,
    /// Address and length of the host array.
    host: (usize, usize),
    dev: Arc<CudaSlice<u32>>,
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Device").field("name", &self.name).finish()
    }
}

/// One depth's system on the card, uploaded once ([`Device::upload`]) and read by every
/// right-hand side and relaxation of the depth in the solve.
pub struct Resident {
    depth: u32,
    depth_arg: i32,
    nodes: usize,
    nodes_arg: u32,
    clusters: usize,
    clusters_arg: u32,
    lo: i64,
    hi: i64,
    words: u64,
    nbrs: Arc<CudaSlice<u32>>,
    keys: Arc<CudaSlice<u32>>,
    stencil: CudaSlice<f64>,
    brood_start: CudaSlice<u32>,
    brood_slot: CudaSlice<u32>,
    brood_coef: CudaSlice<f64>,
    mass: CudaSlice<f64>,
    stiff: CudaSlice<f64>,
    rank_bits: CudaSlice<u64>,
    rank_before: CudaSlice<u32>,
    omega: CudaSlice<f64>,
    first: CudaSlice<i32>,
    vals: CudaSlice<f32>,
    cl_node: CudaSlice<u32>,
    cl_pos: CudaSlice<f64>,
    boundary: i32,
    order: CudaSlice<u32>,
    class_ends: Vec<usize>,
    brood_parent: CudaSlice<u32>,
    parent_nbrs: Arc<CudaSlice<u32>>,
    parent_keys: Arc<CudaSlice<u32>>,
    pstencil: CudaSlice<f64>,
    pvstencil: CudaSlice<f64>,
    nonzero_start: CudaSlice<u32>,
    nonzero: CudaSlice<u32>,
    pmass: CudaSlice<f64>,
    pstiff: CudaSlice<f64>,
    pvmass: CudaSlice<f64>,
    pvderiv: CudaSlice<f64>,
    prolong: Weights,
    vprolong: Weights,
    vlo: i64,
    vhi: i64,
    bytes_per_sweep: u64,
}

/// Two-scale weights on the card (`system::Prolong`): the first index, the rows (three
/// weights each) and how many.
struct Weights {
    lo: i64,
    rows: CudaSlice<f64>,
    len: u64,
}

impl Device {
    /// Opens the first CUDA device and compiles the solver's kernels for elements of
    /// `degree`. The error says what is missing (driver, device, NVRTC) in words.
    pub fn open(degree: u8) -> Result<Device, String> {
        // SAFETY: only probes whether the shared library can be loaded.
        if !unsafe { cudarc::driver::sys::is_culib_present() } {
            return Err("no NVIDIA driver found (libcuda could not be loaded)".into());
        }
        let count = CudaContext::device_count().map_err(|e| driver("the CUDA driver", e))?;
        if count < 1 {
            return Err("the NVIDIA driver reports no CUDA device".into());
        }
        let ctx = CudaContext::new(0).map_err(|e| driver("opening CUDA device 0", e))?;
        keep_freed_memory(&ctx);
        let name = ctx.name().unwrap_or_else(|_| "CUDA device 0".into());
        let (major, minor) = ctx
            .compute_capability()
            .map_err(|e| driver("reading the compute capability", e))?;
        // SAFETY: as above.
        if !unsafe { cudarc::nvrtc::sys::is_culib_present() } {
            return Err(format!(
                "found {name}, but not NVRTC, the CUDA runtime compiler (libnvrtc), which \
                 compiles spsr's kernels: install the CUDA toolkit or the pip package \
                 nvidia-cuda-nvrtc, and put its lib folder on LD_LIBRARY_PATH"
            ));
        }
        let ptx = compile_ptx_with_opts(
            kernel_source(degree),
            CompileOptions {
                // No fused multiply-adds: each product and sum rounds as on the CPU.
                fmad: Some(false),
                options: vec![format!("--gpu-architecture=compute_{major}{minor}")],
                ..Default::default()
            },
        )
        .map_err(|e| format!("compiling spsr's kernels for {name}: {e:?}"))?;
        let module = ctx
            .load_module(ptx)
            .map_err(|e| driver("loading spsr's kernels", e))?;
        let function = |name: &str| {
            module
                .load_function(name)
                .map_err(|e| driver(&format!("loading the kernel {name}"), e))
        };
        Ok(Device {
            stream: ctx.default_stream(),
            relax: function("relax")?,
            cluster_values: function("cluster_values")?,
            first_right_hand_sides: function("first_right_hand_sides")?,
            cycle_right_hand_side: function("cycle_right_hand_side")?,
            push_finer_v: function("push_finer_v")?,
            constraint_rows: function("constraint_rows")?,
            push_to_parents: function("push_to_parents")?,
            coupling_rows: function("coupling_rows")?,
            coarse_cluster_values: function("coarse_cluster_values")?,
            prolong_solution: function("prolong_solution")?,
            prolong_field: function("prolong_field")?,
            degree,
            name,
            failure: Mutex::new(None),
            timings: Mutex::new(Vec::new()),
            staging: Staging::default(),
            tables: Mutex::new(Vec::new()),
        })
    }

    /// The card's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Notes that a step fell back to the CPU, and why (the first reason is kept).
    pub fn record_failure(&self, reason: String) {
        let mut f = self.failure.lock().unwrap_or_else(|e| e.into_inner());
        f.get_or_insert(reason);
    }

    /// Why a step fell back to the CPU, if one did; clears the record.
    pub fn take_failure(&self) -> Option<String> {
        self.failure
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
    }

    /// Forgets the tables kept on the card ([`Device::tables`]): called before the constraints,
    /// which copy the tree's tables anew.
    pub fn forget_tables(&self) {
        self.tables
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }

    /// The neighbour table of depth `depth`, a copy of `host`: copied by `copy` the first
    /// time, then the same array on the card. The constraints copy each level's neighbour
    /// tables and keys, and the solve reads them again (and each level's as its children's
    /// parent table), so that they cross the bus once. The host array is known by `id`, its
    /// address and length (for the rows a level derives, those of what it derives them from:
    /// `octree::Level::brood_rows_identity`), which cannot change while the tree that holds
    /// them lives; the record is cleared before each run's constraints, so that a later tree
    /// cannot match.
    fn tables(
        &self,
        depth: u32,
        id: (usize, usize),
        copy: impl FnOnce() -> Result<CudaSlice<u32>, DriverError>,
    ) -> Result<Arc<CudaSlice<u32>>, DriverError> {
        let mut tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(t) = tables.iter().find(|t| t.depth == depth && t.host == id) {
            return Ok(t.dev.clone());
        }
        let dev = Arc::new(copy()?);
        tables.push(OnCardTable {
            depth,
            host: id,
            dev: dev.clone(),
        });
        Ok(dev)
    }

    /// The neighbour table and keys of the level `shape` on the card ([`Device::tables`]).
    #[allow(clippy::type_complexity)]
    fn shape_tables(
        &self,
        shape: &LevelShape,
    ) -> Result<(Arc<CudaSlice<u32>>, Arc<CudaSlice<u32>>), DriverError> {
        let s = &self.stream;
        let nbrs = self.tables(shape.depth, shape.brood_nbrs_id, || {
            self.staging.upload(s, shape.brood_nbrs.as_flattened())
        })?;
        let keys = self.tables(shape.depth, slice_id(shape.brood_key), || {
            self.staging.upload(s, shape.brood_key.as_flattened())
        })?;
        Ok((nbrs, keys))
    }

    /// The steps run so far, in order; clears the record.
    pub fn take_timings(&self) -> Vec<GpuRelaxation> {
        std::mem::take(&mut *self.timings.lock().unwrap_or_else(|e| e.into_inner()))
    }

    fn record(&self, step: GpuRelaxation) {
        self.timings
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(step);
    }

    /// Copies the depth's system `sys` to the card, for the solve's right-hand sides and
    /// relaxations of that depth.
    pub fn upload(&self, sys: &LevelSystem) -> Result<Resident, String> {
        if sys.degree != self.degree {
            return Err(format!(
                "the kernels were compiled for degree {}, not {}",
                self.degree, sys.degree
            ));
        }
        let clock = Instant::now();
        let res = self.upload_arrays(sys).map_err(|e| {
            driver(
                &format!("copying depth {} to {}", sys.shape.depth, self.name),
                e,
            )
        })?;
        self.record(GpuRelaxation {
            kind: GpuKernel::Upload,
            depth: sys.shape.depth,
            nodes: res.nodes,
            sweeps: 0,
            transfer: clock.elapsed(),
            kernels: Duration::ZERO,
            bytes_per_sweep: 0,
        });
        Ok(res)
    }

    fn upload_arrays(&self, sys: &LevelSystem) -> Result<Resident, DriverError> {
        let s = &self.stream;
        let (nbrs, keys) = self.shape_tables(&sys.shape)?;
        let parent_depth = sys.shape.depth.saturating_sub(1);
        let parent_nbrs = self.tables(parent_depth, sys.parent_nbrs_id, || {
            self.staging.upload(s, sys.parent_nbrs.as_flattened())
        })?;
        let parent_keys = self.tables(parent_depth, slice_id(sys.parent_keys), || {
            self.staging.upload(s, sys.parent_keys.as_flattened())
        })?;
        let res = Resident {
            depth: sys.shape.depth,
            depth_arg: sys.shape.depth as i32,
            nodes: sys.shape.nodes,
            nodes_arg: sys.shape.nodes as u32,
            clusters: sys.omega.len(),
            clusters_arg: sys.omega.len() as u32,
            lo: sys.shape.lo,
            hi: sys.shape.hi,
            words: sys.rank_bits.len() as u64,
            nbrs,
            keys,
            stencil: self.staging.upload(s, &sys.stencil[..])?,
            brood_start: self.staging.upload(s, &sys.brood_start)?,
            brood_slot: self.staging.upload(s, &sys.brood_slot)?,
            brood_coef: self.staging.upload(s, &sys.brood_coef)?,
            mass: self.staging.upload(s, &sys.mass)?,
            stiff: self.staging.upload(s, &sys.stiff)?,
            rank_bits: self.staging.upload(s, sys.rank_bits)?,
            rank_before: self.staging.upload(s, sys.rank_before)?,
            omega: self.staging.upload(s, sys.omega)?,
            first: self.staging.upload(s, sys.first.as_flattened())?,
            vals: self
                .staging
                .upload(s, sys.vals.as_flattened().as_flattened())?,
            cl_node: self.staging.upload(s, sys.cl_node)?,
            cl_pos: self.staging.upload(s, sys.pos.as_flattened())?,
            boundary: sys.boundary,
            order: self.staging.upload(s, &sys.order)?,
            class_ends: sys.class_ends.clone(),
            brood_parent: self.staging.upload(s, sys.brood_parent)?,
            parent_nbrs,
            parent_keys,
            pstencil: self.staging.upload(s, sys.pstencil.as_flattened())?,
            pvstencil: self
                .staging
                .upload(s, sys.pvstencil.as_flattened().as_flattened())?,
            nonzero_start: self.staging.upload(s, &sys.nonzero_start)?,
            nonzero: self.staging.upload(s, &sys.nonzero)?,
            pmass: self.staging.upload(s, &sys.pmass)?,
            pstiff: self.staging.upload(s, &sys.pstiff)?,
            pvmass: self.staging.upload(s, &sys.pvmass)?,
            pvderiv: self.staging.upload(s, &sys.pvderiv)?,
            prolong: Weights {
                lo: sys.prolong.0,
                rows: self.staging.upload(s, sys.prolong.1.as_flattened())?,
                len: sys.prolong.1.len() as u64,
            },
            vprolong: Weights {
                lo: sys.vprolong.0,
                rows: self.staging.upload(s, sys.vprolong.1.as_flattened())?,
                len: sys.vprolong.1.len() as u64,
            },
            vlo: sys.vrange.0,
            vhi: sys.vrange.1,
            bytes_per_sweep: sys.bytes_per_sweep(),
        };
        s.synchronize()?;
        Ok(res)
    }

    /// `iters` Gauss–Seidel sweeps over the resident depth `lvl` from the coefficients `x`,
    /// with right-hand side `rhs` (per node).
    pub fn gauss_seidel(
        &self,
        lvl: &Resident,
        rhs: &[f32],
        x: &mut [f32],
        iters: u32,
    ) -> Result<(), String> {
        self.sweeps(lvl, rhs, x, iters)
            .map_err(|e| driver(&format!("relaxing depth {} on {}", lvl.depth, self.name), e))
    }

    fn sweeps(
        &self,
        lvl: &Resident,
        rhs: &[f32],
        x: &mut [f32],
        iters: u32,
    ) -> Result<(), DriverError> {
        if x.is_empty() {
            return Ok(());
        }
        let s = &self.stream;
        let clock = Instant::now();
        let rhs_d = self.staging.upload(s, rhs)?;
        let mut x_d = self.staging.upload(s, x)?;
        let mut chi_d = s.alloc_zeros::<f64>(lvl.clusters.max(1))?;
        s.synchronize()?;
        let uploaded = clock.elapsed();
        let clock = Instant::now();
        // χ at the clusters from the starting coefficients (`Op::cluster_values`).
        if lvl.clusters > 0 {
            let mut launch = s.launch_builder(&self.cluster_values);
            launch
                .arg(&lvl.clusters_arg)
                .arg(&lvl.cl_node)
                .arg(&lvl.first)
                .arg(&lvl.vals)
                .arg(&*lvl.nbrs)
                .arg(&*lvl.keys)
                .arg(&lvl.depth_arg)
                .arg(&x_d)
                .arg(&mut chi_d);
            // SAFETY: the arguments match the kernel's parameters in order and type; each
            // cluster's node and window name nodes of the level, and each thread writes its
            // own cluster's value.
            unsafe { launch.launch(config(lvl.clusters_arg)) }?;
        }
        for _ in 0..iters {
            let mut start = 0usize;
            for &end in &lvl.class_ends {
                let count = (end - start) as u32;
                let first_node = start as u64;
                start = end;
                if count == 0 {
                    continue;
                }
                let mut launch = s.launch_builder(&self.relax);
                launch
                    .arg(&lvl.order)
                    .arg(&first_node)
                    .arg(&count)
                    .arg(&*lvl.nbrs)
                    .arg(&*lvl.keys)
                    .arg(&lvl.depth_arg)
                    .arg(&lvl.lo)
                    .arg(&lvl.hi)
                    .arg(&lvl.stencil)
                    .arg(&lvl.brood_start)
                    .arg(&lvl.brood_slot)
                    .arg(&lvl.brood_coef)
                    .arg(&lvl.mass)
                    .arg(&lvl.stiff)
                    .arg(&lvl.rank_bits)
                    .arg(&lvl.rank_before)
                    .arg(&lvl.words)
                    .arg(&lvl.omega)
                    .arg(&lvl.first)
                    .arg(&lvl.vals)
                    .arg(&rhs_d)
                    .arg(&mut x_d)
                    .arg(&mut chi_d);
                // SAFETY: the arguments match the kernel's parameters in order and type, every
                // index the kernel forms stays inside the arrays uploaded (the tree's neighbour
                // tables name only nodes of the level, clusters only clusters), and nodes of
                // one class write disjoint coefficients and cluster values.
                unsafe { launch.launch(config(count)) }?;
            }
        }
        s.synchronize()?;
        let relaxed = clock.elapsed();
        let clock = Instant::now();
        self.staging.download_into(s, &x_d, x)?;
        self.record(GpuRelaxation {
            kind: GpuKernel::Relaxation,
            depth: lvl.depth,
            nodes: lvl.order.len(),
            sweeps: iters,
            transfer: uploaded + clock.elapsed(),
            kernels: relaxed,
            bytes_per_sweep: lvl.bytes_per_sweep,
        });
        Ok(())
    }

    /// The right-hand sides of the cascade's pass over the resident depth `lvl` (see the
    /// kernel `first_right_hand_sides`): `r`, and with `fixed` its fixed part `b` (else
    /// empty). `tcons` are the depth's constraints, `pc` and `vc` the parent depth's
    /// cumulative solution and V; the coarser solution at the depth's clusters is made on the
    /// card from `pc` ([`Device::coarse_chi`]).
    pub fn first_right_hand_sides(
        &self,
        lvl: &Resident,
        tcons: &[f32],
        pc: &[f64],
        vc: &[[f32; 3]],
        fixed: bool,
    ) -> Result<(Vec<f32>, Vec<f32>), String> {
        if lvl.nodes == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let run = || -> Result<(Vec<f32>, Vec<f32>), DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let tcons_d = self.staging.upload(s, tcons)?;
            let pc_d = self.staging.upload(s, pc)?;
            let vc_d = self.staging.upload(s, vc.as_flattened())?;
            let cchi_d = self.coarse_chi(lvl, &pc_d)?;
            let mut r_d = s.alloc_zeros::<f32>(lvl.nodes.max(1))?;
            let mut b_d = s.alloc_zeros::<f32>(if fixed { lvl.nodes.max(1) } else { 1 })?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let clock = Instant::now();
            let null = 0u64;
            let mut launch = s.launch_builder(&self.first_right_hand_sides);
            push_level(&mut launch, lvl);
            launch
                .arg(&tcons_d)
                .arg(&pc_d)
                .arg(&vc_d)
                .arg(&cchi_d)
                .arg(&mut r_d);
            if fixed {
                launch.arg(&mut b_d);
            } else {
                launch.arg(&null);
            }
            // SAFETY: the arguments match the kernel's parameters in order and type (a null
            // `b` when the fixed part is not wanted, which the kernel checks); each thread
            // writes its own node's values, and every index it reads stays in the arrays
            // (parent nodes index `pc` and `vc`, which hold the parent depth's nodes).
            unsafe { launch.launch(config(lvl.nodes_arg)) }?;
            s.synchronize()?;
            let kernels = clock.elapsed();
            let clock = Instant::now();
            let r = self.staging.download(s, &r_d, lvl.nodes)?;
            let b = if fixed {
                self.staging.download(s, &b_d, lvl.nodes)?
            } else {
                Vec::new()
            };
            transfer += clock.elapsed();
            self.record_rhs(lvl, transfer, kernels, pc.len());
            Ok((r, b))
        };
        if pc.len() != vc.len() || tcons.len() != lvl.nodes {
            return Err("the right-hand side's inputs do not match the depth".into());
        }
        run().map_err(|e| {
            driver(
                &format!(
                    "the right-hand sides of depth {} on {}",
                    lvl.depth, self.name
                ),
                e,
            )
        })
    }

    /// The right-hand side a further cycle relaxes the resident depth `lvl` against (see the
    /// kernel `cycle_right_hand_side`): the fixed part `b`, the parent depth's cumulative
    /// solution `pc` (from which the coarser solution at the clusters is made on the card), and
    /// the finer depths' coupling `u` (empty for none).
    pub fn cycle_right_hand_side(
        &self,
        lvl: &Resident,
        b: &[f32],
        pc: &[f64],
        u: &[f64],
    ) -> Result<Vec<f32>, String> {
        if b.len() != lvl.nodes || !(u.is_empty() || u.len() == lvl.nodes) {
            return Err("the right-hand side's inputs do not match the depth".into());
        }
        if lvl.nodes == 0 {
            return Ok(Vec::new());
        }
        let run = || -> Result<Vec<f32>, DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let b_d = self.staging.upload(s, b)?;
            let pc_d = self.staging.upload(s, pc)?;
            let cchi_d = self.coarse_chi(lvl, &pc_d)?;
            let u_d = self.staging.upload(s, u)?;
            let mut r_d = s.alloc_zeros::<f32>(lvl.nodes.max(1))?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let clock = Instant::now();
            let null = 0u64;
            let mut launch = s.launch_builder(&self.cycle_right_hand_side);
            push_level(&mut launch, lvl);
            launch.arg(&b_d).arg(&pc_d).arg(&cchi_d);
            if u.is_empty() {
                launch.arg(&null);
            } else {
                launch.arg(&u_d);
            }
            launch.arg(&mut r_d);
            // SAFETY: as in `first_right_hand_sides`; a null `u` is checked by the kernel.
            unsafe { launch.launch(config(lvl.nodes_arg)) }?;
            s.synchronize()?;
            let kernels = clock.elapsed();
            let clock = Instant::now();
            let r = self.staging.download(s, &r_d, lvl.nodes)?;
            transfer += clock.elapsed();
            self.record_rhs(lvl, transfer, kernels, pc.len());
            Ok(r)
        };
        run().map_err(|e| {
            driver(
                &format!(
                    "the right-hand side of depth {} on {}",
                    lvl.depth, self.name
                ),
                e,
            )
        })
    }

    /// The divergence constraints `T` of one depth (`system::divergence_constraints`), given
    /// what the next finer depth left on the card (`None` for the finest, or to copy the V and
    /// `G` of `sys` instead); also hands back what this depth leaves there for the next
    /// coarser one: its V, and its `G` where the CPU's is not empty. `G` never leaves the card.
    pub fn constraints(
        &self,
        sys: &ConstraintLevel,
        finer: Option<OnCard>,
    ) -> Result<(Vec<f32>, OnCard), String> {
        let broods = sys.shape.nodes / 8;
        let finer_g = finer
            .as_ref()
            .map_or(sys.g_finer.is_some(), |f| f.g.is_some());
        if sys.shape.brood_nbrs.len() != broods
            || !(sys.v.is_empty() || sys.v.len() == sys.shape.nodes)
            || !(sys.children.is_empty() || sys.children.len() == sys.shape.nodes)
            || (sys.push && sys.v_finer.len() != 8 * sys.next_parent.len())
            || (finer_g && sys.children.is_empty())
        {
            return Err("the constraints' inputs do not match the depth".into());
        }
        let keep_g = sys.push || finer_g;
        let run = || -> Result<(Vec<f32>, OnCard), DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let (nbrs, keys) = self.shape_tables(&sys.shape)?;
            let v = self.staging.upload(s, sys.v.as_flattened())?;
            let (finer_v, finer_g) = match finer {
                Some(f) => (Some(f.v), f.g),
                None => (
                    None,
                    sys.g_finer.map(|g| self.staging.upload(s, g)).transpose()?,
                ),
            };
            let mut g = s.alloc_zeros::<f64>(if keep_g { sys.shape.nodes.max(1) } else { 1 })?;
            let mut b = s.alloc_zeros::<f32>(sys.shape.nodes.max(1))?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let mut kernels = Duration::ZERO;
            if sys.push {
                let clock = Instant::now();
                let runs = self.staging.upload(s, sys.push_runs.as_flattened())?;
                let parent = self.staging.upload(s, sys.next_parent)?;
                let v_finer = match finer_v {
                    Some(v) => v,
                    None => self.staging.upload(s, sys.v_finer.as_flattened())?,
                };
                let cvmass = self.staging.upload(s, sys.cvmass.as_flattened())?;
                let cvderiv = self.staging.upload(s, sys.cvderiv.as_flattened())?;
                s.synchronize()?;
                transfer += clock.elapsed();
                let clock = Instant::now();
                let (depth, rows) = (sys.shape.depth as i32, sys.cvmass.len() as u64);
                let mut start = 0usize;
                for &end in &sys.push_run_ends {
                    let (first, count) = (start as u64, (end - start) as u32);
                    start = end;
                    if count == 0 {
                        continue;
                    }
                    let mut launch = s.launch_builder(&self.push_finer_v);
                    launch
                        .arg(&runs)
                        .arg(&first)
                        .arg(&count)
                        .arg(&parent)
                        .arg(&*nbrs)
                        .arg(&*keys)
                        .arg(&depth)
                        .arg(&sys.coarse_lo)
                        .arg(&rows)
                        .arg(&cvmass)
                        .arg(&cvderiv)
                        .arg(&v_finer)
                        .arg(&mut g);
                    // SAFETY: the arguments match the kernel's parameters in order and type;
                    // the runs name broods of the next level, whose parents are nodes of this
                    // one, and the threads of one colour write disjoint entries of `g`.
                    unsafe { launch.launch(config(count)) }?;
                }
                s.synchronize()?;
                kernels += clock.elapsed();
            }
            let clock = Instant::now();
            let vmass = self.staging.upload(s, &sys.vmass)?;
            let vderiv = self.staging.upload(s, &sys.vderiv)?;
            let children = self.staging.upload(s, sys.children)?;
            let (ch_count, ch_j, ch_w) =
                self.child_tables(&sys.child_count, &sys.child_index, &sys.child_weight)?;
            s.synchronize()?;
            transfer += clock.elapsed();
            let clock = Instant::now();
            let null = 0u64;
            let (count, depth, nchildren) = (
                sys.shape.nodes as u32,
                sys.shape.depth as i32,
                sys.children.len() as u64,
            );
            let mut launch = s.launch_builder(&self.constraint_rows);
            launch
                .arg(&count)
                .arg(&*nbrs)
                .arg(&*keys)
                .arg(&depth)
                .arg(&sys.shape.lo)
                .arg(&sys.shape.hi)
                .arg(&vmass)
                .arg(&vderiv)
                .arg(&children)
                .arg(&nchildren)
                .arg(&ch_count)
                .arg(&ch_j)
                .arg(&ch_w);
            // The pushed sums are in `g`: each thread reads its own entry before it writes its
            // `G` there.
            let pushed = i32::from(sys.push);
            launch.arg(&pushed);
            match &finer_g {
                Some(gf) => launch.arg(gf),
                None => launch.arg(&null),
            };
            if sys.v.is_empty() {
                launch.arg(&null);
            } else {
                launch.arg(&v);
            }
            if keep_g {
                launch.arg(&mut g);
            } else {
                launch.arg(&null);
            }
            launch.arg(&mut b);
            // SAFETY: the arguments match the kernel's parameters in order and type (null for
            // the arrays the CPU has empty, which the kernel checks); each thread reads and
            // writes only its own node's `g` and `b`, and every index it forms stays in the
            // arrays (children index the next level's `G`, which has its nodes).
            if count > 0 {
                unsafe { launch.launch(config(count)) }?;
            }
            s.synchronize()?;
            kernels += clock.elapsed();
            let clock = Instant::now();
            let b = self.staging.download(s, &b, sys.shape.nodes)?;
            transfer += clock.elapsed();
            self.record(GpuRelaxation {
                kind: GpuKernel::Constraints,
                depth: sys.shape.depth,
                nodes: sys.shape.nodes,
                sweeps: 1,
                transfer,
                kernels,
                bytes_per_sweep: sys.bytes(),
            });
            let g = keep_g.then_some(g);
            Ok((b, OnCard { v, g }))
        };
        run().map_err(|e| {
            driver(
                &format!(
                    "the constraints of depth {} on {}",
                    sys.shape.depth, self.name
                ),
                e,
            )
        })
    }

    /// χ_{<d} at the clusters of the resident depth `lvl`, made on the card from the parent
    /// depth's cumulative solution `pc` (already there) by the kernel `coarse_cluster_values`
    /// (solver.rs `coarse_cluster_values`). The kernel's time counts with the copies of the
    /// step that asked for it.
    fn coarse_chi(
        &self,
        lvl: &Resident,
        pc: &CudaSlice<f64>,
    ) -> Result<CudaSlice<f64>, DriverError> {
        let s = &self.stream;
        let mut out = s.alloc_zeros::<f64>(lvl.clusters.max(1))?;
        if lvl.clusters > 0 {
            let parent_depth = lvl.depth_arg - 1;
            let mut launch = s.launch_builder(&self.coarse_cluster_values);
            launch
                .arg(&lvl.clusters_arg)
                .arg(&lvl.cl_node)
                .arg(&lvl.cl_pos)
                .arg(&lvl.brood_parent)
                .arg(&*lvl.parent_nbrs)
                .arg(&*lvl.parent_keys)
                .arg(&parent_depth)
                .arg(&lvl.boundary)
                .arg(pc)
                .arg(&mut out);
            // SAFETY: the arguments match the kernel's parameters in order and type; each
            // cluster's node has a parent on the parent depth, whose window names nodes that
            // `pc` holds, and each thread writes its own cluster's value.
            unsafe { launch.launch(config(lvl.clusters_arg)) }?;
        }
        Ok(out)
    }

    /// The cumulative solution of the resident depth `lvl` (solver.rs `prolong_solution`): the
    /// parent depth's `pc` prolonged, plus the depth's coefficients `x`.
    pub fn prolong_solution(
        &self,
        lvl: &Resident,
        pc: &[f64],
        x: &[f32],
    ) -> Result<Vec<f64>, String> {
        if x.len() != lvl.nodes {
            return Err("the prolongation's inputs do not match the depth".into());
        }
        let run = || -> Result<Vec<f64>, DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let pc_d = self.staging.upload(s, pc)?;
            let x_d = self.staging.upload(s, x)?;
            let mut out = s.alloc_zeros::<f64>(lvl.nodes.max(1))?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let clock = Instant::now();
            let w = &lvl.prolong;
            let mut launch = s.launch_builder(&self.prolong_solution);
            launch
                .arg(&lvl.nodes_arg)
                .arg(&*lvl.keys)
                .arg(&lvl.depth_arg)
                .arg(&lvl.lo)
                .arg(&lvl.hi)
                .arg(&lvl.brood_parent)
                .arg(&*lvl.parent_nbrs)
                .arg(&w.rows)
                .arg(&w.lo)
                .arg(&w.len)
                .arg(&pc_d)
                .arg(&x_d)
                .arg(&mut out);
            // SAFETY: the arguments match the kernel's parameters in order and type; parent
            // windows name nodes of the parent depth, which `pc` holds, and each thread writes
            // its own node's value.
            if lvl.nodes > 0 {
                unsafe { launch.launch(config(lvl.nodes_arg)) }?;
            }
            s.synchronize()?;
            let kernels = clock.elapsed();
            let clock = Instant::now();
            let out = self.staging.download(s, &out, lvl.nodes)?;
            transfer += clock.elapsed();
            self.record_prolongation(
                lvl,
                transfer,
                kernels,
                (pc.len() * 8 + lvl.nodes * 12) as u64,
            );
            Ok(out)
        };
        run().map_err(|e| {
            driver(
                &format!("prolonging to depth {} on {}", lvl.depth, self.name),
                e,
            )
        })
    }

    /// The cumulative V of the resident depth `lvl` (solver.rs `prolong_field`): the parent
    /// depth's `vc` prolonged, plus the depth's own V `vt` (empty: none).
    pub fn prolong_field(
        &self,
        lvl: &Resident,
        vc: &[[f32; 3]],
        vt: &[[f32; 3]],
    ) -> Result<Vec<[f32; 3]>, String> {
        if !(vt.is_empty() || vt.len() == lvl.nodes) {
            return Err("the prolongation's inputs do not match the depth".into());
        }
        let run = || -> Result<Vec<[f32; 3]>, DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let vc_d = self.staging.upload(s, vc.as_flattened())?;
            let vt_d = self.staging.upload(s, vt.as_flattened())?;
            let mut out = s.alloc_zeros::<f32>(3 * lvl.nodes.max(1))?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let clock = Instant::now();
            let w = &lvl.vprolong;
            let null = 0u64;
            let mut launch = s.launch_builder(&self.prolong_field);
            launch
                .arg(&lvl.nodes_arg)
                .arg(&*lvl.keys)
                .arg(&lvl.depth_arg)
                .arg(&lvl.vlo)
                .arg(&lvl.vhi)
                .arg(&lvl.brood_parent)
                .arg(&*lvl.parent_nbrs)
                .arg(&w.rows)
                .arg(&w.lo)
                .arg(&w.len)
                .arg(&vc_d);
            if vt.is_empty() {
                launch.arg(&null);
            } else {
                launch.arg(&vt_d);
            }
            launch.arg(&mut out);
            // SAFETY: as in `prolong_solution`, with three values per node (a null `vt` is
            // checked by the kernel).
            if lvl.nodes > 0 {
                unsafe { launch.launch(config(lvl.nodes_arg)) }?;
            }
            s.synchronize()?;
            let kernels = clock.elapsed();
            let clock = Instant::now();
            let flat = self.staging.download(s, &out, 3 * lvl.nodes)?;
            let out: Vec<[f32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            transfer += clock.elapsed();
            let bytes = (vc.len() * 12 + vt.len() * 12 + lvl.nodes * 12) as u64;
            self.record_prolongation(lvl, transfer, kernels, bytes);
            Ok(out)
        };
        run().map_err(|e| {
            driver(
                &format!("prolonging V to depth {} on {}", lvl.depth, self.name),
                e,
            )
        })
    }

    fn record_prolongation(
        &self,
        lvl: &Resident,
        transfer: Duration,
        kernels: Duration,
        bytes: u64,
    ) {
        // Besides the values: per brood its key and parent, per parent brood its neighbours.
        let bytes = bytes + (lvl.nodes / 8 * (12 + 4 + 27 * 4)) as u64;
        self.record(GpuRelaxation {
            kind: GpuKernel::Prolongation,
            depth: lvl.depth,
            nodes: lvl.nodes,
            sweeps: 1,
            transfer,
            kernels,
            bytes_per_sweep: bytes,
        });
    }

    /// The finer depths' coupling of the parent depth of the resident depth `lvl`
    /// (`solver::cycles::coupling_below_of`): `sys.x` pushed into the parents' windows, tile by
    /// tile in the CPU's colours, plus `sys.u` restricted. One value per parent node.
    pub fn coupling(&self, lvl: &Resident, sys: &CouplingLevel) -> Result<Vec<f64>, String> {
        if sys.x.len() != lvl.nodes
            || !(sys.u.is_empty() || sys.u.len() == lvl.nodes)
            || (!sys.u.is_empty() && sys.children.len() != sys.parent.nodes)
            || sys.parent.brood_nbrs.len() != sys.parent.nodes / 8
        {
            return Err("the coupling's inputs do not match the depth".into());
        }
        let run = || -> Result<Vec<f64>, DriverError> {
            let s = &self.stream;
            let clock = Instant::now();
            let (pnbrs, pkeys) = self.shape_tables(&sys.parent)?;
            let x = self.staging.upload(s, sys.x)?;
            let runs = self.staging.upload(s, sys.runs.as_flattened())?;
            let mut g = s.alloc_zeros::<f64>(sys.parent.nodes.max(1))?;
            s.synchronize()?;
            let mut transfer = clock.elapsed();
            let clock = Instant::now();
            let mut start = 0usize;
            for &end in &sys.run_ends {
                let (first, count) = (start as u64, (end - start) as u32);
                start = end;
                if count == 0 {
                    continue;
                }
                let mut launch = s.launch_builder(&self.push_to_parents);
                launch
                    .arg(&runs)
                    .arg(&first)
                    .arg(&count)
                    .arg(&x)
                    .arg(&*lvl.keys)
                    .arg(&lvl.depth_arg)
                    .arg(&lvl.lo)
                    .arg(&lvl.hi)
                    .arg(&lvl.brood_parent)
                    .arg(&*pnbrs)
                    .arg(&lvl.pmass)
                    .arg(&lvl.pstiff)
                    .arg(&mut g);
                // SAFETY: the arguments match the kernel's parameters in order and type; the
                // tiles name broods of the depth, whose parents' windows name nodes of the
                // parent depth, and the tiles of one colour write disjoint entries of `g`.
                unsafe { launch.launch(config(count)) }?;
            }
            s.synchronize()?;
            let mut kernels = clock.elapsed();
            if !sys.u.is_empty() {
                let clock = Instant::now();
                let u = self.staging.upload(s, sys.u)?;
                let children = self.tables(sys.parent.depth, slice_id(sys.children), || {
                    self.staging.upload(s, sys.children)
                })?;
                let (ch_count, ch_j, ch_w) =
                    self.child_tables(&sys.child_count, &sys.child_index, &sys.child_weight)?;
                s.synchronize()?;
                transfer += clock.elapsed();
                let clock = Instant::now();
                let (count, depth, nchildren) = (
                    sys.parent.nodes as u32,
                    sys.parent.depth as i32,
                    sys.children.len() as u64,
                );
                let mut launch = s.launch_builder(&self.coupling_rows);
                launch
                    .arg(&count)
                    .arg(&*pnbrs)
                    .arg(&*pkeys)
                    .arg(&depth)
                    .arg(&sys.parent.lo)
                    .arg(&sys.parent.hi)
                    .arg(&*children)
                    .arg(&nchildren)
                    .arg(&ch_count)
                    .arg(&ch_j)
                    .arg(&ch_w)
                    .arg(&u)
                    .arg(&mut g);
                // SAFETY: the arguments match the kernel's parameters in order and type; each
                // thread writes its own node's `g`, and children index the depth's nodes, which
                // `u` holds.
                if count > 0 {
                    unsafe { launch.launch(config(count)) }?;
                }
                s.synchronize()?;
                kernels += clock.elapsed();
            }
            let clock = Instant::now();
            let g = self.staging.download(s, &g, sys.parent.nodes)?;
            transfer += clock.elapsed();
            self.record(GpuRelaxation {
                kind: GpuKernel::Coupling,
                depth: lvl.depth,
                nodes: lvl.nodes,
                sweeps: 1,
                transfer,
                kernels,
                bytes_per_sweep: sys.bytes(),
            });
            Ok(g)
        };
        run().map_err(|e| {
            driver(
                &format!("the coupling below depth {} on {}", lvl.depth, self.name),
                e,
            )
        })
    }

    /// The two-scale children tables that `restrict_one` reads, on the card.
    #[allow(clippy::type_complexity)]
    fn child_tables(
        &self,
        count: &[u32],
        index: &[i64],
        weight: &[f64],
    ) -> Result<(CudaSlice<u32>, CudaSlice<i64>, CudaSlice<f64>), DriverError> {
        let s = &self.stream;
        Ok((
            self.staging.upload(s, count)?,
            self.staging.upload(s, index)?,
            self.staging.upload(s, weight)?,
        ))
    }

    fn record_rhs(&self, lvl: &Resident, transfer: Duration, kernels: Duration, parents: usize) {
        // Per node its constraint (or fixed part) and result; per brood its neighbours, key
        // and parent; per parent brood its neighbours, per parent node its solution and V; per
        // cluster its data and χ_{<d}.
        let (broods, parent_broods) = (lvl.nodes / 8, parents / 8);
        let bytes = (lvl.nodes * (4 + 4)
            + broods * (27 * 4 + 12 + 4)
            + parent_broods * 27 * 4
            + parents * (8 + 12)
            + lvl.clusters * (8 + 12 + 36 + 8)) as u64;
        self.record(GpuRelaxation {
            kind: GpuKernel::RightHandSide,
            depth: lvl.depth,
            nodes: lvl.nodes,
            sweeps: 1,
            transfer,
            kernels,
            bytes_per_sweep: bytes,
        });
    }
}

/// What one depth's constraints leave on the card for the next coarser depth's
/// ([`Device::constraints`]): the depth's V, and its `G` where it has one.
pub struct OnCard {
    v: CudaSlice<f32>,
    g: Option<CudaSlice<f64>>,
}

/// The arguments the two right-hand-side kernels share, in their order: the depth, its
/// clusters and its parent depth.
fn push_level<'a>(launch: &mut LaunchArgs<'a>, lvl: &'a Resident) {
    launch
        .arg(&lvl.nodes_arg)
        .arg(&*lvl.nbrs)
        .arg(&*lvl.keys)
        .arg(&lvl.depth_arg)
        .arg(&lvl.lo)
        .arg(&lvl.hi)
        .arg(&lvl.rank_bits)
        .arg(&lvl.rank_before)
        .arg(&lvl.words)
        .arg(&lvl.omega)
        .arg(&lvl.first)
        .arg(&lvl.vals)
        .arg(&lvl.brood_parent)
        .arg(&*lvl.parent_nbrs)
        .arg(&lvl.pstencil)
        .arg(&lvl.pvstencil)
        .arg(&lvl.nonzero_start)
        .arg(&lvl.nonzero)
        .arg(&lvl.pmass)
        .arg(&lvl.pstiff)
        .arg(&lvl.pvmass)
        .arg(&lvl.pvderiv);
}

/// One thread per item.
fn config(count: u32) -> LaunchConfig {
    LaunchConfig {
        grid_dim: (count.div_ceil(BLOCK), 1, 1),
        block_dim: (BLOCK, 1, 1),
        shared_mem_bytes: 0,
    }
}

/// Lets the card's memory pool keep the memory of freed arrays for the next allocation,
/// instead of handing it back to the driver at every synchronisation (the default): each
/// depth allocates and frees arrays of the same sizes over and over. Without a pool (old
/// drivers) nothing changes, so a failure here is ignored.
fn keep_freed_memory(ctx: &Arc<CudaContext>) {
    use cudarc::driver::sys;
    let mut pool = std::mem::MaybeUninit::<sys::CUmemoryPool>::uninit();
    // SAFETY: the driver writes the device's default pool into `pool` on success, and only
    // then is it read; the attribute's value is a u64, as the driver expects.
    unsafe {
        if sys::cuDeviceGetDefaultMemPool(pool.as_mut_ptr(), ctx.cu_device())
            .result()
            .is_ok()
        {
            let mut threshold = u64::MAX;
            let _ = sys::cuMemPoolSetAttribute(
                pool.assume_init(),
                sys::CUmemPool_attribute::CU_MEMPOOL_ATTR_RELEASE_THRESHOLD,
                (&mut threshold as *mut u64).cast(),
            );
        }
    }
}

fn driver(what: &str, e: DriverError) -> String {
    format!("{what}: CUDA error {e}")
}

/// A host array's address and length, which name its copy on the card ([`Device::tables`]).
fn slice_id<T>(host: &[T]) -> (usize, usize) {
    (host.as_ptr() as usize, host.len())
}
