//! The GPU kernels run on the CPU: `gpu/kernels.cu`, compiled as C++ by the host's compiler
//! with a thin shim for CUDA's names, each kernel called once per thread index in the order the
//! device launches them, and the results compared bit for bit with the solver's own CPU code.
//!
//! This checks the kernels' arithmetic and indexing on any machine with a C++ compiler, with
//! no GPU (CI has none); `tests::the_gpu_gives_the_cpus_bits` checks the same on a card, with
//! the copies and launches of `gpu/cuda.rs`. Floating-point contraction is off on both sides
//! (`-ffp-contract=off` here, `--fmad=false` on the card), so each product and sum rounds once.

use std::path::{Path, PathBuf};

use super::device::constraint_level;
use super::tests::{fixtures, pseudo_random, right_hand_side_inputs};
use super::{coarse_cluster_values, cycles, prolong_field, prolong_solution, right_hand_side, Op};
use crate::gpu::{kernel_source, ConstraintLevel, CouplingLevel, LevelSystem};
use crate::system::divergence_constraints;

/// What CUDA provides and C++ does not: the qualifiers, the thread index (set before each
/// call, one thread per block) and the bit intrinsics.
const SHIM: &str = r#"
#include <math.h>
#define __global__
#define __device__
#define __forceinline__ inline
#define __restrict__ __restrict
#define __constant__ static const
struct Dim3 { unsigned x, y, z; };
static Dim3 blockIdx = {0, 0, 0}, threadIdx = {0, 0, 0};
static const Dim3 blockDim = {1, 1, 1};
extern "C" void spsr_thread(unsigned t) { blockIdx.x = t; }
static inline int __popcll(unsigned long long v) { return __builtin_popcountll(v); }
static inline int __popc(unsigned v) { return __builtin_popcount(v); }
static inline int __ffs(unsigned v) { return __builtin_ffs((int)v); }
"#;

type Thread = unsafe extern "C" fn(u32);
type Relax = unsafe extern "C" fn(
    *const u32,
    u64,
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const f64,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const f64,
    *const u64,
    *const u32,
    u64,
    *const f64,
    *const i32,
    *const f32,
    *const f32,
    *mut f32,
    *mut f64,
);
type ClusterValues = unsafe extern "C" fn(
    u32,
    *const u32,
    *const i32,
    *const f32,
    *const u32,
    *const u32,
    i32,
    *const f32,
    *mut f64,
);
/// The arguments the two right-hand-side kernels share (`cuda.rs` `push_level`).
type Level = (
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u64,
    *const u32,
    u64,
    *const f64,
    *const i32,
    *const f32,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const f64,
    *const f64,
);
type FirstRhs = unsafe extern "C" fn(
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u64,
    *const u32,
    u64,
    *const f64,
    *const i32,
    *const f32,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const f64,
    *const f64,
    *const f32,
    *const f64,
    *const f32,
    *const f64,
    *mut f32,
    *mut f32,
);
type CycleRhs = unsafe extern "C" fn(
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u64,
    *const u32,
    u64,
    *const f64,
    *const i32,
    *const f32,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *const f64,
    *const f64,
    *const f32,
    *const f64,
    *const f64,
    *const f64,
    *mut f32,
);

type PushFinerV = unsafe extern "C" fn(
    *const u32,
    u64,
    u32,
    *const u32,
    *const u32,
    *const u32,
    i32,
    i64,
    u64,
    *const f64,
    *const f64,
    *const f32,
    *mut f64,
);
type ConstraintRows = unsafe extern "C" fn(
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const f64,
    *const f64,
    *const u32,
    u64,
    *const u32,
    *const i64,
    *const f64,
    i32,
    *const f64,
    *const f32,
    *mut f64,
    *mut f32,
);

type PushToParents = unsafe extern "C" fn(
    *const u32,
    u64,
    u32,
    *const f32,
    *const u32,
    i32,
    i64,
    i64,
    *const u32,
    *const u32,
    *const f64,
    *const f64,
    *mut f64,
);
type CouplingRows = unsafe extern "C" fn(
    u32,
    *const u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u32,
    u64,
    *const u32,
    *const i64,
    *const f64,
    *const f64,
    *mut f64,
);

