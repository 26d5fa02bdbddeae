//! The CUDA device: opening it (driver, card, NVRTC, kernel) and relaxing one level on it.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use cudarc::driver::{
    CudaContext, CudaFunction, CudaSlice, CudaStream, DeviceRepr, DriverError, LaunchConfig,
    PushKernelArg,
};
use cudarc::nvrtc::{compile_ptx_with_opts, CompileOptions};

use super::{kernel_source, GpuRelaxation, LevelSystem};

/// Threads per block of the relaxation kernel.
const BLOCK: u32 = 256;

/// An opened NVIDIA GPU with the relaxation kernel compiled for it.
pub struct Device {
    stream: Arc<CudaStream>,
    relax: CudaFunction,
    /// Degree of the elements the kernel was compiled for.
    degree: u8,
    name: String,
    /// Why a level fell back to the CPU, if one did (the first reason).
    failure: Mutex<Option<String>>,
    /// The relaxations run so far.
    timings: Mutex<Vec<GpuRelaxation>>,
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Device").field("name", &self.name).finish()
    }
}

impl Device {
    /// Opens the first CUDA device and compiles the relaxation kernel for elements of
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
        let relax = module
            .load_function("relax")
            .map_err(|e| driver("loading the relaxation kernel", e))?;
        Ok(Device {
            stream: ctx.default_stream(),
            relax,
            degree,
            name,
            failure: Mutex::new(None),
            timings: Mutex::new(Vec::new()),
        })
    }

    /// The card's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Notes that a level fell back to the CPU, and why (the first reason is kept).
    pub fn record_failure(&self, reason: String) {
        let mut f = self.failure.lock().unwrap_or_else(|e| e.into_inner());
        f.get_or_insert(reason);
    }

    /// Why a level fell back to the CPU, if one did; clears the record.
    pub fn take_failure(&self) -> Option<String> {
        self.failure
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
    }

    /// The relaxations run so far, in order; clears the record.
    pub fn take_timings(&self) -> Vec<GpuRelaxation> {
        std::mem::take(&mut *self.timings.lock().unwrap_or_else(|e| e.into_inner()))
    }

    /// `iters` Gauss–Seidel sweeps over `sys` from the coefficients `x`, with right-hand side
    /// `rhs` (per node) and χ at the clusters `chi` (which the sweeps keep up to date).
    pub fn gauss_seidel(
        &self,
        sys: &LevelSystem,
        rhs: &[f64],
        x: &mut [f32],
        chi: &[f64],
        iters: u32,
    ) -> Result<(), String> {
        if sys.degree != self.degree {
            return Err(format!(
                "the kernel was compiled for degree {}, not {}",
                self.degree, sys.degree
            ));
        }
        self.sweeps(sys, rhs, x, chi, iters)
            .map_err(|e| driver(&format!("relaxing depth {} on {}", sys.depth, self.name), e))
    }

    fn sweeps(
        &self,
        sys: &LevelSystem,
        rhs: &[f64],
        x: &mut [f32],
        chi: &[f64],
        iters: u32,
    ) -> Result<(), DriverError> {
        if x.is_empty() {
            return Ok(());
        }
        let s = &self.stream;
        let clock = Instant::now();
        let nbrs = upload(s, sys.brood_nbrs.as_flattened())?;
        let keys = upload(s, sys.brood_key.as_flattened())?;
        let stencil = upload(s, &sys.stencil[..])?;
        let mass = upload(s, &sys.mass)?;
        let stiff = upload(s, &sys.stiff)?;
        let rank_bits = upload(s, sys.rank_bits)?;
        let rank_before = upload(s, sys.rank_before)?;
        let omega = upload(s, sys.omega)?;
        let first = upload(s, sys.first.as_flattened())?;
        let vals = upload(s, sys.vals.as_flattened().as_flattened())?;
        let order = upload(s, &sys.order)?;
        let rhs_d = upload(s, rhs)?;
        let mut x_d = upload(s, x)?;
        let mut chi_d = upload(s, chi)?;
        let depth = sys.depth as i32;
        let words = sys.rank_bits.len() as u64;
        s.synchronize()?;
        let uploaded = clock.elapsed();
        let clock = Instant::now();
        for _ in 0..iters {
            let mut start = 0usize;
            for &end in &sys.class_ends {
                let count = (end - start) as u32;
                let first_node = start as u64;
                start = end;
                if count == 0 {
                    continue;
                }
                let cfg = LaunchConfig {
                    grid_dim: (count.div_ceil(BLOCK), 1, 1),
                    block_dim: (BLOCK, 1, 1),
                    shared_mem_bytes: 0,
                };
                let mut launch = s.launch_builder(&self.relax);
                launch
                    .arg(&order)
                    .arg(&first_node)
                    .arg(&count)
                    .arg(&nbrs)
                    .arg(&keys)
                    .arg(&depth)
                    .arg(&sys.lo)
                    .arg(&sys.hi)
                    .arg(&stencil)
                    .arg(&mass)
                    .arg(&stiff)
                    .arg(&rank_bits)
                    .arg(&rank_before)
                    .arg(&words)
                    .arg(&omega)
                    .arg(&first)
                    .arg(&vals)
                    .arg(&rhs_d)
                    .arg(&mut x_d)
                    .arg(&mut chi_d);
                // SAFETY: the arguments match the kernel's parameters in order and type, every
                // index the kernel forms stays inside the arrays uploaded above (the tree's
                // neighbour tables name only nodes of the level, clusters only clusters), and
                // nodes of one class write disjoint coefficients and cluster values.
                unsafe { launch.launch(cfg) }?;
            }
        }
        s.synchronize()?;
        let relaxed = clock.elapsed();
        s.memcpy_dtoh(&x_d, &mut x[..])?;
        s.synchronize()?;
        self.timings
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(GpuRelaxation {
                depth: sys.depth,
                nodes: sys.order.len(),
                sweeps: iters,
                transfer: uploaded,
                kernels: relaxed,
                bytes_per_sweep: sys.bytes_per_sweep(),
            });
        Ok(())
    }
}

/// Copies `host` to a new device array (one element when empty: CUDA allocates no zero-size
/// arrays, and the kernel never reads an empty one).
fn upload<T: DeviceRepr + Default + Clone>(
    s: &Arc<CudaStream>,
    host: &[T],
) -> Result<CudaSlice<T>, DriverError> {
    if host.is_empty() {
        s.clone_htod(&[T::default()][..])
    } else {
        s.clone_htod(host)
    }
}

fn driver(what: &str, e: DriverError) -> String {
    format!("{what}: CUDA error {e}")
}