type CoarseClusterValues = unsafe extern "C" fn(
    u32,
    *const u32,
    *const f64,
    *const u32,
    *const u32,
    *const u32,
    i32,
    i32,
    *const f64,
    *mut f64,
);

type ProlongSolution = unsafe extern "C" fn(
    u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u32,
    *const u32,
    *const f64,
    i64,
    u64,
    *const f64,
    *const f32,
    *mut f64,
);
type ProlongField = unsafe extern "C" fn(
    u32,
    *const u32,
    i32,
    i64,
    i64,
    *const u32,
    *const u32,
    *const f64,
    i64,
    u64,
    *const f32,
    *const f32,
    *mut f32,
);

/// The kernels of one degree, compiled for the host and loaded.
struct Kernels {
    lib: libloading::Library,
    _dir: TempDir,
}

struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl Kernels {
    /// Compiles the kernels for `degree`; `Err` says why they cannot be (no compiler here).
    fn build(degree: u8) -> Result<Kernels, String> {
        let dir = std::env::temp_dir().join(format!(
            "spsr-kernels-{}-{degree}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let dir = TempDir(dir);
        let src = dir.0.join("kernels.cpp");
        std::fs::write(&src, format!("{SHIM}\n{}", kernel_source(degree)))
            .map_err(|e| e.to_string())?;
        let lib = dir.0.join("kernels.so");
        compile(&src, &lib)?;
        // SAFETY: the library is the kernels just compiled; loading runs no initialisers but
        // the shim's static data.
        let lib = unsafe { libloading::Library::new(&lib) }.map_err(|e| e.to_string())?;
        Ok(Kernels { lib, _dir: dir })
    }

    /// [`Kernels::build`], or `None` with a message where no C++ compiler can be found; a
    /// kernel source that does not compile fails the test.
    fn build_or_skip(degree: u8) -> Option<Kernels> {
        match Kernels::build(degree) {
            Ok(k) => Some(k),
            Err(reason) => {
                assert!(!reason.contains("do not compile"), "{reason}");
                eprintln!("skipped: {reason}");
                None
            }
        }
    }

    fn get<T: Copy>(&self, name: &str) -> T {
        // SAFETY: each name is one of the kernels (or the shim's setter), and the caller's type
        // is its signature, written out above from `kernels.cu`.
        unsafe { *self.lib.get::<T>(name.as_bytes()).expect(name) }
    }

    /// Runs `f` once per thread index `0..count`.
    fn threads(&self, count: usize, mut f: impl FnMut()) {
        let set: Thread = self.get("spsr_thread");
        for t in 0..count {
            // SAFETY: sets the shim's thread index.
            unsafe { set(t as u32) };
            f();
        }
    }
}

fn compile(src: &Path, lib: &Path) -> Result<(), String> {
    let out = std::process::Command::new("c++")
        .args([
            "-std=c++17",
            "-O2",
            "-ffp-contract=off",
            "-fPIC",
            "-shared",
            "-x",
            "c++",
        ])
        .arg(src)
        .arg("-o")
        .arg(lib)
        .output()
        .map_err(|e| format!("no C++ compiler (c++): {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "the kernels do not compile as C++:\n{}",
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

/// The shared arguments of the right-hand-side kernels for `sys`.
fn level_args(sys: &LevelSystem) -> Level {
    (
        sys.shape.nodes as u32,
        sys.shape.brood_nbrs.as_flattened().as_ptr(),
        sys.shape.brood_key.as_flattened().as_ptr(),
        sys.shape.depth as i32,
        sys.shape.lo,
        sys.shape.hi,
        sys.rank_bits.as_ptr(),
        sys.rank_before.as_ptr(),
        sys.rank_bits.len() as u64,
        sys.omega.as_ptr(),
        sys.first.as_flattened().as_ptr(),
        sys.vals.as_flattened().as_flattened().as_ptr(),
        sys.brood_parent.as_ptr(),
        sys.parent_nbrs.as_flattened().as_ptr(),
        sys.pstencil.as_flattened().as_ptr(),
        sys.pvstencil.as_flattened().as_flattened().as_ptr(),
        sys.nonzero_start.as_ptr(),
        sys.nonzero.as_ptr(),
        sys.pmass.as_ptr(),
        sys.pstiff.as_ptr(),
        sys.pvmass.as_ptr(),
        sys.pvderiv.as_ptr(),
    )
}

/// The emulated `Device::first_right_hand_sides` (with the fixed part).
fn first_right_hand_sides(
    k: &Kernels,
    sys: &LevelSystem,
    tcons: &[f32],
    pc: &[f64],
    vc: &[[f32; 3]],
    cchi: &[f64],
) -> (Vec<f32>, Vec<f32>) {
    let f: FirstRhs = k.get("first_right_hand_sides");
    let a = level_args(sys);
    let mut r = vec![f32::NAN; sys.shape.nodes];
    let mut b = vec![f32::NAN; sys.shape.nodes];
    let (rp, bp) = (r.as_mut_ptr(), b.as_mut_ptr());
    k.threads(sys.shape.nodes, || {
        // SAFETY: the arguments are the kernel's, over arrays of the sizes it indexes.
        unsafe {
            f(
                a.0,
                a.1,
                a.2,
                a.3,
                a.4,
                a.5,
                a.6,
                a.7,
                a.8,
                a.9,
                a.10,
                a.11,
                a.12,
                a.13,
                a.14,
                a.15,
                a.16,
                a.17,
                a.18,
                a.19,
                a.20,
                a.21,
                tcons.as_ptr(),
                pc.as_ptr(),
                vc.as_flattened().as_ptr(),
                cchi.as_ptr(),
                rp,
                bp,
            )
        }
    });
    (r, b)
}

/// The emulated `Device::cycle_right_hand_side`.
fn cycle_right_hand_side(
    k: &Kernels,
    sys: &LevelSystem,
    b: &[f32],
    pc: &[f64],
    cchi: &[f64],
    u: &[f64],
) -> Vec<f32> {
    let f: CycleRhs = k.get("cycle_right_hand_side");
    let a = level_args(sys);
    let mut r = vec![f32::NAN; sys.shape.nodes];
    let rp = r.as_mut_ptr();
    let up = if u.is_empty() {
        std::ptr::null()
    } else {
        u.as_ptr()
    };
    k.threads(sys.shape.nodes, || {
        // SAFETY: as in `first_right_hand_sides`; a null `u` is checked by the kernel.
        unsafe {
            f(
                a.0,
                a.1,
                a.2,
                a.3,
                a.4,
                a.5,
                a.6,
                a.7,
                a.8,
                a.9,
                a.10,
                a.11,
                a.12,
                a.13,
                a.14,
                a.15,
                a.16,
                a.17,
                a.18,
                a.19,
                a.20,
                a.21,
                b.as_ptr(),
                pc.as_ptr(),
                cchi.as_ptr(),
                up,
                rp,
            )
        }
    });
    r
}

/// The emulated `Device::coarse_chi` (made on the card): χ_{<d} at the level's clusters from
/// the parent level's cumulative solution `pc`.
fn coarse_chi(k: &Kernels, sys: &LevelSystem, pc: &[f64]) -> Vec<f64> {
    let f: CoarseClusterValues = k.get("coarse_cluster_values");
    let mut out = vec![f64::NAN; sys.omega.len()];
    let op = out.as_mut_ptr();
    k.threads(sys.omega.len(), || {
        // SAFETY: the kernel's arguments; each thread writes its own cluster's value.
        unsafe {
            f(
                sys.omega.len() as u32,
                sys.cl_node.as_ptr(),
                sys.pos.as_flattened().as_ptr(),
                sys.brood_parent.as_ptr(),
                sys.parent_nbrs.as_flattened().as_ptr(),
                sys.parent_keys.as_flattened().as_ptr(),
                sys.shape.depth as i32 - 1,
                sys.boundary,
                pc.as_ptr(),
                op,
            )
        }
    });
    out
}

/// The emulated `Device::prolong_solution`.
fn prolong_solution_kernel(k: &Kernels, sys: &LevelSystem, pc: &[f64], x: &[f32]) -> Vec<f64> {
    let f: ProlongSolution = k.get("prolong_solution");
    let mut out = vec![f64::NAN; sys.shape.nodes];
    let op = out.as_mut_ptr();
    k.threads(sys.shape.nodes, || {
        // SAFETY: the kernel's arguments; each thread writes its own node's value.
        unsafe {
            f(
                sys.shape.nodes as u32,
                sys.shape.brood_key.as_flattened().as_ptr(),
                sys.shape.depth as i32,
                sys.shape.lo,
                sys.shape.hi,
                sys.brood_parent.as_ptr(),
                sys.parent_nbrs.as_flattened().as_ptr(),
                sys.prolong.1.as_flattened().as_ptr(),
                sys.prolong.0,
                sys.prolong.1.len() as u64,
                pc.as_ptr(),
                x.as_ptr(),
                op,
            )
        }
    });
    out
}

/// The emulated `Device::prolong_field`.
fn prolong_field_kernel(
    k: &Kernels,
    sys: &LevelSystem,
    vc: &[[f32; 3]],
    vt: &[[f32; 3]],
) -> Vec<[f32; 3]> {
    let f: ProlongField = k.get("prolong_field");
    let mut out = vec![[f32::NAN; 3]; sys.shape.nodes];
    let op = out.as_flattened_mut().as_mut_ptr();
    let vtp = if vt.is_empty() {
        std::ptr::null()
    } else {
        vt.as_flattened().as_ptr()
    };
    k.threads(sys.shape.nodes, || {
        // SAFETY: the kernel's arguments (a null `vt` for none); each thread writes its own
        // node's values.
        unsafe {
            f(
                sys.shape.nodes as u32,
                sys.shape.brood_key.as_flattened().as_ptr(),
                sys.shape.depth as i32,
                sys.vrange.0,
                sys.vrange.1,
                sys.brood_parent.as_ptr(),
                sys.parent_nbrs.as_flattened().as_ptr(),
                sys.vprolong.1.as_flattened().as_ptr(),
                sys.vprolong.0,
                sys.vprolong.1.len() as u64,
                vc.as_flattened().as_ptr(),
                vtp,
                op,
            )
        }
    });
    out
}

/// The emulated `Device::gauss_seidel`: χ at the clusters, then the sweeps class by class.
fn gauss_seidel(k: &Kernels, sys: &LevelSystem, rhs: &[f32], x: &mut [f32], iters: u32) {
    let values: ClusterValues = k.get("cluster_values");
    let relax: Relax = k.get("relax");
    let mut chi = vec![f64::NAN; sys.omega.len()];
    let (xp, cp) = (x.as_mut_ptr(), chi.as_mut_ptr());
    let nbrs = sys.shape.brood_nbrs.as_flattened().as_ptr();
    let keys = sys.shape.brood_key.as_flattened().as_ptr();
    let (first, vals) = (
        sys.first.as_flattened().as_ptr(),
        sys.vals.as_flattened().as_flattened().as_ptr(),
    );
    k.threads(sys.omega.len(), || {
        // SAFETY: the kernel's arguments; each thread writes its own cluster's χ.
        unsafe {
            values(
                sys.omega.len() as u32,
                sys.cl_node.as_ptr(),
                first,
                vals,
                nbrs,
                keys,
                sys.shape.depth as i32,
                xp,
                cp,
            )
        }
    });
    for _ in 0..iters {
        let mut start = 0usize;
        for &end in &sys.class_ends {
            let count = end - start;
            k.threads(count, || {
                // SAFETY: the kernel's arguments, over arrays of the sizes it indexes.
                unsafe {
                    relax(
                        sys.order.as_ptr(),
                        start as u64,
                        count as u32,
                        nbrs,
                        keys,
                        sys.shape.depth as i32,
                        sys.shape.lo,
                        sys.shape.hi,
                        sys.stencil.as_ptr(),
                        sys.brood_start.as_ptr(),
                        sys.brood_slot.as_ptr(),
                        sys.brood_coef.as_ptr(),
                        sys.mass.as_ptr(),
                        sys.stiff.as_ptr(),
                        sys.rank_bits.as_ptr(),
                        sys.rank_before.as_ptr(),
                        sys.rank_bits.len() as u64,
                        sys.omega.as_ptr(),
                        first,
                        vals,
                        rhs.as_ptr(),
                        xp,
                        cp,
                    )
                }
            });
            start = end;
        }
    }
}

/// The emulated `Device::constraints`: the tiles colour by colour, then the rows.
fn constraints(k: &Kernels, sys: &ConstraintLevel) -> (Vec<f64>, Vec<f32>) {
    let push: PushFinerV = k.get("push_finer_v");
    let rows: ConstraintRows = k.get("constraint_rows");
    let keep_g = sys.push || sys.g_finer.is_some();
    let mut g = vec![0.0f64; if keep_g { sys.shape.nodes } else { 0 }];
    let mut b = vec![f32::NAN; sys.shape.nodes];
    let gp = if keep_g {
        g.as_mut_ptr()
    } else {
        std::ptr::null_mut()
    };
    let nbrs = sys.shape.brood_nbrs.as_flattened().as_ptr();
    let keys = sys.shape.brood_key.as_flattened().as_ptr();
    if sys.push {
        let mut start = 0usize;
        for &end in &sys.push_run_ends {
            let count = end - start;
            k.threads(count, || {
                // SAFETY: the kernel's arguments, over arrays of the sizes it indexes.
                unsafe {
                    push(
                        sys.push_runs.as_flattened().as_ptr(),
                        start as u64,
                        count as u32,
                        sys.next_parent.as_ptr(),
                        nbrs,
                        keys,
                        sys.shape.depth as i32,
                        sys.coarse_lo,
                        sys.cvmass.len() as u64,
                        sys.cvmass.as_flattened().as_ptr(),
                        sys.cvderiv.as_flattened().as_ptr(),
                        sys.v_finer.as_flattened().as_ptr(),
                        gp,
                    )
                }
            });
            start = end;
        }
    }
    let or_null = |empty: bool, p: *const f32| if empty { std::ptr::null() } else { p };
    let vp = or_null(sys.v.is_empty(), sys.v.as_flattened().as_ptr());
    let gf = sys.g_finer.map_or(std::ptr::null(), |g| g.as_ptr());
    let bp = b.as_mut_ptr();
    k.threads(sys.shape.nodes, || {
        // SAFETY: the kernel's arguments (null for the arrays the CPU has empty); each thread
        // writes its own node's values.
        unsafe {
            rows(
                sys.shape.nodes as u32,
                nbrs,
                keys,
                sys.shape.depth as i32,
                sys.shape.lo,
                sys.shape.hi,
                sys.vmass.as_ptr(),
                sys.vderiv.as_ptr(),
                sys.children.as_ptr(),
                sys.children.len() as u64,
                sys.child_count.as_ptr(),
                sys.child_index.as_ptr(),
                sys.child_weight.as_ptr(),
                i32::from(sys.push),
                gf,
                vp,
                gp,
                bp,
            )
        }
    });
    (g, b)
}

/// The emulated `Device::coupling`: the tiles colour by colour, then the rows when there is a
/// finer coupling to restrict. `lvl` is the depth's system (for its keys, parents and parent
/// stencils).
fn coupling(k: &Kernels, lvl: &LevelSystem, sys: &CouplingLevel) -> Vec<f64> {
    let push: PushToParents = k.get("push_to_parents");
    let rows: CouplingRows = k.get("coupling_rows");
    let mut g = vec![0.0f64; sys.parent.nodes];
    let gp = g.as_mut_ptr();
    let pnbrs = sys.parent.brood_nbrs.as_flattened().as_ptr();
    let mut start = 0usize;
    for &end in &sys.run_ends {
        let count = end - start;
        k.threads(count, || {
            // SAFETY: the kernel's arguments, over arrays of the sizes it indexes.
            unsafe {
                push(
                    sys.runs.as_flattened().as_ptr(),
                    start as u64,
                    count as u32,
                    sys.x.as_ptr(),
                    lvl.shape.brood_key.as_flattened().as_ptr(),
                    lvl.shape.depth as i32,
                    lvl.shape.lo,
                    lvl.shape.hi,
                    lvl.brood_parent.as_ptr(),
                    pnbrs,
                    lvl.pmass.as_ptr(),
                    lvl.pstiff.as_ptr(),
                    gp,
                )
            }
        });
        start = end;
    }
    if !sys.u.is_empty() {
        k.threads(sys.parent.nodes, || {
            // SAFETY: the kernel's arguments; each thread writes its own node's value.
            unsafe {
                rows(
                    sys.parent.nodes as u32,
                    pnbrs,
                    sys.parent.brood_key.as_flattened().as_ptr(),
                    sys.parent.depth as i32,
                    sys.parent.lo,
                    sys.parent.hi,
                    sys.children.as_ptr(),
                    sys.children.len() as u64,
                    sys.child_count.as_ptr(),
                    sys.child_index.as_ptr(),
                    sys.child_weight.as_ptr(),
                    sys.u.as_ptr(),
                    gp,
                )
            }
        });
    }
    g
}

/// Asserts that `a` and `b` hold the same bits, naming the first difference and their count.
fn same_bits(a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let differ: Vec<usize> = (0..a.len())
        .filter(|&k| a[k].to_bits() != b[k].to_bits())
        .collect();
    if let Some(&k) = differ.first() {
        panic!(
            "{what}: {} of {} values differ, the first at {k}: {} (solver) vs {} (kernel)",
            differ.len(),
            a.len(),
            a[k],
            b[k]
        );
    }
}

fn as_f32(v: Vec<f64>) -> Vec<f32> {
    v.iter().map(|&x| x as f32).collect()
}

/// The kernels, run on the CPU in the device's launch order, give the solver's right-hand
/// sides (the cascade's, with their fixed part, and a further cycle's, with and without the
/// finer levels' coupling) and its Gauss–Seidel sweeps bit for bit, on every level of every
/// fixture (degrees 1 and 2, each boundary). Skipped, with a message, without a C++ compiler.
#[test]
fn the_gpu_kernels_run_on_the_cpu_give_the_solvers_bits() {
    for (what, f) in fixtures() {
        let Some(kernels) = Kernels::build_or_skip(f.fem.degree.get()) else {
            return;
        };
        let p = f.problem();
        for t in f.base_level + 1..=f.max_level() {
            let op = Op::new(&p, t);
            let sys = op.level_system();
            let seed = u64::from(t);
            let (tcons, pc, vc) = right_hand_side_inputs(f, t);
            let cchi = coarse_cluster_values(&op, f.fem, &pc);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
            assert_eq!(
                bits(&cchi),
                bits(&coarse_chi(&kernels, &sys, &pc)),
                "{what}, level {t}: the coarser solution at the clusters"
            );
            let (r, b) = cycles::right_hand_sides(&op, f.fem, tcons.clone(), &pc, &vc);
            let (er, eb) = first_right_hand_sides(&kernels, &sys, &tcons, &pc, &vc, &cchi);
            same_bits(&r, &er, &format!("{what}, level {t}: r"));
            same_bits(&b, &eb, &format!("{what}, level {t}: b"));
            let single = right_hand_side(&op, f.fem, tcons.clone(), &pc, &vc, &[]);
            same_bits(&single, &er, &format!("{what}, level {t}: the cascade's r"));
            let u = pseudo_random(op.level.len(), 19 + seed);
            for u in [Vec::new(), u] {
                let cpu = cycles::cycle_right_hand_side(&op, f.fem, b.clone(), &pc, &u);
                let emu = cycle_right_hand_side(&kernels, &sys, &b, &pc, &cchi, &u);
                same_bits(&cpu, &emu, &format!("{what}, level {t}: a cycle's r"));
            }
            let x = as_f32(pseudo_random(op.level.len(), 31 + seed));
            assert_eq!(
                bits(&prolong_solution(&op, &pc, &x)),
                bits(&prolong_solution_kernel(&kernels, &sys, &pc, &x)),
                "{what}, level {t}: the cumulative solution"
            );
            let vt: Vec<[f32; 3]> = (pseudo_random(3 * op.level.len(), 37 + seed).chunks(3))
                .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
                .collect();
            for vt in [Vec::new(), vt] {
                let emu = prolong_field_kernel(&kernels, &sys, &vc, &vt);
                let cpu = prolong_field(&op, &vc, vt);
                same_bits(
                    cpu.as_flattened(),
                    emu.as_flattened(),
                    &format!("{what}, level {t}: the cumulative V"),
                );
            }
            let start = as_f32(pseudo_random(op.level.len(), 7 + seed));
            for x0 in [vec![0.0f32; op.level.len()], start] {
                let mut cpu = x0.clone();
                op.gauss_seidel_cpu(&r, &mut cpu, 3);
                let mut emu = x0;
                gauss_seidel(&kernels, &sys, &r, &mut emu, 3);
                same_bits(&cpu, &emu, &format!("{what}, level {t}: sweeps"));
            }
        }
    }
}

/// The constraint kernels, run on the CPU in the device's launch order, give
/// `system::divergence_constraints`' `G` and `T` bit for bit, fine to coarse over every level
/// of every fixture (degrees 1 and 2, each boundary), with each level's `G` feeding the next
/// coarser one as in `solver::constraints`. Skipped, with a message, without a C++ compiler.
#[test]
fn the_gpu_constraint_kernels_run_on_the_cpu_give_the_solvers_bits() {
    let f64_bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    for (what, f) in fixtures() {
        let Some(kernels) = Kernels::build_or_skip(f.fem.degree.get()) else {
            return;
        };
        let p = f.problem();
        let mut v = f.v.clone();
        v.resize_with(f.tree.levels.len(), Vec::new);
        let empty = Vec::new();
        let mut g_finer: Vec<f64> = Vec::new();
        let mut pushed_levels = 0;
        for t in (f.base_level..=f.max_level()).rev() {
            let tab = p.tables[t as usize].as_ref().expect("tables");
            let v_finer = v.get(t as usize + 1).unwrap_or(&empty);
            let gf = (t < f.max_level()).then_some(g_finer.as_slice());
            let (g, b) =
                divergence_constraints(&f.tree, t, tab, f.fem, &v[t as usize], v_finer, gf);
            let sys = constraint_level(&p, t, &v[t as usize], v_finer, gf);
            pushed_levels += usize::from(sys.push);
            let (eg, eb) = constraints(&kernels, &sys);
            assert_eq!(f64_bits(&g), f64_bits(&eg), "{what}, level {t}: G");
            same_bits(&b, &eb, &format!("{what}, level {t}: T"));
            g_finer = g;
        }
        assert!(pushed_levels > 0, "{what}: no level had finer V to push");
    }
}

/// The coupling kernels, run on the CPU in the device's launch order, give
/// `cycles::coupling_below_of` bit for bit on every level above the base's next of every
/// fixture (degrees 1 and 2, each boundary), from coefficients with zeros among them, with and
/// without a finer coupling to restrict. Skipped, with a message, without a C++ compiler.
#[test]
fn the_gpu_coupling_kernels_run_on_the_cpu_give_the_solvers_bits() {
    let f64_bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    for (what, f) in fixtures() {
        let Some(kernels) = Kernels::build_or_skip(f.fem.degree.get()) else {
            return;
        };
        let p = f.problem();
        for t in f.base_level + 1..=f.max_level() {
            let op = Op::new(&p, t);
            let sys = op.level_system();
            let seed = u64::from(t);
            // Every third coefficient zero, as where the CPU skips a function.
            let x: Vec<f32> = as_f32(pseudo_random(op.level.len(), 23 + seed))
                .into_iter()
                .enumerate()
                .map(|(k, v)| if k % 3 == 0 { 0.0 } else { v })
                .collect();
            let u = pseudo_random(op.level.len(), 29 + seed);
            for u in [Vec::new(), u] {
                let cpu = cycles::coupling_below_of(&p, &op, &x, &u);
                let emu = coupling(&kernels, &sys, &op.coupling_level(&p, &x, &u));
                assert_eq!(
                    f64_bits(&cpu),
                    f64_bits(&emu),
                    "{what}, level {t}: coupling (finer coupling: {})",
                    !u.is_empty()
                );
                assert!(cpu.iter().any(|&g| g != 0.0), "{what}, level {t}: all zero");
            }
        }
    }
}
